"""The steady-window criterion (cvj_ros.physics.steady) on synthetic signals whose window
follows in closed form: a steady oscillation, a speed ramp, a decaying oscillation on a
steady one, a pure decay (never steady) and rounding-level ripple (counts as zero).

Each expected window is derived from the signal's formula below; each case is built so the
criterion at the boundary slice is >= 10 % away from its tolerance, so the answer does not
hinge on rounding or on the sampling of the peaks."""
from __future__ import annotations

import math

import numpy as np
import pytest

from cvj_ros.physics import steady
from cvj_ros.physics.steady import find_steady_window, joint_state_window

T_END = 10.0                 # s, record length; 10 slices of 1 s (N_SLICES)
F_OSC = 20.0                 # Hz, 20 periods per slice
DT = 1.0 / (100 * F_OSC)     # s, 100 samples per period: the sine's peaks are samples
T = np.arange(int(round(T_END / DT)) + 1) * DT


def test_defaults_are_the_documented_ones() -> None:
    assert (steady.N_SLICES, steady.MIN_SLICES, steady.DRIFT_TOL, steady.AMPLITUDE_TOL) == (10, 3, 2e-3, 0.05)
    assert steady.FALLBACK_FRACTION == 0.5


def test_steady_oscillation_is_steady_from_the_start() -> None:
    """Constant mean + constant amplitude: every slice equals the last (20 whole periods
    each, same sample phase), so the window is the whole record, drift and change ~ 0."""
    w = 200.0 + 3.0 * np.sin(2 * math.pi * F_OSC * T)
    tq = {'shaft torque': 50.0 + 7.0 * np.cos(2 * math.pi * 3 * F_OSC * T)}
    win = find_steady_window(T, w, amplitude_signals=tq)
    assert win.steady and win.start_s == 0.0 and win.end_s == pytest.approx(T_END)
    assert win.slices == 10 and win.slice_s == pytest.approx(1.0)
    assert win.drift < 1e-12 and win.amplitude_change < 1e-9   # rounding only
    assert np.count_nonzero(win.mask(T)) == T.size


@pytest.mark.parametrize('alpha, start, slices', [
    # ramp w = 100 + alpha t: slice means differ by alpha L (k - last); window slices k0..9
    # agree with the last when alpha L (9 - k0) <= 2e-3 x mean (~100.4):
    # alpha 0.045: (9 - k0) <= 4.46 -> k0 = 5 (drift 1.79e-3, next slice 2.24e-3: margins 10 %, 12 %)
    (0.045, 5.0, 5),
    # alpha 0.004: (9 - k0) <= 50 -> whole record (drift 9 x 0.004 / 100.02 = 3.6e-4)
    (0.004, 0.0, 10),
])
def test_speed_ramp_window_from_closed_form(alpha: float, start: float, slices: int) -> None:
    win = find_steady_window(T, 100.0 + alpha * T)
    assert win.steady and win.start_s == pytest.approx(start) and win.slices == slices
    # the last slice also holds the final sample t = 10 s: its mean is alpha dt/2 later
    m = 9 - int(round(start)) + DT / 2
    assert win.drift == pytest.approx(alpha * 1.0 * m / np.mean(100.0 + alpha * T[T >= start - 1e-9]), rel=1e-9)
    # a ramp's half range is alpha (L - dt)/2 in every slice, alpha L/2 in the last (one more sample)
    assert win.amplitude_change == pytest.approx(DT / 1.0, rel=1e-6)


def test_fast_ramp_is_never_steady_and_says_so() -> None:
    """alpha L 2 = 1.0 > 2e-3 x 105: even the last three slices drift -> fallback to the
    last half, flagged NOT STEADY with the measured drift alpha (2 L + dt/2) / mean."""
    alpha = 0.5
    w = 100.0 + alpha * T
    win = find_steady_window(T, w)
    assert not win.steady and win.slices == 0
    assert win.start_s == pytest.approx(0.5 * T_END) and win.end_s == pytest.approx(T_END)
    assert win.drift == pytest.approx(alpha * (2 + DT / 2) / np.mean(w[T >= 7.0 - 1e-9]), rel=1e-9)
    assert 'NOT STEADY' in win.describe() and 'last 50%' in win.describe()


def _envelope(t: np.ndarray | float, a_s: float, a_d: float, tau: float) -> np.ndarray | float:
    return a_s + a_d * np.exp(-np.asarray(t) / tau)


def test_decaying_oscillation_window_from_closed_form() -> None:
    """Torque (a_s + a_d e^{-t/tau}) sin(2 pi f t): slice k's half range is
    (A(t_k + P/4) + A(t_k + 3P/4))/2 (its first peak and trough are samples; the envelope
    falls by < 0.05 % per sample, less than the 0.2 % by which a neighbouring sample of the
    sine is lower, so the extremes stay on those samples). The window starts at the first
    slice whose half range is within 5 % of the last slice's: with a_s 1, a_d 10, tau 1 s
    that is k0 = 6 (relative difference 0.024; slice 5: 0.063)."""
    a_s, a_d, tau, period = 1.0, 10.0, 1.0, 1.0 / F_OSC
    x = _envelope(T, a_s, a_d, tau) * np.sin(2 * math.pi * F_OSC * T)
    half = np.array([0.5 * (_envelope(k + period / 4, a_s, a_d, tau) + _envelope(k + 3 * period / 4, a_s, a_d, tau))
                     for k in range(10)])
    rel = np.abs(half - half[-1]) / np.maximum(half, half[-1])
    k0 = int(np.flatnonzero(rel <= 0.05)[0])
    assert k0 == 6 and rel[6] < 0.9 * 0.05 < 0.05 * 1.1 < rel[5]    # the >= 10 % margins
    win = find_steady_window(T, np.full_like(T, 150.0), amplitude_signals={'joint torque': x})
    assert win.steady and win.start_s == pytest.approx(6.0) and win.slices == 4
    assert win.amplitude_signal == 'joint torque'
    assert win.amplitude_change == pytest.approx(rel[6], rel=1e-6)


def test_slow_decay_small_per_slice_is_caught_against_the_last_slice() -> None:
    """A decay of 3 % per slice never differs by > 5 % between neighbours, but over the
    record by 1 - 0.97^9 = 24 %: only the slices within 5 % of the last count,
    0.97^(9 - k) >= 0.95 -> 9 - k <= 1.68 -> k >= 8: two slices < MIN_SLICES: not steady."""
    x = (0.97 ** T) * np.sin(2 * math.pi * F_OSC * T)
    win = find_steady_window(T, np.full_like(T, 150.0), amplitude_signals={'torque': x})
    assert not win.steady
    assert win.amplitude_change == pytest.approx(1.0 - 0.97 ** 2, rel=2e-3)


def test_pure_decay_is_never_steady() -> None:
    x = 10.0 * np.exp(-T / 1.0) * np.sin(2 * math.pi * F_OSC * T)
    win = find_steady_window(T, np.full_like(T, 150.0), amplitude_signals={'torque': x})
    assert not win.steady and win.start_s == pytest.approx(5.0)
    assert win.amplitude_change > 0.5


def test_rounding_level_ripple_counts_as_zero() -> None:
    """Random speed ripple of 1e-13 x mean (an ideal joint) and torque ripple of 1e-5 x its
    mean (a road load), and a free end's torque of 1e-16 N m, change by ~100 % between
    slices but sit below the floors (SPEED_FLOOR 1e-6 of the speed's peak, TORQUE_FLOOR 1e-3
    of the largest torque peak): steady."""
    rng = np.random.default_rng(3)
    w = 40.0 * (1.0 + 1e-13 * rng.standard_normal(T.size))
    tq = 236.0 * (1.0 + 1e-5 * rng.standard_normal(T.size))
    free_end = 1e-16 * rng.standard_normal(T.size)     # a shaft with no load: rounding only
    win = find_steady_window(T, w, amplitude_signals={'wheel torque': tq, 'free end torque': free_end})
    assert win.steady and win.start_s == 0.0
    assert win.amplitude_change < 0.05


def test_joint_state_window_uses_first_shaft_and_every_torque() -> None:
    names = ['engine_crank', 'wheel']
    vel = np.column_stack([100.0 + 0.5 * T, 20.0 + 0.0 * T])
    eff = np.column_stack([np.full_like(T, 10.0), np.full_like(T, 50.0)])
    win = joint_state_window(T, names, vel, eff)
    assert win.reference == 'engine_crank speed' and not win.steady
    assert win.signals == ['engine_crank speed', 'engine_crank torque', 'wheel torque']
    assert 'engine_crank speed' in win.criterion()
    d = win.to_dict()
    assert d['steady'] is False and 'criterion' in d


def test_slice_seconds_and_bad_input() -> None:
    win = find_steady_window(T, np.full_like(T, 5.0), slice_s=2.5)
    assert win.slices == 4 and win.slice_s == 2.5
    with pytest.raises(ValueError, match='t: need at least 2'):
        find_steady_window([0.0], [1.0])
    with pytest.raises(ValueError, match='reference_speed'):
        find_steady_window(T, T[:-1])
    with pytest.raises(ValueError, match='slice_s'):
        find_steady_window(T, T, slice_s=-1.0)
    with pytest.raises(ValueError, match='torque'):
        find_steady_window(T, T, amplitude_signals={'torque': T[:5]})
    short = find_steady_window(T[:4], np.ones(4))      # fewer than 2 samples per slice
    assert not short.steady and math.isnan(short.drift)


def test_a_gap_in_the_record_starves_its_slices_only() -> None:
    """The steady oscillation above with no samples between 0 s and 2.5 s (ticks a free
    run skipped to catch up after a late step): slices 0..1 s and 1..2 s hold 1 and 0
    samples, 2..3 s holds those from 2.5 s on. The criterion compares the 8 slices after the
    starved ones (usable_tail), so the window is 2.5..10 s, steady, with drift and change
    measured; only when fewer than min_slices slices of >= 2 samples end the record is it
    not measurable, and the report says that, not that every slice is short."""
    keep = (T < 0.5 * DT) | (T >= 2.5)
    t = T[keep]
    w = (200.0 + 3.0 * np.sin(2 * math.pi * F_OSC * T))[keep]
    tq = {'shaft torque': (50.0 + 7.0 * np.cos(2 * math.pi * 3 * F_OSC * T))[keep]}
    _edges, lo, hi = steady.slice_bounds(t)
    assert list(hi - lo)[:3] == [1, 0, 1000] and steady.usable_tail(lo, hi) == 2
    win = find_steady_window(t, w, amplitude_signals=tq)
    assert win.steady and win.start_s == pytest.approx(2.5) and win.slices == 8
    assert win.drift < 1e-12 and win.amplitude_change < 1e-9
    assert 'not measurable' not in win.describe() and 'drift ' in win.describe()
    # a gap that leaves only 2 slices (8..10 s) after it: min_slices 3 cannot be met
    keep = (T < 0.5 * DT) | (T >= 8.0)
    short = find_steady_window(T[keep], np.full(np.count_nonzero(keep), 200.0))
    assert steady.usable_tail(*steady.slice_bounds(T[keep])[1:]) is None
    assert not short.steady and math.isnan(short.drift) and math.isnan(short.amplitude_change)
    assert ('not measurable (fewer than 3 slices of 1 s with 2 samples or more each at the end '
            'of the record)') in short.describe()


def test_user_skip_window_reports_the_criterion_on_it() -> None:
    """--skip 5 on the decaying oscillation above (a_s 1, a_d 10, tau 1 s): 5..10 s in 10
    slices of 0.5 s; half ranges as in the closed form above: the first 1 + 10 e^-5 ~ 1.067,
    the last (9.5 s) ~ 1.0008: change 0.061 > 0.05 -> not steady; --skip 6: ~0.024, steady."""
    x = _envelope(T, 1.0, 10.0, 1.0) * np.sin(2 * math.pi * F_OSC * T)
    names, vel, eff = ['crank'], np.full((T.size, 1), 150.0), x[:, None]
    late = joint_state_window(T, names, vel, eff, skip_s=6.0)
    early = joint_state_window(T, names, vel, eff, skip_s=5.0)
    assert late.source == early.source == 'skip'
    assert late.start_s == pytest.approx(6.0) and early.start_s == pytest.approx(5.0)
    assert late.steady and not early.steady
    period = 1.0 / F_OSC
    half = [0.5 * (_envelope(t0 + period / 4, 1.0, 10.0, 1.0) + _envelope(t0 + 3 * period / 4, 1.0, 10.0, 1.0))
            for t0 in (5.0, 9.5)]
    assert early.amplitude_change == pytest.approx((half[0] - half[1]) / half[0], rel=1e-6)
    assert 'start set by the user, NOT STEADY' in early.describe()
    with pytest.raises(ValueError, match='skip_s'):
        joint_state_window(T, names, vel, eff, skip_s=-1.0)


def test_partial_periods_in_a_slice_do_not_fake_a_drift() -> None:
    """Speed 20 + 3 cos(40 t) over 8 s: 0.8 s slices hold nu = 40 x 0.8 / 2 pi = 5.09
    periods. A plain slice mean is off by up to a |sin(pi nu)/(pi nu)| = 3 x 0.018 rad/s,
    so two slices differ by up to 5.4e-3 of the mean (above DRIFT_TOL 2e-3); the
    Hann-weighted mean is off by a |sin(pi nu)/(pi nu (nu^2 - 1))| (the continuous Hann
    window's transform), 24.9x less: drift <= 2 x 3 x 7.2e-4 / 20 = 2.2e-4, 9x under
    DRIFT_TOL: steady from the start."""
    t = np.arange(8001) * 1e-3
    a, om, length = 3.0, 40.0, 0.8
    w = 20.0 + a * np.cos(om * t)
    nu = om * length / (2 * math.pi)
    plain_bound = a * abs(math.sin(math.pi * nu) / (math.pi * nu))
    hann_bound = plain_bound / (nu ** 2 - 1.0)
    plain = [np.mean(w[(t >= k * length - 1e-12) & (t < (k + 1) * length - 1e-12)]) for k in range(10)]
    assert (max(plain) - min(plain)) / 20.0 > steady.DRIFT_TOL      # the plain mean would fail
    win = find_steady_window(t, w)
    assert win.steady and win.start_s == 0.0
    assert win.drift <= 2 * hann_bound / 20.0 * 1.05 < steady.DRIFT_TOL / 8   # 5 %: discrete vs continuous window
