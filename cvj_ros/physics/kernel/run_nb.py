"""A whole offline run in one compiled call: start the stepper, integrate over the
samples, then every sample's outputs.

``Simulation.run`` without a progress callback used to make three compiled calls per run
(reset, the sampled or landing loop, ``outputs_nb.sample_outputs``) with Python between
them: ~15 us of a 30 us loose-tolerance stiff run (docs/solvers.md "Short runs"). The
``*_run`` functions here do the same three things in one call, calling the same compiled
functions in the same order, so a run's bytes do not change (test_run_nb.py compares every
method and sampling with the step-by-step path).

Arguments: the two packs ``fpk, ipk`` (below), the stepper's buffers ``fbuf, ibuf`` (every
float / int array of its state is a view of one of them, see ``KernelStepper.__init__``),
its state ``y``, the model's ``ip, fp``, the intermediate members' ``mfp`` (read where it
is, as ``fp``: a sweep patches both between runs), then the method's scalar options and ``h0`` (start
step proposal, 0 = HINIT); then per run ``e0`` (initial energy, J), ``X`` (the states at
``times``; X[0] is written here), ``XG`` (landing: the states at the grid's landings; X
itself when every landing is a sample) and the outputs ``pos, vel, eff, te, tl, res``.

The packs: every other array a run reads is one entry of a table in ``ipk`` (:func:`pack`):
a view of ``fbuf`` / ``ibuf`` (the stepper's state: ``fs, y_old, K, work``, Rosenbrock
``J, LU, ft``, ``cnt, piv``) or a copy in ``fpk`` / ``ipk`` made when the run is bound (read-only
data and scratch: ``x0``, the sample ``times``, the plan - ``grid, rows`` (landing: the grid of
landings and the grid row of every sample, empty when every landing is a sample; ``grid``
empty for dense sampling) and ``seg, brk, tb, two`` (dense: sample rows [seg[i, 0], seg[i, 1])
read by dense output up to breakpoint brk[i] (NaN: none), on which a step lands; ``tb`` (2,)
and ``two`` (2, n) are that landing's scratch) -, ``atol``, the method's tableau,
``sample_outputs``' shaft table ``tab``, ``fill_mid_samples``' ``mtab`` and the lean
outputs' ``skip``, empty for ``sample_outputs``). Unpacking them in compiled code is a few slices;
unboxing each as an argument cost ~60-90 ns (a meminfo allocated and freed, two atomic
reference counts): 39 array arguments were ~3 of a 19 us stiff run, 15 are ~1.

Returns ``(status, bad)``: ST_* of the integration (the stepper's arrays say where it
failed, as after the step-by-step path) and the first sample whose state is not finite, or
-1.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit, types
from numba.core import cgutils
from numba.core.imputils import impl_ret_borrowed
from numba.extending import intrinsic

from .borrow_nb import borrowed_all
from .outputs_nb import fill_mid_samples, sample_outputs, sample_outputs_lean
from .steppers_nb import (
    FS_ERROLD, FS_H, FS_T, FS_TOLD, ST_OK, dop853_land, dop853_sample, dopri5_land,
    dopri5_sample, rk4_land, rk4_sample, ros2_land, ros2_sample, ros_land, ros_sample)

# entries of the pack table (pack(): the arrays in this order); the method's own from E_M0
(E_X0, E_TIMES, E_GRID, E_BRK, E_TB, E_TWO, E_ATOL, E_FS, E_YOLD, E_K, E_WORK, E_ROWS, E_SEG,
 E_TAB, E_CNT, E_MTAB, E_SKIP) = range(17)
E_M0 = 17
# Rosenbrock (ros2 uses the first four): J, LU, ft, piv, then A, C, M, E, alpha, gsum, H
E_J, E_LU, E_FT, E_PIV, E_A, E_C, E_MW, E_E, E_ALPHA, E_GSUM, E_H = range(E_M0, E_M0 + 11)
# dop853: C, A, B, E5, E3, D, A_EXTRA, C_EXTRA
E_D8 = E_M0
# where an entry lives
B_FPK, B_FBUF, B_IPK, B_IBUF = 0, 1, 2, 3
_HEAD = 4   # table row: buffer, offset, shape[0], shape[1] (-1: 1-d)


def pack(entries: list[np.ndarray], fbuf: np.ndarray, ibuf: np.ndarray
         ) -> tuple[np.ndarray, np.ndarray]:
    """(fpk, ipk) of ``entries`` (1-d or 2-d C-contiguous float64 / int64 arrays, in the E_*
    order): a view of ``fbuf`` / ``ibuf`` is kept as its offset there (the run writes the
    stepper's state in place), any other array is copied after the table (ipk) or into fpk."""
    n_e = len(entries)
    table = np.zeros((n_e, _HEAD), np.int64)
    floats: list[np.ndarray] = []
    ints: list[np.ndarray] = []
    f_off, i_off = 0, 1 + n_e * _HEAD
    for e, a in enumerate(entries):
        if a.ndim not in (1, 2) or not a.flags.c_contiguous or a.dtype not in (np.float64,
                                                                                np.int64):
            raise ValueError(f'pack entry {e}: a 1-d or 2-d C-contiguous float64/int64 array')
        row = table[e]
        row[2] = a.shape[0]
        row[3] = a.shape[1] if a.ndim == 2 else -1
        base = fbuf if a.dtype == np.float64 else ibuf
        off = (a.ctypes.data - base.ctypes.data) // a.itemsize
        if a.size and np.shares_memory(a, base) and 0 <= off <= base.size - a.size:
            row[0] = B_FBUF if a.dtype == np.float64 else B_IBUF
            row[1] = off
        elif a.dtype == np.float64:
            row[0], row[1] = B_FPK, f_off
            floats.append(a.ravel())
            f_off += a.size
        else:
            row[0], row[1] = B_IPK, i_off
            ints.append(a.ravel())
            i_off += a.size
    fpk = np.concatenate(floats) if floats else np.zeros(0)
    ipk = np.concatenate([np.array([n_e], np.int64), table.ravel(), *ints])
    return np.ascontiguousarray(fpk, dtype=np.float64), ipk


@intrinsic
def _as_2d(typingctx, flat, d0, d1):
    """The 1-d C array ``flat`` (d0 * d1 items) as a (d0, d1) C array over the same data, as
    ``flat.reshape((d0, d1))`` gives it, built directly: numba's reshape calls a C helper
    (``numba_attempt_nocopy_reshape``) to find the strides, which a C-contiguous source does
    not need."""
    if not (isinstance(flat, types.Array) and flat.ndim == 1 and flat.layout == 'C'
            and isinstance(d0, types.Integer) and isinstance(d1, types.Integer)):
        return None
    arrty = types.Array(flat.dtype, 2, 'C')

    def codegen(context, builder, sig, args):
        from numba.np.arrayobj import populate_array
        src = context.make_array(flat)(context, builder, value=args[0])
        rows = context.cast(builder, args[1], sig.args[1], types.intp)
        cols = context.cast(builder, args[2], sig.args[2], types.intp)
        ary = context.make_array(arrty)(context, builder)
        populate_array(ary, data=src.data, shape=cgutils.pack_array(builder, [rows, cols]),
                       strides=cgutils.pack_array(builder, [builder.mul(cols, src.itemsize),
                                                            src.itemsize]),
                       itemsize=src.itemsize, meminfo=src.meminfo, parent=src.parent)
        return impl_ret_borrowed(context, builder, arrty, ary._getvalue())

    return arrty(flat, d0, d1), codegen


@njit(cache=True, inline='always')
def _view1(e, ipk, pk, buf, in_buf):
    """1-d entry e of the pack table: in ``buf`` (the stepper's buffer) when the table says
    ``in_buf``, else in the pack ``pk``."""
    r = 1 + _HEAD * e
    o = ipk[r + 1]
    if ipk[r] == in_buf:
        return buf[o:o + ipk[r + 2]]
    return pk[o:o + ipk[r + 2]]


@njit(cache=True, inline='always')
def _view2(e, ipk, pk, buf, in_buf):
    """2-d entry e of the pack table (as :func:`_view1`)."""
    r = 1 + _HEAD * e
    o = ipk[r + 1]
    d0 = ipk[r + 2]
    d1 = ipk[r + 3]
    if ipk[r] == in_buf:
        return _as_2d(buf[o:o + d0 * d1], d0, d1)
    return _as_2d(pk[o:o + d0 * d1], d0, d1)


@njit(cache=True, inline='always')
def _f1(e, fpk, ipk, fbuf):
    """1-d float entry e."""
    return _view1(e, ipk, fpk, fbuf, B_FBUF)


@njit(cache=True, inline='always')
def _f2(e, fpk, ipk, fbuf):
    """2-d float entry e."""
    return _view2(e, ipk, fpk, fbuf, B_FBUF)


@njit(cache=True, inline='always')
def _i1(e, ipk, ibuf):
    """1-d int entry e."""
    return _view1(e, ipk, ipk, ibuf, B_IBUF)


@njit(cache=True, inline='always')
def _i2(e, ipk, ibuf):
    """2-d int entry e."""
    return _view2(e, ipk, ipk, ibuf, B_IBUF)


@njit(cache=True, inline='always')
def _outputs(times, X, ip, fp, tab, e0, pos, vel, eff, te, tl, res, ipk, ibuf, mfp):
    """``sample_outputs`` and, when every sample is finite, the intermediate members'
    angles and speeds (``fill_mid_samples`` with the pack's ``mtab`` and ``mfp``): what
    ``Simulation.run`` did after the call, in the same order. With a non-empty ``skip``
    entry (a sweep's lean run, ``outputs_nb.unread_angles``): ``sample_outputs_lean``
    instead. Returns the first non-finite sample, or -1."""
    skip = _i1(E_SKIP, ipk, ibuf)
    if skip.shape[0] > 0:
        bad = sample_outputs_lean(times, X, ip, fp, tab, e0, skip, pos, vel, eff, te, tl, res)
    else:
        bad = sample_outputs(times, X, ip, fp, tab, e0, pos, vel, eff, te, tl, res)
    mtab = _i2(E_MTAB, ipk, ibuf)
    if bad < 0 and mtab.shape[0] > 0:
        fill_mid_samples(pos, vel, mtab, mfp)
    return bad


@njit(cache=True, inline='always')
def _common(fpk, ipk, fbuf, ibuf):
    """The entries every method reads: x0, times, grid, brk, tb, two, atol, fs, y_old, K,
    work, rows, seg, tab, cnt."""
    return (_f1(E_X0, fpk, ipk, fbuf), _f1(E_TIMES, fpk, ipk, fbuf),
            _f1(E_GRID, fpk, ipk, fbuf), _f1(E_BRK, fpk, ipk, fbuf), _f1(E_TB, fpk, ipk, fbuf),
            _f2(E_TWO, fpk, ipk, fbuf), _f1(E_ATOL, fpk, ipk, fbuf),
            _f1(E_FS, fpk, ipk, fbuf), _f1(E_YOLD, fpk, ipk, fbuf), _f2(E_K, fpk, ipk, fbuf),
            _f2(E_WORK, fpk, ipk, fbuf), _i1(E_ROWS, ipk, ibuf), _i2(E_SEG, ipk, ibuf),
            _i2(E_TAB, ipk, ibuf), _i1(E_CNT, ipk, ibuf))


@njit(cache=True, inline='always')
def _linear(fpk, ipk, fbuf, ibuf):
    """The linearly implicit methods' state entries: J, LU, ft, piv."""
    return (_f2(E_J, fpk, ipk, fbuf), _f2(E_LU, fpk, ipk, fbuf), _f1(E_FT, fpk, ipk, fbuf),
            _i1(E_PIV, ipk, ibuf))


@njit(cache=True, inline='always')
def _start(x0, h0, X, fbuf, ibuf, y, y_old, fs):
    """``KernelStepper._set_start(0, x0)`` (every array zero, then y, the h given) and X[0]."""
    for i in range(fbuf.shape[0]):
        fbuf[i] = 0.0
    for i in range(ibuf.shape[0]):
        ibuf[i] = 0
    for i in range(x0.shape[0]):
        y[i] = x0[i]
        y_old[i] = x0[i]
        X[0, i] = x0[i]
    fs[FS_ERROLD] = 1e-4
    fs[FS_T] = 0.0
    fs[FS_TOLD] = 0.0
    fs[FS_H] = h0


@njit(cache=True, inline='always')
def _gather(X, XG, rows):
    """X[k] = XG[rows[k]] for k >= 1 (landing: the samples among the grid's landings; rows
    is empty when every landing is a sample and XG is X itself: nothing to copy)."""
    for k in range(1, rows.shape[0]):
        r = rows[k]
        for i in range(X.shape[1]):
            X[k, i] = XG[r, i]


@njit(cache=True, inline='always')
def _to_breakpoint(b, fs, tb):
    """True when a step must land on breakpoint b (not NaN, ahead of t); then tb = (t, b),
    the landing grid of that one landing (``advance_to(b)`` of the step-by-step path)."""
    if math.isnan(b) or not b > fs[FS_T]:
        return False
    tb[0] = fs[FS_T]
    tb[1] = b
    return True


@njit(cache=True)
def ros_run(fpk, ipk, fbuf, ibuf, y, ip, fp, mfp, h0, rtol, max_step, autonomous, constant_jac, gamma,
            order, fac_max, hermite_row, e0, X, XG, pos, vel, eff, te, tl, res):
    """The Rosenbrock methods (RODAS5P, rodas4, rodas3): ros_land or ros_sample / ros_land, then
    sample_outputs."""
    (fpk, ipk, fbuf, ibuf, y, ip, fp, mfp, X, XG) = borrowed_all((fpk, ipk, fbuf, ibuf, y, ip,
                                                                 fp, mfp, X, XG))
    (x0, times, grid, brk, tb, two, atol, fs, y_old, K, work, rows, seg, tab,
     cnt) = _common(fpk, ipk, fbuf, ibuf)
    J, LU, ft, piv = _linear(fpk, ipk, fbuf, ibuf)
    A, C, H = _f2(E_A, fpk, ipk, fbuf), _f2(E_C, fpk, ipk, fbuf), _f2(E_H, fpk, ipk, fbuf)
    M, E = _f1(E_MW, fpk, ipk, fbuf), _f1(E_E, fpk, ipk, fbuf)
    alpha, gsum = _f1(E_ALPHA, fpk, ipk, fbuf), _f1(E_GSUM, fpk, ipk, fbuf)
    _start(x0, h0, X, fbuf, ibuf, y, y_old, fs)
    if grid.shape[0] > 0:
        st, _k = ros_land(grid, XG, y, y_old, ip, fp, fs, cnt, rtol, atol, max_step,
                          autonomous, constant_jac, gamma, A, C, M, E, alpha, gsum, order,
                          fac_max, J, LU, piv, ft, K, work)
        if st != ST_OK:
            return st, -1
        _gather(X, XG, rows)
    else:
        for i in range(seg.shape[0]):
            k, k_end = seg[i, 0], seg[i, 1]
            if k_end > k:
                st, _k = ros_sample(times[k:k_end], X[k:k_end], y, y_old, ip, fp, fs, cnt,
                                    rtol, atol, max_step, autonomous, constant_jac, gamma, A,
                                    C, M, E, alpha, gsum, order, fac_max, J, LU, piv, ft, K,
                                    work, H, hermite_row)
                if st != ST_OK:
                    return st, -1
            if _to_breakpoint(brk[i], fs, tb):
                st, _k = ros_land(tb, two, y, y_old, ip, fp, fs, cnt, rtol, atol,
                                  max_step, autonomous, constant_jac, gamma, A, C, M, E,
                                  alpha, gsum, order, fac_max, J, LU, piv, ft, K, work)
                if st != ST_OK:
                    return st, -1
    return ST_OK, _outputs(times, X, ip, fp, tab, e0, pos, vel, eff, te, tl, res, ipk, ibuf,
                           mfp)


@njit(cache=True)
def dopri5_run(fpk, ipk, fbuf, ibuf, y, ip, fp, mfp, h0, rtol, max_step, e0, X, XG, pos, vel, eff,
               te, tl, res):
    """dopri5: dopri5_land or dopri5_sample / dopri5_land, then sample_outputs."""
    (fpk, ipk, fbuf, ibuf, y, ip, fp, mfp, X, XG) = borrowed_all((fpk, ipk, fbuf, ibuf, y, ip,
                                                                 fp, mfp, X, XG))
    (x0, times, grid, brk, tb, two, atol, fs, y_old, K, work, rows, seg, tab,
     cnt) = _common(fpk, ipk, fbuf, ibuf)
    _start(x0, h0, X, fbuf, ibuf, y, y_old, fs)
    if grid.shape[0] > 0:
        st, _k = dopri5_land(grid, XG, y, y_old, ip, fp, fs, cnt, rtol, atol, max_step, K,
                             work)
        if st != ST_OK:
            return st, -1
        _gather(X, XG, rows)
    else:
        for i in range(seg.shape[0]):
            k, k_end = seg[i, 0], seg[i, 1]
            if k_end > k:
                st, _k = dopri5_sample(times[k:k_end], y, y_old, ip, fp, fs, cnt, rtol,
                                       atol, max_step, K, work, X[k:k_end])
                if st != ST_OK:
                    return st, -1
            if _to_breakpoint(brk[i], fs, tb):
                st, _k = dopri5_land(tb, two, y, y_old, ip, fp, fs, cnt, rtol, atol,
                                     max_step, K, work)
                if st != ST_OK:
                    return st, -1
    return ST_OK, _outputs(times, X, ip, fp, tab, e0, pos, vel, eff, te, tl, res, ipk, ibuf,
                           mfp)


@njit(cache=True)
def dop853_run(fpk, ipk, fbuf, ibuf, y, ip, fp, mfp, h0, rtol, max_step, e0, X, XG, pos, vel, eff,
               te, tl, res):
    """dop853: dop853_land or dop853_sample / dop853_land, then sample_outputs."""
    (fpk, ipk, fbuf, ibuf, y, ip, fp, mfp, X, XG) = borrowed_all((fpk, ipk, fbuf, ibuf, y, ip,
                                                                 fp, mfp, X, XG))
    (x0, times, grid, brk, tb, two, atol, fs, y_old, K, work, rows, seg, tab,
     cnt) = _common(fpk, ipk, fbuf, ibuf)
    C, A = _f1(E_D8, fpk, ipk, fbuf), _f2(E_D8 + 1, fpk, ipk, fbuf)
    B = _f1(E_D8 + 2, fpk, ipk, fbuf)
    E5, E3 = _f1(E_D8 + 3, fpk, ipk, fbuf), _f1(E_D8 + 4, fpk, ipk, fbuf)
    D, A_EXTRA = _f2(E_D8 + 5, fpk, ipk, fbuf), _f2(E_D8 + 6, fpk, ipk, fbuf)
    C_EXTRA = _f1(E_D8 + 7, fpk, ipk, fbuf)
    _start(x0, h0, X, fbuf, ibuf, y, y_old, fs)
    if grid.shape[0] > 0:
        st, _k = dop853_land(grid, XG, y, y_old, ip, fp, fs, cnt, rtol, atol, max_step, C, A,
                             B, E5, E3, K, work)
        if st != ST_OK:
            return st, -1
        _gather(X, XG, rows)
    else:
        for i in range(seg.shape[0]):
            k, k_end = seg[i, 0], seg[i, 1]
            if k_end > k:
                st, _k = dop853_sample(times[k:k_end], X[k:k_end], y, y_old, ip, fp, fs, cnt,
                                       rtol, atol, max_step, C, A, B, E5, E3, D, A_EXTRA,
                                       C_EXTRA, K, work)
                if st != ST_OK:
                    return st, -1
            if _to_breakpoint(brk[i], fs, tb):
                st, _k = dop853_land(tb, two, y, y_old, ip, fp, fs, cnt, rtol, atol,
                                     max_step, C, A, B, E5, E3, K, work)
                if st != ST_OK:
                    return st, -1
    return ST_OK, _outputs(times, X, ip, fp, tab, e0, pos, vel, eff, te, tl, res, ipk, ibuf,
                           mfp)


@njit(cache=True)
def rk4_run(fpk, ipk, fbuf, ibuf, y, ip, fp, mfp, h0, e0, X, XG, pos, vel, eff, te, tl, res):
    """rk4: rk4_land or rk4_sample / rk4_land, then sample_outputs."""
    (fpk, ipk, fbuf, ibuf, y, ip, fp, mfp, X, XG) = borrowed_all((fpk, ipk, fbuf, ibuf, y, ip,
                                                                 fp, mfp, X, XG))
    (x0, times, grid, brk, tb, two, atol, fs, y_old, K, work, rows, seg, tab,
     cnt) = _common(fpk, ipk, fbuf, ibuf)
    _start(x0, h0, X, fbuf, ibuf, y, y_old, fs)
    if grid.shape[0] > 0:
        st, _k = rk4_land(grid, XG, y, y_old, ip, fp, fs, cnt, K, work)
        if st != ST_OK:
            return st, -1
        _gather(X, XG, rows)
    else:
        for i in range(seg.shape[0]):
            k, k_end = seg[i, 0], seg[i, 1]
            if k_end > k:
                st, _k = rk4_sample(times[k:k_end], y, y_old, ip, fp, fs, cnt, K, work,
                                    X[k:k_end])
                if st != ST_OK:
                    return st, -1
            if _to_breakpoint(brk[i], fs, tb):
                st, _k = rk4_land(tb, two, y, y_old, ip, fp, fs, cnt, K, work)
                if st != ST_OK:
                    return st, -1
    return ST_OK, _outputs(times, X, ip, fp, tab, e0, pos, vel, eff, te, tl, res, ipk, ibuf,
                           mfp)


@njit(cache=True)
def ros2_run(fpk, ipk, fbuf, ibuf, y, ip, fp, mfp, h0, autonomous, constant_jac, e0, X, XG, pos,
             vel, eff, te, tl, res):
    """ros2: ros2_land or ros2_sample / ros2_land, then sample_outputs."""
    (fpk, ipk, fbuf, ibuf, y, ip, fp, mfp, X, XG) = borrowed_all((fpk, ipk, fbuf, ibuf, y, ip,
                                                                 fp, mfp, X, XG))
    (x0, times, grid, brk, tb, two, atol, fs, y_old, K, work, rows, seg, tab,
     cnt) = _common(fpk, ipk, fbuf, ibuf)
    J, LU, ft, piv = _linear(fpk, ipk, fbuf, ibuf)
    _start(x0, h0, X, fbuf, ibuf, y, y_old, fs)
    if grid.shape[0] > 0:
        st, _k = ros2_land(grid, XG, y, y_old, ip, fp, fs, cnt, autonomous, constant_jac, J,
                           LU, piv, ft, K, work)
        if st != ST_OK:
            return st, -1
        _gather(X, XG, rows)
    else:
        for i in range(seg.shape[0]):
            k, k_end = seg[i, 0], seg[i, 1]
            if k_end > k:
                st, _k = ros2_sample(times[k:k_end], X[k:k_end], y, y_old, ip, fp, fs, cnt,
                                     autonomous, constant_jac, J, LU, piv, ft, K, work)
                if st != ST_OK:
                    return st, -1
            if _to_breakpoint(brk[i], fs, tb):
                st, _k = ros2_land(tb, two, y, y_old, ip, fp, fs, cnt, autonomous,
                                   constant_jac, J, LU, piv, ft, K, work)
                if st != ST_OK:
                    return st, -1
    return ST_OK, _outputs(times, X, ip, fp, tab, e0, pos, vel, eff, te, tl, res, ipk, ibuf,
                           mfp)
