"""Circumferentially varying stiffness of a spring (``stiffness_variation``): potential
s(phi) V(theta), s = 1 + sum eps cos(n phi + psi) over the angle phi of the shaft right of
the spring (cvj_ros/physics/sections.py SpringLaw). Checked against the numerical derivative
of the potential, the energy balance, the compiled kernel and the linearised forced response.
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

from cvj_ros.errors import SceneError
from cvj_ros.physics.ordinates import ordinate_harmonics
from cvj_ros.physics.scene import parse_scene

# KAVZ-685 unit of Davidbaev et al. 2023 (as test/physics/joints/test_runout.py)
J1, J2, C0, D0 = 0.128, 0.161, 715.4, 6.35
M1, MC, W0 = 623.0, 107.5, 39.0
K1 = (M1 - MC) / W0


def scene(variation: list[dict[str, Any]], *, damping: float = D0, method: str = 'dopri5',
          duration: float = 1.0, law: str = 'linear', extra: dict[str, Any] | None = None
          ) -> dict[str, Any]:
    """J1 - bushings (varying stiffness) - J2, linear engine M1 - K1 omega, constant load MC."""
    spring = {'type': 'spring', 'name': 'bushings', 'stiffness': C0, 'damping': damping,
              'law': law, 'stiffness_variation': variation, **(extra or {})}
    solver = ({'method': method, 'h': 1e-4} if method in ('rk4', 'ros2')
              else {'method': method, 'rtol': 1e-11, 'atol': 1e-12})
    return {'name': 'varying_unit', 'seed': 1, 'duration': duration, 'exchange_step': 0.001,
            'solver': solver,
            'engine': {'model': 'linear', 'm1': M1},
            'load': {'model': 'constant', 'torque': MC},
            'initial': {'speed_rad_s': W0},
            'driveline': [{'type': 'inertia', 'name': 'drive_shaft', 'J': J1}, spring,
                          {'type': 'inertia', 'name': 'driven_shaft', 'J': J2}]}


TERMS = [{'order': 1, 'amplitude': 0.3, 'phase_deg': 40.0},
         {'order': 3, 'amplitude': 0.1, 'phase_deg': -75.0}]


def test_scene_keys_round_trip_and_field_path_errors() -> None:
    sc = parse_scene(scene(TERMS))
    sp = sc.driveline[1]
    assert [n for n, _e, _p in sp.variation] == [1, 3]
    assert np.allclose([v[1:] for v in sp.variation],
                       [(0.3, math.radians(40.0)), (0.1, math.radians(-75.0))], rtol=0, atol=1e-15)
    again = parse_scene(sc.to_dict()).driveline[1].variation
    assert np.allclose(np.array(again), np.array(sp.variation), rtol=0, atol=1e-15)
    assert parse_scene(scene([])).driveline[1].variation == ()
    for terms, msg in (([{'order': 0, 'amplitude': 0.1}],
                        r'^driveline\[1\]\.stiffness_variation\[0\]\.order: must be an integer'),
                       ([{'order': 1.5, 'amplitude': 0.1}], r'\[0\]\.order: must be an integer'),
                       ([{'order': 2}], r'\[0\]\.amplitude: missing'),
                       ([{'order': 2, 'amplitude': -0.1}], r'\[0\]\.amplitude: must be >= 0'),
                       ([{'order': 2, 'amplitude': 0.1, 'phase': 3}], r'\[0\]\.phase: unknown'),
                       ([{'order': 1, 'amplitude': 0.6}, {'order': 2, 'amplitude': 0.5}],
                        r'^driveline\[1\]\.stiffness_variation: the amplitudes sum to 1\.1'),
                       ({'order': 1}, r'^driveline\[1\]\.stiffness_variation: must be a list')):
        with pytest.raises(SceneError, match=msg):
            parse_scene(scene(terms))  # type: ignore[arg-type]


def _driveline(law: str = 'linear', **kw: Any) -> Any:
    from cvj_ros.physics.driveline import Driveline
    extra = {'k2': 4.0, 'backlash_deg': 2.0} if law == 'progressive' else None
    sc = parse_scene(scene(TERMS, law=law, extra=extra, **kw))
    return Driveline.from_scene(sc, fidelity={'bushings': 'elastic'}, track_energy=True)


@pytest.mark.parametrize('law', ['linear', 'progressive'])
def test_generalised_forces_are_minus_the_gradient_of_the_potential(law: str) -> None:
    """At rest, without damping or sources: M q'' = Q = -dV/dq, V = energy()['elastic']
    (central difference, h = 1e-6: error ~ V''' h^2 + 1e-16 V / h, below 1e-8 of |Q|)."""
    dl = _driveline(law, damping=0.0)
    rng = np.random.default_rng(7)
    n = dl.n_dof
    for _ in range(10):
        x = np.zeros(dl._n_state)
        x[:n] = rng.uniform(-4.0, 4.0, n)
        x[1] = x[0] - rng.uniform(-0.4, 0.4)            # twists of the working range
        xd = dl._rhs(0.0, x, 0.0, 0.0, None, None)
        q = xd[n:2 * n] * dl.mass(x)
        for g in range(n):
            h = 1e-6
            xp, xm = x.copy(), x.copy()
            xp[g] += h
            xm[g] -= h
            grad = (dl.energy(xp)['elastic'] - dl.energy(xm)['elastic']) / (2.0 * h)
            assert abs(q[g] + grad) <= 1e-8 * max(1.0, abs(q[g])), (g, q[g], -grad)


@pytest.mark.parametrize('law', ['linear', 'progressive'])
def test_jacobian_matches_finite_differences(law: str) -> None:
    """Analytic Jacobian (work integrals included) against central differences of the rhs,
    h = 1e-6: relative error ~ h^2 T''' / T', about 1e-9 for the linear law; the backlash's
    softplus (width 1.7e-3 rad) makes T''' ~ 1/w^2 larger (measured 1e-7 relative)."""
    dl = _driveline(law)
    rng = np.random.default_rng(11)
    n = dl.n_dof
    for _ in range(5):
        x = np.array(dl.x0)
        x[:n] += rng.uniform(-3.0, 3.0, n)
        x[1] = x[0] - rng.uniform(-0.4, 0.4)
        x[n:2 * n] += rng.uniform(-10.0, 10.0, n)
        jac = dl.jacobian(0.0, x, 50.0, 20.0)
        num = np.empty_like(jac)
        for j in range(x.size):
            h = 1e-6 * max(1.0, abs(x[j]))
            xp, xm = x.copy(), x.copy()
            xp[j] += h
            xm[j] -= h
            num[:, j] = (dl.rhs(0.0, xp, 50.0, 20.0) - dl.rhs(0.0, xm, 50.0, 20.0)) / (2.0 * h)
        assert np.max(np.abs(jac - num)) <= 1e-6 * np.max(np.abs(num))


@pytest.mark.parametrize('damping', [0.0, D0])
def test_energy_balance(damping: float) -> None:
    """The KAVZ-685 unit started 10 deg off its static twist, with and without damping: the
    work integrals close the balance with the varying potential s V in E_el, on both
    backends, to the integrator's 1e-9 (dopri5 at rtol 1e-11)."""
    from cvj_ros.physics.simulate import Simulation
    raw = scene(TERMS, damping=damping, duration=0.5)
    raw['driveline'][1]['initial_twist_deg'] = 10.0
    for backend in ('kernel', 'python'):
        tr = Simulation(parse_scene(raw), backend=backend).run(0.5, sample_dt=1e-3)
        assert tr.max_energy_residual <= 1e-9, backend


def test_kernel_matches_the_python_reference() -> None:
    """Same fixed rk4 steps on both backends (rounding only: 1e-12), rhs at random states to
    1e-12 and the Jacobian to 1e-8 (its dC/dq central differences, as test_runout.py)."""
    from cvj_ros.physics.engine import engine_from_spec
    from cvj_ros.physics.kernel.layout import H_SPRING_F, SPRING_STRIDE, build_model
    from cvj_ros.physics.kernel.rhs_nb import jac as kernel_jac
    from cvj_ros.physics.kernel.rhs_nb import rhs as kernel_rhs
    from cvj_ros.physics.load import load_from_spec
    from cvj_ros.physics.simulate import Simulation
    for law in ('linear', 'progressive'):
        extra = {'k2': 4.0, 'backlash_deg': 2.0} if law == 'progressive' else None
        sc = parse_scene(scene(TERMS, method='rk4', duration=0.2, law=law, extra=extra))
        kern, ref = Simulation(sc), Simulation(sc, backend='python')
        assert kern.backend == 'kernel', kern.backend_note
        a, b = kern.run(0.2, sample_dt=0.005), ref.run(0.2, sample_dt=0.005)
        for x, y in ((a.position, b.position), (a.velocity, b.velocity), (a.effort, b.effort)):
            assert np.max(np.abs(x - y)) <= 1e-12 * max(1.0, float(np.max(np.abs(y))))
        assert np.max(np.abs(a.energy_residual - b.energy_residual)) <= 1e-12
        dl = _driveline(law)
        engine = engine_from_spec(sc.engine)
        load = load_from_spec(sc.load, seed=sc.seed, field='load')
        model = build_model(dl, engine=engine, load=load, horizon=sc.duration)
        assert model.fp[int(model.ip[H_SPRING_F]) + 5] > 0.0   # the variation block's offset
        assert SPRING_STRIDE == 6
        rng = np.random.default_rng(3)
        n, ns = dl.n_dof, model.n_state
        dy, J = np.empty(ns), np.empty((ns, ns))
        for _ in range(5):
            x = np.array(dl.x0, dtype=float)
            x[:n] += rng.uniform(-3.0, 3.0, n)
            x[1] = x[0] - rng.uniform(-0.4, 0.4)
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
            assert np.max(np.abs(J - jref)) <= 1e-8 * np.max(np.abs(jref))


def test_uniform_spring_packs_and_runs_as_before() -> None:
    """No variation: offset 0 in the spring table, the generated Python rhs."""
    from cvj_ros.physics.driveline import Driveline
    from cvj_ros.physics.kernel.layout import H_SPRING_F, build_model
    dl = Driveline.from_scene(parse_scene(scene([])), fidelity={'bushings': 'elastic'})
    assert dl._fast != dl._rhs
    model = build_model(dl)
    assert model.fp[int(model.ip[H_SPRING_F]) + 5] == 0.0


def _order(tr: Any, n: int, angle_col: int, values: np.ndarray, revs: int = 4,
           m: int = 72) -> complex:
    """Complex order-n coefficient a_n - i b_n of ``values`` over the angle of column
    ``angle_col`` (values = Re(C e^{i n phi})), averaged over the last revolutions."""
    q = tr.position[:, angle_col]
    q0 = q[-1] - 2.0 * math.pi * revs
    q0 = 2.0 * math.pi * math.ceil(q0 / (2.0 * math.pi))
    out = 0.0 + 0.0j
    for r in range(revs - 1):
        grid = q0 + 2.0 * math.pi * (r + np.arange(m) / m)
        hm = ordinate_harmonics(np.interp(grid, q, values))
        out += complex(hm.cos_coeffs[n - 1], -hm.sin_coeffs[n - 1])
    return out / (revs - 1)


def linear_response(eps: float, n: int, psi: float) -> dict[str, complex]:
    """Order-n coefficients (over phi = the driven shaft's angle) of the unit J1 - spring
    c0 (1 + eps cos(n phi + psi)), d - J2 with engine M1 - K1 omega and load MC, linearised
    about the uniform steady state (speed W0, twist th0 = MC / c0). With x1, x2 the shafts'
    deviations, s = i n W0 and the forcing e^{i (n W0 t + psi)}:

        (J1 s^2 + K1 s + c0 + d s) X1 - (c0 + d s) X2 = -eps c0 th0
        -(c0 + d s) X1 + (J2 s^2 + c0 + d s) X2 = eps c0 th0 (1 - i n th0 / 2)

    (the second line's last term is the extra torque -c'(phi) th0^2 / 2); the spring torque
    is (c0 + d s)(X1 - X2) + eps c0 th0, the speeds s X. Neglected: O(eps^2)."""
    th0 = MC / C0
    s = 1j * n * W0
    kd = C0 + D0 * s
    a = np.array([[J1 * s * s + K1 * s + kd, -kd], [-kd, J2 * s * s + kd]])
    f = eps * C0 * th0 * np.array([-1.0, 1.0 - 0.5j * n * th0])
    x1, x2 = np.linalg.solve(a, f)
    rot = np.exp(1j * psi)
    return {'speed_in': s * x1 * rot, 'speed_out': s * x2 * rot,
            'torque': (kd * (x1 - x2) + eps * C0 * th0) * rot, 'twist': (x1 - x2) * rot}


@pytest.mark.parametrize('eps,n', [(0.01, 1), (0.03, 1), (0.02, 2)])
def test_simulated_order_matches_the_linearised_response(eps: float, n: int) -> None:
    """Steady run on the compiled kernel; harmonic analysis of its last revolutions over the
    driven shaft's angle against :func:`linear_response`: within 2 eps^2 relative, plus
    2e-5 for the harmonic analysis of interpolated samples (the neglected terms are
    O(eps^2) relative; measured 0.3-1.0 eps^2 for eps = 0.01-0.3, docs/imperfections.md);
    the other order at most eps^2 of the mean torque (measured 0.5 eps^2 MC for n = 1)."""
    from cvj_ros.physics.simulate import Simulation
    psi = 0.7
    sc = parse_scene(scene([{'order': n, 'amplitude': eps, 'phase_deg': math.degrees(psi)}]))
    tr = Simulation(sc, backend='kernel').run(1.0, sample_dt=2e-4)
    i_in, i_out = tr.names.index('drive_shaft'), tr.names.index('driven_shaft')
    want = linear_response(eps, n, psi)
    got = {'speed_in': _order(tr, n, i_out, tr.velocity[:, i_in]),
           'speed_out': _order(tr, n, i_out, tr.velocity[:, i_out]),
           'torque': _order(tr, n, i_out, tr.effort[:, i_in]),
           'twist': _order(tr, n, i_out, tr.position[:, i_in] - tr.position[:, i_out])}
    for key, w in want.items():
        assert abs(got[key] - w) <= (2.0 * eps * eps + 2e-5) * abs(w), (key, got[key], w)
    other = 3 - n                                   # order 2 for n = 1, order 1 for n = 2
    assert abs(_order(tr, other, i_out, tr.effort[:, i_in])) <= eps * eps * MC


@pytest.mark.parametrize('name,index,key,value', [
    ('fwd_axle', 1, 'stiffness_variation', [{'order': 1, 'amplitude': 0.2}]),
    ('fwd_axle', 0, 'imbalance', {'mass_kg': 1.0, 'radius_m': 0.01}),
    ('launch_clutch_chain', 2, 'stiffness_variation', [{'order': 1, 'amplitude': 0.2}]),
    ('launch_clutch_chain', 0, 'imbalance', {'mass_kg': 1.0, 'radius_m': 0.01}),
])
def test_scenes_without_the_imperfections_name_the_field(name: str, index: int, key: str,
                                                          value: Any) -> None:
    """Vehicle and clutch scenes do not carry them yet: one line naming the field."""
    from cvj_ros.commands.sweep import load_scene_data
    from cvj_ros.physics.scene import find_scene
    from cvj_ros.physics.simulate import Simulation
    raw = load_scene_data(find_scene(name))
    raw['driveline'][index][key] = value
    with pytest.raises(SceneError, match=rf'^driveline\[{index}\]\.{key}: not available'):
        Simulation(parse_scene(raw))
