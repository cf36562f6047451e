"""Lever-hinge coupling: rigid = synchronous, derivatives, derived small-deformation formula
against an independent numerical solution of the vector closure."""
from __future__ import annotations

import math

import numpy as np
import pytest

from cvj_ros.errors import GeometryError
from cvj_ros.physics.joints import JOINTS, make_joint
from cvj_ros.physics.joints.lever_hinge import (KAVZ685_ALPHA, LeverHinge, deformation_angles,
                                                rocking_angles, twist_for_torque)

H = 1e-3
PHI = np.array([-7.3, -1.1, 0.0, 0.37, 1.9, 4.4, 11.0, 1e4 + 0.3, 2.5e4 - 1.2])


def richardson(f, x: np.ndarray) -> np.ndarray:
    d_h = (f(x + H) - f(x - H)) / (2 * H)
    d_h2 = (f(x + H / 2) - f(x - H / 2)) / H
    return (4 * d_h2 - d_h) / 3


def closure_solution(phi_in: float, alpha: float, delta_alpha: float, twist: float) -> tuple[float, float]:
    """Independent geometry: fork pins, earring hinge axes and shafts as vectors.
    Intermediate angle c from p1 . q(c) = 0, output angle from p2(phi) . q(c + twist) = 0,
    each by Newton with numerical derivative, starting at the rigid solution."""
    def pin(phi: float, a: float) -> np.ndarray:
        b = np.array([-math.sin(a), math.cos(a), 0.0])
        return math.cos(phi) * b + math.sin(phi) * np.array([0.0, 0.0, 1.0])

    def q(c: float) -> np.ndarray:
        return np.array([0.0, -math.sin(c), math.cos(c)])

    def newton(f, x: float) -> float:
        for _ in range(60):
            d = (f(x + 1e-7) - f(x - 1e-7)) / 2e-7
            step = f(x) / d
            x -= step
            if abs(step) < 1e-15 * (1 + abs(x)):
                break
        return x

    c = newton(lambda cc: float(pin(phi_in, alpha) @ q(cc)), phi_in)
    a2 = alpha + delta_alpha
    # the output fork pin must also be normal to its shaft: check the construction
    shaft2 = np.array([math.cos(a2), math.sin(a2), 0.0])
    assert abs(pin(0.3, a2) @ shaft2) < 1e-15
    phi_out = newton(lambda p: float(pin(p, a2) @ q(c + twist)), phi_in + twist)
    return phi_out, c


def test_rigid_is_synchronous() -> None:
    phi = np.linspace(-30.0, 30.0, 3001)
    for alpha in (0.0, math.radians(15.0), math.radians(40.0), math.radians(75.0)):
        for fid in ('ideal', 'closed', 'exact'):
            lh = LeverHinge(alpha, fidelity=fid)
            ev = lh.evaluate(phi)
            np.testing.assert_allclose(ev.phi_out, phi, atol=1e-13)
            np.testing.assert_allclose(ev.ratio, 1.0, atol=1e-13)
            np.testing.assert_allclose(ev.ratio_slope, 0.0, atol=1e-12)
    # the earring itself turns non-uniformly (Hooke, seed 004 eq. 3.2): tan c = tan phi / cos a
    lh = LeverHinge(math.radians(30.0))
    p = np.array([0.4, 1.2])
    np.testing.assert_allclose(np.tan(lh.evaluate(p).phi_mid), np.tan(p) / math.cos(math.radians(30.0)),
                               rtol=1e-13)


@pytest.mark.parametrize('fidelity', ['closed', 'exact'])
def test_ratio_and_slope_are_derivatives(fidelity: str) -> None:
    lh = LeverHinge(math.radians(25.0), fidelity=fidelity, delta_alpha=0.04, twist=0.05)
    ev = lh.evaluate(PHI)
    np.testing.assert_allclose(ev.ratio, richardson(lambda x: lh.evaluate(x).phi_out, PHI), atol=1e-7)
    np.testing.assert_allclose(ev.ratio_slope, richardson(lambda x: lh.evaluate(x).ratio, PHI), atol=1e-7)
    sc = np.array([lh.scalar(float(p)) for p in PHI])
    np.testing.assert_allclose(sc[:, 0], ev.phi_out, atol=1e-12)
    np.testing.assert_allclose(sc[:, 1], ev.ratio, atol=1e-13)
    np.testing.assert_allclose(sc[:, 2], ev.ratio_slope, atol=1e-13)


def test_exact_matches_vector_closure() -> None:
    alpha, da, tw = math.radians(15.0), 0.03, -0.05
    lh = LeverHinge(alpha, delta_alpha=da, twist=tw)
    for phi in (0.0, 0.3, 1.2, 2.8, 4.0, 5.9, 1e3 + 0.4):
        out, c = closure_solution(phi, alpha, da, tw)
        ev = lh.evaluate(np.array([phi]))
        assert ev.phi_out[0] == pytest.approx(out, abs=1e-12)
        assert ev.phi_mid[0] == pytest.approx(c, abs=1e-12)


def test_closed_form_error_is_second_order() -> None:
    """Derived formula vs numerical closure: error <= C d^2 and falls 4x per halving of d."""
    alpha = KAVZ685_ALPHA
    phi = np.linspace(0.0, 2 * math.pi, 37)
    errs = []
    scales = [0.04, 0.02, 0.01]
    for d in scales:
        cl = LeverHinge(alpha, fidelity='closed', delta_alpha=d, twist=d).evaluate(phi).phi_out
        ex = np.array([closure_solution(float(p), alpha, d, d)[0] for p in phi])
        errs.append(np.max(np.abs(cl - ex)))
    # first-order terms are ~d; the remainder must be ~d^2
    assert errs[0] < 1.0 * scales[0] ** 2
    slope = np.polyfit(np.log(scales), np.log(errs), 1)[0]
    assert abs(slope - 2.0) < 0.1, slope
    # and the first-order content is really there: dropping it costs O(d)
    ideal_err = np.max(np.abs(phi - np.array([closure_solution(float(p), alpha, 0.01, 0.01)[0] for p in phi])))
    assert ideal_err > 0.005


def test_deviation_trends() -> None:
    """Twist: mean shift twist/cos(alpha) and 2nd harmonic; tilt: 2nd harmonic ~ tan(alpha)."""
    phi = np.linspace(0.0, math.pi, 2001)[:-1]
    lh = LeverHinge(math.radians(20.0), twist=0.01)
    dev = lh.evaluate(phi).phi_out - phi
    a = math.radians(20.0)
    assert dev.mean() == pytest.approx(0.01 * (1 - 0.5 * math.sin(a) ** 2) / math.cos(a), rel=1e-3)
    tilt = LeverHinge(math.radians(20.0), delta_alpha=0.01)
    amp = tilt.nonuniformity()
    assert amp == pytest.approx(0.005 * math.tan(a), rel=0.05)
    assert LeverHinge(math.radians(30.0), delta_alpha=0.01).nonuniformity() > amp


def test_helpers() -> None:
    da, tw = deformation_angles(support_deflection=0.03, shaft_length=1.0,
                                hinge_deflection=0.05 * 0.2, earring_length=0.2)
    assert da == pytest.approx(math.asin(0.03)) and tw == pytest.approx(math.asin(0.05))
    assert twist_for_torque(107.5) == pytest.approx(107.5 / 715.4)
    with pytest.raises(GeometryError, match=r'^shaft_length:'):
        deformation_angles(shaft_length=0.0)
    with pytest.raises(GeometryError, match=r'^stiffness:'):
        twist_for_torque(1.0, stiffness=-1.0)


def test_reactions_power_balance() -> None:
    lh = LeverHinge(math.radians(20.0), delta_alpha=0.02)
    r = lh.reactions(0.7, 30.0, 100.0)
    assert r['torque_out'] * lh.scalar(0.7)[1] == pytest.approx(100.0, rel=1e-13)


def test_long_run_continuous() -> None:
    lh = LeverHinge(math.radians(25.0), delta_alpha=0.03, twist=0.02)
    phi = 2 * math.pi * 1e5 + np.linspace(-0.5, 0.5, 1001)
    ev = lh.evaluate(phi)
    mid = 0.5 * (phi[1:] + phi[:-1])
    np.testing.assert_allclose(np.diff(ev.phi_out) / np.diff(phi), lh.evaluate(mid).ratio, atol=1e-6)
    coarse = np.linspace(0.0, 2 * math.pi * 1e5, 100001) + 0.1
    assert np.max(np.abs(lh.evaluate(coarse).phi_out - coarse)) <= lh.nonuniformity() * 1.001


def test_errors_name_the_parameter() -> None:
    with pytest.raises(GeometryError, match=r'^alpha:'):
        LeverHinge(math.pi / 2)
    with pytest.raises(GeometryError, match=r'^alpha:'):
        LeverHinge(float('nan'))
    # the sum out of range: named with both terms, blamed on the larger one
    with pytest.raises(GeometryError, match=r'^alpha: the sum alpha \+ delta_alpha must be in '
                                            r'\[0, 90\) deg, got 89 \+ 5\.72958 = 94\.7296 deg$'):
        LeverHinge(math.radians(89.0), delta_alpha=0.1)
    with pytest.raises(GeometryError, match=r'^delta_alpha: the sum alpha \+ delta_alpha'):
        LeverHinge(0.1, delta_alpha=1.6)
    with pytest.raises(GeometryError, match=r'^twist:'):
        LeverHinge(0.2, twist=float('inf'))
    with pytest.raises(GeometryError, match=r'^phi_in:'):
        LeverHinge(0.2).evaluate([float('nan')])
    with pytest.raises(GeometryError, match=r'^fidelity:'):
        LeverHinge(0.2, fidelity='approx')


def test_registry_entry() -> None:
    spec = JOINTS['lever_hinge']
    assert spec.fidelities == ('ideal', 'closed', 'exact')
    lh = make_joint('lever_hinge', fidelity='exact', alpha=0.3, twist=0.01)
    assert lh.kind == 'lever_hinge' and lh.mid_name == 'earring'
    assert make_joint('lever_hinge').params()['alpha'] == pytest.approx(math.radians(15.0))


@pytest.mark.parametrize('alpha_deg', [5.0, 15.0, 40.0])
def test_rocking_angles_against_vector_construction(alpha_deg: float) -> None:
    """Fork pin p1 = cos(phi) b1 + sin(phi) z on the shaft axis a1 = (cos a, sin a, 0),
    earring rod-hinge axis q normal to p1 and to O1-O2 (x), found as the unit x x p1 (no
    Hooke formula; it is q(c) = (0, -sin c, cos c) with c continuous in phi): the
    earring's turn in the fork about p1 is asin(-q . a1) and equals atan(tan a sin phi);
    the rods' turn on the earring is asin(-p1 . x) and equals asin(sin a cos phi) (Davidbaev
    et al. 2023 eq. 3.2's xi): the docs' attribution."""
    a = math.radians(alpha_deg)
    a1 = np.array([math.cos(a), math.sin(a), 0.0])
    b1 = np.array([-math.sin(a), math.cos(a), 0.0])
    x = np.array([1.0, 0.0, 0.0])
    phi = np.linspace(-7.0, 7.0, 71)
    fork_earring, earring_rod = rocking_angles(phi, a)
    for k, p in enumerate(phi):
        p1 = math.cos(p) * b1 + math.sin(p) * np.array([0.0, 0.0, 1.0])
        q = np.cross(x, p1)
        q /= np.linalg.norm(q)
        assert abs(p1 @ q) < 1e-12
        assert fork_earring[k] == pytest.approx(math.asin(-q @ a1), abs=1e-12)
        assert earring_rod[k] == pytest.approx(math.asin(-p1 @ x), abs=1e-12)
    # they are different angles: equal amplitude alpha, a quarter turn apart
    assert np.max(np.abs(fork_earring)) == pytest.approx(a, rel=1e-3)
    assert abs(fork_earring[35]) < 1e-12 and earring_rod[35] == pytest.approx(a, rel=1e-12)
