"""Python wrappers implementing the ``solvers.Stepper`` protocol on compiled steppers.

``KernelStepper(method, rhs, ip, fp, t0, y0, ...)`` drives the ``@njit`` steppers of
``steppers_nb`` over a compiled right-hand side ``rhs(t, y, ip, fp, dy)`` (a numba
dispatcher: core-A's ``rhs_nb.rhs`` for a ModelData, or a toy rhs in the tests).
State persists in arrays between calls, so ``advance_to`` at every exchange step
does not restart the stepper. numba is imported here (lazily by callers), so
commands that do not integrate do not pay for it.

Implemented: 'dopri5' (adaptive 5(4), dense output), 'rk4' (fixed step h, Hermite
dense output), 'ros2' (fixed step h, L-stable Rosenbrock with the analytic compiled
``jac(t, y, ip, fp, J)``, hand-written LU; Hermite dense output), 'rosenbrock'
(RODAS5P, its own dense output), 'rodas4' and 'rodas3' (Hermite dense output),
adaptive,
'dop853' (8(5,3), 7th-order dense output), and the efficient FSAL pairs 'tsit5' (Tsitouras
5(4)) and 'vern6' (Verner 6(5)) with their interpolants (``steppers_rk_nb``). Every method
of solvers.METHODS is compiled; unknown names raise
SolverOptionError('method', ...).
"""
from __future__ import annotations

import contextlib
import functools
import math
import time

import numpy as np

from ...errors import SolverError
from ..stepper_base import SolverOptionError, _StepperBase
from . import _will_compile, compiling, load_cached, steppers_nb
from . import steppers_nb as nb   # layout constants (FS_*, C_*, ST_*)

_COPIES: dict = {}
# Compiled entry point per stepper function, shared by every KernelStepper of the process:
# the constructor normalises every argument's type (float64/int64 contiguous arrays, float
# scalars, bools), so one function has one signature per number of arguments (keyed so:
# hermite_dense's optional row once made a 9-argument call hit the 10-argument entry point,
# a TypeError); resolving it per stepper cost ~130 us
# (typeof of ~20 arguments), more than a 0.5 s kavz685_lever run's whole integration.
_ENTRY_POINTS: dict = {}
#: (t, h) of ``fs`` and (nfev, njev, nlu, naccept, nreject) of ``cnt`` are adjacent, so
#: :meth:`KernelStepper.stats` reads each group as one slice's ``tolist()`` (on every short
#: run's path: ~0.2 us less than the whole arrays' lists picked by an itemgetter)
_TH_SLICE = slice(nb.FS_T, nb.FS_H + 1)
_COUNTS_SLICE = slice(nb.C_NFEV, nb.C_NREJ + 1)


@functools.lru_cache(maxsize=None)
def _rhs_module():
    from . import rhs_nb   # lazily: importing it compiles nothing, but loads numba's typing
    return rhs_nb


def steppers_for(rhs, jac=None, module=None):
    """The compiled steppers calling ``rhs``/``jac``: ``module`` (default ``steppers_nb``;
    also ``steppers_rk_nb``) itself for the
    driveline kernel (rhs_nb.rhs / rhs_nb.jac, disk-cached), else a private copy of that
    module whose globals RHS/JAC are the given dispatchers, with disk caching off (a toy
    rhs in a test would otherwise overwrite the kernel's cache entries of the same
    signature). Copies are made once per (rhs, jac, module) and process."""
    rhs_nb = _rhs_module()
    base = steppers_nb if module is None else module
    if rhs is rhs_nb.rhs and (jac is None or jac is rhs_nb.jac):
        return base
    key = (id(rhs), id(jac)) if base is steppers_nb else (id(rhs), id(jac), base.__name__)
    mod = _COPIES.get(key)
    if mod is None:
        import importlib.util

        from numba.core.caching import NullCache
        from numba.core.registry import CPUDispatcher
        name = f'{__package__}._steppers_copy_{len(_COPIES)}'
        spec = importlib.util.spec_from_file_location(name, base.__file__)
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
        for obj in vars(mod).values():   # the copy's own functions, not the imported ones
            if isinstance(obj, CPUDispatcher) and obj.py_func.__module__ == name:
                obj._cache = NullCache()
        mod.RHS = rhs
        mod.JAC = jac if jac is not None else rhs_nb.jac
        if hasattr(mod, 'keep_none'):   # steppers_nb: a toy's J is evaluated whole at every step
            mod.JAC_KEEP = mod.keep_none
        _COPIES[key] = (mod, rhs, jac)   # keep rhs/jac alive so their ids stay unique
    else:
        mod = mod[0]
    return mod

KERNEL_METHODS = ('dopri5', 'dop853', 'rk4', 'ros2', 'rosenbrock', 'rodas4', 'rodas3', 'tsit5',
                  'vern6', 'vern7', 'vern8')
_ERK = ('tsit5', 'vern6', 'vern7', 'vern8')   # efficient pairs with interpolants (steppers_rk_nb)
_ROSENBROCK = ('ros2', 'rosenbrock', 'rodas4', 'rodas3')
_RODAS = ('rosenbrock', 'rodas4', 'rodas3')   # adaptive, tableau passed in (tableaux.py)
_HERMITE_RODAS = ('rodas4', 'rodas3')   # dense output: cubic Hermite from K's last row


@functools.lru_cache(maxsize=None)
def _dop853_args() -> tuple[tuple[np.ndarray, ...], tuple[np.ndarray, ...]]:
    """((C, A, B, E5, E3), (D, A_EXTRA, C_EXTRA)) as float arrays, built once per process
    (the steppers only read them; rebuilding them cost ~20-60 us per stepper)."""
    from ..tableaux import dop853_coefficients   # scipy's, without scipy.integrate
    step_coef, dense_coef = dop853_coefficients()
    return (tuple(np.array(c, dtype=float) for c in step_coef),
            tuple(np.array(c, dtype=float) for c in dense_coef))


@functools.lru_cache(maxsize=None)
def _rosenbrock_args(method: str) -> tuple[tuple, np.ndarray | None]:
    """(gamma, A, C, M, E, alpha, gamma_sum, order, fac_max) and the dense matrix H (or
    None) of a Rosenbrock method, built once per process (read-only use)."""
    from ..tableaux import RODAS_FAC_MAX, ROSENBROCK_TABLEAUX   # no scipy
    tableau, order = ROSENBROCK_TABLEAUX[method]
    tab = tableau()
    args = (float(tab['gamma']), np.ascontiguousarray(tab['A']),
            np.ascontiguousarray(tab['C']), np.ascontiguousarray(tab['M']),
            np.ascontiguousarray(tab['E']), np.ascontiguousarray(tab['alpha']),
            np.ascontiguousarray(tab['gamma_sum']), int(order), float(RODAS_FAC_MAX))
    return args, (np.ascontiguousarray(tab['H']) if 'H' in tab else None)


class KernelStepper(_StepperBase):
    """Stepper protocol over a compiled rhs. Argument checks are those of the
    Python steppers (``_StepperBase``); counters and t/h live in the arrays of
    ``steppers_nb`` and are exposed as attributes."""

    def __init__(self, method: str, rhs, ip: np.ndarray, fp: np.ndarray, t0: float, y0, *,
                 rtol: float = 1e-6, atol: float | np.ndarray = 1e-9, h: float | None = None,
                 max_step: float = math.inf, jac=None, autonomous: bool = False,
                 constant_jac: bool = False) -> None:
        if method not in KERNEL_METHODS:
            raise SolverOptionError('method', f'not compiled: {method!r} (compiled: '
                                    f'{", ".join(KERNEL_METHODS)})')
        self.method = method
        super().__init__(None, t0, y0, rtol=rtol, atol=atol, h=h, jac=None, max_step=max_step)
        if method in ('rk4', 'ros2') and self.h is None:
            raise SolverOptionError('h', f'required for the fixed-step method {method!r}')
        self._rhs = rhs
        self.compile_seconds = 0.0   # wall spent compiling (cache misses), s
        self.cache_path: str | None = None
        self.ip = np.ascontiguousarray(ip, dtype=np.int64)
        if not (isinstance(fp, np.ndarray) and fp.dtype == np.float64 and fp.ndim == 1
                and fp.flags.c_contiguous):
            raise SolverOptionError('fp', 'must be a 1-d C-contiguous float64 array')
        self.fp = fp  # not copied: set_torque_inputs writes into it between exchange steps
        self._y = self.y.copy()
        if method in _ROSENBROCK and jac is None:
            raise SolverOptionError('jac', f'the compiled {method} needs the compiled '
                                    f'jac(t, y, ip, fp, J)')
        self._jac = jac
        self._nb = steppers_for(rhs, jac)
        self._autonomous = bool(autonomous)
        self._constant_jac = bool(constant_jac)
        stages = 6 if method == 'dopri5' else 4
        if method == 'dop853':
            self._d8, self._d8_dense = _dop853_args()
            stages = 22   # K rows: 13 stages + FSAL, 3 dense stages, 7 dense coefficients
        if method in _RODAS:
            self._tab, self._H = _rosenbrock_args(method)
            stages = len(self._tab[3]) + 1   # K rows: f, stages (M), f at the last step start
        if method in _ERK:
            from ..erk_tableaux import erk_tableau
            from . import steppers_rk_nb
            tab = erk_tableau(method)
            self._rk_nb = steppers_for(rhs, jac, steppers_rk_nb)
            self._erk = (int(tab['error_order']), tab['C'], tab['A'], tab['B'], tab['E'])
            self._erk_P = tab['P']
            stages = tab['C'].size - 1   # K rows: the step's stages, the interpolant's extra
        # every float array of the state is a C-contiguous view of one buffer (and every
        # int one of another), so reset() is two fills: a run that reuses its stepper
        # (Simulation.run) pays ~2 us instead of this constructor's ~14. fs (NFS), y_old,
        # K (stages+1, n: stage derivatives, row 0 = f at the step start, FSAL), work (4, n:
        # stage argument, y_new, error, spare); Rosenbrock: J, LU (n, n), ft (n), piv (n)
        n = self.n
        sizes = [nb.NFS, n, (stages + 1) * n, 4 * n]
        if method in _ROSENBROCK:
            sizes += [n * n, n * n, n]
        self._fbuf = np.zeros(sum(sizes))
        self._ibuf = np.zeros(nb.NCNT + (n if method in _ROSENBROCK else 0), np.int64)
        views, o = [], 0
        for size in sizes:
            views.append(self._fbuf[o:o + size])
            o += size
        self._fs, self._y_old = views[0], views[1]
        self._K, self._work = views[2].reshape(stages + 1, n), views[3].reshape(4, n)
        self._cnt = self._ibuf[:nb.NCNT]
        self._th, self._counts = self._fs[_TH_SLICE], self._cnt[_COUNTS_SLICE]   # stats()
        if method in _ROSENBROCK:
            self._J, self._LU, self._ft = views[4].reshape(n, n), views[5].reshape(n, n), views[6]
            self._piv = self._ibuf[nb.NCNT:]
        self._h0 = self.h
        self._tails: dict[str, tuple] = {}   # argument tails built once (_rodas_args, ...)
        self._set_start(self.t, self._y)
        if isinstance(self.atol, float):
            self._atol = np.empty(self.n)
            self._atol.fill(self.atol)
        else:
            self._atol = np.array(self.atol, dtype=float)
        self._dense_out = np.empty(self.n)

    def _set_start(self, t0: float, y0: np.ndarray) -> None:
        """The constructor's state at (t0, y0): every array zero, then t, y, the h given."""
        self._fbuf.fill(0.0)
        self._ibuf.fill(0)
        self._y[:] = y0
        self._y_old[:] = y0
        fs = self._fs
        fs[nb.FS_ERROLD] = 1e-4
        fs[nb.FS_T] = t0
        fs[nb.FS_TOLD] = t0
        fs[nb.FS_H] = 0.0 if self._h0 is None else self._h0

    def reset(self, t0: float, y0: np.ndarray) -> None:
        """Start again at (t0 (s), y0) as a new stepper with the same options would: the same
        steps and bytes (test/physics/kernel/test_stepper_reset.py). y0: float64, finite, this stepper's size -
        the caller's promise (``Simulation.run`` passes its driveline's checked x0); counters
        restart at 0."""
        self._set_start(float(t0), y0)
        self._sync()

    def _call(self, fn, *args):
        """Call the compiled function fn; after the first call (which loads the cache,
        see :func:`load_cached`, or compiles) call its compiled entry point directly. Dispatching a call
        whose arguments include a numba dispatcher (rhs, jac) costs ~7 us in
        typeof() per call (measured: 10.7 us per call via the dispatcher, 0.7 us
        via the entry point), which would dominate a 1 kHz exchange loop."""
        key = (fn, len(args))          # an entry point has one signature: one per arity
        entry = _ENTRY_POINTS.get(key)
        if entry is not None:
            return entry(*args)
        entry = load_cached(fn, args)   # disk cache without numba's target refresh
        if entry is not None:
            _ENTRY_POINTS[key] = entry
            return entry(*args)
        misses = sum(fn.stats.cache_misses.values()) if hasattr(fn, 'stats') else 0
        c0 = time.perf_counter()
        # (the tests' private copies with caching off are not announced)
        cached = type(getattr(fn, '_cache', None)).__name__ != 'NullCache'
        with compiling(fn) if cached and _will_compile(fn) else contextlib.nullcontext():
            result = fn(*args)
        if hasattr(fn, 'stats') and sum(fn.stats.cache_misses.values()) > misses:
            self.compile_seconds += time.perf_counter() - c0   # compiled, not loaded
            self.cache_path = fn.stats.cache_path
        from numba import typeof
        try:
            _ENTRY_POINTS[key] = fn.overloads[tuple(typeof(a) for a in args)].entry_point
        except (KeyError, AttributeError, ValueError):
            _ENTRY_POINTS[key] = fn
        return result

    # -- protocol attributes backed by the kernel arrays
    def _sync(self) -> None:
        fs, cnt = self._fs.tolist(), self._cnt.tolist()
        self.t = float(fs[nb.FS_T])
        self.t_old = float(fs[nb.FS_TOLD])
        self.h = float(fs[nb.FS_H]) if fs[nb.FS_H] > 0 else None
        self.nfev, self.njev, self.nlu = int(cnt[nb.C_NFEV]), int(cnt[nb.C_NJEV]), int(cnt[nb.C_NLU])
        self.naccept, self.nreject = int(cnt[nb.C_NACC]), int(cnt[nb.C_NREJ])
        self.y = self._y.copy()
        self.y_old = self._y_old.copy()

    def stats(self) -> dict:
        """Counters and the current step-size proposal (s), read from the kernel arrays (so
        also right after :meth:`bind_run`'s run, which does not refresh the attributes)."""
        t, h = self._th.tolist()
        nfev, njev, nlu, naccept, nreject = self._counts.tolist()
        return {'method': self.method, 't': t, 'h': h if h > 0 else None, 'nfev': nfev,
                'njev': njev, 'nlu': nlu, 'naccept': naccept, 'nreject': nreject}

    def stats_into(self, out: dict) -> None:
        """:meth:`stats`' counters and step-size proposal written into ``out`` (a dict it
        returned), its other keys left as they are: a run that reuses its Trace
        (``Simulation.run(reuse_trace=True)``) refreshes its solver dict without a new one."""
        t, h = self._th.tolist()
        (out['nfev'], out['njev'], out['nlu'], out['naccept'],
         out['nreject']) = self._counts.tolist()
        out['t'] = t
        out['h'] = h if h > 0 else None

    def _check(self, status: int) -> None:
        self._sync()
        if status == nb.ST_OK:
            return
        t_bad = float(self._fs[nb.FS_TBAD])
        if status == nb.ST_SINGULAR:
            raise SolverError(f'h: matrix I/(h*gamma) - J is singular or non-finite at '
                              f't={t_bad:.9g} s ({self.method})')
        if status == nb.ST_NONFINITE:
            idx = int(self._cnt[nb.C_BADIDX])
            if idx < 0:
                raise SolverError(f't: state or derivative too large to integrate at '
                                  f't={t_bad!r} s (its error norm overflows, {self.method})')
            raise SolverError(f'y[{idx}]: non-finite value in the step at t={t_bad:.9g} s '
                              f'({self.method}, step from t={self.t:.9g} s)')
        raise SolverError(f't: step size underflow at t={self.t!r} s ({self.method}); the '
                          f'problem may be stiff or singular, try method="rosenbrock"')

    def advance_to(self, t_end: float) -> np.ndarray:
        """Integrate to exactly t_end (s); the step-size proposal is kept."""
        t_end = self._check_t_end(t_end)
        a = (t_end, self._y, self._y_old, self.ip, self.fp, self._fs, self._cnt)
        if self.method == 'dopri5':
            st = self._call(self._nb.dopri5_advance, *a, self.rtol, self._atol, self.max_step, self._K, self._work)
        elif self.method == 'dop853':
            st = self._call(self._nb.dop853_advance, *a, self.rtol, self._atol, self.max_step, *self._d8, self._K,
                                   self._work)
        elif self.method in _ERK:
            st = self._call(self._rk_nb.erk_advance, *a, self.rtol, self._atol, self.max_step,
                            *self._erk, self._K, self._work)
        elif self.method == 'ros2':
            st = self._call(self._nb.ros2_advance, *a, *self._ros_args())
        elif self.method in _ROSENBROCK:
            st = self._call(self._nb.ros_advance, *a, *self._rodas_args())
        else:
            st = self._call(self._nb.rk4_advance, *a, self._K, self._work)
        self._check(st)
        return self.y

    def land(self, times: np.ndarray, X: np.ndarray) -> None:
        """advance_to(times[k]) for k = 1 .. m-1 in one compiled call, X[k] = y there
        (X[0] is left to the caller). times: increasing, finite, times[1] >= t (s).
        Same steps and bytes as the advance_to loop; raises SolverError like it."""
        times = np.ascontiguousarray(times, dtype=float)
        if times.ndim != 1 or X.shape != (times.size, self.n):
            raise SolverOptionError('times', 'must be 1-d with one row of X per time')
        if times.size < 2:
            return
        if not np.isfinite(times).all() or (times[2:] < times[1:-1]).any() or times[1] < self.t:
            raise SolverOptionError('times', f'must be finite, non-decreasing and >= t={self.t!r}')
        self._land(times, X)

    def _land(self, times: np.ndarray, X: np.ndarray) -> None:
        """:meth:`land` without its argument checks, for a caller that built ``times``
        (float64, C-contiguous, finite, non-decreasing, times[1] >= t) and ``X`` (C-contiguous
        float64, one row per time) itself: ``Simulation.run``, where the checks cost ~8 us of a
        150 us run."""
        a = (times, X, self._y, self._y_old, self.ip, self.fp, self._fs, self._cnt)
        if self.method == 'dopri5':
            st, _ = self._call(self._nb.dopri5_land, *a, self.rtol, self._atol, self.max_step,
                               self._K, self._work)
        elif self.method == 'dop853':
            st, _ = self._call(self._nb.dop853_land, *a, self.rtol, self._atol, self.max_step,
                               *self._d8, self._K, self._work)
        elif self.method in _ERK:
            st, _ = self._call(self._rk_nb.erk_land, *a, self.rtol, self._atol, self.max_step,
                               *self._erk, self._K, self._work)
        elif self.method == 'ros2':
            st, _ = self._call(self._nb.ros2_land, *a, *self._ros_args())
        elif self.method in _ROSENBROCK:
            st, _ = self._call(self._nb.ros_land, *a, *self._rodas_args())
        else:
            st, _ = self._call(self._nb.rk4_land, *a, self._K, self._work)
        self._check(st)

    def step(self, t_bound: float = math.inf) -> float:
        """One natural step never past t_bound (s); returns the new t."""
        t_bound = self._check_t_end(t_bound) if math.isfinite(t_bound) else math.inf
        a = (t_bound, self._y, self._y_old, self.ip, self.fp, self._fs, self._cnt)
        if self.method == 'dopri5':
            st = self._call(self._nb.dopri5_step_once, *a, self.rtol, self._atol, self.max_step, self._K,
                                     self._work)
        elif self.method == 'dop853':
            st = nb.ST_OK if self.t >= t_bound else self._call(self._nb.dop853_step, 
                *a, self.rtol, self._atol, self.max_step, *self._d8, self._K, self._work)
        elif self.method in _ERK:
            st = self._call(self._rk_nb.erk_step_once, *a, self.rtol, self._atol, self.max_step,
                            *self._erk, self._K, self._work)
        elif self.method == 'ros2':
            st = self._call(self._nb.ros2_step_once, *a, *self._ros_args())
        elif self.method in _ROSENBROCK:
            st = nb.ST_OK if self.t >= t_bound else self._call(self._nb.ros_step, 
                *a, *self._rodas_args())
        else:
            st = self._call(self._nb.rk4_step_once, *a, self._K, self._work)
        self._check(st)
        return self.t

    def _ros_args(self) -> tuple:
        tail = self._tails.get('ros2')
        if tail is None:
            tail = self._tails['ros2'] = (self._autonomous, self._constant_jac, self._J,
                                          self._LU, self._piv, self._ft, self._K, self._work)
        return tail

    def _rodas_args(self) -> tuple:
        """The Rosenbrock steppers' arguments after (y, ..., cnt): built once (options and
        arrays are fixed at construction; a 20-tuple per call was ~0.5 us)."""
        tail = self._tails.get('rodas')
        if tail is None:
            tail = self._tails['rodas'] = (
                self.rtol, self._atol, self.max_step, self._autonomous, self._constant_jac,
                *self._tab, self._J, self._LU, self._piv, self._ft, self._K, self._work)
        return tail

    def dense(self, t: float) -> np.ndarray:
        """y(t) inside the last accepted step (dopri5, tsit5: 4th order; vern6: 6th; rk4:
        cubic Hermite)."""
        t = self._check_dense_t(t)
        out = np.empty(self.n)
        if self.method == 'dopri5':
            if t == self.t or self._fs[nb.FS_HLAST] == 0.0:
                return self.y.copy()
            self._call(self._nb.dopri5_dense, t, self._y_old, self._fs, self._K, out)
        elif self.method == 'dop853':
            if t == self.t or self._fs[nb.FS_HLAST] == 0.0:
                return self.y.copy()
            self._call(self._nb.dop853_dense, t, self._y, self._y_old, self.ip, self.fp, self._fs,
                            self._cnt, *self._d8_dense, self._K, out)
            self._sync()
        elif self.method in _ERK:
            if t == self.t or self._fs[nb.FS_HLAST] == 0.0:
                return self.y.copy()
            _order, C, A, B, _E = self._erk
            self._call(self._rk_nb.erk_dense, t, self._y, self._y_old, self.ip, self.fp,
                       self._fs, self._cnt, C, A, self._erk_P, self._K, self._work, B.size, out)
            self._sync()
        elif self.method == 'rosenbrock':
            if t == self.t or self._fs[nb.FS_HLAST] == 0.0:
                return self.y.copy()
            self._call(self._nb.ros_dense_h, t, self._y, self._y_old, self._fs, self._H, self._K, out)
        elif self.method in _HERMITE_RODAS:
            if t == self.t or self._fs[nb.FS_HLAST] == 0.0:
                return self.y.copy()
            self._call(self._nb.hermite_dense, t, self._y, self._y_old, self.ip, self.fp, self._fs,
                             self._cnt, self._K, out, self._K.shape[0] - 1)
            self._sync()
        else:
            # frow given: _call keeps one entry point per function (rodas4/3 pass their own row)
            self._call(self._nb.hermite_dense, t, self._y, self._y_old, self.ip, self.fp, self._fs,
                       self._cnt, self._K, out, 4)
            self._sync()
        return out

    def sample(self, t_eval) -> np.ndarray:
        """Compiled sampled loop: states at the increasing times t_eval (s), (m, n)."""
        t_eval = np.ascontiguousarray(t_eval, dtype=float)
        if t_eval.ndim != 1 or (t_eval.size and (np.any(np.diff(t_eval) < 0)
                                                or not np.all(np.isfinite(t_eval)))):
            raise SolverOptionError('t_eval', 'must be a finite, non-decreasing 1-d array')
        Y = np.empty((t_eval.size, self.n))
        if t_eval.size == 0:
            return Y
        if (self.method in _ROSENBROCK or self.method == 'dop853') and t_eval[0] < self.t_old:
            # stepper_base.sample_dense's contract (super_sample)
            raise SolverOptionError('t_eval', f'must be finite, increasing and >= the start of '
                                    f'the last step t_old={self.t_old!r}')
        self._sample_into(t_eval, Y)
        return Y

    def _sample_into(self, t_eval: np.ndarray, Y: np.ndarray) -> None:
        """:meth:`sample` into ``Y`` without its checks, for a caller that built ``t_eval``
        (float64, C-contiguous, finite, non-decreasing, >= t_old; not empty) and ``Y``
        (C-contiguous float64, one row per time) itself: ``Simulation.run``."""
        call = self._tails.get('sample')
        if call is None:
            call = self._tails['sample'] = self._sample_call()
        fn, rest, y_last = call
        if y_last:
            st, _ = self._call(fn, t_eval, *rest, Y)
        else:
            st, _ = self._call(fn, t_eval, Y, *rest)
        self._check(st)

    def _sample_call(self) -> tuple:
        """(compiled sampled loop, its arguments but t_eval and Y, whether Y comes last)."""
        state = (self._y, self._y_old, self.ip, self.fp, self._fs, self._cnt)
        if self.method == 'dop853':
            # stepper_base.sample_dense's steps (super_sample), in one call
            return (self._nb.dop853_sample, (*state, self.rtol, self._atol, self.max_step,
                                             *self._d8, *self._d8_dense, self._K, self._work),
                    False)
        if self.method in _ERK:
            return (self._rk_nb.erk_sample, (*state, self.rtol, self._atol, self.max_step,
                                             *self._erk, self._erk_P, self._K, self._work),
                    False)
        if self.method == 'ros2':
            return self._nb.ros2_sample, (*state, *self._ros_args()), False
        if self.method in _ROSENBROCK:
            hermite = self.method in _HERMITE_RODAS   # as dense(): cubic Hermite, K's last row
            return (self._nb.ros_sample, (*state, *self._rodas_args(), _NO_H if hermite else self._H,
                                          self._K.shape[0] - 1 if hermite else -1), False)
        if self.method == 'dopri5':
            return (self._nb.dopri5_sample, (*state, self.rtol, self._atol, self.max_step,
                                             self._K, self._work), True)
        return self._nb.rk4_sample, (*state, self._K, self._work), True

    def _run_call(self) -> tuple:
        """(whole-run function of ``run_nb`` for this method, its scalar options after the
        model arrays, the method's pack entries after the common ones)."""
        from . import run_nb
        if self.method == 'dopri5':
            return run_nb.dopri5_run, (self.rtol, self.max_step), ()
        if self.method == 'dop853':
            return run_nb.dop853_run, (self.rtol, self.max_step), (*self._d8, *self._d8_dense)
        if self.method in _ERK:
            from .run_rk_nb import erk_run
            order, C, A, B, E = self._erk
            return erk_run, (self.rtol, self.max_step, order), (C, A, B, E, self._erk_P)
        if self.method == 'rk4':
            return run_nb.rk4_run, (), ()
        linear = (self._J, self._LU, self._ft, self._piv)
        if self.method == 'ros2':
            return run_nb.ros2_run, (self._autonomous, self._constant_jac), linear
        hermite = self.method in _HERMITE_RODAS   # as _sample_call
        gamma, A, C, M, E, alpha, gsum, order, fac_max = self._tab
        return (run_nb.ros_run,
                (self.rtol, self.max_step, self._autonomous, self._constant_jac, gamma,
                 order, fac_max, self._K.shape[0] - 1 if hermite else -1),
                (*linear, A, C, M, E, alpha, gsum, _NO_H if hermite else self._H))

    def bind_run(self, x0: np.ndarray, times: np.ndarray, plan: tuple, tab: np.ndarray,
                 mids: tuple[np.ndarray, np.ndarray] | None = None,
                 skip: np.ndarray | None = None, ip: np.ndarray | None = None):
        """A whole offline run in one compiled call (``run_nb``), bound to what is fixed for a
        Simulation's options: ``run(e0, X, XG, pos, vel, eff, te, tl, res)`` starts again at
        (0, x0) as :meth:`reset` does, integrates over ``times`` (s) into ``X`` (X[0] = x0)
        by the ``plan`` - ``(grid, rows, seg, brk, tb, two)``, see ``run_nb`` - and fills
        the samples' outputs as ``outputs_nb.sample_outputs(times, X, ip, fp, tab, e0,
        pos, ...)`` does, then - every sample finite - the intermediate members of
        ``mids = (mtab, mfp)`` (``outputs_nb.mid_table``) as ``fill_mid_samples(pos, vel,
        mtab, mfp)`` does (none when None). ``skip`` (``outputs_nb.unread_angles``; None:
        none): ``sample_outputs_lean`` instead, NaN angles after the joints it flags; ``ip``
        (None: the stepper's): the model's ints the run reads instead, of the same layout
        (``outputs_nb.ratio_only_ip``). Same
        steps and bytes as reset + land / sample + sample_outputs + fill_mid_samples
        (test_run_nb.py). It raises SolverError as
        :meth:`advance_to` and returns the first sample whose state is not finite, or -1. For ``Simulation.run``, which builds every
        array (C-contiguous float64 / int64, fixed ndim): nothing is checked per run, and a
        run that succeeds leaves the Python attributes (t, y, counters: ~1.1 us to refresh)
        as they were - :meth:`stats` reads the arrays; :meth:`reset` refreshes them. Only
        for the driveline kernel (``rhs_nb.rhs``/``rhs_nb.jac``). ``x0``, ``times``, the plan,
        ``atol``, the tableau, ``tab`` and ``mtab`` are copied into the run's packs here
        (``run_nb.pack``: fixed for these options; ``fp`` and ``mfp`` are read where they
        are, a sweep patches them between runs); the fixed arguments are bound to the
        entry point after its first call (functools.partial)."""
        if self._nb is not steppers_nb:
            raise SolverOptionError('rhs', 'bind_run runs the driveline kernel only')
        from .run_nb import pack
        fn, scalars, entries = self._run_call()
        grid, rows, seg, brk, tb, two = plan
        mtab, mfp = mids if mids is not None else (np.zeros((0, 4), np.int64), np.zeros(0))
        skip = np.zeros(0, np.int64) if skip is None else np.ascontiguousarray(skip, np.int64)
        if not (isinstance(mfp, np.ndarray) and mfp.dtype == np.float64 and mfp.ndim == 1
                and mfp.flags.c_contiguous):
            raise SolverOptionError('mids', 'mfp must be a 1-d C-contiguous float64 array')
        fpk, ipk = pack([x0, times, grid, brk, tb, two, self._atol, self._fs, self._y_old,
                         self._K, self._work, rows, seg, tab, self._cnt,
                         np.ascontiguousarray(mtab, dtype=np.int64), skip, *entries],
                        self._fbuf, self._ibuf)
        # mfp is read where it is, as fp is (a sweep patches both between runs)
        ip = self.ip if ip is None else np.ascontiguousarray(ip, dtype=np.int64)
        head = (fpk, ipk, self._fbuf, self._ibuf, self._y, ip, self.fp, mfp,
                0.0 if self._h0 is None else float(self._h0), *scalars)
        check = self._check
        bound = None

        def run(*per_run) -> int:
            nonlocal bound
            if bound is None:
                st, bad = self._call(fn, *head, *per_run)
                bound = functools.partial(_ENTRY_POINTS[(fn, len(head) + len(per_run))], *head)
            else:
                st, bad = bound(*per_run)
            if st != nb.ST_OK:
                check(st)   # raises
            return bad
        # for a caller that skips this frame after the first call: run.bound() is the
        # bound entry point (None before), bound(*per_run) -> (status, bad), and a status
        # != ST_OK goes to run.check (raises). Read through a lambda: run itself in its
        # own body would make a reference cycle.
        run.bound = lambda: bound
        run.check = check

        def kept(per_run: tuple):
            """``call(e0) -> (status, bad)``: the bound run with these arrays X, XG, pos,
            vel, eff, te, tl, res every time (``Simulation.run(reuse_trace=True)``), through
            ``kept_nb.ros_run_kept`` (two scalar arguments instead of 16 arrays and 10
            scalars to unbox); None for the other methods (their runs are called as
            ``bound``)."""
            from . import run_nb
            if fn is not run_nb.ros_run:
                return None
            from .kept_nb import kept_call
            return kept_call(head, per_run)
        run.kept = kept
        return run

    def restart(self) -> None:
        """Inputs changed discontinuously: drop the FSAL derivative, the Jacobian (also a
        kept block) and its LU; keep h."""
        self._cnt[nb.C_HAVEF] = 0
        self._cnt[nb.C_HAVEJ] = 0
        self._cnt[nb.C_HAVELU] = 0
        self._cnt[nb.C_JKEPT] = 0


_NO_H = np.zeros((3, 0))   # ros_sample's H for rodas4/3 (not read: their dense output is Hermite)


def super_sample(stepper: KernelStepper, t_eval: np.ndarray) -> np.ndarray:
    """Sampling by natural steps + dense output from Python (stepper_base.sample_dense over
    step/dense): the oracle of the compiled sampled loops of the Rosenbrock methods and
    dop853 (test_kernel_sample.py)."""
    from ..stepper_base import sample_dense
    return sample_dense(stepper, t_eval)
