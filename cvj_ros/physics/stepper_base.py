"""Light base of the persistent steppers: the Stepper protocol, argument checks and
counters shared by the Python steppers (solvers.py) and the compiled ones
(kernel/stepper.py). Split from solvers.py so that the compiled path does not import
scipy (~0.7 s of start-up); solvers.py re-exports every name (``sample_dense`` too,
which moved here so that the compiled steppers' dense sampling needs no scipy either).
"""
from __future__ import annotations

import math
from typing import Callable, Protocol, runtime_checkable

import numpy as np

from cvj_ros.errors import SolverError

RhsFunction = Callable[[float, np.ndarray], np.ndarray]
JacFunction = Callable[[float, np.ndarray], np.ndarray]

_EPS = float(np.finfo(float).eps)
_INVERSE_MAX_N = 12  # up to this size stage solves use an explicit inverse (np.dot)


class SolverOptionError(SolverError, ValueError):
    """A solver option is invalid; ``str()`` starts with the option name."""

    def __init__(self, parameter: str, message: str) -> None:
        self.parameter = parameter
        super().__init__(f'{parameter}: {message}')


@runtime_checkable
class Stepper(Protocol):
    """Persistent integrator interface (docs/contracts.md, "Solvers")."""

    method: str
    t: float
    y: np.ndarray
    t_old: float
    y_old: np.ndarray
    h: float | None
    nfev: int
    njev: int
    nlu: int
    naccept: int
    nreject: int

    def advance_to(self, t_end: float) -> np.ndarray: ...

    def step(self, t_bound: float = math.inf) -> float: ...

    def dense(self, t: float) -> np.ndarray: ...

    def restart(self) -> None: ...

    def stats(self) -> dict: ...


# --------------------------------------------------------------------------- base


class _StepperBase:
    """State, counters and checks shared by every stepper."""

    method = ''
    order = 1

    def __init__(self, fun: RhsFunction, t0: float, y0: np.ndarray, *,
                 rtol: float, atol: float | np.ndarray, h: float | None,
                 jac: JacFunction | None, max_step: float) -> None:
        self.fun = fun
        self.jac = jac
        self.t = float(t0)
        y = np.array(y0, dtype=float).reshape(-1)
        if y.size == 0:
            raise SolverOptionError('y0', 'must have at least one state')
        if not np.isfinite(y).all():
            bad = np.flatnonzero(~np.isfinite(y))
            raise SolverOptionError(f'y0[{bad[0]}]', f'must be finite, got {y[bad[0]]}')
        self.y = y
        self.n = y.size
        try:
            rtol = float(rtol)
        except (TypeError, ValueError):
            raise SolverOptionError('rtol', f'must be a positive number, got {rtol!r}') from None
        if not (math.isfinite(rtol) and rtol > 0):
            raise SolverOptionError('rtol', f'must be a positive number, got {rtol!r}')
        if isinstance(atol, float) and math.isfinite(atol) and atol >= 0:
            atol_arr = np.asarray(atol)      # the common case, without array reductions
        else:
            atol_arr = np.asarray(atol, dtype=float)
            if atol_arr.ndim > 1 or (atol_arr.ndim == 1 and atol_arr.size != self.n) \
                    or not np.all(np.isfinite(atol_arr)) or np.any(atol_arr < 0):
                raise SolverOptionError('atol', f'must be >= 0 (scalar or one per state), '
                                                f'got {atol!r}')
        if rtol < 100 * _EPS:
            raise SolverOptionError('rtol', f'must be >= {100 * _EPS:.3g}, got {rtol!r}')
        self.rtol = float(rtol)
        self.atol = float(atol_arr) if atol_arr.ndim == 0 else atol_arr.copy()
        if not (isinstance(max_step, (int, float, np.floating)) and max_step > 0):
            raise SolverOptionError('max_step', f'must be > 0, got {max_step!r}')
        self.max_step = float(max_step)
        if h is not None and not (isinstance(h, (int, float, np.floating))
                                  and math.isfinite(h) and h > 0):
            raise SolverOptionError('h', f'must be a positive finite step, got {h!r}')
        self.h: float | None = None if h is None else min(float(h), self.max_step)
        self.t_old = self.t
        self.y_old = self.y
        self.nfev = 0
        self.njev = 0
        self.nlu = 0
        self.naccept = 0
        self.nreject = 0

    # -- helpers
    def _eval(self, t: float, y: np.ndarray) -> np.ndarray:
        self.nfev += 1
        return self.fun(t, y)

    def _raise_nonfinite(self, y: np.ndarray, t: float, what: str) -> None:
        idx = int(np.flatnonzero(~np.isfinite(y))[0])
        raise SolverError(f'y[{idx}]: non-finite value {y[idx]} in {what} at t={t:.9g} s '
                          f'({self.method}, step from t={self.t:.9g} s)')

    def _check_t_end(self, t_end: float) -> float:
        t_end = float(t_end)
        if not math.isfinite(t_end) or t_end < self.t:
            raise SolverOptionError('t_end', f'must be finite and >= t={self.t!r}, got {t_end!r}')
        return t_end

    def _check_dense_t(self, t: float) -> float:
        t = float(t)
        span = self.t - self.t_old
        tol = 1e-12 * max(1.0, abs(self.t)) + 1e-9 * span
        if not (self.t_old - tol <= t <= self.t + tol):
            raise SolverOptionError('t', f'dense output only inside the last step '
                                    f'[{self.t_old!r}, {self.t!r}], got {t!r}')
        return t

    def restart(self) -> None:
        """Forget data that assumed smooth inputs (FSAL value, Jacobian); keep h."""

    def stats(self) -> dict:
        """Counters and the current step-size proposal (s)."""
        return {'method': self.method, 't': self.t, 'h': self.h, 'nfev': self.nfev,
                'njev': self.njev, 'nlu': self.nlu, 'naccept': self.naccept,
                'nreject': self.nreject}


def sample_dense(stepper: Stepper, t_eval) -> np.ndarray:
    """States at the increasing times ``t_eval`` (s), shape (len(t_eval), n).

    The stepper takes its natural steps (``step``) up to the last time and each
    sample comes from the dense output of the step that contains it, so dense
    sampling does not shorten the steps (``advance_to`` per sample would: one
    step per sample when samples are closer than the natural step). Times may
    start inside the last accepted step (>= ``stepper.t_old``), so the function
    can be called sample by sample: ``x_k = sample_dense(st, [t_k])[0]``. The
    stepper ends at or after the last time, not exactly on it: use
    ``advance_to`` where the state must sit on a time (input changes).
    """
    times = np.asarray(t_eval, dtype=float).reshape(-1)
    if times.size and (np.any(np.diff(times) < 0) or times[0] < stepper.t_old
                       or not np.all(np.isfinite(times))):
        raise SolverOptionError('t_eval', f'must be finite, increasing and >= the start of the '
                                f'last step t_old={stepper.t_old!r}')
    out = np.empty((times.size, stepper.y.size))
    for i, t in enumerate(times):
        while stepper.t < t:
            stepper.step()
        out[i] = stepper.y if t == stepper.t else stepper.dense(t)
    return out
