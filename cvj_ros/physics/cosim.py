"""Exchange coupling for the lockstep loop: a persistent stepper over a driveline
whose engine and load torques arrive only at exchange points t_k.

The coupling node integrates every inertia and spring itself; the torque sources
(engine node, load node) answer once per exchange step H with T_k = T(t_k,
omega_k, phi_k) and optionally their slope K = dT/domega. Between exchanges the
torque must be *modelled*; the schemes:

``zoh``
    T(t) = T_k, held over [t_k, t_k + H]. First order in H. It is an explicit
    feedback: write the torque's speed dependence as a damping K (engine:
    K = -dT_engine/domega, load: K = +dT_load/domega; K > 0 damps) acting on
    the inertia J it drives. Held over the step, the speed error obeys
    J de/dt = -K e_k, so the exchange map is e_{k+1} = (1 - H K / J) e_k
    (explicit Euler on J de/dt = -K e). It is stable only for
    |1 - H K/J| <= 1, i.e. H < 2 J / K, and beyond H = J/K it already
    overshoots and oscillates. A steep source (large K) or a small inertia
    forces a tiny exchange step.
``extrapolate``
    T(t) = T_k + (T_k - T_{k-1}) (t - t_k) / (t_k - t_{k-1}): linear
    extrapolation in time from the last two exchanges. Second order in H for
    smooth torques; still explicit, so still limited to H ~ J/K.
``linear_implicit``
    T(omega) = T_k + K (omega - omega_k) inside the step, with omega the speed
    where the torque acts, integrated by the stepper together with the
    driveline, so the slope part of the feedback is implicit: exact for a
    linear torque-speed characteristic (Davidbaev et al. 2023, eq. 3.23: M = M1 - K1 omega)
    and stable for any H when K is damping. K comes from the source's reported
    slope (``slope='reported'``: the slope_engine / slope_load arguments) or is
    estimated by least squares from the recent (omega_k, T_k) samples
    (``slope='estimate'``), clipped to the damping sign and to |K| <= slope_max
    so an estimate from noisy samples can never destabilise the loop.

Sign conventions (docs/contracts.md): engine torque drives the crank
(positive along positive rotation); load torque *resists* on the output shaft.
"""
from __future__ import annotations

import math
from collections import deque
from typing import Protocol, runtime_checkable

import numpy as np

from cvj_ros.errors import LockstepError
from cvj_ros.physics.fixed_order import dot
# the Python steppers (solvers.py) only for backend='python': importing them loads
# scipy.integrate and scipy.linalg (~0.3 s of every node process's start-up)
from cvj_ros.physics.stepper_base import SolverOptionError

__all__ = ['SCHEMES', 'DrivelineLike', 'CoupledStepper']

SCHEMES = ('zoh', 'extrapolate', 'linear_implicit')


@runtime_checkable
class DrivelineLike(Protocol):
    """What CoupledStepper needs from a driveline (cvj_ros.physics.driveline.Driveline).

    ``jacobian(t, x, T_engine, T_load) -> (n, n)`` is optional (used by the
    Rosenbrock methods; finite differences otherwise).
    """

    n_dof: int
    x0: np.ndarray

    def rhs(self, t: float, x: np.ndarray, T_engine: float, T_load: float) -> np.ndarray: ...

    def engine_omega(self, x: np.ndarray) -> float: ...

    def load_omega(self, x: np.ndarray) -> float: ...


class CoupledStepper:
    """Persistent integration of a driveline between torque exchanges.

    Args:
        driveline: a DrivelineLike.
        scheme: 'zoh' | 'extrapolate' | 'linear_implicit' (module docstring).
        method: solver name (cvj_ros.physics.solvers.METHODS); one stepper is
            created here and reused for the whole run (never one per exchange).
        t0: initial time (s). x0: initial state (default driveline.x0).
        rtol, atol, h, max_step, constant_jac: passed to make_stepper
            (h is required for the fixed-step methods 'rk4' and 'ros2').
        autonomous: the coupled right-hand side has no explicit time dependence
            (lets Rosenbrock methods skip the f_t difference, 2 fev per step).
            Default: True for 'zoh' and 'linear_implicit' (the driveline is
            time-invariant and the torques are frozen functions of the state),
            False for 'extrapolate' (torques ramp in time).
        slope: 'reported' (use the slopes passed to advance) or 'estimate'
            (least squares over the last ``slope_window`` exchanges).
        slope_max: bound on |K| (N m s/rad) for estimated slopes.
        extrapolate_residual: 'linear_implicit' only: also extrapolate in time the
            part of the torque the slope does not explain, R = T - K omega (firing
            ripple, load over time or shaft angle): T = T_k + K (omega - omega_k)
            + (R_k - R_{k-1}) (t - t_k) / (t_k - t_{k-1}). Second order for
            time-varying torques; explicit in that part, so keep H well inside the
            extrapolation's stability limit when the slope is inexact.
        backend: 'auto' (default: the compiled kernel when the driveline is a
            :class:`~cvj_ros.physics.driveline.Driveline` it covers, else Python),
            'kernel' (SolverOptionError if not covered) or 'python' (the readable
            reference: driveline.rhs with the Python steppers). The kernel applies the
            same torque law through its input block (kernel.layout.set_torque_inputs):
            T = T_k + rate (t - t_k) + K (omega - omega_k).
    """

    def __init__(self, driveline: DrivelineLike, *, scheme: str = 'zoh', method: str = 'dopri5',
                 t0: float = 0.0, x0: np.ndarray | None = None, rtol: float = 1e-6,
                 atol: float = 1e-9, h: float | None = None, max_step: float = math.inf,
                 autonomous: bool | None = None, constant_jac: bool = False,
                 slope: str = 'reported', slope_window: int = 6, slope_max: float = 1e6,
                 extrapolate_residual: bool = False, backend: str = 'auto') -> None:
        if scheme not in SCHEMES:
            raise SolverOptionError('scheme', f'unknown coupling scheme {scheme!r}; choose one of '
                                    f'{", ".join(SCHEMES)}')
        if slope not in ('reported', 'estimate'):
            raise SolverOptionError('slope', f"must be 'reported' or 'estimate', got {slope!r}")
        if not (isinstance(slope_window, int) and slope_window >= 2):
            raise SolverOptionError('slope_window',
                                    f'must be an integer >= 2, got {slope_window!r}')
        if not (slope_max > 0):
            raise SolverOptionError('slope_max', f'must be > 0, got {slope_max!r}')
        self.driveline = driveline
        self.scheme = scheme
        self.extrapolate_residual = bool(extrapolate_residual) and scheme == 'linear_implicit'
        self._prev: tuple[float, float, float, float, float] | None = None  # t, we, Te, wl, Tl
        self.slope_mode = slope
        self.slope_max = float(slope_max)
        x_start = np.array(driveline.x0 if x0 is None else x0, dtype=float)
        # exchange inputs for the current step (read by the right-hand side)
        self._tk = float(t0)
        self._Te = 0.0
        self._Tl = 0.0
        self._rate_e = 0.0   # dT_engine/dt (extrapolate), N m/s
        self._rate_l = 0.0
        self._Ke = 0.0       # dT_engine/domega (linear_implicit), N m s/rad
        self._Kl = 0.0
        self._we = 0.0       # omega at t_k where engine / load act, rad/s
        self._wl = 0.0
        self._history: deque = deque(maxlen=slope_window)  # (t, we, Te, wl, Tl)
        fun = {'zoh': self._rhs_zoh, 'extrapolate': self._rhs_extrapolate,
               'linear_implicit': self._rhs_linear_implicit}[scheme]
        jac = self._jac if hasattr(driveline, 'jacobian') else None
        if autonomous is None:
            autonomous = scheme != 'extrapolate' and not self.extrapolate_residual
        self._omega_grad: dict[int, np.ndarray] = {}
        self.backend_fallback: str | None = None   # why 'auto' ran python, one line
        self.model = self._kernel_model(driveline, backend)
        self.backend = 'python' if self.model is None else 'kernel'
        if self.model is not None:
            from cvj_ros.physics.kernel import rhs_nb
            from cvj_ros.physics.kernel.layout import H_INPUT_F, IN_TE, IN_TK, IN_TL
            from cvj_ros.physics.kernel.stepper import KernelStepper
            # zoh input block: the rates and slopes stay 0 (set_torque_inputs' layout)
            self._inputs = self.model.fp
            o = int(self.model.ip[H_INPUT_F])
            self._in_tk, self._in_te, self._in_tl = o + IN_TK, o + IN_TE, o + IN_TL
            kw = dict(rtol=rtol, atol=atol, h=h, max_step=max_step, jac=rhs_nb.jac,
                      autonomous=autonomous, constant_jac=constant_jac)
            self.stepper = KernelStepper(method, rhs_nb.rhs, self.model.ip, self.model.fp, t0,
                                         x_start, **kw)
            # Load (or compile) the compiled entry point now, on a throwaway copy, so the
            # first exchange of a running loop does not pay it (~0.5 s warm, 10+ s cold).
            warm = KernelStepper(method, rhs_nb.rhs, self.model.ip, self.model.fp.copy(), t0,
                                 x_start, **kw)
            warm.advance_to(t0 + 1e-6)
            self.compile_seconds = warm.compile_seconds
        else:
            from cvj_ros.physics.solvers import make_stepper
            self.stepper = make_stepper(method, fun, t0, x_start, rtol=rtol, atol=atol, h=h,
                                        jac=jac, max_step=max_step, autonomous=autonomous,
                                        constant_jac=constant_jac)
        self.n_exchanges = 0

    def _kernel_model(self, driveline: DrivelineLike, backend: str):
        """ModelData of the driveline with input-block torques, or None for Python."""
        if backend not in ('auto', 'kernel', 'python'):
            raise SolverOptionError('backend', f"must be 'auto', 'kernel' or 'python', got {backend!r}")
        if backend == 'python':
            return None
        from cvj_ros.physics.driveline import Driveline
        # a vehicle scene's TreeDriveline: engine torque from the input block, tyres inside
        if not (isinstance(driveline, Driveline) or getattr(driveline, 'is_tree', False)):
            if backend == 'kernel':
                raise SolverOptionError('backend', 'the compiled kernel needs a Driveline')
            self.backend_fallback = f'{type(driveline).__name__} is not a Driveline'
            return None
        from cvj_ros.physics.kernel.layout import build_model
        try:
            return build_model(driveline)
        except NotImplementedError as exc:
            if backend == 'kernel':
                raise SolverOptionError('backend', str(exc)) from None
            self.backend_fallback = str(exc)
            return None

    def _set_kernel_inputs(self) -> None:
        """Write this step's torque law into the kernel's input block (the layout of
        :func:`cvj_ros.physics.kernel.layout.set_torque_inputs`, written in place: this runs
        once per exchange in the lockstep loop)."""
        if self.scheme == 'zoh' and not self.extrapolate_residual:
            self._inputs[self._in_tk] = self._tk
            self._inputs[self._in_te] = self._Te
            self._inputs[self._in_tl] = self._Tl
            return
        from cvj_ros.physics.kernel.layout import set_torque_inputs
        ramp = self.scheme == 'extrapolate' or self.extrapolate_residual
        slope = self.scheme == 'linear_implicit'
        set_torque_inputs(self.model, t_k=self._tk, Te=self._Te, Tl=self._Tl,
                          Te_rate=self._rate_e if ramp else 0.0,
                          Tl_rate=self._rate_l if ramp else 0.0,
                          Ke=self._Ke if slope else 0.0, we=self._we if slope else 0.0,
                          Kl=self._Kl if slope else 0.0, wl=self._wl if slope else 0.0)

    # ------------------------------------------------------------ right-hand sides
    def _rhs_zoh(self, t: float, x: np.ndarray) -> np.ndarray:
        return self.driveline.rhs(t, x, self._Te, self._Tl)

    def _rhs_extrapolate(self, t: float, x: np.ndarray) -> np.ndarray:
        dt = t - self._tk
        return self.driveline.rhs(t, x, self._Te + self._rate_e * dt, self._Tl + self._rate_l * dt)

    def _torques_linear_implicit(self, x: np.ndarray) -> tuple[float, float]:
        dl = self.driveline
        Te = self._Te + self._Ke * (dl.engine_omega(x) - self._we) if self._Ke else self._Te
        Tl = self._Tl + self._Kl * (dl.load_omega(x) - self._wl) if self._Kl else self._Tl
        return Te, Tl

    def _rhs_linear_implicit(self, t: float, x: np.ndarray) -> np.ndarray:
        Te, Tl = self._torques_linear_implicit(x)
        if self.extrapolate_residual:
            dt = t - self._tk
            Te += self._rate_e * dt
            Tl += self._rate_l * dt
        return self.driveline.rhs(t, x, Te, Tl)

    def torques(self, t: float, x: np.ndarray) -> tuple[float, float]:
        """(T_engine, T_load) (N m) the current scheme applies at (t, x) inside the step."""
        if self.scheme == 'zoh':
            return self._Te, self._Tl
        if self.scheme == 'extrapolate':
            dt = t - self._tk
            return self._Te + self._rate_e * dt, self._Tl + self._rate_l * dt
        Te, Tl = self._torques_linear_implicit(x)
        if self.extrapolate_residual:
            dt = t - self._tk
            Te += self._rate_e * dt
            Tl += self._rate_l * dt
        return Te, Tl

    def _jac(self, t: float, x: np.ndarray) -> np.ndarray:
        """Jacobian of the coupled right-hand side: driveline.jacobian at the applied
        torques plus, for linear_implicit, the rank-one slope terms
        (df/dT) K (domega/dx), both by exact-for-linear finite differences."""
        dl = self.driveline
        Te, Tl = self.torques(t, x)
        J = np.array(dl.jacobian(t, x, Te, Tl), dtype=float)
        if self.scheme == 'linear_implicit' and (self._Ke or self._Kl):
            f0 = dl.rhs(t, x, Te, Tl)
            for K, omega_fn, which in ((self._Ke, dl.engine_omega, 0),
                                       (self._Kl, dl.load_omega, 1)):
                if not K:
                    continue
                dT = 1.0
                f1 = dl.rhs(t, x, Te + dT, Tl) if which == 0 else dl.rhs(t, x, Te, Tl + dT)
                dfdT = (f1 - f0) / dT
                J += K * np.outer(dfdT, self._omega_gradient(which, omega_fn, x))
        return J

    def _omega_gradient(self, which: int, omega_fn, x: np.ndarray) -> np.ndarray:
        """d omega / dx (1/s per state unit) by central differences; cached when the
        speed is a plain state component (a unit vector gradient, the usual case)."""
        cached = self._omega_grad.get(which)
        if cached is not None:
            return cached
        grad = np.empty(x.size)
        for j in range(x.size):
            d = 1e-6 * max(1.0, abs(x[j]))
            xp = x.copy()
            xm = x.copy()
            xp[j] += d
            xm[j] -= d
            grad[j] = (omega_fn(xp) - omega_fn(xm)) / (2 * d)
        unit = np.round(grad)
        if np.count_nonzero(unit) == 1 and np.max(np.abs(unit)) == 1.0 \
                and np.allclose(grad, unit, atol=1e-8, rtol=0):
            self._omega_grad[which] = unit
            return unit
        return grad

    # ------------------------------------------------------------------ exchange
    @property
    def t(self) -> float:
        """Current time (s)."""
        return self.stepper.t

    @property
    def x(self) -> np.ndarray:
        """Current state."""
        return self.stepper.y

    def _estimate_slope(self, idx_w: int, idx_T: int, sign: float, previous: float) -> float:
        """Least-squares slope dT/domega (N m s/rad) over the stored samples, clipped
        to the damping sign (sign * K >= 0) and |K| <= slope_max. While the speeds
        barely differ (spread below 1e-6 of their size) the samples say nothing
        about the slope: the previous estimate is kept."""
        if len(self._history) < 2:
            return previous
        w = np.array([s[idx_w] for s in self._history])
        T = np.array([s[idx_T] for s in self._history])
        dw = w - w.mean()
        var = dot(dw, dw)   # fixed order: BLAS ddot's order follows the CPU kernel
        if var <= (1e-6 * max(1.0, float(np.max(np.abs(w))))) ** 2 * len(w):
            return previous
        K = dot(dw, T - T.mean()) / var
        K = sign * min(max(sign * K, 0.0), self.slope_max)
        return K

    def advance(self, t_next: float, T_engine: float, T_load: float, *,
                slope_engine: float = 0.0, slope_load: float = 0.0) -> np.ndarray:
        """Integrate from the current exchange time t_k to ``t_next`` (s).

        Args:
            T_engine: engine torque received for t_k (N m, drives the crank).
            T_load: load torque received for t_k (N m, resists on the output).
            slope_engine, slope_load: dT/domega (N m s/rad) reported by the
                sources (used by 'linear_implicit' with slope='reported').
        Returns:
            the state at t_next (also ``self.x``).
        Raises:
            LockstepError: non-finite torque or slope, or t_next <= t.
        """
        isfinite = math.isfinite
        if not (isfinite(T_engine) and isfinite(T_load) and isfinite(slope_engine)
                and isfinite(slope_load)):
            for name, value in (('T_engine', T_engine), ('T_load', T_load),
                                ('slope_engine', slope_engine), ('slope_load', slope_load)):
                if not isfinite(value):
                    raise LockstepError(f'{name}: non-finite value {value} at t={self.t:.9g} s, '
                                        f'not integrated')
        t_k = self.stepper.t
        if not (t_next > t_k):
            raise LockstepError(f't_next: must be > t={t_k!r}, got {t_next!r}')
        x = self.stepper.y
        dl = self.driveline
        T_engine = float(T_engine)
        T_load = float(T_load)
        if self.scheme == 'extrapolate':
            if self._history:
                t_prev, _, Te_prev, _, Tl_prev = self._history[-1]
                dt = t_k - t_prev
                self._rate_e = (T_engine - Te_prev) / dt if dt > 0 else 0.0
                self._rate_l = (T_load - Tl_prev) / dt if dt > 0 else 0.0
            self._history.append((t_k, 0.0, T_engine, 0.0, T_load))
        elif self.scheme == 'linear_implicit':
            we = float(dl.engine_omega(x))
            wl = float(dl.load_omega(x))
            self._we, self._wl = we, wl
            if self.slope_mode == 'reported':
                self._Ke, self._Kl = float(slope_engine), float(slope_load)
            else:
                self._history.append((t_k, we, T_engine, wl, T_load))
                # engine slope damps when negative, load slope when positive
                self._Ke = self._estimate_slope(1, 2, -1.0, self._Ke)
                self._Kl = self._estimate_slope(3, 4, +1.0, self._Kl)
            if self.extrapolate_residual:
                # residual R = T - K omega, both exchanges with the current slopes
                if self._prev is not None and t_k > self._prev[0]:
                    tp, wep, Tep, wlp, Tlp = self._prev
                    dt = t_k - tp
                    self._rate_e = ((T_engine - self._Ke * we) - (Tep - self._Ke * wep)) / dt
                    self._rate_l = ((T_load - self._Kl * wl) - (Tlp - self._Kl * wlp)) / dt
                self._prev = (t_k, we, T_engine, wl, T_load)
        self._tk = t_k
        self._Te = T_engine
        self._Tl = T_load
        if self.model is not None:
            self._set_kernel_inputs()
        self.stepper.restart()  # the input changed at t_k: FSAL / Jacobian are stale
        self.n_exchanges += 1
        return self.stepper.advance_to(t_next)

    @property
    def slopes(self) -> tuple[float, float]:
        """(K_engine, K_load) in use for the current step (N m s/rad)."""
        return self._Ke, self._Kl

    def stats(self) -> dict:
        """Stepper counters plus scheme and exchange count."""
        out = self.stepper.stats()
        out.update(scheme=self.scheme, n_exchanges=self.n_exchanges, backend=self.backend,
                   backend_fallback=self.backend_fallback,
                   slope_engine=self._Ke, slope_load=self._Kl)
        return out
