"""Rolling-window monitor metrics against closed forms of synthetic signals."""
from __future__ import annotations

import math

import numpy as np
import pytest

from cvj_ros.physics.monitor_metrics import (RollingWindow, amplitude, angle_level, column_stats,
                                             detrended_nonuniformity,
                                             level, speed_nonuniformity)


def test_nonuniformity_of_sinusoidal_speed_closed_form():
    # omega = w0 (1 + eps sin(2 pi f t)) sampled over whole periods: delta = 2 eps exactly
    # at the extremes (sampled at the peaks), seed 004 sec. 4 definition.
    w0, eps, f = 40.0, 0.03, 5.0
    t = np.arange(0, 1.0, 1e-3)       # 1 ms samples hit t = 0.05 s (peak) and 0.15 s (trough)
    omega = w0 * (1 + eps * np.sin(2 * math.pi * f * t))
    delta = speed_nonuniformity(omega[:, None])
    assert delta[0] == pytest.approx(2 * eps, rel=1e-9)
    # mean of the sine over whole periods is w0; amplitude is w0 eps
    assert amplitude(omega[:, None])[0] == pytest.approx(w0 * eps, rel=1e-9)


def test_hooke_output_speed_nonuniformity_matches_ratio_swing():
    # Independent construction: constant input speed through a Hooke joint at beta; output speed
    # = w * cos b / (1 - sin^2 b cos^2 phi) swings between w cos b and w / cos b (seed 002 eq. 10).
    b, w = math.radians(30.0), 100.0
    phi = np.linspace(0, 2 * math.pi, 20001)
    out = w * math.cos(b) / (1 - math.sin(b) ** 2 * np.cos(phi) ** 2)
    # closed form of (max - min)/mean: mean output speed over a revolution equals w
    expected = (1 / math.cos(b) - math.cos(b))
    delta = speed_nonuniformity(np.c_[np.full_like(out, w), out])
    assert delta[0] == 0.0
    assert delta[1] == pytest.approx(expected, rel=1e-4)


def test_standstill_and_empty_give_nan():
    assert np.isnan(speed_nonuniformity(np.zeros((10, 1)))[0])
    assert np.isnan(speed_nonuniformity(np.zeros((0, 2)))).all()
    assert np.isnan(amplitude(np.zeros((0, 3)))).all()


def test_rolling_window_keeps_last_samples_in_order_and_time_span():
    win = RollingWindow(5, 2)
    for i in range(8):
        win.push(0.1 * i, [i, -i])
    t, rows = win.samples()
    assert len(win) == 5
    np.testing.assert_allclose(t, [0.3, 0.4, 0.5, 0.6, 0.7])
    np.testing.assert_allclose(rows[:, 0], [3, 4, 5, 6, 7])
    t2, rows2 = win.window(0.25)        # t >= 0.45
    np.testing.assert_allclose(t2, [0.5, 0.6, 0.7])
    np.testing.assert_allclose(rows2[:, 1], [-5, -6, -7])
    with pytest.raises(ValueError, match='capacity'):
        RollingWindow(0, 1)


def test_rolling_window_selection_equals_the_definition_on_every_fill_state():
    """window(span) = the samples (in time order) with t >= t_newest - span, whatever the
    buffer's fill and wrap state, also for times that are not increasing."""
    rng = np.random.default_rng(7)
    for capacity in (1, 2, 7, 50):
        win = RollingWindow(capacity, 3)
        for k in range(3 * capacity + 5):
            t = 0.01 * k if k % 11 else 0.01 * k - 0.05 * rng.random()   # some going back
            win.push(t, rng.normal(size=3))
            t_all, rows_all = win.samples()
            for span in (0.0, 0.015, 0.1, 1e9):
                keep = t_all >= t_all[-1] - span
                t_w, rows_w = win.window(span)
                np.testing.assert_array_equal(t_w, t_all[keep])
                np.testing.assert_array_equal(rows_w, rows_all[keep])
    empty = RollingWindow(4, 2).window(1.0)
    assert empty[0].shape == (0,) and empty[1].shape == (0, 2)


def test_push_many_equals_pushes_one_by_one():
    rng = np.random.default_rng(3)
    for capacity in (1, 3, 10):
        one, many = RollingWindow(capacity, 2), RollingWindow(capacity, 2)
        k = 0
        for m in (0, 1, 2, 5, 11, 3, 25, 1):
            t = 0.01 * np.arange(k, k + m)
            rows = rng.normal(size=(m, 2))
            for i in range(m):
                one.push(t[i], rows[i])
            many.push_many(t, rows)
            k += m
            assert len(one) == len(many)
            for a, b in zip(one.samples(), many.samples()):
                np.testing.assert_array_equal(a, b)
            np.testing.assert_array_equal(one._t, many._t)


def test_levels():
    assert level(0.05, 0.11, 0.15) == 0
    assert level(0.12, 0.11, 0.15) == 1
    assert level(0.2, 0.11, 0.15) == 2
    assert level(float('nan'), 0.11, 0.15) == 2
    assert level(5.0, 0.0, 0.0) == 0          # disabled thresholds
    assert angle_level(20.0, 25.0) == 0
    assert angle_level(27.0, 25.0) == 1
    assert angle_level(31.0, 25.0) == 2


@pytest.mark.parametrize('capacity, pushes, span', [(50, 30, 0.01), (50, 130, 0.02), (50, 130, 1e9),
                                                    (7, 7, 0.0), (64, 1000, 0.0355)])
def test_stats_are_the_window_column_stats(capacity: int, pushes: int, span: float) -> None:
    """RollingWindow.stats (compiled, on the ring buffer in place) against column_stats of
    RollingWindow.window (numpy): same n, min and max exactly, mean to rounding; with a
    wrapped buffer, NaN in one column, and stamps out of order."""
    rng = np.random.default_rng(capacity + pushes)
    w = RollingWindow(capacity, 3)
    for k in range(pushes):
        t = k * 1e-3 if k % 17 else max(0.0, (k - 5) * 1e-3)      # a late stamp now and then
        row = rng.normal(size=3)
        if k == pushes - 3:
            row[2] = np.nan
        w.push(t, row)
    t, rows = w.window(span)
    n, mean, lo, hi = w.stats(span)
    assert n == t.size
    want_mean, want_lo, want_hi = column_stats(rows)
    np.testing.assert_array_equal(lo, want_lo)
    np.testing.assert_array_equal(hi, want_hi)
    np.testing.assert_allclose(mean, want_mean, rtol=1e-13, atol=1e-15)   # NaN where NaN


def test_stats_of_an_empty_window_are_nan() -> None:
    n, mean, lo, hi = RollingWindow(5, 2).stats(1.0)
    assert n == 0 and np.isnan(mean).all() and np.isnan(lo).all() and np.isnan(hi).all()


def test_detrended_nonuniformity_removes_a_ramp_and_keeps_a_ripple() -> None:
    """A pure ramp has no nonuniformity about its trend (its raw delta is the speed change);
    a steady ripple A sin(2 pi f t) about a constant mean keeps delta = 2A/mean; the ripple on
    a ramp gives it back about the trend (over 50 periods the line absorbs the ripple's slope
    6A/(pi f T^2) = 0.11 rad/s^2: delta within 2 %), with the ramp's slope."""
    t = np.linspace(0.0, 1.0, 1001)
    ramp = 200.0 + 40.0 * t
    ripple = 3.0 * np.sin(2 * np.pi * 50.0 * t)
    w = np.column_stack([ramp, 200.0 + ripple, ramp + ripple, np.zeros_like(t)])
    d, b = detrended_nonuniformity(t, w, min_speed=1.0)
    assert d[0] == pytest.approx(0.0, abs=1e-12) and b[0] == pytest.approx(40.0, rel=1e-12)
    raw = (w.max(axis=0) - w.min(axis=0)) / w.mean(axis=0)
    assert raw[0] == pytest.approx(40.0 / 220.0, rel=1e-12)
    assert d[1] == pytest.approx(raw[1], rel=2e-2) and abs(b[1]) < 0.5
    assert d[2] == pytest.approx(6.0 / 220.0, rel=2e-2) and b[2] == pytest.approx(40.0, abs=0.5)
    assert math.isnan(d[3])                         # standstill
    nan, _b = detrended_nonuniformity(t[:2], w[:2])
    assert np.all(np.isnan(nan))
