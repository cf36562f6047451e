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
