"""Ctrl-C at random moments of a command's start-up: how often it prints a traceback.

    python scripts/sigint_probe.py --tries 200 --max-delay 0.3 -- cvj-sim scenes
    python scripts/sigint_probe.py --tries 200 -- monitor_node
    python scripts/sigint_probe.py --startup 20 -- cvj-sim scenes

Each try starts the command in its own session (as a shell's foreground job), waits a
uniformly random delay in [0, --max-delay] s (seeded) and sends SIGINT to its process group,
as a terminal's Ctrl-C does. Printed: tries, how many ended before the signal, tracebacks
(``Traceback`` or ``KeyboardInterrupt`` in stderr), the exit statuses (negative: killed by
that signal, which a shell shows as 128 + n) and one traceback's last lines. ``--startup N``
instead times N uninterrupted runs (median and spread of the wall time).
"""
from __future__ import annotations

import argparse
import collections
import os
import random
import signal
import statistics
import subprocess
import sys
import time

__all__ = ['probe', 'startup', 'main']


def probe(cmd: list[str], tries: int, max_delay: float, seed: int) -> dict[str, object]:
    """Send SIGINT ``tries`` times at random delays into ``cmd``; counts and exit statuses."""
    rng = random.Random(seed)
    statuses: collections.Counter[int] = collections.Counter()
    tracebacks, finished_first, example = 0, 0, ''
    hung: list[float] = []     # delays after which the command did not end within 60 s
    for _ in range(tries):
        delay = rng.uniform(0.0, max_delay)
        proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                stderr=subprocess.PIPE, start_new_session=True)
        time.sleep(delay)
        if proc.poll() is None:
            try:
                os.killpg(proc.pid, signal.SIGINT)
            except ProcessLookupError:
                pass
        else:
            finished_first += 1
        try:
            _, err = proc.communicate(timeout=60)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            _, err = proc.communicate()
            hung.append(round(delay, 4))
        text = err.decode(errors='replace')
        statuses[proc.returncode] += 1
        if 'Traceback' in text or 'KeyboardInterrupt' in text:
            tracebacks += 1
            example = example or '\n'.join(text.strip().splitlines()[-4:])
    return {'tries': tries, 'finished_before_signal': finished_first, 'tracebacks': tracebacks,
            'statuses': dict(sorted(statuses.items())), 'example': example, 'hung': hung}


def startup(cmd: list[str], runs: int) -> dict[str, float]:
    """Wall and CPU (user + system) time of ``runs`` uninterrupted runs of ``cmd`` (s):
    medians, and the wall's min and max."""
    import resource
    times, cpus = [], []
    for _ in range(runs):
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.perf_counter()
        subprocess.run(cmd, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                       stderr=subprocess.DEVNULL, check=False)
        times.append(time.perf_counter() - t0)
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        cpus.append(after.ru_utime - before.ru_utime + after.ru_stime - before.ru_stime)
    return {'median': statistics.median(times), 'min': min(times), 'max': max(times),
            'cpu': statistics.median(cpus)}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--tries', type=int, default=200)
    parser.add_argument('--max-delay', type=float, default=0.3)
    parser.add_argument('--seed', type=int, default=1)
    parser.add_argument('--startup', type=int, default=0, metavar='N',
                        help='time N uninterrupted runs instead')
    parser.add_argument('cmd', nargs='+')
    a = parser.parse_args(argv)
    # started in the background of a script, this process may have SIGINT ignored, and its
    # children would inherit that: give them the default a terminal's foreground job has
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    if a.startup:
        r = startup(a.cmd, a.startup)
        print(f'{" ".join(a.cmd)}: {a.startup} runs, wall median {r["median"]:.3f} s '
              f'(min {r["min"]:.3f}, max {r["max"]:.3f}), CPU median {r["cpu"]:.3f} s')
        return 0
    r = probe(a.cmd, a.tries, a.max_delay, a.seed)
    print(f'{" ".join(a.cmd)}: {r["tries"]} tries (delay 0-{a.max_delay} s), '
          f'{r["finished_before_signal"]} ended before the signal, tracebacks {r["tracebacks"]}, '
          f'exit statuses {r["statuses"]}')
    if r['hung']:
        print(f'  still running 60 s after the SIGINT (then SIGKILL), delays {r["hung"]} s')
    if r['example']:
        print('  e.g.: ' + r['example'].replace('\n', '\n        '))
    return 0


if __name__ == '__main__':
    sys.exit(main())
