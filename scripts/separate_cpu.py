#!/usr/bin/env python3
"""CPU per exchange step of every process and thread of a separate-process `cvj-sim run`
(results in docs/nodes.md, "Separate processes: where the CPU goes").

Runs ``cvj-sim run SCENE --duration D`` in this process (``cvj_ros.orchestrate.run``: engine,
load and coupling nodes as their own processes, the recorder and the hosted monitor - a
thread named ``monitor_node`` - in this one) and
samples ``/proc/<pid>/task/<tid>/stat`` (user + system CPU of each thread) every 50 ms. The
window is the middle of the loop: from the sample where the recorder holds 10 % of the
run's joint states to the one where it holds 90 %, so start-up and shutdown stay out; CPU
per exchange = a thread's CPU in the window / the joint states recorded in it.

On a 2-core machine the loop is CPU-bound when the total is close to twice the wall time
per exchange; then any CPU taken from any process shortens the exchange.

Usage: ``python scripts/separate_cpu.py [SCENE ...] [--duration 5] [--runs 1]``
"""
from __future__ import annotations

import argparse
import io
import json
import os
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

TCK = os.sysconf('SC_CLK_TCK')


def thread_cpu(pid: int) -> dict[str, float]:
    """CPU seconds per thread of ``pid``, keyed ``name/tid`` (thread name from ``comm``)."""
    out: dict[str, float] = {}
    for tid in os.listdir(f'/proc/{pid}/task'):
        try:
            with open(f'/proc/{pid}/task/{tid}/stat') as fh:
                text = fh.read()
        except OSError:
            continue
        comm = text[text.index('(') + 1:text.rindex(')')]
        fields = text.rsplit(')', 1)[1].split()
        out[f'{comm}/{tid}'] = (int(fields[11]) + int(fields[12])) / TCK
    return out


def measure(scene: str, duration: float, out: Path) -> dict[str, Any]:
    """One run; returns {'rtf', 'wall_us', 'steps', 'cpu': {process: {thread: us per step}}}."""
    import cvj_ros.orchestrate as orch
    recorders: list[Any] = []

    class Recorder(orch._Recorder):          # to read the recorder's counts while it runs
        def __init__(self, *args: Any, **kwargs: Any) -> None:
            super().__init__(*args, **kwargs)
            recorders.append(self)

    samples: list[tuple[float, int, dict[str, dict[str, float]]]] = []
    stop = threading.Event()
    me = os.getpid()

    def poll(procs: dict[str, Any]) -> None:
        from cvj_ros.bag import _name_os_thread
        _name_os_thread('cpu-poll')          # this thread's own CPU is left out
        while not stop.is_set():
            snap = {'orchestrator (recorder)': thread_cpu(me)}
            for name, p in procs.items():
                try:
                    snap[name] = thread_cpu(p.pid)
                except OSError:
                    pass
            n = recorders[0].recorder.counts.get('/driveline/joint_states', 0) if recorders else 0
            samples.append((time.monotonic(), n, snap))
            stop.wait(0.05)

    original = orch._Recorder
    orch._Recorder = Recorder
    try:
        orch.run(orch.RunOptions(scene=scene, out=out, duration=duration, overwrite=True),
                 stream=io.StringIO(),
                 on_started=lambda procs: threading.Thread(target=poll, args=(procs,),
                                                           daemon=True).start())
    finally:
        stop.set()
        orch._Recorder = original
    report = json.loads((out / 'report.json').read_text())
    total = report['steps_expected']
    a = next(s for s in samples if s[1] >= 0.1 * total)
    b = next(s for s in samples if s[1] >= 0.9 * total)
    steps = b[1] - a[1]
    cpu: dict[str, dict[str, float]] = {}
    for proc, threads in b[2].items():
        before = a[2].get(proc, {})
        per = {}
        for key, c in threads.items():
            used = c - before.get(key, 0.0)
            if used > 0 and not key.startswith('cpu-poll/'):
                name = key.rsplit('/', 1)[0]
                per[name] = per.get(name, 0.0) + used / steps * 1e6
        cpu[proc] = per
    return {'rtf': report['real_time_factor'], 'wall_us': report['wall_per_step'] * 1e6,
            'window_us': (b[0] - a[0]) / steps * 1e6, 'steps': steps, 'cpu': cpu}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('scenes', nargs='*', default=['kavz685_lever', 'fwd_halfshaft'])
    ap.add_argument('--duration', type=float, default=5.0)
    ap.add_argument('--runs', type=int, default=1)
    args = ap.parse_args(argv)
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    print(f'load average {os.getloadavg()[0]:.2f}')
    with tempfile.TemporaryDirectory() as tmp:
        for scene in args.scenes:
            for k in range(args.runs):
                r = measure(scene, args.duration, Path(tmp) / f'{scene}_{k}')
                total = sum(sum(t.values()) for t in r['cpu'].values())
                print(f'{scene} run {k + 1}: real-time factor {r["rtf"]:.2f}, '
                      f'{r["wall_us"]:.0f} us per exchange; CPU per exchange (us) in the middle '
                      f'{r["steps"]} steps: {total:.0f} of {2 * r["window_us"]:.0f} on 2 cores')
                for proc, threads in r['cpu'].items():
                    parts = ', '.join(f'{t} {us:.0f}' for t, us in
                                      sorted(threads.items(), key=lambda kv: -kv[1]) if us >= 1)
                    print(f'  {proc:24s} {sum(threads.values()):5.0f}  ({parts})')
    print(f'load average {os.getloadavg()[0]:.2f}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
