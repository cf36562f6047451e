"""The expert baseline of `cvj-sim bench` (family ``baseline_expert``): the project's compiled
right-hand side (kernel/rhs_nb.rhs, engine and load inside) handed to a compiled integrator,
numbalsoda's LSODA (Petzold 1983; a C++ rewrite of ODEPACK's) and DOP853 (Hairer, Norsett
& Wanner 1993; in Fortran), through one ``numba.cfunc`` of numbalsoda's signature
``void f(double t, double *u, double *du, double *p)``.

The cfunc is compiled once for every scene: ``p`` points at a small float64 block holding
the addresses and lengths of the scene's ``ip``/``fp`` arrays (kernel/layout.py), the state
length and an evaluation counter, so a scene is data, not code. numbalsoda is optional
(``make bench`` installs it from ``requirements-bench.txt``; it builds from source with a
Fortran compiler and cmake): :func:`unavailable_reason` says in one line why the family is
skipped when it is not importable.
"""
from __future__ import annotations

import contextlib
import functools
import os
import sys
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np

__all__ = ['EXPERT_METHODS', 'P_COUNT', 'P_FP', 'P_IP', 'P_KIND', 'P_LEN', 'P_NFP', 'P_NIP',
           'P_NSC', 'P_NSTATE', 'P_SC', 'PM_LEN', 'expert_cfunc', 'expert_data',
           'mode_expert_cfunc', 'mode_expert_data', 'quiet_stdout', 'skip_line', 'solve_expert',
           'unavailable_reason']

EXPERT_METHODS = ('lsoda', 'dop853')
# layout of the parameter block p: addresses (exact in a double below 2**53) and lengths
P_IP, P_NIP, P_FP, P_NFP, P_NSTATE, P_COUNT = range(6)
P_LEN = 6
# the mode scenes' block (mode_expert_cfunc): the same six, then which mode right-hand side
# (segment_nb.KIND_CHAIN 0 / KIND_TREE 1) and the address and length of a scratch array
P_KIND, P_SC, P_NSC = 6, 7, 8
PM_LEN = 9


@functools.lru_cache(maxsize=1)
def unavailable_reason() -> str | None:
    """None when numbalsoda imports, else why not (one line)."""
    try:
        import numbalsoda  # noqa: F401
    except Exception as exc:   # ImportError, or a broken build's OSError loading its library
        first = (str(exc).splitlines() or [type(exc).__name__])[0]
        return f'numbalsoda not importable ({first[:120]})'
    return None


def _c_flush() -> None:
    """fflush(NULL) (every C stdio stream) and, when libgfortran is loaded (numbalsoda's
    DOP853 is Fortran), a flush of Fortran unit 6 (its stdout, buffered apart from C's)."""
    import ctypes
    try:
        ctypes.CDLL(None).fflush(None)
    except (OSError, AttributeError):
        pass
    try:
        gf = ctypes.CDLL('libgfortran.so.5', mode=os.RTLD_NOLOAD)   # only if already loaded
        gf._gfortran_flush_i4(ctypes.byref(ctypes.c_int(6)))
    except (OSError, AttributeError):
        pass


@contextlib.contextmanager
def quiet_stdout() -> Iterator[None]:
    """File descriptor 1 sent to /dev/null: numbalsoda's C++ and Fortran solvers print their
    diagnostics ('the problem seems to become stiff', 'more than nmax steps') there, into
    the bench's report on stdout; a failure is recorded in the row instead. The C and Fortran
    buffers are flushed at both ends (else they reach the restored stdout at exit)."""
    sys.stdout.flush()
    _c_flush()
    saved = os.dup(1)
    try:
        with open(os.devnull, 'w') as null:
            os.dup2(null.fileno(), 1)
        yield
    finally:
        sys.stdout.flush()
        _c_flush()
        os.dup2(saved, 1)
        os.close(saved)


def skip_line(reason: str, *, install_hint: bool = True) -> str:
    """The one line the bench prints when the family is skipped (with how to install
    numbalsoda when it is missing)."""
    hint = ('; `make bench` installs it (pip install -r requirements-bench.txt: builds from '
            'source, needs gfortran and cmake)') if install_hint else ''
    return f'[bench] baseline_expert skipped: {reason}{hint}'


@functools.lru_cache(maxsize=1)
def _pointer_intrinsic() -> Any:
    """A numba intrinsic: an int64 address as a void pointer (for numba.carray); shared by
    the cfuncs below."""
    from numba import types
    from numba.core import cgutils
    from numba.extending import intrinsic

    @intrinsic
    def _as_pointer(typingctx: Any, addr: Any) -> Any:
        sig = types.voidptr(addr)

        def codegen(context: Any, builder: Any, signature: Any, args: Any) -> Any:
            return builder.inttoptr(args[0], cgutils.voidptr_t)
        return sig, codegen
    return _as_pointer


@functools.lru_cache(maxsize=1)
def expert_cfunc() -> Any:
    """The numba cfunc (numbalsoda's rhs signature) over kernel/rhs_nb.rhs; compiled on first
    use (seconds: the whole rhs is inlined into it)."""
    import numba as nb
    from numba import types

    from cvj_ros.physics.kernel.rhs_nb import rhs

    _as_pointer = _pointer_intrinsic()

    sig = types.void(types.double, types.CPointer(types.double), types.CPointer(types.double),
                     types.CPointer(types.double))

    # not cached: its key holds the intrinsic made in this process, so a disk cache would
    # never hit and would grow by a file per process (~1 s to compile on warm kernels)
    @nb.cfunc(sig)
    def f(t, u, du, p):   # pragma: no cover - compiled
        n = np.int64(p[P_NSTATE])
        ip = nb.carray(_as_pointer(np.int64(p[P_IP])), (np.int64(p[P_NIP]),), dtype=np.int64)
        fp = nb.carray(_as_pointer(np.int64(p[P_FP])), (np.int64(p[P_NFP]),), dtype=np.float64)
        y = nb.carray(u, (n,))
        dy = nb.carray(du, (n,))
        p[P_COUNT] += 1.0
        rhs(t, y, ip, fp, dy)
    return f


def expert_data(ip: np.ndarray, fp: np.ndarray, n_state: int) -> np.ndarray:
    """The parameter block for :func:`expert_cfunc` (the caller keeps ``ip`` and ``fp``
    alive and unmoved while it is used)."""
    if ip.dtype != np.int64 or fp.dtype != np.float64 or not (ip.flags.c_contiguous and fp.flags.c_contiguous):
        raise ValueError('expert_data: ip must be C-contiguous int64 and fp float64')
    p = np.zeros(P_LEN)
    p[P_IP], p[P_NIP] = float(ip.ctypes.data), float(ip.size)
    p[P_FP], p[P_NFP] = float(fp.ctypes.data), float(fp.size)
    p[P_NSTATE] = float(n_state)
    return p


@functools.lru_cache(maxsize=1)
def mode_expert_cfunc() -> Any:
    """The numba cfunc (numbalsoda's rhs signature) over one mode's compiled right-hand side,
    the one the project's mode segments integrate: a chain's kernel/modes_nb.mode_eval
    (P_KIND 0) or a vehicle tree's kernel/tree_modes_nb.tm_eval (P_KIND 1), the mode's
    ``ip``/``fp`` (kernel/modes.py, kernel/tree_modes.py) read through the parameter block
    (:func:`mode_expert_data`); witnesses not evaluated (want=False)."""
    import numba as nb
    from numba import types

    from cvj_ros.physics.kernel.modes_nb import mode_eval
    from cvj_ros.physics.kernel.tree_modes_nb import tm_eval

    _as_pointer = _pointer_intrinsic()

    sig = types.void(types.double, types.CPointer(types.double), types.CPointer(types.double),
                     types.CPointer(types.double))

    # not cached: its key holds the intrinsic made in this process, so a disk cache would
    # never hit and would grow by a file per process (~1 s to compile on warm kernels)
    @nb.cfunc(sig)
    def f(t, u, du, p):   # pragma: no cover - compiled
        n = np.int64(p[P_NSTATE])
        ip = nb.carray(_as_pointer(np.int64(p[P_IP])), (np.int64(p[P_NIP]),), dtype=np.int64)
        fp = nb.carray(_as_pointer(np.int64(p[P_FP])), (np.int64(p[P_NFP]),), dtype=np.float64)
        sc = nb.carray(_as_pointer(np.int64(p[P_SC])), (np.int64(p[P_NSC]),), dtype=np.float64)
        y = nb.carray(u, (n,))
        dy = nb.carray(du, (n,))
        p[P_COUNT] += 1.0
        if p[P_KIND] == 0.0:
            mode_eval(t, y, ip, fp, dy, sc, False)
        else:
            tm_eval(t, y, ip, fp, dy, sc, False)
    return f


def mode_expert_data(kind: int, ip: np.ndarray, fp: np.ndarray, n_state: int,
                     sc: np.ndarray) -> np.ndarray:
    """The parameter block for :func:`mode_expert_cfunc`: ``kind`` 0 (chain) or 1 (vehicle
    tree), the mode's arrays and a float64 scratch ``sc`` (the caller keeps the arrays
    alive and unmoved while it is used)."""
    if kind not in (0, 1):
        raise ValueError(f'mode_expert_data: kind 0 (chain) or 1 (tree), not {kind!r}')
    if sc.dtype != np.float64 or not sc.flags.c_contiguous or sc.size < 1:
        raise ValueError('mode_expert_data: sc must be a non-empty C-contiguous float64 array')
    p = np.zeros(PM_LEN)
    p[:P_LEN] = expert_data(ip, fp, n_state)
    p[P_KIND] = float(kind)
    p[P_SC], p[P_NSC] = float(sc.ctypes.data), float(sc.size)
    return p


def _snapped(breaks: np.ndarray, t_eval: np.ndarray) -> np.ndarray:
    """The breaks strictly inside t_eval's span, each within 1e-12 of the span of a sample
    replaced by that sample (a knot at k x 10 ms and a sample at 50 ms differ by an ulp; a
    segment that short stops LSODA: 'tout too close to t')."""
    eps = 1e-12 * max(1.0, abs(float(t_eval[-1])))
    b = np.asarray(breaks, dtype=float)
    b = b[(b > t_eval[0] + eps) & (b < t_eval[-1] - eps)]
    i = np.clip(np.searchsorted(t_eval, b), 1, t_eval.size - 1)
    near = np.where(np.abs(t_eval[i - 1] - b) < np.abs(t_eval[i] - b), t_eval[i - 1], t_eval[i])
    return np.unique(np.where(np.abs(near - b) <= eps, near, b))


def solve_expert(method: str, address: int, x0: np.ndarray, t_eval: np.ndarray, data: np.ndarray,
                 *, rtol: float, atol: float, breaks: np.ndarray | None = None,
                 max_steps: int = 100_000) -> tuple[np.ndarray, int, bool]:
    """Solve with numbalsoda ``method`` ('lsoda' or 'dop853') from t_eval[0], the states at
    ``t_eval`` (rows), the rhs evaluations and success. ``breaks`` (times inside the span):
    restart the integrator at each, as an expert does at the knots of a piecewise load (one
    call per segment, its t_eval the samples inside plus the segment's ends)."""
    import numbalsoda
    solver: Callable[..., tuple[np.ndarray, bool]] = getattr(numbalsoda, method)
    data[P_COUNT] = 0.0
    if breaks is None or breaks.size == 0:
        sol, ok = solver(address, x0, t_eval, data=data, rtol=rtol, atol=atol, mxstep=max_steps)
        return sol, int(data[P_COUNT]), bool(ok)
    out = np.empty((t_eval.size, x0.size))
    edges = np.concatenate(([t_eval[0]], _snapped(breaks, t_eval), [t_eval[-1]]))
    ok = _restart_kernel()(method == 'lsoda', address, np.asarray(x0, dtype=float), t_eval, edges, data,
                           rtol, atol, max_steps, out)
    return out, int(data[P_COUNT]), bool(ok)


@functools.lru_cache(maxsize=1)
def _restart_kernel() -> Any:
    """The compiled segment loop of :func:`solve_expert` (numbalsoda's solvers are numba
    functions: calling them per segment from Python would add its dispatch, ~10 us, per knot)."""
    import numba as nb
    import numbalsoda
    lsoda, dop853 = numbalsoda.lsoda, numbalsoda.dop853

    @nb.njit   # not cached: numba cannot pickle numbalsoda's ctypes bindings it closes over
    def run(use_lsoda, address, x0, t_eval, edges, data, rtol, atol, mxstep, out):  # pragma: no cover
        x = x0.copy()
        out[0, :] = x0
        j = 1                                   # next sample to fill
        for seg in range(edges.size - 1):
            a, b = edges[seg], edges[seg + 1]
            k = j
            while k < t_eval.size and t_eval[k] <= b:
                k += 1
            m = k - j                           # samples in (a, b]
            extra = 1 if (m == 0 or t_eval[k - 1] < b) else 0
            ts = np.empty(1 + m + extra)
            ts[0] = a
            for i in range(m):
                ts[1 + i] = t_eval[j + i]
            if extra:
                ts[m + 1] = b
            if use_lsoda:
                sol, ok = lsoda(address, x, ts, data, rtol, atol, mxstep)
            else:
                sol, ok = dop853(address, x, ts, data, rtol, atol, mxstep)
            if not ok:
                return False
            for i in range(m):
                out[j + i, :] = sol[1 + i, :]
            x = sol[ts.size - 1, :].copy()
            j = k
        return True
    return run
