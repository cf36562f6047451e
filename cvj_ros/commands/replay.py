"""`cvj-sim replay BAG`: publish a recorded bag with its own /clock (runs replay_node in-process)."""
from __future__ import annotations

import argparse

from cvj_ros.errors import CvjError

NAME = 'replay'
HELP = 'replay a recorded bag on ROS topics with its own /clock'
DESCRIPTION = """Publish a cvj_ros bag's topics (raw CDR, original types, project QoS) paced by
their record time (simulated time), with /clock from the bag. Same as
`replay_node --ros-args -p bag:=BAG ...`.

examples:
  cvj-sim replay runs/demo/bag --rate 2
  cvj-sim replay runs/demo/bag --loop --topics /driveline/joint_states /load/wrench
"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('bag', help='bag directory (mcap or sqlite3)')
    parser.add_argument('--rate', type=float, default=1.0, help='playback speed factor (default 1.0)')
    parser.add_argument('--loop', action='store_true', help='start over at the end')
    parser.add_argument('--topics', nargs='+', default=[], metavar='T',
                        help='topics or glob patterns to replay (* within one name segment, '
                             '** across segments; default: all)')
    parser.add_argument('--start-delay', type=float, default=0.5,
                        help='wall seconds before the first message, for discovery (default 0.5)')
    parser.add_argument('--no-clock', action='store_true', help='do not publish /clock')


def replay_ros_args(args: argparse.Namespace) -> list[str]:
    """The ``--ros-args`` of replay_node for these options (validated, bag checked)."""
    from cvj_ros import bag as bagmod
    if not args.rate > 0:
        raise CvjError(f'--rate: must be > 0, got {args.rate}')
    if not args.start_delay >= 0:
        raise CvjError(f'--start-delay: must be >= 0, got {args.start_delay}')
    info = bagmod.bag_info(args.bag)  # BagError names a missing/unreadable bag
    from cvj_ros.topic_pattern import topic_selected
    for t in args.topics:
        if not any(topic_selected(x, t) for x in info.types):
            raise CvjError(f'--topics: {t}: topic not in bag {args.bag}')
    ros = ['--ros-args', '-p', f'bag:={args.bag}', '-p', f'rate:={float(args.rate)}',
           '-p', f'loop:={str(bool(args.loop)).lower()}',
           '-p', f'start_delay:={float(args.start_delay)}',
           '-p', f'publish_clock:={str(not args.no_clock).lower()}']
    if args.topics:
        ros += ['-p', 'topics:=[' + ','.join(f"'{t}'" for t in args.topics) + ']']
    return ros


def run(args: argparse.Namespace) -> int:
    from cvj_ros.nodes.common import run_node
    from cvj_ros.nodes.replay_node import ReplayNode
    ros = replay_ros_args(args)
    return run_node(ReplayNode, ['cvj-sim', *ros], prog='cvj-sim replay')
