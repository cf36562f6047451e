"""Runout (eccentric axis): the law against an independent construction (the direction of the
contact seen from the offset axis), its derivatives against finite differences, its order
signature against the log series, the scene keys and their field-path errors, the compiled
kernel against the Python reference, and the order-1 speed and torque of a simulated
two-inertia unit against the closed-form small-amplitude (linearised) response."""
from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

from cvj_ros.errors import GeometryError, SceneError
from cvj_ros.physics.joints import make_joint
from cvj_ros.physics.ordinates import ordinate_harmonics
from cvj_ros.physics.scene import parse_scene

J1, J2 = 0.128, 0.161          # kg m^2, the KAVZ-685 unit (Davidbaev et al. 2023)
M1, MC, W0 = 623.0, 107.5, 39.0
K1 = (M1 - MC) / W0            # N m s/rad: the engine default, steady speed W0 under MC


def _construction(phi: np.ndarray, e: float, r: float, phase: float) -> np.ndarray:
    """Unwrapped direction of the contact r e^{i phi} seen from the driven axis, which lies
    at e in the direction pi - phase: arg(r e^{i phi} + e e^{-i phase})."""
    out = np.unwrap(np.angle(r * np.exp(1j * phi) + e * np.exp(-1j * phase)))
    i0 = int(np.argmin(np.abs(phi)))
    return out - 2.0 * math.pi * round((out[i0] - phi[i0]) / (2.0 * math.pi))


@pytest.mark.parametrize('e, r, phase', [(0.006, 0.05, 0.4), (0.03, 0.05, -2.0),
                                         (0.0005, 0.08, 3.0)])
def test_law_matches_the_construction_and_its_derivatives(e: float, r: float, phase: float
                                                          ) -> None:
    j = make_joint('runout', eccentricity=e, radius=r, phase=phase)
    phi = np.linspace(-9.0, 9.0, 3001)
    ev = j.evaluate(phi)
    assert np.max(np.abs(ev.phi_out - _construction(phi, e, r, phase))) < 1e-12
    # central differences, h = 1e-5: rounding ~ eps/h ~ 1e-11; truncation h^2/6 |f'''|, where
    # the derivatives of the ratio grow like k/(1 - k)^4 (~ 23 at k = 0.6): bound 1e-8
    h = 1e-5
    k = e / r
    up, dn = j.evaluate(phi + h), j.evaluate(phi - h)
    assert np.max(np.abs((up.phi_out - dn.phi_out) / (2 * h) - ev.ratio)) < 1e-8
    assert np.max(np.abs((up.ratio - dn.ratio) / (2 * h) - ev.ratio_slope)) < 1e-8
    assert ev.ratio.min() >= 1.0 / (1.0 + k) - 1e-15 and ev.ratio.max() <= 1.0 / (1.0 - k) + 1e-15
    for p in (-7.1, 0.0, 0.3, 12.5):       # the float fast path is the same law
        assert j.scalar(p) == pytest.approx(tuple(float(v[0]) for v in
                                                  (lambda q: (q.phi_out, q.ratio, q.ratio_slope))(
                                                      j.evaluate([p]))), rel=1e-15, abs=1e-15)
    assert j.nonuniformity() == pytest.approx(np.max(np.abs(ev.phi_out - phi)), rel=1e-6)


@pytest.mark.parametrize('k', [0.01, 0.12, 0.4])
def test_order_signature_is_the_log_series(k: float) -> None:
    """phi_out - phi_in = sum (-1)^n k^n/n sin(n x), x = phi_in + phase: the harmonic analysis
    (Davidbaev et al. 2023 eqs. 4.2-4.3) of 128 ordinates gives orders 1..20 to rounding: the
    orders folded onto them (128 - n and beyond) carry k^108 / 108 < 1e-40."""
    phase = 0.7
    j = make_joint('runout', eccentricity=k * 0.05, radius=0.05, phase=phase)
    m = 128
    phi = 2.0 * math.pi * np.arange(m) / m
    hm = ordinate_harmonics(j.evaluate(phi).phi_out - phi)
    n = hm.orders[:20]
    # (-1)^n k^n/n sin(n phi + n phase) = a_n cos(n phi) + b_n sin(n phi)
    amp = (-1.0) ** n * k ** n / n
    assert hm.mean == pytest.approx(0.0, abs=1e-15)
    np.testing.assert_allclose(hm.cos_coeffs[:20], amp * np.sin(n * phase), rtol=0, atol=2e-15)
    np.testing.assert_allclose(hm.sin_coeffs[:20], amp * np.cos(n * phase), rtol=0, atol=2e-15)
    assert hm.amplitudes[0] == pytest.approx(k, rel=1e-13)


def test_ideal_fidelity_and_zero_eccentricity_are_the_identity() -> None:
    for j in (make_joint('runout', eccentricity=0.01, radius=0.05, fidelity='ideal'),
              make_joint('runout', radius=0.05)):
        assert j.scalar(1.3) == (1.3, 1.0, 0.0)
        ev = j.evaluate([0.2, 5.0])
        assert list(ev.phi_out) == [0.2, 5.0] and list(ev.ratio) == [1.0, 1.0]


@pytest.mark.parametrize('kw, field', [({'eccentricity': 0.05, 'radius': 0.05}, 'eccentricity'),
                                       ({'eccentricity': -1e-3}, 'eccentricity'),
                                       ({'radius': 0.0}, 'radius'),
                                       ({'phase': float('nan')}, 'phase'),
                                       ({'runout': 1.0}, 'runout')])
def test_bad_parameters_name_the_field(kw: dict[str, float], field: str) -> None:
    with pytest.raises(GeometryError, match=rf'^{field}'):
        make_joint('runout', **kw)


def scene(params: dict[str, Any], *, spring: bool = False, method: str = 'dopri5',
          duration: float = 1.0) -> dict[str, Any]:
    """The KAVZ-685 two-inertia unit with a runout between the shafts (rigid, or behind the
    rubber bushings of Davidbaev et al. 2023 with ``spring``), constant load MC."""
    chain: list[dict[str, Any]] = [{'type': 'inertia', 'name': 'drive_shaft', 'J': J1}]
    if spring:
        chain += [{'type': 'spring', 'name': 'bushings', 'stiffness': 715.4, 'damping': 6.35},
                  {'type': 'inertia', 'name': 'hub', 'J': 0.01}]
    chain += [{'type': 'joint', 'name': 'runout', 'kind': 'runout', 'params': params},
              {'type': 'inertia', 'name': 'driven_shaft', 'J': J2}]
    solver = ({'method': method, 'h': 1e-4} if method in ('rk4', 'ros2')
              else {'method': method, 'rtol': 1e-11, 'atol': 1e-12})
    return {'name': 'runout_unit', 'seed': 1, 'duration': duration, 'exchange_step': 0.001,
            'solver': solver, 'engine': {'model': 'linear', 'm1': M1},
            'load': {'model': 'constant', 'torque': MC}, 'initial': {'speed_rad_s': W0},
            'driveline': chain}


def test_scene_keys_and_field_path_errors() -> None:
    sc = parse_scene(scene({'eccentricity_mm': 5.0, 'radius_mm': 50.0, 'phase_deg': 30.0}))
    el = sc.driveline[1]
    assert el.kind == 'runout'
    assert el.params == pytest.approx({'eccentricity': 0.005, 'radius': 0.05,
                                       'phase': math.radians(30.0)})
    for params, msg in (({'eccentricity_mm': 60.0, 'radius_mm': 50.0},
                         r'^driveline\[1\]\.params\.eccentricity_mm: must be >= 0 and < the radius'),
                        ({'eccentricity_mm': 1.0, 'radius_mm': -50.0},
                         r'^driveline\[1\]\.params\.radius_mm: must be > 0'),
                        ({'eccentricity_mm': 1.0, 'offset_mm': 2.0},
                         r'^driveline\[1\]\.params\.offset_mm: unknown parameter')):
        with pytest.raises(SceneError, match=msg):
            parse_scene(scene(params))


def test_kernel_matches_the_python_reference() -> None:
    """Same fixed rk4 steps on both backends: the difference is rounding only (the 1e-12
    bound of test/physics/kernel/test_fuzz_backends.py); rhs and jac at random states too."""
    from cvj_ros.physics.driveline import Driveline
    from cvj_ros.physics.engine import engine_from_spec
    from cvj_ros.physics.kernel.layout import OP_RUNOUT, build_model
    from cvj_ros.physics.kernel.rhs_nb import jac as kernel_jac
    from cvj_ros.physics.kernel.rhs_nb import rhs as kernel_rhs
    from cvj_ros.physics.load import load_from_spec
    from cvj_ros.physics.simulate import Simulation
    for spring in (False, True):
        sc = parse_scene(scene({'eccentricity_mm': 7.0, 'radius_mm': 50.0, 'phase_deg': -40.0},
                               spring=spring, method='rk4', duration=0.2))
        kern, ref = Simulation(sc), Simulation(sc, backend='python')
        assert kern.backend == 'kernel', kern.backend_note
        a, b = kern.run(0.2, sample_dt=0.005), ref.run(0.2, sample_dt=0.005)
        for x, y in ((a.position, b.position), (a.velocity, b.velocity), (a.effort, b.effort)):
            assert np.max(np.abs(x - y)) <= 1e-12 * max(1.0, float(np.max(np.abs(y))))
        assert np.ptp(b.velocity[:, -1]) > 1.0      # the runout does move the driven shaft
        dl = Driveline.from_scene(sc, track_energy=True)
        engine = engine_from_spec(sc.engine)
        load = load_from_spec(sc.load, seed=sc.seed, field='load')
        model = build_model(dl, engine=engine, load=load, horizon=sc.duration)
        assert OP_RUNOUT in model.ip.tolist()
        rng = np.random.default_rng(3)
        n, ns = dl.n_dof, model.n_state
        dy, J = np.empty(ns), np.empty((ns, ns))
        for _ in range(5):
            x = np.array(dl.x0, dtype=float)
            x[:n] += rng.uniform(-3.0, 3.0, n)
            x[n:2 * n] += rng.uniform(-20.0, 20.0, n)
            t = float(rng.uniform(0.0, 0.2))
            yref = dl._rhs(t, x, 0.0, 0.0, engine.torque, load.torque)
            kernel_rhs(t, x, model.ip, model.fp, dy)
            assert np.max(np.abs(dy - yref)) <= 1e-12 * np.max(np.abs(yref))
            w_e, phi_e = float(x[n]), float(x[0])
            phi_l, w_l = dl.load_state(x)
            jref = dl.jacobian(t, x, engine.torque(t, w_e, phi_e), load.torque(t, w_l, phi_l),
                               dTe_domega=engine.slope(t, w_e, phi_e),
                               dTl_domega=load.slope(t, w_l, phi_l))
            kernel_jac(t, x, model.ip, model.fp, J)
            # entry (n+g, g) holds dC/dq by central differences on both sides (a few ulp
            # |C|/h apart, h = 1e-6): test_fuzz_backends.py's FD_ULPS allowance, here 1e-8
            assert np.max(np.abs(J - jref)) <= 1e-8 * np.max(np.abs(jref))


def _order1(tr: Any, col: int, angle_col: int, values: np.ndarray, revs: int = 4,
            m: int = 72) -> complex:
    """Complex order-1 coefficient a_1 - i b_1 of ``values`` over the angle of column
    ``angle_col``, averaged over the last ``revs`` whole revolutions, ``m`` ordinates each
    (cubic-accurate interpolation is not needed: samples every 2e-4 s are 8e-3 rad apart)."""
    q = tr.position[:, angle_col]
    q0 = q[-1] - 2.0 * math.pi * revs
    q0 = 2.0 * math.pi * math.ceil(q0 / (2.0 * math.pi))
    out = 0.0 + 0.0j
    for r in range(revs - 1):
        grid = q0 + 2.0 * math.pi * (r + np.arange(m) / m)
        hm = ordinate_harmonics(np.interp(grid, q, values))
        out += complex(hm.cos_coeffs[0], -hm.sin_coeffs[0])
    return out / (revs - 1)


@pytest.mark.parametrize('k', [0.004, 0.01])
def test_simulated_order_one_matches_the_linearised_response(k: float) -> None:
    """Rigid unit J1 - runout - J2, engine M1 - K1 omega, load MC: with theta = phi_1 + phase,
    ratio 1 - k cos(theta) and ratio slope k sin(theta) to first order in k, the section's
    equation M(q) q'' + J2 a a' q'^2 = M1 - K1 q' - MC a linearises about omega = W0 to

        J u' + K1 u = k (MC cos(theta) - J2 W0^2 sin(theta)),   J = J1 + J2,

    so the input speed's order-1 coefficient (of e^{i theta}) is U = k (MC + i J2 W0^2) /
    (K1 + i J W0), the output speed's U - k W0 and the output shaft's torque (MC plus the
    driven inertia's) i W0 J2 (U - k W0). Neglected: O(k^2) relative; bound 2 k^2 relative
    (measured 0.3-0.7 k^2 at k = 0.004-0.15, the torque's the largest)."""
    phase = 0.5
    sc = parse_scene(scene({'eccentricity_m': k * 0.05, 'radius_m': 0.05, 'phase_rad': phase}))
    tr = __import__('cvj_ros.physics.simulate', fromlist=['Simulation']).Simulation(
        sc, backend='kernel').run(1.0, sample_dt=2e-4)
    names = tr.names
    i_in, i_out = names.index('drive_shaft'), names.index('runout_output')
    u = k * (MC + 1j * J2 * W0 ** 2) / (K1 + 1j * (J1 + J2) * W0)
    rot = np.exp(1j * phase)         # coefficients over phi_1 = those over theta times e^{i phase}
    expect = {'speed_in': u * rot, 'speed_out': (u - k * W0) * rot,
              'torque_out': 1j * W0 * J2 * (u - k * W0) * rot}
    got = {'speed_in': _order1(tr, i_in, i_in, tr.velocity[:, i_in]),
           'speed_out': _order1(tr, i_out, i_in, tr.velocity[:, i_out]),
           'torque_out': _order1(tr, i_out, i_in, tr.effort[:, i_out])}
    for key, want in expect.items():
        assert abs(got[key] - want) <= 2.0 * k * k * abs(want), (key, got[key], want)


def test_accuracy_target_drops_a_runout_below_it() -> None:
    """The fidelity picker's speed error of the ideal level is the ratio's deviation,
    max |ratio - 1| = k/(1 - k) ~ k: below the scene's target the runout is switched off."""
    from cvj_ros.physics.fidelity import choose_fidelity
    for e_mm, want in ((0.005, 'ideal'), (5.0, 'exact')):      # k = 1e-4, 0.1; target 1e-3
        d = scene({'eccentricity_mm': e_mm, 'radius_mm': 50.0})
        d['accuracy_target'] = 1e-3
        (choice,) = choose_fidelity(parse_scene(d)).choices
        assert choice.chosen == want, choice
        k = e_mm / 50.0     # sampled on 2048 angles, which include x = pi (phase 0)
        assert choice.candidates['ideal']['speed_error'] == pytest.approx(k / (1.0 - k), rel=1e-9)
