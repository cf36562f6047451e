"""The kernel's rhs against the hand-written ones, both measurements in the same minutes
(docs/benchmark.md, "The stiff rhs against its hand-written twin").

Per model of bench.HAND_WRITTEN, ROUNDS alternating rounds of CALLS calls each:
the chained loop (bench_handrhs.time_*_chain: not inlined, each input from the output
before; the timing thread's CPU time) and the cycled loop (time_*_calls, the bench's loop
before the chain), the latter with its wall time (perf_counter, what the bench reported)
and its CPU time and the scheduler's run delay (/proc/self/schedstat) taken around the same
call. Medians over the rounds, min-max in brackets, ratios the medians of per-round ratios.

    PYTHONPATH=. python scripts/handrhs_clocks.py [ROUNDS] [CALLS]
"""
from __future__ import annotations

import os
import sys
import time
from typing import Any, Callable

import numpy as np

from cvj_ros import bench
from cvj_ros import bench_handrhs as hw
from cvj_ros.physics.kernel.layout import build_model
from cvj_ros.physics.simulate import Simulation

MODELS = {'hooke_2dof': (hw.hooke_2dof_params, hw.time_hooke_2dof_calls, hw.time_hooke_2dof_chain),
          'stiff': (hw.stiff_params, hw.time_stiff_calls, hw.time_stiff_chain),
          'fwd_halfshaft': (hw.fwd_halfshaft_params, hw.time_fwd_halfshaft_calls,
                            hw.time_fwd_halfshaft_chain)}


def _run_delay_ns() -> int:
    """Time this process waited for a CPU while runnable (ns; 0 where not available)."""
    try:
        with open('/proc/self/schedstat') as fh:
            return int(fh.read().split()[1])
    except (OSError, IndexError, ValueError):
        return 0


def _timed(fun: Callable[[int], Any], calls: int) -> tuple[float, float, float]:
    """(wall, CPU, run delay) ns per call of fun(calls)."""
    d0 = _run_delay_ns()
    w0, c0 = time.perf_counter(), time.thread_time()
    fun(calls)
    c1, w1 = time.thread_time(), time.perf_counter()
    d1 = _run_delay_ns()
    return (w1 - w0) / calls * 1e9, (c1 - c0) / calls * 1e9, (d1 - d0) / calls


def _fmt(v: list[float]) -> str:
    return f'{np.median(v):.1f} ({min(v):.1f}-{max(v):.1f})'


def main(rounds: int = 7, calls: int = 200_000) -> None:
    print(f'load average {os.getloadavg()[0]:.1f} {os.getloadavg()[1]:.1f} at the start')
    print('| model | chain: kernel / hand ns (CPU) | chain floor | ratio | cycled, wall: kernel / hand '
          '| ratio | cycled, CPU: kernel / hand | ratio | wall - CPU waiting (ns per call) |')
    print('| --- | --- | --- | --- | --- | --- | --- | --- | --- |')
    for name, (params, cycle, chain) in MODELS.items():
        scene = bench.hooke_2dof_scene() if name == 'hooke_2dof' else bench.resolve_scene(name)
        sim = Simulation(scene, fidelity=bench.forced_levels(scene, 'exact'))
        model = build_model(sim.driveline, engine=sim.engine, load=sim.load)
        ys = hw.timing_states(model.x0)
        p = params(scene)
        funs = {
            'ck': lambda n: hw.time_kernel_chain(n, 0.001, ys, hw.CHAIN_H, model.ip, model.fp),
            'ch': lambda n: chain(n, 0.001, ys, hw.CHAIN_H, p),
            'cn': lambda n: hw.time_null_chain(n, 0.001, ys, hw.CHAIN_H, p),
            'yk': lambda n: hw.time_kernel_calls(n, 0.001, ys, model.ip, model.fp),
            'yh': lambda n: cycle(n, 0.001, ys, p)}
        for f in funs.values():
            f(10)
        res: dict[str, list[tuple[float, float, float]]] = {k: [] for k in funs}
        for _ in range(rounds):
            for k, f in funs.items():
                res[k].append(_timed(f, calls))

        def col(k: str, i: int) -> list[float]:
            return [r[i] for r in res[k]]

        def ratio(a: str, b: str, i: int) -> str:
            r = np.array(col(a, i)) / np.array(col(b, i))
            return f'{np.median(r):.2f}x ({r.min():.2f}-{r.max():.2f})'

        wait = [r[2] for k in ('yk', 'yh') for r in res[k]]
        gap = [r[0] - r[1] for k in ('yk', 'yh') for r in res[k]]
        print(f'| {name} | {_fmt(col("ck", 1))} / {_fmt(col("ch", 1))} | {_fmt(col("cn", 1))} '
              f'| {ratio("ck", "ch", 1)} | {_fmt(col("yk", 0))} / {_fmt(col("yh", 0))} '
              f'| {ratio("yk", "yh", 0)} | {_fmt(col("yk", 1))} / {_fmt(col("yh", 1))} '
              f'| {ratio("yk", "yh", 1)} | wall - CPU {_fmt(gap)}, run delay {_fmt(wait)} |',
              flush=True)
    print(f'load average {os.getloadavg()[0]:.1f} {os.getloadavg()[1]:.1f} at the end')


if __name__ == '__main__':
    try:
        counts = [int(a) for a in sys.argv[1:3]]
    except ValueError:
        sys.exit(f'handrhs_clocks.py: ROUNDS and CALLS must be integers, got {" ".join(sys.argv[1:3])}')
    main(*counts)
