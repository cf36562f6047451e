"""Project against the expert baseline in alternating rounds (docs/benchmark.md, "Expert baseline").

Reads a `cvj-sim bench` CSV, takes per scene and error level 1e-3..1e-8 the cheapest project
configuration and the cheapest baseline_expert configuration (numbalsoda on the compiled rhs)
that reach it, then times each such pair again in ROUNDS alternating rounds (project, expert,
project, expert ...; each timing the min over a few runs, as the bench times) and prints per
pair the median cost of each and the median, min and max of the per-round ratios expert /
project. Also the compiled rhs's ns per call per scene and the kernel rhs of the 2-DOF Hooke
model and of the stiff scene against their hand-written versions, in the same alternating rounds. The machine may be shared:
a round's pair shares its moment, and the spread says how much the moments differ.

    PYTHONPATH=. python scripts/expert_rounds.py BENCH_CSV [ROUNDS] > rounds.md
"""
from __future__ import annotations

import csv
import sys

import numpy as np

from cvj_ros import bench

LEVELS = (1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8)


def _best(rows: list[dict], family: str, level: float) -> dict | None:
    cand = [r for r in rows if r['family'] == family and r['ok'] == 'True'
            and r['err_speed_rel'] and float(r['err_speed_rel']) <= level]
    return min(cand, key=lambda r: float(r['wall_per_sim_s'])) if cand else None


def _knob(r: dict) -> str:
    """'tol=1e-06', or 'h=0.001' for a fixed-step row (rk4: no tolerance)."""
    return f'tol={float(r["tol"]):.0e}' if r['tol'] else f'h={float(r["h"]):g}'


def _time(prob: bench.SceneProblem, r: dict, cfg: bench.BenchConfig) -> float:
    tol = float(r['tol']) if r['tol'] else None
    h = float(r['h']) if r.get('h') else None
    if r['family'] == 'project':
        out = bench.run_project(prob, solver=r['solver'], tol=tol, h=h, fidelity=r['fidelity'],
                                cfg=cfg, breakpoints=r['breakpoints'] in ('True', ''),
                                sampling=r['sampling'] or 'land', energy=r.get('energy') != 'off')
    else:
        out = bench.run_expert(prob, method=r['solver'], tol=tol, cfg=cfg,
                               restart=r['breakpoints'] == 'True')
    if not out.get('ok'):
        raise RuntimeError(f'{r["label"]}: {out.get("note")}')
    return float(out['wall_per_sim_s'])


def main() -> None:
    if len(sys.argv) < 2 or sys.argv[1].startswith('-'):
        sys.exit('usage: PYTHONPATH=. python scripts/expert_rounds.py BENCH_CSV [ROUNDS]')
    try:
        with open(sys.argv[1]) as fh:
            rows = list(csv.DictReader(fh))
    except OSError as exc:
        sys.exit(f'{sys.argv[1]}: cannot read the bench CSV ({exc.strerror})')
    if not rows or 'family' not in rows[0]:
        sys.exit(f'{sys.argv[1]}: not a `cvj-sim bench` CSV (no family column)')
    try:
        rounds = int(sys.argv[2]) if len(sys.argv) > 2 else 5
    except ValueError:
        sys.exit(f'ROUNDS: an integer, got {sys.argv[2]!r}')
    cfg = bench.BenchConfig(repeats=3, passes=1, min_timed_s=0.02, max_repeats=60, horizon=1.0)
    scenes = list(dict.fromkeys(r['scene'] for r in rows))
    print('| scene | level | project config | expert config | project s/s (median) | expert s/s (median) '
          '| expert / project: median (min-max) |')
    print('| --- | --- | --- | --- | --- | --- | --- |')
    for name in scenes:
        srows = [r for r in rows if r['scene'] == name]
        prob = bench.prepare(bench.resolve_scene(name), cfg, reference_tol=1e-12)
        pairs = {}
        for lv in LEVELS:
            p, e = _best(srows, 'project', lv), _best(srows, 'baseline_expert', lv)
            if p and e:
                pairs.setdefault((p['label'] + _knob(p), e['label'] + _knob(e)), (p, e, []))[2].append(lv)
        for p, e, lvs in pairs.values():
            tp, te = [], []
            for _ in range(rounds):
                tp.append(_time(prob, p, cfg))
                te.append(_time(prob, e, cfg))
            ratio = np.array(te) / np.array(tp)
            print(f'| {name} | {", ".join(f"{lv:.0e}" for lv in lvs)} | {p["label"]} {_knob(p)} '
                  f'| {e["label"]} {_knob(e)} | {np.median(tp):.3g} | {np.median(te):.3g} '
                  f'| {np.median(ratio):.2f}x ({ratio.min():.2f}-{ratio.max():.2f}) |', flush=True)
    print()
    print('| scene | compiled rhs ns per call: median (min-max) |')
    print('| --- | --- |')
    for name in scenes:
        ns = [bench.rhs_cost(bench.resolve_scene(name), calls=100_000)['compiled_ns'] for _ in range(rounds)]
        print(f'| {name} | {np.median(ns):.1f} ({min(ns):.1f}-{max(ns):.1f}) |', flush=True)
    print()
    for model in bench.HAND_WRITTEN:
        h = bench.hand_written_rhs_cost(model, rounds=max(rounds, 5))
        print(f'{model}: kernel rhs {h["kernel_ns"]:.1f} ns ({h["kernel_ns_min"]:.1f}-'
              f'{h["kernel_ns_max"]:.1f}), hand-written {h["hand_ns"]:.1f} ns ({h["hand_ns_min"]:.1f}-'
              f'{h["hand_ns_max"]:.1f}), ratio {h["ratio"]:.2f}x over {h["rounds"]} alternating rounds')


if __name__ == '__main__':
    main()
