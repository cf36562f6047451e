"""A whole offline run in one compiled call (issue 9): start the stepper, integrate over the
samples, then every sample's outputs.

``Simulation.run`` without a progress callback used to make three compiled calls per run
(reset, the sampled or landing loop, ``outputs_nb.sample_outputs``) with Python between
them: ~15 us of a 30 us loose-tolerance stiff run (docs/solvers.md "Short runs"). The
``*_run`` functions here do the same three things in one call, calling the same compiled
functions in the same order, so a run's bytes do not change (test_run_nb.py compares every
method and sampling with the step-by-step path).

Arguments, in order - first what is fixed for a Simulation's options (bound once,
``KernelStepper.bind_run``), then what each run allocates: ``x0, h0`` (start state and
step proposal, 0 = HINIT), ``times`` (sample times, s), the plan - ``grid, rows``
(landing: the grid of landings and the grid row of every sample, empty when every landing
is a sample; ``grid`` empty for dense sampling) and ``seg, brk, tb, two`` (dense: sample rows [seg[i, 0], seg[i, 1]) read by
dense output up to breakpoint brk[i] (NaN: none), on which a step lands; ``tb`` (2,) and
``two`` (2, n) are that landing's scratch) -, the stepper's buffers ``fbuf, ibuf`` (every
float / int array of its state is a view of one of them, see ``KernelStepper.__init__``),
the state views and method options of the method's sampled loop, ``sample_outputs``'
``tab``; then per run ``e0`` (initial energy, J), ``X`` (the states at ``times``; X[0] is
written here), ``XG`` (landing: the states at the grid's landings; X itself when every
landing is a sample) and the outputs ``pos, vel, eff, te, tl, res``.

Returns ``(status, bad)``: ST_* of the integration (the stepper's arrays say where it
failed, as after the step-by-step path) and the first sample whose state is not finite, or
-1.
"""
from __future__ import annotations

import math

from numba import njit

from .borrow_nb import borrowed_all
from .outputs_nb import sample_outputs
from .steppers_nb import (
    FS_ERROLD, FS_H, FS_T, FS_TOLD, ST_OK, dop853_land, dop853_sample, dopri5_land,
    dopri5_sample, rk4_land, rk4_sample, ros2_land, ros2_sample, ros_land, ros_sample)


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
def ros_run(x0, h0, times, grid, rows, seg, brk, tb, two, fbuf, ibuf, y, y_old, ip, fp, fs,
            cnt, rtol, atol, max_step, autonomous, constant_jac, gamma, A, C, M, E, alpha,
            gsum, order, fac_max, J, LU, piv, ft, K, work, H, hermite_row, tab, e0, X, XG, pos,
            vel, eff, te, tl, res):
    """The Rosenbrock methods (rodas4, RODAS5P): ros_land or ros_sample / ros_land, then
    sample_outputs."""
    (x0, times, X, grid, XG, rows, seg, brk, tb, two, fbuf, ibuf, y, y_old, ip, fp, fs, cnt,
     A, C, M, E, alpha, gsum, J, LU, piv, ft, K, work, H) = borrowed_all((
        x0, times, X, grid, XG, rows, seg, brk, tb, two, fbuf, ibuf, y, y_old, ip, fp, fs, cnt,
        A, C, M, E, alpha, gsum, J, LU, piv, ft, K, work, H))
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
    return ST_OK, sample_outputs(times, X, ip, fp, tab, e0, pos, vel, eff, te, tl, res)


@njit(cache=True)
def dopri5_run(x0, h0, times, grid, rows, seg, brk, tb, two, fbuf, ibuf, y, y_old, ip, fp,
               fs, cnt, rtol, atol, max_step, K, work, tab, e0, X, XG, pos, vel, eff,
               te, tl, res):
    """dopri5: dopri5_land or dopri5_sample / dopri5_land, then sample_outputs."""
    (x0, times, X, grid, XG, rows, seg, brk, tb, two, fbuf, ibuf, y, y_old, ip, fp, fs, cnt,
     K, work) = borrowed_all((x0, times, X, grid, XG, rows, seg, brk, tb, two, fbuf, ibuf, y,
                              y_old, ip, fp, fs, cnt, K, work))
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
    return ST_OK, sample_outputs(times, X, ip, fp, tab, e0, pos, vel, eff, te, tl, res)


@njit(cache=True)
def dop853_run(x0, h0, times, grid, rows, seg, brk, tb, two, fbuf, ibuf, y, y_old, ip, fp,
               fs, cnt, rtol, atol, max_step, C, A, B, E5, E3, D, A_EXTRA, C_EXTRA, K,
               work, tab, e0, X, XG, pos, vel, eff, te, tl, res):
    """dop853: dop853_land or dop853_sample / dop853_land, then sample_outputs."""
    (x0, times, X, grid, XG, rows, seg, brk, tb, two, fbuf, ibuf, y, y_old, ip, fp, fs, cnt,
     C, A, B, E5, E3, D, A_EXTRA, C_EXTRA, K, work) = borrowed_all((
        x0, times, X, grid, XG, rows, seg, brk, tb, two, fbuf, ibuf, y, y_old, ip, fp, fs, cnt,
        C, A, B, E5, E3, D, A_EXTRA, C_EXTRA, K, work))
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
    return ST_OK, sample_outputs(times, X, ip, fp, tab, e0, pos, vel, eff, te, tl, res)


@njit(cache=True)
def rk4_run(x0, h0, times, grid, rows, seg, brk, tb, two, fbuf, ibuf, y, y_old, ip, fp, fs,
            cnt, K, work, tab, e0, X, XG, pos, vel, eff, te, tl, res):
    """rk4: rk4_land or rk4_sample / rk4_land, then sample_outputs."""
    (x0, times, X, grid, XG, rows, seg, brk, tb, two, fbuf, ibuf, y, y_old, ip, fp, fs, cnt,
     K, work) = borrowed_all((x0, times, X, grid, XG, rows, seg, brk, tb, two, fbuf, ibuf, y,
                              y_old, ip, fp, fs, cnt, K, work))
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
    return ST_OK, sample_outputs(times, X, ip, fp, tab, e0, pos, vel, eff, te, tl, res)


@njit(cache=True)
def ros2_run(x0, h0, times, grid, rows, seg, brk, tb, two, fbuf, ibuf, y, y_old, ip, fp, fs,
             cnt, autonomous, constant_jac, J, LU, piv, ft, K, work, tab, e0, X, XG, pos,
             vel, eff, te, tl, res):
    """ros2: ros2_land or ros2_sample / ros2_land, then sample_outputs."""
    (x0, times, X, grid, XG, rows, seg, brk, tb, two, fbuf, ibuf, y, y_old, ip, fp, fs, cnt,
     J, LU, piv, ft, K, work) = borrowed_all((
        x0, times, X, grid, XG, rows, seg, brk, tb, two, fbuf, ibuf, y, y_old, ip, fp, fs, cnt,
        J, LU, piv, ft, K, work))
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
    return ST_OK, sample_outputs(times, X, ip, fp, tab, e0, pos, vel, eff, te, tl, res)
