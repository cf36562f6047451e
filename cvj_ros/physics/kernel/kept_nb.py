"""A kept Rosenbrock run called with two scalars: its arrays read by address.

``Simulation.run(reuse_trace=True)`` calls the same compiled run (``run_nb.ros_run``) with
the same 16 arrays and 9 scalar options every time. numba's entry point unboxes each
argument from Python: an array costs a meminfo allocated and freed and two reference
counts, a scalar a conversion. ``ros_run_kept(table, e0)`` takes the address of one int64
table instead (:func:`kept_table`: every array's address and shape, the integer options,
and the address of a float64 array of the float options), rebuilds the arrays as
``numba.carray`` views (no meminfo: no allocation and no reference count, as
``borrow_nb.borrowed``) and calls ``ros_run`` with the same arguments and types: the same
compiled code, so the same bytes. The table holds addresses only: :func:`kept_call` keeps
every array alive with the call, and the arrays must stay where they are (numpy arrays
never move; a sweep patches ``fp`` and ``mfp`` in place).
"""
from __future__ import annotations

import contextlib
import functools
from typing import Any, Callable, Sequence

import numpy as np
from numba import carray, njit, types
from numba.extending import intrinsic

from .run_nb import ros_run


def _pointer_to(dtype: Any) -> Any:
    """An intrinsic: the integer address ``addr`` as a pointer to ``dtype``, for
    ``numba.carray`` (whose arrays have no meminfo: views of memory the caller keeps alive
    and in place)."""
    ptr = types.CPointer(dtype)

    @intrinsic
    def pointer(typingctx, addr):
        if not isinstance(addr, types.Integer):
            return None

        def codegen(context, builder, sig, args):
            value = context.cast(builder, args[0], sig.args[0], types.intp)
            return builder.inttoptr(value, context.get_value_type(ptr))

        return ptr(addr), codegen

    return pointer


#: float64 / int64 pointer at an integer address (``array.ctypes.data``)
f8_pointer = _pointer_to(types.float64)
i8_pointer = _pointer_to(types.int64)

#: ros_run's array arguments in its order (float64 unless in _INT_ROWS), with their ndim;
#: row 0 of the table is the float options (h0, rtol, max_step, gamma, fac_max)
_ROWS = 17
_NDIM = (1,  1, 1, 1, 1, 1, 1, 1, 1,  2, 2, 2, 2, 2, 1, 1, 1)
_INT_ROWS = (2, 4, 6)     # ipk, ibuf, ip
#: the integer options after the rows: autonomous, constant_jac, order, hermite_row
K_INTS = 3 * _ROWS
TABLE_LEN = K_INTS + 4


@njit(cache=True, inline='always')
def _f1(T, r):
    return carray(f8_pointer(T[3 * r]), (T[3 * r + 1],))


@njit(cache=True, inline='always')
def _f2(T, r):
    return carray(f8_pointer(T[3 * r]), (T[3 * r + 1], T[3 * r + 2]))


@njit(cache=True, inline='always')
def _i1(T, r):
    return carray(i8_pointer(T[3 * r]), (T[3 * r + 1],))


@njit(cache=True)
def ros_run_kept(table, e0):
    """``run_nb.ros_run(fpk, ipk, fbuf, ibuf, y, ip, fp, mfp, h0, rtol, max_step,
    autonomous, constant_jac, gamma, order, fac_max, hermite_row, e0, X, XG, pos, vel, eff,
    te, tl, res)`` with the arrays and options of the table at address ``table``
    (:func:`kept_table`); returns ros_run's (status, bad)."""
    T = carray(i8_pointer(table), (TABLE_LEN,))
    F = _f1(T, 0)
    return ros_run(_f1(T, 1), _i1(T, 2), _f1(T, 3), _i1(T, 4), _f1(T, 5), _i1(T, 6),
                   _f1(T, 7), _f1(T, 8), F[0], F[1], F[2], T[K_INTS] != 0,
                   T[K_INTS + 1] != 0, F[3], T[K_INTS + 2], F[4], T[K_INTS + 3], e0,
                   _f2(T, 9), _f2(T, 10), _f2(T, 11), _f2(T, 12), _f2(T, 13), _f1(T, 14),
                   _f1(T, 15), _f1(T, 16))


def kept_table(head: Sequence[Any], per_run: Sequence[np.ndarray]
               ) -> tuple[np.ndarray, np.ndarray] | None:
    """(table, float options) of :func:`ros_run_kept` for ros_run's bound arguments
    ``head`` (fpk, ipk, fbuf, ibuf, y, ip, fp, mfp, h0, rtol, max_step, autonomous,
    constant_jac, gamma, order, fac_max, hermite_row) and ``per_run`` (X, XG, pos, vel,
    eff, te, tl, res); None when an array is not C-contiguous float64/int64 of ros_run's
    ndim (then the run is called as it is)."""
    (fpk, ipk, fbuf, ibuf, y, ip, fp, mfp, h0, rtol, max_step, autonomous, constant_jac,
     gamma, order, fac_max, hermite_row) = head
    floats = np.array([h0, rtol, max_step, gamma, fac_max], np.float64)
    arrays = (floats, fpk, ipk, fbuf, ibuf, y, ip, fp, mfp, *per_run)
    if len(arrays) != _ROWS:
        return None
    table = np.zeros(TABLE_LEN, np.int64)
    for r, a in enumerate(arrays):
        dtype = np.int64 if r in _INT_ROWS else np.float64
        if not (isinstance(a, np.ndarray) and a.dtype == dtype and a.ndim == _NDIM[r]
                and a.flags.c_contiguous and a.flags.writeable):
            return None
        table[3 * r] = a.ctypes.data
        table[3 * r + 1] = a.shape[0]
        table[3 * r + 2] = a.shape[1] if a.ndim == 2 else -1
    table[K_INTS:] = (int(bool(autonomous)), int(bool(constant_jac)), int(order),
                      int(hermite_row))
    return table, floats


_SIG = (types.int64, types.float64)
_ENTRY: dict[Any, Callable[..., Any]] = {}


def kept_entry(dispatcher: Any = ros_run_kept) -> Callable[..., Any]:
    """The compiled entry point of ``dispatcher(table, e0)`` (:func:`ros_run_kept`), loaded
    from the disk cache or compiled by signature - never by a call, which would run the
    run - and kept per process."""
    entry = _ENTRY.get(dispatcher)
    if entry is None:
        from . import _will_compile, compiling, load_cached
        entry = load_cached(dispatcher, (0, 0.0))
        if entry is None:
            with compiling(dispatcher) if _will_compile(dispatcher) else contextlib.nullcontext():
                dispatcher.compile(_SIG)
            entry = dispatcher.overloads[_SIG].entry_point
        _ENTRY[dispatcher] = entry
    return entry


def kept_call(head: Sequence[Any], per_run: Sequence[np.ndarray]
              ) -> Callable[[float], tuple[int, int]] | None:
    """``call(e0) -> (status, bad)``, the same as ros_run's entry point called with
    ``(*head, e0, *per_run)``, through :func:`ros_run_kept`; it keeps ``head``, ``per_run``
    and the table alive. None when :func:`kept_table` is."""
    made = kept_table(head, per_run)
    if made is None:
        return None
    table, floats = made
    addr = int(table.ctypes.data)
    call = functools.partial(kept_entry(), addr)
    call.keep = (table, floats, tuple(head), tuple(per_run))   # type: ignore[attr-defined]
    return call
