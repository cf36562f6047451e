"""Torque orders of a sweep row with the harmonics' cos/sin matrices kept per angle grid:
:func:`cvj_ros.sweep.run.order_amplitudes` (``signal.harmonics_over_angle``, Davidbaev et
al. 2023, eqs. 4.1-4.3) doing the same numpy operations on the same values, so the same
floats. The grid phi_i = phi_start + 2 pi i / m depends only on the multiple of 2 pi / m
where the window's angle starts and on the number of whole revolutions; variants of a
sweep mostly share both, and the matrices cos(k phi_i), sin(k phi_i) were most of the
orders' cost. The batched sweep uses it; the per-variant path keeps order_amplitudes (the
reference the tests compare with).
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np

__all__ = ['amplitudes_over_angle', 'order_amplitudes_cached', 'window_rows']

#: grids kept per process (a sweep's windows start at a few multiples of 2 pi / m)
MAX_GRIDS = 64

_GRIDS: dict[tuple[int, int, int, int], tuple[np.ndarray, np.ndarray, np.ndarray]] = {}


def amplitudes_over_angle(phi: np.ndarray, values: np.ndarray, n_harmonics: int,
                          samples_per_rev: int) -> list[float] | None:
    """The amplitudes of ``harmonics_over_angle(phi, values, n_harmonics=...,
    samples_per_rev=...)``, the same floats, or None where it raises ValueError (fewer than
    one whole revolution, an angle not strictly monotonic, bad options)."""
    if n_harmonics < 1 or samples_per_rev < 2 * n_harmonics + 1:
        return None
    p = np.asarray(phi, dtype=float)
    v = np.asarray(values, dtype=float)
    if p.shape != v.shape or p.ndim != 1:
        return None
    d = p[1:] - p[:-1]      # np.diff's values; the array methods skip numpy's wrappers
    if p.size < 2 or not (bool((d > 0).all()) or bool((d < 0).all())):
        return None
    if d[0] < 0:
        p, v = p[::-1], v[::-1]
    dphi = 2.0 * math.pi / samples_per_rev
    j = math.ceil(p[0] / dphi - 1e-9)
    start = j * dphi
    revolutions = int(math.floor((p[-1] - start) / (2.0 * math.pi) + 1e-9))
    if revolutions < 1:
        return None
    n_grid = revolutions * samples_per_rev
    key = (j, n_grid, n_harmonics, samples_per_rev)
    entry = _GRIDS.get(key)
    if entry is None:
        grid = start + dphi * np.arange(n_grid)
        kp = np.arange(1, n_harmonics + 1)[:, None] * grid[None, :]
        entry = (grid, np.cos(kp), np.sin(kp))
        if len(_GRIDS) >= MAX_GRIDS:
            _GRIDS.clear()
        _GRIDS[key] = entry
    grid, cos_kp, sin_kp = entry
    vg = np.interp(grid, p, v)
    a = 2.0 / n_grid * (cos_kp @ vg)
    b = 2.0 / n_grid * (sin_kp @ vg)
    return np.hypot(a, b).tolist()


def window_rows(t: np.ndarray, window: Any) -> slice:
    """The rows ``window.mask(t)`` selects (steady.SteadyWindow.mask: start_s <= t <= end_s,
    else the last two) as a slice, for strictly increasing ``t``: the selected rows are then
    one contiguous run [first t >= start_s, last t <= end_s]."""
    m = t.size
    i0 = int(np.searchsorted(t, window.start_s, 'left'))
    i1 = int(np.searchsorted(t, window.end_s, 'right'))
    if i1 - i0 < 2 and m >= 2:
        return slice(m - 2, m)
    return slice(i0, max(i0, i1))


def order_amplitudes_cached(trace: Any, orders: int, shaft: str | None, window: Any, *,
                            increasing: bool = False) -> dict[str, float]:
    """``order_amplitudes(trace, orders, transient, shaft, window)`` (the row's
    ``SHAFT.torque_order1..K``, N m; NaN below one revolution) through
    :func:`amplitudes_over_angle`. Raises KeyError for an unknown ``shaft`` as it does.
    ``increasing``: the caller knows ``trace.t`` strictly increasing (the compiled reduction
    checked it), so the window's rows are taken as a slice (:func:`window_rows`; the same
    values in the same order as the mask's)."""
    shaft = shaft or trace.names[0]
    col = trace.column(shaft)
    rows = window_rows(trace.t, window) if increasing else window.mask(trace.t)
    amps = amplitudes_over_angle(trace.position[rows, 0], trace.effort[rows, col], orders,
                                 max(72, 2 * orders + 2))
    if amps is None:
        amps = [math.nan] * orders
    return {f'{shaft}.torque_order{k + 1}': a for k, a in enumerate(amps)}
