"""Runs whose numbers do not mean what they seem: one plain line each.

* :func:`fastest_mode`: the scene's fastest torsional oscillation - the largest imaginary
  part of the eigenvalues of the linearised driveline d(rhs)/dx at the initial state with
  the engine and load torques held (their slopes 0): for two inertias J1, J2 joined by a
  spring c with damper b, lambda = (-b +- sqrt(b^2 - 4 mu c)) / (2 mu), mu = J1 J2/(J1 + J2).
* :func:`coarse_step_line`: a sample or exchange step longer than half that mode's period
  cannot show the mode (fewer than two samples per period: Nyquist), so amplitudes,
  nonuniformity and steady-state checks read an aliased signal.
* :func:`stall_line`: a line whose mean speed is ~0 (|mean| < STALL_FRACTION of the speed
  it started at, or < STALL_RAD_S) stalled; its speed nonuniformity (w_max - w_min)/w_mean
  divides by ~0 and means nothing.
* :func:`trend_line`: on an accelerating or decelerating record the speed nonuniformity
  (w_max - w_min)/w_mean over the window includes the speed trend; when the least-squares
  line's change over the window is more than TREND_SHARE of a shaft's max - min, that
  share is named.
* :func:`angle_limit_lines`: a joint bent beyond its scene ``limits.max_angle_deg`` (else
  the recommended limit the ROS monitor uses, :data:`RECOMMENDED_MAX_ANGLE_DEG`), said
  offline as the monitor says it in a ROS run.
"""
from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any, NamedTuple

import numpy as np

__all__ = ['Mode', 'fastest_mode', 'coarse_step_line', 'stall_line', 'trend_line',
           'trend_line_of', 'slope_from_sums',
           'angle_limit_lines', 'STALL_FRACTION', 'STALL_RAD_S', 'TREND_SHARE']

#: a mean speed below this fraction of the initial speed counts as a stall
STALL_FRACTION = 0.01
#: ... or below this many rad/s when the line started (near) standstill
STALL_RAD_S = 0.05
#: a trend whose change over the window exceeds this share of max - min is named
TREND_SHARE = 0.5
#: joint parameters that hold its bend angle (SI, rad)
_ANGLE_PARAMS = ('beta', 'beta1', 'beta2', 'delta', 'alpha')


class Mode(NamedTuple):
    """A damped torsional mode: angular frequency (rad/s) and period (s)."""
    omega: float
    period: float


def fastest_mode(driveline: Any) -> Mode | None:
    """The fastest oscillating mode of ``driveline`` (None when no mode oscillates)."""
    n = int(driveline.n_dof)
    x0 = np.asarray(driveline.x0, dtype=float)
    jac = np.asarray(driveline.jacobian(0.0, x0, 0.0, 0.0), dtype=float)[:2 * n, :2 * n]
    if not np.all(np.isfinite(jac)):
        return None
    omega = float(np.max(np.abs(np.linalg.eigvals(jac).imag), initial=0.0))
    if omega <= 0.0:
        return None
    return Mode(omega, 2.0 * math.pi / omega)


def coarse_step_line(step: float, mode: Mode | None, what: str) -> str | None:
    """One line when ``step`` (s; ``what`` names it, e.g. 'sample step') is longer than half
    the period of ``mode``, else None."""
    if mode is None or step <= 0.5 * mode.period:
        return None
    return (f'{what} {step:.3g} s is too coarse for the scene\'s fastest mode ({mode.omega:.4g} '
            f'rad/s, period {mode.period:.3g} s): fewer than 2 samples per period, so that mode '
            f'is aliased in the speeds, amplitudes and nonuniformity; use <= '
            f'{0.5 * mode.period:.2g} s to resolve it')


def stall_line(mean_speeds: Mapping[str, float], initial_speed: float) -> str | None:
    """One line when every shaft's mean speed is ~0 (see the module docstring), else None."""
    if not mean_speeds:
        return None
    bound = max(STALL_FRACTION * abs(initial_speed), STALL_RAD_S)
    if any(not math.isfinite(v) or abs(v) >= bound for v in mean_speeds.values()):
        return None
    name, v = max(mean_speeds.items(), key=lambda kv: abs(kv[1]))
    return (f'stall: the line stopped (mean speeds within {bound:.3g} rad/s of 0, e.g. {name} '
            f'{v:.3g} rad/s, after {initial_speed:.4g} rad/s at the start): the torque cannot '
            f'drive it; speed nonuniformity, relative to a mean speed of ~0, means nothing here')


def trend_line(t: Any, speeds: Mapping[str, Any]) -> str | None:
    """One line naming the speed trend inside the window samples ``t`` (s) of ``speeds``
    (shaft -> rad/s) when it makes up more than :data:`TREND_SHARE` of a shaft's
    max - min (the shaft where the share is largest), else None. The trend is the
    least-squares line's slope (:func:`trend_line_of`)."""
    tt = np.asarray(t, dtype=float)
    if tt.size < 3 or not tt[-1] > tt[0]:
        return None
    fits: dict[str, tuple[float, float]] = {}
    for name, w in speeds.items():
        ww = np.asarray(w, dtype=float)
        if ww.shape != tt.shape or not np.all(np.isfinite(ww)):
            continue
        fits[name] = (float(np.polyfit(tt, ww, 1)[0]), float(ww.max() - ww.min()))
    return trend_line_of(fits, float(tt[-1] - tt[0]))


def slope_from_sums(n: int, sum_t: float, sum_tt: float, sum_w: float, sum_tw: float) -> float:
    """Least-squares slope of w over t from running sums (for a report that streams its
    samples): (n sum(t w) - sum(t) sum(w)) / (n sum(t^2) - sum(t)^2); NaN when the times
    do not spread."""
    den = n * sum_tt - sum_t * sum_t
    return (n * sum_tw - sum_t * sum_w) / den if n >= 2 and den > 0 else float('nan')


def trend_line_of(fits: Mapping[str, tuple[float, float]], duration: float) -> str | None:
    """:func:`trend_line` from per shaft (slope (rad/s^2), max - min (rad/s)) over a window
    of ``duration`` s: the line's change slope * duration is named when it exceeds
    :data:`TREND_SHARE` of max - min (the shaft where the share is largest)."""
    if not duration > 0:
        return None
    worst: tuple[float, str, float, float] | None = None
    for name, (slope, span) in fits.items():
        if not (math.isfinite(slope) and math.isfinite(span)):
            continue
        change = slope * duration
        if span > 0 and abs(change) > TREND_SHARE * span and (worst is None or abs(change) / span > worst[0]):
            worst = (abs(change) / span, name, slope, change)
    if worst is None:
        return None
    share, name, slope, change = worst
    return (f'speed trend: {name} {"accelerates" if slope > 0 else "decelerates"} by {change:+.4g} '
            f'rad/s over the window ({slope:+.4g} rad/s^2), {min(share, 1.0):.0%} of its max - min '
            f'speed: the speed nonuniformity there measures that trend, not a fluctuation')


def angle_limit_lines(scene: Any) -> list[str]:
    """One line per joint of ``scene`` (a parsed Scene) bent beyond its limit."""
    from cvj_ros.physics.monitor_metrics import RECOMMENDED_MAX_ANGLE_DEG
    out = []
    for el in getattr(scene, 'driveline', ()):
        params = getattr(el, 'params', None)
        if getattr(el, 'kind', None) is None or not isinstance(params, Mapping):
            continue
        angles = [abs(float(params[k])) for k in _ANGLE_PARAMS
                  if isinstance(params.get(k), (int, float))]
        limits = getattr(el, 'limits', None) or {}
        limit = limits.get('max_angle_deg', RECOMMENDED_MAX_ANGLE_DEG.get(el.kind))
        if not angles or limit is None:
            continue
        angle = math.degrees(max(angles))
        if angle > float(limit):
            source = ('its limits.max_angle_deg' if 'max_angle_deg' in limits
                      else f'the recommended limit for a {el.kind} joint')
            out.append(f'limit exceeded: joint {el.name} bent {angle:.4g} deg, above {source} '
                       f'{float(limit):.4g} deg')
    return out
