"""Metrics against closed forms of sampled sinusoids."""
from __future__ import annotations

import math

import numpy as np
import pytest

from cvj_ros.physics.metrics import amplitude, nonuniformity, shaft_metrics, steady_mask


def test_nonuniformity_and_amplitudes_of_sinusoid() -> None:
    t = np.linspace(0.0, 2.0, 20001)
    w = 10.0 + 0.5 * np.sin(2 * math.pi * 5 * t)
    torque = 100.0 + 7.0 * np.cos(2 * math.pi * 5 * t)
    assert nonuniformity(w) == pytest.approx(1.0 / 10.0, rel=1e-6)
    assert amplitude(torque) == pytest.approx(7.0, rel=1e-6)
    m = shaft_metrics(t, ['s'], w[:, None], torque[:, None])['s']
    assert m['mean_speed'] == pytest.approx(10.0, abs=1e-3)
    assert m['speed_amplitude'] == pytest.approx(0.5, rel=1e-6)
    # acceleration amplitude 0.5 * 2 pi 5 (numerical derivative of the samples)
    assert m['acceleration_amplitude'] == pytest.approx(0.5 * 2 * math.pi * 5, rel=1e-4)
    assert m['torque_amplitude'] == pytest.approx(7.0, rel=1e-6)


def test_steady_window_skips_transient() -> None:
    t = np.linspace(0.0, 1.0, 101)
    assert steady_mask(t).sum() == 51
    assert steady_mask(t, transient=0.9).sum() == 11
    w = np.where(t < 0.5, 0.0, 10.0)        # run-up then constant
    assert shaft_metrics(t, ['s'], w[:, None], w[:, None])['s']['delta'] == 0.0


def test_nonuniformity_zero_mean_is_inf() -> None:
    assert nonuniformity([-1.0, 1.0]) == float('inf')
