"""Tests of cvj_ros.physics.cosim.CoupledStepper on toy linear drivelines.

The reference is the monolithic linear system (engine law and load inside the
right-hand side) solved in closed form with a matrix exponential.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.linalg

from cvj_ros.errors import LockstepError
from cvj_ros.physics.cosim import CoupledStepper, DrivelineLike
from cvj_ros.physics.solvers import SolverOptionError

# seed 004 machine unit (DESIGN.md section 6): I1, I2, c_y, b_y, M1, omega0, M_c
J1, J2, C_Y, B_Y = 0.128, 0.161, 715.4, 6.35
M1, OMEGA0, M_C = 623.0, 39.0, 107.5
K1 = M1 / OMEGA0          # engine slope magnitude, N m s/rad (M = M1 - K1 omega)
B_LOAD = 2.0              # viscous part of the load, N m s/rad


class TwoMass:
    """Engine inertia J1 - spring/damper - load inertia J2; x = (phi1, w1, phi2, w2)."""

    n_dof = 2
    x0 = np.zeros(4)

    def rhs(self, t, x, T_engine, T_load):
        T_sp = C_Y * (x[0] - x[2]) + B_Y * (x[1] - x[3])
        return np.array([x[1], (T_engine - T_sp) / J1, x[3], (T_sp - T_load) / J2])

    def jacobian(self, t, x, T_engine, T_load):
        return np.array([[0, 1, 0, 0],
                         [-C_Y / J1, -B_Y / J1, C_Y / J1, B_Y / J1],
                         [0, 0, 0, 1],
                         [C_Y / J2, B_Y / J2, -C_Y / J2, -B_Y / J2]], dtype=float)

    def engine_omega(self, x):
        return x[1]

    def load_omega(self, x):
        return x[3]


class OneMass:
    """A single inertia J between engine and load; x = (phi, w)."""

    n_dof = 1
    x0 = np.zeros(2)

    def rhs(self, t, x, T_engine, T_load):
        return np.array([x[1], (T_engine - T_load) / J1])

    def engine_omega(self, x):
        return x[1]

    def load_omega(self, x):
        return x[1]


def engine_torque(w):
    return M1 - K1 * w


def load_torque(w):
    return M_C + B_LOAD * w


def exact_two_mass(t_end: float) -> np.ndarray:
    """Closed form of the monolithic linear system x' = A x + b by an augmented expm."""
    A = TwoMass().jacobian(0, None, 0, 0)
    A[1, 1] -= K1 / J1
    A[3, 3] -= B_LOAD / J2
    b = np.array([0.0, M1 / J1, 0.0, -M_C / J2])
    aug = np.zeros((5, 5))
    aug[:4, :4] = A
    aug[:4, 4] = b
    return (scipy.linalg.expm(aug * t_end) @ np.r_[np.zeros(4), 1.0])[:4]


def run_loop(dl, scheme: str, H: float, t_end: float, **kw) -> CoupledStepper:
    cs = CoupledStepper(dl, scheme=scheme, **kw)
    n = round(t_end / H)
    for k in range(n):
        x = cs.x
        we, wl = dl.engine_omega(x), dl.load_omega(x)
        cs.advance((k + 1) * H, engine_torque(we), load_torque(wl),
                   slope_engine=-K1, slope_load=B_LOAD)
    return cs


def test_toys_satisfy_protocol() -> None:
    assert isinstance(TwoMass(), DrivelineLike)
    assert isinstance(OneMass(), DrivelineLike)


def test_error_versus_exchange_step_per_scheme() -> None:
    """ZOH is first order in H; extrapolation and the linearly implicit scheme beat it."""
    t_end = 0.4
    ref = exact_two_mass(t_end)
    errs: dict[str, list[float]] = {}
    for scheme in ('zoh', 'extrapolate', 'linear_implicit'):
        errs[scheme] = []
        for H in (4e-3, 2e-3, 1e-3):
            cs = run_loop(TwoMass(), scheme, H, t_end, rtol=1e-10, atol=1e-12)
            assert cs.t == pytest.approx(t_end, abs=1e-15)
            errs[scheme].append(float(np.max(np.abs(cs.x - ref))))
    zoh = errs['zoh']
    rates = [math.log2(zoh[i] / zoh[i + 1]) for i in range(2)]
    assert all(0.8 < r < 1.3 for r in rates), (zoh, rates)
    ext = errs['extrapolate']
    assert math.log2(ext[1] / ext[2]) > 1.6, ext  # second order
    for i in range(3):
        assert ext[i] < 0.3 * zoh[i]
        assert errs['linear_implicit'][i] < 1e-3 * zoh[i]
    # the engine law is linear: linear_implicit is exact up to the solver tolerance
    assert max(errs['linear_implicit']) < 1e-7


def test_zoh_unstable_beyond_2J_over_K_linear_implicit_stable() -> None:
    limit = 2 * J1 / (K1 + B_LOAD)   # both torques act on the one inertia
    w_eq = (M1 - M_C) / (K1 + B_LOAD)
    t_end = 60 * limit
    for factor, zoh_stable in ((0.8, True), (1.25, False)):
        H = factor * limit
        zoh = run_loop(OneMass(), 'zoh', H, t_end)
        li = run_loop(OneMass(), 'linear_implicit', H, t_end)
        li_res = run_loop(OneMass(), 'linear_implicit', H, t_end, extrapolate_residual=True)
        assert abs(li_res.x[1] - w_eq) < 1e-6 * w_eq
        dev_zoh = abs(zoh.x[1] - w_eq)
        if zoh_stable:
            assert dev_zoh < 1e-3 * w_eq
        else:
            # amplification |1 - H K/J| = 1.5 per exchange: grows by many decades
            assert dev_zoh > 1e3 * w_eq
        assert abs(li.x[1] - w_eq) < 1e-6 * w_eq


def test_estimated_slope_matches_characteristic_and_stabilises() -> None:
    H = 1.25 * 2 * J1 / (K1 + B_LOAD)
    cs = run_loop(OneMass(), 'linear_implicit', H, 40 * H, slope='estimate')
    K_e, K_l = cs.slopes
    assert K_e == pytest.approx(-K1, rel=1e-6)
    assert K_l == pytest.approx(B_LOAD, rel=1e-6)
    w_eq = (M1 - M_C) / (K1 + B_LOAD)
    assert abs(cs.x[1] - w_eq) < 1e-6 * w_eq


def test_estimated_slope_clipped_to_damping_sign_and_bound() -> None:
    """Samples with an anti-damping trend are clipped to zero slope; steep ones to slope_max."""
    cs = CoupledStepper(OneMass(), scheme='linear_implicit', slope='estimate', slope_max=5.0)
    # engine torque rising with speed (anti-damping for the engine): K_e clipped to 0
    for k in range(4):
        w = cs.x[1]
        cs.advance((k + 1) * 1e-3, 100.0 + 3.0 * w, 50.0 + 50.0 * w)
    K_e, K_l = cs.slopes
    assert K_e == 0.0
    assert K_l == 5.0


def test_rosenbrock_coupled_jacobian_matches_finite_differences() -> None:
    dl = TwoMass()
    cs = CoupledStepper(dl, scheme='linear_implicit', method='rosenbrock', rtol=1e-8, atol=1e-10)
    cs.advance(1e-3, engine_torque(0.0), load_torque(0.0), slope_engine=-K1, slope_load=B_LOAD)
    x = cs.x
    J = cs._jac(cs.t, x)
    f0 = cs._rhs_linear_implicit(cs.t, x)
    J_fd = np.empty((4, 4))
    for j in range(4):
        xp = x.copy()
        xp[j] += 1e-6
        J_fd[:, j] = (cs._rhs_linear_implicit(cs.t, xp) - f0) / 1e-6
    np.testing.assert_allclose(J, J_fd, rtol=1e-5, atol=1e-3)
    # and the loop with the stiff-capable method agrees with the closed form
    cs = run_loop(dl, 'linear_implicit', 2e-3, 0.2, method='rosenbrock', rtol=1e-9, atol=1e-11)
    np.testing.assert_allclose(cs.x, exact_two_mass(0.2), atol=1e-6)


class Stiff(TwoMass):
    """A 1e6 N m/rad spring with 1 N m s/rad between two 0.01 kg m^2 inertias."""

    def rhs(self, t, x, T_engine, T_load):
        T_sp = 1e6 * (x[0] - x[2]) + 1.0 * (x[1] - x[3])
        return np.array([x[1], (T_engine - T_sp) / 0.01, x[3], (T_sp - T_load) / 0.01])

    def jacobian(self, t, x, T_engine, T_load):
        c, d, j = 1e6, 1.0, 0.01
        return np.array([[0, 1, 0, 0], [-c / j, -d / j, c / j, d / j], [0, 0, 0, 1],
                         [c / j, d / j, -c / j, -d / j]], dtype=float)


@pytest.mark.parametrize('method,kw', [('ros2', dict(h=1e-3)),
                                       ('rosenbrock', dict(rtol=1e-6, atol=1e-9)),
                                       ('rodas4', dict(rtol=1e-6, atol=1e-9))])
def test_stiff_spring_at_1ms_exchange(method: str, kw: dict) -> None:
    """DESIGN.md section 8: 1e6 N m/rad at 1 ms exchange, linearly implicit methods."""
    cs = CoupledStepper(Stiff(), scheme='linear_implicit', method=method, **kw)
    for k in range(200):
        cs.advance((k + 1) * 1e-3, 10.0, 0.0)
    # momentum balance: w = T t / (J1 + J2) exactly for a linear integrator
    assert cs.x[1] == pytest.approx(10.0 * 0.2 / 0.02, rel=1e-6)
    # the twist has settled at the static value (T/2) / c (relative mode decays at 100 1/s)
    assert cs.x[0] - cs.x[2] == pytest.approx(5.0 / 1e6, rel=1e-3)
    if method == 'ros2':
        assert cs.stepper.naccept == 200  # one fixed step per exchange, persistent stepper
    else:
        assert cs.stepper.naccept < 20 * 200


def test_persistent_stepper_one_step_per_short_exchange() -> None:
    """Exchange step far below the natural step: one step per exchange, h proposal kept."""
    dl = TwoMass()
    cs = CoupledStepper(dl, scheme='zoh', rtol=1e-6, atol=1e-9)
    stepper = cs.stepper
    H = 1e-4
    for k in range(300):
        cs.advance((k + 1) * H, 100.0, 50.0)
    assert cs.stepper is stepper
    assert stepper.naccept <= 300 + 10 and stepper.nreject <= 5
    assert stepper.h > 2 * H


def test_bad_input_raises_named_errors() -> None:
    with pytest.raises(SolverOptionError, match='^scheme:'):
        CoupledStepper(OneMass(), scheme='magic')
    cs = CoupledStepper(OneMass())
    with pytest.raises(LockstepError, match='^T_load:'):
        cs.advance(1e-3, 1.0, math.nan)
    with pytest.raises(LockstepError, match='^t_next:'):
        cs.advance(0.0, 1.0, 1.0)


def test_residual_extrapolation_second_order_for_time_varying_load() -> None:
    """Load M_c + B w + A sin(omega_L t): the slope covers B w, the sine is the residual.
    Held, it gives first order in H; extrapolated, second order and more accurate."""
    amp, om = 20.0, 40.0

    def load(t, w):
        return M_C + B_LOAD * w + amp * math.sin(om * t)

    # reference: monolithic system with the sine inside the right-hand side
    from scipy.integrate import solve_ivp

    dl = TwoMass()

    def mono(t, x):
        return dl.rhs(t, x, engine_torque(x[1]), load(t, x[3]))

    t_end = 0.4
    ref = solve_ivp(mono, (0, t_end), np.zeros(4), method='DOP853', rtol=1e-12,
                    atol=1e-12).y[:, -1]
    errs: dict[bool, list[float]] = {False: [], True: []}
    for extra in (False, True):
        for H in (2e-3, 1e-3):
            cs = CoupledStepper(dl, scheme='linear_implicit', rtol=1e-10, atol=1e-12,
                                extrapolate_residual=extra)
            for k in range(round(t_end / H)):
                x = cs.x
                t = k * H
                cs.advance((k + 1) * H, engine_torque(x[1]), load(t, x[3]),
                           slope_engine=-K1, slope_load=B_LOAD)
            errs[extra].append(float(np.max(np.abs(cs.x - ref))))
    assert math.log2(errs[False][0] / errs[False][1]) == pytest.approx(1.0, abs=0.3)
    assert math.log2(errs[True][0] / errs[True][1]) > 1.6
    assert errs[True][1] < 0.1 * errs[False][1]
