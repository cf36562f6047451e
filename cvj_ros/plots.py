"""PNG figures of an analysed bag and of the work-precision benchmark (matplotlib, Agg backend).

Analysis figures (:func:`write_analysis_plots`): ``speeds_torques.png`` (speed and torque of
every shaft over time, the skipped start transient shaded), ``nonuniformity.png`` (speed
deviation over shaft angle, joint geometric and kinematic nonuniformity over input angle),
``harmonics.png`` (torque harmonic amplitudes per order, and the torque resampled over one
revolution with its truncated Fourier series, seed 004 eqs. 4.1-4.3).
Benchmark figures: :func:`work_precision_plot` (log-log error vs cost, one line per solver).
"""
from __future__ import annotations

import math
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


def _wrapped(phi: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Angle mod 360 deg with NaN inserted at each wrap so lines do not jump across."""
    deg = np.degrees(np.mod(phi, 2 * math.pi))
    order_breaks = np.nonzero(np.abs(np.diff(deg)) > 180.0)[0] + 1
    return (np.insert(deg, order_breaks, np.nan), np.insert(y.astype(float), order_breaks, np.nan))


def write_analysis_plots(sig: BagSignals, report: dict[str, Any], out_dir: str | Path) -> list[Path]:
    """Write the analysis PNGs of a bag to ``out_dir`` (created); returns the file paths."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    t0 = report['window']['start_s']
    mask = sig.t >= t0
    paths = []
    with plt.rc_context(_STYLE):
        paths.append(_plot_time(sig, t0, out / 'speeds_torques.png'))
        paths.append(_plot_nonuniformity(sig, mask, out / 'nonuniformity.png'))
        p = _plot_harmonics(sig, report, mask, out / 'harmonics.png')
        if p is not None:
            paths.append(p)
    return paths


def _bag_label(sig: BagSignals) -> str:
    p = sig.path if sig.path.is_dir() else sig.path.parent
    return f'{p.parent.name}/{p.name}' if p.name == 'bag' else p.name


def _plot_time(sig: BagSignals, t0: float, path: Path) -> Path:
    fig, (ax_w, ax_t) = plt.subplots(2, 1, figsize=(9, 6.5), sharex=True)
    for j, name in enumerate(sig.joint_names):
        ax_w.plot(sig.t, sig.velocity[:, j], lw=1.1, label=name)
        ax_t.plot(sig.t, sig.effort[:, j], lw=1.1, label=f'{name} (shaft)')
    if sig.engine_t.size:
        ax_t.plot(sig.engine_t, sig.engine_torque, 'k--', lw=0.9, label=f'engine on {engine_shaft(sig)}')
    if sig.load_t.size:
        ax_t.plot(sig.load_t, sig.load_torque, color='0.45', ls=':', lw=1.1,
                  label=f'load on {load_shaft(sig)} (resisting)')
    for ax in (ax_w, ax_t):
        if t0 > sig.t[0]:
            ax.axvspan(sig.t[0], t0, color='0.85', alpha=0.6, lw=0, label='skipped transient')
        ax.legend(loc='best', ncol=2, framealpha=0.85)
    ax_w.set_ylabel('speed  [rad/s]')
    ax_w.set_title(f'Shaft speeds and torques - {_bag_label(sig)}')
    ax_t.set_ylabel('torque  [N m]')
    ax_t.set_xlabel('simulated time  [s]')
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path


def _plot_nonuniformity(sig: BagSignals, mask: np.ndarray, path: Path) -> Path:
    pairs = joint_pairs(sig.joint_names)
    n_rows = 3 if pairs else 1
    fig, axes = plt.subplots(n_rows, 1, figsize=(9, 2.9 * n_rows + 0.6), squeeze=False)
    ax = axes[0, 0]
    for j, name in enumerate(sig.joint_names):
        w = sig.velocity[mask, j]
        mean = float(np.mean(w))
        if mean == 0.0:
            continue
        x, y = _wrapped(sig.position[mask, j], w / mean - 1.0)
        ax.plot(x, 100.0 * y, lw=0.9, label=f'{name} (delta = {signal.speed_nonuniformity(w):.3g})')
    ax.set_ylabel(r'$\omega/\bar\omega - 1$  [%]')
    ax.set_title('Speed deviation over shaft angle (steady window)')
    ax.set_xlabel('own shaft angle mod 360  [deg]')
    ax.legend(loc='best', ncol=2, framealpha=0.85)
    if pairs:
        ax_g, ax_k = axes[1, 0], axes[2, 0]
        for joint, n_in, n_out in pairs:
            i, o = sig.column(n_in), sig.column(n_out)
            nu = signal.joint_nonuniformity(sig.position[mask, i], sig.position[mask, o],
                                            sig.velocity[mask, i], sig.velocity[mask, o])
            r = nu.nominal_ratio
            dev = sig.position[mask, o] - r * sig.position[mask, i]
            dev = dev - (2 * math.pi * round(float(np.mean(dev)) / (2 * math.pi)) if r == 1.0 else float(np.mean(dev)))
            x, y = _wrapped(sig.position[mask, i], dev)
            label = joint if r == 1.0 else f'{joint} (ratio {r:.4g})'
            ax_g.plot(x, 1e3 * y, lw=1.0, label=label)
            wi, wo = sig.velocity[mask, i], sig.velocity[mask, o]
            ok = np.abs(wi) > 1e-6
            x, y = _wrapped(sig.position[mask, i][ok], wo[ok] / (r * wi[ok]) - 1.0)
            ax_k.plot(x, y, lw=1.0, label=label)
        ax_g.set_ylabel(r'$\varphi_{out}-i\,\varphi_{in}$  [mrad]')
        ax_g.set_title('Geometric nonuniformity of the joints (seed 002)')
        ax_k.set_ylabel(r'$\omega_{out}/(i\,\omega_{in}) - 1$  [-]')
        ax_k.set_title('Kinematic nonuniformity of the joints (seed 002)')
        for a in (ax_g, ax_k):
            a.set_xlabel('joint input angle mod 360  [deg]')
            a.legend(loc='best', framealpha=0.85)
    for a in axes[:, 0]:
        a.set_xlim(0, 360)
        a.set_xticks(range(0, 361, 45))
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path


def _plot_harmonics(sig: BagSignals, report: dict[str, Any], mask: np.ndarray, path: Path) -> Path | None:
    series = [(n, s['torque_harmonics']) for n, s in report['shafts'].items()]
    series += [(f'{k} wrench', report[k]['torque_harmonics']) for k in ('engine', 'load') if k in report]
    series = [(n, h) for n, h in series if _oscillates(h)]   # flat torques say nothing here
    if not series:
        return None
    fig, (ax_b, ax_c) = plt.subplots(2, 1, figsize=(9, 7))
    n = len(series)
    width = 0.8 / n
    for i, (name, h) in enumerate(series):
        orders = np.asarray(h['orders'], dtype=float)
        amps = np.asarray([a if a is not None else np.nan for a in h['amplitude']])
        ax_b.bar(orders - 0.4 + width * (i + 0.5), amps, width=width, label=f"{name} (mean {h['mean']:.4g} N m)")
    ax_b.set_xlabel('harmonic order k  [per shaft revolution]')
    ax_b.set_ylabel(r'amplitude $A_k$  [N m]')
    ax_b.set_title(r'Torque harmonics over shaft angle, $T=\bar T+\sum A_k\cos(k\varphi+p_k)$ (seed 004 eqs. 4.1-4.3)')
    ax_b.set_xticks(np.asarray(series[0][1]['orders']))
    ax_b.legend(loc='best', framealpha=0.85)
    # One revolution: the resampled torque (all revolutions folded) and the truncated series.
    phi1 = np.linspace(0.0, 2 * math.pi, 361)
    for name, h in series[:4]:
        series_val = h['mean'] + sum(a * np.cos(k * phi1 + p) for k, a, p in
                                     zip(h['orders'], h['amplitude'], h['phase_rad']) if a is not None)
        line, = ax_c.plot(np.degrees(phi1), series_val, lw=1.6, label=f'{name}: series, {len(h["orders"])} harmonics')
        if name in sig.joint_names:
            j = sig.column(name)
            x, y = _wrapped(sig.position[mask, j], sig.effort[mask, j])
            ax_c.plot(x, y, color=line.get_color(), lw=0.5, alpha=0.35)
    ax_c.set_xlim(0, 360)
    ax_c.set_xticks(range(0, 361, 45))
    ax_c.set_xlabel('shaft angle mod 360  [deg]')
    ax_c.set_ylabel('torque  [N m]')
    ax_c.set_title('Torque over one revolution: recorded (thin, all revolutions) and Fourier series (thick)')
    ax_c.legend(loc='best', framealpha=0.85)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path


def _oscillates(h: dict[str, Any]) -> bool:
    if 'skipped' in h:
        return False
    amps = [a for a in h['amplitude'] if a is not None]
    return bool(amps) and max(amps) > 1e-6 * max(1.0, abs(h['mean'] or 0.0))


def work_precision_plot(rows: Sequence[dict[str, Any]], *, scene: str, path: str | Path,
                        error_key: str = 'err_speed_rel', cost_key: str = 'wall_per_sim_s') -> Path:
    """Log-log work-precision figure of one scene: error (x) vs cost (y), one line per
    (solver, fidelity); rows whose ``family`` is ``'baseline'`` (solve_ivp) are dashed."""
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
    solvers = sorted({rs[0]['solver'] for rs in groups.values()})
    colors = {s: plt.get_cmap('tab10')(i % 10) for i, s in enumerate(solvers)}
    markers = {'ideal': 'v', 'closed': 'D', 'exact': 'o', 'auto': '*'}
    with plt.rc_context(_STYLE):
        fig, ax = plt.subplots(figsize=(9, 6.2))
        for label, rs in sorted(groups.items(), key=lambda kv: (kv[1][0].get('family') == 'baseline', kv[0])):
            # connect in order of the knob (tolerance, or fixed step for rk4): loose -> tight
            rs = sorted(rs, key=lambda r: -(r.get('tol') or r.get('h') or 0.0))
            base = rs[0].get('family') == 'baseline'
            fid = rs[0].get('fidelity', 'exact')
            ax.loglog([r[error_key] for r in rs], [r[cost_key] for r in rs],
                      ls='--' if base else '-', marker='s' if base else markers.get(fid, 'o'),
                      ms=5 if fid != 'auto' or base else 9, lw=1.3 if base else 1.6,
                      color=colors[rs[0]['solver']], alpha=0.95 if fid in ('exact', 'auto') or base else 0.6,
                      label=f'solve_ivp {rs[0]["solver"]} (baseline)' if base else label)
        for lv in (1e-3, 1e-8):
            ax.axvline(lv, color='0.6', lw=0.8, ls=':')
        ax.set_xlabel('max relative error of output speed  [-]' if error_key == 'err_speed_rel'
                      else error_key)
        ax.set_ylabel('wall time per simulated second  [s/s]')
        ax.set_title(f'Work-precision: {scene}  (lower-left is better; markers: o exact, * auto, '
                     f'v ideal, D closed)', fontsize=10)
        ax.grid(True, which='both', alpha=0.25)
        ax.legend(loc='best', fontsize=7, framealpha=0.85, ncol=1 if len(groups) < 9 else 2)
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
