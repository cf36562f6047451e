"""The expert baseline of `cvj-sim bench` (family ``baseline_expert``): the project's compiled
right-hand side (kernel/rhs_nb.rhs, engine and load inside) handed to a compiled integrator,
numbalsoda's LSODA (Petzold 1983, Hindmarsh's ODEPACK in Fortran) and DOP853 (Hairer,
Norsett & Wanner 1993, in C), through one ``numba.cfunc`` of numbalsoda's signature
``void f(double t, double *u, double *du, double *p)``.

The cfunc is compiled once for every scene: ``p`` points at a small float64 block holding
the addresses and lengths of the scene's ``ip``/``fp`` arrays (kernel/layout.py), the state
length and an evaluation counter, so a scene is data, not code. numbalsoda is optional
(``make bench`` installs it from ``requirements-bench.txt``; it builds from source with a
Fortran compiler and cmake): :func:`unavailable_reason` says in one line why the family is
skipped when it is not importable.
"""
from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any

import numpy as np

__all__ = ['EXPERT_METHODS', 'P_COUNT', 'P_FP', 'P_IP', 'P_LEN', 'P_NFP', 'P_NIP', 'P_NSTATE',
           'expert_cfunc', 'expert_data', 'skip_line', 'solve_expert', 'unavailable_reason']

EXPERT_METHODS = ('lsoda', 'dop853')
# layout of the parameter block p: addresses (exact in a double below 2**53) and lengths
P_IP, P_NIP, P_FP, P_NFP, P_NSTATE, P_COUNT = range(6)
P_LEN = 6


@functools.lru_cache(maxsize=1)
def unavailable_reason() -> str | None:
    """None when numbalsoda imports, else why not (one line)."""
    try:
        import numbalsoda  # noqa: F401
    except Exception as exc:   # ImportError, or a broken build's OSError loading its library
        first = (str(exc).splitlines() or [type(exc).__name__])[0]
        return f'numbalsoda not importable ({first[:120]})'
    return None


def skip_line(reason: str) -> str:
    """The one line the bench prints when the family is skipped."""
    return (f'[bench] baseline_expert skipped: {reason}; `make bench` installs it '
            f'(pip install -r requirements-bench.txt: builds from source, needs gfortran and cmake)')


@functools.lru_cache(maxsize=1)
def expert_cfunc() -> Any:
    """The numba cfunc (numbalsoda's rhs signature) over kernel/rhs_nb.rhs; compiled on first
    use (seconds: the whole rhs is inlined into it)."""
    import numba as nb
    from numba import types
    from numba.core import cgutils
    from numba.extending import intrinsic

    from cvj_ros.physics.kernel.rhs_nb import rhs

    @intrinsic
    def _as_pointer(typingctx: Any, addr: Any) -> Any:
        """An int64 address as a void pointer (for numba.carray)."""
        sig = types.voidptr(addr)

        def codegen(context: Any, builder: Any, signature: Any, args: Any) -> Any:
            return builder.inttoptr(args[0], cgutils.voidptr_t)
        return sig, codegen

    sig = types.void(types.double, types.CPointer(types.double), types.CPointer(types.double),
                     types.CPointer(types.double))

    @nb.cfunc(sig, cache=True)
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
    out[0] = x0
    edges = np.concatenate(([t_eval[0]], breaks[(breaks > t_eval[0]) & (breaks < t_eval[-1])], [t_eval[-1]]))
    x = np.asarray(x0, dtype=float).copy()
    for a, b in zip(edges[:-1], edges[1:]):
        inside = np.flatnonzero((t_eval > a) & (t_eval <= b))
        ts = np.concatenate(([a], t_eval[inside], [b] if (inside.size == 0 or t_eval[inside[-1]] < b) else []))
        sol, ok = solver(address, x, ts, data=data, rtol=rtol, atol=atol, mxstep=max_steps)
        if not ok:
            return out, int(data[P_COUNT]), False
        out[inside] = sol[1:1 + inside.size]
        x = sol[-1].copy()
    return out, int(data[P_COUNT]), True
