"""Rzeppa / Birfield joint against seed 003 and an independent construction: the ball
line as the intersection of the input groove plane and the cage plane, read in the
output and cage frames built from rotation matrices."""
from __future__ import annotations

import math

import numpy as np
import pytest

from cvj_ros.errors import GeometryError
from cvj_ros.physics.joints import make_joint
from cvj_ros.physics.joints.rzeppa import Rzeppa

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


def construct(phi1: float, delta: float, alpha: float) -> tuple[float, float]:
    """phi2 and phi3 (mod pi) of the ball line pi_1 & cage plane."""
    r1 = rot_y(phi1) @ EX                 # normal of groove plane pi_1 (eq. 4)
    n = rot_x(alpha) @ EY                 # normal of the cage plane (eq. 9)
    u = np.cross(r1, n)
    w2 = rot_x(delta).T @ u               # output frame: groove plane spanned by e_y, R_y(phi2) e_z
    w3 = rot_x(alpha).T @ u               # cage frame
    return math.atan2(w2[0], w2[2]), math.atan2(w3[0], w3[2])


PHI = np.concatenate([np.linspace(-7.0, 7.0, 71), 1e4 + np.linspace(0, 6.3, 9)])


@pytest.mark.parametrize('delta_deg', [0.0, 10.0, 30.0, 47.0, 60.0, 85.0])
def test_homokinetic_on_bisecting_cage_plane(delta_deg: float) -> None:
    joint = make_joint('rzeppa', delta=D(delta_deg))
    ev = joint.evaluate(PHI)
    assert np.abs(ev.phi_out - PHI).max() < 1e-12
    assert np.abs(ev.ratio - 1.0).max() < 1e-12 and np.abs(ev.ratio_slope).max() < 1e-12
    # alpha given explicitly as delta/2 (floating point) is homokinetic to 1e-12 as well
    joint2 = make_joint('rzeppa', delta=D(delta_deg), alpha=D(delta_deg) / 2)
    assert np.abs(joint2.evaluate(PHI).phi_out - PHI).max() < 1e-12


@pytest.mark.parametrize('delta_deg,alpha_deg', [(47.0, 23.5), (40.0, 12.0), (30.0, 25.0), (20.0, -5.0)])
def test_eq10_and_cage_against_construction(delta_deg: float, alpha_deg: float) -> None:
    delta, alpha = D(delta_deg), D(alpha_deg)
    joint = Rzeppa(delta, alpha=alpha)
    ev = joint.evaluate(PHI)
    k = math.tan(alpha) * math.sin(delta) + math.cos(delta)          # seed 003 eq. 10 verbatim
    for i, p in enumerate(PHI):
        phi2, phi3 = construct(float(p), delta, alpha)
        assert abs(wrap_pi(ev.phi_out[i] - phi2)) < 1e-11
        assert abs(wrap_pi(ev.phi_mid[i] - phi3)) < 1e-11
        if abs(math.cos(p)) > 1e-3:
            assert abs(wrap_pi(ev.phi_out[i] - math.atan(math.tan(p) / k))) < 1e-11


def test_cage_functions_match_seed003_closed_forms() -> None:
    delta = D(40.0)
    joint = Rzeppa(delta)
    phi3, f1, f2 = joint.cage(PHI)
    s, c = math.sin(delta / 2), math.cos(delta / 2)
    # eq. 26 (mod pi), eq. 29, eq. 34
    assert np.abs(wrap_pi(phi3 - np.arctan(c * np.tan(PHI)))).max() < 1e-11
    den = 1 - s * s * np.sin(PHI) ** 2
    assert np.abs(f1 - c / den).max() < 1e-13
    assert np.abs(f2 - c * s * s * np.sin(2 * PHI) / den ** 2).max() < 1e-13
    assert np.array_equal(joint.evaluate(PHI).phi_mid, phi3)
    # phi_mid continuous and within pi/2 of phi_in over many turns
    many = np.linspace(0, 2 * np.pi * 1e4, 200_001)
    mid = joint.evaluate(many).phi_mid
    assert np.abs(np.diff(mid)).max() <= (1 / c) * (many[1] - many[0]) * (1 + 1e-12)


def test_ball_point_against_seed003_and_derivatives() -> None:
    delta, radius, omega, domega = D(40.0), 0.03, 150.0, 0.0
    joint = Rzeppa(delta, r=radius)
    s, c = math.sin(delta / 2), math.cos(delta / 2)
    phi = np.linspace(-3.0, 3.0, 41)
    b = joint.ball_point(phi, omega, domega)
    root = np.sqrt(1 - s * s * np.sin(phi) ** 2)
    # eq. 35 position
    pos = radius * np.stack([c * np.sin(phi), -s * np.cos(phi), c * np.cos(phi)], -1) / root[:, None]
    assert np.abs(b['position'] - pos).max() < 1e-15
    # eq. 37 velocity, with V_Az = -... (the seed prints +; the time derivative decides)
    vel = omega * radius * np.stack([c * np.cos(phi), s * c * c * np.sin(phi), -c ** 3 * np.sin(phi)],
                                    -1) / root[:, None] ** 3
    assert np.abs(b['velocity'] - vel).max() < 1e-12
    # velocity = d(position)/dt by central differences in time (phi1 = omega t)
    dt = 1e-7
    fwd = joint.ball_point(phi + omega * dt, omega)['position']
    bwd = joint.ball_point(phi - omega * dt, omega)['position']
    assert np.abs((fwd - bwd) / (2 * dt) - b['velocity']).max() < 1e-6 * np.abs(vel).max()
    # eqs. 39 and 41 with phi3'' = f'' omega^2 (eq. 33), phi3' = f' omega (eq. 28)
    _, f1, f2 = joint.cage(phi)
    at = (f2 * omega ** 2 * radius)[:, None] * np.stack([np.cos(phi), c * s * np.sin(phi),
                                                         -c * c * np.sin(phi)], -1) / root[:, None]
    an = ((f1 * omega) ** 2 * radius)[:, None] * np.stack([-c * np.sin(phi), s * np.cos(phi),
                                                          -c * np.cos(phi)], -1) / root[:, None]
    assert np.abs(b['accel_tangential'] - at).max() < 1e-9 * np.abs(at).max()
    assert np.abs(b['accel_normal'] - an).max() < 1e-9 * np.abs(an).max()
    # total acceleration = d(velocity)/dt numerically
    vf = joint.ball_point(phi + omega * dt, omega)['velocity']
    vb = joint.ball_point(phi - omega * dt, omega)['velocity']
    acc = b['acceleration']
    assert np.abs((vf - vb) / (2 * dt) - acc).max() < 1e-6 * np.abs(acc).max()


def test_torque_relation_eq20() -> None:
    delta, alpha = D(40.0), D(12.0)
    joint = Rzeppa(delta, alpha=alpha)
    k = math.tan(alpha) * math.sin(delta) + math.cos(delta)
    for phi in (0.1, 0.7, 2.0, -1.2):
        phi2 = joint.scalar(phi)[0]
        eq20 = k * math.cos(phi) ** 2 / math.cos(phi2) ** 2 * 90.0
        assert joint.reactions(phi, 10.0, 90.0)['torque_out'] == pytest.approx(eq20, rel=1e-12)


def test_nonuniformity_and_errors() -> None:
    joint = Rzeppa(D(40.0), alpha=D(12.0))
    phi = np.linspace(0, np.pi, 200_001)
    assert joint.nonuniformity() == pytest.approx(np.abs(joint.evaluate(phi).phi_out - phi).max(), rel=1e-8)
    assert Rzeppa(D(47.0)).nonuniformity() == 0.0
    for kwargs, name in [({'delta': D(90)}, 'delta'), ({'delta': -0.1}, 'delta'),
                         ({'delta': float('nan')}, 'delta'), ({'delta': 0.5, 'alpha': D(95)}, 'alpha'),
                         ({'delta': 0.5, 'r': -0.01}, 'r'), ({'delta': 0.5, 'alpha': float('nan')}, 'alpha')]:
        with pytest.raises(GeometryError, match=f'^{name}'):
            make_joint('rzeppa', **kwargs)
    with pytest.raises(GeometryError, match='^r'):
        Rzeppa(0.5).ball_point(0.1, 1.0)
