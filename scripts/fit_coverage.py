"""Coverage of `cvj-sim fit`'s 95 % confidence intervals on synthetic data (docs/fit.md).

The KAVZ-685 unit with a constant load (1 s), its drive-shaft torque at a known truth
(alpha 12 deg, load 130 N m) plus white noise of 2 N m per sample, one noise seed per fit;
prints how often each interval holds the truth, the median half widths and the scatter of the
estimates.

    PYTHONPATH=. python scripts/fit_coverage.py [N]
"""
from __future__ import annotations

import sys

import numpy as np

from cvj_ros.commands.sweep import load_scene_data
from cvj_ros.fit.data import orders_of_series
from cvj_ros.fit.problem import FitProblem, parse_fit_parameter
from cvj_ros.fit.solve import solve_fit
from cvj_ros.physics.scene import find_scene

TRUTH = {'driveline[coupling].params.alpha_deg': 12.0, 'load.torque': 130.0}
RANGES = {'driveline[coupling].params.alpha_deg': '5:25', 'load.torque': '50:200'}


def main() -> None:
    n = int(sys.argv[1]) if len(sys.argv) > 1 else 40
    d = load_scene_data(find_scene('kavz685_lever'))
    d['load'] = {'model': 'constant', 'torque': 107.5}
    d['duration'] = 1.0
    params = [parse_fit_parameter(d, f'{p}={RANGES[p]}') for p in TRUTH]
    truth = np.array(list(TRUTH.values()))
    tr = FitProblem(d, params, orders=4).trace(truth.tolist())
    hits, widths, values = np.zeros(len(truth)), [], []
    for seed in range(n):
        rng = np.random.default_rng(1000 + seed)
        torque = tr.effort[:, 0] + rng.normal(0.0, 2.0, tr.t.size)
        m = orders_of_series('synthetic', tr.t, tr.position[:, 0], torque, 4, 0.5, None)
        pr = FitProblem(d, params, orders=4, duration=1.0, start_time=m.start_time,
                        revolutions=m.revolutions)
        res = solve_fit(pr, m.vector())
        est = np.array([e.value for e in res.estimates])
        ci = np.array([e.ci for e in res.estimates])
        hits += np.abs(est - truth) <= ci
        widths.append(ci)
        values.append(est)
    for j, path in enumerate(TRUTH):
        sd = np.std(np.array(values)[:, j], ddof=1)
        print(f'{path}: truth {truth[j]:g}, inside {int(hits[j])}/{n}, median half width '
              f'{np.median(np.array(widths)[:, j]):.3g}, scatter of the estimates {sd:.3g} '
              f'(1.96 x = {1.96 * sd:.3g})')


if __name__ == '__main__':
    main()
