"""Fidelity choice: bounds against the exact model, cheap picks stay inside the target."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from cvj_ros.physics.fidelity import choose_fidelity, joint_error_bounds, joint_max_order
from cvj_ros.physics.scene import parse_scene
from cvj_ros.physics.simulate import Simulation


class Const:
    def __init__(self, value: float) -> None:
        self.value = value

    def torque(self, t: float, omega: float, phi: float = 0.0) -> float:
        return self.value

    def slope(self, t: float, omega: float, phi: float = 0.0) -> float:
        return 0.0


def tripod_scene(target: float | None, *, beta_deg: float = 15.0) -> object:
    d = {'name': 'f', 'duration': 0.5, 'engine': {'model': 'linear'},
         'load': {'model': 'constant', 'torque': 0.0}, 'initial': {'speed_rad_s': 100.0},
         'driveline': [{'type': 'inertia', 'name': 'big', 'J': 1e6},
                       {'type': 'joint', 'name': 'tj', 'kind': 'tripod',
                        'params': {'beta_deg': beta_deg, 'r_m': 0.0264, 'l_m': 0.24}},
                       {'type': 'inertia', 'name': 'out', 'J': 0.01}]}
    if target is not None:
        d['accuracy_target'] = target
    return parse_scene(d)


def test_hooke_bound_is_closed_form() -> None:
    beta = math.radians(20.0)
    b = joint_error_bounds('hooke', {'beta': beta})
    # ratio swings cos b .. 1/cos b; ideal has ratio 1: max |1 - r| = 1/cos b - 1
    assert b['ideal']['ratio_error'] == pytest.approx(1 / math.cos(beta) - 1, rel=1e-6)
    assert b['exact']['speed_error'] == 0.0
    assert joint_max_order('hooke', {'beta': beta}) >= 2
    assert joint_max_order('ideal_cv', {}) == 0


@pytest.mark.parametrize('target,expected', [(0.01, 'ideal'), (1e-4, 'closed'), (1e-9, 'exact'),
                                             (None, 'exact')])
def test_tripod_choice_by_target(target: float | None, expected: str) -> None:
    rep = choose_fidelity(tripod_scene(target))
    assert rep.levels['tj'] == expected


@pytest.mark.parametrize('target', [0.01, 1e-4])
def test_cheap_choice_measured_error_inside_target(target: float) -> None:
    """Run the chosen (cheap) model and the exact one at constant input speed: the
    measured relative output-speed error stays inside the target."""
    sc = tripod_scene(target)
    cheap = Simulation(sc, method='dop853', rtol=1e-10, atol=1e-12, engine=Const(0.0), load=Const(0.0))
    assert cheap.fidelity_report.levels['tj'] != 'exact'
    exact = Simulation(sc, method='dop853', rtol=1e-10, atol=1e-12, engine=Const(0.0), load=Const(0.0),
                       fidelity={'tj': 'exact'})
    a = cheap.run(0.2, sample_dt=2e-4)
    b = exact.run(0.2, sample_dt=2e-4)
    i = a.column('out')
    err = np.max(np.abs(a.velocity[:, i] - b.velocity[:, i]) / np.abs(b.velocity[:, i]))
    assert err <= target
    assert err > 0.05 * target       # the bound is not vacuous: the cheap model does differ


def test_spring_rigid_when_far_above_band() -> None:
    base = {'name': 's', 'duration': 0.5, 'engine': {'model': 'linear', 'm1': 50.0, 'k1': 0.4},
            'load': {'model': 'constant', 'torque': 10.0}, 'initial': {'speed_rad_s': 100.0},
            'driveline': [{'type': 'inertia', 'name': 'a', 'J': 0.01},
                          {'type': 'spring', 'name': 'k', 'stiffness': 1e6, 'damping': 10.0},
                          {'type': 'inertia', 'name': 'b', 'J': 0.01}]}
    rep = choose_fidelity(parse_scene({**base, 'accuracy_target': 0.01}))
    ch = {c.name: c for c in rep.choices}['k']
    assert ch.chosen == 'rigid'
    assert ch.candidates['rigid']['omega_n'] == pytest.approx(math.sqrt(1e6 * 200.0))
    assert ch.candidates['rigid']['speed_error'] <= 0.01
    soft = dict(base, driveline=[base['driveline'][0], {**base['driveline'][1], 'stiffness': 50.0},
                                 base['driveline'][2]], accuracy_target=0.01)
    assert choose_fidelity(parse_scene(soft)).levels['k'] == 'elastic'
    # without a target the spring stays as written
    assert choose_fidelity(parse_scene(base)).levels['k'] == 'elastic'
    # rigid and elastic runs agree on the speeds (quasi-static)
    sc = parse_scene({**base, 'accuracy_target': 0.01})
    r = Simulation(sc, method='dopri5', rtol=1e-8).run(0.3, sample_dt=1e-3)
    e = Simulation(sc, method='rosenbrock', rtol=1e-8, fidelity={'k': 'elastic'}).run(0.3, sample_dt=1e-3)
    assert np.max(np.abs(r.velocity[:, -1] - e.velocity[:, -1]) / e.velocity[:, -1]) < 0.01


def test_report_printable_and_serialisable() -> None:
    rep = choose_fidelity(tripod_scene(0.01))
    text = str(rep)
    assert 'tj' in text and 'ideal' in text
    d = json.loads(rep.to_json())
    assert d['choices'][0]['chosen'] == 'ideal'
    assert d['accuracy_target'] == 0.01
