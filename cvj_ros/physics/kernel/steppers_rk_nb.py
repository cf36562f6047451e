"""Compiled (numba) steppers of the efficient explicit FSAL pairs with interpolants:
Tsitouras 5(4) ('tsit5') and Verner's 6(5) ('vern6'), one generic stepper over the arrays
of ``physics/erk_tableaux.py`` (C, A, B, E, P; S stages, the last one f(t + h, y_new)).

Same conventions as ``steppers_nb`` (its state arrays ``fs``/``cnt``, return codes, hand-
written loops in a fixed order, the rhs as the module global ``RHS``; toy right-hand sides
get a private uncached copy: ``kernel.stepper.steppers_for``) and the same error control as
its dopri5: scaled RMS norm of ``h sum_j E_j k_j`` over ``atol + rtol max(|y|, |y_new|)``,
Hairer's HINIT first step and PI controller (safety 0.9, fac 0.2..10, beta 0.04, exponent
1/(q+1) - 0.75 beta with q the embedded order), a step within 1 % of t_bound clipped onto it.

K rows: 0..S-1 the step's stages (K[S-1] = f(t_new, y_new), moved to K[0] at the next step),
S.. the interpolant's extra stages, evaluated once per step on the first dense output.
Dense output: y_old + h sum_j b_j(theta) k_j, b_j(theta) = sum_d P[j, d] theta^(d+1).

Sources: Tsitouras, Comput. Math. Appl. 62 (2011); Verner, Numer. Algorithms 53 (2010);
Hairer, Norsett & Wanner I, sec. II.4 (HINIT), IV.2 (PI control).
"""
from __future__ import annotations

import math

from numba import njit

from .borrow_nb import borrowed_all
from .rhs_nb import rhs as RHS
from .steppers_nb import (
    _EPS, BETA, C_BADIDX, C_DENSE, C_HAVEF, C_LASTREJ, C_NACC, C_NFEV, C_NREJ, FAC_MIN,
    FAC_MAX, FS_H, FS_HLAST, FS_T, FS_TBAD, FS_TOLD, SAFETY, ST_NONFINITE, ST_OK,
    ST_UNDERFLOW, _first_nonfinite, _proposal, _store_row)

__all__ = ['erk_advance', 'erk_dense', 'erk_land', 'erk_sample', 'erk_step', 'erk_step_once']


@njit(cache=True)
def _hinit(y, f0, ip, fp, fs, cnt, rtol, atol, max_step, order, tmp, f1):
    """Hairer's HINIT, the arithmetic of ``steppers_nb._initial_step`` on this module's RHS;
    one fev. Returns h0 (s), or -1.0 when the error norm overflows."""
    n = y.shape[0]
    t = fs[FS_T]
    s0 = 0.0
    s1 = 0.0
    for i in range(n):
        sc = abs(y[i]) * rtol + atol[i]
        s0 += (y[i] / sc) ** 2
        s1 += (f0[i] / sc) ** 2
    d0 = math.sqrt(s0 / n)
    d1 = math.sqrt(s1 / n)
    if not (math.isfinite(d0) and math.isfinite(d1)):
        return -1.0
    h0 = 1e-6 if (d0 < 1e-5 or d1 < 1e-5) else 0.01 * d0 / d1
    h0 = min(h0, max_step)
    for i in range(n):
        tmp[i] = y[i] + h0 * f0[i]
    RHS(t + h0, tmp, ip, fp, f1)
    cnt[C_NFEV] += 1
    s2 = 0.0
    for i in range(n):
        sc = abs(y[i]) * rtol + atol[i]
        s2 += ((f1[i] - f0[i]) / sc) ** 2
    d2 = math.sqrt(s2 / n) / h0
    if not math.isfinite(d2):
        return -1.0
    dmax = max(d1, d2)
    if dmax <= 1e-15:
        h1 = max(1e-6, h0 * 1e-3)
    else:
        h1 = (0.01 / dmax) ** (1.0 / (order + 1))
    return min(100 * h0, h1, max_step)


@njit(cache=True, inline='always')
def _attempt(h, y, ip, fp, fs, cnt, rtol, atol, C, A, B, E, K, work):
    """One attempt of size h from (fs[FS_T], y) with K[0] = f(t, y): stages K[1..S-2],
    work[1] = y_new = y + h sum_j B_j k_j, K[S-1] = f(t + h, y_new) (S-1 fev). Returns the
    scaled RMS error (NaN when a stage is not finite)."""
    n = y.shape[0]
    ns = B.shape[0]
    t = fs[FS_T]
    arg = work[0]
    for s in range(1, ns - 1):
        for i in range(n):
            arg[i] = y[i]
        for j in range(s):
            c = h * A[s, j]
            if c != 0.0:
                kj = K[j]
                for i in range(n):
                    arg[i] += c * kj[i]
        RHS(t + C[s] * h, arg, ip, fp, K[s])
    ynew = work[1]
    for i in range(n):
        ynew[i] = y[i]
    for j in range(ns - 1):
        c = h * B[j]
        if c != 0.0:
            kj = K[j]
            for i in range(n):
                ynew[i] += c * kj[i]
    RHS(t + h, ynew, ip, fp, K[ns - 1])
    cnt[C_NFEV] += ns - 1
    ss = 0.0
    for i in range(n):
        e = 0.0
        for j in range(ns):
            e += E[j] * K[j, i]
        sc = max(abs(y[i]), abs(ynew[i])) * rtol + atol[i]
        ss += (e / sc) ** 2
    return abs(h) * math.sqrt(ss / n)


@njit(cache=True, inline='always')
def _fsal(K, cnt, ns):
    """Move the FSAL derivative of the last accepted step (K[S-1]) to K[0]."""
    if cnt[C_HAVEF] == 2:
        for i in range(K.shape[1]):
            K[0, i] = K[ns - 1, i]
        cnt[C_HAVEF] = 1


@njit(cache=True, inline='always')
def erk_step(t_bound, y, y_old, ip, fp, fs, cnt, rtol, atol, max_step, order, C, A, B, E, K,
             work):
    """One accepted step from fs[FS_T] of the controller's size, clipped to land on t_bound
    when within 1 % (``steppers_nb.dopri5_step``'s control; ``order`` is the embedded
    order). y is updated in place (old value in y_old); K keeps the stages for
    ``erk_dense``. Returns ST_*."""
    n = y.shape[0]
    ns = B.shape[0]
    expo = 1.0 / (order + 1) - 0.75 * BETA
    t = fs[FS_T]
    _fsal(K, cnt, ns)
    if cnt[C_HAVEF] == 0:
        RHS(t, y, ip, fp, K[0])
        cnt[C_NFEV] += 1
        bad = _first_nonfinite(K[0])
        if bad >= 0:
            cnt[C_BADIDX] = bad
            fs[FS_TBAD] = t
            return ST_NONFINITE
        cnt[C_HAVEF] = 1
    if fs[FS_H] <= 0.0:
        h0 = _hinit(y, K[0], ip, fp, fs, cnt, rtol, atol, max_step, order, work[0], work[2])
        if h0 < 0.0:
            cnt[C_BADIDX] = -1
            fs[FS_TBAD] = t
            return ST_NONFINITE
        fs[FS_H] = h0
    h_prop = fs[FS_H]
    remaining = t_bound - t
    clipped = h_prop * 1.01 >= remaining
    h = remaining if clipped else h_prop
    nonfinite = False
    ynew = work[1]
    while True:
        if h < 10 * _EPS * max(abs(t), 1e-300) or h <= 1e-300:
            return ST_NONFINITE if nonfinite else ST_UNDERFLOW
        err = _attempt(h, y, ip, fp, fs, cnt, rtol, atol, C, A, B, E, K, work)
        if err <= 1.0:
            h_new = _proposal(h, err, fs, expo, FAC_MAX)
            if cnt[C_LASTREJ] == 1:
                h_new = min(h_new, h)
            cnt[C_LASTREJ] = 0
            cnt[C_NACC] += 1
            t_new = t_bound if clipped else t + h
            for i in range(n):
                y_old[i] = y[i]
                y[i] = ynew[i]
            fs[FS_TOLD] = t
            fs[FS_T] = t_new
            fs[FS_HLAST] = t_new - t
            fs[FS_H] = min(max(h_new, h_prop) if clipped else h_new, max_step)
            cnt[C_HAVEF] = 2   # FSAL value in K[S-1]
            cnt[C_DENSE] = 0   # extra stages of the interpolant not evaluated yet
            return ST_OK
        cnt[C_NREJ] += 1
        cnt[C_LASTREJ] = 1
        clipped = False
        if math.isfinite(err) and _first_nonfinite(ynew) < 0:
            h = h / min(1.0 / FAC_MIN, err ** expo / SAFETY)
        else:
            nonfinite = True
            cnt[C_BADIDX] = _first_nonfinite(ynew)
            fs[FS_TBAD] = t + h
            h = h * FAC_MIN


@njit(cache=True, inline='always')
def erk_advance(t_end, y, y_old, ip, fp, fs, cnt, rtol, atol, max_step, order, C, A, B, E, K,
                work):
    """Integrate to exactly t_end (s); keeps h across calls. Returns ST_*."""
    (y, y_old, ip, fp, fs, cnt, C, A, B, E, K, work) = borrowed_all((
        y, y_old, ip, fp, fs, cnt, C, A, B, E, K, work))
    while fs[FS_T] < t_end:
        st = erk_step(t_end, y, y_old, ip, fp, fs, cnt, rtol, atol, max_step, order, C, A, B,
                      E, K, work)
        if st != ST_OK:
            return st
    return ST_OK


@njit(cache=True)
def erk_step_once(t_bound, y, y_old, ip, fp, fs, cnt, rtol, atol, max_step, order, C, A, B, E,
                  K, work):
    """One natural step never past t_bound (Stepper.step); returns ST_*."""
    (y, y_old, ip, fp, fs, cnt, C, A, B, E, K, work) = borrowed_all((
        y, y_old, ip, fp, fs, cnt, C, A, B, E, K, work))
    if fs[FS_T] < t_bound:
        return erk_step(t_bound, y, y_old, ip, fp, fs, cnt, rtol, atol, max_step, order, C, A,
                        B, E, K, work)
    return ST_OK


@njit(cache=True, inline='always')
def _dense_into(t, y_old, ip, fp, fs, cnt, C, A, P, ns, K, arg, out):
    """out = y(t) inside the last accepted step; evaluates the extra stages K[S..] once per
    step (arg: scratch of n)."""
    n = y_old.shape[0]
    h = fs[FS_HLAST]
    t_old = fs[FS_TOLD]
    s_all = C.shape[0]
    if cnt[C_DENSE] == 0 and s_all > ns:
        for s in range(ns, s_all):
            for i in range(n):
                arg[i] = y_old[i]
            for j in range(s):
                c = h * A[s, j]
                if c != 0.0:
                    kj = K[j]
                    for i in range(n):
                        arg[i] += c * kj[i]
            RHS(t_old + C[s] * h, arg, ip, fp, K[s])
        cnt[C_NFEV] += s_all - ns
    cnt[C_DENSE] = 1
    x = (t - t_old) / h
    deg = P.shape[1]
    for i in range(n):
        acc = 0.0
        for j in range(s_all):
            q = 0.0
            for d in range(deg - 1, -1, -1):
                q = (q + P[j, d]) * x
            acc += K[j, i] * q
        out[i] = y_old[i] + h * acc


@njit(cache=True)
def erk_dense(t, y, y_old, ip, fp, fs, cnt, C, A, P, K, work, ns, out):
    """y(t) (the interpolant's order) inside the last accepted step, into out."""
    (y, y_old, ip, fp, fs, cnt, C, A, P, K, work, out) = borrowed_all((
        y, y_old, ip, fp, fs, cnt, C, A, P, K, work, out))
    if t == fs[FS_T] or fs[FS_HLAST] == 0.0:
        for i in range(y.shape[0]):
            out[i] = y[i]
        return
    _dense_into(t, y_old, ip, fp, fs, cnt, C, A, P, ns, K, work[3], out)


@njit(cache=True)
def erk_sample(t_eval, Y, y, y_old, ip, fp, fs, cnt, rtol, atol, max_step, order, C, A, B, E,
               P, K, work):
    """Compiled sampled loop: natural steps to t_eval[-1], each output time (ascending,
    >= fs[FS_T]) filled into Y[k] by dense output (the step end itself at a step end).
    Returns (status, number of rows written)."""
    (t_eval, Y, y, y_old, ip, fp, fs, cnt, C, A, B, E, P, K, work) = borrowed_all((
        t_eval, Y, y, y_old, ip, fp, fs, cnt, C, A, B, E, P, K, work))
    m = t_eval.shape[0]
    ns = B.shape[0]
    k = 0
    while k < m and t_eval[k] <= fs[FS_T]:
        _store_row(Y, k, y)
        k += 1
    if k >= m:
        return ST_OK, k
    t_last = t_eval[m - 1]
    while k < m:
        st = erk_step(t_last, y, y_old, ip, fp, fs, cnt, rtol, atol, max_step, order, C, A, B,
                      E, K, work)
        if st != ST_OK:
            return st, k
        t_now = fs[FS_T]
        while k < m and t_eval[k] <= t_now:
            if t_eval[k] == t_now:
                _store_row(Y, k, y)
            else:
                _dense_into(t_eval[k], y_old, ip, fp, fs, cnt, C, A, P, ns, K, work[3], Y[k])
            k += 1
    return ST_OK, k


@njit(cache=True)
def erk_land(times, X, y, y_old, ip, fp, fs, cnt, rtol, atol, max_step, order, C, A, B, E, K,
             work):
    """erk_advance to each times[k], k >= 1, row k of X = y there.
    Returns (ST_*, k of the failing sample, or times.size)."""
    (times, X, y, y_old, ip, fp, fs, cnt, C, A, B, E, K, work) = borrowed_all((
        times, X, y, y_old, ip, fp, fs, cnt, C, A, B, E, K, work))
    for k in range(1, times.size):
        st = erk_advance(times[k], y, y_old, ip, fp, fs, cnt, rtol, atol, max_step, order, C, A,
                         B, E, K, work)
        if st != ST_OK:
            return st, k
        _store_row(X, k, y)
    return ST_OK, times.size
