"""Output of a fit: the text report, the JSON object and the measured-vs-fitted plot (PNG)."""
from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from cvj_ros.fit.data import SHIPPED_PREFIX, MeasuredOrders
from cvj_ros.fit.solve import LEVEL, FitResult

__all__ = ['result_dict', 'format_result', 'write_fit_plot']


def _num(x: float | None) -> float | None:
    return None if x is None or not math.isfinite(x) else float(x)


def _rms(result: FitResult) -> float:
    """Root mean square of the residuals the fit used (N m)."""
    return float(np.sqrt(np.mean(result.residuals[list(result.used)] ** 2)))


def result_dict(result: FitResult, measured: MeasuredOrders, *, scene: str,
                plot: str | None) -> dict[str, Any]:
    """The JSON object: ``fitted`` maps each PATH to its value (null when not identifiable),
    ``ci95`` to the half width of its 95 % interval, ``orders`` the residual per order."""
    return {
        'scene': scene, 'data': measured.source, 'data_kind': measured.kind,
        'fitted': {e.path: _num(e.value) for e in result.estimates},
        'ci95': {e.path: _num(e.ci) for e in result.estimates},
        'identifiable': {e.path: e.identifiable for e in result.estimates},
        'at_bound': {e.path: e.at_bound for e in result.estimates},
        'fields': {e.path: e.field for e in result.estimates},
        'orders': [{'order': k, 'measured': float(m), 'fitted': float(f), 'residual': float(f - m),
                    'used': k in result.used,
                    'measured_stderr': None if measured.stderr is None else float(measured.stderr[k])}
                   for k, (m, f) in enumerate(zip(result.measured, result.fitted))],
        'rms_residual': _rms(result),
        'sigma': _num(result.sigma), 'dof': result.dof,
        'singular_values': [float(s) for s in result.singular_values],
        'evaluations': result.evaluations, 'solver_status': result.status,
        'solver_message': result.message, 'plot': plot,
    }


def format_result(result: FitResult, measured: MeasuredOrders, *, scene: str,
                  plot: str | None) -> str:
    """Human-readable report: one line per parameter, one per order."""
    lines = [f'fit of {scene} to {measured.source} ({measured.kind}, mean and orders '
             f'1..{measured.orders}; {result.evaluations} model runs; {result.message})']
    width = max(len(e.path) for e in result.estimates)
    for e in result.estimates:
        if not e.identifiable:
            lines.append(f'  {e.path:<{width}}  not identifiable: the data do not depend on it '
                         f'in {e.lo:g}..{e.hi:g}')
            continue
        ci = f' +- {e.ci:.4g} ({100 * LEVEL:.0f} %)' if e.ci is not None else \
            ' (no interval: as many parameters as data)'
        bound = '  at the bound of its range' if e.at_bound else ''
        lines.append(f'  {e.path:<{width}}  {e.value:.6g}{ci}{bound}')
    se = measured.stderr
    lines.append('  order   measured N m   fitted N m   residual N m'
                 + ('   measured std. error N m' if se is not None else ''))
    for k, (m, f) in enumerate(zip(result.measured, result.fitted)):
        label = 'mean' if k == 0 else str(k)
        err = f'   {se[k]:10.4f}' if se is not None else ''
        note = '' if k in result.used else '   (not fitted)'
        lines.append(f'  {label:>5}   {m:12.4f}   {f:10.4f}   {f - m:+12.4f}{err}{note}')
    tail = ''
    if result.sigma is not None:
        plural = 's' if result.dof != 1 else ''
        tail = f', residual sigma {result.sigma:.4g} N m on {result.dof} degree{plural} of freedom'
    lines.append(f'  rms residual {_rms(result):.4g} N m{tail}')
    if plot:
        lines.append(f'plot: {plot}')
    return '\n'.join(lines)


def write_fit_plot(path: str | Path, result: FitResult, measured: MeasuredOrders, *,
                   scene: str) -> Path:
    """Bars of the measured and fitted mean and order amplitudes (N m) with the residuals."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    out = Path(path)
    if out.parent and not out.parent.exists():
        out.parent.mkdir(parents=True)
    k = np.arange(1, measured.orders + 1)
    fig, (ax0, ax1) = plt.subplots(1, 2, figsize=(10, 4), gridspec_kw={'width_ratios': [1, 4]})
    ax0.bar([-0.2], [result.measured[0]], 0.4, label='measured')
    ax0.bar([0.2], [result.fitted[0]], 0.4, label='fitted')
    ax0.set_xticks([0], ['mean'])
    ax0.set_ylabel('torque, N m')
    se = measured.stderr
    ax0.errorbar([-0.2], [result.measured[0]], yerr=None if se is None else [se[0]], fmt='none',
                 ecolor='k', capsize=3)
    ax1.bar(k - 0.2, result.measured[1:], 0.4, label='measured',
            yerr=None if se is None else se[1:], capsize=3)
    ax1.bar(k + 0.2, result.fitted[1:], 0.4, label='fitted')
    ax1.set_xticks(k)
    ax1.set_xlabel('order of the shaft angle')
    ax1.set_ylabel('amplitude, N m')
    ax1.legend()
    fitted = ', '.join(f'{e.path.split(".")[-1]} = {e.value:.4g}' + (f' +- {e.ci:.2g}' if e.ci else '')
                       if e.identifiable else f'{e.path.split(".")[-1]}: not identifiable'
                       for e in result.estimates)
    source = measured.source if measured.source.startswith(SHIPPED_PREFIX) else \
        Path(measured.source).name
    fig.suptitle(f'{scene} fitted to {source}: {fitted}', fontsize=9)
    fig.tight_layout()
    fig.savefig(out, metadata={'Software': None})
    plt.close(fig)
    return out
