#!/usr/bin/env python3
"""`cvj-sim analyze` at bag scale: write a run-like bag of N messages, time its analysis.

Usage: ``python scripts/analyze_scale.py OUT_DIR [N_MESSAGES] [--storage mcap|sqlite3]
[--keep]``

The bag is what a lockstep run at a 1 ms exchange step records, without running one:
per step one /clock, one /driveline/joint_states (4 shafts: an engine, a joint's input and
output, a wheel; speeds about 40 rad/s with a 2nd-order ripple), one /engine/wrench and one
/load/wrench answer (4 messages per step), a /diagnostics status every 100 steps and one
/driveline/scene, written through cvj_ros.bag.BagWriter with the project's own encoders.
Then ``cvj-sim analyze BAG --json`` runs as a child process; the script prints one line:
messages, storage, bag size, wall time (s) and the child's peak RSS (MiB, getrusage
RUSAGE_CHILDREN; the largest single descendant's peak).
"""
from __future__ import annotations

import argparse
import resource
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

H_NS = 1_000_000
NAMES = ['engine_crank', 'lever_input', 'lever_output', 'wheel']


def write_bag(path: Path, n_messages: int, storage: str) -> int:
    """A run-like bag of about ``n_messages`` messages at ``path``; returns the step count."""
    from cvj_ros import bag
    from cvj_ros.nodes.cdr import ClockEncoder, JointStateEncoder, WrenchStampedEncoder
    from cvj_ros.nodes.diagnostics import diagnostic_array_encoder, plain_status
    diag = diagnostic_array_encoder()
    steps = n_messages // 4
    js = JointStateEncoder(NAMES, 'driveline')
    eng, load = WrenchStampedEncoder("engine_crank"), WrenchStampedEncoder("wheel")
    clock = ClockEncoder()
    w = bag.BagWriter(path, storage=storage, overwrite=True)
    for topic in (bag.SCENE_TOPIC, bag.CLOCK_TOPIC, bag.JOINT_STATES_TOPIC, '/engine/wrench',
                  '/load/wrench', '/diagnostics'):
        w.add_topic(topic)
    w.write(bag.SCENE_TOPIC, 0, _string_cdr('scene: {name: synthetic}\nseed: 0\n'))
    batch: list[tuple[str, int, bytes]] = []
    phi = np.zeros(4)
    for k in range(steps):
        t_ns = k * H_NS
        sec, nsec = divmod(t_ns, 1_000_000_000)
        t = t_ns * 1e-9
        omega = 40.0 + np.array([0.0, 0.0, 0.3, 0.1]) * np.sin(2 * phi[0] + np.arange(4))
        phi += omega * 1e-3
        effort = np.array([100.0, 100.0, 100.0, 100.0]) + 5.0 * np.cos(2 * phi[0])
        batch += [(bag.CLOCK_TOPIC, t_ns, clock.encode(sec, nsec)),
                  (bag.JOINT_STATES_TOPIC, t_ns, js.encode(sec, nsec, phi, omega, effort)),
                  ('/engine/wrench', t_ns, eng.encode(sec, nsec, 0, 0, 0, 0, 0, 600 - 12.5 * omega[0])),
                  ('/load/wrench', t_ns, load.encode(sec, nsec, 0, 0, 0, 0, 0, 100.0 + np.sin(t)))]
        if k % 100 == 0:
            batch.append(('/diagnostics', t_ns, diag.encode(
                t_ns, 'driveline', [plain_status('coupling_node: loop', b'\x00', 'running',
                                                 {'ignored_stamps': 0})])))
        if len(batch) >= 4096:
            w.write_batch(batch)
            batch = []
    w.write_batch(batch)
    w.close()
    return steps


def _string_cdr(text: str) -> bytes:
    import struct
    raw = text.encode() + b'\x00'
    return b'\x00\x01\x00\x00' + struct.pack('<I', len(raw)) + raw


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    ap.add_argument('out', type=Path)
    ap.add_argument('messages', type=int, nargs='?', default=1_000_000)
    ap.add_argument('--storage', choices=('mcap', 'sqlite3'), default='mcap')
    ap.add_argument('--keep', action='store_true', help='reuse OUT/bag if it exists')
    a = ap.parse_args(argv)
    bag_dir = a.out / 'bag'
    if not (a.keep and (bag_dir / 'metadata.yaml').exists()):
        if bag_dir.exists():
            shutil.rmtree(bag_dir)
        t0 = time.perf_counter()
        write_bag(bag_dir, a.messages, a.storage)
        print(f'wrote {bag_dir} in {time.perf_counter() - t0:.1f} s', file=sys.stderr)
    size = sum(f.stat().st_size for f in bag_dir.iterdir()) / 2**20
    cvj_sim = str(Path(sys.executable).with_name('cvj-sim'))
    t0 = time.perf_counter()
    r = subprocess.run([cvj_sim, 'analyze', str(bag_dir), '--json'], stdout=subprocess.DEVNULL,
                       stderr=subprocess.PIPE, text=True)
    wall = time.perf_counter() - t0
    rss = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
    from cvj_ros import bag
    n = sum(bag.bag_info(bag_dir).counts.values())
    print(f'analyze_scale: {n} messages, {a.storage}, {size:.0f} MiB: exit {r.returncode}, '
          f'wall {wall:.1f} s, peak RSS {rss:.0f} MiB' + (f'; {r.stderr.strip()}' if r.returncode else ''))
    return r.returncode


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
