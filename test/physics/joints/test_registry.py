"""Contract checks for every joint model of part A (and any registered kind that builds
with default parameters): ratio = d(phi_out)/d(phi_in) and ratio_slope = d(ratio)/d(phi_in)
against Richardson-extrapolated central differences, including angles beyond 1e4 rad;
scalar() == evaluate(); continuity over 1e5 revolutions; registry metadata and errors.

Roundoff of the difference scheme: D(h) = (f(x+h) - f(x-h)) / 2h, R = (4 D(h/2) - D(h)) / 3.
At |x| = 2e4 rad, f carries an absolute rounding error of about eps |f| = 2.2e-16 * 2e4
= 4.4e-12, so R carries about (4/3 * 2/h + 1/3 * 1/h) * 4.4e-12 = 3/h * 4.4e-12 = 1.3e-8
for h = 1e-3, below 1e-7; truncation is O(h^4 f^(5)) ~ 1e-12 for O(1) derivatives.
test_difference_scheme_error_at_1e4_rad measures it on sin.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from cvj_ros.errors import GeometryError
from cvj_ros.physics.joints import JOINTS, JointModel, make_joint

D = math.radians

# (id, kind, fidelity, params, difference step h in rad)
CASES = [
    ('ideal_cv', 'ideal_cv', 'ideal', {}, 1e-3),
    ('gear', 'gear', 'exact', {'gear_ratio': 3.9}, 1e-3),
    ('gear_reverse', 'gear', 'exact', {'gear_ratio': -2.5}, 1e-3),
    ('hooke30', 'hooke', 'exact', {'beta': D(30)}, 1e-3),
    ('hooke60', 'hooke', 'exact', {'beta': D(60)}, 1e-3),
    ('hooke80', 'hooke', 'exact', {'beta': D(80)}, 1e-3),
    ('hooke89', 'hooke', 'exact', {'beta': D(89)}, 3e-4),
    ('hooke_ideal', 'hooke', 'ideal', {'beta': D(30)}, 1e-3),
    ('dc_inphase', 'double_cardan', 'exact', {'beta1': D(25), 'beta2': D(25)}, 1e-3),
    ('dc_unequal_W', 'double_cardan', 'exact', {'beta1': D(20), 'beta2': D(35), 'layout': 'W'}, 1e-3),
    ('dc_phase', 'double_cardan', 'exact', {'beta1': D(30), 'beta2': D(30), 'phase': D(40),
                                             'bend_plane': D(15)}, 1e-3),
    ('rzeppa47', 'rzeppa', 'exact', {'delta': D(47)}, 1e-3),
    ('rzeppa_cage_error', 'rzeppa', 'exact', {'delta': D(40), 'alpha': D(12)}, 1e-3),
    ('chain', 'chain', 'exact', {'joints': [{'kind': 'hooke', 'beta': D(15)},
                                            {'kind': 'rzeppa', 'delta': D(40), 'alpha': D(25)},
                                            {'kind': 'gear', 'gear_ratio': 3.7}]}, 1e-3),
]
IDS = [c[0] for c in CASES]

PHI = np.concatenate([np.linspace(-3 * np.pi, 3 * np.pi, 97),
                      1.0e4 + np.linspace(0.0, 2 * np.pi, 25),
                      -2.0e4 + np.linspace(0.0, 2 * np.pi, 25)])


def richardson(f, x: np.ndarray, h: float) -> np.ndarray:
    def central(hh: float) -> np.ndarray:
        return (f(x + hh) - f(x - hh)) / (2.0 * hh)
    return (4.0 * central(0.5 * h) - central(h)) / 3.0


def build(case) -> JointModel:
    _, kind, fidelity, params, _ = case
    return make_joint(kind, fidelity=fidelity, **params)


def test_difference_scheme_error_at_1e4_rad() -> None:
    x = 1.0e4 + np.linspace(0.0, 2 * np.pi, 101)
    err = np.abs(richardson(lambda t: t + np.sin(t), x, 1e-3) - (1.0 + np.cos(x))).max()
    assert err < 2e-8          # measured ~3e-9; the bound in the module docstring is 1.3e-8
    x2 = -2.0e4 + np.linspace(0.0, 2 * np.pi, 101)
    assert np.abs(richardson(np.sin, x2, 1e-3) - np.cos(x2)).max() < 2e-8


@pytest.mark.parametrize('case', CASES, ids=IDS)
def test_ratio_is_derivative_of_position(case) -> None:
    joint, h = build(case), case[4]
    ev = joint.evaluate(PHI)
    num = richardson(lambda x: joint.evaluate(x).phi_out, PHI, h)
    scale = max(1.0, float(np.abs(ev.ratio).max()))
    assert np.abs(num - ev.ratio).max() < 1e-7 * scale


@pytest.mark.parametrize('case', CASES, ids=IDS)
def test_slope_is_derivative_of_ratio(case) -> None:
    joint, h = build(case), case[4]
    ev = joint.evaluate(PHI)
    num = richardson(lambda x: joint.evaluate(x).ratio, PHI, h)
    scale = max(1.0, float(np.abs(ev.ratio_slope).max()))
    assert np.abs(num - ev.ratio_slope).max() < 1e-7 * scale


@pytest.mark.parametrize('case', CASES, ids=IDS)
def test_scalar_agrees_with_evaluate(case) -> None:
    joint = build(case)
    ev = joint.evaluate(PHI)
    for k in range(0, PHI.size, 7):
        out, ratio, slope = joint.scalar(float(PHI[k]))
        assert isinstance(out, float) and isinstance(ratio, float) and isinstance(slope, float)
        assert out == pytest.approx(ev.phi_out[k], abs=1e-12 * max(1.0, abs(out)))
        assert ratio == pytest.approx(ev.ratio[k], rel=1e-13, abs=1e-13)
        assert slope == pytest.approx(ev.ratio_slope[k], rel=1e-12, abs=1e-12)


@pytest.mark.parametrize('case', CASES, ids=IDS)
def test_continuous_over_1e5_revolutions(case) -> None:
    joint = build(case)
    phi = np.linspace(0.0, 2 * np.pi * 1e5, 2_000_001)    # step 0.314 rad
    ev = joint.evaluate(phi)
    step = phi[1] - phi[0]
    jumps = np.abs(np.diff(ev.phi_out))
    assert jumps.max() <= np.abs(ev.ratio).max() * step * (1 + 1e-9)
    # after whole revolutions the periodic joints are back on phi_in * mean ratio
    mean_ratio = (ev.phi_out[-1] - ev.phi_out[0]) / (phi[-1] - phi[0])
    assert np.isfinite(ev.phi_out).all()
    if case[1] != 'gear' and case[0] != 'chain':
        assert mean_ratio == pytest.approx(1.0, abs=1e-12)


@pytest.mark.parametrize('case', CASES, ids=IDS)
def test_model_contract(case) -> None:
    joint = build(case)
    assert isinstance(joint, JointModel)
    assert joint.kind == case[1] and joint.fidelity == case[2]
    ev = joint.evaluate(np.zeros((2, 3)))
    assert ev.phi_out.shape == (2, 3) and ev.ratio.shape == (2, 3)
    if ev.phi_mid is not None:
        assert ev.phi_mid.shape == (2, 3) and isinstance(getattr(joint, 'mid_name', None), str)
    with pytest.raises(GeometryError, match=r'^phi_in'):
        joint.evaluate([0.0, float('nan')])
    t = joint.reactions(0.3, 10.0, 50.0)
    assert t['torque_out'] * joint.scalar(0.3)[1] == pytest.approx(50.0, rel=1e-12)  # power balance


def test_registry_entries_describe_themselves() -> None:
    for kind in ('ideal_cv', 'gear', 'hooke', 'double_cardan', 'rzeppa', 'chain'):
        spec = JOINTS[kind]
        assert spec.kind == kind and spec.source and spec.fidelities
        for name, desc in spec.params.items():
            assert name and desc
    assert 'Dziopa' in JOINTS['rzeppa'].source and 'Bugaru & Vasile 2021' in JOINTS['hooke'].source


@pytest.mark.parametrize('kind,fidelity', [('hooke', 'closed'), ('rzeppa', 'fast'), ('gear', 'ideal'),
                                           ('double_cardan', 'closed')])
def test_unknown_fidelity_names_fidelity(kind: str, fidelity: str) -> None:
    with pytest.raises(GeometryError, match=r'^fidelity'):
        make_joint(kind, fidelity=fidelity)


def test_unknown_kind_and_parameter() -> None:
    with pytest.raises(GeometryError, match=r'^kind'):
        make_joint('cardan_shaft')
    with pytest.raises(GeometryError, match=r'^betta'):
        make_joint('hooke', betta=0.1)


def test_chain_stage_errors_name_the_stage() -> None:
    with pytest.raises(GeometryError, match=r'^joints\[1\]\.delta'):
        make_joint('chain', joints=[{'kind': 'hooke', 'beta': 0.1}, {'kind': 'rzeppa', 'delta': -0.1}])
    with pytest.raises(GeometryError, match=r'^joints'):
        make_joint('chain', joints=[])
