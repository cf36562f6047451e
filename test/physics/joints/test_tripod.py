"""Tripod joint: derivatives, exact geometry, closed form, seed errata, reactions."""
from __future__ import annotations

import math

import numpy as np
import pytest

from cvj_ros.errors import GeometryError
from cvj_ros.physics.joints import JOINTS, make_joint
from cvj_ros.physics.joints.tripod import (PRACTICAL_MAX_BETA, RECOMMENDED_MAX_BETA, TWO_PI_3,
                                           Tripod, closed_form_amplitude)

H = 1e-3
PHI = np.array([-7.3, -1.1, 0.0, 0.37, 1.9, 4.4, 11.0, 1e4 + 0.3, 2.5e4 - 1.2])


def richardson(f, x: np.ndarray) -> np.ndarray:
    """Richardson-extrapolated central difference, error O(h^4)."""
    d_h = (f(x + H) - f(x - H)) / (2 * H)
    d_h2 = (f(x + H / 2) - f(x - H / 2)) / H
    return (4 * d_h2 - d_h) / 3


@pytest.fixture(scope='module')
def seed002() -> Tripod:
    return Tripod(math.radians(47.0), 0.09, 1.0)


@pytest.mark.parametrize('method', ['table', 'newton'])
@pytest.mark.parametrize('fidelity', ['ideal', 'closed', 'exact'])
@pytest.mark.parametrize('beta_deg', [15.0, 47.0])
def test_ratio_and_slope_are_derivatives(fidelity: str, beta_deg: float, method: str) -> None:
    tp = Tripod(math.radians(beta_deg), 0.09, 1.0, fidelity=fidelity)
    ev = tp.evaluate(PHI, method=method)
    num_ratio = richardson(lambda x: tp.evaluate(x, method=method).phi_out, PHI)
    num_slope = richardson(lambda x: tp.evaluate(x, method=method).ratio, PHI)
    np.testing.assert_allclose(ev.ratio, num_ratio, rtol=0, atol=1e-7)
    np.testing.assert_allclose(ev.ratio_slope, num_slope, rtol=0, atol=1e-7)
    # the scalar fast path (Fourier table for exact) too
    sc = np.array([tp.scalar(float(p)) for p in PHI])
    np.testing.assert_allclose(richardson(lambda x: np.array([tp.scalar(float(p))[0] for p in x]), PHI),
                               sc[:, 1], rtol=0, atol=1e-7)
    np.testing.assert_allclose(richardson(lambda x: np.array([tp.scalar(float(p))[1] for p in x]), PHI),
                               sc[:, 2], rtol=0, atol=1e-7)


def test_spectral_table_matches_newton(seed002: Tripod) -> None:
    rng = np.random.default_rng(7)
    phi = np.concatenate([rng.uniform(-1e4, 1e4, 200), rng.uniform(0, TWO_PI_3, 200)])
    ev = seed002.evaluate(phi, method='newton')
    tab = seed002.evaluate(phi)
    sc = np.array([seed002.scalar(float(p)) for p in phi])
    np.testing.assert_allclose(sc[:, 0] - phi, ev.phi_out - phi, rtol=0, atol=1e-12)
    np.testing.assert_allclose(tab.phi_out - phi, ev.phi_out - phi, rtol=0, atol=1e-12)
    np.testing.assert_allclose(tab.ratio, ev.ratio, rtol=0, atol=1e-11)
    np.testing.assert_allclose(tab.ratio_slope, ev.ratio_slope, rtol=0, atol=1e-10)
    np.testing.assert_allclose(sc[:, 1], ev.ratio, rtol=0, atol=1e-11)
    np.testing.assert_allclose(sc[:, 2], ev.ratio_slope, rtol=0, atol=1e-10)
    assert seed002.spectral_error <= 1e-12


def test_exact_geometry_satisfies_constraints_independently(seed002: Tripod) -> None:
    """Roller centres on the tracks, trunnions unit, 120 deg apart and normal to the shaft,
    spider centre at distance l from P, phi_out = angle of trunnion 0 in the shaft frame."""
    r, l, beta = 0.09, 1.0, math.radians(47.0)
    u0 = np.array([math.cos(beta), 0.0, -math.sin(beta)])
    for phi in (0.0, 0.4, 1.3, 2.9, 5e3 + 0.1):
        g = seed002.positions(phi)
        for j in range(3):
            psi = phi + j * TWO_PI_3
            rc = g['rollers'][j]
            tol = r * (1e-12 + 2e-16 * abs(phi))      # + the test's own cos(psi) rounding
            assert abs(rc[0] - r * math.cos(psi)) < tol
            assert abs(rc[1] - r * math.sin(psi)) < tol
            assert abs(np.linalg.norm(g['arms'][j]) - 1.0) < 1e-14
            assert abs(g['arms'][j] @ g['n']) < 1e-14
            assert abs(g['arms'][j] @ g['arms'][(j + 1) % 3] + 0.5) < 1e-14
            h = (rc - g['S']) @ g['arms'][j]           # roller slides along its trunnion
            assert 0.5 * r < h < 2.0 * r     # r ... (r + orbit) / cos(beta)
        assert abs(np.linalg.norm(g['P'] - g['S']) - l) < 1e-14
        assert abs(np.linalg.norm(g['n']) - 1.0) < 1e-14
        # output angle from the frame convention (v normal to u0), built here independently
        v = np.cross(g['n'], u0)
        v /= np.linalg.norm(v)
        u = np.cross(v, g['n'])
        ang = math.atan2(g['arms'][0] @ v, g['arms'][0] @ u)
        assert abs(math.remainder(ang - g['phi_out'], 2 * math.pi)) < 1e-13 + 2e-16 * abs(phi)


def test_closed_form_error_falls_as_r_over_l_squared() -> None:
    """Exact minus closed deviation ~ (r/l)^2: log-log slope 2 +- 0.1 over a decade."""
    phi = np.linspace(0.0, TWO_PI_3, 121)
    rls = np.geomspace(0.01, 0.1, 4)
    errs = []
    for rl in rls:
        ex = Tripod(math.radians(25.0), rl, 1.0).evaluate(phi).phi_out
        cl = Tripod(math.radians(25.0), rl, 1.0, fidelity='closed').evaluate(phi).phi_out
        errs.append(np.max(np.abs(ex - cl)))
    slope = np.polyfit(np.log(rls), np.log(errs), 1)[0]
    assert abs(slope - 2.0) < 0.1, slope


def test_amplitude_at_seed002_geometry(seed002: Tripod) -> None:
    closed = Tripod(math.radians(47.0), 0.09, 1.0, fidelity='closed').nonuniformity()
    exact = seed002.nonuniformity()
    assert abs(exact / closed - 1.0) < 0.01
    assert exact == pytest.approx(9.14e-3, rel=2e-3)


def test_erratum_deviation_is_a_sine_with_seed_zero(seed002: Tripod) -> None:
    """Groove m1 in the bend plane at phi = 0: the exact deviation is odd (a sine)."""
    phi = np.linspace(0.05, 2.0, 17)
    dev_p = seed002.evaluate(phi).phi_out - phi
    dev_m = seed002.evaluate(-phi).phi_out + phi
    np.testing.assert_allclose(dev_p, -dev_m, atol=1e-13)
    assert abs(seed002.evaluate(np.array([0.0])).phi_out[0]) < 1e-14
    # a cosine (seed 002 eq. 19 literally) would be maximal at 0
    amp = seed002.nonuniformity()
    assert abs(seed002.evaluate(np.array([math.pi / 6])).phi_out[0] - math.pi / 6) > 0.99 * amp


def test_erratum_derivative_is_minus_three_sine() -> None:
    """In the seed's phase (deviation = A cos 3 phi'), the ratio is 1 - 3 A sin 3 phi',
    not seed 000 eq. 19's 1 - 3 A cos 3 phi'."""
    tp = Tripod(math.radians(30.0), 0.05, 1.0, fidelity='closed')
    a = tp.amplitude_closed
    phi_seed = np.linspace(0.0, 2.0, 41)
    phi = phi_seed - math.pi / 6                 # our zero = seed's zero shifted by pi/6
    ev = tp.evaluate(phi)
    np.testing.assert_allclose(ev.phi_out - phi, a * np.cos(3 * phi_seed), atol=1e-15)
    numeric = richardson(lambda x: tp.evaluate(x - math.pi / 6).phi_out, phi_seed)
    np.testing.assert_allclose(numeric, 1 - 3 * a * np.sin(3 * phi_seed), atol=1e-9)
    eq19 = 1 - 3 * a * np.cos(3 * phi_seed)
    assert np.max(np.abs(numeric - eq19)) > 2.0 * a


def test_erratum_seed002_amplitude_in_rad() -> None:
    a = closed_form_amplitude(math.radians(47.0), 0.09, 1.0)
    assert a == pytest.approx(9.12e-3, rel=1e-3)                 # rad
    assert math.degrees(a) == pytest.approx(0.523, rel=1e-3)     # not 0.009 deg
    assert a > 50 * math.radians(0.009)


def test_erratum_seed002_eq23_has_no_factor_1_5() -> None:
    """Chain tulip-tripode (beta1 15 deg, r1/l 0.11) and bowl (beta2 47 deg, r2/l 0.09),
    both by the closed form as in seed 002 eqs. 20-22: the velocity ratio is the product
    of the two ratios (chain rule), not seed 002 eq. 23."""
    j1 = Tripod(math.radians(15.0), 0.11, 1.0, fidelity='closed')
    j2 = Tripod(math.radians(47.0), 0.09, 1.0, fidelity='closed')
    phi = np.linspace(0.0, 2.0, 41)
    chain = lambda x: j2.evaluate(j1.evaluate(x).phi_out).phi_out  # noqa: E731
    numeric = richardson(chain, phi)
    product = j1.evaluate(phi).ratio * j2.evaluate(j1.evaluate(phi).phi_out).ratio
    np.testing.assert_allclose(numeric, product, atol=1e-9)
    # eq. 23 in the seed's phase: 1 - 3 A1 s1 - 1.5 A2 sin(...) (3 - 4.5 ...): second term 1.5x
    a1, a2 = j1.amplitude_closed, j2.amplitude_closed
    ps = phi + math.pi / 6
    phi2 = ps + a1 * np.cos(3 * ps)
    eq23 = 1 - 3 * a1 * np.sin(3 * ps) - 1.5 * a2 * np.sin(3 * phi2) * (3 - 9 * a1 * np.sin(3 * ps))
    right = (1 - 3 * a1 * np.sin(3 * ps)) * (1 - 3 * a2 * np.sin(3 * phi2))
    np.testing.assert_allclose(numeric, right, atol=1e-9)
    assert np.max(np.abs(eq23 - right)) > a2


def test_reactions_seed000_example_magnitude() -> None:
    """m = 0.2 kg, 2000 rpm, r = 26 mm, l = 700 mm: newtons, not 8000 kN."""
    omega = 2000 * math.pi / 30
    phi = np.linspace(0.0, TWO_PI_3, 25)
    peaks = {}
    for beta_deg in (5.0, 25.0, 30.0):
        tp = Tripod(math.radians(beta_deg), 0.026, 0.7)
        peaks[beta_deg] = max(abs(tp.reactions(float(p), omega, 0.0)['axial_force']) for p in phi)
    assert 0.0 < peaks[5.0] < peaks[25.0] < peaks[30.0] < 20.0       # N
    tp = Tripod(math.radians(25.0), 0.026, 0.7)
    rx = tp.reactions(0.3, omega, 0.0)
    # single plunger: m a_j ~ m omega^2 r tan(beta) cos(psi) ~ 100 N
    assert rx['roller_accel_0'] == pytest.approx(omega ** 2 * 0.026 * math.tan(math.radians(25)) * math.cos(0.3),
                                                 rel=0.05)


def test_reactions_accelerations_are_second_derivatives() -> None:
    tp = Tripod(math.radians(25.0), 0.026, 0.7)
    omega = 150.0
    phi = np.array([0.2, 1.4])
    d2 = richardson(lambda x: richardson(lambda y: tp.solve(y)['roller_z'][0], x), phi)
    for k, p in enumerate(phi):
        acc = tp.reactions(float(p), omega, 0.0)['roller_accel_0']
        assert acc == pytest.approx(omega ** 2 * d2[k], rel=1e-5)


def test_reactions_virtual_work_and_energy_balance() -> None:
    """Massless rollers: T_out * spin_ratio = T_in. With mass: input minus output power
    equals the rate of change of the rollers' axial kinetic energy, m w^3 sum z'_j z''_j.
    spin_ratio (Omega . n / omega_in) and ratio (d phi_out/d phi_in) differ by O((rho/l)^2)."""
    omega, torque = 200.0, 80.0
    for phi in (0.1, 0.9, 2.0):
        tp0 = Tripod(math.radians(30.0), 0.05, 0.5, roller_mass=0.0)
        sol0 = tp0.solve(np.array([phi]))
        spin = sol0['spin_ratio'][0]
        assert abs(spin - sol0['ratio'][0]) < 1e-3 * abs(1 - sol0['ratio'][0]) + 1e-3
        assert tp0.reactions(phi, omega, torque)['torque_out'] * spin == pytest.approx(torque, rel=1e-10)
        tp = Tripod(math.radians(30.0), 0.05, 0.5, roller_mass=0.3, spider_mass=0.8)
        sol = tp.solve(np.array([phi]))
        rx = tp.reactions(phi, omega, torque)
        p_in = torque * omega
        p_out = rx['torque_out'] * omega * sol['spin_ratio'][0]
        dke = 0.3 * omega ** 3 * float(np.sum(sol['roller_dz'][:, 0] * sol['roller_d2z'][:, 0]))
        dke += 0.8 * omega ** 3 * float(sol['spider_d'][:, 0] @ sol['spider_d2'][:, 0])
        assert p_in - p_out == pytest.approx(dke, rel=1e-8, abs=1e-9 * p_in)


def test_spider_orbit_three_times_per_revolution() -> None:
    """The spider centre circles at 3x shaft speed with radius ~ r (1/cos b - 1)/2 (classical
    tripode result); its centripetal force ~ m_s rho (3 omega)^2 reaches the bearings."""
    beta, r = math.radians(25.0), 0.026
    tp = Tripod(beta, r, 0.7, roller_mass=0.0, spider_mass=0.5)
    phi = np.linspace(0.0, 2 * math.pi, 721)
    sol = tp.solve(phi)
    rho = r * (1 / math.cos(beta) - 1) / 2
    assert sol['orbit_radius'].mean() == pytest.approx(rho, rel=0.02)
    turns = np.unwrap(sol['orbit_angle'])
    assert abs(abs(turns[-1] - turns[0]) / (2 * math.pi) - 3.0) < 1e-9
    omega = 200.0
    straight = Tripod(beta, r, 0.7, roller_mass=0.0, spider_mass=0.0)
    # the rollers carry it to the housing (bearing P is l away): housing force ~ m_s a_S
    for p in np.linspace(0.0, 2.0, 5):
        a, b = tp.reactions(float(p), omega, 0.0), straight.reactions(float(p), omega, 0.0)
        f = math.hypot(a['input_force_x'] - b['input_force_x'], a['input_force_y'] - b['input_force_y'])
        assert 0.85 * math.cos(beta) < f / (0.5 * rho * (3 * omega) ** 2) < 1.15


def test_reactions_scale_with_omega_squared_and_vanish_straight() -> None:
    tp = Tripod(math.radians(20.0), 0.026, 0.7)
    a1 = tp.reactions(0.5, 100.0, 0.0)
    a2 = tp.reactions(0.5, 200.0, 0.0)
    for key in ('axial_force', 'input_force_x', 'input_moment_y'):
        assert a2[key] == pytest.approx(4 * a1[key], rel=1e-9)
    straight = Tripod(0.0, 0.026, 0.7).reactions(0.5, 200.0, 50.0)
    assert abs(straight['axial_force']) < 1e-9 and abs(straight['input_force_x']) < 1e-9
    assert straight['torque_out'] == pytest.approx(50.0, rel=1e-12)


def test_closed_reactions_close_to_exact() -> None:
    omega, torque = 209.0, 100.0
    ex = Tripod(math.radians(25.0), 0.026, 0.7)
    cl = Tripod(math.radians(25.0), 0.026, 0.7, fidelity='closed')
    for phi in (0.2, 1.0):
        re, rc = ex.reactions(phi, omega, torque), cl.reactions(phi, omega, torque)
        for key in ('input_force_y', 'input_moment_x', 'input_moment_y', 'torque_out'):
            assert rc[key] == pytest.approx(re[key], rel=0.1, abs=0.5), key


@pytest.mark.parametrize('beta_deg', [25.0, 27.5, 30.0, 70.0])
def test_large_angles_stable(beta_deg: float) -> None:
    tp = Tripod(math.radians(beta_deg), 0.11, 1.0)
    phi = np.linspace(-20.0, 20.0, 2001)
    ev = tp.evaluate(phi)
    assert np.all(np.isfinite(ev.ratio))
    amp = tp.nonuniformity()
    assert np.max(np.abs(ev.phi_out - phi)) <= amp * (1 + 1e-9)
    assert amp == pytest.approx(tp.amplitude_closed, rel=0.01 if beta_deg <= 30 else 0.05)


def test_long_run_continuous() -> None:
    """1e5 revolutions: bounded deviation everywhere, smooth at the far end."""
    tp = Tripod(math.radians(30.0), 0.11, 1.0)
    amp = tp.nonuniformity()
    coarse = np.linspace(0.0, 2 * math.pi * 1e5, 20001) + 0.123
    ev = tp.evaluate(coarse)
    assert np.max(np.abs(ev.phi_out - coarse)) <= amp * (1 + 1e-9)
    fine = 2 * math.pi * 1e5 + np.linspace(-0.5, 0.5, 1001)
    out = tp.evaluate(fine)
    mid = 0.5 * (fine[1:] + fine[:-1])
    secant = np.diff(out.phi_out) / np.diff(fine)
    np.testing.assert_allclose(secant, tp.evaluate(mid).ratio, atol=1e-6)
    sc = [tp.scalar(float(p))[0] for p in fine[::100]]
    np.testing.assert_allclose(sc, out.phi_out[::100], atol=1e-10)


def test_errors_name_the_parameter() -> None:
    with pytest.raises(GeometryError, match=r'^r:'):
        Tripod(0.2, 0.7, 0.7)
    with pytest.raises(GeometryError, match=r'^r:'):
        Tripod(0.2, 0.8, 0.7)
    with pytest.raises(GeometryError, match=r'^r:'):
        Tripod(0.2, 0.0, 0.7)
    with pytest.raises(GeometryError, match=r'^l:'):
        Tripod(0.2, 0.02, -1.0)
    with pytest.raises(GeometryError, match=r'^beta:'):
        Tripod(math.pi / 2, 0.02, 0.7, fidelity='closed')
    with pytest.raises(GeometryError, match=r'^beta:'):
        Tripod(float('nan'), 0.02, 0.7)
    with pytest.raises(GeometryError, match=r'^beta:'):
        Tripod(PRACTICAL_MAX_BETA + 0.01, 0.02, 0.7)
    with pytest.raises(GeometryError, match=r'^phi_in:'):
        Tripod(0.3, 0.02, 0.7).evaluate([0.0, float('nan')])
    with pytest.raises(GeometryError, match=r'^fidelity:'):
        Tripod(0.3, 0.02, 0.7, fidelity='fancy')
    with pytest.raises(GeometryError, match=r'^omega_in:'):
        Tripod(0.3, 0.02, 0.7).reactions(0.0, float('inf'), 0.0)


def test_registry_entry() -> None:
    spec = JOINTS['tripod']
    assert spec.fidelities == ('ideal', 'closed', 'exact')
    assert {'beta', 'r', 'l'} <= set(spec.params)
    tp = make_joint('tripod', fidelity='closed', beta=0.3, r=0.02, l=0.5)
    assert tp.kind == 'tripod' and tp.params()['r'] == 0.02
    assert RECOMMENDED_MAX_BETA == pytest.approx(math.radians(25.0))


def test_per_roller_forces_against_a_reduced_construction() -> None:
    """Massless rollers (Xiu et al. 2024 eqs. 22-24): a frictionless roller force is normal
    to its track (z) and to its trunnion e_j, so F_j = f_j (z x e_j)/|z x e_j|; the housing
    torque and the spider's moment balance about P then fix (f_0, f_1, f_2, T_out) by a
    4 x 4 system built here from positions() alone. The model's roller_force_j (force on
    the trunnion across it in the spider plane) must equal -F_j . (n x e_j); the three
    differ (3.5 % at 25 deg), the arms sum to 3 r + 3 rho(phi) (rho = orbit radius, to
    ~rho^2/r), so their mean is T / (3 r + 3 rho), not the paper's T / (3 r - 3 rho)."""
    r, l, torque = 0.026, 0.7, 100.0
    tp = Tripod(math.radians(25.0), r, l, roller_mass=0.0)
    spreads = []
    for p in np.linspace(0.0, TWO_PI_3, 13):
        g = tp.positions(float(p))
        z = np.array([0.0, 0.0, 1.0])
        dirs = [np.cross(z, e) / np.linalg.norm(np.cross(z, e)) for e in g['arms']]
        A = np.zeros((4, 4))
        for j in range(3):
            A[0, j] = np.cross(g['rollers'][j], dirs[j])[2]            # housing torque: -T_in
            A[1:4, j] = -np.cross(g['rollers'][j] - g['P'], dirs[j])  # spider about P
        A[1:4, 3] = g['n']
        x = np.linalg.solve(A, np.array([-torque, 0.0, 0.0, 0.0]))
        rx = tp.reactions(float(p), 0.0, torque)
        assert rx['torque_out'] == pytest.approx(-x[3], rel=1e-10)
        forces = [rx[f'roller_force_{j}'] for j in range(3)]
        arms = [rx[f'roller_arm_{j}'] for j in range(3)]
        for j in range(3):
            ref = -x[j] * dirs[j] @ np.cross(g['n'], g['arms'][j])
            assert forces[j] == pytest.approx(ref, rel=1e-9)
            assert arms[j] == pytest.approx(np.linalg.norm(g['rollers'][j] - g['S']), rel=1e-12)
        assert sum(f * h for f, h in zip(forces, arms)) == pytest.approx(rx['torque_out'],
                                                                        rel=1e-10)
        rho = tp.solve(np.array([float(p)]))['orbit_radius'][0]
        assert sum(arms) == pytest.approx(3 * r + 3 * rho, abs=3e-6)      # rho^2/r = 7e-5 r
        spreads.append((max(forces) - min(forces)) / np.mean(forces))
    assert max(spreads) > 0.03
    rho0 = r * (1 / math.cos(math.radians(25.0)) - 1) / 2
    mean = np.mean([tp.reactions(float(p), 0.0, torque)[f'roller_force_{j}']
                    for p in np.linspace(0.0, TWO_PI_3, 12, endpoint=False) for j in range(3)])
    assert mean == pytest.approx(torque / (3 * r + 3 * rho0), rel=1e-4)
    assert abs(mean / (torque / (3 * r - 3 * rho0)) - 1) > 0.09


def test_input_moment_includes_the_plungers_angular_momentum() -> None:
    """The housing bearing supplies dL/dt of the plungers about O (Euler on housing +
    plungers): plunger_moment = omega dL/dphi with L = sum m R_j x V_j, V_j = omega dR_j/dphi,
    both derivatives by central differences of positions() (h = 1e-4 rad: error ~h^2 ~1e-8
    relative). Without load torque it is 1.4 % of the bearing moment at 25 deg and 1.8 % at
    30 deg (m = 0.2 kg, 2000 rpm, r = 26 mm, l = 700 mm)."""
    omega, m, h = 2000 * math.pi / 30, 0.2, 1e-4
    for beta_deg, share in ((25.0, 0.0142), (30.0, 0.0182)):
        tp = Tripod(math.radians(beta_deg), 0.026, 0.7, roller_mass=m)

        def momentum(p: float) -> np.ndarray:
            rp, rm = tp.positions(p + h)['rollers'], tp.positions(p - h)['rollers']
            vel = omega * (rp - rm) / (2 * h)
            return m * np.cross(tp.positions(p)['rollers'], vel).sum(axis=0)

        worst, old_max, new_max = 0.0, 0.0, 0.0
        for p in np.linspace(0.0, TWO_PI_3, 40, endpoint=False):
            rx = tp.reactions(float(p), omega, 0.0)
            dl = omega * (momentum(float(p) + h) - momentum(float(p) - h)) / (2 * h)
            pl = np.array([rx['plunger_moment_x'], rx['plunger_moment_y']])
            worst = max(worst, float(np.max(np.abs(pl - dl[:2]))))
            new = np.array([rx['input_moment_x'], rx['input_moment_y']])
            old_max = max(old_max, float(np.hypot(*(new - pl))))
            new_max = max(new_max, float(np.hypot(*pl)))
        assert worst < 1e-5 * new_max
        assert new_max / old_max == pytest.approx(share, abs=5e-4)
