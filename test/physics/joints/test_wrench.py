"""Housing-frame reaction wrench: closed forms per joint, frame conventions."""
from __future__ import annotations

import math

import numpy as np
import pytest

from cvj_ros.physics.joints import make_joint
from cvj_ros.physics.joints.hooke import hooke_ratio
from cvj_ros.physics.joints.wrench import housing_wrench


@pytest.mark.parametrize('phi', [0.0, 0.4, 1.3, 2.9, 1e4 + 0.2])
def test_hooke_secondary_couple_and_output_torque(phi: float) -> None:
    beta, t1 = math.radians(30.0), 120.0
    f, m = housing_wrench(make_joint('hooke', beta=beta), phi, 50.0, t1)
    assert f == (0.0, 0.0, 0.0)
    # |C1| = T1 tan(b) |sin phi1| (bending on the input yoke, normal to the input axis)
    assert math.hypot(m[0], m[1]) == pytest.approx(t1 * math.tan(beta) * abs(math.sin(phi)), abs=1e-9)
    # power balance: T2 = T1 / ratio
    assert m[2] == pytest.approx(t1 / float(hooke_ratio(phi, beta)), rel=1e-12)


def test_tripod_axial_force_and_bearing_reactions() -> None:
    tp = make_joint('tripod', beta=math.radians(25.0), r=0.026, l=0.7)
    phi, omega, t_in = 0.3, 2000 * 2 * math.pi / 60, 80.0
    r = tp.reactions(phi, omega, t_in)
    f, m = housing_wrench(tp, phi, omega, t_in)
    assert f == (r['input_force_x'], r['input_force_y'], r['axial_force'])
    assert m == (r['input_moment_x'], r['input_moment_y'], r['torque_out'])
    # torque delivered to the output ~ input torque / spin ratio (power balance)
    assert m[2] == pytest.approx(t_in, rel=0.02)


@pytest.mark.parametrize('kind,params,expected', [
    ('gear', {'gear_ratio': 3.5}, 3.5 * 40.0),
    ('rzeppa', {'delta': math.radians(30.0)}, 40.0),           # homokinetic: T2 = T1
    ('lever_hinge', {}, 40.0),                                   # rigid lever hinge: synchronous
])
def test_torque_only_joints(kind: str, params: dict, expected: float) -> None:
    f, m = housing_wrench(make_joint(kind, **params), 0.7, 10.0, 40.0)
    assert f == (0.0, 0.0, 0.0)
    assert m[:2] == (0.0, 0.0)
    assert m[2] == pytest.approx(expected, rel=1e-9)


def test_ideal_cv_passes_torque_and_model_without_reactions_has_none() -> None:
    assert housing_wrench(make_joint('ideal_cv', fidelity='ideal'), 0.1, 1.0, 7.0) == \
        ((0.0, 0.0, 0.0), (0.0, 0.0, 7.0))

    class NoReactions:
        kind = 'custom'
    assert housing_wrench(NoReactions(), 0.1, 1.0, 1.0) is None


def test_rzeppa_cage_error_torque_follows_eq_20() -> None:
    rz = make_joint('rzeppa', delta=math.radians(40.0), alpha=math.radians(17.0))
    phi = np.linspace(0.1, 3.0, 7)
    for p in phi:
        _f, m = housing_wrench(rz, float(p), 10.0, 50.0)
        ratio = float(rz.evaluate([p]).ratio[0])
        assert m[2] == pytest.approx(50.0 / ratio, rel=1e-9)
