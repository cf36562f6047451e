"""Compiled statistics of the monitor's rolling windows (the monitor's publication).

``ring_window_stats`` reads the samples of the last ``span`` seconds straight from a
:class:`cvj_ros.physics.monitor_metrics.RollingWindow`'s ring buffer and returns, per
column, the mean, minimum and maximum - what the monitor's speed nonuniformity (Davidbaev et
al. 2023, sec. 4) and amplitudes need - in one pass without copying the window. The numpy path it
replaces (select, copy, transpose, three reductions, per window) cost ~25 numpy calls per
window; inside a running composed loop each numpy call ran 3-7x slower than in isolation
(measured: a 13000-element reduction 15 us alone, 45 us median / 110 us mean between the
loop's callbacks), which made the monitor's publication the largest share of an exchange.

Semantics are numpy's: a column holding a NaN has NaN mean, min and max; an empty window
gives NaN everywhere and n = 0. The mean is the sequential sum over the window divided by
n (numpy's pairwise sum may differ in the last bits).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True, nogil=False)
def ring_window_stats(t: np.ndarray, rows: np.ndarray, count: int, nxt: int, span: float,
                      mean: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> int:
    """Mean, min and max per column (into ``mean``, ``lo``, ``hi``) of the ring-buffer
    samples with t >= t_last - span (s); returns their number. ``t`` (capacity,), ``rows``
    (capacity, width); ``count`` samples stored, the next write at ``nxt`` (the oldest
    sample is at ``nxt - count`` modulo capacity)."""
    cap = t.shape[0]
    width = rows.shape[1]
    for j in range(width):
        mean[j] = 0.0
        lo[j] = math.inf
        hi[j] = -math.inf
    if count == 0:
        for j in range(width):
            mean[j] = math.nan
            lo[j] = math.nan
            hi[j] = math.nan
        return 0
    newest = (nxt - 1) % cap
    threshold = t[newest] - span
    # every stored sample is tested (as RollingWindow.window's mask does: stamps need not
    # be ordered); 20000 comparisons cost ~10-20 us
    n = 0
    nan_col = np.zeros(width, dtype=np.bool_)
    for m in range(count):
        i = (nxt - count + m) % cap
        if not (t[i] >= threshold):
            continue
        n += 1
        for j in range(width):
            v = rows[i, j]
            if v != v:
                nan_col[j] = True
                continue
            mean[j] += v
            if v < lo[j]:
                lo[j] = v
            if v > hi[j]:
                hi[j] = v
    for j in range(width):
        if nan_col[j] or n == 0:
            mean[j] = math.nan
            lo[j] = math.nan
            hi[j] = math.nan
        else:
            mean[j] /= n
    return n


@njit(cache=True)
def ring_push(t: np.ndarray, rows: np.ndarray, nxt: int, t_new: np.ndarray,
              rows_new: np.ndarray) -> int:
    """Append samples (``t_new`` (m,) s, ``rows_new`` (m, width)) to the ring buffer at
    ``nxt`` in order (only the last capacity survive); returns the next write position."""
    cap = t.shape[0]
    width = rows.shape[1]
    m = t_new.shape[0]
    start = m - cap if m > cap else 0
    nxt = (nxt + start) % cap
    for k in range(start, m):
        t[nxt] = t_new[k]
        for j in range(width):
            rows[nxt, j] = rows_new[k, j]
        nxt += 1
        if nxt == cap:
            nxt = 0
    return nxt


@njit(cache=True)
def _f8(buf: np.ndarray, row: int, at: int, scratch: np.ndarray) -> float:
    """The little-endian float64 at byte ``at`` of ``buf[row]`` (any alignment)."""
    u = np.uint64(0)
    for b in range(7, -1, -1):
        u = (u << np.uint64(8)) | np.uint64(buf[row, at + b])
    scratch[0] = u
    return scratch.view(np.float64)[0]


@njit(cache=True)
def cdr_rows(buf: np.ndarray, fixed: np.ndarray, starts: np.ndarray, n: int,
             stamp_ns: np.ndarray, values: np.ndarray) -> bool:
    """Samples of one CDR layout side by side (``buf`` (m, L) uint8, one serialised message
    per row): False unless every row equals row 0 on the byte ranges ``fixed`` ((k, 2)
    [start, end)); else the stamps (header sec int32 at byte 4, nanosec uint32 at 8) into
    ``stamp_ns`` (m,) int64 ns and, for each offset ``starts[a]``, ``n`` float64 values
    into ``values[a]`` ((len(starts), m, n)). The monitor's bulk reading of its collected
    joint states and answers (cvj_ros.nodes.cdr.read_joint_state_block)."""
    m = buf.shape[0]
    for p in range(fixed.shape[0]):
        for c in range(fixed[p, 0], fixed[p, 1]):
            first = buf[0, c]
            for r in range(1, m):
                if buf[r, c] != first:
                    return False
    scratch = np.empty(1, dtype=np.uint64)
    for r in range(m):
        sec = np.int64(buf[r, 4]) | (np.int64(buf[r, 5]) << 8) | (np.int64(buf[r, 6]) << 16) \
            | (np.int64(buf[r, 7]) << 24)
        if sec >= 2**31:
            sec -= 2**32
        nsec = np.int64(buf[r, 8]) | (np.int64(buf[r, 9]) << 8) | (np.int64(buf[r, 10]) << 16) \
            | (np.int64(buf[r, 11]) << 24)
        stamp_ns[r] = sec * 1_000_000_000 + nsec
        for a in range(starts.shape[0]):
            at = starts[a]
            for j in range(n):
                values[a, r, j] = _f8(buf, r, at + 8 * j, scratch)
    return True


def warm() -> None:
    """Load (or compile) every function of this module for the argument types the monitor
    uses: called by ``make kernel`` (kernel/warmup.py) and when a monitor node is created,
    so neither a first run nor a running loop pays the load (10-50 ms each from numba's
    cache). The byte buffer is read-only, as ``np.frombuffer`` gives it: another numba type
    than a writable array. Loaded through :func:`cvj_ros.physics.kernel.entry_point`
    (numba's own first call refreshes its typing registries, which imports scipy.linalg:
    0.5 s of a composed run's start-up); a cache miss compiles as a first call would."""
    from cvj_ros.physics.kernel import entry_point
    t = np.zeros(2)
    rows = np.zeros((2, 1))
    args = (t, rows, 0, np.zeros(1), np.ones((1, 1)))
    nxt = entry_point(ring_push, args)(*args)
    out = np.empty(1)
    args = (t, rows, 1, nxt, 1.0, out, np.empty(1), np.empty(1))
    entry_point(ring_window_stats, args)(*args)
    args = (np.frombuffer(bytes(24), np.uint8).reshape(1, 24), np.zeros((1, 2), np.int64),
            np.array([16], np.int64), 1, np.empty(1, np.int64), np.empty((1, 1, 1)))
    entry_point(cdr_rows, args)(*args)
