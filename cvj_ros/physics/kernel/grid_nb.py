"""Compiled landing grid of an offline run (part of a run's fixed cost).

``landing_grid`` is :func:`cvj_ros.physics.simulate.landing_grid` (the readable numpy
definition, its test oracle) in one pass: the sample times with the load's breakpoints
merged in. The numpy version costs ~20 numpy calls, ~25 us for kavz685_lever's 100 knots
per second - a tenth of a loose-tolerance run of that scene; this one ~1 us.
"""
from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def landing_grid(times: np.ndarray, breaks: np.ndarray, tol: float, grid: np.ndarray,
                 rows: np.ndarray) -> int:
    """Merge ``breaks`` (s, any order, repeats allowed) strictly inside (times[0],
    times[-1]) into the ascending sample ``times`` (s); a breakpoint within tol max(1, |b|)
    of a sample or of the last breakpoint kept is dropped. Writes the merged times to
    grid[:m] (grid.size >= times.size + breaks.size) and the row of each sample in grid to
    ``rows`` (times.size,); returns m."""
    n = times.shape[0]
    b = np.sort(breaks)   # NaN sorts last and never lies inside the span
    t_first, t_last = times[0], times[n - 1]
    i = 0
    m = 0
    have_last = False
    last = 0.0
    for j in range(b.shape[0]):
        bj = b[j]
        if not (t_first < bj < t_last):
            continue
        while times[i] < bj:   # ends: times[0] < bj < times[-1]
            grid[m] = times[i]
            rows[i] = m
            m += 1
            i += 1
        near = tol * max(1.0, abs(bj))
        if bj - times[i - 1] <= near or times[i] - bj <= near:
            continue
        if have_last and bj - last <= near:
            continue
        grid[m] = bj
        m += 1
        last = bj
        have_last = True
    while i < n:
        grid[m] = times[i]
        rows[i] = m
        m += 1
        i += 1
    return m


def warm() -> None:
    """Compile or load it (``make kernel``)."""
    g = np.empty(4)
    landing_grid(np.array([0.0, 1.0]), np.array([0.5, 2.0]), 1e-9, g, np.empty(2, np.int64))
