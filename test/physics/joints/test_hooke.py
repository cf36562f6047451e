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


# --- yoke phase, bend plane and cross angle (Bugaru & Vasile 2021 eq. 10, general form) -------

def transport(beta: float, gamma: float) -> np.ndarray:
    """Output body frame at zero angle: the input frame turned by beta about the normal of
    the bend plane, which lies at gamma about the input axis (y) from the y-z plane."""
    return rot_y(gamma) @ rot_x(beta) @ rot_y(-gamma)


def construct_general(phi1: float, beta: float, psi: float, gamma: float, delta: float,
                      frame: np.ndarray | None = None) -> tuple[float, np.ndarray, np.ndarray]:
    """Independent vector construction, no Hooke formula: the driving arm p1 at psi from the
    input's reference plane, the output axis a2 = T e_y, the driven arm p2 normal to a2 at the
    angle delta from p1, on the side a2 x p1 (the cross's handedness at beta = 0); phi_out
    read off p2 = T R_y(phi_out + psi + delta) e_z. ``frame`` (housing orientation, default
    identity) places the joint in a global frame. Returns (phi_out mod 2 pi, p1, p2)."""
    f = np.eye(3) if frame is None else frame
    p1 = f @ rot_y(phi1 + psi) @ EZ
    t = f @ transport(beta, gamma)
    a2 = t @ EY
    perp = p1 - (p1 @ a2) * a2
    nrm = float(np.linalg.norm(perp))
    u = perp / nrm
    k = math.cos(delta) / nrm
    p2 = k * u + math.sqrt(1.0 - k * k) * np.cross(a2, u)
    w = t.T @ p2                      # = (sin a, 0, cos a), a = phi_out + psi + delta
    assert abs(w[1]) < 1e-12
    assert abs(p1 @ p2 - math.cos(delta)) < 1e-12 and abs(p2 @ a2) < 1e-12
    return math.atan2(w[0], w[2]) - psi - delta, p1, p2


def wrap_2pi(x: np.ndarray | float) -> np.ndarray | float:
    return (np.asarray(x) + np.pi) % (2 * np.pi) - np.pi


GENERAL = [  # beta, psi, gamma, delta (deg)
    (25.0, 0.0, 0.0, 90.0), (25.0, 37.0, 0.0, 90.0), (25.0, 37.0, -110.0, 90.0),
    (60.0, -150.0, 30.0, 90.0), (6.0, 90.0, 180.0, 90.0), (20.0, 0.0, 0.0, 75.0),
    (30.0, 45.0, 60.0, 105.0), (10.0, -20.0, 5.0, 60.0), (0.0, 33.0, 71.0, 80.0)]


@pytest.mark.parametrize('beta_deg, psi_deg, gamma_deg, delta_deg', GENERAL)
def test_phase_bend_plane_cross_angle_match_vector_construction(
        beta_deg: float, psi_deg: float, gamma_deg: float, delta_deg: float) -> None:
    """Position against the vector construction (mod 2 pi: the arm directions fix the
    branch), ratio and slope against central differences of it (h = 1e-5 rad:
    truncation ~h^2 |f'''| / 6 <~ 1e-9, rounding ~1e-16 / h)."""
    b, psi, gam, dl = (math.radians(v) for v in (beta_deg, psi_deg, gamma_deg, delta_deg))
    joint = make_joint('hooke', beta=b, phase=psi, bend_plane=gam, cross_angle=dl)
    phi = np.concatenate([np.linspace(-7.0, 7.0, 41), [1e3 + 0.3, -3e3 - 1.1]])
    ev = joint.evaluate(phi)
    h = 1e-5
    for k, p in enumerate(phi):
        ref = construct_general(float(p), b, psi, gam, dl)[0]
        assert abs(wrap_2pi(ev.phi_out[k] - ref)) < 1e-12 * max(1.0, abs(p))
        assert joint.scalar(float(p)) == pytest.approx(
            (ev.phi_out[k], ev.ratio[k], ev.ratio_slope[k]), rel=1e-14, abs=1e-14)
        if abs(p) < 10.0:
            fp, fm = (construct_general(float(p) + s, b, psi, gam, dl)[0] for s in (h, -h))
            assert ev.ratio[k] == pytest.approx(wrap_2pi(fp - fm) / (2 * h), abs=1e-8)
            rp, rm = (joint.scalar(float(p) + s)[1] for s in (h, -h))
            assert ev.ratio_slope[k] == pytest.approx((rp - rm) / (2 * h), abs=1e-7)
    # unwrapped: continuous over revolutions, within pi/2 of the input
    assert np.all(np.abs(np.diff(ev.phi_out[:41])) < 1.0)
    assert np.all(np.abs(ev.phi_out - phi) < np.pi / 2)


def test_default_phase_is_bit_identical_to_the_plain_law() -> None:
    """Stated defaults (phase 0, bend plane 0, cross 90 deg) take the plain law's path: the
    same bits as tan(phi_out) = tan(phi_in)/cos(beta) alone (existing scenes unchanged)."""
    from cvj_ros.physics.joints.hooke import hooke_stage, hooke_stage_scalar
    beta = math.radians(17.3)
    joint = make_joint('hooke', beta=beta, phase=0.0, bend_plane=0.0, cross_angle=math.pi / 2)
    phi = np.linspace(-40.0, 40.0, 4001)
    ev = joint.evaluate(phi)
    ref = hooke_stage(phi, math.cos(beta))
    for a, r in zip((ev.phi_out, ev.ratio, ev.ratio_slope), ref):
        assert np.array_equal(a, r)
    for p in phi[::97]:
        assert joint.scalar(float(p)) == hooke_stage_scalar(float(p), math.cos(beta))
    assert joint.params() == {'beta': beta}


def test_phase_and_bend_plane_only_shift_the_single_joint_law() -> None:
    """phi_out = H(phi_in + psi - gamma) - psi + gamma: a single joint's nonuniformity does
    not depend on them; the ratio is the plain law's at the shifted angle."""
    b = math.radians(20.0)
    plain = Hooke(b)
    joint = Hooke(b, phase=0.7, bend_plane=-0.2)
    phi = np.linspace(0.0, 2 * np.pi, 1001)
    assert np.allclose(joint.evaluate(phi).ratio, plain.evaluate(phi + 0.9).ratio,
                       rtol=0, atol=1e-14)
    assert joint.nonuniformity() == plain.nonuniformity()


def _pair(beta1: float, beta2: float, psi2: float, gamma2: float,
          delta: float = math.pi / 2) -> object:
    return make_joint('chain', joints=[
        {'kind': 'hooke', 'beta': beta1, 'cross_angle': delta},
        {'kind': 'hooke', 'beta': beta2, 'phase': psi2, 'bend_plane': gamma2,
         'cross_angle': delta}])


@pytest.mark.parametrize('gamma2_deg', [0.0, 180.0])       # W and Z layouts
@pytest.mark.parametrize('beta_deg', [6.0, 20.0, 45.0])
def test_in_phase_equal_angle_pair_is_homokinetic(beta_deg: float, gamma2_deg: float) -> None:
    """Two equal-angle Hooke joints, the yokes of the rigid centre shaft in phase (second
    phase = first + 90 deg), coplanar: phi_out = phi_in to 1e-12, ratio 1, slope 0."""
    b = math.radians(beta_deg)
    pair = _pair(b, b, math.radians(90.0), math.radians(gamma2_deg))
    phi = np.linspace(-20.0, 20.0, 20001)
    ev = pair.evaluate(phi)
    assert np.max(np.abs(ev.phi_out - phi)) < 1e-12 * 20.0
    assert np.max(np.abs(ev.ratio - 1.0)) < 1e-12
    assert np.max(np.abs(ev.ratio_slope)) < 1e-11
    assert pair.nonuniformity() < 1e-12


def test_ninety_degrees_out_of_phase_gives_the_single_law_twice() -> None:
    """Second phase = first (yokes 90 deg apart): tan(phi_out) = tan(phi_in)/cos^2(b), the
    single-joint law twice; nonuniformity 0.00549 at 2 x 6 deg, equal to the double cardan's
    at phase 90 and to twice the single joint's to first order."""
    b = math.radians(6.0)
    pair = _pair(b, b, 0.0, 0.0)
    phi = np.linspace(-1.5, 1.5, 301)
    out = pair.evaluate(phi).phi_out
    assert np.max(np.abs(np.tan(out) - np.tan(phi) / math.cos(b) ** 2)) < 1e-12 * 20
    dc = make_joint('double_cardan', beta1=b, beta2=b, phase=math.pi / 2)
    assert pair.nonuniformity() == pytest.approx(dc.nonuniformity(), rel=1e-6)
    assert pair.nonuniformity() == pytest.approx(0.00549, abs=5e-6)
    assert pair.nonuniformity() == pytest.approx(2 * Hooke(b).nonuniformity(), rel=2e-3)


@pytest.mark.parametrize('psi1_deg, gamma2_deg, delta_deg', [
    (0.0, 0.0, 90.0), (30.0, 180.0, 90.0), (-45.0, 40.0, 90.0), (10.0, 180.0, 80.0)])
def test_pair_in_global_frame_in_phase_means_parallel_yokes(
        psi1_deg: float, gamma2_deg: float, delta_deg: float) -> None:
    """A two-joint propshaft built in one global frame (the second housing turned with the
    centre shaft's axis, T1): the chain equals the construction, and with psi2 = psi1 +
    delta the centre shaft's two yoke arms (front: driven arm of cross 1, rear: driving arm
    of cross 2) are parallel, i.e. the yokes are in phase as a mechanic sees them."""
    b1, b2 = math.radians(18.0), math.radians(12.0)
    psi1, gam2, dl = math.radians(psi1_deg), math.radians(gamma2_deg), math.radians(delta_deg)
    psi2 = psi1 + dl
    pair = make_joint('chain', joints=[
        {'kind': 'hooke', 'beta': b1, 'phase': psi1, 'cross_angle': dl},
        {'kind': 'hooke', 'beta': b2, 'phase': psi2, 'bend_plane': gam2, 'cross_angle': dl}])
    t1 = transport(b1, 0.0)
    for p in np.linspace(-4.0, 4.0, 33):
        mid, _front_in, front = construct_general(float(p), b1, psi1, 0.0, dl)
        out, rear, _ = construct_general(mid, b2, psi2, gam2, dl, frame=t1)
        assert abs(wrap_2pi(pair.scalar(float(p))[0] - out)) < 1e-12 * max(1.0, abs(p))
        assert np.linalg.norm(np.cross(front, rear)) < 1e-12       # rear arm parallel to front


def test_cross_angle_reactions_by_virtual_work_and_vectors() -> None:
    """A non-square cross: torque_out = T1 / ratio (virtual work, T1 dphi1 = T2 dphi2), the
    moment through the cross normal to both arms, and the square-cross closed form in the
    limit."""
    b, t1 = math.radians(28.0), 120.0
    joint = Hooke(b, cross_angle=math.radians(78.0), phase=0.4)
    for p in np.linspace(-3.0, 3.0, 13):
        r = joint.reactions(float(p), 0.0, t1)
        assert r['torque_out'] == pytest.approx(t1 / joint.scalar(float(p))[1], rel=1e-12)
        th1, th2 = joint.pins(float(p))
        p1 = np.array([math.sin(th1), 0.0, math.cos(th1)])
        p2 = rot_x(b) @ rot_y(th2) @ EX
        m = np.array([r['moment_x'], r['moment_y'], r['moment_z']])
        assert abs(m @ p1) < 1e-9 and abs(m @ p2) < 1e-9
    near = Hooke(b, cross_angle=math.pi / 2 - 1e-9, phase=0.4)._reactions_vector(0.9, t1)
    square = Hooke(b, phase=0.4).reactions(0.9, 0.0, t1)
    for key, v in square.items():
        assert near[key] == pytest.approx(v, abs=1e-6)


@pytest.mark.parametrize('delta_deg', [20.0, 150.0, 0.0, 180.0])
def test_cross_angle_that_locks_is_an_error(delta_deg: float) -> None:
    with pytest.raises(GeometryError, match=r'^cross_angle: .*locks'):
        make_joint('hooke', beta=math.radians(30.0), cross_angle=math.radians(delta_deg))
