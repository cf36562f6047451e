"""Double cardan against the product of two Hooke laws and a rotation-matrix
construction of the whole shaft in Z and W layouts, with phase and bend-plane offsets."""
from __future__ import annotations

import math

import numpy as np
import pytest

from cvj_ros.errors import GeometryError
from cvj_ros.physics.joints import make_joint

EX, EY, EZ = np.eye(3)
D = math.radians


def rot_x(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def rot_y(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def wrap_pi(x):
    return (np.asarray(x) + np.pi / 2) % np.pi - np.pi / 2


def construct(phi1, b1, b2, psi, layout, gamma):
    """Solve both crosses with rotation matrices; returns (phi_out, phi_mid) mod pi."""
    p1 = rot_y(phi1) @ EZ
    rm = rot_x(b1)
    q = np.cross(rm @ EY, p1)
    w = rm.T @ q                                        # ∝ R_y(phi_mid) e_x
    phim = math.atan2(-w[2], w[0])
    drive2 = rm @ rot_y(phim + psi) @ EX                # intermediate yoke at joint 2
    sign = -1.0 if layout == 'Z' else 1.0
    ro = rm @ rot_y(gamma) @ rot_x(sign * b2) @ rot_y(-gamma)
    q2 = np.cross(ro @ EY, drive2)
    w2 = ro.T @ q2                                      # ∝ R_y(phi_out + psi) e_z
    return math.atan2(w2[0], w2[2]) - psi, phim, ro @ EY


CASES = [(20, 20, 0, 'Z', 0), (20, 20, 0, 'W', 0), (15, 35, 0, 'Z', 0), (30, 10, 25, 'W', 0),
         (30, 30, 0, 'Z', 40), (25, 25, 40, 'W', 40), (60, 45, -70, 'Z', 110)]


@pytest.mark.parametrize('b1,b2,psi,layout,gamma', CASES)
def test_matches_construction(b1, b2, psi, layout, gamma) -> None:
    joint = make_joint('double_cardan', beta1=D(b1), beta2=D(b2), phase=D(psi), layout=layout,
                       bend_plane=D(gamma))
    phi = np.concatenate([np.linspace(-7, 7, 43), [1e4 + 0.2]])
    ev = joint.evaluate(phi)
    for k, p in enumerate(phi):
        ref_out, ref_mid, axis = construct(float(p), D(b1), D(b2), D(psi), layout, D(gamma))
        assert abs(wrap_pi(ev.phi_out[k] - ref_out)) < 1e-11
        assert abs(wrap_pi(ev.phi_mid[k] - ref_mid)) < 1e-11
    assert joint.output_axis_angle() == pytest.approx(math.acos(np.clip(axis @ EY, -1, 1)), abs=1e-12)


@pytest.mark.parametrize('beta_deg', [5.0, 30.0, 60.0, 85.0])
@pytest.mark.parametrize('layout', ['Z', 'W'])
def test_homokinetic_in_phase_equal_angles(beta_deg: float, layout: str) -> None:
    joint = make_joint('double_cardan', beta1=D(beta_deg), beta2=D(beta_deg), layout=layout)
    phi = np.concatenate([np.linspace(-20, 20, 401), 1e4 + np.linspace(0, 7, 50)])
    ev = joint.evaluate(phi)
    assert np.abs(ev.phi_out - phi).max() < 1e-12 * np.abs(phi).max()
    assert np.abs(ev.ratio - 1.0).max() < 1e-12 / math.cos(D(beta_deg)) ** 2
    assert joint.nonuniformity() < 1e-12
    # ... while the intermediate shaft is not uniform: the single-Hooke law
    assert np.abs(ev.phi_mid - make_joint('hooke', beta=D(beta_deg)).evaluate(phi).phi_out).max() < 1e-12


def test_unequal_angles_is_product_of_hooke_laws() -> None:
    b1, b2 = D(15.0), D(35.0)
    joint = make_joint('double_cardan', beta1=b1, beta2=b2)
    phi = np.linspace(0.05, 1.5, 30)       # first quadrant, tan is single valued
    ev = joint.evaluate(phi)
    # tan(phi_out) = cos b2 tan(phi_mid), tan(phi_mid) = tan(phi)/cos b1
    assert np.abs(np.tan(ev.phi_out) - math.cos(b2) / math.cos(b1) * np.tan(phi)).max() < 1e-11
    # ratio = Hooke(b1) ratio times the inverse-Hooke(b2) ratio: tan(phi_mid) = tan(phi_out)/cos b2
    h1 = make_joint('hooke', beta=b1).evaluate(phi)
    inv2 = 1.0 / make_joint('hooke', beta=b2).evaluate(ev.phi_out).ratio
    assert np.abs(ev.ratio - h1.ratio * inv2).max() < 1e-12
    # net law tan(out) = tan(in) / c with c = cos b1/cos b2: amplitude atan(|1-c|/(2 sqrt c))
    c = math.cos(b1) / math.cos(b2)
    assert joint.nonuniformity() == pytest.approx(math.atan(abs(1 - c) / (2 * math.sqrt(c))), rel=1e-9)
    assert joint.nonuniformity() > 0.03


def test_wrong_phase_breaks_homokinetism() -> None:
    joint = make_joint('double_cardan', beta1=D(20.0), beta2=D(20.0), phase=D(90.0))
    hooke = make_joint('hooke', beta=D(20.0)).nonuniformity()
    assert joint.nonuniformity() == pytest.approx(math.atan((1 - math.cos(D(20)) ** 2) /
                                                            (2 * math.cos(D(20)))), rel=1e-9)
    assert joint.nonuniformity() > 1.9 * hooke     # 90 deg out of phase: the two errors add


def test_reactions_power_balance_and_errors() -> None:
    joint = make_joint('double_cardan', beta1=D(20.0), beta2=D(30.0))
    r = joint.reactions(0.7, 10.0, 100.0)
    out, ratio, _ = joint.scalar(0.7)
    mid = joint.evaluate(0.7).phi_mid
    h1 = make_joint('hooke', beta=D(20.0))
    assert r['torque_mid'] == pytest.approx(h1.reactions(0.7, 10.0, 100.0)['torque_out'])
    assert r['secondary_in'] == pytest.approx(h1.reactions(0.7, 10.0, 100.0)['secondary_in'])
    assert r['secondary_mid1'] == pytest.approx(h1.reactions(0.7, 10.0, 100.0)['secondary_out'])
    assert r['torque_out'] * ratio == pytest.approx(100.0) and float(mid) != 0.7
    for kwargs, name in [({'beta1': D(90)}, 'beta1'), ({'beta1': 0.1, 'beta2': D(91)}, 'beta2'),
                         ({'beta1': 0.1, 'layout': 'X'}, 'layout'), ({'beta1': 0.1, 'phase': float('nan')}, 'phase')]:
        with pytest.raises(GeometryError, match=f'^{name}'):
            make_joint('double_cardan', **kwargs)
