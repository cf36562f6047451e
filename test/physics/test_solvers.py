"""Tests of cvj_ros.physics.solvers against closed forms, scipy and each other."""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from cvj_ros.errors import SolverError
from cvj_ros.physics.solvers import METHODS, SolverOptionError, make_stepper

ADAPTIVE = ['dopri5', 'dop853', 'rosenbrock', 'rodas4', 'rodas3']
ROSENBROCK = ['rosenbrock', 'rodas4', 'rodas3', 'ros2']
FIXED = ['rk4', 'ros2']


def oscillator(t: float, y: np.ndarray) -> np.ndarray:
    """Harmonic oscillator y'' = -y: y = (cos t, -sin t) from (1, 0)."""
    return np.array([y[1], -y[0]])


def oscillator_jac(t: float, y: np.ndarray) -> np.ndarray:
    return np.array([[0.0, 1.0], [-1.0, 0.0]])


def van_der_pol(t: float, y: np.ndarray) -> np.ndarray:
    mu = 1.0
    return np.array([y[1], mu * (1 - y[0] ** 2) * y[1] - y[0]])


def fixed_error(method: str, h: float, fun, y0, t_end: float, exact, **kw) -> float:
    st = make_stepper(method, fun, 0.0, y0, h=h, **kw)
    return float(np.max(np.abs(st.advance_to(t_end) - exact)))


@pytest.mark.parametrize('method,order', [('rk4', 4), ('ros2', 2)])
def test_fixed_step_observed_order_on_oscillator(method: str, order: int) -> None:
    exact = np.array([math.cos(2.0), -math.sin(2.0)])
    errs = [fixed_error(method, h, oscillator, [1.0, 0.0], 2.0, exact, jac=oscillator_jac)
            for h in (0.1, 0.05, 0.025)]
    rates = [math.log2(errs[i] / errs[i + 1]) for i in range(2)]
    assert all(abs(r - order) < 0.25 for r in rates), rates


@pytest.mark.parametrize('method,order', [('rk4', 4), ('ros2', 2)])
def test_fixed_step_observed_order_on_decay(method: str, order: int) -> None:
    exact = np.array([math.exp(-1.0)])
    errs = [fixed_error(method, h, lambda t, y: -y, [1.0], 1.0, exact) for h in (0.1, 0.05, 0.025)]
    rates = [math.log2(errs[i] / errs[i + 1]) for i in range(2)]
    assert all(abs(r - order) < 0.25 for r in rates), rates


@pytest.mark.parametrize('method', ADAPTIVE)
def test_adaptive_tolerance_proportionality_oscillator(method: str) -> None:
    """Error shrinks as rtol tightens, roughly in proportion (global error ~ tol)."""
    exact = np.array([math.cos(10.0), -math.sin(10.0)])
    errs = []
    for rtol in (1e-4, 1e-6, 1e-8):
        st = make_stepper(method, oscillator, 0.0, [1.0, 0.0], rtol=rtol, atol=rtol * 1e-2,
                          jac=oscillator_jac)
        errs.append(float(np.max(np.abs(st.advance_to(10.0) - exact))))
    assert errs[0] > errs[1] > errs[2]
    assert errs[2] < 1e-6
    # two decades of tolerance give at least ~1.2 decades of error
    assert errs[0] / errs[2] > 10 ** 2.4


@pytest.mark.parametrize('method', ADAPTIVE)
def test_adaptive_observed_order_on_forced_decay(method: str) -> None:
    """Observed order on y' = -y + sin t (closed form): constant steps are forced
    via h = max_step and a loose tol (no rejections); halving h divides the error by 2^p."""
    order = {'dopri5': 5, 'dop853': 8, 'rosenbrock': 5, 'rodas4': 4, 'rodas3': 3}[method]

    def f(t, y):
        return -y + math.sin(t)

    def exact(t):  # y(0) = 1
        return 1.5 * math.exp(-t) + 0.5 * (math.sin(t) - math.cos(t))

    hs = (0.2, 0.1) if method != 'dop853' else (1.0, 0.5)
    errs = []
    for h in hs:
        st = make_stepper(method, f, 0.0, [1.0], rtol=1.0, atol=1.0, h=h, max_step=h)
        y = st.advance_to(4.0)
        assert st.nreject == 0
        errs.append(abs(y[0] - exact(4.0)))
    rate = math.log2(errs[0] / errs[1])
    assert rate == pytest.approx(order, abs=0.6), (errs, rate)


@pytest.mark.parametrize('method', ADAPTIVE + FIXED)
def test_matches_scipy_on_van_der_pol(method: str) -> None:
    ref = solve_ivp(van_der_pol, (0.0, 5.0), [2.0, 0.0], method='DOP853', rtol=1e-12, atol=1e-12)
    kw = dict(h=1e-3) if method in FIXED else dict(rtol=1e-10, atol=1e-12)
    # ros2 takes the finite-difference Jacobian path, the other Rosenbrock methods the analytic one
    jac = None if method == 'ros2' else (
        lambda t, y: np.array([[0.0, 1.0], [-2.0 * y[0] * y[1] - 1.0, 1.0 - y[0] ** 2]]))
    st = make_stepper(method, van_der_pol, 0.0, [2.0, 0.0], jac=jac, autonomous=True, **kw)
    y = st.advance_to(5.0)
    tol = {'ros2': 1e-4, 'rk4': 1e-9}.get(method, 2e-8)
    np.testing.assert_allclose(y, ref.y[:, -1], atol=tol)


@pytest.mark.parametrize('method', ADAPTIVE + FIXED)
def test_advance_to_lands_exactly_and_keeps_step(method: str) -> None:
    # RODAS3 (order 3) at rtol 1e-5: its first step (HINIT) is then > 1 ms as the others'
    kw = (dict(h=0.01) if method in FIXED else dict(rtol=1e-5, atol=1e-7) if method == 'rodas3'
          else dict(rtol=1e-8, atol=1e-10))
    exchange = 0.001  # much smaller than the natural step
    st = make_stepper(method, oscillator, 0.0, [1.0, 0.0], jac=oscillator_jac, **kw)
    for k in range(1, 201):
        y = st.advance_to(k * exchange)
        assert st.t == k * exchange
    tol = 1e-5 if method in ('ros2', 'rodas3') else 1e-7
    assert np.max(np.abs(y - [math.cos(0.2), -math.sin(0.2)])) < tol
    if method in ADAPTIVE:
        # the controller proposal survives the clipped steps: larger than the exchange step
        assert st.h > 5 * exchange
        # one step per exchange, no rejections
        assert st.naccept == 200 and st.nreject == 0


@pytest.mark.parametrize('method', ADAPTIVE)
def test_step_persistence_beats_restarting(method: str) -> None:
    """Calling advance_to on long intervals costs fewer steps than a fresh solver each time."""
    kw = dict(rtol=1e-8, atol=1e-10, jac=oscillator_jac)
    st = make_stepper(method, oscillator, 0.0, [1.0, 0.0], **kw)
    for k in range(1, 21):
        st.advance_to(0.5 * k)
    persistent = st.naccept + st.nreject
    fresh_steps = 0
    y, t = np.array([1.0, 0.0]), 0.0
    for k in range(1, 21):
        fresh = make_stepper(method, oscillator, t, y, **kw)
        y = fresh.advance_to(0.5 * k)
        t = 0.5 * k
        fresh_steps += fresh.naccept + fresh.nreject
    assert persistent < fresh_steps


@pytest.mark.parametrize('method,tol', [('dopri5', 1e-7), ('dop853', 1e-9), ('rosenbrock', 1e-5),
                                        ('rodas4', 1e-5), ('rodas3', 1e-5),
                                        ('rk4', 1e-5), ('ros2', 1e-3)])
def test_dense_output_inside_last_step(method: str, tol: float) -> None:
    kw = (dict(h=0.1 if method == 'rk4' else 0.01) if method in FIXED
          else dict(rtol=1e-9, atol=1e-12))
    st = make_stepper(method, oscillator, 0.0, [1.0, 0.0], jac=oscillator_jac, **kw)
    st.advance_to(3.0)
    np.testing.assert_array_equal(st.dense(st.t), st.y)
    np.testing.assert_allclose(st.dense(st.t_old), st.y_old, atol=1e-14)
    assert st.t_old < st.t
    for x in (0.0, 0.25, 0.5, 0.9, 1.0):
        t = st.t_old + x * (st.t - st.t_old)
        np.testing.assert_allclose(st.dense(t), [math.cos(t), -math.sin(t)], atol=tol)
    with pytest.raises(SolverOptionError, match='^t:'):
        st.dense(st.t + 1.0)


@pytest.mark.parametrize('method,local_order', [('dopri5', 5), ('rosenbrock', 5), ('rodas4', 4),
                                                ('rodas3', 4)])
def test_dense_output_local_order(method: str, local_order: int) -> None:
    """Interpolation error inside one step falls at least like h^(p+1) for a dense
    output of order p (4 for dopri5 and RODAS5P, 3 for the Hermite of RODAS4)."""
    errs = []
    for h in (0.4, 0.2, 0.1):
        st = make_stepper(method, oscillator, 0.0, [1.0, 0.0], h=h, max_step=h, rtol=1, atol=1,
                          jac=oscillator_jac)
        st.advance_to(h)
        errs.append(max(abs(st.dense(x * h)[0] - math.cos(x * h)) for x in (0.2, 0.5, 0.7)))
    assert math.log2(errs[1] / errs[2]) > local_order - 0.3, errs


def test_rosenbrock_stiff_decay_few_steps() -> None:
    """y' = -1e6 (y - cos t): L-stable Rosenbrock takes few steps; dopri5 would need ~1e6/3."""
    lam = 1e6

    def f(t, y):
        return -lam * (y - np.cos(t)) - np.sin(t)

    st = make_stepper('rosenbrock', f, 0.0, [2.0], rtol=1e-6, atol=1e-9,
                      jac=lambda t, y: np.array([[-lam]]))
    y = st.advance_to(1.0)
    assert abs(y[0] - math.cos(1.0)) < 1e-6
    assert st.naccept + st.nreject < 200
    # dopri5 stability limit h < 3.3/lambda: check it is forced into tiny steps
    st5 = make_stepper('dopri5', f, 0.0, [2.0], rtol=1e-6, atol=1e-9)
    st5.advance_to(1e-3)
    assert st5.naccept > 0.5 * 1e-3 * lam / 3.3


def test_rosenbrock_linear_stiff_system_order_and_fd_jacobian() -> None:
    """Linear stiff system with eigenvalues -1 and -1e4, closed form; FD Jacobian path."""
    A = np.array([[-1.0, 0.0], [1e4 - 1.0, -1e4]])  # eigen -1 (v=(1,1)), -1e4 (v=(0,1))

    def f(t, y):
        return A @ y

    y0 = np.array([1.0, 2.0])
    # y = e^{-t} (1,1) + e^{-1e4 t} (0,1)
    exact = np.array([math.exp(-1.0), math.exp(-1.0)])
    st = make_stepper('rosenbrock', f, 0.0, y0, rtol=1e-8, atol=1e-10, autonomous=True)
    y = st.advance_to(1.0)
    np.testing.assert_allclose(y, exact, rtol=1e-6)
    assert st.njev_fd == st.njev > 0
    # fixed-step ROS2 at h = 0.01 (h*lambda = -100): stable, 2nd order on the slow mode
    errs = []
    for h in (0.02, 0.01):
        s2 = make_stepper('ros2', f, 0.0, y0, h=h, jac=lambda t, y: A, constant_jac=True,
                          autonomous=True)
        errs.append(np.max(np.abs(s2.advance_to(1.0) - exact)))
        assert s2.nlu == 1
    assert math.log2(errs[0] / errs[1]) == pytest.approx(2.0, abs=0.3)


@pytest.mark.parametrize('degree', [0, 1, 2, 3, 4])
def test_rk4_exact_for_polynomials(degree: int) -> None:
    """y' = p'(t) with deg p <= 4: RK4 (Simpson in t) is exact to rounding."""
    coef = np.arange(1.0, degree + 2.0)

    def p(t):
        return sum(c * t ** k for k, c in enumerate(coef))

    def dp(t, y):
        return np.array([sum(k * c * t ** (k - 1) for k, c in enumerate(coef) if k > 0)])

    st = make_stepper('rk4', dp, 0.0, [p(0.0)], h=0.37)
    y = st.advance_to(2.0)
    assert y[0] == pytest.approx(p(2.0), rel=1e-13, abs=1e-13)


@pytest.mark.parametrize('method', list(METHODS))
def test_nan_raises_solver_error_with_time_and_index(method: str) -> None:
    def f(t, y):
        out = -y.copy()
        if t > 0.5:
            out[1] = math.nan
        return out

    kw = dict(h=0.01) if method in FIXED else {}
    st = make_stepper(method, f, 0.0, [1.0, 1.0], jac=lambda t, y: -np.eye(2), **kw)
    # linearly implicit methods mix components in the solve: any index may show the NaN
    index = '1' if method in ('dopri5', 'dop853', 'rk4') else r'\d'
    with pytest.raises(SolverError, match=rf'^y\[{index}\]: non-finite .* t=') as info:
        st.advance_to(1.0)
    assert not isinstance(info.value, SolverOptionError)


def test_restart_keeps_step_and_drops_fsal() -> None:
    u = {'value': 1.0}

    def f(t, y):
        return np.array([u['value']])

    st = make_stepper('dopri5', f, 0.0, [0.0], rtol=1e-8, atol=1e-10)
    st.advance_to(1.0)
    h = st.h
    u['value'] = -1.0
    st.restart()
    assert st.h == h
    y = st.advance_to(2.0)
    assert y[0] == pytest.approx(0.0, abs=1e-10)


def test_bad_options_raise_named_errors() -> None:
    with pytest.raises(SolverOptionError, match='^method:'):
        make_stepper('euler', oscillator, 0.0, [1.0, 0.0])
    with pytest.raises(SolverOptionError, match='^h:'):
        make_stepper('rk4', oscillator, 0.0, [1.0, 0.0])
    with pytest.raises(SolverOptionError, match='^rtol:'):
        make_stepper('dopri5', oscillator, 0.0, [1.0, 0.0], rtol=-1.0)
    with pytest.raises(SolverOptionError, match=r'^y0\[1\]:'):
        make_stepper('dopri5', oscillator, 0.0, [1.0, math.inf])
    st = make_stepper('dopri5', oscillator, 0.0, [1.0, 0.0])
    st.advance_to(1.0)
    with pytest.raises(SolverOptionError, match='^t_end:'):
        st.advance_to(0.5)


@pytest.mark.parametrize('method,order', [('rosenbrock', 5), ('rodas4', 4), ('rodas3', 3)])
def test_rosenbrock_order_on_linear_stiff_system(method: str, order: int) -> None:
    """Forced constant steps h >> 1/|lambda_fast|: the order holds on the slow mode
    (no order reduction on this linear stiff problem)."""
    A = np.array([[-1.0, 0.0], [1e4 - 1.0, -1e4]])
    exact = np.array([math.exp(-2.0), math.exp(-2.0)])
    errs = []
    for h in (0.2, 0.1):
        st = make_stepper(method, lambda t, y: A @ y, 0.0, [1.0, 2.0], rtol=1.0, atol=1.0,
                          h=h, max_step=h, jac=lambda t, y: A, autonomous=True)
        errs.append(np.max(np.abs(st.advance_to(2.0) - exact)))
        assert st.nreject == 0
    assert math.log2(errs[0] / errs[1]) == pytest.approx(order, abs=0.9), errs


@pytest.mark.parametrize('method', ROSENBROCK)
def test_rosenbrock_stability_function_is_l_stable(method: str) -> None:
    """One step on y' = lambda y gives R(z), z = h lambda: |R| <= 1 on the left half
    plane (A-stable) and R -> 0 as z -> -inf (L-stable), sampled."""
    def R(z: float) -> float:
        lam = z  # h = 1
        st = make_stepper(method, lambda t, y: lam * y, 0.0, [1.0], h=1.0,
                          max_step=1.0, rtol=1e6, atol=1e6, jac=lambda t, y: np.array([[lam]]),
                          autonomous=True, constant_jac=True)
        return st.advance_to(1.0)[0]

    # complex z through the equivalent real 2x2 system
    def R_complex(z: complex) -> float:
        a, b = z.real, z.imag
        M = np.array([[a, -b], [b, a]])
        st = make_stepper(method, lambda t, y: M @ y, 0.0, [1.0, 0.0], h=1.0, max_step=1.0,
                          rtol=1e6, atol=1e6, jac=lambda t, y: M, autonomous=True)
        y = st.advance_to(1.0)
        return math.hypot(y[0], y[1])

    for x in (-1e-3, -0.5, -2.0, -10.0, -1e3, -1e6):
        assert abs(R(x)) <= 1.0 + 1e-12
    assert abs(R(-1e9)) < 1e-6
    for z in [complex(-r * math.cos(th), r * math.sin(th))
              for r in (0.1, 1.0, 3.0, 10.0, 100.0, 1e4)
              for th in np.linspace(0.0, math.pi / 2, 7)]:
        assert R_complex(z) <= 1.0 + 1e-9, z


def test_blow_up_raises_solver_error() -> None:
    """y' = y^2, y(0) = 1 has a pole at t = 1: the solver stops with a clear error."""
    st = make_stepper('dopri5', lambda t, y: y * y, 0.0, [1.0], rtol=1e-8, atol=1e-10)
    with pytest.raises(SolverError, match=r'^(t: step size underflow at t=1\.0.*y\[0\]=|y\[0\]: )'):
        st.advance_to(2.0)
    assert 0.99 < st.t < 1.01


@pytest.mark.parametrize('method', ADAPTIVE + FIXED)
def test_sample_dense_matches_closed_form_without_shortening_steps(method: str) -> None:
    from cvj_ros.physics.solvers import sample_dense

    kw = (dict(h=0.05 if method == 'rk4' else 0.002) if method in FIXED
          else dict(rtol=1e-6, atol=1e-9) if method == 'rodas3'   # order 3: looser
          else dict(rtol=1e-9, atol=1e-12))
    t_eval = np.linspace(0.0, 5.0, 501)  # samples 10 ms apart
    st = make_stepper(method, oscillator, 0.0, [1.0, 0.0], jac=oscillator_jac, autonomous=True,
                      constant_jac=method == 'ros2', **kw)
    ys = sample_dense(st, t_eval)
    exact = np.column_stack([np.cos(t_eval), -np.sin(t_eval)])
    tol = {'rk4': 1e-5, 'ros2': 1e-4, 'rosenbrock': 1e-6, 'rodas4': 1e-6,
           'rodas3': 1e-4}.get(method, 1e-7)
    np.testing.assert_allclose(ys, exact, atol=tol)
    assert st.t_old < 5.0 <= st.t
    if method in ADAPTIVE:
        # far fewer steps than samples: the samples did not cut the steps
        assert st.naccept < 0.6 * t_eval.size
    with pytest.raises(SolverOptionError, match='^t_eval:'):
        sample_dense(st, [st.t_old - 1.0])
    # sample by sample gives the same values
    st2 = make_stepper(method, oscillator, 0.0, [1.0, 0.0], jac=oscillator_jac, autonomous=True,
                       constant_jac=method == 'ros2', **kw)
    one_by_one = np.array([sample_dense(st2, [t])[0] for t in t_eval])
    np.testing.assert_allclose(one_by_one, ys, rtol=0, atol=1e-14)


@pytest.mark.parametrize('method', ROSENBROCK)
def test_rosenbrock_time_derivative_matches_autonomized_system(method: str) -> None:
    """The f_t terms of a non-autonomous Rosenbrock step equal the same method on the
    autonomized system (y, t)' = (f(t, y), 1) with its exact Jacobian, step for step."""
    def f(t, y):
        return np.array([-y[0] + math.sin(3 * t)])

    def g(t, z):
        return np.array([-z[0] + math.sin(3 * z[1]), 1.0])

    def g_jac(t, z):
        return np.array([[-1.0, 3 * math.cos(3 * z[1])], [0.0, 0.0]])

    kw = dict(h=0.01) if method == 'ros2' else dict(h=0.05, max_step=0.05, rtol=1.0, atol=1.0)
    a = make_stepper(method, f, 0.0, [1.0], jac=lambda t, y: np.array([[-1.0]]), **kw)
    b = make_stepper(method, g, 0.0, [1.0, 0.0], jac=g_jac, autonomous=True, **kw)
    ya = a.advance_to(2.0)
    yb = b.advance_to(2.0)
    assert a.naccept == b.naccept
    assert ya[0] == pytest.approx(yb[0], abs=1e-9)
    exact = 1.3 * math.exp(-2.0) + (math.sin(6.0) - 3 * math.cos(6.0)) / 10
    # global error of 40 steps of 0.05 s: order 2 (ROS2, h = 0.01), 3 (RODAS3), 4-5
    assert abs(ya[0] - exact) < {'ros2': 1e-4, 'rodas3': 1e-5}.get(method, 1e-6)


@pytest.mark.parametrize('method', list(METHODS))
def test_every_method_satisfies_the_stepper_protocol(method: str) -> None:
    from cvj_ros.physics.solvers import Stepper

    st = make_stepper(method, oscillator, 0.0, [1.0, 0.0], h=0.1, jac=oscillator_jac)
    assert isinstance(st, Stepper)
    st.advance_to(0.35)
    stats = st.stats()
    assert stats['method'] == method and stats['t'] == 0.35
    assert stats['naccept'] == st.naccept > 0 and stats['nfev'] == st.nfev > 0


def test_dop853_error_estimate_ignores_unfilled_dense_rows() -> None:
    """DOP853's stage array holds 3 dense-output rows that a step does not fill; its error
    estimate gives them zero weight. Stale memory there (NaN left by earlier work in the
    process) once made every step non-finite (0 * NaN): fill them with NaN and step."""
    st = make_stepper('dop853', oscillator, 0.0, [1.0, 0.0], rtol=1e-6, atol=1e-8)
    st._KE[:] = np.nan
    y = st.advance_to(1.0)
    assert np.allclose(y, [math.cos(1.0), -math.sin(1.0)], atol=1e-5)   # 10x rtol-scale margin



@pytest.mark.parametrize('method', ['rodas3', 'rodas4', 'rosenbrock'])
def test_ft_window_keeps_f_t_inside_a_segment_before_a_jump(method: str) -> None:
    """y' = y + c(t), c = t jumping to 1e3 at t = 1 (a command row that jumps, the new value
    from 1 on): with ``ft_window`` = (0, 1) no evaluation lies at or beyond 1 (f_t one-sided
    within eps^(1/3) of the end; a stage at t + h = 1 and f at the end take the last float
    before 1, the inputs' left limit), the run matches y = 2 e^t - t - 1 at the tolerance
    and no step is rejected: the jump never enters the error estimate, so the last step
    lands on 1 at its natural size (measured 227 / 38 / 11 steps for rodas3 / rodas4 /
    RODAS5P, last step 1.3e-3 / 1.5e-2 / 9.3e-2 s; with the row's value at t + h = 1 they
    crept to it with 279 / 94 / 70 steps, 27-31 rejected, the last ~1e-10 s; with the
    central f_t, which straddles the jump, 375 / 308 / 121)."""
    def run(window):
        seen = []

        def f(t, y):
            seen.append(t)
            return y + (t if t < 1.0 else 1e3)
        st = make_stepper(method, f, 0.0, np.array([1.0]), rtol=1e-8, atol=1e-10)
        st.ft_window = window
        steps = 0
        while st.t < 1.0 and steps < 100000:
            st.step(1.0)
            steps += 1
        return steps, st, max(seen)

    n_win, st, t_max = run((0.0, 1.0))
    n_central, _, t_central = run(None)
    assert t_max < 1.0 and t_central > 1.0
    assert float(st.y[0]) == pytest.approx(2.0 * math.e - 2.0, rel=1e-6)
    assert st.nreject == 0 and st.t - st.t_old > 1e-4
    # the last step's dense output takes f's left limit at its end, not the jump
    tm = 0.5 * (st.t_old + st.t)
    assert float(st.dense(tm)[0]) == pytest.approx(2.0 * math.exp(tm) - tm - 1.0, rel=1e-6)
    assert n_central > n_win
