"""Compiled reductions of a sampled run to the steady window and the shaft metrics, the
same floats bit for bit as the numpy code of :mod:`cvj_ros.physics.steady` and
:mod:`cvj_ros.physics.metrics` (used by the batched sweep, cvj_ros/sweep/batch.py).

Bit for bit because every operation is the one numpy performs, in its order:

* means (``np.mean`` of a series) use numpy's pairwise summation (:func:`pairwise_sum`:
  blocks of at most 128 terms summed by 8 accumulators, larger ranges halved at a
  multiple of 8; numpy/_core/src/umath/loops_utils.h.src);
* max, min, abs and comparisons are exact;
* the acceleration is ``np.gradient(..., edge_order=2)``'s arithmetic element by element
  (its uniform-spacing branch when every time step is the same double, else the
  non-uniform coefficients), without FMA contraction (numba keeps IEEE operations).

``test/physics/kernel/test_reduce_nb.py`` compares every output with the numpy functions
on many runs; a change of numpy's summation would show there. Not here: the slices'
Hann-weighted means (``np.dot``, i.e. OpenBLAS's ``ddot``, whose strided loop sums four
products into two accumulators and whose rounding depends on the CPU kernel OpenBLAS picks
and its FMA contraction: a plain replica differed in 4 of 3000 sums here), so the caller
computes them with numpy and passes them in.

:func:`reduce_lean` is the batched sweep's one call per variant: the window, the
intermediate members' speeds from the row before it on (:func:`fill_mid_speeds`, the
speeds of ``outputs_nb.fill_mid_one`` without the member angles, which the metrics do not
read) and the metrics.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from cvj_ros.physics.kernel.outputs_nb import _mid_angle, fill_mid_one

__all__ = ['fill_mid_speeds', 'gradient_table', 'pairwise_sum', 'reduce_lean', 'series_sum',
           'steady_start', 'warm', 'window_first_row', 'window_metrics']

PW_BLOCKSIZE = 128


@njit(cache=True)
def pairwise_sum(a: np.ndarray, start: int, n: int, stride: int, col: int) -> float:
    """numpy's pairwise sum of ``a[start + i*stride, col]``, i = 0..n-1 (``np.add.reduce``
    of a float64 series: ``0.0 +`` the pairwise sum of all n terms)."""
    if n < 8:
        res = 0.0
        for i in range(n):
            res += a[start + i * stride, col]
        return res
    if n <= PW_BLOCKSIZE:
        r0 = a[start, col]
        r1 = a[start + stride, col]
        r2 = a[start + 2 * stride, col]
        r3 = a[start + 3 * stride, col]
        r4 = a[start + 4 * stride, col]
        r5 = a[start + 5 * stride, col]
        r6 = a[start + 6 * stride, col]
        r7 = a[start + 7 * stride, col]
        i = 8
        while i < n - (n % 8):
            k = start + i * stride
            r0 += a[k, col]
            r1 += a[k + stride, col]
            r2 += a[k + 2 * stride, col]
            r3 += a[k + 3 * stride, col]
            r4 += a[k + 4 * stride, col]
            r5 += a[k + 5 * stride, col]
            r6 += a[k + 6 * stride, col]
            r7 += a[k + 7 * stride, col]
            i += 8
        res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
        while i < n:
            res += a[start + i * stride, col]
            i += 1
        return res
    n2 = n // 2
    n2 -= n2 % 8
    return (pairwise_sum(a, start, n2, stride, col)
            + pairwise_sum(a, start + n2 * stride, n - n2, stride, col))


@njit(cache=True)
def series_sum(a: np.ndarray, start: int, n: int, col: int) -> float:
    """``np.add.reduce`` of ``a[start:start+n, col]``: 0.0 plus the pairwise sum."""
    return 0.0 + pairwise_sum(a, start, n, 1, col)


@njit(cache=True)
def _max(a: np.ndarray, i0: int, i1: int, col: int) -> float:
    """np.max of a[i0:i1, col] (NaN propagates)."""
    m = a[i0, col]
    for i in range(i0 + 1, i1):
        x = a[i, col]
        if x > m or x != x:
            m = x
            if x != x:
                return x
    return m


@njit(cache=True)
def _min(a: np.ndarray, i0: int, i1: int, col: int) -> float:
    """np.min of a[i0:i1, col] (NaN propagates)."""
    m = a[i0, col]
    for i in range(i0 + 1, i1):
        x = a[i, col]
        if x < m or x != x:
            m = x
            if x != x:
                return x
    return m


@njit(cache=True)
def _searchsorted_left(t: np.ndarray, v: float) -> int:
    """np.searchsorted(t, v, side='left') of an ascending t."""
    lo, hi = 0, t.size
    while lo < hi:
        mid = (lo + hi) // 2
        if t[mid] < v:
            lo = mid + 1
        else:
            hi = mid
    return lo


@njit(cache=True)
def _gradient_at(t: np.ndarray, f: np.ndarray, col: int, r: int, uniform: bool) -> float:
    """Row r of ``np.gradient(f[:, col], t, edge_order=2)`` (len(t) >= 3, t strictly
    increasing; ``uniform``: every np.diff(t) equals the first, numpy's scalar branch)."""
    m = t.size
    if uniform:
        h = t[1] - t[0]
        if r == 0:
            return (-1.5 / h) * f[0, col] + (2. / h) * f[1, col] + (-0.5 / h) * f[2, col]
        if r == m - 1:
            return ((0.5 / h) * f[m - 3, col] + (-2. / h) * f[m - 2, col]
                    + (1.5 / h) * f[m - 1, col])
        return (f[r + 1, col] - f[r - 1, col]) / (2. * h)
    if r == 0:
        dx1 = t[1] - t[0]
        dx2 = t[2] - t[1]
        a = -(2. * dx1 + dx2) / (dx1 * (dx1 + dx2))
        b = (dx1 + dx2) / (dx1 * dx2)
        c = -dx1 / (dx2 * (dx1 + dx2))
        return a * f[0, col] + b * f[1, col] + c * f[2, col]
    if r == m - 1:
        dx1 = t[m - 2] - t[m - 3]
        dx2 = t[m - 1] - t[m - 2]
        a = dx2 / (dx1 * (dx1 + dx2))
        b = -(dx2 + dx1) / (dx1 * dx2)
        c = (2. * dx2 + dx1) / (dx2 * (dx1 + dx2))
        return a * f[m - 3, col] + b * f[m - 2, col] + c * f[m - 1, col]
    dx1 = t[r] - t[r - 1]
    dx2 = t[r + 1] - t[r]
    a = -dx2 / (dx1 * (dx1 + dx2))
    b = (dx2 - dx1) / (dx1 * dx2)
    c = dx1 / (dx2 * (dx1 + dx2))
    return a * f[r - 1, col] + b * f[r, col] + c * f[r + 1, col]


@njit(cache=True)
def _gradient_coefs(t: np.ndarray, r: int, uniform: bool, co: np.ndarray) -> int:
    """Row r of :func:`_gradient_at` as coefficients of any column f: returns x0 >= 0 with
    the row's value co[0] f[x0] + co[1] f[x0+1] + co[2] f[x0+2] (the same products and
    additions in the same order), or -1 for a uniform interior row, whose value is
    (f[r+1] - f[r-1]) / co[3]."""
    m = t.size
    if uniform:
        h = t[1] - t[0]
        if r == 0:
            co[0] = -1.5 / h
            co[1] = 2. / h
            co[2] = -0.5 / h
            return 0
        if r == m - 1:
            co[0] = 0.5 / h
            co[1] = -2. / h
            co[2] = 1.5 / h
            return m - 3
        co[3] = 2. * h
        return -1
    if r == 0:
        dx1 = t[1] - t[0]
        dx2 = t[2] - t[1]
        co[0] = -(2. * dx1 + dx2) / (dx1 * (dx1 + dx2))
        co[1] = (dx1 + dx2) / (dx1 * dx2)
        co[2] = -dx1 / (dx2 * (dx1 + dx2))
        return 0
    if r == m - 1:
        dx1 = t[m - 2] - t[m - 3]
        dx2 = t[m - 1] - t[m - 2]
        co[0] = dx2 / (dx1 * (dx1 + dx2))
        co[1] = -(dx2 + dx1) / (dx1 * dx2)
        co[2] = (2. * dx2 + dx1) / (dx2 * (dx1 + dx2))
        return m - 3
    dx1 = t[r] - t[r - 1]
    dx2 = t[r + 1] - t[r]
    co[0] = -dx2 / (dx1 * (dx1 + dx2))
    co[1] = (dx2 - dx1) / (dx1 * dx2)
    co[2] = dx1 / (dx2 * (dx1 + dx2))
    return r - 1


@njit(cache=True)
def steady_start(t: np.ndarray, vel: np.ndarray, eff: np.ndarray, lo: np.ndarray,
                 hi: np.ndarray, means: np.ndarray, drift_tol: float, amplitude_tol: float,
                 min_slices: int, speed_floor: float, torque_floor: float,
                 fallback_fraction: float, out: np.ndarray) -> int:
    """The steady window of :func:`cvj_ros.physics.steady.joint_state_window` (criterion,
    no skip) of a record of m >= 3 strictly increasing times ``t`` (s), speeds ``vel`` and
    torques ``eff`` (m, shafts): slices [lo[k], hi[k]) (steady.slice_bounds, every slice
    >= 2 samples, at least ``min_slices``), ``means`` the slices' Hann means of the first
    shaft's speed (steady.hann_mean). Reads the first shaft's speed and every torque.
    ``out[0]`` = 1.0 if steady else 0.0, ``out[1]`` = the window's start (s). Returns 0, or
    -1 when a value it reads is not finite (the caller then uses the numpy functions,
    whose NaN handling this does not replicate)."""
    m = t.size
    n_sh = vel.shape[1]
    n = lo.size
    # one pass over the rows: finite, the speed's peak and each torque's peak |value|
    speed_peak = 0.0
    pk = np.zeros(n_sh)
    for i in range(m):
        x = vel[i, 0]
        if not math.isfinite(x):
            return -1
        speed_peak = max(speed_peak, abs(x))
        for j in range(n_sh):
            e = eff[i, j]
            if not math.isfinite(e):
                return -1
            pk[j] = max(pk[j], abs(e))
    torque_scale = 0.0
    for j in range(n_sh):
        torque_scale = max(torque_scale, pk[j])
    # each slice's half range of every signal (the reference speed, then every shaft's
    # torque), row by row: a value replaces the max (min) only when greater (less), as
    # _max / _min, so the same floats (signed zeros included)
    amp = np.empty((n, n_sh + 1))
    mx = np.empty(n_sh + 1)
    mn = np.empty(n_sh + 1)
    for k in range(n):
        i0, i1 = lo[k], hi[k]
        mx[0] = mn[0] = vel[i0, 0]
        for j in range(n_sh):
            mx[j + 1] = mn[j + 1] = eff[i0, j]
        for i in range(i0 + 1, i1):
            x = vel[i, 0]
            if x > mx[0]:
                mx[0] = x
            if x < mn[0]:
                mn[0] = x
            for j in range(n_sh):
                e = eff[i, j]
                if e > mx[j + 1]:
                    mx[j + 1] = e
                if e < mn[j + 1]:
                    mn[j + 1] = e
        for sig in range(n_sh + 1):
            amp[k, sig] = 0.5 * (mx[sig] - mn[sig])
    change = np.zeros(n)
    for sig in range(n_sh + 1):
        floor = max((speed_floor * speed_peak) if sig == 0 else (torque_floor * torque_scale),
                    1e-300)
        last = amp[n - 1, sig]
        for k in range(n):
            a = amp[k, sig]
            rel = abs(a - last) / max(max(a, last), floor)
            if rel > change[k]:
                change[k] = rel
    best = -1
    for k0 in range(n - min_slices, -1, -1):
        cnt = m - lo[k0]
        scale = abs(series_sum(vel, lo[k0], cnt, 0) / cnt)
        dm = 0.0
        ch = change[k0]
        for k in range(k0, n):
            dm = max(dm, abs(means[k] - means[n - 1]))
            ch = max(ch, change[k])
        drift = dm / scale if scale > 0.0 else math.inf
        if drift <= drift_tol and ch <= amplitude_tol:
            best = k0
        else:
            break
    if best >= 0:
        out[0] = 1.0
        out[1] = t[lo[best]]
    else:       # steady.fallback_start
        s0 = t[m - 1] - fallback_fraction * (t[m - 1] - t[0])
        out[0] = 0.0
        out[1] = t[_searchsorted_left(t, s0 - 1e-12 * max(1.0, abs(s0)))]
    return 0


@njit(cache=True)
def window_first_row(t: np.ndarray, start: float) -> int:
    """First row of the window [start, t[-1]] (SteadyWindow.mask of an increasing t: at
    least the last two rows)."""
    i0 = _searchsorted_left(t, start)
    return min(i0, t.size - 2)


@njit(cache=True)
def gradient_table(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Every row's :func:`_gradient_coefs` of ``np.gradient(f, t, edge_order=2)`` (m >= 3
    strictly increasing times ``t``, numpy's uniform branch when every step equals the
    first): (co (m, 4), x0 (m,)), row r's value co[r, 0] f[x0] + co[r, 1] f[x0+1] +
    co[r, 2] f[x0+2], or (f[r+1] - f[r-1]) / co[r, 3] where x0 is -1. A function of the
    times alone: a batched template computes it once for all its runs."""
    m = t.size
    uniform = True
    h0 = t[1] - t[0]
    for i in range(1, m - 1):
        if t[i + 1] - t[i] != h0:
            uniform = False
            break
    co = np.zeros((m, 4))
    x0 = np.empty(m, np.int64)
    for r in range(m):
        x0[r] = _gradient_coefs(t, r, uniform, co[r])
    return co, x0


@njit(cache=True)
def window_metrics(t: np.ndarray, vel: np.ndarray, eff: np.ndarray, res: np.ndarray,
                   gco: np.ndarray, gx0: np.ndarray, out: np.ndarray) -> int:
    """:func:`cvj_ros.physics.metrics.shaft_metrics` over the window starting at ``out[1]``
    (s) and the energy residual, of a record as :func:`steady_start`'s, with ``gco, gx0``
    the :func:`gradient_table` of ``t``. Reads every speed and torque from the row before
    the window on (the acceleration's central difference) and all of ``res``. ``out[2]`` =
    max |energy residual| ignoring NaN (NaN if all are), then per shaft mean_speed, delta,
    speed_amplitude, acceleration_amplitude, mean_torque, torque_amplitude. Returns 0, or -1
    for a non-finite speed or torque."""
    m = t.size
    n_sh = vel.shape[1]
    i0 = window_first_row(t, out[1])
    for i in range(max(0, i0 - 1), m):
        for j in range(n_sh):
            if not (math.isfinite(vel[i, j]) and math.isfinite(eff[i, j])):
                return -1
    emax = math.nan         # Trace.max_energy_residual
    for i in range(res.size):
        x = abs(res[i])
        if x == x and not (x <= emax):
            emax = x
    out[2] = emax
    cnt = m - i0
    # one pass over the window's rows: the acceleration's extrema (each row's coefficients
    # for every shaft) and the speeds' and torques' extrema (replaced only when greater /
    # less, as _max / _min)
    gmax = np.empty(n_sh)
    gmin = np.empty(n_sh)
    vmax = np.empty(n_sh)
    vmin = np.empty(n_sh)
    emx = np.empty(n_sh)
    emn = np.empty(n_sh)
    for j in range(n_sh):
        vmax[j] = vmin[j] = vel[i0, j]
        emx[j] = emn[j] = eff[i0, j]
    for r in range(i0, m):
        x0 = gx0[r]
        for j in range(n_sh):
            if x0 < 0:      # uniform spacing, an interior row: numpy's central difference
                g = (vel[r + 1, j] - vel[r - 1, j]) / gco[r, 3]
            else:
                g = gco[r, 0] * vel[x0, j] + gco[r, 1] * vel[x0 + 1, j] + \
                    gco[r, 2] * vel[x0 + 2, j]
            if r == i0:
                gmax[j] = g
                gmin[j] = g
            else:
                gmax[j] = max(gmax[j], g)
                gmin[j] = min(gmin[j], g)
            v = vel[r, j]
            if v > vmax[j]:
                vmax[j] = v
            if v < vmin[j]:
                vmin[j] = v
            e = eff[r, j]
            if e > emx[j]:
                emx[j] = e
            if e < emn[j]:
                emn[j] = e
    for j in range(n_sh):
        mean = series_sum(vel, i0, cnt, j) / cnt
        span = vmax[j] - vmin[j]
        o = 3 + 6 * j
        out[o] = mean
        out[o + 1] = span / abs(mean) if mean != 0.0 else math.inf
        out[o + 2] = 0.5 * span
        out[o + 3] = 0.5 * (gmax[j] - gmin[j])
        out[o + 4] = series_sum(eff, i0, cnt, j) / cnt
        out[o + 5] = 0.5 * (emx[j] - emn[j])
    return 0


@njit(cache=True)
def fill_mid_speeds(pos: np.ndarray, vel: np.ndarray, i0: int, mtab: np.ndarray,
                    mfp: np.ndarray) -> None:
    """The intermediate members' speeds of rows i0.. of (samples, shafts) arrays pos/vel as
    ``outputs_nb.fill_mid_one`` computes them: the Richardson-extrapolated central
    difference (h = 1e-3 rad) of phi_mid = _mid_angle(op, phi_in) times omega_in, the same
    operations, without the member angle itself (pos of a member is left as it is). When a
    member's input is another member (its angle is read), every row is filled in full by
    fill_mid_one instead."""
    n = mtab.shape[0]
    chained = False
    for i in range(n):
        for j in range(n):
            if mtab[i, 1] == mtab[j, 0]:
                chained = True
    h = 1e-3
    for k in range(i0, pos.shape[0]):
        if chained:
            fill_mid_one(pos[k], vel[k], mtab, mfp)
            continue
        for i in range(n):
            i_mid, i_in, code, off = mtab[i, 0], mtab[i, 1], mtab[i, 2], mtab[i, 3]
            phi = pos[k, i_in]
            mp = _mid_angle(code, phi + h, mfp, off)
            mm = _mid_angle(code, phi - h, mfp, off)
            mp2 = _mid_angle(code, phi + h / 2, mfp, off)
            mm2 = _mid_angle(code, phi - h / 2, mfp, off)
            d_h = (mp - mm) / (2 * h)
            d_h2 = (mp2 - mm2) / h
            vel[k, i_mid] = (4.0 * d_h2 - d_h) / 3.0 * vel[k, i_in]


@njit(cache=True)
def reduce_lean(t: np.ndarray, pos: np.ndarray, vel: np.ndarray, eff: np.ndarray,
                res: np.ndarray, lo: np.ndarray, hi: np.ndarray, means: np.ndarray,
                drift_tol: float, amplitude_tol: float, min_slices: int, speed_floor: float,
                torque_floor: float, fallback_fraction: float, mtab: np.ndarray,
                mfp: np.ndarray, gco: np.ndarray, gx0: np.ndarray, out: np.ndarray) -> int:
    """:func:`steady_start`, then :func:`fill_mid_speeds` of the members ``mtab`` from the
    row before the window on (:func:`window_first_row` - 1, at least 0), then
    :func:`window_metrics`, in one call (same arguments and ``out``). Returns 0; -1 when
    steady_start declined (nothing filled), -2 when window_metrics did (speeds filled)."""
    if steady_start(t, vel, eff, lo, hi, means, drift_tol, amplitude_tol, min_slices,
                    speed_floor, torque_floor, fallback_fraction, out) != 0:
        return -1
    fill_mid_speeds(pos, vel, max(0, window_first_row(t, out[1]) - 1), mtab, mfp)
    if window_metrics(t, vel, eff, res, gco, gx0, out) != 0:
        return -2
    return 0


def warm() -> None:
    """Compile or load :func:`steady_start`, :func:`window_metrics` and
    :func:`reduce_lean` for the argument types the sweep passes
    (``python -m cvj_ros.physics.kernel.warmup``)."""
    t = np.linspace(0.0, 1.0, 31)
    ones = np.ones((31, 1))
    lo = np.array([0, 10, 20], np.int64)
    hi = np.array([10, 20, 31], np.int64)
    out = np.empty(9)
    steady_start(t, ones, ones, lo, hi, np.ones(3), 2e-3, 0.05, 3, 1e-6, 1e-3, 0.5, out)
    gco, gx0 = gradient_table(t)
    window_metrics(t, ones, ones, np.zeros(31), gco, gx0, out)
    reduce_lean(t, ones, ones, ones, np.zeros(31), lo, hi, np.ones(3), 2e-3, 0.05, 3, 1e-6,
                1e-3, 0.5, np.zeros((0, 4), np.int64), np.zeros(1), gco, gx0, out)
