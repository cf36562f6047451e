"""Mass imbalance on any inertia (``imbalance: {mass_kg, radius_m, angle_deg}``): the weight
of a mass m at radius e on a horizontal shaft resists with m g e cos(phi + angle), potential
m g e sin(phi + angle) (cvj_ros/physics/sections.py section_imbalance). Checked against the
numerical derivative of the potential, the compiled kernel, the energy balance and the
linearised order-1 response of the KAVZ-685 unit (Davidbaev et al. 2023).
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

from cvj_ros.errors import SceneError
from cvj_ros.physics.ordinates import ordinate_harmonics
from cvj_ros.physics.scene import GRAVITY, parse_scene

J1, J2, C0, D0 = 0.128, 0.161, 715.4, 6.35
M1, MC, W0 = 623.0, 107.5, 39.0
K1 = (M1 - MC) / W0


def scene(imb: dict[str, Any] | None, *, method: str = 'dopri5', duration: float = 1.0,
          hooke: bool = False, imb_mid: dict[str, Any] | None = None) -> dict[str, Any]:
    """drive_shaft (imbalance) - bushings - [hooke 20 deg - hub (imb_mid)] - driven_shaft."""
    first: dict[str, Any] = {'type': 'inertia', 'name': 'drive_shaft', 'J': J1}
    if imb is not None:
        first['imbalance'] = imb
    chain = [first, {'type': 'spring', 'name': 'bushings', 'stiffness': C0, 'damping': D0}]
    if hooke:
        hub: dict[str, Any] = {'type': 'inertia', 'name': 'hub', 'J': 0.02}
        if imb_mid is not None:
            hub['imbalance'] = imb_mid
        chain += [{'type': 'joint', 'name': 'cross', 'kind': 'hooke', 'params': {'beta_deg': 20.0}},
                  hub]
    chain.append({'type': 'inertia', 'name': 'driven_shaft', 'J': J2})
    solver = ({'method': method, 'h': 1e-4} if method in ('rk4', 'ros2')
              else {'method': method, 'rtol': 1e-11, 'atol': 1e-12})
    return {'name': 'imbalance_unit', 'seed': 1, 'duration': duration, 'exchange_step': 0.001,
            'solver': solver, 'engine': {'model': 'linear', 'm1': M1},
            'load': {'model': 'constant', 'torque': MC}, 'initial': {'speed_rad_s': W0},
            'driveline': chain}


IMB = {'mass_kg': 2.0, 'radius_m': 0.05, 'angle_deg': 30.0}
IMB_MID = {'mass_kg': 1.0, 'radius_m': 0.04, 'angle_deg': -100.0}


def test_scene_keys_round_trip_and_field_path_errors() -> None:
    sc = parse_scene(scene(IMB))
    m, e, ang = sc.driveline[0].imbalance
    assert (m, e) == (2.0, 0.05) and abs(ang - math.radians(30.0)) < 1e-15
    assert parse_scene(sc.to_dict()).driveline[0].imbalance == sc.driveline[0].imbalance
    assert parse_scene(scene(None)).driveline[0].imbalance is None
    for imb, msg in (({'mass_kg': -1.0, 'radius_m': 0.1}, r'imbalance\.mass_kg: must be >= 0'),
                     ({'radius_m': 0.1}, r'imbalance\.mass_kg: missing'),
                     ({'mass_kg': 1.0, 'radius_m': 0.1, 'phase': 2}, r'imbalance\.phase: unknown'),
                     ([1, 2], r'^driveline\[0\]\.imbalance: ')):
        with pytest.raises(SceneError, match=msg):
            parse_scene(scene(imb))  # type: ignore[arg-type]


def _driveline(**kw: Any) -> Any:
    from cvj_ros.physics.driveline import Driveline
    sc = parse_scene(scene(IMB, hooke=True, imb_mid=IMB_MID, **kw))
    return Driveline.from_scene(sc, fidelity={'bushings': 'elastic', 'cross': 'exact'},
                                track_energy=True)


def test_generalised_forces_are_minus_the_gradient_of_the_potential() -> None:
    """At rest, no sources and no twist rate: M q'' = Q = -dV/dq with the imbalance behind a
    20 deg Hooke joint (its a and b enter); central difference h = 1e-6."""
    dl = _driveline()
    rng = np.random.default_rng(5)
    n = dl.n_dof
    for _ in range(10):
        x = np.zeros(dl._n_state)
        x[:n] = rng.uniform(-4.0, 4.0, n)
        xd = dl._rhs(0.0, x, 0.0, 0.0, None, None)
        q = xd[n:2 * n] * dl.mass(x)
        for g in range(n):
            h = 1e-6
            xp, xm = x.copy(), x.copy()
            xp[g] += h
            xm[g] -= h
            grad = (dl.energy(xp)['elastic'] - dl.energy(xm)['elastic']) / (2.0 * h)
            assert abs(q[g] + grad) <= 1e-7 * max(1.0, abs(q[g])), (g, q[g], -grad)


def test_jacobian_matches_finite_differences() -> None:
    dl = _driveline()
    rng = np.random.default_rng(9)
    n = dl.n_dof
    for _ in range(5):
        x = np.array(dl.x0)
        x[:n] += rng.uniform(-3.0, 3.0, n)
        x[n:2 * n] += rng.uniform(-10.0, 10.0, n)
        jac = dl.jacobian(0.0, x, 50.0, 20.0)
        num = np.empty_like(jac)
        for j in range(x.size):
            h = 1e-6 * max(1.0, abs(x[j]))
            xp, xm = x.copy(), x.copy()
            xp[j] += h
            xm[j] -= h
            num[:, j] = (dl.rhs(0.0, xp, 50.0, 20.0) - dl.rhs(0.0, xm, 50.0, 20.0)) / (2.0 * h)
        assert np.max(np.abs(jac - num)) <= 1e-7 * np.max(np.abs(num))


def test_kernel_matches_the_python_reference_and_closes_the_energy_balance() -> None:
    """Fixed rk4 steps on both backends (rounding only, 1e-12), rhs and Jacobian at random
    states (1e-12, 1e-8: dC/dq central differences); dopri5 at rtol 1e-11 closes the energy
    balance (gravity potential in E_el) to 1e-9."""
    from cvj_ros.physics.engine import engine_from_spec
    from cvj_ros.physics.kernel.layout import H_IMBALANCE, build_model
    from cvj_ros.physics.kernel.rhs_nb import jac as kernel_jac
    from cvj_ros.physics.kernel.rhs_nb import rhs as kernel_rhs
    from cvj_ros.physics.load import load_from_spec
    from cvj_ros.physics.simulate import Simulation
    sc = parse_scene(scene(IMB, hooke=True, imb_mid=IMB_MID, method='rk4', duration=0.2))
    kern, ref = Simulation(sc), Simulation(sc, backend='python')
    assert kern.backend == 'kernel', kern.backend_note
    a, b = kern.run(0.2, sample_dt=0.005), ref.run(0.2, sample_dt=0.005)
    for x, y in ((a.position, b.position), (a.velocity, b.velocity), (a.effort, b.effort)):
        assert np.max(np.abs(x - y)) <= 1e-12 * max(1.0, float(np.max(np.abs(y))))
    assert np.max(np.abs(a.energy_residual - b.energy_residual)) <= 1e-12
    dl = _driveline()
    engine = engine_from_spec(sc.engine)
    load = load_from_spec(sc.load, seed=sc.seed, field='load')
    model = build_model(dl, engine=engine, load=load, horizon=sc.duration)
    it = int(model.ip[H_IMBALANCE])
    assert it > 0 and model.ip[it] == 2
    rng = np.random.default_rng(4)
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
        assert np.max(np.abs(J - jref)) <= 1e-8 * np.max(np.abs(jref))
    tr = Simulation(parse_scene(scene(IMB, hooke=True, imb_mid=IMB_MID, duration=0.5))).run(
        0.5, sample_dt=1e-3)
    assert tr.max_energy_residual <= 1e-9


def _order1(tr: Any, angle_col: int, values: np.ndarray, revs: int = 4, m: int = 72) -> complex:
    """Complex order-1 coefficient a_1 - i b_1 over the angle of column ``angle_col``."""
    q = tr.position[:, angle_col]
    q0 = 2.0 * math.pi * math.ceil((q[-1] - 2.0 * math.pi * revs) / (2.0 * math.pi))
    out = 0.0 + 0.0j
    for r in range(revs - 1):
        grid = q0 + 2.0 * math.pi * (r + np.arange(m) / m)
        hm = ordinate_harmonics(np.interp(grid, q, values))
        out += complex(hm.cos_coeffs[0], -hm.sin_coeffs[0])
    return out / (revs - 1)


@pytest.mark.parametrize('me', [0.005, 0.05, 0.5])
def test_order_one_of_an_imbalance_on_the_driving_shaft(me: float) -> None:
    """Imbalance m e on the driving shaft (an inner shaft: the load acts on the driven one)
    of the elastic KAVZ-685 unit. Linearised about the steady state (speed W0), with
    s = i W0 and the forcing -m g e e^{i (phi_1 + angle)} on the driving shaft:

        (J1 s^2 + K1 s + c + d s) X1 - (c + d s) X2 = -m g e e^{i angle}
        -(c + d s) X1 + (J2 s^2 + c + d s) X2 = 0

    speeds s X, spring torque (c + d s)(X1 - X2) (the driving shaft's effort). Neglected:
    the forcing's phase modulation by x1, O(|X1|) relative; bound 0.5 |X1| + 2e-5 (the
    second term for the harmonic analysis of interpolated samples; measured at most
    0.02 |X1| + 5e-6 for m e = 0.005-3 kg m, docs/imperfections.md)."""
    from cvj_ros.physics.simulate import Simulation
    ang = 0.6
    imb = {'mass_kg': me / 0.05, 'radius_m': 0.05, 'angle_deg': math.degrees(ang)}
    tr = Simulation(parse_scene(scene(imb))).run(1.0, sample_dt=2e-4)
    i1, i2 = tr.names.index('drive_shaft'), tr.names.index('driven_shaft')
    s = 1j * W0
    kd = C0 + D0 * s
    a = np.array([[J1 * s * s + K1 * s + kd, -kd], [-kd, J2 * s * s + kd]])
    x1, x2 = np.linalg.solve(a, np.array([-me * GRAVITY * np.exp(1j * ang), 0.0]))
    want = {'speed_in': s * x1, 'speed_out': s * x2, 'torque': kd * (x1 - x2)}
    got = {'speed_in': _order1(tr, i1, tr.velocity[:, i1]),
           'speed_out': _order1(tr, i1, tr.velocity[:, i2]),
           'torque': _order1(tr, i1, tr.effort[:, i1])}
    bound = 0.5 * abs(x1) + 2e-5
    for key, w in want.items():
        assert abs(got[key] - w) <= bound * abs(w), (key, got[key], w, abs(got[key] - w) / abs(w))
