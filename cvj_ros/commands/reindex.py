"""`cvj-sim reindex BAG`: rebuild metadata.yaml (and a readable storage file) of a bag whose
recording was killed; see :mod:`cvj_ros.reindex`."""
from __future__ import annotations

import argparse

NAME = 'reindex'
HELP = 'rebuild a bag whose recording was killed (metadata.yaml from the data on disk)'
DESCRIPTION = """Rebuild a rosbag2 bag (mcap or sqlite3) from what is on disk, like `ros2 bag
reindex`: a run killed hard (SIGKILL, OOM killer, power loss) leaves no metadata.yaml and
an mcap file without its summary. Every complete message is salvaged (also from a last
chunk cut short), written again with a new metadata.yaml (topics, types, counts, start,
duration, storage id, custom data recovered from the /driveline/scene message); the
damaged original is kept as <file>.orig.

examples:
  cvj-sim reindex runs/demo/bag
  cvj-sim analyze runs/demo/bag
"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('bag', help='bag directory (or its .mcap/.db3 file)')


def run(args: argparse.Namespace) -> int:
    from cvj_ros.reindex import reindex
    res = reindex(args.bag)
    total = sum(res.counts.values())
    print(f'reindexed {res.path} ({res.storage}): {total} messages on {len(res.counts)} topics, '
          f'start {res.start_ns * 1e-9:.6f} s, duration {res.duration_s:.6f} s')
    for topic, n in sorted(res.counts.items()):
        print(f'  {topic}: {n}')
    if res.damage:
        print(f'  recovered from a damaged recording: {res.damage}')
    for kept in res.kept_original:
        print(f'  original kept as {kept}')
    return 0
