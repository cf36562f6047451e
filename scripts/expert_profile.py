"""Where a benchmarked run's time goes (docs/benchmark.md, "Expert baseline").

For the cheapest project and baseline_expert configurations per scene and error level of a
`cvj-sim bench` CSV, splits the run's wall time into: the fixed cost (the same call over a
1 us horizon: Python glue, set-up of the stepper and the output arrays, numbalsoda's
dispatch), the right-hand side (its evaluations x the compiled rhs's ns per call from a
compiled loop, bench.rhs_cost) and the rest (the integrator's own arithmetic, step control,
landing on samples and knots, dense output, per-sample outputs), and the cost per rhs
evaluation all in, (wall - fixed) / evaluations, against the rhs alone from a compiled loop.
Medians of ROUNDS alternating measurements; the machine may be shared, and the rhs alone is
timed at one state (a lower bound where the run's states take cheaper branches, so the rest
can come out negative: read it as 'the run is rhs-bound').

    PYTHONPATH=. python scripts/expert_profile.py BENCH_CSV [ROUNDS] > profile.md
"""
from __future__ import annotations

import csv
import sys
import time

import numpy as np

from cvj_ros import bench, bench_expert
from cvj_ros.physics.kernel.layout import build_model
from cvj_ros.physics.simulate import Simulation

LEVELS = (1e-3, 1e-6, 1e-8)


def _best(rows: list[dict], family: str, level: float) -> dict | None:
    cand = [r for r in rows if r['family'] == family and r['ok'] == 'True'
            and r['err_speed_rel'] and float(r['err_speed_rel']) <= level]
    return min(cand, key=lambda r: float(r['wall_per_sim_s'])) if cand else None


def _min_time(fn, n: int) -> float:
    best = np.inf
    for _ in range(n):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def _project_parts(scene, r: dict, n: int) -> tuple[float, float]:
    tol = float(r['tol'])
    sim = Simulation(scene, method=r['solver'], rtol=tol, atol=tol,
                     fidelity=bench.forced_levels(scene, r['fidelity']))
    kw = dict(breakpoints=r['breakpoints'] in ('True', ''), sampling=r['sampling'] or 'land')
    sim.run(1.0, sample_dt=0.05, **kw)
    full = _min_time(lambda: sim.run(1.0, sample_dt=0.05, **kw), n)
    fixed = _min_time(lambda: sim.run(1e-6, sample_dt=5e-8, **kw), n)
    return full, fixed


def _expert_parts(scene, r: dict, n: int) -> tuple[float, float]:
    tol = float(r['tol'])
    sim = Simulation(scene, fidelity=bench.forced_levels(scene, 'exact'))
    model = build_model(sim.driveline, engine=sim.engine, load=sim.load, horizon=max(1.0, scene.duration))
    addr = bench_expert.expert_cfunc().address
    x0 = sim.driveline.x0.copy()
    data = bench_expert.expert_data(model.ip, model.fp, x0.size)
    t_eval = np.linspace(0.0, 1.0, 21)
    breaks = np.asarray(sim.breakpoints(1.0), dtype=float) if r['breakpoints'] == 'True' else None
    kw = dict(rtol=tol, atol=tol, breaks=breaks)
    bench_expert.solve_expert(r['solver'], addr, x0, t_eval, data, **kw)
    full = _min_time(lambda: bench_expert.solve_expert(r['solver'], addr, x0, t_eval, data, **kw), n)
    fixed = _min_time(lambda: bench_expert.solve_expert(r['solver'], addr, x0, np.array([0.0, 1e-6]),
                                                        data, rtol=tol, atol=tol), n)
    return full, fixed


def main() -> None:
    rows = list(csv.DictReader(open(sys.argv[1])))
    rounds = int(sys.argv[2]) if len(sys.argv) > 2 else 5
    print('| scene | level | family: config | wall us (median) | fixed us | rhs evals | rhs alone ns '
          '| all-in ns per eval | rhs us (evals x ns) | rest us |')
    print('| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |')
    for name in dict.fromkeys(r['scene'] for r in rows):
        scene = bench.resolve_scene(name)
        srows = [r for r in rows if r['scene'] == name]
        for lv in LEVELS:
            for fam, parts in (('project', _project_parts), ('baseline_expert', _expert_parts)):
                r = _best(srows, fam, lv)
                if r is None:
                    continue
                meas, nss = [], []
                for _ in range(rounds):
                    meas.append(parts(scene, r, 5))
                    nss.append(bench.rhs_cost(scene, calls=20_000)['compiled_ns'])
                ns = float(np.median(nss))
                full = float(np.median([m[0] for m in meas])) * 1e6
                fixed = float(np.median([m[1] for m in meas])) * 1e6
                rhs_us = int(r['nfev']) * ns * 1e-3
                allin = (full - fixed) * 1e3 / int(r['nfev'])
                print(f'| {name} | {lv:.0e} | {fam}: {r["label"]} tol={float(r["tol"]):.0e} | {full:.0f} | '
                      f'{fixed:.0f} | {r["nfev"]} | {ns:.0f} | {allin:.0f} | {rhs_us:.0f} | '
                      f'{full - fixed - rhs_us:.0f} |', flush=True)


if __name__ == '__main__':
    main()
