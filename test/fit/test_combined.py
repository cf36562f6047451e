"""Several operating conditions fitted at once."""
from __future__ import annotations


import numpy as np
import pytest

from cvj_ros.commands.sweep import load_scene_data
from cvj_ros.fit.combined import CombinedProblem
from cvj_ros.fit.problem import FitProblem, parse_fit_parameter
from cvj_ros.fit.solve import solve_fit
from cvj_ros.physics.scene import find_scene


def _problem(stiffness: float, path: str = 'load.torque=50:200') -> FitProblem:
    d = load_scene_data(find_scene('kavz685_lever'))
    d['load'] = {'model': 'constant', 'torque': 107.5}
    d['duration'] = 1.0
    d['driveline'][1]['stiffness'] = stiffness
    return FitProblem(d, [parse_fit_parameter(d, path)], orders=2)


def test_stacks_predictions_and_fits_one_vector():
    a, b = _problem(450.0), _problem(1200.0)
    comb = CombinedProblem([a, b])
    pred = comb.predict([130.0])
    np.testing.assert_array_equal(pred, np.concatenate([a.predict([130.0]), b.predict([130.0])]))
    # synthetic truth 130 N m seen through both stiffnesses, mean and order 2 only
    result = solve_fit(comb, pred, use=[0, 2, 3, 5])
    assert result.estimates[0].value == pytest.approx(130.0, abs=1e-3)


def test_parameters_must_match():
    with pytest.raises(ValueError, match='same parameters'):
        CombinedProblem([_problem(450.0), _problem(450.0, 'driveline[bushings].damping=1:10')])
