"""A vehicle scene against the expert baseline, its outputs from Python and compiled, in
alternating rounds (docs/benchmark.md, fwd_axle: "The samples' outputs compiled").

Takes ``scripts/expert_rounds.py``'s pairs (per error level 1e-3..1e-8 the cheapest project
and the cheapest baseline_expert configuration of a `cvj-sim bench` CSV that reach it) for
one scene and times in each round the project with its outputs from Python per sample
(``Simulation._run_tree`` switched off: ``Simulation._run_python``), the project as it
runs, and numbalsoda, each the min over a few runs as the bench times. Prints per pair the
median costs and the median, min and max of numbalsoda / project both ways.

    PYTHONPATH=.:scripts python scripts/tree_rounds.py BENCH_CSV [ROUNDS] [SCENE]
"""
from __future__ import annotations

import csv
import sys

import numpy as np

import expert_rounds as ER   # scripts/ is on the path when run as a script
from cvj_ros import bench
from cvj_ros.physics import simulate


def _python_outputs(self, dur, dt, breakpoints):   # noqa: ANN001, ANN202 - Simulation._run_tree's
    return None


def main() -> None:
    rows = list(csv.DictReader(open(sys.argv[1])))
    rounds = int(sys.argv[2]) if len(sys.argv) > 2 else 5
    name = sys.argv[3] if len(sys.argv) > 3 else 'fwd_axle'
    rows = [r for r in rows if r['scene'] == name]
    cfg = bench.BenchConfig(repeats=3, passes=1, min_timed_s=0.02, max_repeats=60, horizon=1.0)
    compiled = simulate.Simulation._run_tree
    prob = bench.prepare(bench.resolve_scene(name), cfg, reference_tol=1e-12)
    pairs: dict = {}
    for lv in ER.LEVELS:
        p, e = ER._best(rows, 'project', lv), ER._best(rows, 'baseline_expert', lv)
        if p and e:
            pairs.setdefault((p['label'] + p['tol'], e['label'] + e['tol']), (p, e, []))[2].append(lv)
    print('| levels | project config | expert config | Python outputs s/s | compiled s/s | expert s/s '
          '| expert / Python outputs | expert / compiled |')
    print('| --- | --- | --- | --- | --- | --- | --- | --- |')
    for p, e, lvs in pairs.values():
        tb, ta, te = [], [], []
        for _ in range(rounds):
            simulate.Simulation._run_tree = _python_outputs
            try:
                tb.append(ER._time(prob, p, cfg))
            finally:
                simulate.Simulation._run_tree = compiled
            ta.append(ER._time(prob, p, cfg))
            te.append(ER._time(prob, e, cfg))
        rb, ra = np.array(te) / np.array(tb), np.array(te) / np.array(ta)
        print(f'| {", ".join(f"{lv:.0e}" for lv in lvs)} | {p["label"]} tol={float(p["tol"]):.0e} '
              f'| {e["label"]} tol={float(e["tol"]):.0e} | {np.median(tb):.3g} | {np.median(ta):.3g} '
              f'| {np.median(te):.3g} | {np.median(rb):.2f}x ({rb.min():.2f}-{rb.max():.2f}) '
              f'| {np.median(ra):.2f}x ({ra.min():.2f}-{ra.max():.2f}) |', flush=True)


if __name__ == '__main__':
    main()
