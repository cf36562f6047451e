"""Maps of a finished sweep (PNG, matplotlib Agg), written to ``DIR/plots``.

* ``line_<metric>.png`` - the metric over the first varied parameter, one line per value
  of the second (at most 8 lines, evenly picked; the legend names the values, and the
  title and ``notes`` of :func:`write_sweep_plots` name the values left out);
* ``map_<metric>.png`` - the metric over the first two varied parameters: heat map (cells
  centred on the grid points) with labelled contour lines; for random samples a
  triangulated filled contour with the sample points;
* ``resonance.png`` - when a speed is swept and the rows hold torque orders: torque
  amplitude of each order over speed (see :mod:`cvj_ros.sweep.run`, ``--orders``).

Further varied parameters are held at their first value (the title says so). Invalid or
failed variants leave grey cells / gaps. Axis labels carry the unit read from the field
name (``_deg`` deg, ``_rad_s`` rad/s, ``stiffness`` N m/rad, ...).
"""
from __future__ import annotations

import json
import math
import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use('Agg')
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from cvj_ros.sweep.results import MANIFEST, RESULTS, as_float, read_results  # noqa: E402

_STYLE = {'figure.dpi': 110, 'axes.grid': True, 'grid.alpha': 0.3, 'axes.titlesize': 10,
          'axes.labelsize': 10, 'legend.fontsize': 8, 'font.size': 9}
MAX_LINES = 8
# field name (last key) -> unit; first match wins
_UNITS = [(r'_deg$', 'deg'), (r'_rad_s$', 'rad/s'), (r'_rpm$', 'rpm'), (r'_rad$', 'rad'),
          (r'_mm$', 'mm'), (r'_m$', 'm'), (r'^stiffness$', 'N m/rad'), (r'^damping$', 'N m s/rad'),
          (r'^J$', 'kg m²'), (r'^(duration|exchange_step|sample_step|h|max_step)$', 's'),
          (r'^(m1|mean|amplitude|torque)$', 'N m'), (r'^k1$', 'N m s/rad')]
_METRIC_LABELS = {'mean_speed': ('mean speed', 'rad/s'), 'delta': ('nonuniformity δ', '-'),
                  'speed_amplitude': ('speed amplitude', 'rad/s'),
                  'acceleration_amplitude': ('acceleration amplitude', 'rad/s²'),
                  'mean_torque': ('mean torque', 'N m'), 'torque_amplitude': ('torque amplitude', 'N m'),
                  'energy_residual': ('energy residual', '-'), 'naccept': ('accepted steps', '-'),
                  'nreject': ('rejected steps', '-'), 'nfev': ('rhs evaluations', '-')}


def unit_of(path: str) -> str:
    """Unit of a scene field from its last key (empty if unknown)."""
    last = re.split(r'[.\]]', path)[-1]
    for pattern, unit in _UNITS:
        if re.search(pattern, last):
            return unit
    return ''


def axis_label(path: str) -> str:
    u = unit_of(path)
    return f'{path} ({u})' if u else path


def metric_label(metric: str) -> str:
    """'driven_shaft.delta' -> 'driven_shaft: nonuniformity δ (-)'."""
    shaft, _, key = metric.rpartition('.')
    m = re.fullmatch(r'torque_order(\d+)', key)
    if m:
        name, unit = f'torque order {m.group(1)}', 'N m'
    else:
        name, unit = _METRIC_LABELS.get(key, (key, ''))
    text = f'{shaft}: {name}' if shaft else name
    return f'{text} ({unit})' if unit else text


def _slug(text: str) -> str:
    return re.sub(r'[^A-Za-z0-9]+', '_', text).strip('_')


def default_metric(header: Sequence[str]) -> str | None:
    """The last shaft's nonuniformity delta (the driven end of the driveline); for a scene
    with clutch, gearbox or brake its final speed."""
    deltas = ([c for c in header if c.endswith('.delta')]
              or [c for c in header if c.endswith('.final_speed')])
    return deltas[-1] if deltas else None


def _fmt(v: float) -> str:
    return f'{v:.4g}'


def write_sweep_plots(out_dir: str | Path, *, metric: str | None = None,
                      required: bool = False, notes: list[str] | None = None) -> list[Path]:
    """Draw the plots of the sweep in ``out_dir``; returns the PNG paths. ``required``:
    a missing sweep is an error (``--replot``) instead of no plots. ``notes`` (if given)
    receives one line per plot that leaves series out (``line_x.png: ...``)."""
    from cvj_ros.sweep.spec import SweepError
    out = Path(out_dir)
    if not (out / RESULTS).is_file() or not (out / MANIFEST).is_file():
        if required:
            raise SweepError(f'--replot {out}: no finished sweep there (results.csv and sweep.json)')
        return []
    manifest = json.loads((out / MANIFEST).read_text())
    header, rows = read_results(out / RESULTS)
    if metric is None:
        metric = default_metric(header)
        if metric is None:
            return []           # no variant ran ok: nothing to draw
    elif metric not in header:
        import difflib
        cols = [c for c in header if c not in ('variant', 'status', 'error', 'backend')]
        near = difflib.get_close_matches(metric, cols, n=1)
        hint = f"; did you mean '{near[0]}'?" if near else f'; columns: {", ".join(cols)}'
        raise SweepError(f'--metric {metric}: not a column of results.csv{hint}')
    defn = manifest.get('definition', {})
    axes = [a['path'] for a in defn.get('axes', [])]
    logs = {a['path'] for a in defn.get('axes', []) if a.get('log')}
    scene = (defn.get('scene') or {}).get('name', '')
    random = defn.get('samples') is not None
    varied = [a for a in axes if len({r[a] for r in rows}) > 1 and
              all(math.isfinite(as_float(r[a])) for r in rows)]
    plots = out / 'plots'
    plots.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []
    if not varied:
        return written
    with plt.rc_context(_STYLE):
        path, dropped = _line_plot(rows, varied, axes, metric, scene, random, plots, logs)
        written.append(path)
        if dropped and notes is not None:
            notes.append(f'{path.name}: {dropped}')
        if len(varied) >= 2:
            written.append(_map_plot(rows, varied, axes, metric, scene, random, plots, logs))
        res = _resonance_plot(rows, header, varied, axes, scene, random, plots)
        if res is not None:
            written.append(res)
    return written


def _held(rows: list[dict[str, str]], varied: list[str], axes: list[str],
          keep: Sequence[str]) -> tuple[list[dict[str, str]], str]:
    """Rows with every varied parameter outside ``keep`` at its first value, and a note."""
    notes = []
    out = rows
    for a in varied:
        if a in keep:
            continue
        first = rows[0][a]
        out = [r for r in out if r[a] == first]
        notes.append(f'{a} = {_fmt(as_float(first))}')
    return out, ('; held: ' + ', '.join(notes)) if notes else ''


def _values(rows: list[dict[str, str]], col: str) -> np.ndarray:
    return np.array([as_float(r[col]) if r.get('status') == 'ok' else math.nan for r in rows])


def dropped_note(column: str, values: Sequence[float], shown: Sequence[float],
                 empty: Sequence[float] = ()) -> str:
    """One line naming the values of ``column`` whose series a line plot does not draw:
    those left out of ``shown`` (more than :data:`MAX_LINES`) and those in ``empty`` (no
    variant ok); '' when every value is drawn."""
    parts = []
    left = [v for v in values if v not in shown]
    if left:
        parts.append(f'{len(shown)} of {len(values)} values of {column} drawn, not drawn: '
                     + ', '.join(_fmt(v) for v in left))
    if empty:
        parts.append(f'no ok variant (no line) at {column} = ' + ', '.join(_fmt(v) for v in empty))
    return '; '.join(parts)


def _line_plot(rows, varied, axes, metric, scene, random, plots: Path, logs: set[str]
               ) -> tuple[Path, str]:
    """The line plot and the :func:`dropped_note` of its series ('' if none dropped)."""
    x_col = varied[0]
    dropped = ''
    fig, ax = plt.subplots(figsize=(7.0, 4.4))
    if random:
        x = np.array([as_float(r[x_col]) for r in rows])
        y = _values(rows, metric)
        if len(varied) >= 2:
            c = np.array([as_float(r[varied[1]]) for r in rows])
            from matplotlib.colors import LogNorm
            sc = ax.scatter(x, y, c=c, s=14, cmap='viridis',
                            norm=LogNorm() if varied[1] in logs else None)
            fig.colorbar(sc, ax=ax, label=axis_label(varied[1]))
        else:
            ax.scatter(x, y, s=14)
        note = f'{len(rows)} random samples'
    else:
        keep = varied[:2]
        sel, note = _held(rows, varied, axes, keep)
        if len(varied) >= 2:
            every = sorted({as_float(r[varied[1]]) for r in sel})
            groups = every
            if len(groups) > MAX_LINES:
                idx = np.unique(np.linspace(0, len(groups) - 1, MAX_LINES).round().astype(int))
                groups = [groups[i] for i in idx]
            cmap = plt.get_cmap('viridis')
            empty = []
            for k, g in enumerate(groups):
                part = [r for r in sel if as_float(r[varied[1]]) == g]
                x = np.array([as_float(r[x_col]) for r in part])
                order = np.argsort(x)
                y = _values(part, metric)[order]
                if not np.isfinite(y).any():
                    empty.append(g)
                ax.plot(x[order], y, 'o-', ms=3, lw=1.4,
                        color=cmap(k / max(1, len(groups) - 1)), label=_fmt(g))
            ax.legend(title=axis_label(varied[1]), loc='best', ncol=2 if len(groups) > 4 else 1)
            dropped = dropped_note(varied[1], every, groups, empty)
            if dropped:
                note = (note + '; ' + dropped).lstrip('; ')
        else:
            x = np.array([as_float(r[x_col]) for r in sel])
            order = np.argsort(x)
            ax.plot(x[order], _values(sel, metric)[order], 'o-', ms=3, lw=1.4)
        note = note.lstrip('; ')
    if x_col in logs:
        _log_axis(ax.xaxis, ax.set_xscale)
    ax.set_xlabel(axis_label(x_col))
    ax.set_ylabel(metric_label(metric))
    import textwrap
    ax.set_title(f'{scene}: {metric_label(metric)}' + (f'\n{textwrap.fill(note, 95)}' if note else ''))
    fig.tight_layout()
    path = plots / f'line_{_slug(metric)}.png'
    fig.savefig(path)
    plt.close(fig)
    return path, dropped


def _map_plot(rows, varied, axes, metric, scene, random, plots: Path, logs: set[str]) -> Path:
    x_col, y_col = varied[0], varied[1]
    fig, ax = plt.subplots(figsize=(7.0, 5.0))
    if random:
        import matplotlib.tri as mtri
        x = np.array([as_float(r[x_col]) for r in rows])
        y = np.array([as_float(r[y_col]) for r in rows])
        z = _values(rows, metric)
        ok = np.isfinite(z)
        tri = mtri.Triangulation(x[ok], y[ok])
        cf = ax.tricontourf(tri, z[ok], levels=14, cmap='viridis')
        cs = ax.tricontour(tri, z[ok], levels=cf.levels[::2], colors='k', linewidths=0.7, alpha=0.8)
        _label_contours(ax, cs)
        ax.plot(x[ok], y[ok], 'k.', ms=2, alpha=0.5)
        if (~ok).any():
            ax.plot(x[~ok], y[~ok], 'rx', ms=4, label='invalid / failed')
            ax.legend(loc='upper right')
        fig.colorbar(cf, ax=ax, label=metric_label(metric))
        note = f'{len(rows)} random samples'
    else:
        sel, note = _held(rows, varied, axes, (x_col, y_col))
        xs = sorted({as_float(r[x_col]) for r in sel})
        ys = sorted({as_float(r[y_col]) for r in sel})
        z = np.full((len(ys), len(xs)), math.nan)
        for r in sel:
            if r.get('status') == 'ok':
                z[ys.index(as_float(r[y_col])), xs.index(as_float(r[x_col]))] = as_float(r[metric])
        ax.set_facecolor('0.85')            # grey where a variant is invalid or failed
        mesh = ax.pcolormesh(_edges(xs, x_col in logs), _edges(ys, y_col in logs),
                             np.ma.masked_invalid(z), shading='flat', cmap='viridis')
        fig.colorbar(mesh, ax=ax, label=metric_label(metric))
        if len(xs) >= 2 and len(ys) >= 2 and np.isfinite(z).sum() >= 4 and np.nanmax(z) > np.nanmin(z):
            cs = ax.contour(xs, ys, z, levels=8, colors='k', linewidths=0.8, alpha=0.8)
            _label_contours(ax, cs)
        if np.isnan(z).any():
            note = (note + '; grey: invalid or failed').lstrip('; ')
        note = note.lstrip('; ')
    if x_col in logs:
        _log_axis(ax.xaxis, ax.set_xscale)
    if y_col in logs:
        _log_axis(ax.yaxis, ax.set_yscale)
    ax.set_xlabel(axis_label(x_col))
    ax.set_ylabel(axis_label(y_col))
    ax.grid(False)
    ax.set_title(f'{scene}: {metric_label(metric)}' + (f'\n{note}' if note else ''))
    fig.tight_layout()
    path = plots / f'map_{_slug(metric)}.png'
    fig.savefig(path)
    plt.close(fig)
    return path


def _label_contours(ax: Any, cs: Any) -> None:
    """Contour labels in black on a light halo: readable on dark and light cells alike."""
    import matplotlib.patheffects as pe
    for text in ax.clabel(cs, fmt=_fmt, fontsize=7):
        text.set_path_effects([pe.withStroke(linewidth=2.5, foreground='white', alpha=0.8)])


def _log_axis(axis: Any, set_scale: Any) -> None:
    """Log scale with plain numbers (300, 1000, 2000) instead of 3 x 10^2 tick labels."""
    from matplotlib.ticker import FuncFormatter, LogLocator
    set_scale('log')
    axis.set_major_locator(LogLocator(base=10, subs=(1.0, 2.0, 5.0)))
    axis.set_major_formatter(FuncFormatter(lambda v, _: f'{v:g}'))
    axis.set_minor_formatter(FuncFormatter(lambda v, _: ''))


def _edges(centres: Sequence[float], log: bool) -> np.ndarray:
    """Cell edges around grid points: midpoints (geometric means on a log axis), the outer
    cells as wide as their neighbours; one point gets a cell of +-50 % (+-1 on zero)."""
    c = np.log(np.asarray(centres, float)) if log else np.asarray(centres, float)
    if c.size == 1:
        half = 0.5 * abs(c[0]) if c[0] != 0 else 1.0
        e = np.array([c[0] - half, c[0] + half])
    else:
        mid = 0.5 * (c[1:] + c[:-1])
        e = np.concatenate([[c[0] - (mid[0] - c[0])], mid, [c[-1] + (c[-1] - mid[-1])]])
    return np.exp(e) if log else e


def _resonance_plot(rows, header, varied, axes, scene, random, plots: Path) -> Path | None:
    """Torque amplitude per engine order over the first shaft's mean speed (a Campbell-style
    resonance map), when the rows hold torque orders and that speed varies by > 10 %.
    In a grid, the varied parameter that moves the speed most is kept, the others held."""
    order_cols = [c for c in header if re.search(r'\.torque_order\d+$', c)]
    speed_cols = [c for c in header if c.endswith('.mean_speed')]
    if not order_cols or not speed_cols:
        return None
    speed = speed_cols[0]

    def span(part: list[dict[str, str]]) -> float:
        w = _values(part, speed)
        w = w[np.isfinite(w)]
        return float(w.max() - w.min()) / max(abs(float(np.mean(w))), 1e-300) if w.size > 1 else 0.0

    if random:
        sel, note = rows, f'{len(rows)} random samples'
    else:
        best = max(varied, key=lambda a: span(_held(rows, varied, axes, (a,))[0]))
        sel, note = _held(rows, varied, axes, (best,))
        note = (f'speed varied by {best}' + note).strip()
    if span(sel) < 0.1:
        return None
    x = _values(sel, speed)
    order = np.argsort(x)
    fig, ax = plt.subplots(figsize=(7.0, 4.4))
    shaft = order_cols[0].rsplit('.', 1)[0]
    cmap = plt.get_cmap('tab10')
    for k, col in enumerate(order_cols):
        n = col.rsplit('order', 1)[1]
        ax.plot(x[order], _values(sel, col)[order], '.' if random else 'o-', ms=3, lw=1.2,
                color=cmap(k % 10), label=f'order {n}')
    ax.set_xlabel(f'{speed.rsplit(".", 1)[0]}: mean speed (rad/s)')
    ax.set_ylabel(f'{shaft}: torque amplitude (N m)')
    ax.set_yscale('log')
    top = np.nanmax([_values(sel, c) for c in order_cols])
    if np.isfinite(top) and top > 0:
        # orders the joint does not excite sit at round-off / load noise: keep 4 decades
        ax.set_ylim(bottom=1e-4 * top, top=2.0 * top)
        note = (note + '; orders below 1e-4 of the largest not shown').lstrip('; ')
    ax.legend(loc='best', ncol=2, title='engine order')
    ax.set_title(f'{scene}: {shaft} torque per engine order over speed' +
                 (f'\n{note.lstrip("; ")}' if note else ''))
    fig.tight_layout()
    path = plots / 'resonance.png'
    fig.savefig(path)
    plt.close(fig)
    return path
