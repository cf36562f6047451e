#!/usr/bin/env python3
"""Peak resident set size (RSS) of a command, e.g. one of the slow studies.

Usage: ``python scripts/peak_rss.py -- python -m pytest -q -p no:cacheprovider -m slow
test/hard_cases/test_long_run_6000rpm.py``

Runs the command as a child process, waits for it, and prints one line: exit code, wall
time (s) and the child's peak RSS from ``resource.getrusage(RUSAGE_CHILDREN).ru_maxrss``
(Linux reports KiB; printed in MiB). RUSAGE_CHILDREN covers every waited-for descendant;
its ru_maxrss is the largest single descendant's peak, not a sum. Also gives the
baseline of an interpreter that only imports the package (``--baseline``).
"""
from __future__ import annotations

import resource
import subprocess
import sys
import time


def peak_rss_mib(cmd: list[str]) -> tuple[int, float, float]:
    """(exit code, wall s, peak RSS MiB) of ``cmd`` run to completion."""
    t0 = time.perf_counter()
    rc = subprocess.call(cmd)
    wall = time.perf_counter() - t0
    kib = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    return rc, wall, kib / 1024.0


def main(argv: list[str]) -> int:
    if argv[:1] == ['--baseline']:
        cmd = [sys.executable, '-c', 'import cvj_ros.physics.simulate, cvj_ros.physics.kernel.rhs_nb']
    elif argv[:1] == ['--']:
        cmd = argv[1:]
    else:
        print(__doc__.strip().splitlines()[2], file=sys.stderr)
        return 2
    if not cmd:
        print('peak_rss: no command given', file=sys.stderr)
        return 2
    rc, wall, mib = peak_rss_mib(cmd)
    print(f'peak_rss: exit {rc}, wall {wall:.1f} s, peak RSS {mib:.1f} MiB: {" ".join(cmd)}')
    return rc


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
