#!/usr/bin/env python3
"""Measure which exchange step free-run holds on this machine (docs/ros.md, Free-run).

For each exchange step h: ``cvj-sim run SCENE --mode free-run --exchange-step h`` (skip)
for ``--duration`` simulated seconds, then one table row from its ``report.json``: the
1-minute load average before the run, lateness p50/p99/max, ticks skipped, drift max,
joint states recorded vs published, and whether p99 lateness < h/2 (the rate is "held").

Default scene: the two-mass scene of test/e2e/test_free_run_deadline.py (linear engine,
spring, constant load), written to the output directory. Runs are sequential; the
processes are cvj-sim's own (started and stopped by it). Timing on a shared machine is
noisy: repeat and quote the load average.

    python scripts/free_run_rate.py --steps 0.01 0.005 0.002 0.001 --duration 10 --out /tmp/frr
        [--composed] [--scene config/scenes/kavz685_lever.yaml]
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--steps', type=float, nargs='+', default=[0.01, 0.005, 0.002, 0.001],
                    help='exchange steps h in s')
    ap.add_argument('--duration', type=float, default=10.0, help='simulated s per run')
    ap.add_argument('--scene', default=None, help='scene (default: the e2e two-mass scene)')
    ap.add_argument('--catch-up', choices=('skip', 'burst'), default='skip')
    ap.add_argument('--rt-priority', type=int, default=0,
                    help="the coupling loop thread's SCHED_FIFO priority (cvj-sim run --rt-priority)")
    ap.add_argument('--composed', action='store_true',
                    help='every node and the recorder in one process (cvj-sim run --composed)')
    ap.add_argument('--out', type=Path, required=True, help='directory for the runs')
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    scene = args.scene
    if scene is None:
        sys.path.insert(0, str(ROOT / 'test' / 'e2e'))
        from test_free_run_deadline import SCENE
        path = args.out / 'two_mass.yaml'
        path.write_text(yaml.safe_dump(dict(SCENE, duration=args.duration), sort_keys=False))
        scene = str(path)
    cvj_sim = str(Path(sys.executable).with_name('cvj-sim'))
    print('| h | load avg | lateness p50 / p99 / max | ticks skipped | drift max | states recorded '
          '| p99 < h/2 |')
    print('| --- | --- | --- | --- | --- | --- | --- |')
    for h in args.steps:
        load = os.getloadavg()[0]
        out = args.out / f'h{h:g}'
        proc = subprocess.run([cvj_sim, 'run', scene, '--out', str(out), '--overwrite', '--mode',
                               'free-run', '--exchange-step', str(h), '--duration', str(args.duration),
                               '--catch-up', args.catch_up, '--rt-priority', str(args.rt_priority)]
                              + (['--composed'] if args.composed else []),
                              capture_output=True, text=True)
        try:
            report = json.loads((out / 'report.json').read_text())
            fr = report['metrics']['free_run']
        except (OSError, KeyError, ValueError):
            print(f'| {h * 1e3:g} ms | {load:.1f} | run failed (exit {proc.returncode}): '
                  f'{proc.stderr.strip().splitlines()[-1:]} |')
            continue
        n = fr['ticks_handled']
        recorded = report['counts'].get('/driveline/joint_states', 0)
        p99 = fr['lateness_us_p99'] * 1e-6
        print(f'| {h * 1e3:g} ms | {load:.1f} | {fr["lateness_us_p50"] / 1e3:.2f} / '
              f'{fr["lateness_us_p99"] / 1e3:.1f} / {fr["lateness_us_max"] / 1e3:.1f} ms | '
              f'{fr["ticks_skipped"]} of {n} | {fr["drift_max_s"] * 1e3:.1f} ms | '
              f'{recorded} of {fr["ticks_run"] + 1} | {"yes" if p99 < h / 2 else "no"} |', flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
