"""Steady-state metrics of a sampled run (units follow the inputs: rad/s, rad/s^2, N m).

* speed nonuniformity delta = (omega_max - omega_min) / omega_mean per shaft
  (Davidbaev et al. 2023, coefficient of unevenness of rotation; dimensionless),
* amplitude A = (max - min) / 2 of speed, acceleration and torque (Davidbaev et al. 2023, section
  3.3.2 compares these amplitudes of drive and driven shafts, figs. 3.11-3.18).

All are taken over the *steady window* of :mod:`cvj_ros.physics.steady` (the one
definition shared by ``simulate``, ``run`` and ``analyze``): found by its criterion
(``transient=None``), or starting ``transient`` s after the first sample. Acceleration
is the numerical time derivative of the sampled speed over the whole record, then
windowed (:func:`cvj_ros.physics.signal.time_derivative`, second order, as ``analyze``),
so sample finely enough for it.
"""
from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cvj_ros.physics.steady import SteadyWindow, joint_state_window

FloatArray = NDArray[np.float64]


def steady_window(t: ArrayLike, names: list[str], velocity: ArrayLike, effort: ArrayLike, *,
                  transient: float | None = None) -> SteadyWindow:
    """The steady window of a JointState record (:func:`cvj_ros.physics.steady.joint_state_window`);
    ``transient`` (s) sets its start instead of the criterion."""
    return joint_state_window(t, names, velocity, effort, skip_s=transient)


def nonuniformity(omega: ArrayLike) -> float:
    """delta = (max - min) / mean of a speed series (-); inf if the mean is 0."""
    w = np.asarray(omega, dtype=float)
    mean = float(np.mean(w))
    span = float(np.max(w) - np.min(w))
    return span / abs(mean) if mean != 0.0 else float('inf')


def amplitude(x: ArrayLike) -> float:
    """(max - min) / 2 of a series (its unit)."""
    a = np.asarray(x, dtype=float)
    return 0.5 * float(np.max(a) - np.min(a))


def shaft_metrics(t: ArrayLike, names: list[str], velocity: ArrayLike, effort: ArrayLike, *,
                  transient: float | None = None,
                  window: SteadyWindow | None = None) -> dict[str, dict[str, float]]:
    """Per shaft over the steady window (``window``, else :func:`steady_window` with
    ``transient``): mean_speed (rad/s), delta (-), speed_amplitude
    (rad/s), acceleration_amplitude (rad/s^2), mean_torque and torque_amplitude (N m).
    acceleration_amplitude is NaN when the stamps are not strictly increasing (e.g. a bag
    that recorded a second run on the same domain): no derivative over a zero time step."""
    tt = np.asarray(t, dtype=float)
    vel = np.asarray(velocity, dtype=float)
    eff = np.asarray(effort, dtype=float)
    if tt.size < 2:
        mask = np.ones(tt.shape, dtype=bool)
    else:
        win = window or steady_window(tt, names, vel, eff, transient=transient)
        mask = win.mask(tt)
    increasing = bool(np.all(np.diff(tt) > 0.0))
    n_sh = len(names)
    if tt.size <= 2:
        acc = np.zeros((tt.size, n_sh))
    elif increasing:
        # all shafts at once: np.gradient along axis 0 does per element the arithmetic of
        # time_derivative on each column, so the same numbers
        acc = np.gradient(vel[:, :n_sh], tt, axis=0, edge_order=2)
    else:
        acc = np.full((tt.size, n_sh), np.nan)
    # windowed rows, one contiguous row per shaft: means see the same contiguous series as
    # np.mean(vel[mask, i]) (same summation order, same bits); max and min are exact anyway
    w_rows = np.ascontiguousarray(vel[mask, :n_sh].T)
    e_rows = np.ascontiguousarray(eff[mask, :n_sh].T)
    acc_w = acc[mask]
    w_max, w_min = w_rows.max(axis=1), w_rows.min(axis=1)
    a_span = acc_w.max(axis=0) - acc_w.min(axis=0)
    e_span = e_rows.max(axis=1) - e_rows.min(axis=1)
    out: dict[str, dict[str, float]] = {}
    for i, name in enumerate(names):
        mean = float(np.mean(w_rows[i]))
        span = float(w_max[i] - w_min[i])
        out[name] = {'mean_speed': mean,
                     'delta': span / abs(mean) if mean != 0.0 else float('inf'),  # nonuniformity()
                     'speed_amplitude': 0.5 * span,                               # amplitude()
                     'acceleration_amplitude': 0.5 * float(a_span[i]),
                     'mean_torque': float(np.mean(e_rows[i])),
                     'torque_amplitude': 0.5 * float(e_span[i])}
    return out


def summarize(trace: Any, *, transient: float | None = None,
              window: SteadyWindow | None = None) -> dict[str, dict[str, float]]:
    """:func:`shaft_metrics` of a :class:`cvj_ros.physics.simulate.Trace`."""
    return shaft_metrics(trace.t, trace.names, trace.velocity, trace.effort, transient=transient,
                         window=window)
