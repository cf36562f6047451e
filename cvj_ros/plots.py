"""PNG figures of an analysed bag and of the work-precision benchmark (matplotlib, Agg backend).

Analysis figures (:func:`write_analysis_plots`), one row per speed level (:func:`speed_levels`):
``speeds_torques.png`` (speed and torque of every shaft over time, the skipped start transient
shaded), ``nonuniformity.png`` (speed deviation over the shaft's own angle relative to its
revolution mean, joint geometric and kinematic nonuniformity over input angle, Bugaru & Vasile 2021, all
folded to one revolution: mean line and min-max band; peak-to-peak below a stated floor drawn
flat and called "uniform"), ``harmonics.png`` (torque harmonic amplitudes per order, and the
torque over one revolution with its truncated Fourier series, Davidbaev et al. 2023, eqs. 4.1-4.3).
Each figure function returns the matplotlib Figure so tests can inspect it; docs/analysis.md
describes what each panel shows.
Benchmark figures: :func:`work_precision_plot` (log-log error vs cost, one line per solver).
"""
from __future__ import annotations

import math
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use('Agg')
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from cvj_ros.analysis import BagSignals, engine_shaft, joint_pairs, load_shaft  # noqa: E402
from cvj_ros.physics import signal  # noqa: E402

_STYLE = {'figure.dpi': 110, 'axes.grid': True, 'grid.alpha': 0.3, 'axes.titlesize': 11,
          'axes.labelsize': 10, 'legend.fontsize': 8, 'font.size': 9}


# -- series styles, labels and speed levels --------------------------------------------------

_COLORS = tuple(plt.get_cmap('tab10').colors)
# the work-precision figure's methods (13-14 with numbalsoda and solve_ivp): tab10, then six
# colours unlike any of it (black, plum, periwinkle, mustard, maroon, pale olive)
_METHOD_COLORS = _COLORS + ('#000000', '#7b4173', '#6b6ecf', '#e7ba52', '#843c39', '#b5cf6b')
_LINESTYLES = ('-', '--', '-.', ':')
_HATCHES = ('', '////', '....', 'xxxx')
_MARKERS = ('o', 's', '^', 'D', 'v', 'P', 'X', '*', '<', '>')
#: the harmonic chart (log amplitude) shows four decades below its largest amplitude: orders
#: a joint does not excite sit at round-off or load noise below that.
HARMONIC_DECADES_FLOOR = 1e-4
#: peak-to-peak below which a deviation is drawn flat and called "uniform". Rounding noise of
#: the recorded angles is eps * |phi| ~ 2.2e-16 * 1e3 rad = 2e-13 rad for a 1000 rad unwrapped
#: angle (the shipped scenes reach ~700 rad), of a speed ratio ~1e-16 relative (seen: 1.1e-11
#: mrad and 2.2e-16 on the gear of fwd_halfshaft): 1e-9 is >= 5000x above both and 1e5x below
#: the smallest physical nonuniformity plotted (tripod 15 deg, r/l 0.11: ~2.5e-4 rad).
UNIFORM_FLOOR = 1e-9
#: two shafts share a speed level (one axis) when their mean speeds differ by less than this
#: factor: a gear or final drive (ratios ~3-6 in the shipped scenes) starts a new level.
LEVEL_RATIO = 1.5


def series_style(i: int) -> dict[str, Any]:
    """Line style of series ``i``: ten colours x four line styles, unique for 40 series (then the
    width grows so pairs stay distinct up to 160)."""
    return {'color': _COLORS[i % 10], 'ls': _LINESTYLES[(i // 10) % 4], 'lw': 1.2 + 0.7 * (i // 40)}


def marker_of(i: int) -> str:
    """Marker of series ``i``: with its colour (:func:`series_style`) unique for 100 series."""
    return _MARKERS[(i + i // 10) % len(_MARKERS)]


def bar_style(i: int) -> dict[str, Any]:
    """Bar style of series ``i``: ten colours x four hatches (unique for 40 series)."""
    return {'color': _COLORS[i % 10], 'hatch': _HATCHES[(i // 10) % 4], 'edgecolor': 'white',
            'linewidth': 0.0}


def shaft_labels(names: Sequence[str]) -> list[str]:
    """Legend labels of the joint-state columns: the name, with ``[column k]`` appended to
    every column whose name occurs more than once (so no two legend entries read the same)."""
    return [f'{n} [column {k}]' if names.count(n) > 1 else n for k, n in enumerate(names)]


def speed_levels(mean_speeds: Sequence[float], *, ratio: float = LEVEL_RATIO,
                 rest_fraction: float = 1e-6) -> list[list[int]]:
    """Group shaft indices by speed level, fastest level first.

    Shafts whose |mean speed| is below ``rest_fraction`` x the largest form one "at rest" level
    (last); the others are split by sign, sorted by |mean speed|, and a new level starts where
    the next |mean speed| exceeds the previous one by more than ``ratio``. Each level is one
    axis of the figures, so ~42 rad/s shafts are not squashed under ~230 rad/s ones.
    """
    w = np.asarray(mean_speeds, dtype=float)
    w = np.where(np.isfinite(w), w, 0.0)
    scale = float(np.max(np.abs(w))) if w.size else 0.0
    at_rest = [i for i in range(w.size) if abs(w[i]) <= rest_fraction * scale]
    levels: list[list[int]] = []
    for sign in (1.0, -1.0):
        idx = sorted((i for i in range(w.size) if i not in at_rest and np.sign(w[i]) == sign),
                     key=lambda i: abs(w[i]))
        group: list[int] = []
        for i in idx:
            if group and abs(w[i]) > ratio * abs(w[group[-1]]):
                levels.append(group)
                group = []
            group.append(i)
        if group:
            levels.append(group)
    levels.sort(key=lambda g: -max(abs(w[i]) for i in g))
    if at_rest:
        levels.append(at_rest)
    return [sorted(g) for g in levels]


#: within a speed level, a shaft whose speed deviation (peak-to-peak) is more than this factor
#: smaller than the largest of its axis gets the next axis: drawn together it would fill less
#: than a tenth of the height (fwd_halfshaft, exact Rzeppa: cage 17 % vs 0.2-3 % for the rest).
AMPLITUDE_RATIO = 10.0


def amplitude_groups(peak_to_peak: Sequence[float], *, ratio: float = AMPLITUDE_RATIO,
                     floor: float = UNIFORM_FLOOR) -> list[list[int]]:
    """Split indices into groups drawn on one axis each, largest deviations first: a group
    holds every value >= its largest / ``ratio``; values below ``floor`` (drawn flat) join
    the last group."""
    v = [float(x) if math.isfinite(x) else 0.0 for x in peak_to_peak]
    groups: list[list[int]] = []
    flat = [i for i in range(len(v)) if v[i] < floor]
    for i in sorted((i for i in range(len(v)) if v[i] >= floor), key=lambda i: -v[i]):
        if groups and v[i] * ratio >= v[groups[-1][0]]:
            groups[-1].append(i)
        else:
            groups.append([i])
    if flat:
        if groups:
            groups[-1] += flat
        else:
            groups.append(flat)
    return [sorted(g) for g in groups]


#: a time series of more than 2 x ENVELOPE_BINS samples is drawn as its min/max envelope
#: (band) with the bin mean (line) instead of every sample: at most ENVELOPE_BINS bins, about
#: two pixels each on the ~650 px wide time axes, and no bin shorter than one revolution of
#: the fastest shaft (:func:`envelope_bins`), so a ripple of any order of it fills each bin's
#: min-max instead of beating against the bin width.
ENVELOPE_BINS = 320
#: records of fewer revolutions of the fastest shaft are drawn sample by sample: a 3rd-order
#: ripple then has < 60 periods on the ~650 px axis, > 10 px each, readable as drawn
#: (kavz685_lever: 12 revolutions; tripod_xiu2024's 33 revolutions of 3rd order fill a band).
ENVELOPE_MIN_REVOLUTIONS = 20
#: the zoom columns show the last ZOOM_REVOLUTIONS revolutions of the fastest shaft (the
#: engine: 4 periods of a 4-cylinder's 2nd-order firing ripple), at least ZOOM_MIN_SAMPLES
#: samples.
ZOOM_REVOLUTIONS = 2.0
ZOOM_MIN_SAMPLES = 40


def internal_members(sig: BagSignals) -> list[str]:
    """Joint-state names of the joints' internal members: a ``<joint>_<member>`` column
    between ``<joint>_input`` and ``<joint>_output`` (the order the driveline records them:
    Rzeppa cage, tripod spider, lever-hinge earring, double-cardan yoke). They turn with the
    joint and carry no line torque of their own (effort 0 in the record)."""
    names = sig.joint_names
    found: list[str] = []
    for joint, n_in, n_out in joint_pairs(names):
        i, o = names.index(n_in), names.index(n_out)
        found += [n for n in names[i + 1:o] if n.startswith(joint + '_') and n not in found]
    return found


def envelope(t: np.ndarray, y: np.ndarray, n_bins: int = ENVELOPE_BINS
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Min/max envelope of ``y`` over ``t`` in ``n_bins`` bins of equal sample count: (bin
    centre time, bin mean, bin min, bin max), NaN samples ignored. With at most 2 ``n_bins``
    samples, the samples themselves (mean = min = max = y)."""
    t = np.asarray(t, dtype=float)
    y = np.asarray(y, dtype=float)
    if t.size <= 2 * n_bins:
        return t, y, y, y
    edges = np.linspace(0, t.size, n_bins + 1).round().astype(np.int64)
    tc, mean, lo, hi = (np.empty(n_bins) for _ in range(4))
    with np.errstate(all='ignore'), warnings.catch_warnings():
        warnings.simplefilter('ignore', RuntimeWarning)
        for k in range(n_bins):
            s = y[edges[k]:edges[k + 1]]
            tc[k] = 0.5 * (t[edges[k]] + t[edges[k + 1] - 1])
            mean[k], lo[k], hi[k] = np.nanmean(s), np.nanmin(s), np.nanmax(s)
    return tc, mean, lo, hi


def envelope_bins(t: np.ndarray, means: np.ndarray, cap: int = ENVELOPE_BINS) -> int:
    """Number of envelope bins over ``t``: one per whole revolution of the fastest shaft
    (largest finite |mean speed|), at most ``cap``; 0 (draw every sample) below
    :data:`ENVELOPE_MIN_REVOLUTIONS` revolutions or without a turning shaft."""
    w = np.abs(means[np.isfinite(means)])
    top = float(np.max(w)) if w.size else 0.0
    dur = float(t[-1] - t[0]) if t.size > 1 else 0.0
    revs = dur * top / (2 * math.pi)
    return 0 if revs < ENVELOPE_MIN_REVOLUTIONS else int(min(cap, revs))


def _draw_series(ax: Any, t: np.ndarray, y: np.ndarray, style: dict[str, Any], label: str,
                 n_bins: int = ENVELOPE_BINS) -> Any:
    """Draw ``y`` over ``t``: every sample (``n_bins`` 0, or few samples), or its
    :func:`envelope` (band) with the bin mean (line). Returns the legend handle (line, or (line, band))."""
    tc, mean, lo, hi = envelope(t, y, n_bins) if n_bins > 0 else (t, y, y, y)
    line, = ax.plot(tc, mean, label=label, **style)
    if tc.size == t.size:
        return line
    band = ax.fill_between(tc, lo, hi, color=style.get('color'), alpha=0.18, lw=0)
    return (line, band)


def zoom_window(sig: BagSignals, means: np.ndarray, *, revolutions: float = ZOOM_REVOLUTIONS,
                min_samples: int = ZOOM_MIN_SAMPLES) -> tuple[float, float]:
    """(start, end) [s] of the zoom columns: the last ``revolutions`` revolutions of the
    fastest shaft, at least ``min_samples`` samples, at most the whole record."""
    t = sig.t
    w = np.abs(means[np.isfinite(means)]) if means.size else np.zeros(0)
    top = float(np.max(w)) if w.size else 0.0
    span = revolutions * 2 * math.pi / top if top > 0 else 0.0
    if t.size > 1:
        span = max(span, min_samples * float(np.median(np.diff(t))))
    start = max(float(t[0]), float(t[-1]) - span) if t.size else 0.0
    return start, float(t[-1]) if t.size else 0.0


def _level_title(mean_speeds: np.ndarray, level: list[int]) -> str:
    w = mean_speeds[level]
    if np.all(np.abs(w) <= 1e-6 * max(1e-300, float(np.max(np.abs(mean_speeds))))):
        return 'at rest'
    lo, hi = float(np.min(w)), float(np.max(w))
    return f'mean speed {lo:.3g} rad/s' if math.isclose(lo, hi, rel_tol=5e-3) else \
        f'mean speeds {lo:.3g} to {hi:.3g} rad/s'


def _steady_means(sig: BagSignals, mask: np.ndarray) -> np.ndarray:
    """Mean speed of every shaft over ``mask`` (all samples if empty), NaN samples ignored [rad/s]."""
    if not np.any(mask):
        mask = np.ones(sig.t.size, dtype=bool)
    with np.errstate(all='ignore'), warnings.catch_warnings():
        warnings.simplefilter('ignore', RuntimeWarning)   # all-NaN column -> NaN, read as at rest
        return np.nanmean(sig.velocity[mask], axis=0)


def fold_over_angle(phi: np.ndarray, y: np.ndarray, n_bins: int
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, float]:
    """Fold ``y`` over the angle ``phi`` (rad, unwrapped) into ``n_bins`` bins of one revolution.

    Where ``phi`` is monotonic the signal is first interpolated linearly onto a uniform grid of
    ``n_bins`` points per revolution (so a coarse sampling, e.g. 13 deg per sample of a
    230 rad/s shaft at 1 kHz, does not leave empty bins); otherwise the samples are binned as
    they are. Returns (bin centres in deg, mean, min, max per bin, revolutions covered); empty
    bins are NaN.
    """
    phi = np.asarray(phi, dtype=float)
    y = np.asarray(y, dtype=float)
    ok = np.isfinite(phi) & np.isfinite(y)
    phi, y = phi[ok], y[ok]
    step = 2 * math.pi / n_bins
    revs = float(abs(phi[-1] - phi[0]) / (2 * math.pi)) if phi.size else 0.0
    dphi = np.diff(phi)
    if phi.size >= 2 and (np.all(dphi > 0) or np.all(dphi < 0)):
        if dphi[0] < 0:
            phi, y = phi[::-1], y[::-1]
        k0, k1 = math.ceil(phi[0] / step), math.floor(phi[-1] / step)
        grid = np.arange(k0, k1 + 1) * step
        if grid.size >= 2:
            y = np.interp(grid, phi, y)
            phi = grid
    idx = np.mod(np.floor(np.mod(phi, 2 * math.pi) / step + 0.5).astype(np.int64), n_bins) \
        if phi.size else np.zeros(0, dtype=np.int64)
    count = np.bincount(idx, minlength=n_bins).astype(float)
    with np.errstate(invalid='ignore', divide='ignore'):
        mean = np.bincount(idx, weights=y, minlength=n_bins) / count
    lo = np.full(n_bins, np.inf)
    hi = np.full(n_bins, -np.inf)
    np.minimum.at(lo, idx, y)
    np.maximum.at(hi, idx, y)
    empty = count == 0
    mean[empty] = lo[empty] = hi[empty] = np.nan
    centres = np.degrees(np.arange(n_bins) * step)
    # close the curve at 360 deg
    return (np.append(centres, 360.0), np.append(mean, mean[0]), np.append(lo, lo[0]),
            np.append(hi, hi[0]), revs)


#: a curve within this fraction of its axis' data span of an earlier curve is drawn over it
#: (below one pixel of a ~400 px axis): its legend entry says "= <earlier>" instead.
COINCIDENT = 2e-3


def _coincident(earlier: list[tuple[str, np.ndarray]], y: np.ndarray, span: float) -> str | None:
    """Label of the first earlier curve that ``y`` covers (max |difference| <= COINCIDENT x
    ``span``, NaN where both are NaN), else None."""
    for label, e in earlier:
        if e.shape == y.shape and np.array_equal(np.isnan(e), np.isnan(y)):
            d = np.abs(e - y)
            if not d.size or float(np.nanmax(d, initial=0.0)) <= COINCIDENT * max(span, 1e-300):
                return label
    return None


def _span(arrays: Sequence[np.ndarray]) -> float:
    vals = [a[np.isfinite(a)] for a in arrays]
    vals = [v for v in vals if v.size]
    return float(max(np.max(v) for v in vals) - min(np.min(v) for v in vals)) if vals else 0.0


def revolution_mean_speed(t: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """Mean speed over the revolution centred on each sample, 2 pi / (t(phi + pi) - t(phi - pi))
    [rad/s] (signed); NaN within half a revolution of the ends or where ``phi`` is not strictly
    monotonic (then there is no "revolution" to average over)."""
    t = np.asarray(t, dtype=float)
    phi = np.asarray(phi, dtype=float)
    out = np.full(phi.shape, np.nan)
    d = np.diff(phi)
    if phi.size < 3 or not (np.all(d > 0) or np.all(d < 0)):
        return out
    sgn = 1.0 if d[0] > 0 else -1.0
    u = sgn * phi
    ok = (u - math.pi >= u[0]) & (u + math.pi <= u[-1])
    t_hi = np.interp(u[ok] + math.pi, u, t)
    t_lo = np.interp(u[ok] - math.pi, u, t)
    out[ok] = sgn * 2 * math.pi / (t_hi - t_lo)
    return out


def _peak_to_peak(y: np.ndarray) -> float:
    y = np.asarray(y, dtype=float)
    y = y[np.isfinite(y)]
    return float(np.max(y) - np.min(y)) if y.size else 0.0


def _legend(ax: Any, handles: list[Any], labels: list[str], *, outside: bool = True) -> None:
    from matplotlib.legend_handler import HandlerTuple
    kw: dict[str, Any] = {'loc': 'upper left', 'bbox_to_anchor': (1.01, 1.0)} if outside else {'loc': 'best'}
    ax.legend(handles, labels, framealpha=0.85, handler_map={tuple: HandlerTuple(ndivide=1)},
              ncol=1 if len(labels) <= 14 else 2, borderaxespad=0.0 if outside else 0.5, **kw)


def scene_settings(sig: BagSignals) -> tuple[float | None, dict[str, str]]:
    """(solver rtol, {joint or spring name: chosen fidelity}) from the scene YAML recorded in
    the bag (``/driveline/scene``); (None, {}) when absent or unreadable."""
    if not sig.scene_yaml:
        return None, {}
    import yaml
    try:
        data = yaml.safe_load(sig.scene_yaml)
    except yaml.YAMLError:
        return None, {}
    if not isinstance(data, dict):
        return None, {}
    solver = data.get('solver')
    rtol = solver.get('rtol') if isinstance(solver, dict) else None
    rtol = float(rtol) if isinstance(rtol, (int, float)) and math.isfinite(rtol) and rtol > 0 else None
    fid = data.get('fidelity')
    chosen: dict[str, str] = {}
    if isinstance(fid, dict) and isinstance(fid.get('choices'), list):
        chosen = {str(c['name']): str(c['chosen']) for c in fid['choices']
                  if isinstance(c, dict) and 'name' in c and 'chosen' in c}
    return rtol, chosen


def signals_from_trace(trace: Any, *, scene_yaml: str | None = None, label: str = 'simulate') -> BagSignals:
    """:class:`BagSignals` of an offline run (``cvj_ros.physics.simulate.Trace``: t s, position
    rad, velocity rad/s, effort N m per shaft, engine and load torque N m on the engine and
    load shafts, same sign conventions as the bag's wrenches), so ``analyze_signals`` and the
    figures work on it as on a recorded bag. ``label`` names the figures (a path-like name)."""
    t = np.asarray(trace.t, dtype=float)
    return BagSignals(path=Path(label), joint_names=list(trace.names), t=t,
                      position=np.asarray(trace.position, dtype=float),
                      velocity=np.asarray(trace.velocity, dtype=float),
                      effort=np.asarray(trace.effort, dtype=float),
                      engine_t=t, engine_torque=np.asarray(trace.engine_torque, dtype=float),
                      load_t=t, load_torque=np.asarray(trace.load_torque, dtype=float),
                      scene_yaml=scene_yaml)


def _bag_label(sig: BagSignals) -> str:
    p = sig.path if sig.path.is_dir() or not sig.path.exists() else sig.path.parent   # .mcap file: its dir
    return f'{p.parent.name}/{p.name}' if p.name == 'bag' else p.name


# -- figures ----------------------------------------------------------------------------------

def write_analysis_plots(sig: BagSignals, report: dict[str, Any], out_dir: str | Path, *,
                         internal: bool = True) -> list[Path]:
    """Write the analysis PNGs of a bag to ``out_dir`` (created); returns the file paths.
    ``internal=False`` leaves the joints' internal members out of ``speeds_torques.png``."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    t0 = report['window']['start_s']
    mask = sig.t >= t0
    paths = []
    with plt.rc_context(_STYLE):
        figures = [('speeds_torques.png', speeds_torques_figure(sig, t0, internal=internal)),
                   ('nonuniformity.png', nonuniformity_figure(sig, mask)),
                   ('harmonics.png', harmonics_figure(sig, report, mask))]
        for name, fig in figures:
            if fig is None:
                continue
            fig.savefig(out / name)
            plt.close(fig)
            paths.append(out / name)
    return paths


def speeds_torques_figure(sig: BagSignals, t0: float, *, internal: bool = True) -> Any:
    """Speed and torque over simulated time, one row per speed level (:func:`speed_levels` of
    the means from ``t0`` on), split where one shaft's speed swing (peak-to-peak from ``t0``
    on) is more than :data:`AMPLITUDE_RATIO` x another's (:func:`amplitude_groups`), so one
    swing does not flatten the others. Columns: speed, speed zoomed on the last revolutions
    (:func:`zoom_window`), torque, torque zoomed; dense series are drawn as their min/max
    envelope (:func:`envelope`). Engine and load wrench torques sit in the row of the shaft
    they act on. The joints' internal members (:func:`internal_members`, no line torque) get
    a row of their own below, or none with ``internal=False`` (the title says so). A shaft
    whose curve covers an earlier one of its row is labelled ``= <earlier>``. Returns the
    matplotlib Figure (caller saves and closes)."""
    means = _steady_means(sig, sig.t >= t0)
    members = internal_members(sig)
    member_cols = [sig.column(n) for n in members]
    shafts = [j for j in range(len(sig.joint_names)) if j not in member_cols]
    labels = shaft_labels(sig.joint_names)
    eng, load = engine_shaft(sig), load_shaft(sig)
    wheels = [n for n in sig.joint_names if n.startswith('wheel')]
    steady = sig.t >= t0 if np.any(sig.t >= t0) else np.ones(sig.t.size, dtype=bool)
    rows: list[tuple[list[int], list[int], int, bool]] = []    # (level, shafts, parts, internal)
    for group, is_member in ((shafts, False), (member_cols if internal else [], True)):
        if not group:
            continue
        for level in speed_levels(means[group]):
            level = [group[i] for i in level]
            parts = amplitude_groups([_peak_to_peak(sig.velocity[steady, j]) for j in level])
            rows += [(level, [level[i] for i in p], len(parts), is_member) for p in parts]
    z0, z1 = zoom_window(sig, means[shafts] if shafts else means)
    n_bins = envelope_bins(sig.t, means[shafts] if shafts else means)
    zoom = (sig.t >= z0) & (sig.t <= z1)
    fig = plt.figure(layout='constrained')
    gs = fig.add_gridspec(len(rows), 5)
    first: dict[int, Any] = {}
    legends: list[tuple[Any, list[Any], list[str]]] = []
    for row, (level, cols, parts, is_member) in enumerate(rows):
        ax = [fig.add_subplot(gs[row, c], sharex=first.get(c)) for c in range(4)]
        for c in range(4):
            first.setdefault(c, ax[c])
        ax_w, ax_wz, ax_t, ax_tz = ax
        handles, names = [], []
        span_w = _span([sig.velocity[:, j] for j in cols])
        span_t = _span([sig.effort[:, j] for j in cols])
        seen_w: list[tuple[str, np.ndarray]] = []
        seen_t: list[tuple[str, np.ndarray]] = []
        for j in cols:
            st = series_style(j)
            w, tq = sig.velocity[:, j], sig.effort[:, j]
            h = _draw_series(ax_w, sig.t, w, st, labels[j], n_bins)
            ax_wz.plot(sig.t[zoom], w[zoom], label=labels[j], **st)
            same_w = _coincident(seen_w, w, span_w)
            seen_w.append((labels[j], w))
            same_t = None
            if not is_member:
                _draw_series(ax_t, sig.t, tq, st, labels[j], n_bins)
                ax_tz.plot(sig.t[zoom], tq[zoom], label=labels[j], **st)
                same_t = _coincident(seen_t, tq, span_t)
                seen_t.append((labels[j], tq))
            note = (f' (= {same_w})' if same_w == same_t else
                    ' (' + ', '.join(f'{q} = {o}' for q, o in (('speed', same_w), ('torque', same_t)) if o)
                    + ')') if (same_w or same_t) else ''
            handles.append(h)
            names.append(labels[j] + note)
        names_in_row = [sig.joint_names[j] for j in cols]
        for key, shaft, t_src, tq_src, st in (
                ('engine torque', eng, sig.engine_t, sig.engine_torque,
                 {'color': 'k', 'ls': (0, (5, 2)), 'lw': 0.8, 'alpha': 0.6}),
                ('load torque', load, sig.load_t, sig.load_torque,
                 {'color': '0.4', 'ls': (0, (1, 1.5)), 'lw': 1.2})):
            if is_member or not t_src.size or shaft not in names_in_row:
                continue
            if key == 'load torque' and len(wheels) > 1:
                continue        # the tyres' load on all wheels: each wheel's own torque is drawn
            label = f'{key} on {shaft}' + (' (resisting)' if key == 'load torque' else '')
            h = _draw_series(ax_t, t_src, tq_src, st, label, n_bins)
            z = (t_src >= z0) & (t_src <= z1)
            ax_tz.plot(t_src[z], tq_src[z], **st)
            handles.append(h)
            names.append(label)
        for a in (ax_w,) if is_member else (ax_w, ax_t):
            if t0 > sig.t[0]:
                a.axvspan(sig.t[0], t0, color='0.85', alpha=0.6, lw=0)
            a.axvspan(z0, z1, color='tab:orange', alpha=0.12, lw=0)
        title = _level_title(means, level).replace('mean speeds ', '').replace('mean speed ', '')
        part = '' if parts == 1 else f' ({row - next(r for r, x in enumerate(rows) if x[0] is level) + 1}' \
                                     f' of {parts} by swing)'
        ax_w.set_title(f'{"member speed" if is_member else "speed"}, {title}{part}')
        ax_wz.set_title('speed, zoom')
        ax_w.set_ylabel('speed  [rad/s]')
        if is_member:
            for a in (ax_t, ax_tz):
                a.set_axis_off()
            ax_t.text(0.5, 0.5, 'internal members of the joints (cage, spider, earring, yoke):\n'
                      f'{", ".join(names_in_row)}\nturn with their joint and carry no line '
                      'torque: speed only',
                      transform=ax_t.transAxes, ha='center', va='center', fontsize=9,
                      bbox={'boxstyle': 'round', 'fc': 'white', 'ec': '0.6', 'alpha': 0.9})
        else:
            ax_t.set_title(f'torque, {title}{part}')
            ax_tz.set_title('torque, zoom')
            ax_t.set_ylabel('torque  [N m]')
        legends.append((fig.add_subplot(gs[row, 4]), handles, names))
        for a in ax:        # read 99.98 rad/s, not 'offset +1e2' and -0.02
            if a.axison:
                a.ticklabel_format(axis='y', useOffset=False)
    _legend_column(fig, gs, legends)
    bottom = {c: a for a in fig.axes if a.axison for c in [a.get_subplotspec().colspan.start]}
    for a in bottom.values():
        a.set_xlabel('simulated time  [s]')
    skipped = f'; grey: skipped start transient t < {t0:.3g} s' if t0 > sig.t[0] else ''
    hidden = f'; not drawn (internal members): {", ".join(members)}' if members and not internal else ''
    if len(wheels) > 1:
        hidden += f'; load: the tyres of {len(wheels)} wheels (each wheel shaft\'s torque)'
    dense = f'\nline = mean, band = min-max over each of {n_bins} time bins (one revolution of the ' \
        'fastest shaft each)' if n_bins else ''
    fig.suptitle(f'Shaft speeds and torques by speed level - {_bag_label(sig)}{skipped}; orange: zoom '
                 f't = {z0:.4g}-{z1:.4g} s{hidden}{dense}', fontsize=11)
    return fig


def _legend_column(fig: Any, gs: Any, legends: list[tuple[Any, list[Any], list[str]]]) -> None:
    """Legends in the last grid column (one per row, axes off, kept out of the layout), the
    column as wide and each row as tall as its longest legend needs (8 pt text: ~0.068 in
    per character, 0.16 in per entry), so a long legend never squeezes the plots."""
    from matplotlib.legend_handler import HandlerTuple
    width, heights = 1.0, []
    for ax, handles, names in legends:
        ax.set_axis_off()
        ncol = 1 if len(names) <= 16 else 2
        rows_needed = math.ceil(len(names) / ncol)
        width = max(width, ncol * (0.068 * max((len(n) for n in names), default=0) + 0.7))
        heights.append(max(2.6, 0.16 * rows_needed + 0.5))
        leg = ax.legend(handles, names, loc='upper left', bbox_to_anchor=(0.0, 1.0), borderaxespad=0.0,
                        framealpha=0.85, ncol=ncol, handler_map={tuple: HandlerTuple(ndivide=1)})
        leg.set_in_layout(False)
    plots_w = [3.6, 1.4, 3.6, 1.4]
    gs.set_width_ratios(plots_w + [width])
    gs.set_height_ratios(heights)
    fig.set_size_inches(sum(plots_w) + width + 0.8, sum(heights) + 1.2)


def _draw_folded(ax: Any, phi: np.ndarray, y: np.ndarray, *, scale: float, n_bins: int,
                 style: dict[str, Any], seen: list[tuple[str, np.ndarray]], span: float,
                 name: str, floor: float = UNIFORM_FLOOR) -> tuple[Any, str | None]:
    """Fold ``y`` over ``phi`` and draw the mean line and the min-max band (``scale`` converts
    to display units; a peak-to-peak below ``floor`` draws flat at 0). When the
    folded curve covers one in ``seen`` (within COINCIDENT x ``span``, display units) no band
    is drawn. Returns (legend handle, label of the covered curve or None); appends to seen."""
    if _peak_to_peak(y) < floor:
        x = np.array([0.0, 360.0])
        mean = lo = hi = np.zeros(2)
    else:
        x, mean, lo, hi, _ = fold_over_angle(phi, y, n_bins)
        mean, lo, hi = scale * mean, scale * lo, scale * hi
    key = np.concatenate([mean, lo, hi]) if x.size > 2 else np.zeros(6)
    same = _coincident(seen, key, span)
    seen.append((name, key))
    line, = ax.plot(x, mean, label=name, **style)
    if same or x.size <= 2:
        return line, same
    band = ax.fill_between(x, lo, hi, color=style['color'], alpha=0.13, lw=0)
    return (line, band), same


def _folded_span(pairs: Sequence[tuple[np.ndarray, np.ndarray]], scale: float, n_bins: int,
                 floor: float = UNIFORM_FLOOR) -> float:
    """Display-unit span of the min-max bands of (phi, y) pairs folded over one revolution."""
    arrs = []
    for phi, y in pairs:
        if y.size and _peak_to_peak(y) >= floor:
            _, _, lo, hi, _ = fold_over_angle(phi, y, n_bins)
            arrs += [scale * lo, scale * hi]
    return _span(arrs)


def _uniform_axis(ax: Any, p2p: float, unit: str, floor: float = UNIFORM_FLOOR, why: str = '') -> None:
    """Y-limits and note of an axis whose every series is uniform (not stretched noise)."""
    ax.set_ylim(-1.0, 1.0)
    u = f' {unit}' if unit else ''
    ax.text(0.5, 0.72, f'uniform{why}\npeak-to-peak {p2p:.2g}{u} < {floor:g}{u}',
            transform=ax.transAxes, ha='center', va='center', fontsize=10,
            bbox={'boxstyle': 'round', 'fc': 'white', 'ec': '0.6', 'alpha': 0.9})


def nonuniformity_figure(sig: BagSignals, mask: np.ndarray) -> Any:
    """Speed deviation of every shaft over its own angle (one row per speed level), then one
    row per joint: geometric (mrad) and kinematic nonuniformity over the joint's input angle
    (Bugaru & Vasile 2021). The speed deviation is w / w_rev - 1 with w_rev the mean speed over the
    revolution centred on the sample (:func:`revolution_mean_speed`), so a slow drift of the
    window does not smear it. Curves are folded over one revolution: line = mean over the
    revolutions of the steady window, band = min-max. A deviation whose peak-to-peak is below
    :data:`UNIFORM_FLOOR` (speeds: below the solver's rtol recorded in the scene, if larger:
    the integrator does not resolve relative speed changes below it) is drawn flat and the
    axis says "uniform". Joint titles name the fidelity the scene ran (an ``ideal`` joint is
    uniform by construction, not by physics)."""
    rtol, fidelity = scene_settings(sig)
    speed_floor = max(UNIFORM_FLOOR, rtol or 0.0)
    speed_why = ' (below the solver rtol)' if speed_floor > UNIFORM_FLOOR else ''
    means = _steady_means(sig, mask)
    labels = shaft_labels(sig.joint_names)
    pairs = joint_pairs(sig.joint_names)
    t = sig.t[mask]
    data: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    speed_rows: list[tuple[list[int], list[int], int]] = []    # (level, shafts of the row, parts)
    for level in speed_levels(means):
        for j in level:
            phi, w = sig.position[mask, j], sig.velocity[mask, j]
            w_rev = revolution_mean_speed(t, phi)
            ok = np.isfinite(w_rev) & (w_rev != 0.0)
            data[j] = (phi[ok], w[ok] / w_rev[ok] - 1.0)
        parts = amplitude_groups([_peak_to_peak(data[j][1]) for j in level], floor=speed_floor)
        speed_rows += [(level, [level[i] for i in part], len(parts)) for part in parts]
    n_rows = len(speed_rows) + len(pairs)
    fig = plt.figure(figsize=(13, 2.7 * n_rows + 0.9), layout='constrained')
    gs = fig.add_gridspec(n_rows, 2)
    for row, (level, shafts, parts) in enumerate(speed_rows):
        ax = fig.add_subplot(gs[row, :])
        span = _folded_span([data[j] for j in shafts], 100.0, 72, speed_floor)
        handles, names, seen, p2ps = [], [], [], []
        for j in shafts:
            w = sig.velocity[mask, j]
            phi, dev = data[j]
            if dev.size < 2:
                h, = ax.plot([0.0, 360.0], [0.0, 0.0], label=labels[j], **series_style(j))
                handles.append(h)
                names.append(f'{labels[j]} (no full revolution in one direction)')
                continue
            p2ps.append(_peak_to_peak(dev))
            h, same = _draw_folded(ax, phi, dev, scale=100.0, n_bins=72, style=series_style(j),
                                   seen=seen, span=span, name=labels[j], floor=speed_floor)
            delta = signal.speed_nonuniformity(w)
            handles.append(h)
            names.append(f'{labels[j]} (delta = {delta:.3g})' + (f' = {same}' if same else ''))
        if p2ps and max(p2ps) < speed_floor:
            _uniform_axis(ax, max(p2ps), '', speed_floor, speed_why)
        ax.set_ylabel(r'$\omega/\bar\omega_{rev} - 1$  [%]')
        ax.set_xlabel('own shaft angle mod 360  [deg]')
        part = '' if parts == 1 else \
            f' ({row - next(r for r, sr in enumerate(speed_rows) if sr[0] is level) + 1} of {parts}, ' \
            f'by size of the deviation)'
        ax.set_title(f'Speed deviation over own shaft angle, {_level_title(means, level)}{part}')
        _legend(ax, handles, names)
    for k, (joint, n_in, n_out) in enumerate(pairs):
        ax_g = fig.add_subplot(gs[len(speed_rows) + k, 0])
        ax_k = fig.add_subplot(gs[len(speed_rows) + k, 1])
        i, o = sig.column(n_in), sig.column(n_out)
        phi_i, phi_o = sig.position[mask, i], sig.position[mask, o]
        wi, wo = sig.velocity[mask, i], sig.velocity[mask, o]
        nu = signal.joint_nonuniformity(phi_i, phi_o, wi, wo)
        r = nu.nominal_ratio
        dev = phi_o - r * phi_i
        dev = dev - (2 * math.pi * round(float(np.mean(dev)) / (2 * math.pi)) if r == 1.0 else float(np.mean(dev)))
        ok = np.abs(wi) > 1e-6
        kin = wo[ok] / (r * wi[ok]) - 1.0
        name = joint if r == 1.0 else f'{joint} (ratio {r:.4g})'
        st = series_style(len(sig.joint_names) + k)
        for ax, phi, y, scale, unit, shown in ((ax_g, phi_i, dev, 1e3, 'rad', 'mrad'),
                                               (ax_k, phi_i[ok], kin, 1.0, '', '')):
            p2p = _peak_to_peak(y)
            h, _ = _draw_folded(ax, phi, y, scale=scale, n_bins=360, style=st, seen=[], span=0.0, name=name)
            uni = p2p < UNIFORM_FLOOR
            lab = f'{name}: uniform' if uni else f'{name}: peak-to-peak {scale * p2p:.3g} {shown}'.rstrip()
            if uni:
                _uniform_axis(ax, p2p, unit, why=' (ideal model: output = ratio x input)'
                              if fidelity.get(joint) == 'ideal' else '')
            ax.legend([h], [lab], loc='best', framealpha=0.85)
        ax_g.set_ylabel(r'$\varphi_{out}-i\,\varphi_{in}$  [mrad]')
        model = f', {fidelity[joint]} model' if joint in fidelity else ''
        ax_g.set_title(f'{joint}: geometric nonuniformity (Bugaru & Vasile 2021){model}')
        ax_k.set_ylabel(r'$\omega_{out}/(i\,\omega_{in}) - 1$  [-]')
        ax_k.set_title(f'{joint}: kinematic nonuniformity (Bugaru & Vasile 2021){model}')
        for a in (ax_g, ax_k):
            a.set_xlabel('joint input angle mod 360  [deg]')
    for a in fig.axes:
        a.set_xlim(0, 360)
        a.set_xticks(range(0, 361, 45))
    fig.suptitle(f'Nonuniformity over shaft angle (steady window) - {_bag_label(sig)}\n'
                 r'speed: $\bar\omega_{rev}$ = mean speed over the surrounding revolution, '
                 'delta = (max - min)/mean over the window; '
                 'all panels: line = mean over the revolutions, band = min-max', fontsize=10.5)
    return fig


def harmonics_figure(sig: BagSignals, report: dict[str, Any], mask: np.ndarray) -> Any | None:
    """Torque harmonic amplitudes of every torque that oscillates (top: a marker on a stem at
    each order k, log scale, four decades), then
    one row per speed level: the truncated Fourier series over one revolution (line) and the
    recorded torque folded over the shaft angle (band: min-max over revolutions), Davidbaev et al.
    2023, eqs. 4.1-4.3. None when no torque oscillates."""
    labels = dict(zip(sig.joint_names, shaft_labels(sig.joint_names)))
    series: list[tuple[str, str, dict[str, Any], int]] = []   # (label, shaft, harmonics, style index)
    for j, (n, s) in enumerate(report['shafts'].items()):
        series.append((labels.get(n, n), n, s['torque_harmonics'], j))
    wheels = [n for n in sig.joint_names if n.startswith('wheel')]
    for k, key in enumerate(('engine', 'load')):
        if key == 'load' and len(wheels) > 1:
            continue        # the tyres' load on all wheels: each wheel's own torque is drawn
        if key in report:
            series.append((f'{key} wrench on {report[key]["shaft"]}', report[key]['shaft'],
                           report[key]['torque_harmonics'], len(report['shafts']) + k))
    series = [s for s in series if _oscillates(s[2])]   # flat torques say nothing here
    if not series:
        return None
    means = _steady_means(sig, mask)
    levels = [lv for lv in speed_levels(means)
              if any(sig.joint_names[j] in {s[1] for s in series} for j in lv)]
    # legends of more than 14 entries take two columns (_legend): widen the figure for them
    fig = plt.figure(figsize=(13 if len(series) <= 14 else 19, 3.6 + 2.7 * len(levels) + 0.6),
                     layout='constrained')
    gs = fig.add_gridspec(1 + len(levels), 1, height_ratios=[1.35] + [1.0] * len(levels))
    ax_b = fig.add_subplot(gs[0])
    top = 0.0
    for name, _, h, style_index in series:
        amps = np.asarray([a if a is not None else np.nan for a in h['amplitude']], dtype=float)
        top = max(top, float(np.nanmax(amps, initial=0.0)))
    floor = HARMONIC_DECADES_FLOOR * top
    for name, _, h, style_index in series:
        orders = np.asarray(h['orders'], dtype=float)
        amps = np.asarray([a if a is not None else np.nan for a in h['amplitude']], dtype=float)
        st = series_style(style_index)
        ax_b.vlines(orders, floor, np.maximum(amps, floor), color=st['color'], lw=1.0, alpha=0.45)
        ax_b.plot(orders, np.where(amps >= floor, amps, np.nan), ls='none', color=st['color'],
                  marker=marker_of(style_index), ms=6,
                  label=f"{name} (mean {h['mean']:.4g} N m)")
    ax_b.set_yscale('log')
    ax_b.set_ylim(floor, 2.0 * top)
    ax_b.set_xlabel('harmonic order k  [per shaft revolution]')
    ax_b.set_ylabel(r'amplitude $A_k$  [N m]')
    ax_b.set_title(r'Torque harmonics over shaft angle, $T=\bar T+\sum A_k\cos(k\varphi+p_k)$ '
                   '(Davidbaev et al. 2023, eqs. 4.1-4.3)\neach marker at its order k; '
                   f'amplitudes below {HARMONIC_DECADES_FLOOR:.0e} x the largest not shown')
    all_orders = sorted({float(k) for s_ in series for k in s_[2]['orders']})
    ax_b.set_xticks(all_orders)
    ax_b.set_xlim(min(all_orders) - 0.5, max(all_orders) + 0.5)
    _legend(ax_b, *ax_b.get_legend_handles_labels())
    phi1 = np.linspace(0.0, 2 * math.pi, 73)
    t_first = sig.t[mask][0] if np.any(mask) else -np.inf
    for row, level in enumerate(levels):
        ax = fig.add_subplot(gs[1 + row])
        shafts = {sig.joint_names[j] for j in level}
        rows = []
        for name, shaft, h, style_index in series:
            if shaft not in shafts:
                continue
            j = sig.column(shaft)
            if name.endswith(f'wrench on {shaft}'):
                src_t, src_tq = (sig.engine_t, sig.engine_torque) if name.startswith('engine') \
                    else (sig.load_t, sig.load_torque)
                m = src_t >= t_first
                phi, tq = np.interp(src_t[m], sig.t, sig.position[:, j]), src_tq[m]
            else:
                phi, tq = sig.position[mask, j], sig.effort[mask, j]
            fourier = h['mean'] + sum(a * np.cos(k * phi1 + p) for k, a, p in
                                      zip(h['orders'], h['amplitude'], h['phase_rad']) if a is not None)
            x, _, lo, hi, _ = fold_over_angle(phi, tq, 72)
            rows.append((name, h, style_index, fourier, x, lo, hi))
        span = _span([a for r in rows for a in (r[5], r[6])])
        handles, names, seen = [], [], []
        for name, h, style_index, fourier, x, lo, hi in rows:
            st = series_style(style_index)
            line, = ax.plot(np.degrees(phi1), fourier, label=name, **{**st, 'lw': st['lw'] + 0.6})
            key = np.concatenate([fourier, lo, hi])
            same = _coincident(seen, key, span)
            seen.append((name, key))
            if same:
                handles.append(line)
            else:
                band = ax.fill_between(x, lo, hi, color=st['color'], alpha=0.13, lw=0)
                handles.append((line, band))
            names.append(f'{name}: {len(h["orders"])} harmonics, {h.get("revolutions", "?")} rev'
                         + (f' (= {same})' if same else ''))
        ax.set_xlim(0, 360)
        ax.set_xticks(range(0, 361, 45))
        ax.set_xlabel('shaft angle mod 360  [deg]')
        ax.set_ylabel('torque  [N m]')
        ax.set_title(f'Torque over one revolution, {_level_title(means, level)} '
                     f'(line: Fourier series, band: recorded min-max over the revolutions)')
        _legend(ax, handles, names)
    return fig


def _oscillates(h: dict[str, Any]) -> bool:
    if 'skipped' in h:
        return False
    amps = [a for a in h['amplitude'] if a is not None]
    return bool(amps) and max(amps) > 1e-6 * max(1.0, abs(h['mean'] or 0.0))


def work_precision_plot(rows: Sequence[dict[str, Any]], *, scene: str, path: str | Path,
                        error_key: str = 'err_speed_rel', cost_key: str = 'wall_per_sim_s') -> Path:
    """Log-log work-precision figure of one scene: error (x) vs cost (y), one line per
    configuration family (solver, fidelity, sampling variant) over its tolerances or steps.
    Colour = method, marker = fidelity, line = variant (project: landing on the samples
    solid, across the load's breakpoints dotted and hollow, dense sampling dash-dot;
    solve_ivp: Python rhs dashed with squares, compiled rhs solid with squares; numbalsoda on
    the compiled rhs: triangles, solid, dotted when restarted at the load's knots). Project
    runs without the work integrals (label suffix ' no-energy') are drawn thin; the baseline
    families are drawn above the project's lines, numbalsoda's triangles edged in black. The
    key names each of these once, outside the axes, instead of one entry per line (a full
    run draws ~200 lines)."""
    from matplotlib.lines import Line2D
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    groups: dict[str, list[dict[str, Any]]] = {}
    for r in rows:
        if r.get('scene') != scene:
            continue
        e, c = r.get(error_key), r.get(cost_key)
        if e is None or c is None or not (np.isfinite(e) and np.isfinite(c)) or e <= 0 or c <= 0:
            continue
        groups.setdefault(r['label'], []).append(r)

    def variant(r: dict[str, Any]) -> str:
        fam = r.get('family')
        if fam == 'baseline':
            return 'solve_ivp, Python rhs'
        if fam == 'baseline_compiled':
            return 'solve_ivp, compiled rhs'
        if fam == 'baseline_expert':
            restart = r.get('breakpoints') in (True, 'True')
            return 'numbalsoda, restart at knots' if restart else 'numbalsoda, compiled rhs'
        if r.get('breakpoints', True) in (False, 'False'):
            return 'project, across breakpoints'
        return 'project, dense sampling' if r.get('sampling') == 'dense' else 'project, landing'

    lines = {'project, landing': '-', 'project, across breakpoints': ':',
             'project, dense sampling': '-.', 'solve_ivp, Python rhs': '--',
             'solve_ivp, compiled rhs': '-', 'numbalsoda, compiled rhs': '-',
             'numbalsoda, restart at knots': ':'}

    def method(r: dict[str, Any]) -> str:
        return f'numbalsoda {r["solver"]}' if r.get('family') == 'baseline_expert' else r['solver']
    markers = {'exact': 'o', 'auto': '*', 'closed': 'D', 'ideal': 'v', 'rigid': 'P'}
    methods = sorted({method(rs[0]) for rs in groups.values()},
                     key=lambda m: (m[:1].isupper(), m))   # project methods, then solve_ivp's
    colors = {m: _METHOD_COLORS[i % len(_METHOD_COLORS)] for i, m in enumerate(methods)}
    used_variants: list[str] = []
    used_fids: list[str] = []
    no_energy = False
    # ideal/closed runs are drawn faint beside exact ones; a scene whose modes are all one
    # model (stiff: only 'ideal' runs, exact = auto = ideal) draws them in full
    has_exact = any(rs[0].get('family') == 'project' and rs[0].get('fidelity') in ('exact', 'auto')
                    for rs in groups.values())
    with plt.rc_context(_STYLE):
        fig, ax = plt.subplots(figsize=(11.5, 6.4))
        for _label, rs in sorted(groups.items(), key=lambda kv: (variant(kv[1][0]), kv[0])):
            # connect in order of the knob (tolerance, or fixed step for rk4): loose -> tight
            rs = sorted(rs, key=lambda r: -(r.get('tol') or r.get('h') or 0.0))
            v = variant(rs[0])
            base = v.startswith(('solve_ivp', 'numbalsoda'))
            fid = 'baseline' if base else rs[0].get('fidelity', 'exact')
            used_variants += [v] if v not in used_variants else []
            used_fids += [fid] if not base and fid not in used_fids else []
            strong = base or fid in ('exact', 'auto') or not has_exact
            thin = not base and rs[0].get('energy') == 'off'
            no_energy |= thin
            expert = v.startswith('numbalsoda')
            ax.loglog([r[error_key] for r in rs], [r[cost_key] for r in rs],
                      ls=lines[v], marker=('^' if expert else 's') if base
                      else markers.get(fid, 'o'),
                      mfc='none' if v == 'project, across breakpoints' else None,
                      mec='k' if expert else None, mew=0.7 if expert else None,
                      ms=7 if expert else 9 if fid == 'auto' else 4 if thin else 5,
                      lw=2.2 if expert else 1.8 if base else 0.7 if thin else 1.4,
                      color=colors[method(rs[0])], alpha=0.95 if strong else 0.5,
                      zorder=4 if base else 2)
        for lv in (1e-3, 1e-8):
            ax.axvline(lv, color='0.6', lw=0.8, ls=':')
        ax.set_xlabel('max relative error of output speed  [-]' if error_key == 'err_speed_rel'
                      else error_key)
        ax.set_ylabel('wall time per simulated second  [s/s]')
        ax.set_title(f'Work-precision: {scene} (lower left is better; dotted verticals: the '
                     f'error levels 1e-3 and 1e-8 of the report)', fontsize=10)
        ax.grid(True, which='both', alpha=0.25)
        key: list[Any] = [Line2D([], [], ls='none', label='colour: method')]
        key += [Line2D([], [], color=colors[m], lw=3, label=m if m[:1].islower()
                       else f'solve_ivp {m}') for m in methods]
        key += [Line2D([], [], ls='none', label=''),
                Line2D([], [], ls='none', label='marker: fidelity')]
        key += [Line2D([], [], ls='none', marker=markers[f], color='0.3', ms=9 if f == 'auto' else 6,
                       label=f) for f in ('exact', 'auto', 'closed', 'ideal', 'rigid') if f in used_fids]
        key += [Line2D([], [], ls='none', marker='s', color='0.3', ms=6, label='solve_ivp')]
        if any(v.startswith('numbalsoda') for v in used_variants):
            key += [Line2D([], [], ls='none', marker='^', color='0.3', ms=6, label='numbalsoda')]
        key += [Line2D([], [], ls='none', label=''), Line2D([], [], ls='none', label='line: run')]
        key += [Line2D([], [], ls=lines[v], color='0.3', lw=1.6,
                       marker='o' if 'across' in v else None,
                       mfc='none', label=v) for v in lines if v in used_variants]
        if no_energy:
            key += [Line2D([], [], ls='-', color='0.3', lw=0.7,
                           label='project, no work integrals (thin)')]
        leg = ax.legend(handles=key, loc='upper left', bbox_to_anchor=(1.01, 1.0), fontsize=8,
                        frameon=False, handlelength=2.6)
        for text in leg.get_texts():
            if text.get_text().endswith((': method', ': fidelity', ': run')):
                text.set_fontweight('bold')
        fig.tight_layout()
        fig.savefig(p)
        plt.close(fig)
    return p


def lockstep_plot(rows: Sequence[dict[str, Any]], *, path: str | Path) -> Path:
    """Lockstep study: output-speed error vs exchange step (left) and real-time factor vs
    error (right), one line per (scene, coupling scheme), log-log."""
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    groups: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for r in rows:
        e = r.get('err_speed_rel')
        if r.get('ok') and e is not None and np.isfinite(e) and e > 0:
            groups.setdefault((r['scene'], r['scheme']), []).append(r)
    styles = {'zoh': ('o', '-'), 'extrapolate': ('s', '--'), 'linear_implicit': ('^', '-.')}
    scenes = sorted({k[0] for k in groups})
    colors = {s: plt.get_cmap('tab10')(i % 10) for i, s in enumerate(scenes)}
    with plt.rc_context(_STYLE):
        fig, (ax_h, ax_r) = plt.subplots(1, 2, figsize=(11, 4.8))
        for (scene, scheme), rs in sorted(groups.items()):
            rs = sorted(rs, key=lambda r: r['exchange_step'])
            mk, ls = styles.get(scheme, ('o', '-'))
            kw = dict(marker=mk, ls=ls, color=colors[scene], label=f'{scene} {scheme}', ms=5, lw=1.5)
            ax_h.loglog([r['exchange_step'] for r in rs], [r['err_speed_rel'] for r in rs], **kw)
            ax_r.loglog([r['err_speed_rel'] for r in rs], [r['rtf'] for r in rs], **kw)
        ax_h.set_xlabel('exchange step H  [s]')
        ax_h.set_ylabel('max relative error of output speed  [-]')
        ax_h.set_title('Coupling error vs exchange step')
        ax_r.set_xlabel('max relative error of output speed  [-]')
        ax_r.set_ylabel('real-time factor (offline loop)  [-]')
        ax_r.set_title('Real-time factor vs error')
        for ax in (ax_h, ax_r):
            ax.grid(True, which='both', alpha=0.25)
            ax.legend(loc='best', fontsize=7, framealpha=0.85)
        fig.tight_layout()
        fig.savefig(p)
        plt.close(fig)
    return p
