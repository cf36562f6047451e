"""One compiled mode segment for chains and vehicle trees, on every stepper with dense output.

:func:`mode_segment` integrates one mode of a chain (``kind`` KIND_CHAIN: the right-hand side
``modes_nb.mode_eval``, witnesses ``modes_nb.witness_values``) or of a vehicle tree
(KIND_TREE: ``tree_modes_nb.tm_eval``, which writes its witnesses itself) from t0 towards
t_stop with one of

* M_DOPRI5, M_DOP853: Dormand-Prince 5(4) / 8(5,3), the step control and dense output of
  ``steppers_nb.dopri5_step`` / ``dop853_step``;
* M_ERK: an efficient explicit FSAL pair with interpolant (``tsit5``, Tsitouras 2011;
  ``vern6``, ``vern7``, ``vern8``, Verner 2010; ``physics/erk_tableaux.py``), the step control of
  ``steppers_rk_nb.erk_step`` and the pair's own interpolant (its extra stages once per
  step), as ``solvers._ErkStepper``;
* M_ROSENBROCK: an adaptive RODAS method whose tableau is passed in (``rodas3``, ``rodas4``,
  ``rosenbrock`` = RODAS5P; ``kernel/stepper._rosenbrock_args``), the step of
  ``steppers_nb.ros_step`` with the Jacobian the Python reference uses for a mode's
  right-hand side: a chain's analytic ``modes_jac_nb.mode_jac`` (the reference's
  ``hybrid/chain_jac.mode_jacobian``), a tree's analytic ``tree_modes_jac_nb.tm_jac`` (the
  reference's ``hybrid/tree_jac.tree_mode_jacobian``), and f_t by central differences (increment
  eps^(1/3) max(1, |t|)), one-sided within it of the segment's ends (the commands jump
  there), both at every accepted step. Dense output:
  RODAS5P's continuous extension (``steppers_nb.ros_dense_h``), RODAS3/4 the cubic Hermite
  of ``solvers._hermite`` from f at both step ends.

The segment writes t_stop into the mode's command ramps (``modes_nb.set_ramp_end``), so its
last stage and witnesses see a command step at t_stop from the left (``commands.Ramp.at``).
After every accepted step the mode's witnesses are checked (a crossing in the witness's
direction, scipy's ``find_active_events``), the earliest is located by Brent's method
(scipy's ``brentq``, Brent 1973, xtol = rtol = 4 eps) on the dense output and the segment
stops there; the discrete transition is the caller's (``kernel/modes.py``,
``kernel/tree_modes.py``: the Python reference's decision code).

One loop for both kinds and all methods: numba binds a callee at compile time and does not
cache a function that takes a function argument (a cache miss in every process), so the
right-hand side is chosen by the ``kind`` flag (:func:`_f`) and the stepper by ``method``.
:func:`mode_segment` borrows its array arguments (``borrow_nb.borrowed_all``) and keeps its
float scratch in its stack frame (``borrow_nb.stack_zeros_2d``), so the steps' rhs calls
pass arrays without NRT reference counts, as the continuous steppers' entry points.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from cvj_ros.physics.kernel.borrow_nb import STACK_MAX_DOUBLES, borrowed_all, stack_zeros_2d
from cvj_ros.physics.kernel.modes_jac_nb import mode_jac
from cvj_ros.physics.kernel.modes_nb import (FS_HUSED, M_DOP853, M_DOPRI5, MH_N, MH_NWIT,
                                             MH_RAMP_B, MH_RAMP_C, MH_RAMP_T, MH_WIT,
                                             N_SCRATCH_EXTRA, mode_eval, set_ramp_end,
                                             witness_values)
from cvj_ros.physics.kernel.steppers_nb import (BETA, C_DENSE, C_LASTREJ, C_LUM, C_NACC,
                                                C_NFEV, C_NREJ, D8_FAC_MAX, D8_FAC_MIN,
                                                D8_ORDER, DP_A, DP_B, DP_C, DP_E, DP_ORDER,
                                                FAC_MAX, FAC_MIN, FS_ERROLD, FS_H, FS_HLAST,
                                                FS_LUH, FS_T, FS_TOLD, NCNT, NFS, SAFETY,
                                                ST_NONFINITE, ST_OK, ST_SINGULAR, ST_UNDERFLOW,
                                                _coupled_size, _first_nonfinite, _proposal,
                                                _proposal_nobeta, _stage_at_start,
                                                dopri5_dense, lu_factor, lu_solve, ros_dense_h)
from cvj_ros.physics.kernel.tree_modes_jac_nb import tm_jac
from cvj_ros.physics.kernel.tree_modes_nb import (MB_NWIT, MB_RAMP_B, MB_RAMP_C, MB_RAMP_T,
                                                  MB_WIT, WIT_STRIDE, tm_eval)

__all__ = ['KIND_CHAIN', 'KIND_TREE', 'M_DOP853', 'M_DOPRI5', 'M_ERK', 'M_ROSENBROCK',
           'mode_segment']

KIND_CHAIN, KIND_TREE = 0, 1
M_ROSENBROCK = 2
M_ERK = 3
# rp (Rosenbrock parameters): gamma, embedded order, fac_max
RP_GAMMA, RP_ORDER, RP_FACMAX = 0, 1, 2
_EPS = np.finfo(float).eps
_XTOL = 4 * _EPS


@njit(cache=True, inline='always')
def _scratch(rows, cols):
    """A zeroed (rows, cols) float64 array in the calling function's stack frame
    (``borrow_nb.stack_zeros_2d``), np.zeros above STACK_MAX_DOUBLES."""
    if rows * cols <= STACK_MAX_DOUBLES:
        return stack_zeros_2d(rows, cols)
    return np.zeros((rows, cols))


@njit(cache=True, inline='always')
def _f(kind, t, y, ip, fp, dy, sc, want):
    """The mode's right-hand side into dy (want: also the witnesses' scratch sc)."""
    if kind == KIND_CHAIN:
        mode_eval(t, y, ip, fp, dy, sc, want)
    else:
        tm_eval(t, y, ip, fp, dy, sc, want)


@njit(cache=True, inline='always')
def _witness_from(kind, t, y, ip, fp, dy, sc, wv):
    """Witness values into wv from an evaluation with want=True at (t, y), derivative dy."""
    if kind == KIND_CHAIN:
        witness_values(t, y, ip, fp, dy, sc, wv)
    else:
        for i in range(wv.shape[0]):
            wv[i] = sc[i] if i < sc.shape[0] else 0.0


@njit(cache=True)
def _witness_at(kind, t, y, ip, fp, dy, sc, wv):
    """The mode's witness values at (t, y) into wv (dy: the derivative there)."""
    _f(kind, t, y, ip, fp, dy, sc, True)
    _witness_from(kind, t, y, ip, fp, dy, sc, wv)


@njit(cache=True)
def _hermite(t, y, y_old, fs, f0, f1, out):
    """Cubic Hermite y(t) inside the last step from f0, f1 at its ends (solvers._hermite,
    its order of operations)."""
    h = fs[FS_HLAST]
    if h == 0.0:
        for i in range(y.shape[0]):
            out[i] = y[i]
        return
    x = (t - fs[FS_TOLD]) / h
    h00 = (1 + 2 * x) * (1 - x) ** 2
    h10 = x * (1 - x) ** 2
    h01 = x * x * (3 - 2 * x)
    h11 = x * x * (x - 1)
    for i in range(y.shape[0]):
        out[i] = h00 * y_old[i] + (h10 * h) * f0[i] + h01 * y[i] + (h11 * h) * f1[i]


@njit(cache=True)
def _dense(kind, method, tau, y, y_old, ip, fp, fs, cnt, K, sc, D8, AX, CX, RH, out):
    """The method's dense output at tau inside the last accepted step. dopri5: y itself at
    the step's end (and before a step), as the reference's ``Dopri5Stepper.dense``, not the
    interpolant's last-bit rounding of it."""
    if method == M_DOPRI5:
        if tau == fs[FS_T] or fs[FS_HLAST] == 0.0:
            for i in range(y.shape[0]):
                out[i] = y[i]
        else:
            dopri5_dense(tau, y_old, fs, K, out)
    elif method == M_DOP853:
        _d8_dense(kind, tau, y, y_old, ip, fp, fs, cnt, D8, AX, CX, K, out, sc)
    elif method == M_ERK:     # D8, AX, CX: the pair's P and its extra stages' A rows, C
        _erk_dense(kind, tau, y, y_old, ip, fp, fs, cnt, D8, AX, CX, K, out, sc)
    elif RH.shape[0] > 0:
        ros_dense_h(tau, y, y_old, fs, RH, K, out)
    else:        # f at the step start in K's last row, at its end in K[0]
        _hermite(tau, y, y_old, fs, K[K.shape[0] - 1], K[0], out)


@njit(cache=True)
def _dense_witness(kind, method, tau, i, y, y_old, fs, cnt, K, ip, fp, yy, dy, sc, wv, D8,
                   AX, CX, RH):
    """Witness i on the dense output at tau."""
    _dense(kind, method, tau, y, y_old, ip, fp, fs, cnt, K, sc, D8, AX, CX, RH, yy)
    _witness_at(kind, tau, yy, ip, fp, dy, sc, wv)
    return wv[i]


@njit(cache=True)
def brent_root(kind, xa, xb, fa, fb, i, method, y, y_old, fs, cnt, K, ip, fp, yy, dy, sc, wv,
               D8, AX, CX, RH):
    """Zero of witness i on the dense output in [xa, xb]: scipy's brentq (zeros.c, Brent
    1973, "Algorithms for minimization without derivatives", ch. 4) with xtol = rtol =
    4 eps, maxiter 100; fa, fb: the witness at the ends (opposite signs)."""
    xpre = xa
    xcur = xb
    fpre = fa
    fcur = fb
    xblk = 0.0
    fblk = 0.0
    spre = 0.0
    scur = 0.0
    if fpre == 0.0:
        return xpre
    if fcur == 0.0:
        return xcur
    for _it in range(100):
        if fpre != 0.0 and fcur != 0.0 and (math.copysign(1.0, fpre) != math.copysign(1.0, fcur)):
            xblk = xpre
            fblk = fpre
            spre = xcur - xpre
            scur = spre
        if abs(fblk) < abs(fcur):
            xpre = xcur
            xcur = xblk
            xblk = xpre
            fpre = fcur
            fcur = fblk
            fblk = fpre
        delta = (_XTOL + _XTOL * abs(xcur)) / 2
        sbis = (xblk - xcur) / 2
        if fcur == 0.0 or abs(sbis) < delta:
            return xcur
        if abs(spre) > delta and abs(fcur) < abs(fpre):
            if xpre == xblk:
                stry = -fcur * (xcur - xpre) / (fcur - fpre)
            else:
                dpre = (fpre - fcur) / (xpre - xcur)
                dblk = (fblk - fcur) / (xblk - xcur)
                stry = -fcur * (fblk * dblk - fpre * dpre) / (dblk * dpre * (fblk - fpre))
            if 2 * abs(stry) < min(abs(spre), 3 * abs(sbis) - delta):
                spre = scur
                scur = stry
            else:
                spre = sbis
                scur = sbis
        else:
            spre = sbis
            scur = sbis
        xpre = xcur
        fpre = fcur
        if abs(scur) > delta:
            xcur += scur
        else:
            xcur += delta if sbis > 0 else -delta
        fcur = _dense_witness(kind, method, xcur, i, y, y_old, fs, cnt, K, ip, fp, yy, dy, sc,
                              wv, D8, AX, CX, RH)
    return xcur


@njit(cache=True)
def _initial_step(kind, y, f0, t, ip, fp, sc, rtol, atol, max_step, order, tmp, f1):
    """Hairer's HINIT (steppers_nb._initial_step) on the mode's rhs; h0 (s) or -1.0."""
    n = y.shape[0]
    s0 = 0.0
    s1 = 0.0
    for i in range(n):
        scl = abs(y[i]) * rtol + atol[i]
        s0 += (y[i] / scl) ** 2
        s1 += (f0[i] / scl) ** 2
    d0 = math.sqrt(s0 / n)
    d1 = math.sqrt(s1 / n)
    if not (math.isfinite(d0) and math.isfinite(d1)):
        return -1.0
    h0 = 1e-6 if (d0 < 1e-5 or d1 < 1e-5) else 0.01 * d0 / d1
    h0 = min(h0, max_step)
    for i in range(n):
        tmp[i] = y[i] + h0 * f0[i]
    _f(kind, t + h0, tmp, ip, fp, f1, sc, False)
    s2 = 0.0
    for i in range(n):
        scl = abs(y[i]) * rtol + atol[i]
        s2 += ((f1[i] - f0[i]) / scl) ** 2
    d2 = math.sqrt(s2 / n) / h0
    if not math.isfinite(d2):
        return -1.0
    dmax = max(d1, d2)
    if dmax <= 1e-15:
        h1 = max(1e-6, h0 * 1e-3)
    else:
        h1 = (0.01 / dmax) ** (1.0 / (order + 1))
    return min(100 * h0, h1, max_step)


@njit(cache=True)
def _attempt(kind, h, y, ip, fp, fs, cnt, rtol, atol, K, work, sc):
    """One DOPRI5 attempt (steppers_nb._dopri5_attempt on the mode's rhs)."""
    n = y.shape[0]
    t = fs[FS_T]
    arg = work[0]
    for s in range(1, 6):
        for i in range(n):
            arg[i] = y[i]
        for j in range(s):
            c = h * DP_A[s, j]
            if c != 0.0:
                kj = K[j]
                for i in range(n):
                    arg[i] += c * kj[i]
        _f(kind, t + DP_C[s] * h, arg, ip, fp, K[s], sc, False)
    ynew = work[1]
    for i in range(n):
        ynew[i] = y[i]
    for j in range(6):
        c = h * DP_B[j]
        if c != 0.0:
            kj = K[j]
            for i in range(n):
                ynew[i] += c * kj[i]
    _f(kind, t + h, ynew, ip, fp, K[6], sc, True)      # also the witnesses' scratch
    cnt[C_NFEV] += 6
    ss = 0.0
    for i in range(n):
        e = 0.0
        for j in range(7):
            e += DP_E[j] * K[j, i]
        scl = max(abs(y[i]), abs(ynew[i])) * rtol + atol[i]
        ss += (e / scl) ** 2
    return abs(h) * math.sqrt(ss / n)


@njit(cache=True, inline='always')
def _accepted(t, t_new, h, y, y_old, ynew, fs):
    """Book an accepted step of attempt size h from t to t_new: y_old, y, the times."""
    for i in range(y.shape[0]):
        y_old[i] = y[i]
        y[i] = ynew[i]
    fs[FS_TOLD] = t
    fs[FS_T] = t_new
    fs[FS_HLAST] = t_new - t
    fs[FS_HUSED] = h


@njit(cache=True)
def _step(kind, t_bound, y, y_old, ip, fp, fs, cnt, rtol, atol, max_step, K, work, sc):
    """One accepted DOPRI5 step clipped to land on t_bound within 1 %
    (steppers_nb.dopri5_step); K[0] = f(t, y) on entry. Returns ST_*."""
    expo = 1.0 / (DP_ORDER + 1) - 0.75 * BETA
    t = fs[FS_T]
    h_prop = fs[FS_H]
    remaining = t_bound - t
    clipped = h_prop * 1.01 >= remaining
    h = remaining if clipped else h_prop
    while True:
        if h < 10 * _EPS * max(abs(t), 1e-300) or h <= 1e-300:
            return ST_UNDERFLOW
        err = _attempt(kind, h, y, ip, fp, fs, cnt, rtol, atol, K, work, sc)
        if err <= 1.0:
            h_new = _proposal(h, err, fs, expo, FAC_MAX)
            if cnt[C_LASTREJ] == 1:
                h_new = min(h_new, h)
            cnt[C_LASTREJ] = 0
            cnt[C_NACC] += 1
            _accepted(t, t_bound if clipped else t + h, h, y, y_old, work[1], fs)
            fs[FS_H] = min(max(h_new, h_prop) if clipped else h_new, max_step)
            return ST_OK
        cnt[C_NREJ] += 1
        cnt[C_LASTREJ] = 1
        clipped = False
        if not math.isfinite(err):
            return ST_NONFINITE
        h = h / min(1.0 / FAC_MIN, err ** expo / SAFETY)


@njit(cache=True)
def _d8_step(kind, t_bound, y, y_old, ip, fp, fs, cnt, rtol, atol, max_step, C, A, B, E5, E3,
             K, work, sc):
    """One accepted DOP853 step (steppers_nb.dop853_step on the mode's rhs); K[0] =
    f(t, y) on entry. Returns ST_*."""
    n = y.shape[0]
    ns = B.shape[0]
    expo = 1.0 / (D8_ORDER + 1)
    t = fs[FS_T]
    h_prop = fs[FS_H]
    remaining = t_bound - t
    clipped = h_prop * 1.01 >= remaining
    h = remaining if clipped else h_prop
    arg = work[0]
    ynew = work[1]
    while True:
        if h < 10 * _EPS * max(abs(t), 1e-300) or h <= 1e-300:
            return ST_UNDERFLOW
        for s in range(1, ns):
            for i in range(n):
                acc = 0.0
                for j in range(s):
                    acc += A[s, j] * K[j, i]
                arg[i] = y[i] + h * acc
            _f(kind, t + C[s] * h, arg, ip, fp, K[s], sc, False)
        for i in range(n):
            acc = 0.0
            for j in range(ns):
                acc += B[j] * K[j, i]
            ynew[i] = y[i] + h * acc
        _f(kind, t + h, ynew, ip, fp, K[ns], sc, True)
        cnt[C_NFEV] += ns
        e5n = 0.0
        e3n = 0.0
        for i in range(n):
            e5 = 0.0
            e3 = 0.0
            for j in range(ns + 1):
                e5 += E5[j] * K[j, i]
                e3 += E3[j] * K[j, i]
            scl = max(abs(y[i]), abs(ynew[i])) * rtol + atol[i]
            e5n += (e5 / scl) ** 2
            e3n += (e3 / scl) ** 2
        if e5n == 0.0 and e3n == 0.0:
            err = 0.0
        else:
            err = abs(h) * e5n / math.sqrt((e5n + 0.01 * e3n) * n)
        if err <= 1.0:
            h_new = _proposal_nobeta(h, err, D8_FAC_MIN, D8_FAC_MAX, expo)
            fs[FS_ERROLD] = max(err, 1e-4)
            if cnt[C_LASTREJ] == 1:
                h_new = min(h_new, h)
            cnt[C_LASTREJ] = 0
            cnt[C_NACC] += 1
            _accepted(t, t_bound if clipped else t + h, h, y, y_old, ynew, fs)
            fs[FS_H] = min(max(h_new, h_prop) if clipped else h_new, max_step)
            cnt[C_DENSE] = 0
            return ST_OK
        cnt[C_NREJ] += 1
        cnt[C_LASTREJ] = 1
        clipped = False
        if not math.isfinite(err):
            return ST_NONFINITE
        h = h / min(1.0 / D8_FAC_MIN, err ** expo / SAFETY)


@njit(cache=True)
def _d8_dense(kind, t, y, y_old, ip, fp, fs, cnt, D, A_EXTRA, C_EXTRA, K, out, sc):
    """7th-order dense output of DOP853 (steppers_nb.dop853_dense on the mode's rhs): the
    three extra stages and the coefficients once per step."""
    n = y.shape[0]
    h = fs[FS_HLAST]
    t_old = fs[FS_TOLD]
    if h == 0.0:
        for i in range(n):
            out[i] = y_old[i]
        return
    if cnt[C_DENSE] == 0:
        arg = _scratch(1, n)[0]
        for r in range(3):
            s = 13 + r
            for i in range(n):
                acc = 0.0
                for j in range(s):
                    acc += A_EXTRA[r, j] * K[j, i]
                arg[i] = y_old[i] + h * acc
            _f(kind, t_old + C_EXTRA[r] * h, arg, ip, fp, K[s], sc, False)
        cnt[C_NFEV] += 3
        for i in range(n):
            dy = y[i] - y_old[i]
            K[16, i] = dy
            K[17, i] = h * K[0, i] - dy
            K[18, i] = 2 * dy - h * (K[12, i] + K[0, i])
            for r in range(4):
                acc = 0.0
                for j in range(16):
                    acc += D[r, j] * K[j, i]
                K[19 + r, i] = h * acc
        cnt[C_DENSE] = 1
    x = (t - t_old) / h
    for i in range(n):
        acc = 0.0
        for q in range(7):
            acc += K[22 - q, i]
            acc *= x if q % 2 == 0 else 1.0 - x
        out[i] = acc + y_old[i]


@njit(cache=True)
def _erk_step(kind, t_bound, y, y_old, ip, fp, fs, cnt, rtol, atol, max_step, order, C, A, B,
              E, K, work, sc):
    """One accepted step of an explicit FSAL pair (steppers_rk_nb.erk_step on the mode's
    rhs: C, A, B, E of erk_tableaux, S = B.size stages, K[S-1] = f(t + h, y_new); ``order``
    the embedded order); K[0] = f(t, y) on entry. Returns ST_*."""
    n = y.shape[0]
    ns = B.shape[0]
    expo = 1.0 / (order + 1) - 0.75 * BETA
    t = fs[FS_T]
    h_prop = fs[FS_H]
    remaining = t_bound - t
    clipped = h_prop * 1.01 >= remaining
    h = remaining if clipped else h_prop
    arg = work[0]
    ynew = work[1]
    nonfinite = False
    while True:
        if h < 10 * _EPS * max(abs(t), 1e-300) or h <= 1e-300:
            return ST_NONFINITE if nonfinite else ST_UNDERFLOW
        for s in range(1, ns - 1):
            for i in range(n):
                arg[i] = y[i]
            for j in range(s):
                c = h * A[s, j]
                if c != 0.0:
                    kj = K[j]
                    for i in range(n):
                        arg[i] += c * kj[i]
            _f(kind, t + C[s] * h, arg, ip, fp, K[s], sc, False)
        for i in range(n):
            ynew[i] = y[i]
        for j in range(ns - 1):
            c = h * B[j]
            if c != 0.0:
                kj = K[j]
                for i in range(n):
                    ynew[i] += c * kj[i]
        _f(kind, t + h, ynew, ip, fp, K[ns - 1], sc, True)   # also the witnesses' scratch
        cnt[C_NFEV] += ns - 1
        ss = 0.0
        for i in range(n):
            e = 0.0
            for j in range(ns):
                e += E[j] * K[j, i]
            scl = max(abs(y[i]), abs(ynew[i])) * rtol + atol[i]
            ss += (e / scl) ** 2
        err = abs(h) * math.sqrt(ss / n)
        if err <= 1.0:
            h_new = _proposal(h, err, fs, expo, FAC_MAX)
            if cnt[C_LASTREJ] == 1:
                h_new = min(h_new, h)
            cnt[C_LASTREJ] = 0
            cnt[C_NACC] += 1
            _accepted(t, t_bound if clipped else t + h, h, y, y_old, ynew, fs)
            fs[FS_H] = min(max(h_new, h_prop) if clipped else h_new, max_step)
            cnt[C_DENSE] = 0      # the interpolant's extra stages not evaluated yet
            return ST_OK
        cnt[C_NREJ] += 1
        cnt[C_LASTREJ] = 1
        clipped = False
        if math.isfinite(err) and _first_nonfinite(ynew) < 0:
            h = h / min(1.0 / FAC_MIN, err ** expo / SAFETY)
        else:
            nonfinite = True
            h = h * FAC_MIN


@njit(cache=True)
def _erk_dense(kind, t, y, y_old, ip, fp, fs, cnt, P, A_EXTRA, C_EXTRA, K, out, sc):
    """The pair's interpolant y_old + h sum_j b_j(theta) k_j, b_j(theta) = sum_d P[j, d]
    theta^(d+1) (solvers._ErkStepper.dense); the extra stages (rows S.. of K, S = P's rows
    minus C_EXTRA's size; A_EXTRA, C_EXTRA: their rows of the tableau's A and C) once per
    step. The step end itself is y."""
    n = y.shape[0]
    h = fs[FS_HLAST]
    t_old = fs[FS_TOLD]
    if h == 0.0 or t == fs[FS_T]:
        for i in range(n):
            out[i] = y[i]
        return
    s_all = P.shape[0]
    ns = s_all - C_EXTRA.shape[0]
    if cnt[C_DENSE] == 0 and s_all > ns:
        arg = _scratch(1, n)[0]
        for r in range(s_all - ns):
            s = ns + r
            for i in range(n):
                arg[i] = y_old[i]
            for j in range(s):
                c = h * A_EXTRA[r, j]
                if c != 0.0:
                    kj = K[j]
                    for i in range(n):
                        arg[i] += c * kj[i]
            _f(kind, t_old + C_EXTRA[r] * h, arg, ip, fp, K[s], sc, False)
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
def _time_derivative(kind, t, t_lo, t_hi, y, ip, fp, cnt, ft, K, work, sc):
    """f_t at (t, y) into ft (solvers._LinearlyImplicit._time_derivative, the segment
    [t_lo, t_hi] its ft_window): central difference of increment delta = eps^(1/3)
    max(1, |t|); within delta of an end one-sided away from it, increment min(delta,
    distance to the far end), 0 if that is 0. K[0] = f(t, y)."""
    n = y.shape[0]
    delta = _EPS ** (1.0 / 3.0) * max(1.0, abs(t))
    if t - delta >= t_lo and t + delta <= t_hi:
        _f(kind, t + delta, y, ip, fp, work[2], sc, False)
        _f(kind, t - delta, y, ip, fp, work[3], sc, False)
        cnt[C_NFEV] += 2
        for i in range(n):
            ft[i] = (work[2, i] - work[3, i]) / (2.0 * delta)
        return
    if t - t_lo >= t_hi - t:
        d = min(delta, t - t_lo)
        if d > 0.0:
            _f(kind, t - d, y, ip, fp, work[3], sc, False)
            cnt[C_NFEV] += 1
            for i in range(n):
                ft[i] = (K[0, i] - work[3, i]) / d
            return
    else:
        d = min(delta, t_hi - t)
        if d > 0.0:
            _f(kind, t + d, y, ip, fp, work[2], sc, False)
            cnt[C_NFEV] += 1
            for i in range(n):
                ft[i] = (work[2, i] - K[0, i]) / d
            return
    for i in range(n):
        ft[i] = 0.0


@njit(cache=True)
def _ros_prepare(kind, h, gamma, t_lo, t_hi, y, ip, fp, fs, cnt, J, LU, piv, ft, K, work, sc,
                 fresh):
    """Jacobian and f_t at (t, y) when ``fresh`` (the first attempt of a step), LU of
    I/(h gamma) - J when h changed (solvers._LinearlyImplicit._prepare). K[0] = f(t, y).
    J: a chain's analytic ``modes_jac_nb.mode_jac`` (the reference's
    ``hybrid/chain_jac.mode_jacobian``), a tree's analytic ``tree_modes_jac_nb.tm_jac``
    (``hybrid/tree_jac.tree_mode_jacobian``); f_t: :func:`_time_derivative` on the segment
    [t_lo, t_hi]."""
    n = y.shape[0]
    t = fs[FS_T]
    if fresh:
        if kind == KIND_CHAIN:
            mode_jac(t, y, ip, fp, J)
        else:
            tm_jac(t, y, ip, fp, J)
        _time_derivative(kind, t, t_lo, t_hi, y, ip, fp, cnt, ft, K, work, sc)
        fs[FS_LUH] = 0.0
    if fs[FS_LUH] == 0.0 or abs(fs[FS_LUH] - h) > 1e-12 * h:
        d = 1.0 / (h * gamma)
        for i in range(n):
            for j in range(n):
                LU[i, j] = -J[i, j]
            LU[i, i] += d
        cnt[C_LUM] = _coupled_size(J)
        if not lu_factor(LU, piv, cnt[C_LUM]):
            fs[FS_LUH] = 0.0
            return ST_SINGULAR
        fs[FS_LUH] = h
    return ST_OK


@njit(cache=True)
def _ros_stages(kind, h, t_hi, y, ip, fp, fs, cnt, A, C, M, alpha, gsum, LU, piv, ft, K, work,
                sc):
    """Rosenbrock stages in K form (steppers_nb._ros_stages on the mode's rhs):
    (I/(h g) - J) K_i = f(t + alpha_i h, y + sum_j A_ij K_j) + sum_j C_ij/h K_j
    + h gsum_i f_t into K[i+1]; y_new into work[1]. A stage time reaching the segment's end
    t_hi is the last float before it (the commands' left limit at a row,
    solvers._LinearlyImplicit._inside)."""
    n = y.shape[0]
    st = M.shape[0]
    t = fs[FS_T]
    arg = work[0]
    lum = cnt[C_LUM]
    for s in range(st):
        b = K[s + 1]
        if s == 0:
            for i in range(n):
                b[i] = K[0, i] + (h * gsum[0]) * ft[i]
        elif _stage_at_start(s, A, alpha):
            for i in range(n):
                b[i] = K[0, i]
        else:
            for i in range(n):
                acc = 0.0
                for j in range(s):
                    acc += A[s, j] * K[j + 1, i]
                arg[i] = y[i] + acc
            ts = t + alpha[s] * h
            _f(kind, ts if ts < t_hi else np.nextafter(t_hi, -np.inf), arg, ip, fp, b, sc,
               False)
            cnt[C_NFEV] += 1
        if s > 0:
            for i in range(n):
                acc = 0.0
                for j in range(s):
                    acc += (C[s, j] / h) * K[j + 1, i]
                b[i] += acc + (h * gsum[s]) * ft[i]
        lu_solve(LU, piv, b, lum)
    ynew = work[1]
    for i in range(n):
        acc = 0.0
        for j in range(st):
            acc += M[j] * K[j + 1, i]
        ynew[i] = y[i] + acc


@njit(cache=True)
def _ros_step(kind, t_lo, t_bound, y, y_old, ip, fp, fs, cnt, rtol, atol, max_step, ros, rp,
              J, LU, piv, ft, K, work, sc):
    """One accepted adaptive Rosenbrock step (steppers_nb.ros_step on the mode's rhs, the
    Jacobian of :func:`_ros_prepare` kept across rejected attempts); K[0] = f(t, y) on
    entry, copied to K's last row (f at the step start) on acceptance. ros = (A, C, M, E,
    alpha, gamma_sum, H), rp = (gamma, embedded order, fac_max). Returns ST_*."""
    A, C, M, E, alpha, gsum, _H = ros
    gamma = rp[RP_GAMMA]
    n = y.shape[0]
    st_n = M.shape[0]
    expo = 1.0 / (rp[RP_ORDER] + 1) - 0.75 * BETA
    t = fs[FS_T]
    h_prop = fs[FS_H]
    remaining = t_bound - t
    clipped = h_prop * 1.01 >= remaining
    h = remaining if clipped else h_prop
    ynew = work[1]
    fresh = True
    while True:
        if h < 10 * _EPS * max(abs(t), 1e-300) or h <= 1e-300:
            return ST_UNDERFLOW
        stat = _ros_prepare(kind, h, gamma, t_lo, t_bound, y, ip, fp, fs, cnt, J, LU, piv, ft,
                            K, work, sc, fresh)
        fresh = False
        if stat != ST_OK:
            return stat
        _ros_stages(kind, h, t_bound, y, ip, fp, fs, cnt, A, C, M, alpha, gsum, LU, piv, ft, K,
                    work, sc)
        ss = 0.0
        for i in range(n):
            e = 0.0
            for j in range(st_n):
                e += E[j] * K[j + 1, i]
            scl = max(abs(y[i]), abs(ynew[i])) * rtol + atol[i]
            ss += (e / scl) ** 2
        err = math.sqrt(ss / n)
        if err <= 1.0:
            h_new = _proposal(h, err, fs, expo, rp[RP_FACMAX])
            if cnt[C_LASTREJ] == 1:
                h_new = min(h_new, h)
            cnt[C_LASTREJ] = 0
            cnt[C_NACC] += 1
            for i in range(n):
                K[st_n + 1, i] = K[0, i]
            _accepted(t, t_bound if clipped else t + h, h, y, y_old, ynew, fs)
            fs[FS_H] = min(max(h_new, h_prop) if clipped else h_new, max_step)
            return ST_OK
        cnt[C_NREJ] += 1
        cnt[C_LASTREJ] = 1
        clipped = False
        if math.isfinite(err) and _first_nonfinite(ynew) < 0:
            h = h / min(1.0 / FAC_MIN, err ** expo / SAFETY)
        else:
            h = h * FAC_MIN


@njit(cache=True)
def mode_segment(kind, method, t0, t_stop, y, ip, fp, rtol, atol, max_step, h_in, t_samp, k0,
                 Y, hlog, out_i, out_f, C8, A8, B8, E5, E3, D8, AX, CX, ros, rp):
    """Integrate the mode (``kind``: KIND_CHAIN or KIND_TREE) from t0 towards t_stop until
    the earliest witness crossing, with ``method`` M_DOPRI5, M_DOP853 (its coefficients
    C8 .. CX: scipy's DOP853 tableau, as steppers_nb.dop853_step takes them) or
    M_ROSENBROCK (ros = (A, C, M, E, alpha, gamma_sum, H; H with no rows: Hermite dense
    output), rp = (gamma, embedded order, fac_max)) or M_ERK (an erk_tableaux pair in
    DOP853's slots: C8, A8, B8, E5 = C, A, B, E; D8 = P; AX, CX = the rows of A and C of
    the interpolant's extra stages; rp[1] = the embedded order); the unused coefficients
    are ignored.

    y: the mode state at t0, overwritten with the state at the end (event or t_stop).
    h_in: first step (s), 0: Hairer's estimate. Samples t_samp[k] (ascending, k >= k0) up to
    the end are written into Y[k] (dense output, the step end exactly). hlog (empty: off)
    receives the size of every accepted attempt (s) while it has room. Returns in
    out_i: status ST_*, witness index of the event (-1: reached t_stop), next sample index,
    accepted steps, rhs evaluations, rejected steps, logged steps; out_f: end time (s), the
    step proposal at the end (s) and, given a third slot, the last accepted step's length
    (s)."""
    # the arguments as borrowed views (borrow_nb: the caller holds them for the call), the
    # scratch in this frame's stack: no atomic reference counts in the steps' calls
    y, ip, fp, atol, t_samp, Y, hlog, out_i, out_f = borrowed_all(
        (y, ip, fp, atol, t_samp, Y, hlog, out_i, out_f))
    C8, A8, B8, E5, E3, D8, AX, CX, rp = borrowed_all((C8, A8, B8, E5, E3, D8, AX, CX, rp))
    ros = borrowed_all(ros)
    ns = y.shape[0]
    if kind == KIND_CHAIN:
        nw = ip[MH_NWIT]
        w0 = ip[MH_WIT]
        wstride = 3
        sc = _scratch(1, ip[MH_N] + N_SCRATCH_EXTRA)[0]
        r_t, r_c, r_b = ip[MH_RAMP_T], ip[MH_RAMP_C], ip[MH_RAMP_B]
    else:
        mb = ip[ip.shape[0] - 1]
        nw = ip[mb + MB_NWIT]
        w0 = ip[mb + MB_WIT]
        wstride = WIT_STRIDE
        sc = _scratch(1, max(nw, 1))[0]
        r_t, r_c, r_b = ip[mb + MB_RAMP_T], ip[mb + MB_RAMP_C], ip[mb + MB_RAMP_B]
    # the commands at and beyond t_stop (the last stage, the witnesses there): a jump at
    # t_stop seen from the left, as the reference (commands.Ramp.at)
    set_ramp_end(fp, r_t, t_stop)
    set_ramp_end(fp, r_c, t_stop)
    set_ramp_end(fp, r_b, t_stop)
    RH = ros[6]
    if method == M_DOPRI5:
        nk = 7
        order = DP_ORDER
    elif method == M_DOP853:
        nk = 23
        order = D8_ORDER
    elif method == M_ERK:
        nk = D8.shape[0]                  # the step's stages, the interpolant's extra ones
        order = int(rp[RP_ORDER])
    else:
        nk = ros[2].shape[0] + 2          # f, the stages, f at the step start
        order = int(rp[RP_ORDER])
    K = _scratch(nk, ns)
    fsal = 6 if method == M_DOPRI5 else (B8.shape[0] - 1 if method == M_ERK else B8.shape[0])
    work = _scratch(4, ns)
    vecs = _scratch(3, ns)
    y_old = vecs[0]
    yy = vecs[1]
    dy = vecs[2]
    ros_m = ns if method == M_ROSENBROCK else 0
    J = _scratch(ros_m, ros_m)
    LU = _scratch(ros_m, ros_m)
    piv = np.zeros(ros_m, np.int64)
    ft = _scratch(1, ros_m)[0]
    gs = _scratch(3, max(nw, 1))
    g_old = gs[0]
    g_new = gs[1]
    wv = gs[2]
    fs = _scratch(1, NFS)[0]
    cnt = np.zeros(NCNT, np.int64)
    fs[FS_T] = t0
    fs[FS_ERROLD] = 1e-4        # the PI controller's memory at a start (kernel/stepper.py)
    out_i[0] = ST_OK
    out_i[1] = -1
    _f(kind, t0, y, ip, fp, K[0], sc, False)
    cnt[C_NFEV] += 1
    if h_in > 0.0:
        fs[FS_H] = min(h_in, max_step)
    else:
        h0 = _initial_step(kind, y, K[0], t0, ip, fp, sc, rtol, atol, max_step, order, work[0],
                           work[2])
        cnt[C_NFEV] += 1
        if h0 < 0.0:
            out_i[0] = ST_NONFINITE
            return
        fs[FS_H] = h0
    _witness_at(kind, t0, y, ip, fp, dy, sc, g_old)
    k = k0
    m = t_samp.shape[0]
    steps = 0
    while True:
        t_old = fs[FS_T]
        if method == M_DOPRI5:
            st = _step(kind, t_stop, y, y_old, ip, fp, fs, cnt, rtol, atol, max_step, K, work,
                       sc)
        elif method == M_DOP853:
            st = _d8_step(kind, t_stop, y, y_old, ip, fp, fs, cnt, rtol, atol, max_step, C8,
                          A8, B8, E5, E3, K, work, sc)
        elif method == M_ERK:
            st = _erk_step(kind, t_stop, y, y_old, ip, fp, fs, cnt, rtol, atol, max_step,
                           order, C8, A8, B8, E5, K, work, sc)
        else:
            st = _ros_step(kind, t0, t_stop, y, y_old, ip, fp, fs, cnt, rtol, atol, max_step,
                           ros, rp, J, LU, piv, ft, K, work, sc)
        if st != ST_OK:
            out_i[0] = st
            break
        if steps < hlog.shape[0]:
            hlog[steps] = fs[FS_HUSED]
        steps += 1
        t_new = fs[FS_T]
        if method != M_ROSENBROCK and t_new == fs[FS_TOLD] + fs[FS_HUSED]:
            # the step's FSAL evaluation was at (t_new, y): its derivative and scratch
            _witness_from(kind, t_new, y, ip, fp, K[fsal], sc, g_new)
        else:
            _witness_at(kind, t_new, y, ip, fp, dy, sc, g_new)
            if method == M_ROSENBROCK:
                # f at the step end: the Hermite dense output's and the next step's f(t, y);
                # at the segment's end with the commands' left limit (_ros_stages)
                if t_new >= t_stop:
                    _f(kind, np.nextafter(t_stop, -np.inf), y, ip, fp, K[0], sc, False)
                    cnt[C_NFEV] += 1
                else:
                    for j in range(ns):
                        K[0, j] = dy[j]
                cnt[C_NFEV] += 1
        best_t = math.inf
        best_i = -1
        for i in range(nw):
            d = ip[w0 + wstride * i + 2]
            if d < 0:
                hit = g_old[i] > 0.0 and g_new[i] <= 0.0
            else:
                hit = g_old[i] < 0.0 and g_new[i] >= 0.0
            if hit:
                if g_new[i] == 0.0:
                    t_i = t_new
                else:
                    # as scipy's brentq: both ends from the function (the dense output)
                    f_a = _dense_witness(kind, method, t_old, i, y, y_old, fs, cnt, K, ip, fp,
                                         yy, dy, sc, wv, D8, AX, CX, RH)
                    f_b = _dense_witness(kind, method, t_new, i, y, y_old, fs, cnt, K, ip, fp,
                                         yy, dy, sc, wv, D8, AX, CX, RH)
                    t_i = brent_root(kind, t_old, t_new, f_a, f_b, i, method, y, y_old, fs, cnt,
                                     K, ip, fp, yy, dy, sc, wv, D8, AX, CX, RH)
                if t_i < best_t:
                    best_t = t_i
                    best_i = i
        t_end = best_t if best_i >= 0 else t_new
        while k < m and t_samp[k] <= t_end:
            ts = t_samp[k]
            if ts == t_new:
                for j in range(ns):
                    Y[k, j] = y[j]
            else:
                _dense(kind, method, max(ts, t_old), y, y_old, ip, fp, fs, cnt, K, sc, D8, AX,
                       CX, RH, Y[k])
            k += 1
        if best_i >= 0:
            if best_t != t_new:
                _dense(kind, method, best_t, y, y_old, ip, fp, fs, cnt, K, sc, D8, AX, CX, RH,
                       yy)
                for j in range(ns):
                    y[j] = yy[j]
            out_i[1] = best_i
            out_f[0] = best_t
            break
        for i in range(nw):
            g_old[i] = g_new[i]
        if t_new >= t_stop:
            out_f[0] = t_stop
            break
        if method != M_ROSENBROCK:
            for j in range(ns):        # FSAL
                K[0, j] = K[fsal, j]
    out_i[2] = k
    out_i[3] = steps
    out_i[4] = cnt[C_NFEV]
    out_i[5] = cnt[C_NREJ]
    out_i[6] = min(steps, hlog.shape[0])
    out_f[1] = fs[FS_H]
    if out_f.shape[0] > 2:
        out_f[2] = fs[FS_HLAST]
