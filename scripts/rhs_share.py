"""How much of a run is its rhs, project against expert (docs/benchmark.md, "Where the
missed levels' time goes").

For per scene and error level the cheapest project and baseline_expert configurations of a
`cvj-sim bench` CSV (as scripts/expert_rounds.py picks them), in ROUNDS rounds:
the project's run split by scripts/run_profile.py (Python around the call, the call's
unboxing, the per-sample outputs, the rhs = evaluations x ns per call from a compiled loop
at the run's sample states, the stepper's own arithmetic), and the expert's numbalsoda call
(one call over the bench's 21 samples, CPU time, min over CALLS calls) with its evaluations
x the same ns per call and the rest (numbalsoda's own arithmetic and dispatch). Medians of
the rounds, us per simulated second. numbalsoda integrates the exact model: where the project
row runs the ideal or closed one, the expert row's ns per call is the project's (cheaper)
model's, so read the scene's exact rows for the expert's rhs there.

    PYTHONPATH=. python scripts/rhs_share.py BENCH_CSV [ROUNDS] > share.md
    PYTHONPATH=. python scripts/rhs_share.py --per-call    # ns per rhs call, CPU time
"""
from __future__ import annotations

import csv
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from expert_rounds import LEVELS, _best  # noqa: E402
from run_profile import _min_cpu, profile  # noqa: E402

from cvj_ros import bench, bench_expert  # noqa: E402
from cvj_ros.physics.kernel.layout import build_model  # noqa: E402
from cvj_ros.physics.simulate import Simulation  # noqa: E402

CALLS = 300


def _expert(name: str, r: dict, calls: int = CALLS) -> tuple[float, int]:
    """(CPU s of the least call, rhs evaluations) of numbalsoda as bench.run_expert calls it."""
    scene = bench.resolve_scene(name)
    tol = float(r['tol'])
    sim = Simulation(scene, fidelity=bench.forced_levels(scene, 'exact'))
    model = build_model(sim.driveline, engine=sim.engine, load=sim.load,
                        horizon=max(1.0, float(scene.duration)))
    addr = bench_expert.expert_cfunc().address
    x0 = np.ascontiguousarray(sim.driveline.x0, dtype=float)
    data = bench_expert.expert_data(model.ip, model.fp, x0.size)
    t_eval = np.linspace(0.0, 1.0, 21)
    ip, fp = model.ip, model.fp   # noqa: F841 - kept alive: data holds their addresses
    _sol, nfev, _ok = bench_expert.solve_expert(r['solver'], addr, x0, t_eval, data, rtol=tol, atol=tol)
    wall = _min_cpu(lambda: bench_expert.solve_expert(r['solver'], addr, x0, t_eval, data,
                                                      rtol=tol, atol=tol), calls)
    return wall, int(nfev)


def main() -> None:
    rows = list(csv.DictReader(open(sys.argv[1])))
    rounds = int(sys.argv[2]) if len(sys.argv) > 2 else 3
    print('| scene | level | family: config | whole us | rhs calls | rhs ns per call | rhs us '
          '| outside the rhs us | of which: Python, call, outputs, stepper |')
    print('| --- | --- | --- | --- | --- | --- | --- | --- | --- |')
    for name in dict.fromkeys(r['scene'] for r in rows):
        srows = [r for r in rows if r['scene'] == name]
        pairs: dict = {}
        for lv in LEVELS:
            p, e = _best(srows, 'project', lv), _best(srows, 'baseline_expert', lv)
            if p and e:
                pairs.setdefault((p['label'] + p['tol'], e['label'] + e['tol']), (p, e, []))[2].append(lv)
        for p, e, lvs in pairs.values():
            meds, experts = [], []
            for _ in range(rounds):
                meds.append(profile(name, p['solver'], float(p['tol']), p['sampling'] or 'land',
                                    rounds=1, calls=CALLS, fidelity=p['fidelity'],
                                    breakpoints=p['breakpoints'] in ('True', '')))
                experts.append(_expert(name, e))
            med = {k: float(np.median([m[k] for m in meds])) for k in meds[0]}
            ns = med['rhs'] * 1e3 / med['nfev']
            level = ', '.join(f'{lv:.0e}' for lv in lvs)
            print(f'| {name} | {level} | project: {p["label"]} tol={float(p["tol"]):.0e} '
                  f'| {med["whole"]:.1f} | {med["nfev"]:.0f} | {ns:.0f} | {med["rhs"]:.1f} '
                  f'| {med["whole"] - med["rhs"]:.1f} | {med["python"]:.1f}, '
                  f'{med["call_overhead"]:.1f}, {med["outputs"]:.1f}, {med["integration_rest"]:.1f} |',
                  flush=True)
            wall = float(np.median([x[0] for x in experts])) * 1e6
            nfev = experts[0][1]
            print(f'| {name} | {level} | expert: {e["label"]} tol={float(e["tol"]):.0e} | {wall:.1f} '
                  f'| {nfev} | {ns:.0f} (same rhs) | {nfev * ns * 1e-3:.1f} '
                  f'| {wall - nfev * ns * 1e-3:.1f} | - |', flush=True)


def hand_written_cpu(model_name: str, batches: int = 40, calls: int = 20_000) -> tuple[float, float]:
    """(kernel ns, hand-written ns) per call as bench.hand_written_rhs_cost times them (one
    compiled loop over its 16 states), but CPU time of this thread, least of ``batches``
    alternating batches: on a loaded machine the least batch is the one with the fewest
    interruptions."""
    from cvj_ros import bench_handrhs as hw
    scene, params, timer = {
        'hooke_2dof': (bench.hooke_2dof_scene(), hw.hooke_2dof_params, hw.time_hooke_2dof_calls),
        'stiff': (bench.resolve_scene('stiff'), hw.stiff_params, hw.time_stiff_calls),
        'fwd_halfshaft': (bench.resolve_scene('fwd_halfshaft'), hw.fwd_halfshaft_params,
                          hw.time_fwd_halfshaft_calls)}[model_name]
    sim = Simulation(scene, fidelity=bench.forced_levels(scene, 'exact'))
    model = build_model(sim.driveline, engine=sim.engine, load=sim.load)
    ys = hw.timing_states(model.x0)
    p = params(scene)
    hw.time_kernel_calls(10, 0.0, ys, model.ip, model.fp)
    timer(10, 0.0, ys, p)
    kern, hand = np.inf, np.inf
    for _ in range(batches):
        kern = min(kern, _min_cpu(lambda: hw.time_kernel_calls(calls, 0.001, ys, model.ip, model.fp), 1))
        hand = min(hand, _min_cpu(lambda: timer(calls, 0.001, ys, p), 1))
    return kern / calls * 1e9, hand / calls * 1e9


def scene_rhs_cpu(name: str, batches: int = 40, calls: int = 20_000) -> float:
    """ns per call of the kernel rhs of scene ``name`` (exact fidelity) over the 16 timing
    states, CPU time, least of ``batches`` batches."""
    from cvj_ros import bench_handrhs as hw
    scene = bench.resolve_scene(name)
    sim = Simulation(scene, fidelity=bench.forced_levels(scene, 'exact'))
    model = build_model(sim.driveline, engine=sim.engine, load=sim.load)
    ys = hw.timing_states(model.x0)
    hw.time_kernel_calls(10, 0.0, ys, model.ip, model.fp)
    best = np.inf
    for _ in range(batches):
        best = min(best, _min_cpu(lambda: hw.time_kernel_calls(calls, 0.001, ys, model.ip, model.fp), 1))
    return best / calls * 1e9


def per_call_tables() -> None:
    print()
    print('| rhs | kernel ns per call | hand-written ns per call | ratio |')
    print('| --- | --- | --- | --- |')
    for name in ('kavz685_lever', 'fwd_halfshaft', 'cardan_truck', 'tripod_xiu2024', 'stiff', 'fwd_axle'):
        print(f'| {name} | {scene_rhs_cpu(name):.1f} | - | - |', flush=True)
    for model in bench.HAND_WRITTEN:
        k, h = hand_written_cpu(model)
        print(f'| {model} (hand-written pair) | {k:.1f} | {h:.1f} | {k / h:.2f}x |', flush=True)


if __name__ == '__main__':
    if sys.argv[1:] == ['--per-call']:
        per_call_tables()
        sys.exit(0)
    main()
