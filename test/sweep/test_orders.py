"""The batched sweep's torque orders (cvj_ros.sweep.orders) are harmonics_over_angle's
amplitudes bit for bit, with the grids' cos/sin matrices computed once and reused."""
from __future__ import annotations

import math

import numpy as np
import pytest

from cvj_ros.physics.signal import harmonics_over_angle
from cvj_ros.sweep import orders


def signal(n: int, revs: float, phase: float, sense: float) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(n)
    phi = sense * (0.3 + np.linspace(0.0, 2 * math.pi * revs, n)
                   + 0.01 * np.sin(np.linspace(0, 7, n)))
    tq = 5.0 + 2.0 * np.cos(2 * phi + phase) + 0.3 * np.sin(3 * phi) + 0.01 * rng.standard_normal(n)
    return phi, tq


@pytest.mark.parametrize('n,revs,sense', [(1001, 16.3, 1.0), (1001, 16.3, -1.0), (401, 1.2, 1.0),
                                          (2001, 30.0, 1.0), (17, 3.0, 1.0)])
def test_amplitudes_equal_harmonics_over_angle_bit_for_bit(n: int, revs: float, sense: float) -> None:
    orders._GRIDS.clear()
    for phase in (0.0, 0.7, 0.7):       # the second grid lookup hits the kept matrices
        phi, tq = signal(n, revs, phase, sense)
        ref = harmonics_over_angle(phi, tq, n_harmonics=4, samples_per_rev=72).amplitudes
        got = orders.amplitudes_over_angle(phi, tq, 4, 72)
        assert got is not None
        assert np.array(got).tobytes() == np.asarray(ref, dtype=float).tobytes()
    assert len(orders._GRIDS) == 1


def test_none_where_harmonics_over_angle_raises() -> None:
    phi, tq = signal(101, 0.5, 0.0, 1.0)              # half a revolution
    with pytest.raises(ValueError):
        harmonics_over_angle(phi, tq, n_harmonics=4, samples_per_rev=72)
    assert orders.amplitudes_over_angle(phi, tq, 4, 72) is None
    phi, tq = signal(101, 3.0, 0.0, 1.0)
    phi[50] = phi[49]                                  # not strictly monotonic
    assert orders.amplitudes_over_angle(phi, tq, 4, 72) is None
    assert orders.amplitudes_over_angle(phi[:1], tq[:1], 4, 72) is None
    assert orders.amplitudes_over_angle(phi, tq, 4, 8) is None     # too few points per revolution


class _Trace:
    """What order_amplitudes_cached reads of a Trace."""

    def __init__(self, t: np.ndarray, phi: np.ndarray, tq: np.ndarray) -> None:
        self.t = t
        self.names = ['engine', 'out']
        self.position = np.stack([phi, 0.5 * phi], axis=1)
        self.effort = np.stack([tq, 2.0 * tq], axis=1)

    def column(self, name: str) -> int:
        return self.names.index(name)


@pytest.mark.parametrize('start', [0.0, 0.25, 0.5005, 0.5, 0.9995, 0.9999, 1.5, math.nan])
def test_window_rows_select_the_masks_rows(start: float) -> None:
    """On strictly increasing times the slice holds the mask's rows (a start on a sample,
    between samples, on the last two, past the end, NaN: the last two), so the amplitudes
    are the same floats."""
    from cvj_ros.physics.steady import SteadyWindow
    n = 2001
    t = np.linspace(0.0, 1.0, n)
    phi, tq = signal(n, 30.0, 0.4, 1.0)
    window = SteadyWindow(start, float(t[-1]), False, math.nan, math.nan, '', 0.0, 0, '')
    mask = window.mask(t)
    assert np.array_equal(np.flatnonzero(mask), np.arange(n)[orders.window_rows(t, window)])
    trace = _Trace(t, phi, tq)
    for shaft in (None, 'out'):
        a = orders.order_amplitudes_cached(trace, 4, shaft, window, increasing=True)
        b = orders.order_amplitudes_cached(trace, 4, shaft, window)
        assert np.array(list(a.values())).tobytes() == np.array(list(b.values())).tobytes()
