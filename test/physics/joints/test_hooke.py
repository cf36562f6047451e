"""Hooke joint against an independent rotation-matrix construction of the cross, hard
angles (60, 80, 89 deg), errors at 90 deg and above, and the reaction wrench against a
vector construction and virtual work."""
from __future__ import annotations

import math

import numpy as np
import pytest

from cvj_ros.errors import GeometryError
from cvj_ros.physics.joints import make_joint
from cvj_ros.physics.joints.hooke import Hooke

EX, EY, EZ = np.eye(3)


def rot_x(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def rot_y(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def construct(phi1: float, beta: float) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
    """Input pin p1 = R_y(phi1) e_z; output pin p2 normal to p1 and to the output axis;
    phi2 read off p2 = R_x(b) R_y(phi2) e_x. Returns phi2 (mod pi), p1, p2, a2."""
    p1 = rot_y(phi1) @ EZ
    a2 = rot_x(beta) @ EY
    p2 = np.cross(a2, p1)
    p2 /= np.linalg.norm(p2)
    w = rot_x(beta).T @ p2           # = (cos phi2, 0, -sin phi2)
    assert abs(w[1]) < 1e-12
    return math.atan2(-w[2], w[0]), p1, p2, a2


def wrap_pi(x: np.ndarray | float) -> np.ndarray | float:
    return (np.asarray(x) + np.pi / 2) % np.pi - np.pi / 2


@pytest.mark.parametrize('beta_deg', [0.0, 10.0, 30.0, 60.0, 80.0, 89.0])
def test_matches_rotation_matrix_construction(beta_deg: float) -> None:
    beta = math.radians(beta_deg)
    joint = make_joint('hooke', beta=beta)
    phi = np.concatenate([np.linspace(-7.0, 7.0, 57), [1e4 + 0.3, -3e4 - 1.1]])
    ev = joint.evaluate(phi)
    for k, p in enumerate(phi):
        ref, *_ = construct(float(p), beta)
        assert abs(wrap_pi(ev.phi_out[k] - ref)) < 1e-12 * max(1.0, abs(p))
    # and the branch: the unwrapped output stays within pi/2 of the input
    assert np.all(np.abs(ev.phi_out - phi) < np.pi / 2)


@pytest.mark.parametrize('beta_deg', [60.0, 80.0, 89.0])
def test_hard_angles_ratio_range(beta_deg: float) -> None:
    beta = math.radians(beta_deg)
    joint = make_joint('hooke', beta=beta)
    phi = np.linspace(0.0, 2 * np.pi, 100_001)
    ev = joint.evaluate(phi)
    assert ev.ratio.max() == pytest.approx(1 / math.cos(beta), rel=1e-12)      # at phi = 0
    assert ev.ratio.min() == pytest.approx(math.cos(beta), rel=1e-6)           # at phi = pi/2
    assert np.all(np.isfinite(ev.ratio_slope))
    # amplitude of the deviation: closed form atan((1-c)/(2 sqrt c)) vs the samples
    assert joint.nonuniformity() == pytest.approx(np.abs(ev.phi_out - phi).max(), rel=1e-8)


@pytest.mark.parametrize('bad', [math.pi / 2, math.radians(90.0), math.radians(95.0), 4.0, -0.1,
                                 float('nan'), float('inf')])
def test_bad_beta_raises_geometry_error_naming_beta(bad: float) -> None:
    with pytest.raises(GeometryError, match=r'^beta: ') as info:
        make_joint('hooke', beta=bad)
    assert info.value.parameter == 'beta'


def test_nan_input_angle() -> None:
    with pytest.raises(GeometryError, match=r'^phi_in'):
        Hooke(0.3).evaluate(np.array([0.1, np.nan]))


@pytest.mark.parametrize('beta_deg', [15.0, 45.0, 80.0])
def test_reaction_wrench_from_cross_construction(beta_deg: float) -> None:
    beta = math.radians(beta_deg)
    joint = Hooke(beta)
    t1 = 250.0
    for phi in np.linspace(-3.0, 3.0, 23):
        _, p1, p2, a2 = construct(float(phi), beta)
        n = np.cross(p1, p2)                       # moment through a frictionless cross is along n
        moment = t1 / n[1] * n                     # M . a1 = T1, a1 = e_y
        react = joint.reactions(float(phi), 100.0, t1)
        assert [react['moment_x'], react['moment_y'], react['moment_z']] == pytest.approx(moment, abs=1e-9)
        t2 = moment @ a2
        assert react['torque_out'] == pytest.approx(t2, rel=1e-12)
        c1 = moment - t1 * EY
        c2 = moment - t2 * a2
        assert [react['secondary_in_x'], 0.0, react['secondary_in_z']] == pytest.approx(c1, abs=1e-9)
        assert [react['secondary_out_x'], react['secondary_out_y'], react['secondary_out_z']] == \
            pytest.approx(c2, abs=1e-9)
        # textbook magnitudes: T1 tan b |sin phi1| and T2 tan b |cos phi2|
        phi2 = joint.scalar(float(phi))[0]
        assert react['secondary_in'] == pytest.approx(t1 * math.tan(beta) * abs(math.sin(phi)), abs=1e-9)
        assert react['secondary_out'] == pytest.approx(t2 * math.tan(beta) * abs(math.cos(phi2)), abs=1e-9)


def test_output_torque_by_virtual_work() -> None:
    # T1 dphi1 = T2 dphi2: T2 = T1 / (dphi2/dphi1), derivative by central differences
    joint = Hooke(math.radians(35.0))
    for phi in (0.0, 0.4, 1.2, 2.9):
        h = 1e-5
        d = (joint.scalar(phi + h)[0] - joint.scalar(phi - h)[0]) / (2 * h)
        assert joint.reactions(phi, 0.0, 80.0)['torque_out'] == pytest.approx(80.0 / d, rel=1e-8)


def test_ideal_fidelity() -> None:
    joint = make_joint('hooke', fidelity='ideal', beta=0.5)
    assert joint.scalar(1.3) == (1.3, 1.0, 0.0) and joint.nonuniformity() == 0.0
