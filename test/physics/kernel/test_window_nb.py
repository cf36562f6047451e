"""The monitor's compiled window kernels (kernel/window_nb.py) against numpy, and how
they are loaded (warm(): through the entry-point loader, not numba's first call)."""
from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from cvj_ros.physics.kernel.window_nb import ring_push, ring_window_stats
from cvj_ros.physics.monitor_metrics import RollingWindow, column_stats


@pytest.mark.parametrize('capacity,pushed', [(50, 30), (50, 50), (50, 173)])
def test_ring_push_and_stats_match_numpy_on_the_window(capacity: int, pushed: int) -> None:
    rng = np.random.default_rng(capacity + pushed)
    t = np.arange(pushed) * 1e-3
    rows = rng.normal(size=(pushed, 4))
    rows[pushed // 3, 2] = np.nan                     # a NaN column while it is in the window
    buf_t, buf_rows = np.zeros(capacity), np.zeros((capacity, 4))
    nxt = 0
    for a in range(0, pushed, 7):                     # blocks of 7, as collected batches
        nxt = ring_push(buf_t, buf_rows, nxt, t[a:a + 7], rows[a:a + 7])
    kept = min(capacity, pushed)
    span = 0.02
    sel = (t >= t[-1] - span) & (np.arange(pushed) >= pushed - kept)
    mean, lo, hi = np.empty(4), np.empty(4), np.empty(4)
    n = ring_window_stats(buf_t, buf_rows, kept, nxt, span, mean, lo, hi)
    ref_mean, ref_lo, ref_hi = column_stats(rows[sel])
    assert n == int(sel.sum())
    np.testing.assert_allclose(mean, ref_mean, rtol=1e-14, equal_nan=True)
    np.testing.assert_array_equal(lo, ref_lo)
    np.testing.assert_array_equal(hi, ref_hi)
    win = RollingWindow(capacity, 4)                  # the class the monitor uses: same result
    win.push_many(t, rows)
    assert win.stats(span)[0] == n


def test_warm_loads_without_refreshing_numbas_typing_registries() -> None:
    """warm() (every monitor node calls it when created) loads its three kernels through
    cvj_ros.physics.kernel.entry_point: numba's own first call would refresh the typing
    registries, which imports numba.np.arraymath and with it scipy.linalg (~0.5 s of a
    composed run's start-up, measured). The first process fills the cache if it is cold."""
    code = ('import sys; from cvj_ros.physics.kernel import window_nb; window_nb.warm(); '
            'print("numba.np.arraymath" in sys.modules)')
    subprocess.run([sys.executable, '-c', code], check=True, capture_output=True, timeout=300)
    out = subprocess.run([sys.executable, '-c', code], check=True, capture_output=True, text=True,
                         timeout=300)
    assert out.stdout.strip() == 'False'
