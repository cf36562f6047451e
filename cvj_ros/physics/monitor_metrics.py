"""Rolling-window metrics of the monitor node (pure numpy, no ROS).

* Speed nonuniformity (coefficient of unevenness), Davidbaev et al. 2023, section 4 (unevenness of the
  drive and driven shafts delta_1, delta_2)::

      delta = (omega_max - omega_min) / omega_mean          (-)

  over the samples of a window; ``nan`` where |omega_mean| is below ``min_speed``
  (a shaft at standstill has no meaningful unevenness).
* The same about the window's speed trend (a driveline accelerating in gear):
  r = omega - (a + b t), the least-squares line over the window removed, and
  delta_trend = (r_max - r_min) / omega_mean; equal to delta for a steady periodic speed
  (b ~ 0), 0 for a pure speed ramp (:func:`detrended_nonuniformity`).
* Amplitude of any signal (speed rad/s, torque N m): (x_max - x_min) / 2.
* Recommended joint angles: :data:`RECOMMENDED_MAX_ANGLE_DEG` (seed references below).

Davidbaev et al. 2023 (section 4, after fig. 4.9) recommends delta_1 <= 0.075..0.11 for the drive
shaft and delta_2 <= 0.12..0.15 for the driven shaft of the KAVZ-685 lever-hinge
coupling; the monitor uses 0.11 / 0.15 as default WARN / ERROR thresholds.
"""
from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]

# Recommended maximum working angle per joint kind (deg): tripod Xiu et al. 2024 ("beta <= 25 deg"),
# fixed ball (Rzeppa / bowl-ball) Bugaru & Vasile 2021 (beta2 up to 47 deg).
RECOMMENDED_MAX_ANGLE_DEG: dict[str, float] = {'tripod': 25.0, 'rzeppa': 47.0}

DEFAULT_NONUNIFORMITY_WARN = 0.11    # Davidbaev et al. 2023, sec. 4, drive shaft upper recommendation
DEFAULT_NONUNIFORMITY_ERROR = 0.15   # Davidbaev et al. 2023, sec. 4, driven shaft upper recommendation


class RollingWindow:
    """Ring buffer of the last ``capacity`` samples (t in s, one row of ``width`` values).

    ``push`` is O(width); ``window(span)`` returns the samples of the last ``span`` seconds
    in time order as arrays (t: (n,), rows: (n, width)).
    """

    def __init__(self, capacity: int, width: int) -> None:
        if capacity < 1 or width < 1:
            raise ValueError(f'capacity/width: must be >= 1, got {capacity}, {width}')
        self.capacity = int(capacity)
        self.width = int(width)
        self._t = np.zeros(self.capacity)
        self._rows = np.zeros((self.capacity, self.width))
        self._next = 0
        self._count = 0

    def __len__(self) -> int:
        return self._count

    def push(self, t: float, row: Sequence[float] | FloatArray) -> None:
        """Append one sample (t in s; row of ``width`` floats)."""
        self._t[self._next] = t
        self._rows[self._next, :] = row
        self._next = (self._next + 1) % self.capacity
        self._count = min(self._count + 1, self.capacity)

    def push_many(self, t: Sequence[float] | FloatArray, rows: Sequence[Sequence[float]] | FloatArray) -> None:
        """Append samples in order (t (m,) in s; rows (m, width)): the same buffer as m
        calls of :meth:`push`, in one compiled call (cvj_ros.physics.kernel.window_nb)."""
        from cvj_ros.physics.kernel.window_nb import ring_push
        t = np.ascontiguousarray(t, dtype=float).reshape(-1)
        m = t.size
        if m == 0:
            return
        rows = np.ascontiguousarray(rows, dtype=float).reshape(m, self.width)
        self._next = ring_push(self._t, self._rows, self._next, t, rows)
        self._count = min(self._count + m, self.capacity)

    def stats(self, span: float) -> tuple[int, FloatArray, FloatArray, FloatArray]:
        """(n, mean, min, max) per column of :meth:`window` ``(span)``'s rows, computed on
        the buffer in place by the compiled ``ring_window_stats``
        (cvj_ros.physics.kernel.window_nb); NaN columns and an empty window as
        :func:`column_stats`."""
        from cvj_ros.physics.kernel.window_nb import ring_window_stats
        mean = np.empty(self.width)
        lo = np.empty(self.width)
        hi = np.empty(self.width)
        n = ring_window_stats(self._t, self._rows, self._count, self._next, float(span), mean, lo, hi)
        return n, mean, lo, hi

    def samples(self) -> tuple[FloatArray, FloatArray]:
        """All stored samples in time order: (t (n,), rows (n, width))."""
        if self._count < self.capacity:
            return self._t[:self._count].copy(), self._rows[:self._count].copy()
        order = np.r_[self._next:self.capacity, 0:self._next]
        return self._t[order], self._rows[order]

    def window(self, span: float) -> tuple[FloatArray, FloatArray]:
        """Samples with t >= t_last - span (s), in time order (t_last = the newest sample's).

        Selects on the stored times and copies only the selected rows (a full buffer of
        20000 x 13 was copied per call before: 0.6 ms, four calls per monitor publication)."""
        n = self._count
        if n == 0:
            return self._t[:0].copy(), self._rows[:0].copy()
        nxt = self._next
        t_last = self._t[nxt - 1]               # index -1 wraps to the end: the newest sample
        if n < self.capacity:
            idx = np.flatnonzero(self._t[:n] >= t_last - span)
        else:
            idx = np.flatnonzero(self._t >= t_last - span)
            split = np.searchsorted(idx, nxt)    # storage order -> time order (oldest at nxt)
            idx = np.concatenate((idx[split:], idx[:split]))
        return self._t[idx], self._rows[idx]


def column_stats(x: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """(mean, min, max) per column of ``x`` (k samples x width); nan for k = 0.

    One transposed copy, then reductions along contiguous rows: a 1000 x 13 window costs
    ~25 us this way against ~110 us for three reductions along axis 0 (numpy walks the
    13-wide rows element by element there)."""
    a = np.atleast_2d(np.asarray(x, dtype=float).T)     # (width, k)
    if a.shape[1] == 0:
        nan = np.full(a.shape[0], np.nan)
        return nan, nan.copy(), nan.copy()
    a = np.ascontiguousarray(a)
    return a.mean(axis=1), a.min(axis=1), a.max(axis=1)


def nonuniformity_from_stats(mean: FloatArray, lo: FloatArray, hi: FloatArray, *,
                             min_speed: float = 1e-3) -> FloatArray:
    """delta = (hi - lo)/|mean| (Davidbaev et al. 2023, sec. 4) from :func:`column_stats`; nan where
    |mean| < ``min_speed`` (rad/s) or the window was empty."""
    out = np.full(mean.shape, np.nan)
    with np.errstate(invalid='ignore'):
        ok = np.abs(mean) >= min_speed
    out[ok] = (hi[ok] - lo[ok]) / np.abs(mean[ok])
    return out


def speed_nonuniformity(omega: FloatArray, *, min_speed: float = 1e-3) -> FloatArray:
    """delta = (omega_max - omega_min)/omega_mean per column of ``omega`` (rad/s), Davidbaev et al. 2023
    sec. 4; nan for columns whose |mean| < ``min_speed`` (rad/s) or for an empty window."""
    mean, lo, hi = column_stats(omega)
    return nonuniformity_from_stats(mean, lo, hi, min_speed=min_speed)


def detrended_nonuniformity(t: FloatArray, omega: FloatArray, *, min_speed: float = 1e-3
                            ) -> tuple[FloatArray, FloatArray]:
    """(delta_trend, b) per column of ``omega`` (n, m) at times ``t`` (n,) (s): the
    nonuniformity about the least-squares line a + b t (module docstring) and the slope b
    (rad/s^2); nan where |mean| < ``min_speed`` or fewer than 3 samples."""
    t = np.asarray(t, dtype=float)
    w = np.asarray(omega, dtype=float)
    m = w.shape[1] if w.ndim == 2 else 0
    nan = np.full(m, np.nan)
    if w.ndim != 2 or w.shape[0] < 3:
        return nan, nan.copy()
    tc = t - t.mean()
    mean = w.mean(axis=0)
    denom = float(tc @ tc)
    b = (tc @ (w - mean)) / denom if denom > 0 else np.zeros(m)
    r = w - mean - np.outer(tc, b)
    out = nan.copy()
    with np.errstate(invalid='ignore'):
        ok = np.abs(mean) >= min_speed
    out[ok] = (r.max(axis=0)[ok] - r.min(axis=0)[ok]) / np.abs(mean[ok])
    return out, b


def amplitude(x: FloatArray) -> FloatArray:
    """(max - min)/2 per column (same unit as ``x``); nan for an empty window."""
    _mean, lo, hi = column_stats(x)
    return 0.5 * (hi - lo)


def level(value: float, warn: float, error: float) -> int:
    """0 (OK) below ``warn``, 1 (WARN) below ``error``, 2 (ERROR) at/above it or NaN.
    A threshold <= 0 disables that level."""
    if math.isnan(value):
        return 2
    if error > 0 and value >= error:
        return 2
    if warn > 0 and value >= warn:
        return 1
    return 0


def angle_level(angle_deg: float, limit_deg: float, *, error_margin_deg: float = 5.0) -> int:
    """Joint angle vs recommended limit: OK up to the limit, WARN up to limit + margin, ERROR beyond."""
    if angle_deg <= limit_deg:
        return 0
    return 1 if angle_deg <= limit_deg + error_margin_deg else 2
