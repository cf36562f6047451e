"""Metrics against closed forms of sampled sinusoids."""
from __future__ import annotations

import math

import numpy as np
import pytest

from cvj_ros.physics.metrics import amplitude, nonuniformity, shaft_metrics, steady_window


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
    """A step from 0 to 10 rad/s at 0.5 s: 10 slices of 0.1 s; slices 5..9 agree with the
    last, slice 4 (mean 0) does not -> window 0.5..1 s (51 samples), delta 0 there;
    ``transient`` 0.9 s sets the start instead (11 samples)."""
    t = np.linspace(0.0, 1.0, 101)
    w = np.where(t < 0.5 - 1e-9, 0.0, 10.0)        # run-up then constant
    names, vel = ['s'], w[:, None]
    win = steady_window(t, names, vel, vel)
    assert win.steady and win.start_s == pytest.approx(0.5) and win.mask(t).sum() == 51
    assert steady_window(t, names, vel, vel, transient=0.9).mask(t).sum() == 11
    assert shaft_metrics(t, ['s'], w[:, None], w[:, None])['s']['delta'] == 0.0


def test_nonuniformity_zero_mean_is_inf() -> None:
    assert nonuniformity([-1.0, 1.0]) == float('inf')
