"""Identifiability: parameters fitted back from synthetic data made by the model with noise."""
from __future__ import annotations

import numpy as np
import pytest

from cvj_ros.commands.sweep import load_scene_data
from cvj_ros.fit.data import read_measured
from cvj_ros.fit.problem import FitProblem, parse_fit_parameter
from cvj_ros.fit.solve import solve_fit
from cvj_ros.physics.scene import find_scene

TRUTH = {'driveline[coupling].params.alpha_deg': 12.0, 'load.torque': 130.0}
RANGES = {'driveline[coupling].params.alpha_deg': '5:25', 'load.torque': '50:200'}


@pytest.fixture(scope='module')
def base() -> dict:
    # the KAVZ-685 unit with a constant load, 1 s: seconds per fit
    d = load_scene_data(find_scene('kavz685_lever'))
    d['load'] = {'model': 'constant', 'torque': 107.5}
    d['duration'] = 1.0
    return d


def _synthetic_csv(base, tmp_path, noise_nm: float, seed: int):
    """The model's drive-shaft torque at TRUTH plus seeded white noise, as a CSV time series."""
    params = [parse_fit_parameter(base, f'{p}={RANGES[p]}') for p in TRUTH]
    tr = FitProblem(base, params, orders=4).trace(list(TRUTH.values()))
    rng = np.random.default_rng(seed)
    torque = tr.effort[:, 0] + rng.normal(0.0, noise_nm, tr.t.size)
    path = tmp_path / 'synthetic.csv'
    np.savetxt(path, np.column_stack([tr.t, tr.position[:, 0], torque]), delimiter=',',
               header='t_s,angle_rad,torque_Nm', comments='', fmt='%.17g')
    return path


def test_recovers_truth_inside_confidence_intervals(base, tmp_path):
    path = _synthetic_csv(base, tmp_path, noise_nm=2.0, seed=7)
    measured = read_measured(str(path), orders=4, skip=0.5)
    params = [parse_fit_parameter(base, f'{p}={RANGES[p]}') for p in TRUTH]
    problem = FitProblem(base, params, orders=4, duration=1.0, start_time=measured.start_time,
                         revolutions=measured.revolutions)
    result = solve_fit(problem, measured.vector())
    for est in result.estimates:
        truth = TRUTH[est.path]
        assert est.identifiable and est.value is not None and est.ci is not None
        assert abs(est.value - truth) <= est.ci, (est.path, est.value, est.ci)
        # an informative interval: narrower than the range searched
        assert est.ci < 0.5 * (est.hi - est.lo), (est.path, est.ci)
    assert result.dof == 3


def test_parameter_without_effect_is_not_identifiable(base, tmp_path):
    # the coupling's angle limit only validates alpha: it changes nothing the data see
    path = _synthetic_csv(base, tmp_path, noise_nm=0.5, seed=3)
    measured = read_measured(str(path), orders=3, skip=0.5)
    params = [parse_fit_parameter(base, 'load.torque=50:200'),
              parse_fit_parameter(base, 'driveline[coupling].limits.max_angle_deg=26:40')]
    problem = FitProblem(base, params, orders=3, duration=1.0, start_time=measured.start_time,
                         revolutions=measured.revolutions)
    result = solve_fit(problem, measured.vector())
    torque, limit = result.estimates
    assert torque.identifiable and abs(torque.value - 130.0) <= torque.ci
    assert not limit.identifiable and limit.value is None and limit.ci is None
    assert result.singular_values[-1] == 0.0


def test_same_inputs_same_result(base):
    params = [parse_fit_parameter(base, 'load.torque=50:200')]
    target = np.array([120.0, 0.0, 2.0, 0.0])
    a = solve_fit(FitProblem(base, params, orders=3, duration=1.0), target)
    b = solve_fit(FitProblem(base, params, orders=3, duration=1.0), target)
    assert a.values.tobytes() == b.values.tobytes()
    assert a.fitted.tobytes() == b.fitted.tobytes()


def test_as_many_parameters_as_data_gives_no_interval_and_bounds_are_flagged(base):
    params = [parse_fit_parameter(base, 'load.torque=50:200')]
    pr = FitProblem(base, params, orders=2, duration=1.0)
    exact = solve_fit(pr, np.array([120.0, 0.0, 1.0]), use=[0])
    est = exact.estimates[0]
    assert exact.dof == 0 and exact.sigma is None and est.ci is None
    # the model's mean drive-shaft torque matches exactly; the load that gives it is within
    # 0.05 N m of it (the analysed revolutions are not perfectly steady after 1 s)
    assert exact.fitted[0] == pytest.approx(120.0, abs=1e-6)
    assert est.value == pytest.approx(120.0, abs=0.05) and not est.at_bound
    # a mean torque above the range: the optimum sits on HI and says so
    high = solve_fit(pr, np.array([260.0, 0.0, 1.0]), use=[0, 2])
    assert high.estimates[0].at_bound and high.estimates[0].value == pytest.approx(200.0, abs=0.2)


def test_start_points_are_fixed():
    from cvj_ros.fit.solve import start_points
    pts = start_points(2, 4)
    np.testing.assert_array_equal(pts[0], [0.5, 0.5])
    # unscrambled Halton, bases 2 and 3, from its second point
    np.testing.assert_allclose(pts[1:], [[0.5, 1 / 3], [0.25, 2 / 3], [0.75, 1 / 9]])
    with pytest.raises(ValueError, match='starts'):
        start_points(2, 0)


def test_more_starts_never_end_higher(base):
    # the fit kept is the best of its starts, so never worse than the middle start alone
    params = [parse_fit_parameter(base, 'load.torque=50:200')]
    target = np.array([120.0, 0.0, 1.0])
    one = solve_fit(FitProblem(base, params, orders=2, duration=1.0), target)
    many = solve_fit(FitProblem(base, params, orders=2, duration=1.0), target, starts=3)
    assert np.sum(many.residuals ** 2) <= np.sum(one.residuals ** 2) + 1e-12
