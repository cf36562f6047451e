#!/usr/bin/env python3
"""Run the ROS, end-to-end and process tests N times with both cores kept busy.

``make test-stress`` (or ``python scripts/stress.py``). Each repetition

* starts ``--load`` CPU burners (default 2 = the cores of the target machine kind:
  ``python -c 'while True: pass'``), started and killed by this script (by pid);
* runs pytest on :data:`STRESS_PATHS` on a fresh block of ROS domain ids
  (``CVJ_TEST_DOMAINS``, see test/conftest.py): repetition r uses
  ``BASE + r * SPAN .. BASE + r * SPAN + SPAN - 1``, so no repetition meets another's
  leftovers;
* counts as passed when pytest exits 0.

Tests marked ``stress`` (heavy repetitions, e.g. every attack of
test/robustness/test_hostile_runs.py) run here and not in ``make test``: this script's
``-m`` replaces the one in pytest.ini.

Prints one line per repetition and the summary ``stress: N/REPS passed``; exit status 0
only if all passed. Environment: ``CVJ_STRESS_DOMAIN_BASE`` (default ``ROS_DOMAIN_ID`` or
100), ``CVJ_STRESS_DOMAIN_SPAN`` (default 4), ``CVJ_STRESS_REPS`` (default 5).
"""
from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
# The tests that start DDS participants or real processes (the colcon build is left out: it
# compiles nothing timing-sensitive and takes minutes).
STRESS_PATHS = ('test/nodes', 'test/e2e/test_run.py', 'test/robustness/test_faults_processes.py',
                'test/robustness/test_fuzz_wrench_inputs.py', 'test/robustness/test_hard_kill.py',
                'test/robustness/test_signal_stop.py',
                'test/test_bag.py', 'test/test_bench_loop.py', 'test/e2e/test_vehicle_stack.py',
                'test/commands/test_run_external_options.py', 'test/e2e/test_free_run_deadline.py',
                'test/robustness/test_hostile_peers.py', 'test/robustness/test_hostile_runs.py',
                # runs started by hand or as ros2 launch starts them (no gate between the
                # processes: what discovery delays break first) and the hosted-monitor recorder
                'test/e2e/test_hand_start.py', 'test/launch/test_launch_processes.py',
                'test/orchestrate/test_recorder_host.py')


def _burners(n: int) -> list[subprocess.Popen]:
    return [subprocess.Popen([sys.executable, '-c', 'while True: pass']) for _ in range(n)]


def _stop(procs: list[subprocess.Popen]) -> None:
    for p in procs:
        if p.poll() is None:
            p.kill()
    for p in procs:
        p.wait()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog='scripts/stress.py', description=__doc__.split('\n')[0])
    parser.add_argument('--reps', type=int, default=int(os.environ.get('CVJ_STRESS_REPS', '5')))
    parser.add_argument('--load', type=int, default=2, help='CPU burner processes (default 2)')
    parser.add_argument('pytest_args', nargs='*', help='extra pytest arguments (after --)')
    args = parser.parse_args(argv)
    signal.signal(signal.SIGTERM, lambda *_: (_ for _ in ()).throw(KeyboardInterrupt()))
    base = int(os.environ.get('CVJ_STRESS_DOMAIN_BASE') or os.environ.get('ROS_DOMAIN_ID') or 100)
    span = int(os.environ.get('CVJ_STRESS_DOMAIN_SPAN', '4'))
    paths = [p for p in STRESS_PATHS if (ROOT / p).exists()]
    passed = 0
    for r in range(args.reps):
        lo = base + r * span
        env = dict(os.environ, CVJ_TEST_DOMAINS=f'{lo}-{lo + span - 1}', ROS_DOMAIN_ID=str(lo),
                   ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
        env.pop('CVJ_TEST_FRESH_DOMAIN', None)
        burners = _burners(args.load)
        t0 = time.monotonic()
        proc = subprocess.Popen([sys.executable, '-m', 'pytest', '-q', '-p', 'no:cacheprovider',
                                 '-m', 'not slow and not colcon', *paths, *args.pytest_args],
                                cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                text=True, start_new_session=True)
        try:
            output, _ = proc.communicate()
        finally:   # also on Ctrl-C / SIGTERM: no burner and no test process left behind
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()
            _stop(burners)
        tail = [ln for ln in output.strip().splitlines() if ln.strip()][-1:] or ['']
        ok = proc.returncode == 0
        passed += ok
        print(f'stress: repetition {r + 1}/{args.reps} on domains {lo}-{lo + span - 1} with '
              f'{args.load} burners: {"passed" if ok else "FAILED"} in {time.monotonic() - t0:.0f} s: '
              f'{tail[0]}', flush=True)
        if not ok:
            print(output[-6000:], flush=True)
    print(f'stress: {passed}/{args.reps} passed', flush=True)
    return 0 if passed == args.reps else 1


if __name__ == '__main__':
    sys.exit(main())
