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


def test_shaft_metrics_on_repeated_stamps_no_warning_nan_acceleration() -> None:
    """A bag that recorded a second run on the same domain repeats stamps; the run report's
    metrics must not spill numpy warnings onto stderr (the one-line error contract)."""
    import warnings

    from cvj_ros.physics.metrics import shaft_metrics
    t = np.array([0.0, 1e-3, 1e-3, 2e-3, 3e-3, 3e-3, 4e-3])
    w = np.linspace(10.0, 11.0, t.size)[:, None]
    with warnings.catch_warnings():
        warnings.simplefilter('error')
        m = shaft_metrics(t, ['a'], w, w)['a']
    assert math.isnan(m['acceleration_amplitude'])
    assert m['mean_speed'] == pytest.approx(float(np.mean(w[t >= t[-1] / 2])))
    # control: strictly increasing stamps give the finite derivative 1 rad/s / 6 ms
    t_ok = np.linspace(0.0, 6e-3, 7)
    m_ok = shaft_metrics(t_ok, ['a'], w, w)['a']
    assert m_ok['acceleration_amplitude'] == pytest.approx(0.0, abs=1e-6)
