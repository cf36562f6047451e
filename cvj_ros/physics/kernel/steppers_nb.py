"""Compiled (numba) steppers over a right-hand side ``RHS(t, y, ip, fp, dy)``.

Every function here is ``@njit(cache=True)`` without fastmath, and
every sum is a hand-written loop in a fixed order (no BLAS, no numpy reductions
whose order could depend on the CPU), so the bytes of a trajectory do not
depend on ``OPENBLAS_CORETYPE`` or the machine.

The right-hand side and its Jacobian are the module globals ``RHS`` and ``JAC``:
``kernel/rhs_nb.py``'s ``rhs(t, y, ip, fp, dy)`` / ``jac(t, y, ip, fp, J)`` (filled in
place; ip: int64 codes, fp: float64 parameters - the scene as data); ``JAC_KEEP(ip)`` (1:
the model's Jacobian varies only in its work integrals' rows) and ``JAC_ROWS(t, y, ip, fp,
J)`` (those rows alone) let the Rosenbrock steppers keep the rest (:func:`_ros_jacobian`).
Globals, not arguments: a numba function with a dispatcher among its arguments is compiled afresh in
every process (the disk cache keys on the dispatcher object; measured 20-30 s per method
per process), while calls to a global dispatcher are linked into the cached code. Toy
right-hand sides (tests) get a private, uncached copy of this module with other globals:
:func:`cvj_ros.physics.kernel.stepper.steppers_for`.

Persistent state lives in arrays owned by the caller (``kernel/stepper.py``), so
a stepper is not restarted at each exchange step:

``fs`` (float64[NFS]) : FS_T t (s), FS_H next step proposal (s, 0 = unset),
    FS_TOLD start of the last accepted step (s), FS_ERROLD PI controller memory,
    FS_HLAST length of the last accepted step (s), FS_TBAD t of a non-finite state.
``cnt`` (int64[NCNT]) : C_NFEV, C_NJEV, C_NLU, C_NACC, C_NREJ, C_HAVEF (1 = the
    FSAL derivative K[0] / f is valid), C_LASTREJ (1 = last attempt rejected),
    C_BADIDX (index of the first non-finite state for the error message), C_HAVEJ,
    C_HAVELU (Rosenbrock: Jacobian, LU valid), C_DENSE (dop853: dense stages valid),
    C_LUM (Rosenbrock: size of the block the LU factors, see _coupled_size), C_JKEPT
    (Rosenbrock: J's coupled block is the model's constant one, see _ros_jacobian).

Step-size control copies ``solvers._AdaptiveStepper`` (Hairer's HINIT initial
step, PI controller with safety 0.9, fac_min 0.2, fac_max 10, beta 0.04, step
clipped to land on t_bound when within 1 %, proposal kept across a clipped
step), so the compiled and the Python steppers take the same steps up to
rounding. Return codes: ST_OK, ST_NONFINITE (a state or derivative is not
finite even after shrinking the step), ST_UNDERFLOW (h < 10 eps |t|).

Sources: Dormand & Prince, J. Comp. Appl. Math. 6 (1980) 19-26; Hairer,
Norsett & Wanner, Solving ODEs I (2nd ed.), sec. II.4 (HINIT), II.5 (table
5.2), IV.2 (PI control); dense output coefficients of Shampine, Math. Comp. 46
(1986) as in scipy.integrate.RK45; classic RK4: Kutta, Z. Math. Phys. 46 (1901).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from .borrow_nb import borrowed_all
from .rhs_nb import jac as JAC
from .rhs_nb import jac_energy_rows as JAC_ROWS
from .rhs_nb import jac_keeps_block as JAC_KEEP
from .rhs_nb import rhs as RHS

# ------------------------------------------------------------------ layout
FS_T, FS_H, FS_TOLD, FS_ERROLD, FS_HLAST, FS_TBAD = 0, 1, 2, 3, 4, 5
NFS = 8
(C_NFEV, C_NJEV, C_NLU, C_NACC, C_NREJ, C_HAVEF, C_LASTREJ, C_BADIDX, C_HAVEJ, C_HAVELU,
 C_DENSE, C_LUM, C_JKEPT) = range(13)
NCNT = 13
FS_LUH = 6      # h of the current LU factors (Rosenbrock)
ST_SINGULAR = 3  # I/(h gamma) - J singular or non-finite
ST_OK, ST_NONFINITE, ST_UNDERFLOW = 0, 1, 2

_EPS = np.finfo(float).eps
SAFETY = 0.9
FAC_MIN = 0.2
FAC_MAX = 10.0
BETA = 0.04

# ------------------------------------------------- Dormand-Prince 5(4) tableau
# Exactly the doubles of scipy.integrate.RK45 (C, A, B, E, P), so the Python
# oracle (solvers.Dopri5Stepper) and this kernel use the same coefficients.
DP_C = np.array([0.0, 0.2, 0.3, 0.8, 0.8888888888888888, 1.0])
DP_A = np.array([
    [0.0, 0.0, 0.0, 0.0, 0.0],
    [0.2, 0.0, 0.0, 0.0, 0.0],
    [0.075, 0.225, 0.0, 0.0, 0.0],
    [0.9777777777777777, -3.7333333333333334, 3.5555555555555554, 0.0, 0.0],
    [2.9525986892242035, -11.595793324188385, 9.822892851699436, -0.2908093278463649, 0.0],
    [2.8462752525252526, -10.757575757575758, 8.906422717743473, 0.2784090909090909,
     -0.2735313036020583]])
DP_B = np.array([0.09114583333333333, 0.0, 0.44923629829290207, 0.6510416666666666,
                 -0.322376179245283, 0.13095238095238096])
DP_E = np.array([-0.0012326388888888888, 0.0, 0.0042527702905061394, -0.03697916666666667,
                 0.05086379716981132, -0.0419047619047619, 0.025])
DP_P = np.array([
    [1.0, -2.8535800653862835, 3.0717434641059005, -1.1270175653862835],
    [0.0, 0.0, 0.0, 0.0],
    [0.0, 4.023133379230305, -6.249321565289, 2.675424484351598],
    [0.0, -3.7324019615885042, 10.068970589843675, -5.685526961588504],
    [0.0, 2.5548038301849423, -6.399112377351017, 3.5219323679207912],
    [0.0, -1.3744241142186024, 3.272657752246729, -1.7672812570757455],
    [0.0, 1.3824689317781436, -3.764937863556287, 2.382468931778144]])
DP_ORDER = 4  # order of the error estimator: controller exponent 1/(order+1)


# ------------------------------------------------------------------ helpers
@njit(cache=True, inline='always')
def _first_nonfinite(v: np.ndarray) -> int:
    """Index of the first non-finite entry of v, -1 when all are finite."""
    for i in range(v.shape[0]):
        if not math.isfinite(v[i]):
            return i
    return -1


@njit(cache=True)
def _initial_step(y, f0, ip, fp, fs, cnt, rtol, atol, max_step, order, tmp, f1):
    """Hairer's HINIT (HNW I, sec. II.4), same arithmetic as solvers._initial_step;
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
def _proposal(h, err, fs, expo, fac_max):
    """PI controller after an accepted step (solvers._proposal)."""
    fac = err ** expo / fs[FS_ERROLD] ** BETA / SAFETY
    if fac > 0:
        fac = min(1.0 / FAC_MIN, max(1.0 / fac_max, fac))
    else:
        fac = 1.0 / fac_max
    fs[FS_ERROLD] = max(err, 1e-4)
    return h / fac


# ------------------------------------------------------------------ dopri5
@njit(cache=True, inline='always')
def _dopri5_attempt(h, y, ip, fp, fs, cnt, rtol, atol, K, work):
    """One DOPRI5 attempt of size h from (fs[FS_T], y) with K[0] = f(t, y).
    Fills K[1..6] (K[6] = f(t+h, y_new), FSAL) and work[1] = y_new; returns the
    scaled RMS error (NaN when a stage is not finite)."""
    n = y.shape[0]
    t = fs[FS_T]
    arg = work[0]
    # stage sums row by row (contiguous rows of K, fixed order j = 0, 1, ...):
    # arg = y + (h a_s0) k_0 + (h a_s1) k_1 + ..., the order of the Python oracle's
    # product with the h-scaled coefficient row
    for s in range(1, 6):
        for i in range(n):
            arg[i] = y[i]
        for j in range(s):
            c = h * DP_A[s, j]
            if c != 0.0:
                kj = K[j]
                for i in range(n):
                    arg[i] += c * kj[i]
        RHS(t + DP_C[s] * h, arg, ip, fp, K[s])
    ynew = work[1]
    for i in range(n):
        ynew[i] = y[i]
    for j in range(6):
        c = h * DP_B[j]
        if c != 0.0:
            kj = K[j]
            for i in range(n):
                ynew[i] += c * kj[i]
    RHS(t + h, ynew, ip, fp, K[6])
    cnt[C_NFEV] += 6
    ss = 0.0
    for i in range(n):
        e = 0.0
        for j in range(7):
            e += DP_E[j] * K[j, i]
        sc = max(abs(y[i]), abs(ynew[i])) * rtol + atol[i]
        ss += (e / sc) ** 2
    return abs(h) * math.sqrt(ss / n)


@njit(cache=True, inline='always')
def dopri5_step(t_bound, y, y_old, ip, fp, fs, cnt, rtol, atol, max_step, K, work):
    """One accepted DOPRI5 step from fs[FS_T] of the controller's size, clipped to
    land on t_bound when within 1 %. y is updated in place (old value in
    y_old); K keeps the stages of the step for ``dopri5_dense``. Returns ST_*."""
    n = y.shape[0]
    expo = 1.0 / (DP_ORDER + 1) - 0.75 * BETA
    t = fs[FS_T]
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
        h0 = _initial_step(y, K[0], ip, fp, fs, cnt, rtol, atol, max_step, DP_ORDER,
                           work[0], work[2])
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
    while True:
        if h < 10 * _EPS * max(abs(t), 1e-300) or h <= 1e-300:
            return ST_NONFINITE if nonfinite else ST_UNDERFLOW
        err = _dopri5_attempt(h, y, ip, fp, fs, cnt, rtol, atol, K, work)
        if err <= 1.0:
            h_new = _proposal(h, err, fs, expo, FAC_MAX)
            if cnt[C_LASTREJ] == 1:
                h_new = min(h_new, h)
            cnt[C_LASTREJ] = 0
            cnt[C_NACC] += 1
            t_new = t_bound if clipped else t + h
            ynew = work[1]
            for i in range(n):
                y_old[i] = y[i]
                y[i] = ynew[i]
            # K[0] <- FSAL value after the dense data are no longer needed: keep
            # the stages in K[0..6] for dense output and move FSAL on next step.
            fs[FS_TOLD] = t
            fs[FS_T] = t_new
            fs[FS_HLAST] = t_new - t
            fs[FS_H] = min(max(h_new, h_prop) if clipped else h_new, max_step)
            cnt[C_HAVEF] = 2  # 2: FSAL value sits in K[6]
            return ST_OK
        cnt[C_NREJ] += 1
        cnt[C_LASTREJ] = 1
        clipped = False
        ynew = work[1]
        if math.isfinite(err) and _first_nonfinite(ynew) < 0:
            h = h / min(1.0 / FAC_MIN, err ** expo / SAFETY)
        else:
            nonfinite = True
            bad = _first_nonfinite(ynew)
            cnt[C_BADIDX] = bad
            fs[FS_TBAD] = t + h
            h = h * FAC_MIN


@njit(cache=True, inline='always')
def _dopri5_fsal(K, cnt):
    """Move the FSAL derivative of the last accepted step (K[6]) to K[0]."""
    if cnt[C_HAVEF] == 2:
        for i in range(K.shape[1]):
            K[0, i] = K[6, i]
        cnt[C_HAVEF] = 1


@njit(cache=True, inline='always')
def dopri5_advance(t_end, y, y_old, ip, fp, fs, cnt, rtol, atol, max_step, K, work):
    """Integrate to exactly t_end (s); keeps h across calls. Returns ST_*.
    After return K holds the last step's stages (dense output valid)."""
    y, y_old, ip, fp, fs, cnt, K, work = borrowed_all((y, y_old, ip, fp, fs, cnt, K, work))
    while fs[FS_T] < t_end:
        _dopri5_fsal(K, cnt)
        st = dopri5_step(t_end, y, y_old, ip, fp, fs, cnt, rtol, atol, max_step, K, work)
        if st != ST_OK:
            return st
    return ST_OK


@njit(cache=True)
def dopri5_step_once(t_bound, y, y_old, ip, fp, fs, cnt, rtol, atol, max_step, K, work):
    """One natural step never past t_bound (Stepper.step); returns ST_*."""
    y, y_old, ip, fp, fs, cnt, K, work = borrowed_all((y, y_old, ip, fp, fs, cnt, K, work))
    if fs[FS_T] < t_bound:
        _dopri5_fsal(K, cnt)
        return dopri5_step(t_bound, y, y_old, ip, fp, fs, cnt, rtol, atol, max_step,
                           K, work)
    return ST_OK


@njit(cache=True)
def dopri5_dense(t, y_old, fs, K, out):
    """4th-order continuous extension inside the last accepted step:
    out = y_old + h * sum_j K[j] * (P[j] . [x, x^2, x^3, x^4]), x = (t - t_old)/h."""
    n = y_old.shape[0]
    h = fs[FS_HLAST]
    if h == 0.0:
        for i in range(n):
            out[i] = y_old[i]
        return
    x = (t - fs[FS_TOLD]) / h
    x2 = x * x
    x3 = x2 * x
    x4 = x3 * x
    for i in range(n):
        acc = 0.0
        for j in range(7):
            q = DP_P[j, 0] * x + DP_P[j, 1] * x2 + DP_P[j, 2] * x3 + DP_P[j, 3] * x4
            acc += K[j, i] * q
        out[i] = y_old[i] + h * acc


@njit(cache=True)
def dopri5_sample(t_eval, y, y_old, ip, fp, fs, cnt, rtol, atol, max_step, K, work, Y):
    """Compiled sampled loop: natural steps to t_eval[-1], each output time
    (ascending, >= fs[FS_T]) filled into Y[k] by dense output (exact end point
    at the step end). Returns (status, number of rows written)."""
    (t_eval, y, y_old, ip, fp, fs, cnt, K, work, Y) = borrowed_all((
        t_eval, y, y_old, ip, fp, fs, cnt, K, work, Y))
    m = t_eval.shape[0]
    k = 0
    n = y.shape[0]
    while k < m and t_eval[k] <= fs[FS_T]:
        for i in range(n):
            Y[k, i] = y[i]
        k += 1
    if k >= m:
        return ST_OK, k
    t_last = t_eval[m - 1]
    while k < m:
        _dopri5_fsal(K, cnt)
        st = dopri5_step(t_last, y, y_old, ip, fp, fs, cnt, rtol, atol, max_step, K, work)
        if st != ST_OK:
            return st, k
        t_now = fs[FS_T]
        while k < m and t_eval[k] <= t_now:
            if t_eval[k] == t_now:
                for i in range(n):
                    Y[k, i] = y[i]
            else:
                dopri5_dense(t_eval[k], y_old, fs, K, Y[k])
            k += 1
    return ST_OK, k


# ---------------------------------------------------------------------- rk4
@njit(cache=True, inline='always')
def _rk4_take(dt, t_new, y, y_old, ip, fp, fs, cnt, K, work):
    """One classic RK4 step of dt; K[0] = f(t, y) on entry (computed when
    cnt[C_HAVEF] == 0), K[4] = f at the new point is left invalid (cnt[C_HAVEF]=0)."""
    n = y.shape[0]
    t = fs[FS_T]
    if cnt[C_HAVEF] == 0:
        RHS(t, y, ip, fp, K[0])
        cnt[C_NFEV] += 1
    hh = 0.5 * dt
    arg = work[0]
    for i in range(n):
        arg[i] = y[i] + hh * K[0, i]
    RHS(t + hh, arg, ip, fp, K[1])
    for i in range(n):
        arg[i] = y[i] + hh * K[1, i]
    RHS(t + hh, arg, ip, fp, K[2])
    for i in range(n):
        arg[i] = y[i] + dt * K[2, i]
    RHS(t + dt, arg, ip, fp, K[3])
    cnt[C_NFEV] += 3
    ynew = work[1]
    for i in range(n):
        ynew[i] = y[i] + (dt / 6.0) * (K[0, i] + 2.0 * (K[1, i] + K[2, i]) + K[3, i])
    bad = _first_nonfinite(ynew)
    if bad >= 0:
        cnt[C_BADIDX] = bad
        fs[FS_TBAD] = t_new
        return ST_NONFINITE
    for i in range(n):
        y_old[i] = y[i]
        y[i] = ynew[i]
        K[4, i] = K[0, i]   # f at the step start, kept for Hermite dense output
    fs[FS_TOLD] = t
    fs[FS_T] = t_new
    fs[FS_HLAST] = t_new - t
    cnt[C_HAVEF] = 0
    cnt[C_NACC] += 1
    return ST_OK


@njit(cache=True, inline='always')
def rk4_advance(t_end, y, y_old, ip, fp, fs, cnt, K, work):
    """Integrate to exactly t_end with ceil((t_end - t)/h) equal substeps <= h
    (h = fs[FS_H]), as solvers._FixedStepper.advance_to. Returns ST_*."""
    y, y_old, ip, fp, fs, cnt, K, work = borrowed_all((y, y_old, ip, fp, fs, cnt, K, work))
    t0 = fs[FS_T]
    span = t_end - t0
    if span <= 0.0:
        return ST_OK
    nsub = max(1, int(math.ceil(span / fs[FS_H] * (1 - 1e-12))))
    dt = span / nsub
    for k in range(1, nsub + 1):
        t_new = t_end if k == nsub else t0 + k * dt
        st = _rk4_take(dt, t_new, y, y_old, ip, fp, fs, cnt, K, work)
        if st != ST_OK:
            return st
    return ST_OK


@njit(cache=True)
def rk4_step_once(t_bound, y, y_old, ip, fp, fs, cnt, K, work):
    """One step of h shortened to end on t_bound (Stepper.step); returns ST_*."""
    y, y_old, ip, fp, fs, cnt, K, work = borrowed_all((y, y_old, ip, fp, fs, cnt, K, work))
    t = fs[FS_T]
    if t >= t_bound:
        return ST_OK
    h = fs[FS_H]
    if h * (1 + 1e-12) >= t_bound - t:
        return _rk4_take(t_bound - t, t_bound, y, y_old, ip, fp, fs, cnt, K, work)
    return _rk4_take(h, t + h, y, y_old, ip, fp, fs, cnt, K, work)


@njit(cache=True)
def hermite_dense(t, y, y_old, ip, fp, fs, cnt, K, out, frow=4):
    """Cubic Hermite y(t) inside the last fixed step (3rd order), from f at the
    step start (K[frow]) and f at the step end (computed once into K[0], reused by
    the next step as its first stage: cnt[C_HAVEF] = 1)."""
    y, y_old, ip, fp, fs, cnt, K, out = borrowed_all((y, y_old, ip, fp, fs, cnt, K, out))
    _hermite_into(t, y, y_old, ip, fp, fs, cnt, K, out, frow)


@njit(cache=True, inline='always')
def _hermite_into(t, y, y_old, ip, fp, fs, cnt, K, out, frow):
    """:func:`hermite_dense`'s body, inlined where a sampled loop calls it per sample."""
    n = y.shape[0]
    h = fs[FS_HLAST]
    if h == 0.0 or t == fs[FS_T]:
        for i in range(n):
            out[i] = y[i]
        return
    if cnt[C_HAVEF] == 0:
        RHS(fs[FS_T], y, ip, fp, K[0])
        cnt[C_NFEV] += 1
        cnt[C_HAVEF] = 1
    s = (t - fs[FS_TOLD]) / h
    s2 = s * s
    s3 = s2 * s
    h00 = 2 * s3 - 3 * s2 + 1
    h10 = s3 - 2 * s2 + s
    h01 = -2 * s3 + 3 * s2
    h11 = s3 - s2
    for i in range(n):
        out[i] = h00 * y_old[i] + h10 * h * K[frow, i] + h01 * y[i] + h11 * h * K[0, i]


@njit(cache=True)
def rk4_sample(t_eval, y, y_old, ip, fp, fs, cnt, K, work, Y):
    """Compiled sampled loop for rk4: steps of h to t_eval[-1], Hermite dense
    output at each output time. Returns (status, rows written)."""
    (t_eval, y, y_old, ip, fp, fs, cnt, K, work, Y) = borrowed_all((
        t_eval, y, y_old, ip, fp, fs, cnt, K, work, Y))
    m = t_eval.shape[0]
    n = y.shape[0]
    k = 0
    while k < m and t_eval[k] <= fs[FS_T]:
        for i in range(n):
            Y[k, i] = y[i]
        k += 1
    t_last = t_eval[m - 1] if m > 0 else fs[FS_T]
    while k < m:
        st = rk4_step_once(t_last, y, y_old, ip, fp, fs, cnt, K, work)
        if st != ST_OK:
            return st, k
        t_now = fs[FS_T]
        while k < m and t_eval[k] <= t_now:
            if t_eval[k] == t_now:
                for i in range(n):
                    Y[k, i] = y[i]
            else:
                _hermite_into(t_eval[k], y, y_old, ip, fp, fs, cnt, K, Y[k], 4)
            k += 1
    return ST_OK, k


# ------------------------------------------------------------ Rosenbrock (ros2)
# Linear algebra by hand (partial pivoting LU, row order fixed), no LAPACK/BLAS.
ROS2_GAMMA = 1.0 + 1.0 / math.sqrt(2.0)
ROS2_A = np.array([[0.0, 0.0], [1.0 / ROS2_GAMMA, 0.0]])
ROS2_C = np.array([[0.0, 0.0], [-2.0 / ROS2_GAMMA, 0.0]])
ROS2_M = np.array([1.5 / ROS2_GAMMA, 0.5 / ROS2_GAMMA])
ROS2_ALPHA = np.array([0.0, 1.0])
ROS2_GSUM = np.array([ROS2_GAMMA, -ROS2_GAMMA])


@njit(cache=True, inline='always')
def lu_factor(G, piv, m):
    """In-place LU with partial pivoting (Doolittle, row interchanges in piv) of the leading
    m x m block of G, for a G whose columns m.. are zero but for a diagonal: then G is block
    lower triangular [[G11, 0], [G21, D]] and solving needs only G11's factors, G21 and D
    (lu_solve). m = n is the plain LU. Returns False when a pivot is zero or an entry the
    solve reads is not finite."""
    n = G.shape[0]
    for k in range(m):
        p = k
        big = abs(G[k, k])
        for i in range(k + 1, m):
            if abs(G[i, k]) > big:
                big = abs(G[i, k])
                p = i
        piv[k] = p
        if big == 0.0 or not math.isfinite(big):
            return False
        if p != k:
            for j in range(m):
                tmp = G[k, j]
                G[k, j] = G[p, j]
                G[p, j] = tmp
        inv = 1.0 / G[k, k]
        for i in range(k + 1, m):
            G[i, k] *= inv
            lik = G[i, k]
            if lik != 0.0:
                for j in range(k + 1, m):
                    G[i, j] -= lik * G[k, j]
    for i in range(m):
        for j in range(m):
            if not math.isfinite(G[i, j]):
                return False
    for i in range(m, n):
        if G[i, i] == 0.0 or not math.isfinite(G[i, i]):
            return False
        for j in range(m):
            if not math.isfinite(G[i, j]):
                return False
    return True


@njit(cache=True, inline='always')
def lu_solve(LU, piv, b, m):
    """Solve G x = b in place in b from lu_factor(G, piv, m): forward then back
    substitution on the leading block, then x_i = (b_i - G21 x_1) / D_ii below it."""
    n = LU.shape[0]
    for k in range(m):
        p = piv[k]
        if p != k:
            tmp = b[k]
            b[k] = b[p]
            b[p] = tmp
    for i in range(m):
        acc = b[i]
        for j in range(i):
            acc -= LU[i, j] * b[j]
        b[i] = acc
    for i in range(m - 1, -1, -1):
        acc = b[i]
        for j in range(i + 1, m):
            acc -= LU[i, j] * b[j]
        b[i] = acc / LU[i, i]
    for i in range(m, n):
        acc = b[i]
        for j in range(m):
            acc -= LU[i, j] * b[j]
        b[i] = acc / LU[i, i]


@njit(cache=True, inline='always')
def _coupled_size(J):
    """States up to the last column of J that is not all zero: the trailing states with
    zero columns (the energy work integrals, quadratures that feed back into nothing)
    leave I/(h gamma) - J block lower triangular, so the LU needs only the block before
    them (6x fewer multiplications for a 2-DOF driveline: 4x4 instead of 7x7)."""
    n = J.shape[0]
    m = n
    while m > 0:
        for i in range(n):
            if J[i, m - 1] != 0.0:
                return m
        m -= 1
    return 0


@njit(cache=True)
def keep_none(ip):
    """JAC_KEEP of a toy right-hand side (stepper.steppers_for): never keep J."""
    return 0


@njit(cache=True, inline='always')
def _ros_jacobian(t, y, ip, fp, cnt, J):
    """J = JAC(t, y). For a model whose Jacobian varies only in the work integrals' rows
    (JAC_KEEP(ip) = 1: layout.jacobian_block_constant), J's other rows are kept from the
    first evaluation of the run (C_JKEPT) and only those rows refreshed (JAC_ROWS): the
    same bits as JAC at a (t, y) where f is finite, which the callers have checked
    (K[0] = f(t, y) first). Counted in C_NJEV either way."""
    if cnt[C_JKEPT] != 0:
        JAC_ROWS(t, y, ip, fp, J)
    else:
        JAC(t, y, ip, fp, J)
        cnt[C_JKEPT] = JAC_KEEP(ip)
    cnt[C_NJEV] += 1


@njit(cache=True, inline='always')
def _ros_prepare(h, gamma, y, ip, fp, fs, cnt, autonomous, J, LU, piv, ft, K, work):
    """Jacobian and f_t at (t, y) if stale, LU of I/(h gamma) - J if h changed
    (same policy as solvers._LinearlyImplicit._prepare). K[0] = f(t, y)."""
    n = y.shape[0]
    t = fs[FS_T]
    if cnt[C_HAVEF] == 0:
        RHS(t, y, ip, fp, K[0])
        cnt[C_NFEV] += 1
        bad = _first_nonfinite(K[0])
        if bad >= 0:
            cnt[C_BADIDX] = bad
            fs[FS_TBAD] = t
            return ST_NONFINITE
        cnt[C_HAVEF] = 1
    if cnt[C_HAVEJ] == 0:
        _ros_jacobian(t, y, ip, fp, cnt, J)
        cnt[C_HAVELU] = 0
        if autonomous:
            for i in range(n):
                ft[i] = 0.0
        else:
            # central difference: error ~ eps^(2/3)
            delta = _EPS ** (1.0 / 3.0) * max(1.0, abs(t))
            RHS(t + delta, y, ip, fp, work[2])
            RHS(t - delta, y, ip, fp, work[3])
            cnt[C_NFEV] += 2
            for i in range(n):
                ft[i] = (work[2, i] - work[3, i]) / (2.0 * delta)
        cnt[C_HAVEJ] = 1
    if cnt[C_HAVELU] == 0 or abs(fs[FS_LUH] - h) > 1e-12 * h:
        d = 1.0 / (h * gamma)
        for i in range(n):
            for j in range(n):
                LU[i, j] = -J[i, j]
            LU[i, i] += d
        cnt[C_NLU] += 1
        if cnt[C_JKEPT] == 0 or cnt[C_LUM] == 0:
            # a kept block fixes it: the refreshed work integrals' rows have entries in the
            # mechanical states' columns only, which J[n-1, 2n-1] = 1 already covers
            cnt[C_LUM] = _coupled_size(J)
        if not lu_factor(LU, piv, cnt[C_LUM]):
            fs[FS_TBAD] = t
            return ST_SINGULAR
        fs[FS_LUH] = h
        cnt[C_HAVELU] = 1
    return ST_OK


@njit(cache=True, inline='always')
def _stage_at_start(s, A, alpha):
    """True when stage s > 0 evaluates f at (t, y) itself: alpha_s = 0 and no A terms
    (RODAS3's second stage; KPP's ros_NewF = false). Its f is K[0], reused."""
    if alpha[s] != 0.0:
        return False
    for j in range(s):
        if A[s, j] != 0.0:
            return False
    return True


@njit(cache=True, inline='always')
def _ros_stages(h, y, ip, fp, fs, cnt, A, C, M, alpha, gsum, LU, piv, ft, K, work):
    """Rosenbrock stages in K form: (I/(h g) - J) K_i = f(t + alpha_i h,
    y + sum_j A_ij K_j) + sum_j C_ij/h K_j + h gsum_i f_t; K_i into K[i+1]
    (K[0] = f(t, y), also the f of a stage at (t, y): _stage_at_start). y_new into
    work[1]."""
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
            # argument (t, y) itself (RODAS3's second stage): f(t, y) = K[0], not evaluated
            for i in range(n):
                b[i] = K[0, i]
        else:
            for i in range(n):
                acc = 0.0
                for j in range(s):
                    acc += A[s, j] * K[j + 1, i]
                arg[i] = y[i] + acc
            RHS(t + alpha[s] * h, arg, ip, fp, b)
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


@njit(cache=True, inline='always')
def _ros2_take(dt, t_new, y, y_old, ip, fp, fs, cnt, autonomous, constant_jac,
               J, LU, piv, ft, K, work):
    """One ROS2 step of dt (solvers.Ros2Stepper._step + _FixedStepper._take)."""
    n = y.shape[0]
    st = _ros_prepare(dt, ROS2_GAMMA, y, ip, fp, fs, cnt, autonomous, J, LU, piv,
                      ft, K, work)
    if st != ST_OK:
        return st
    _ros_stages(dt, y, ip, fp, fs, cnt, ROS2_A, ROS2_C, ROS2_M, ROS2_ALPHA, ROS2_GSUM,
                LU, piv, ft, K, work)
    ynew = work[1]
    bad = _first_nonfinite(ynew)
    if bad >= 0:
        cnt[C_BADIDX] = bad
        fs[FS_TBAD] = t_new
        return ST_NONFINITE
    for i in range(n):
        y_old[i] = y[i]
        y[i] = ynew[i]
        K[4, i] = K[0, i]   # f at the step start, for Hermite dense output (K has 5 rows)
    fs[FS_TOLD] = fs[FS_T]
    fs[FS_HLAST] = t_new - fs[FS_T]
    fs[FS_T] = t_new
    cnt[C_HAVEF] = 0
    if not constant_jac:
        cnt[C_HAVEJ] = 0
    cnt[C_NACC] += 1
    return ST_OK


@njit(cache=True, inline='always')
def ros2_advance(t_end, y, y_old, ip, fp, fs, cnt, autonomous, constant_jac,
                 J, LU, piv, ft, K, work):
    """ROS2 to exactly t_end with ceil(span/h) equal substeps <= h. Returns ST_*."""
    (y, y_old, ip, fp, fs, cnt, J, LU, piv, ft, K, work) = borrowed_all((
        y, y_old, ip, fp, fs, cnt, J, LU, piv, ft, K, work))
    t0 = fs[FS_T]
    span = t_end - t0
    if span <= 0.0:
        return ST_OK
    nsub = max(1, int(math.ceil(span / fs[FS_H] * (1 - 1e-12))))
    dt = span / nsub
    for k in range(1, nsub + 1):
        t_new = t_end if k == nsub else t0 + k * dt
        st = _ros2_take(dt, t_new, y, y_old, ip, fp, fs, cnt, autonomous,
                        constant_jac, J, LU, piv, ft, K, work)
        if st != ST_OK:
            return st
    return ST_OK


@njit(cache=True)
def ros2_step_once(t_bound, y, y_old, ip, fp, fs, cnt, autonomous, constant_jac,
                   J, LU, piv, ft, K, work):
    """One ROS2 step of h shortened to end on t_bound; returns ST_*."""
    (y, y_old, ip, fp, fs, cnt, J, LU, piv, ft, K, work) = borrowed_all((
        y, y_old, ip, fp, fs, cnt, J, LU, piv, ft, K, work))
    t = fs[FS_T]
    if t >= t_bound:
        return ST_OK
    h = fs[FS_H]
    if h * (1 + 1e-12) >= t_bound - t:
        return _ros2_take(t_bound - t, t_bound, y, y_old, ip, fp, fs, cnt,
                          autonomous, constant_jac, J, LU, piv, ft, K, work)
    return _ros2_take(h, t + h, y, y_old, ip, fp, fs, cnt, autonomous, constant_jac,
                      J, LU, piv, ft, K, work)


# ------------------------------------------------ adaptive Rosenbrock (RODAS)
# Tableau arrays (K form of solvers._rodas5p_tableau / _rodas4_tableau) are passed
# in; K has s + 2 rows: K[0] = f(t, y), K[1..s] the stages, K[s+1] = f at the
# start of the last accepted step (Hermite dense output for RODAS4).
@njit(cache=True, inline='always')
def ros_step(t_bound, y, y_old, ip, fp, fs, cnt, rtol, atol, max_step, autonomous,
             constant_jac, gamma, A, C, M, E, alpha, gsum, order, fac_max, J, LU, piv, ft, K,
             work):
    """One accepted adaptive Rosenbrock step (solvers.RosenbrockStepper with
    _AdaptiveStepper._step_once): the Jacobian is kept across rejected attempts,
    the LU is refactored when h changes. Returns ST_*."""
    (y, y_old, ip, fp, fs, cnt, A, C, M, E, alpha, gsum, J, LU, piv, ft, K, work) = borrowed_all((
        y, y_old, ip, fp, fs, cnt, A, C, M, E, alpha, gsum, J, LU, piv, ft, K, work))
    n = y.shape[0]
    st_n = M.shape[0]
    expo = 1.0 / (order + 1) - 0.75 * BETA
    t = fs[FS_T]
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
        h0 = _initial_step(y, K[0], ip, fp, fs, cnt, rtol, atol, max_step, order,
                           work[0], work[2])
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
        st = _ros_prepare(h, gamma, y, ip, fp, fs, cnt, autonomous, J, LU, piv, ft,
                          K, work)
        if st != ST_OK:
            return st
        _ros_stages(h, y, ip, fp, fs, cnt, A, C, M, alpha, gsum, LU, piv, ft, K, work)
        ss = 0.0
        for i in range(n):
            e = 0.0
            for j in range(st_n):
                e += E[j] * K[j + 1, i]
            sc = max(abs(y[i]), abs(ynew[i])) * rtol + atol[i]
            ss += (e / sc) ** 2
        err = math.sqrt(ss / n)
        if err <= 1.0:
            h_new = _proposal(h, err, fs, expo, fac_max)
            if cnt[C_LASTREJ] == 1:
                h_new = min(h_new, h)
            cnt[C_LASTREJ] = 0
            cnt[C_NACC] += 1
            t_new = t_bound if clipped else t + h
            for i in range(n):
                K[st_n + 1, i] = K[0, i]
                y_old[i] = y[i]
                y[i] = ynew[i]
            fs[FS_TOLD] = t
            fs[FS_T] = t_new
            fs[FS_HLAST] = t_new - t
            fs[FS_H] = min(max(h_new, h_prop) if clipped else h_new, max_step)
            cnt[C_HAVEF] = 0
            if not constant_jac:
                cnt[C_HAVEJ] = 0
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
def ros_advance(t_end, y, y_old, ip, fp, fs, cnt, rtol, atol, max_step, autonomous,
                constant_jac, gamma, A, C, M, E, alpha, gsum, order, fac_max, J, LU, piv, ft,
                K, work):
    """Adaptive Rosenbrock to exactly t_end; returns ST_*."""
    (y, y_old, ip, fp, fs, cnt, A, C, M, E, alpha, gsum, J, LU, piv, ft, K, work) = borrowed_all((
        y, y_old, ip, fp, fs, cnt, A, C, M, E, alpha, gsum, J, LU, piv, ft, K, work))
    while fs[FS_T] < t_end:
        st = ros_step(t_end, y, y_old, ip, fp, fs, cnt, rtol, atol, max_step,
                      autonomous, constant_jac, gamma, A, C, M, E, alpha, gsum, order, fac_max,
                      J, LU, piv, ft, K, work)
        if st != ST_OK:
            return st
    return ST_OK


@njit(cache=True)
def ros_dense_h(t, y, y_old, fs, H, K, out):
    """RODAS5P continuous extension inside the last accepted step:
    y(x) = (1-x) y0 + x (y1 + (1-x) (D1 + x (D2 + x D3))), D = H K (solvers)."""
    _ros_dense_h_into(t, y, y_old, fs, H, K, out)


@njit(cache=True, inline='always')
def _ros_dense_h_into(t, y, y_old, fs, H, K, out):
    """:func:`ros_dense_h`'s body, inlined where ros_sample calls it per sample."""
    n = y.shape[0]
    h = fs[FS_HLAST]
    x = (t - fs[FS_TOLD]) / h
    x1 = 1.0 - x
    st_n = H.shape[1]
    for i in range(n):
        d0 = 0.0
        d1 = 0.0
        d2 = 0.0
        for j in range(st_n):
            d0 += H[0, j] * K[j + 1, i]
            d1 += H[1, j] * K[j + 1, i]
            d2 += H[2, j] * K[j + 1, i]
        out[i] = x1 * y_old[i] + x * (y[i] + x1 * (d0 + x * (d1 + x * d2)))


# ------------------------------------------------------------------ dop853
# Coefficients (scipy.integrate.DOP853: C, A, B, E5, E3, D, A_EXTRA, C_EXTRA) are
# passed in by the wrapper. K rows: 0..11 stages k0..k11, 12 = f(t+h, y_new)
# (FSAL), 13..15 the three extra dense stages, 16..22 the dense coefficients F.
D8_ORDER = 7
D8_FAC_MIN = 0.333
D8_FAC_MAX = 6.0


@njit(cache=True, inline='always')
def _proposal_nobeta(h, err, fac_min, fac_max, expo):
    """solvers._proposal with beta = 0 (DOP853): h * (safety / err^expo), clamped."""
    fac = err ** expo / SAFETY
    if fac > 0:
        fac = min(1.0 / fac_min, max(1.0 / fac_max, fac))
    else:
        fac = 1.0 / fac_max
    return h / fac


@njit(cache=True, inline='always')
def _dop853_attempt_loop(h, y, ip, fp, t, rtol, atol, C, A, B, E5, E3, K, work):
    """DOP853's attempt as a loop over the tableau arrays: stages K[1..11] at
    y + h (0 + sum_j A_sj k_j) (every j < s, in order), y_new = y + h sum_j B_j k_j in work[1],
    K[12] = f(t + h, y_new), and the sums of squares of the scaled error estimates
    sum_j E5_j k_j, sum_j E3_j k_j over atol + rtol max(|y|, |y_new|) (Hairer, Norsett &
    Wanner 1993, sec. II.10). ``_dop853_attempt`` (generated) is this loop unrolled over
    scipy's tableau, the same operations in the same order; the loop stays as its reference."""
    n = y.shape[0]
    ns = B.shape[0]
    arg = work[0]
    ynew = work[1]
    for s in range(1, ns):
        for i in range(n):
            acc = 0.0
            for j in range(s):
                acc += A[s, j] * K[j, i]
            arg[i] = y[i] + h * acc
        RHS(t + C[s] * h, arg, ip, fp, K[s])
    for i in range(n):
        acc = 0.0
        for j in range(ns):
            acc += B[j] * K[j, i]
        ynew[i] = y[i] + h * acc
    RHS(t + h, ynew, ip, fp, K[ns])
    e5n = 0.0
    e3n = 0.0
    for i in range(n):
        e5 = 0.0
        e3 = 0.0
        for j in range(ns + 1):
            e5 += E5[j] * K[j, i]
            e3 += E3[j] * K[j, i]
        sc = max(abs(y[i]), abs(ynew[i])) * rtol + atol[i]
        e5n += (e5 / sc) ** 2
        e3n += (e3 / sc) ** 2
    return e5n, e3n


# ---- generated by scripts/gen_unrolled_rk.py from tableaux.dop853_coefficients: do not edit ----


@njit(cache=True, inline='always')
def _dop853_attempt(h, y, ip, fp, t, rtol, atol, K, work):
    """dop853_step's attempt of size h (12 rhs evaluations: K[1..11], then
    K[12] = f(t + h, y_new), y_new in work[1]); returns the sums of squares of the
    scaled 5th- and 3rd-order error estimates (their partial sums in work[2], work[3])."""
    n = y.shape[0]
    arg = work[0]
    for i in range(n):
        arg[i] = y[i] + h * (0.0 + 0.05260015195876773 * K[0, i])
    RHS(t + 0.05260015195876773 * h, arg, ip, fp, K[1])
    for i in range(n):
        arg[i] = y[i] + h * (0.0 + 0.0197250569845379 * K[0, i] + 0.0591751709536137 * K[1, i])
    RHS(t + 0.0789002279381516 * h, arg, ip, fp, K[2])
    for i in range(n):
        arg[i] = y[i] + h * (0.0 + 0.02958758547680685 * K[0, i] + 0.0 * K[1, i] + 0.08876275643042054 * K[2, i])
    RHS(t + 0.1183503419072274 * h, arg, ip, fp, K[3])
    for i in range(n):
        arg[i] = y[i] + h * (0.0 + 0.2413651341592667 * K[0, i] + 0.0 * K[1, i] + (-0.8845494793282861) * K[2, i] + 0.924834003261792 * K[3, i])
    RHS(t + 0.2816496580927726 * h, arg, ip, fp, K[4])
    for i in range(n):
        arg[i] = y[i] + h * (0.0 + 0.037037037037037035 * K[0, i] + 0.0 * K[1, i] + 0.0 * K[2, i] + 0.17082860872947386 * K[3, i] + 0.12546768756682242 * K[4, i])
    RHS(t + 0.3333333333333333 * h, arg, ip, fp, K[5])
    for i in range(n):
        arg[i] = y[i] + h * (0.0 + 0.037109375 * K[0, i] + 0.0 * K[1, i] + 0.0 * K[2, i] + 0.17025221101954405 * K[3, i] + 0.06021653898045596 * K[4, i] + (-0.017578125) * K[5, i])
    RHS(t + 0.25 * h, arg, ip, fp, K[6])
    for i in range(n):
        arg[i] = y[i] + h * (0.0 + 0.03709200011850479 * K[0, i] + 0.0 * K[1, i] + 0.0 * K[2, i] + 0.17038392571223998 * K[3, i] + 0.10726203044637328 * K[4, i] + (-0.015319437748624402) * K[5, i] + 0.008273789163814023 * K[6, i])
    RHS(t + 0.3076923076923077 * h, arg, ip, fp, K[7])
    for i in range(n):
        arg[i] = y[i] + h * (0.0 + 0.6241109587160757 * K[0, i] + 0.0 * K[1, i] + 0.0 * K[2, i] + (-3.3608926294469414) * K[3, i] + (-0.868219346841726) * K[4, i] + 27.59209969944671 * K[5, i] + 20.154067550477894 * K[6, i] + (-43.48988418106996) * K[7, i])
    RHS(t + 0.6512820512820513 * h, arg, ip, fp, K[8])
    for i in range(n):
        arg[i] = y[i] + h * (0.0 + 0.47766253643826434 * K[0, i] + 0.0 * K[1, i] + 0.0 * K[2, i] + (-2.4881146199716677) * K[3, i] + (-0.590290826836843) * K[4, i] + 21.230051448181193 * K[5, i] + 15.279233632882423 * K[6, i] + (-33.28821096898486) * K[7, i] + (-0.020331201708508627) * K[8, i])
    RHS(t + 0.6 * h, arg, ip, fp, K[9])
    for i in range(n):
        arg[i] = y[i] + h * (0.0 + (-0.9371424300859873) * K[0, i] + 0.0 * K[1, i] + 0.0 * K[2, i] + 5.186372428844064 * K[3, i] + 1.0914373489967295 * K[4, i] + (-8.149787010746927) * K[5, i] + (-18.52006565999696) * K[6, i] + 22.739487099350505 * K[7, i] + 2.4936055526796523 * K[8, i] + (-3.0467644718982196) * K[9, i])
    RHS(t + 0.8571428571428571 * h, arg, ip, fp, K[10])
    for i in range(n):
        arg[i] = y[i] + h * (0.0 + 2.273310147516538 * K[0, i] + 0.0 * K[1, i] + 0.0 * K[2, i] + (-10.53449546673725) * K[3, i] + (-2.0008720582248625) * K[4, i] + (-17.9589318631188) * K[5, i] + 27.94888452941996 * K[6, i] + (-2.8589982771350235) * K[7, i] + (-8.87285693353063) * K[8, i] + 12.360567175794303 * K[9, i] + 0.6433927460157636 * K[10, i])
    RHS(t + 1.0 * h, arg, ip, fp, K[11])
    ynew = work[1]
    p5 = work[2]
    p3 = work[3]
    for i in range(n):
        k0 = K[0, i]
        k1 = K[1, i]
        k2 = K[2, i]
        k3 = K[3, i]
        k4 = K[4, i]
        k5 = K[5, i]
        k6 = K[6, i]
        k7 = K[7, i]
        k8 = K[8, i]
        k9 = K[9, i]
        k10 = K[10, i]
        k11 = K[11, i]
        ynew[i] = y[i] + h * (0.0 + 0.054293734116568765 * k0 + 0.0 * k1 + 0.0 * k2 + 0.0 * k3 + 0.0 * k4 + 4.450312892752409 * k5 + 1.8915178993145003 * k6 + (-5.801203960010585) * k7 + 0.3111643669578199 * k8 + (-0.1521609496625161) * k9 + 0.20136540080403034 * k10 + 0.04471061572777259 * k11)
        p5[i] = 0.0 + 0.01312004499419488 * k0 + 0.0 * k1 + 0.0 * k2 + 0.0 * k3 + 0.0 * k4 + (-1.2251564463762044) * k5 + (-0.4957589496572502) * k6 + 1.6643771824549864 * k7 + (-0.35032884874997366) * k8 + 0.3341791187130175 * k9 + 0.08192320648511571 * k10 + (-0.022355307863886294) * k11
        p3[i] = 0.0 + (-0.18980075407240762) * k0 + 0.0 * k1 + 0.0 * k2 + 0.0 * k3 + 0.0 * k4 + 4.450312892752409 * k5 + 1.8915178993145003 * k6 + (-5.801203960010585) * k7 + (-0.4226823213237919) * k8 + (-0.1521609496625161) * k9 + 0.20136540080403034 * k10 + 0.02265179219836082 * k11
    RHS(t + h, ynew, ip, fp, K[12])
    e5n = 0.0
    e3n = 0.0
    for i in range(n):
        kl = K[12, i]
        e5 = p5[i] + 0.0 * kl
        e3 = p3[i] + 0.0 * kl
        sc = max(abs(y[i]), abs(ynew[i])) * rtol + atol[i]
        e5n += (e5 / sc) ** 2
        e3n += (e3 / sc) ** 2
    return e5n, e3n


# ---- end of the generated part ----


@njit(cache=True, inline='always')
def dop853_step(t_bound, y, y_old, ip, fp, fs, cnt, rtol, atol, max_step, C, A, B, E5, E3,
                K, work):
    """One accepted DOP853 step (solvers.Dop853Stepper + _step_once). Returns ST_*. The
    attempt is ``_dop853_attempt``, scipy's tableau as literals (the arrays C, A, B, E5, E3
    that the Python stepper and the dense output read are that tableau)."""
    (y, y_old, ip, fp, fs, cnt, C, A, B, E5, E3, K, work) = borrowed_all((
        y, y_old, ip, fp, fs, cnt, C, A, B, E5, E3, K, work))
    n = y.shape[0]
    ns = B.shape[0]   # 12
    expo = 1.0 / (D8_ORDER + 1)
    t = fs[FS_T]
    if cnt[C_HAVEF] == 2:
        for i in range(n):
            K[0, i] = K[ns, i]
        cnt[C_HAVEF] = 1
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
        h0 = _initial_step(y, K[0], ip, fp, fs, cnt, rtol, atol, max_step, D8_ORDER,
                           work[0], work[2])
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
        e5n, e3n = _dop853_attempt(h, y, ip, fp, t, rtol, atol, K, work)
        cnt[C_NFEV] += ns
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
            t_new = t_bound if clipped else t + h
            for i in range(n):
                y_old[i] = y[i]
                y[i] = ynew[i]
            fs[FS_TOLD] = t
            fs[FS_T] = t_new
            fs[FS_HLAST] = t_new - t
            fs[FS_H] = min(max(h_new, h_prop) if clipped else h_new, max_step)
            cnt[C_HAVEF] = 2
            cnt[C_DENSE] = 0
            return ST_OK
        cnt[C_NREJ] += 1
        cnt[C_LASTREJ] = 1
        clipped = False
        if math.isfinite(err) and _first_nonfinite(ynew) < 0:
            h = h / min(1.0 / D8_FAC_MIN, err ** expo / SAFETY)
        else:
            nonfinite = True
            cnt[C_BADIDX] = _first_nonfinite(ynew)
            fs[FS_TBAD] = t + h
            h = h * D8_FAC_MIN


@njit(cache=True, inline='always')
def dop853_advance(t_end, y, y_old, ip, fp, fs, cnt, rtol, atol, max_step, C, A, B, E5,
                   E3, K, work):
    """DOP853 to exactly t_end; returns ST_*."""
    (y, y_old, ip, fp, fs, cnt, C, A, B, E5, E3, K, work) = borrowed_all((
        y, y_old, ip, fp, fs, cnt, C, A, B, E5, E3, K, work))
    while fs[FS_T] < t_end:
        st = dop853_step(t_end, y, y_old, ip, fp, fs, cnt, rtol, atol, max_step, C, A, B,
                         E5, E3, K, work)
        if st != ST_OK:
            return st
    return ST_OK


@njit(cache=True)
def dop853_dense(t, y, y_old, ip, fp, fs, cnt, D, A_EXTRA, C_EXTRA, K, out):
    """7th-order dense output of DOP853 inside the last accepted step; the three
    extra stages (3 fev) and the coefficients F are computed once per step."""
    (y, y_old, ip, fp, fs, cnt, D, A_EXTRA, C_EXTRA, K, out) = borrowed_all((
        y, y_old, ip, fp, fs, cnt, D, A_EXTRA, C_EXTRA, K, out))
    n = y.shape[0]
    h = fs[FS_HLAST]
    t_old = fs[FS_TOLD]
    if cnt[C_DENSE] == 0:
        arg = np.empty(n)
        for r in range(3):
            s = 13 + r
            for i in range(n):
                acc = 0.0
                for j in range(s):
                    acc += A_EXTRA[r, j] * K[j, i]
                arg[i] = y_old[i] + h * acc
            RHS(t_old + C_EXTRA[r] * h, arg, ip, fp, K[s])
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


# -- dense sampling of the methods whose steps have no t_last bound in the Python path:
# natural steps (t_bound = inf) until a step passes the sample time, then the method's own
# dense output; the step-by-step Python loop it replaces (stepper_base.sample_dense over
# KernelStepper.step/dense) cost ~5 us of dispatch and state sync per step (stiff,
# rosenbrock at tol 1e-3: 10 steps, 130 us of integration against 57 us landing 27 steps).

@njit(cache=True)
def ros_sample(t_eval, Y, y, y_old, ip, fp, fs, cnt, rtol, atol, max_step, autonomous,
               constant_jac, gamma, A, C, M, E, alpha, gsum, order, fac_max, J, LU, piv, ft,
               K, work, H, hermite_row):
    """stepper_base.sample_dense for RODAS5P (``hermite_row < 0``: dense output ros_dense_h
    with H) and rodas4 (cubic Hermite from K[hermite_row]): row k of Y = y(t_eval[k]).
    t_eval ascending, t_eval[0] >= the last step's start. Same steps, counters and bytes
    as the Python loop. Returns (ST_*, k of the failing sample, or t_eval.size)."""
    (t_eval, Y, y, y_old, ip, fp, fs, cnt, A, C, M, E, alpha, gsum, J, LU, piv, ft, K,
     work, H) = borrowed_all((t_eval, Y, y, y_old, ip, fp, fs, cnt, A, C, M, E, alpha, gsum,
                              J, LU, piv, ft, K, work, H))
    for k in range(t_eval.size):
        t = t_eval[k]
        while fs[FS_T] < t:
            st = ros_step(math.inf, y, y_old, ip, fp, fs, cnt, rtol, atol, max_step,
                          autonomous, constant_jac, gamma, A, C, M, E, alpha, gsum, order,
                          fac_max, J, LU, piv, ft, K, work)
            if st != ST_OK:
                return st, k
        if t == fs[FS_T] or fs[FS_HLAST] == 0.0:
            _store_row(Y, k, y)
        elif hermite_row < 0:
            _ros_dense_h_into(t, y, y_old, fs, H, K, Y[k])
        else:
            _hermite_into(t, y, y_old, ip, fp, fs, cnt, K, Y[k], hermite_row)
    return ST_OK, t_eval.size


@njit(cache=True)
def ros2_sample(t_eval, Y, y, y_old, ip, fp, fs, cnt, autonomous, constant_jac, J, LU, piv,
                ft, K, work):
    """stepper_base.sample_dense for ros2 (steps of h, cubic Hermite dense output); see
    ros_sample."""
    (t_eval, Y, y, y_old, ip, fp, fs, cnt, J, LU, piv, ft, K, work) = borrowed_all((
        t_eval, Y, y, y_old, ip, fp, fs, cnt, J, LU, piv, ft, K, work))
    for k in range(t_eval.size):
        t = t_eval[k]
        while fs[FS_T] < t:
            st = ros2_step_once(math.inf, y, y_old, ip, fp, fs, cnt, autonomous,
                                constant_jac, J, LU, piv, ft, K, work)
            if st != ST_OK:
                return st, k
        if t == fs[FS_T]:
            _store_row(Y, k, y)
        else:
            _hermite_into(t, y, y_old, ip, fp, fs, cnt, K, Y[k], 4)
    return ST_OK, t_eval.size


@njit(cache=True)
def dop853_sample(t_eval, Y, y, y_old, ip, fp, fs, cnt, rtol, atol, max_step, C, A, B, E5,
                  E3, D, A_EXTRA, C_EXTRA, K, work):
    """stepper_base.sample_dense for dop853 (7th-order dense output, its three extra
    stages once per step that holds a sample); see ros_sample."""
    (t_eval, Y, y, y_old, ip, fp, fs, cnt, C, A, B, E5, E3, D, A_EXTRA, C_EXTRA, K,
     work) = borrowed_all((t_eval, Y, y, y_old, ip, fp, fs, cnt, C, A, B, E5, E3, D, A_EXTRA,
                           C_EXTRA, K, work))
    for k in range(t_eval.size):
        t = t_eval[k]
        while fs[FS_T] < t:
            st = dop853_step(math.inf, y, y_old, ip, fp, fs, cnt, rtol, atol, max_step, C, A,
                             B, E5, E3, K, work)
            if st != ST_OK:
                return st, k
        if t == fs[FS_T] or fs[FS_HLAST] == 0.0:
            _store_row(Y, k, y)
        else:
            dop853_dense(t, y, y_old, ip, fp, fs, cnt, D, A_EXTRA, C_EXTRA, K, Y[k])
    return ST_OK, t_eval.size


# -- 'land' sampling: advance_to every sample time in one call (Simulation.run without a
# progress callback). One Python round trip per sample cost ~15-20 us of dispatch and state
# sync (measured: 10 samples of a 0.5 s kavz685_lever run at tol 1e-3 = ~30 % of the run).

@njit(cache=True, inline='always')
def _store_row(X, k, y):
    for i in range(y.size):
        X[k, i] = y[i]


@njit(cache=True)
def dopri5_land(times, X, y, y_old, ip, fp, fs, cnt, rtol, atol, max_step, K, work):
    """dopri5_advance to each times[k], k >= 1, row k of X = y there.
    Returns (ST_*, k of the failing sample, or times.size)."""
    (times, X, y, y_old, ip, fp, fs, cnt, K, work) = borrowed_all((
        times, X, y, y_old, ip, fp, fs, cnt, K, work))
    for k in range(1, times.size):
        st = dopri5_advance(times[k], y, y_old, ip, fp, fs, cnt, rtol, atol, max_step, K, work)
        if st != ST_OK:
            return st, k
        _store_row(X, k, y)
    return ST_OK, times.size


@njit(cache=True)
def dop853_land(times, X, y, y_old, ip, fp, fs, cnt, rtol, atol, max_step, C, A, B, E5,
                E3, K, work):
    """dop853_advance to each times[k], k >= 1 (see dopri5_land)."""
    (times, X, y, y_old, ip, fp, fs, cnt, C, A, B, E5, E3, K, work) = borrowed_all((
        times, X, y, y_old, ip, fp, fs, cnt, C, A, B, E5, E3, K, work))
    for k in range(1, times.size):
        st = dop853_advance(times[k], y, y_old, ip, fp, fs, cnt, rtol, atol, max_step, C, A,
                            B, E5, E3, K, work)
        if st != ST_OK:
            return st, k
        _store_row(X, k, y)
    return ST_OK, times.size


@njit(cache=True)
def rk4_land(times, X, y, y_old, ip, fp, fs, cnt, K, work):
    """rk4_advance to each times[k], k >= 1 (see dopri5_land)."""
    (times, X, y, y_old, ip, fp, fs, cnt, K, work) = borrowed_all((
        times, X, y, y_old, ip, fp, fs, cnt, K, work))
    for k in range(1, times.size):
        st = rk4_advance(times[k], y, y_old, ip, fp, fs, cnt, K, work)
        if st != ST_OK:
            return st, k
        _store_row(X, k, y)
    return ST_OK, times.size


@njit(cache=True)
def ros2_land(times, X, y, y_old, ip, fp, fs, cnt, autonomous, constant_jac,
              J, LU, piv, ft, K, work):
    """ros2_advance to each times[k], k >= 1 (see dopri5_land)."""
    (times, X, y, y_old, ip, fp, fs, cnt, J, LU, piv, ft, K, work) = borrowed_all((
        times, X, y, y_old, ip, fp, fs, cnt, J, LU, piv, ft, K, work))
    for k in range(1, times.size):
        st = ros2_advance(times[k], y, y_old, ip, fp, fs, cnt, autonomous, constant_jac,
                          J, LU, piv, ft, K, work)
        if st != ST_OK:
            return st, k
        _store_row(X, k, y)
    return ST_OK, times.size


@njit(cache=True)
def ros_land(times, X, y, y_old, ip, fp, fs, cnt, rtol, atol, max_step, autonomous,
             constant_jac, gamma, A, C, M, E, alpha, gsum, order, fac_max, J, LU, piv, ft,
             K, work):
    """ros_advance (RODAS5P, rodas4) to each times[k], k >= 1 (see dopri5_land)."""
    (times, X, y, y_old, ip, fp, fs, cnt, A, C, M, E, alpha, gsum, J, LU, piv, ft, K,
     work) = borrowed_all((times, X, y, y_old, ip, fp, fs, cnt, A, C, M, E, alpha, gsum, J,
                           LU, piv, ft, K, work))
    for k in range(1, times.size):
        st = ros_advance(times[k], y, y_old, ip, fp, fs, cnt, rtol, atol, max_step,
                         autonomous, constant_jac, gamma, A, C, M, E, alpha, gsum, order,
                         fac_max, J, LU, piv, ft, K, work)
        if st != ST_OK:
            return st, k
        _store_row(X, k, y)
    return ST_OK, times.size
