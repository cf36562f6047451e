"""Analysis figures read as an engineer needs them (issue 14 item 4), checked on the matplotlib
Figure objects, not on pixels: one axis row per speed level, unique (colour, line style) per
series beyond ten series, every series in a legend exactly once, deviations below the
rounding floor drawn flat and called "uniform", curves folded to one revolution.

The synthetic driveline (no bag, no ROS): an engine level at 230 rad/s (engine_crank, a
duplicated name, a Hooke joint 12 deg) and, behind a gear of ratio 1/5.28, a wheel level at
~43.6 rad/s with twelve shafts (more than the ten colours of tab10).
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import matplotlib
import numpy as np
import pytest

matplotlib.use('Agg')
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.colors import to_rgba  # noqa: E402

from cvj_ros import plots  # noqa: E402
from cvj_ros.analysis import BagSignals, analyze_signals  # noqa: E402

W_ENGINE = 230.0          # rad/s
GEAR = 1.0 / 5.28         # output/input speed ratio of the gear joint
BETA = math.radians(12.0)  # Hooke joint angle
N_SLOW = 12               # shafts behind the gear (> 10 colours)
DT = 5e-4                 # s, sample period
DURATION = 2.0            # s


def hooke_out(phi: np.ndarray) -> np.ndarray:
    """Hooke joint output angle, tan(phi_out) = tan(phi_in) / cos(beta), unwrapped (seed 002)."""
    return phi + np.arctan2((1.0 / math.cos(BETA) - 1.0) * np.sin(phi) * np.cos(phi),
                            1.0 + (1.0 / math.cos(BETA) - 1.0) * np.cos(phi) ** 2)


def hooke_geometric_peak_to_peak() -> float:
    """Closed form: max of phi_out - phi_in at tan(phi_in) = sqrt(cos beta):
    atan(1/sqrt(c)) - atan(sqrt(c)), and the curve is odd, so peak-to-peak = twice that [rad]."""
    c = math.cos(BETA)
    return 2.0 * (math.atan(1.0 / math.sqrt(c)) - math.atan(math.sqrt(c)))


def synthetic_signals(*, gear_noise_rad: float = 0.0) -> BagSignals:
    """Joint-state arrays of the synthetic driveline (angles in rad, speeds by the exact
    derivative, torques N m). ``gear_noise_rad`` adds alternating +-noise to the gear output
    angle (a stand-in for rounding noise of recorded angles)."""
    t = np.arange(0.0, DURATION + DT / 2, DT)
    phi_e = W_ENGINE * t + 0.002 * np.sin(2 * W_ENGINE * t)          # 2nd-order engine ripple
    w_e = W_ENGINE + 0.004 * W_ENGINE * np.cos(2 * W_ENGINE * t)
    phi_h = hooke_out(phi_e)
    h = 1e-7
    w_h = (hooke_out(phi_e + h) - hooke_out(phi_e - h)) / (2 * h) * w_e
    names = ['engine_crank', 'dup', 'dup', 'hooke_input', 'hooke_output', 'gear_input', 'gear_output']
    pos = [phi_e, phi_e, phi_e, phi_e, phi_h, phi_h, GEAR * phi_h]
    vel = [w_e, w_e, w_e, w_e, w_h, w_h, GEAR * w_h]
    tq = [50 + 10 * np.cos(2 * phi_e)] * 4 + [50 + 10 * np.cos(2 * phi_h)] * 2 + [50 / GEAR + 0 * t]
    if gear_noise_rad:
        pos[-1] = pos[-1] + gear_noise_rad * (-1.0) ** np.arange(t.size)
    for k in range(N_SLOW - 1):                    # wheel-level shafts, slightly different each
        names.append(f'slow_{k:02d}')
        pos.append(GEAR * phi_h * (1 + 1e-3 * k))
        vel.append(GEAR * w_h * (1 + 1e-3 * k))
        tq.append(50 / GEAR + (k + 1) * np.cos(phi_h * GEAR))
    sig = BagSignals(path=Path('synthetic/bag'), joint_names=names, t=t,
                     position=np.column_stack(pos), velocity=np.column_stack(vel),
                     effort=np.column_stack(tq))
    sig.engine_t, sig.engine_torque = t, 50 + 10 * np.cos(2 * phi_e)
    sig.load_t, sig.load_torque = t, 50 / GEAR + 0 * t
    return sig


@pytest.fixture(scope='module')
def sig_report() -> tuple[BagSignals, dict[str, Any]]:
    sig = synthetic_signals()
    return sig, analyze_signals(sig, skip_fraction=0.25)


def _legend_labels(ax: Any) -> list[str]:
    leg = ax.get_legend()
    return [t.get_text() for t in leg.get_texts()] if leg is not None else []


def _name(label: str) -> str:
    """Series name of a legend label ('name (note)' / 'name: note' -> 'name')."""
    return label.split(' (')[0].split(':')[0]


def test_speed_levels_split_at_gears_and_signs() -> None:
    # 230/228 one level, 42.0/43.6 one level (ratio < 1.5), reverse and rest levels apart
    assert plots.speed_levels([230.0, 42.0, 228.0, 43.6, -10.0, 0.0]) == [[0, 2], [1, 3], [4], [5]]
    assert plots.speed_levels([]) == []


def test_amplitude_groups_keep_every_curve_above_a_tenth_of_its_axis() -> None:
    # cage 0.17 with 0.02-0.03 shafts (ratio < 10) on one axis, 0.002 next, flat ones with it
    assert plots.amplitude_groups([0.002, 0.17, 0.03, 0.0, 0.02, 1e-12]) == [[1, 2, 4], [0, 3, 5]]
    assert plots.amplitude_groups([0.0, 0.0]) == [[0, 1]] and plots.amplitude_groups([]) == []


def test_shaft_labels_unique_for_duplicate_names() -> None:
    labels = plots.shaft_labels(['a', 'b', 'a'])
    assert labels == ['a [column 0]', 'b', 'a [column 2]'] and len(set(labels)) == 3


def test_series_styles_unique_beyond_ten() -> None:
    styles = {(plots.series_style(i)['color'], plots.series_style(i)['ls'], plots.series_style(i)['lw'])
              for i in range(160)}
    bars = {(plots.bar_style(i)['color'], plots.bar_style(i)['hatch']) for i in range(40)}
    assert len(styles) == 160 and len(bars) == 40


def test_revolution_mean_speed_closed_form() -> None:
    # phi(t + 2 pi / w) = phi(t) + 2 pi exactly for phi = w t + a sin(2 w t): every revolution
    # takes 2 pi / w, so the revolution mean is w. Error: linear interpolation of t(phi),
    # ~ (w dt)^2 * a / 8 relative = 1.3e-5 here (measured 2e-6); bound 1e-4.
    w, dt = 100.0, 1e-3
    t = np.arange(0.0, 1.0, dt)
    w_rev = plots.revolution_mean_speed(t, w * t + 0.05 * np.sin(2 * w * t))
    ok = np.isfinite(w_rev)
    assert np.count_nonzero(ok) > 0.8 * t.size
    assert np.max(np.abs(w_rev[ok] / w - 1.0)) < 1e-4
    assert np.all(np.isnan(plots.revolution_mean_speed(t, np.sin(t))))   # not monotonic: none


def test_fold_over_angle_one_clean_curve() -> None:
    phi = np.linspace(0.0, 5 * 2 * math.pi, 1234)
    x, mean, lo, hi, revs = plots.fold_over_angle(phi, np.cos(2 * phi), 72)
    assert revs == pytest.approx(5.0) and x[0] == 0.0 and x[-1] == 360.0 and np.all(np.diff(x) > 0)
    # interpolated linearly from samples dphi = 2 pi 5 / 1233 apart onto the 5 deg grid: error
    # <= (2 dphi)^2 / 8 = 3.3e-4 of the unit amplitude (measured 2e-4); bound 3.3e-3
    assert np.max(np.abs(mean - np.cos(2 * np.radians(x)))) < 3.3e-3
    assert np.max(hi - lo) < 3.3e-3


def test_speeds_torques_one_row_per_level_and_complete_unique_legends(sig_report) -> None:
    sig, report = sig_report
    fig = plots.speeds_torques_figure(sig, report['window']['start_s'])
    try:
        axes = fig.axes
        rows = [axes[i:i + 5] for i in range(0, len(axes), 5)]
        assert len(axes) == 10 and len(rows) == 2         # engine level, wheel level
        all_labels: list[str] = []
        styles = set()
        for ax_w, ax_wz, ax_t, ax_tz, ax_leg in rows:
            means = [np.mean(line.get_ydata()) for line in ax_w.get_lines()]
            assert max(means) / min(means) < plots.LEVEL_RATIO    # nothing squashed
            labels = _legend_labels(ax_leg)
            assert not ax_leg.axison
            assert ax_wz.get_title() == 'speed, zoom' and ax_tz.get_title() == 'torque, zoom'
            assert len(labels) == len(set(labels))
            # every line of the row (speed lines, + engine/load torque) in the legend, once
            shaft_lines = {ln.get_label() for ln in ax_w.get_lines()}
            torque_only = [ln for ln in ax_t.get_lines() if ln.get_label() not in shaft_lines]
            assert len(labels) == len(ax_w.get_lines()) + len(torque_only)
            assert [_name(lb) for lb in labels[:len(ax_w.get_lines())]] == \
                [ln.get_label() for ln in ax_w.get_lines()]
            for ax in (ax_w, ax_t):
                assert not [ln for ln in ax.get_lines() if ln.get_label().startswith('_')]
                assert 'rad/s' in ax.get_ylabel() or 'N m' in ax.get_ylabel()
            for ln in ax_w.get_lines():
                styles.add((to_rgba(ln.get_color()), ln.get_linestyle(), ln.get_linewidth()))
            all_labels += labels
        n = len(sig.joint_names)
        assert len(styles) == n                                 # 18 series, 18 distinct styles
        assert len(all_labels) == n + 2 == len(set(all_labels))  # + engine and load torque
        assert {'dup [column 1]', 'dup [column 2]'} <= {_name(lb) for lb in all_labels}
        assert 'gear_input (= hooke_output)' in all_labels       # coincident curve says so
        assert all(a.get_xlabel() == 'simulated time  [s]' for a in rows[1][:4])
        assert 'seed' not in fig.get_suptitle()
    finally:
        plt.close(fig)


def _nonuniformity(sig: BagSignals, report: dict[str, Any]) -> Any:
    return plots.nonuniformity_figure(sig, sig.t >= report['window']['start_s'])


def _joint_axes(fig: Any, joint: str) -> tuple[Any, Any]:
    g = [a for a in fig.axes if a.get_title().startswith(f'{joint}: geometric')]
    k = [a for a in fig.axes if a.get_title().startswith(f'{joint}: kinematic')]
    assert len(g) == 1 and len(k) == 1
    return g[0], k[0]


def test_nonuniformity_rows_folded_and_legends_complete(sig_report) -> None:
    sig, report = sig_report
    fig = _nonuniformity(sig, report)
    try:
        speed_axes = [a for a in fig.axes if a.get_title().startswith('Speed deviation')]
        assert len(speed_axes) == 2 and len(fig.axes) == 2 + 2 * 2      # 2 levels, 2 joints x 2
        labels = []
        for ax in speed_axes:
            lines = ax.get_lines()
            leg = _legend_labels(ax)
            assert len(leg) == len(lines) == len(set(leg))
            for ln in lines:                   # one curve over one revolution, no scribble
                x = np.asarray(ln.get_xdata(), dtype=float)
                assert x.size <= 73 and np.all(np.diff(x) > 0) and 0.0 <= x[0] and x[-1] <= 360.0
            labels += [_name(lb) for lb in leg]
        assert sorted(labels) == sorted(plots.shaft_labels(sig.joint_names))
        # the engine's 2nd-order ripple: w/w_rev - 1 = 0.4 % cos(2 phi) (w_rev = W_ENGINE exactly,
        # see test_revolution_mean_speed_closed_form); 5 deg grid, linear interpolation of a
        # sampled (2.6 deg/sample) cosine: amplitude error < 1 %; bound 5 %
        crank = [ln for ln in speed_axes[0].get_lines() if ln.get_label() == 'engine_crank'][0]
        y = np.asarray(crank.get_ydata())
        assert 0.5 * (np.max(y) - np.min(y)) == pytest.approx(0.4, rel=0.05)
    finally:
        plt.close(fig)


def test_nonuniformity_hooke_matches_closed_form_and_gear_is_uniform(sig_report) -> None:
    sig, report = sig_report
    fig = _nonuniformity(sig, report)
    try:
        ax_g, ax_k = _joint_axes(fig, 'hooke')
        y = np.asarray(ax_g.get_lines()[0].get_ydata())          # mrad
        # 1 deg grid interpolated from 2.6 deg samples: relative error of the peaks
        # ~ (2 x 0.046 rad)^2 / 8 = 1e-3; bound 1e-2
        assert (np.max(y) - np.min(y)) / 1e3 == pytest.approx(hooke_geometric_peak_to_peak(), rel=1e-2)
        lo, hi = ax_g.get_ylim()
        assert hi - lo < 1.5 * (np.max(y) - np.min(y))            # the curve fills its axis
        yk = np.asarray(ax_k.get_lines()[0].get_ydata())
        c = math.cos(BETA)                                        # speed ratio c .. 1/c
        assert np.max(yk) - np.min(yk) == pytest.approx(1 / c - c, rel=1e-2)
        for ax in _joint_axes(fig, 'gear'):
            _assert_uniform(ax)
    finally:
        plt.close(fig)


def _assert_uniform(ax: Any) -> None:
    """Flat line at 0, y-limits +-1 display unit (not stretched to the noise), 'uniform' said."""
    assert all(np.all(np.asarray(ln.get_ydata()) == 0.0) for ln in ax.get_lines())
    lo, hi = ax.get_ylim()
    assert hi - lo >= 2.0
    assert any(t.get_text().startswith('uniform') for t in ax.texts)
    assert _legend_labels(ax)[0].endswith('uniform')


def test_rounding_noise_is_drawn_flat_not_stretched() -> None:
    # +-1e-12 rad on the gear output angle: 1000x below UNIFORM_FLOOR, the level of rounding
    # noise seen in recorded bags (fwd_halfshaft gear: 2.8e-14 rad peak-to-peak)
    sig = synthetic_signals(gear_noise_rad=1e-12)
    report = analyze_signals(sig, skip_fraction=0.25)
    fig = _nonuniformity(sig, report)
    try:
        ax_g, ax_k = _joint_axes(fig, 'gear')
        _assert_uniform(ax_g)
    finally:
        plt.close(fig)
    # ... while 1e-6 rad (1000x above the floor) is drawn as it is
    sig = synthetic_signals(gear_noise_rad=1e-6)
    fig = _nonuniformity(sig, analyze_signals(sig, skip_fraction=0.25))
    try:
        ax_g, _ = _joint_axes(fig, 'gear')
        assert not ax_g.texts and np.ptp(ax_g.get_lines()[0].get_ydata()) > 0.0
    finally:
        plt.close(fig)


def test_harmonics_every_series_labelled_once_and_centred_on_its_orders(sig_report) -> None:
    sig, report = sig_report
    fig = plots.harmonics_figure(sig, report, sig.t >= report['window']['start_s'])
    try:
        ax_b, *level_axes = fig.axes
        marks = [ln for ln in ax_b.get_lines() if not ln.get_label().startswith('_')]
        bar_labels = _legend_labels(ax_b)
        assert len(bar_labels) == len(marks) == len(set(bar_labels)) > 10
        faces = {(to_rgba(m.get_color()), m.get_marker()) for m in marks}
        assert len(faces) == len(marks)                          # distinct beyond ten series
        # every amplitude sits exactly on its order (x = k), and its stem with it
        orders = report['shafts']['engine_crank']['torque_harmonics']['orders']
        for m in marks:
            assert list(m.get_xdata()) == [float(k) for k in orders]
        for coll in ax_b.collections:
            xs = {float(seg[0][0]) for seg in coll.get_segments()} | \
                {float(seg[1][0]) for seg in coll.get_segments()}
            assert xs <= {float(k) for k in orders}
        # the engine torque's 10 N m cos(2 phi): the order-2 marker at (2, 10)
        crank = [m for m in marks if m.get_label().startswith('engine_crank (')][0]
        assert crank.get_ydata()[orders.index(2)] == pytest.approx(10.0, rel=1e-2)
        assert 'seed' not in ax_b.get_title() and 'Davidbaev et al. 2023' in ax_b.get_title()
        names = []
        for ax in level_axes:
            leg = _legend_labels(ax)
            assert len(leg) == len(ax.get_lines()) == len(set(leg))
            names += [ln.get_label() for ln in ax.get_lines()]
        # every oscillating series of the chart has its revolution curve, once
        assert sorted(names) == sorted(lb.split(' (mean')[0] for lb in bar_labels)
    finally:
        plt.close(fig)


def test_envelope_of_a_dense_ripple_and_its_bins() -> None:
    # 50 + 3 sin(2 pi 66 t) sampled at 1 kHz over 4 s: every bin of >= one period (20 bins
    # here: 0.2 s each) spans the ripple, so min/max are 50 -+ 3 within the sampling's
    # phase error 1 - cos(pi 66/1000) = 2 % of 3; the mean of whole periods is 50
    t = np.arange(0.0, 4.0, 1e-3)
    y = 50.0 + 3.0 * np.sin(2 * math.pi * 66.0 * t)
    tc, mean, lo, hi = plots.envelope(t, y, 20)
    assert tc.size == 20 and np.all(np.diff(tc) > 0)
    assert np.allclose(lo, 47.0, atol=0.1) and np.allclose(hi, 53.0, atol=0.1)
    assert np.allclose(mean, 50.0, atol=0.1)
    assert plots.envelope(t[:30], y[:30], 20)[0].size == 30          # short: the samples
    # bins: one per whole revolution of the fastest shaft (3.999 s x 20 rev/s -> 79, each
    # bin >= one revolution), capped; below ENVELOPE_MIN_REVOLUTIONS (3.999 s x 5 rev/s =
    # 20 - 0.005) every sample is drawn
    assert plots.envelope_bins(t, np.array([2 * math.pi * 20.0, 1.0])) == 79
    assert plots.envelope_bins(t, np.array([2 * math.pi * 5.0, 1.0])) == 0
    assert plots.envelope_bins(t, np.array([1e4])) == plots.ENVELOPE_BINS


def internal_signals() -> BagSignals:
    """A tripod (spider) and a Rzeppa (cage) between two ~100 rad/s shafts: the cage swings
    +-3.4 rad/s, the shafts 0.05 rad/s; members carry no torque."""
    t = np.arange(0.0, 2.0, 1e-3)
    w = 100.0 + 0.05 * np.cos(200.0 * t)
    cage = 100.0 + 3.4 * np.cos(200.0 * t)
    phi = np.cumsum(w) * 1e-3
    names = ['tripod_input', 'tripod_spider', 'tripod_output', 'rzeppa_input', 'rzeppa_cage',
             'rzeppa_output']
    vel = np.column_stack([w, w, w, w, cage, w])
    effort = np.column_stack([50 + np.sin(phi)] * 6)
    effort[:, 1] = effort[:, 4] = 0.0
    return BagSignals(path=Path('members/bag'), joint_names=names, t=t,
                      position=np.column_stack([phi] * 6), velocity=vel, effort=effort)


def test_internal_members_on_their_own_axes_not_on_the_torque_axis() -> None:
    sig = internal_signals()
    assert plots.internal_members(sig) == ['tripod_spider', 'rzeppa_cage']
    fig = plots.speeds_torques_figure(sig, 0.5)
    try:
        torque_axes = [a for a in fig.axes if a.axison and a.get_ylabel() == 'torque  [N m]']
        on_torque = {ln.get_label() for a in torque_axes for ln in a.get_lines()}
        assert on_torque and not on_torque & {'tripod_spider', 'rzeppa_cage'}
        speed_axes = [a for a in fig.axes if a.get_ylabel() == 'speed  [rad/s]']
        by_axis = [{ln.get_label() for ln in a.get_lines()} for a in speed_axes]
        # the members on axes of their own (the cage's swing 68x the spider's: one each)
        assert {'tripod_spider'} in by_axis and {'rzeppa_cage'} in by_axis
        shafts = [s for s in by_axis if 'tripod_input' in s][0]
        assert not shafts & {'tripod_spider', 'rzeppa_cage'}
        # the shafts' axis spans their own swing, not the cage's +-3.4 rad/s
        ax = speed_axes[by_axis.index(shafts)]
        assert np.ptp(ax.get_ylim()) < 0.5
        labels = [lb for a in fig.axes for lb in _legend_labels(a)]
        assert not [lb for lb in labels if 'torque =' in lb]
    finally:
        plt.close(fig)
    fig = plots.speeds_torques_figure(sig, 0.5, internal=False)
    try:
        drawn = {ln.get_label() for a in fig.axes for ln in a.get_lines()}
        assert not drawn & {'tripod_spider', 'rzeppa_cage'}
        assert 'not drawn (internal members): tripod_spider, rzeppa_cage' in fig.get_suptitle()
    finally:
        plt.close(fig)


def test_write_analysis_plots_writes_three_pngs(sig_report, tmp_path: Path) -> None:
    sig, report = sig_report
    paths = plots.write_analysis_plots(sig, report, tmp_path)
    assert sorted(p.name for p in paths) == ['harmonics.png', 'nonuniformity.png', 'speeds_torques.png']
    assert all(p.read_bytes()[:4] == b'\x89PNG' for p in paths)
    assert not plt.get_fignums()                                 # all figures closed


def test_speed_ripple_below_solver_rtol_is_uniform_and_ideal_joint_named() -> None:
    # 1e-8 relative speed ripple under a scene run with rtol 1e-6: 100x below what the
    # integrator resolves -> flat, "uniform (below the solver rtol)"; the ideal joint's panels
    # name the model that makes it uniform
    t = np.arange(0.0, 1.0, 1e-3)
    phi = 100.0 * t + 1e-8 * np.sin(100.0 * t)
    w = 100.0 * (1.0 + 1e-8 * np.cos(100.0 * t))
    sig = BagSignals(path=Path('tiny/bag'), joint_names=['j_input', 'j_output'], t=t,
                     position=np.column_stack([phi, phi]), velocity=np.column_stack([w, w]),
                     effort=np.ones((t.size, 2)))
    sig.scene_yaml = 'solver: {method: dopri5, rtol: 1.0e-6}\nfidelity: {choices: [{name: j, chosen: ideal}]}\n'
    assert plots.scene_settings(sig) == (1e-6, {'j': 'ideal'})
    fig = plots.nonuniformity_figure(sig, t >= 0.25)
    try:
        ax_s = fig.axes[0]
        assert np.all(ax_s.get_lines()[0].get_ydata() == 0.0) and ax_s.get_ylim() == (-1.0, 1.0)
        assert 'below the solver rtol' in ax_s.texts[0].get_text()
        ax_g, ax_k = _joint_axes(fig, 'j')
        assert ax_g.get_title().endswith('ideal model') and 'ideal model' in ax_g.texts[0].get_text()
    finally:
        plt.close(fig)
    sig.scene_yaml = None                      # no scene recorded: the rounding floor applies
    assert plots.scene_settings(sig) == (None, {})
    fig = plots.nonuniformity_figure(sig, t >= 0.25)
    try:
        assert np.ptp(fig.axes[0].get_lines()[0].get_ydata()) > 0.0 and not fig.axes[0].texts
    finally:
        plt.close(fig)


def test_standing_reversing_and_nan_shafts_still_plot_with_complete_legends(tmp_path: Path) -> None:
    # a shaft at rest, one reversing mid-window (no revolution in one direction), one with a
    # NaN sample: every figure is written and every shaft is in a legend exactly once
    t = np.arange(0.0, 1.0, 1e-3)
    w_rev = 20.0 * np.cos(math.pi * t)
    pos = np.column_stack([0 * t, 20.0 / math.pi * np.sin(math.pi * t), 50.0 * t])
    vel = np.column_stack([0 * t, w_rev, 50.0 + 0 * t])
    vel[500, 2] = np.nan
    sig = BagSignals(path=Path('edge/bag'), joint_names=['rest', 'reverse', 'nan'], t=t,
                     position=pos, velocity=vel, effort=np.column_stack([0 * t, np.sin(pos[:, 1]), 0 * t]))
    report = analyze_signals(sig, skip_fraction=0.25)
    paths = plots.write_analysis_plots(sig, report, tmp_path)
    assert {p.name for p in paths} >= {'speeds_torques.png', 'nonuniformity.png'}
    for fig in (plots.speeds_torques_figure(sig, report['window']['start_s']),
                plots.nonuniformity_figure(sig, t >= report['window']['start_s'])):
        try:
            labels = [lb for ax in fig.axes for lb in _legend_labels(ax)]
            assert sorted(_name(lb) for lb in labels) == ['nan', 'rest', 'reverse']
        finally:
            plt.close(fig)


def test_small_deviation_gets_its_own_axis_at_the_same_speed() -> None:
    # two shafts at 100 rad/s, 2nd-order ripple 1e-3 and 1e-5 (100x apart > AMPLITUDE_RATIO):
    # two speed-deviation axes, each curve filling its own
    t = np.arange(0.0, 1.0, 1e-3)
    cols = [(100.0 * t + a / 2 * np.sin(200.0 * t), 100.0 * (1 + a * np.cos(200.0 * t))) for a in (1e-3, 1e-5)]
    sig = BagSignals(path=Path('two/bag'), joint_names=['big', 'small'], t=t,
                     position=np.column_stack([c[0] for c in cols]),
                     velocity=np.column_stack([c[1] for c in cols]), effort=np.ones((t.size, 2)))
    fig = plots.nonuniformity_figure(sig, t >= 0.25)
    try:
        assert len(fig.axes) == 2 and '(1 of 2' in fig.axes[0].get_title()
        for ax, name, amp in zip(fig.axes, ('big', 'small'), (1e-3, 1e-5)):
            (line,) = ax.get_lines()
            assert line.get_label() == name
            # folded mean of 100 a cos(2 phi) [%]: 5 deg grid from 1.1 deg samples, error
            # < 1e-3 relative; bound 2 %
            assert 0.5 * np.ptp(line.get_ydata()) == pytest.approx(100 * amp, rel=0.02)
    finally:
        plt.close(fig)


def test_simulate_plots_offline(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                monkeypatch: pytest.MonkeyPatch) -> None:
    # `cvj-sim simulate --plots`: the analysis figures of an offline trace (no bag, no ROS);
    # --no-internal-members reaches the figure (the lever-hinge's earring left out)
    import json

    from cvj_ros.cli import main
    titles: list[str] = []
    figure = plots.speeds_torques_figure

    def spy(*a: Any, **k: Any) -> Any:
        fig = figure(*a, **k)
        titles.append(fig.get_suptitle())
        return fig
    monkeypatch.setattr(plots, 'speeds_torques_figure', spy)
    out = tmp_path / 'png'
    assert main(['simulate', 'kavz685_lever', '--duration', '0.6', '--backend', 'python',
                 '--json', '--plots', str(out), '--no-internal-members']) == 0
    assert len(titles) == 1 and 'not drawn (internal members): coupling_earring' in titles[0]
    summary = json.loads(capsys.readouterr().out)
    assert sorted(Path(p).name for p in summary['plots']) == \
        ['harmonics.png', 'nonuniformity.png', 'speeds_torques.png']
    assert all((out / n).read_bytes()[:4] == b'\x89PNG' for n in ('speeds_torques.png', 'nonuniformity.png'))


def test_work_precision_key_names_methods_fidelities_and_runs_once(tmp_path, monkeypatch) -> None:
    """The work-precision figure's key has one entry per method, fidelity and kind of run
    (not one per line: a full bench draws ~50), outside the axes."""
    from cvj_ros import plots
    kept = []
    monkeypatch.setattr(plots.plt, 'close', kept.append)
    rows = []
    for solver, fam, fid, breaks, sampling in (
            ('dopri5', 'project', 'exact', True, 'land'), ('dopri5', 'project', 'exact', False, 'land'),
            ('dopri5', 'project', 'ideal', True, 'dense'), ('rodas4', 'project', 'auto', True, 'land'),
            ('LSODA', 'baseline', 'exact', True, None), ('LSODA', 'baseline_compiled', 'exact', True, None)):
        label = f'{solver} {fam} {fid} {breaks} {sampling}'
        for k, tol in enumerate((1e-3, 1e-6)):
            rows.append({'scene': 's', 'family': fam, 'solver': solver, 'fidelity': fid, 'tol': tol,
                         'h': None, 'breakpoints': breaks, 'sampling': sampling, 'label': label,
                         'err_speed_rel': tol * (2 + k), 'wall_per_sim_s': 1e-3 / tol ** 0.1})
    plots.work_precision_plot(rows, scene='s', path=tmp_path / 'wp.png')
    assert (tmp_path / 'wp.png').stat().st_size > 10_000
    (fig,) = kept
    ax = fig.axes[0]
    assert len(ax.get_lines()) == 6 + 2          # six series and the two level markers
    texts = [t.get_text() for t in ax.get_legend().get_texts()]
    for want in ('colour: method', 'dopri5', 'rodas4', 'solve_ivp LSODA', 'marker: fidelity',
                 'exact', 'auto', 'ideal', 'solve_ivp', 'line: run', 'project, landing',
                 'project, across breakpoints', 'project, dense sampling',
                 'solve_ivp, Python rhs', 'solve_ivp, compiled rhs'):
        assert texts.count(want) == 1, (want, texts)
    assert 'closed' not in texts                  # no closed-fidelity series here
    assert ax.get_legend().get_bbox_to_anchor().x0 > ax.get_window_extent().x1 - 1


def test_two_wheels_draw_their_own_torques_not_the_summed_load_as_one_wheels() -> None:
    # a vehicle's load is the tyres of every wheel: its sum (here 2 x 100 N m) is not drawn
    # as "load torque on wheel_right"; each wheel's shaft torque is, and the title says so
    t = np.arange(0.0, 1.0, 1e-3)
    phi = 30.0 * t
    sig = BagSignals(path=Path('axle/bag'), joint_names=['engine_crank', 'wheel_left', 'wheel_right'],
                     t=t, position=np.column_stack([4 * phi, phi, phi]),
                     velocity=np.column_stack([120.0 + 0 * t, 30.0 + 0 * t, 30.0 + 0 * t]),
                     effort=np.column_stack([50 + 5 * np.cos(8 * phi), 100 + np.cos(phi), 100 + np.cos(phi)]))
    sig.engine_t, sig.engine_torque = t, 50 + 5 * np.cos(8 * phi)
    sig.load_t, sig.load_torque = t, 200 + 2 * np.cos(phi)
    report = analyze_signals(sig, skip_fraction=0.25)
    figs = [plots.speeds_torques_figure(sig, report['window']['start_s']),
            plots.harmonics_figure(sig, report, t >= report['window']['start_s'])]
    try:
        labels = [lb for f in figs for ax in f.axes for lb in _legend_labels(ax)]
        assert not [lb for lb in labels if lb.startswith(('load torque', 'load wrench'))]
        assert {'wheel_left', 'wheel_right'} <= {_name(lb) for lb in labels}
        assert 'the tyres of 2 wheels' in figs[0].get_suptitle()
    finally:
        for f in figs:
            plt.close(f)


def test_work_precision_draws_the_numbalsoda_family_apart(tmp_path, monkeypatch) -> None:
    """baseline_expert rows (numbalsoda on the compiled rhs) get their own colour per method
    (not the project's dop853), triangles, and their two kinds of run in the key."""
    from cvj_ros import plots
    kept = []
    monkeypatch.setattr(plots.plt, 'close', kept.append)
    rows = []
    for solver, fam, breaks in (('dop853', 'project', True), ('dop853', 'baseline_expert', False),
                                ('dop853', 'baseline_expert', True)):
        label = f'{solver} {fam} {breaks}'
        for k, tol in enumerate((1e-3, 1e-6)):
            rows.append({'scene': 's', 'family': fam, 'solver': solver, 'fidelity': 'exact', 'tol': tol,
                         'h': None, 'breakpoints': breaks, 'sampling': 'land', 'label': label,
                         'err_speed_rel': tol * (2 + k), 'wall_per_sim_s': 1e-3 / tol ** 0.1})
    plots.work_precision_plot(rows, scene='s', path=tmp_path / 'wp.png')
    (fig,) = kept
    ax = fig.axes[0]
    texts = [t.get_text() for t in ax.get_legend().get_texts()]
    for want in ('dop853', 'numbalsoda dop853', 'numbalsoda', 'numbalsoda, compiled rhs',
                 'numbalsoda, restart at knots', 'project, landing'):
        assert texts.count(want) == 1, (want, texts)
    series = ax.get_lines()[:3]
    assert sorted(ln.get_marker() for ln in series) == ['^', '^', 'o']
    colours = {ln.get_marker() + str(ln.get_linestyle()): ln.get_color() for ln in series}
    assert len(set(colours.values())) == 2


def test_work_precision_draws_no_energy_runs_thin_and_baselines_on_top(tmp_path, monkeypatch) -> None:
    """Project runs without the work integrals (energy 'off') are thinner than the same
    configuration with them and named once in the key; baseline lines lie above the
    project's (zorder), numbalsoda's triangles edged in black."""
    from cvj_ros import plots
    kept = []
    monkeypatch.setattr(plots.plt, 'close', kept.append)
    rows = []
    for solver, fam, energy in (('dop853', 'project', 'on'), ('dop853', 'project', 'off'),
                                ('dop853', 'baseline_expert', ''), ('LSODA', 'baseline', '')):
        label = f'{solver} {fam} {energy}'
        for k, tol in enumerate((1e-3, 1e-6)):
            rows.append({'scene': 's', 'family': fam, 'solver': solver, 'fidelity': 'exact', 'tol': tol,
                         'h': None, 'breakpoints': False if fam == 'baseline_expert' else True,
                         'sampling': 'land', 'label': label, 'energy': energy,
                         'err_speed_rel': tol * (2 + k), 'wall_per_sim_s': 1e-3 / tol ** 0.1})
    plots.work_precision_plot(rows, scene='s', path=tmp_path / 'wp.png')
    (fig,) = kept
    ax = fig.axes[0]
    texts = [t.get_text() for t in ax.get_legend().get_texts()]
    assert texts.count('project, no work integrals (thin)') == 1
    by_marker: dict[str, list] = {}
    for ln in ax.get_lines()[:4]:
        by_marker.setdefault(ln.get_marker(), []).append(ln)
    on, off = sorted(by_marker['o'], key=lambda ln: -ln.get_linewidth())
    assert off.get_linewidth() < on.get_linewidth()
    (expert,) = by_marker['^']
    (solve_ivp,) = by_marker['s']
    assert expert.get_markeredgecolor() == 'k'
    assert min(expert.get_zorder(), solve_ivp.get_zorder()) > max(on.get_zorder(), off.get_zorder())
