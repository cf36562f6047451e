#!/usr/bin/env python3
"""Memory of a `cvj-sim run` against its duration: peak RSS during the loop and after it.

Usage: ``python scripts/run_rss.py OUT_DIR SCENE DURATION [DURATION ...] [-- RUN OPTIONS]``
(e.g. ``python scripts/run_rss.py /tmp/rss kavz685_lever 30 60 120 -- --composed``)

For each duration, runs ``cvj-sim run SCENE --out OUT_DIR/<duration> --duration D --overwrite
[RUN OPTIONS]`` and samples the process's resident set size (/proc/PID/status VmRSS, every
20 ms). The line ``cvj-sim run: loop ended ...`` on its stdout splits the samples into the
loop (and start-up) and the phases after it (last messages, closing the bag, the report).
Prints one line per duration: peak RSS in each part (MiB), the loop's and the after-loop
wall time (s, from report.json's phases), the loop's real-time factor, the growth per
simulated second against the first duration, and the loop's own slope: a least-squares line
through the RSS samples of the loop's last three quarters (from the ``loop running`` line to
``loop ended``; the first quarter, where caches and histories fill, left out), in MiB per
simulated second and bytes per exchange (wall time converted at the loop's mean speed).
Linux only (/proc). A composed run is one process, so its RSS is the run's;
with separate node processes only cvj-sim's own (recorder and report) is sampled.
"""
from __future__ import annotations

import json
import os
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


def _cpu_s(pid: int) -> float | None:
    """User + system CPU time (s) of the process, all threads (/proc/PID/stat)."""
    try:
        with open(f'/proc/{pid}/stat') as fh:
            fields = fh.read().rsplit(')', 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')
    except (OSError, IndexError, ValueError):
        return None


def measure(out: Path, scene: str, duration: float, extra: list[str]) -> dict[str, float]:
    cvj_sim = str(Path(sys.executable).with_name('cvj-sim'))
    proc = subprocess.Popen([cvj_sim, 'run', scene, '--out', str(out), '--duration', str(duration),
                             '--overwrite', *extra], stdout=subprocess.PIPE, text=True)
    phase = {'after': False, 'running': None, 'closed': False}
    cpu = {'last': 0.0}                         # CPU s at the marks, from the samples
    peaks = {'loop': 0.0, 'after': 0.0}
    samples: list[tuple[float, float]] = []     # (monotonic s, RSS MiB) while the loop runs

    def read_stdout() -> None:
        for line in proc.stdout:
            if line.startswith('cvj-sim run: loop running'):
                phase['running'] = time.monotonic()
                cpu['running'] = _cpu_s(proc.pid) or cpu['last']
            elif line.startswith('cvj-sim run: loop ended'):
                phase['after'] = True
                cpu['ended'] = _cpu_s(proc.pid) or cpu['last']
            elif line.startswith('cvj-sim run: bag closed'):
                cpu['closed'] = _cpu_s(proc.pid) or cpu['last']
    reader = threading.Thread(target=read_stdout, daemon=True)
    reader.start()
    while proc.poll() is None:
        rss = _rss_mib(proc.pid)
        key = 'after' if phase['after'] else 'loop'
        peaks[key] = max(peaks[key], rss)
        if key == 'loop' and phase['running'] is not None and rss > 0:
            samples.append((time.monotonic(), rss))
        c = _cpu_s(proc.pid)
        cpu['last'] = cpu['last'] if c is None else c
        time.sleep(0.02)
    reader.join(5)
    report = json.loads((out / 'report.json').read_text())
    ph = report['phases']
    loop_wall = report.get('loop_wall_time') or 0.0
    nan = float('nan')
    steps = round(duration / float(report.get('exchange_step') or 1e-3))
    slope = loop_slope(samples)                       # MiB per wall s
    per_sim_s = slope * loop_wall / duration if loop_wall else float('nan')
    return {'duration': duration, 'exit': proc.returncode, 'loop_peak': peaks['loop'],
            'after_peak': peaks['after'], 'loop_wall': loop_wall,
            'rtf': duration / loop_wall if loop_wall else float('nan'),
            'loop_slope': per_sim_s, 'bytes_per_exchange': per_sim_s * duration / steps * 2**20,
            'loop_cpu': cpu.get('ended', nan) - cpu.get('running', nan),
            'report_cpu': cpu['last'] - cpu.get('closed', nan),
            'after_wall': ph.get('report_done', 0.0) - ph.get('coupling_exited', 0.0),
            'report_wall': ph.get('report_done', 0.0) - ph.get('bag_closed', 0.0)}


def loop_slope(samples: list[tuple[float, float]], skip: float = 0.25) -> float:
    """Least-squares slope (MiB per wall s) of the RSS samples after the first ``skip`` of
    the loop's wall time; nan with fewer than 10 samples."""
    if len(samples) < 10:
        return float('nan')
    t0, t1 = samples[0][0], samples[-1][0]
    pts = [(t, r) for t, r in samples if t >= t0 + skip * (t1 - t0)]
    n = len(pts)
    mt = sum(t for t, _ in pts) / n
    mr = sum(r for _, r in pts) / n
    den = sum((t - mt) ** 2 for t, _ in pts)
    return sum((t - mt) * (r - mr) for t, r in pts) / den if den > 0 else float('nan')


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
              f'{r["loop_wall"]:.1f} s wall (real-time factor {r["rtf"]:.2f}), after the loop '
              f'{r["after_wall"]:.2f} s (report {r["report_wall"]:.2f} s); CPU loop '
              f'{r["loop_cpu"]:.1f} s, report {r["report_cpu"]:.2f} s '
              f'({100 * r["report_cpu"] / r["loop_cpu"]:.1f} %); loop slope '
              f'{r["loop_slope"]:.4f} MiB per simulated s ({r["bytes_per_exchange"]:.1f} bytes '
              f'per exchange){slope}', flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
