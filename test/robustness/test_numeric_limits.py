"""Numeric limits: states far outside any physical range must give inf/NaN that the
solvers turn into a SolverError, never a bare Python OverflowError (a traceback)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from cvj_ros.physics.driveline import Driveline
from cvj_ros.physics.scene import parse_scene


def scene():
    return parse_scene({
        'name': 'limits', 'duration': 0.1, 'engine': {'model': 'linear'},
        'load': {'model': 'constant', 'torque': 10.0}, 'initial': {'speed_rad_s': 30.0},
        'driveline': [{'type': 'inertia', 'name': 'a', 'J': 0.1},
                      {'type': 'spring', 'name': 's', 'stiffness': 1000.0, 'damping': 1.0},
                      {'type': 'joint', 'name': 'h', 'kind': 'hooke', 'params': {'beta_deg': 20.0}},
                      {'type': 'inertia', 'name': 'b', 'J': 0.2}]})


@pytest.mark.parametrize('speed', [1e200, -1e200, 1e300])
def test_energy_of_a_huge_speed_is_inf_not_an_exception(speed: float) -> None:
    dl = Driveline.from_scene(scene())
    x = dl.x0.copy()
    x[dl.n_dof] = speed                     # speed of the first section (rad/s)
    e = dl.energy(x)
    assert e['kinetic'] == math.inf
    assert math.isfinite(e['elastic'])
    assert np.isfinite(dl.energy(dl.x0)['kinetic'])   # control: the normal state is finite
