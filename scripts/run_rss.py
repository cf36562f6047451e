#!/usr/bin/env python3
"""Memory of a `cvj-sim run` against its duration: peak RSS during the loop and after it.

Usage: ``python scripts/run_rss.py OUT_DIR SCENE DURATION [DURATION ...] [-- RUN OPTIONS]``
(e.g. ``python scripts/run_rss.py /tmp/rss kavz685_lever 30 60 120 -- --composed``)

For each duration, runs ``cvj-sim run SCENE --out OUT_DIR/<duration> --duration D --overwrite
[RUN OPTIONS]`` and samples the process's resident set size (/proc/PID/status VmRSS, every
20 ms). The line ``cvj-sim run: loop ended ...`` on its stdout splits the samples into the
loop (and start-up) and the phases after it (last messages, closing the bag, the report).
Prints one line per duration: peak RSS in each part (MiB), the loop's and the after-loop
wall time (s, from report.json's phases), and the growth per simulated second against the
first duration. Linux only (/proc). A composed run is one process, so its RSS is the run's;
with separate node processes only cvj-sim's own (recorder and report) is sampled.
"""
from __future__ import annotations

import json
import subprocess
import sys
import threading
import time
from pathlib import Path


def _rss_mib(pid: int) -> float:
    try:
        with open(f'/proc/{pid}/status') as fh:
            for line in fh:
                if line.startswith('VmRSS:'):
                    return int(line.split()[1]) / 1024
    except OSError:
        pass
    return 0.0


def measure(out: Path, scene: str, duration: float, extra: list[str]) -> dict[str, float]:
    cvj_sim = str(Path(sys.executable).with_name('cvj-sim'))
    proc = subprocess.Popen([cvj_sim, 'run', scene, '--out', str(out), '--duration', str(duration),
                             '--overwrite', *extra], stdout=subprocess.PIPE, text=True)
    phase = {'after': False}
    peaks = {'loop': 0.0, 'after': 0.0}

    def read_stdout() -> None:
        for line in proc.stdout:
            if line.startswith('cvj-sim run: loop ended'):
                phase['after'] = True
    reader = threading.Thread(target=read_stdout, daemon=True)
    reader.start()
    while proc.poll() is None:
        rss = _rss_mib(proc.pid)
        key = 'after' if phase['after'] else 'loop'
        peaks[key] = max(peaks[key], rss)
        time.sleep(0.02)
    reader.join(5)
    report = json.loads((out / 'report.json').read_text())
    ph = report['phases']
    return {'duration': duration, 'exit': proc.returncode, 'loop_peak': peaks['loop'],
            'after_peak': peaks['after'], 'loop_wall': report.get('loop_wall_time') or 0.0,
            'after_wall': ph.get('report_done', 0.0) - ph.get('coupling_exited', 0.0),
            'report_wall': ph.get('report_done', 0.0) - ph.get('bag_closed', 0.0)}


def main(argv: list[str]) -> int:
    extra: list[str] = []
    if '--' in argv:
        i = argv.index('--')
        argv, extra = argv[:i], argv[i + 1:]
    if len(argv) < 3:
        print(__doc__.strip().splitlines()[2], file=sys.stderr)
        return 2
    out, scene, durations = Path(argv[0]), argv[1], [float(d) for d in argv[2:]]
    first = None
    for d in durations:
        r = measure(out / f'{d:g}', scene, d, extra)
        first = first or r
        slope = ''
        if r is not first and d > first['duration']:
            per_s = lambda key: (r[key] - first[key]) / (d - first['duration'])  # noqa: E731
            slope = (f'; growth per simulated s against {first["duration"]:g} s: loop '
                     f'{per_s("loop_peak"):.3f} MiB, after {per_s("after_peak"):.3f} MiB')
        print(f'run_rss: {scene} {d:g} s {" ".join(extra)}: exit {r["exit"]}, peak RSS loop '
              f'{r["loop_peak"]:.0f} MiB, after the loop {r["after_peak"]:.0f} MiB; loop '
              f'{r["loop_wall"]:.1f} s wall, after the loop {r["after_wall"]:.2f} s (report '
              f'{r["report_wall"]:.2f} s){slope}', flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
