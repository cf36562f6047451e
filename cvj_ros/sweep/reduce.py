"""A run's steady window, shaft metrics and energy residual in two compiled calls
(:func:`cvj_ros.physics.kernel.reduce_nb.steady_start` and ``window_metrics``; one,
``reduce_lean``, with the members' speeds), the same
floats bit for bit as the numpy path of :func:`cvj_ros.sweep.run.simulation_row`
(steady.joint_state_window, metrics.summarize, Trace.max_energy_residual). The batched
sweep uses it; the per-variant path keeps the numpy functions (the reference the tests
compare with).

The window reads only the first shaft's speed and the torques, so a caller may fill the
other speeds (the lever hinge's earring: ``fill``) only from the row before the window on,
all the metrics read. A ``fill`` that names its members (``fill.members``: pos, mtab, mfp)
has the window, their speeds (``reduce_nb.fill_mid_speeds``, without the member angles)
and the metrics computed in one compiled call (``reduce_nb.reduce_lean``). The slices'
Hann-weighted means stay numpy's ``np.dot`` (OpenBLAS;
see reduce_nb). Records the compiled reduction does not cover return None and take the
numpy path: a ``--transient`` start, fewer than 3 or more than :data:`MAX_SAMPLES`
samples (numpy's reductions of longer series sum in buffer-sized blocks, not replicated),
times not strictly increasing, slices too few or too short for the criterion, a non-finite
speed or torque.
"""
from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np

from cvj_ros.physics import steady
from cvj_ros.physics.steady import SteadyWindow, hann_mean, slice_bounds

__all__ = ['MAX_SAMPLES', 'checked_slices', 'compiled_reduction', 'load_entries']

#: longest record reduced compiled (numpy's reduction buffer, 8192 elements)
MAX_SAMPLES = 8192

_ENTRY: dict[str, Any] = {}


def _call(name: str, args: tuple[Any, ...]) -> Any:
    """reduce_nb's ``name`` through its cached entry point (same argument types every call)."""
    entry = _ENTRY.get(name)
    if entry is None:
        from cvj_ros.physics.kernel import entry_point_once, reduce_nb
        entry = _ENTRY[name] = entry_point_once(getattr(reduce_nb, name), args)
    return entry(*args)


Slices = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]

_SLICES: list[tuple[np.ndarray, Slices]] = []


def _slices(t: np.ndarray) -> Slices:
    """(lo, hi) of steady.slice_bounds(t) as int64 and the acceleration's coefficients
    (reduce_nb.gradient_table), kept for the last times seen (a template's variants share
    their sample times; one tuple, replaced whole, so threads sharing it read a consistent
    entry). ``t``: 3..MAX_SAMPLES strictly increasing times."""
    last = _SLICES[0] if _SLICES else None
    if last is not None and last[0].size == t.size and np.array_equal(last[0], t):
        return last[1]
    _edges, lo, hi = slice_bounds(t)
    t = np.ascontiguousarray(t, dtype=np.float64).copy()
    gco, gx0 = _call('gradient_table', (t,))
    entry = (t, (lo.astype(np.int64), hi.astype(np.int64), gco, gx0))
    _SLICES[:] = [entry]
    return entry[1]


def checked_slices(t: np.ndarray) -> Slices | None:
    """The slices' (lo, hi) of the sample times ``t`` and their gradient table (gco, gx0:
    reduce_nb.gradient_table) when the compiled reduction covers them (3..MAX_SAMPLES
    samples, strictly increasing, enough slices of >= 2 samples), else None. A caller
    whose runs share ``t`` (a batched template's) computes it once."""
    m = t.size
    if not 3 <= m <= MAX_SAMPLES or not bool(np.all(t[1:] > t[:-1])):
        return None
    slices = _slices(t)
    lo, hi = slices[0], slices[1]
    if not (lo.size >= steady.MIN_SLICES and bool(np.all(hi - lo >= 2))):
        return None
    return slices


def compiled_reduction(trace: Any, options: Any, fill: Callable[[int], None] | None = None,
                       slices: Slices | None = None
                       ) -> tuple[SteadyWindow, dict[str, Any]] | None:
    """(window, summary) of ``trace`` as simulation_row computes them (the window's start,
    end and verdict; the summary's 'window', 'energy_residual', 'solver' and 'shafts'), or
    None when the record is not one the compiled reduction covers (module docstring).
    ``fill(i)``, if given, completes the speeds of every shaft but the first from row i on
    (called once the window is known, with the row before it); one with ``members``
    (module docstring) is not called: the compiled call fills the members' speeds. ``slices``: what
    :func:`checked_slices` gave for these very times (the caller vouches; not checked
    again)."""
    if options.transient is not None:
        return None
    t = trace.t
    m = t.size
    if slices is None:
        slices = checked_slices(t)
        if slices is None:
            return None
    lo, hi, gco, gx0 = slices
    vel, eff = trace.velocity, trace.effort
    names = trace.names
    n_sh = len(names)
    if n_sh < 1 or vel.shape != (m, n_sh) or eff.shape != (m, n_sh) \
            or not (vel.flags.c_contiguous and eff.flags.c_contiguous):
        return None
    w = vel[:, 0]
    means = np.array([hann_mean(w[a:b]) for a, b in zip(lo, hi)])
    out = np.empty(3 + 6 * n_sh)
    res = np.ascontiguousarray(trace.energy_residual, dtype=np.float64)
    members = getattr(fill, 'members', None)
    if members is not None:     # window, the members' speeds and metrics in one call
        pos, mtab, mfp = members
        if _call('reduce_lean', (t, pos, vel, eff, res, lo, hi, means, steady.DRIFT_TOL,
                                 steady.AMPLITUDE_TOL, steady.MIN_SLICES, steady.SPEED_FLOOR,
                                 steady.TORQUE_FLOOR, steady.FALLBACK_FRACTION, mtab, mfp,
                                 gco, gx0, out)) != 0:
            return None
    else:
        if _call('steady_start', (t, vel, eff, lo, hi, means, steady.DRIFT_TOL,
                                  steady.AMPLITUDE_TOL, steady.MIN_SLICES, steady.SPEED_FLOOR,
                                  steady.TORQUE_FLOOR, steady.FALLBACK_FRACTION, out)) != 0:
            return None
        if fill is not None:    # from the row before the window (reduce_nb.window_first_row)
            fill(max(0, min(int(np.searchsorted(t, out[1])), m - 2) - 1))
        if _call('window_metrics', (t, vel, eff, res, gco, gx0, out)) != 0:
            return None
    vals = out.tolist()
    is_steady = vals[0] == 1.0
    window = SteadyWindow(vals[1], float(t[-1]), is_steady, math.nan, math.nan, '', 0.0, 0, '')
    shafts = {name: {'mean_speed': vals[3 + 6 * i], 'delta': vals[4 + 6 * i],
                     'speed_amplitude': vals[5 + 6 * i],
                     'acceleration_amplitude': vals[6 + 6 * i],
                     'mean_torque': vals[7 + 6 * i], 'torque_amplitude': vals[8 + 6 * i]}
              for i, name in enumerate(names)}
    summary = {'window': {'steady': is_steady, 'start_s': vals[1]},
               'energy_residual': vals[2], 'solver': trace.solver, 'shafts': shafts}
    return window, summary


def load_entries() -> None:
    """Load the compiled reduction's entry points (both forms: with and without the
    members' speeds) on a tiny record of no members, for the argument types the sweep
    passes: a worker then loads them with its first template, not in a later chunk."""
    from types import SimpleNamespace
    t = np.linspace(0.0, 1.0, 31)
    ones = np.ones((31, 1))
    trace = SimpleNamespace(t=t, names=['a'], velocity=ones, effort=ones,
                            energy_residual=np.zeros(31), solver={})
    compiled_reduction(trace, SimpleNamespace(transient=None))
    compiled_reduction(trace, SimpleNamespace(transient=None), fill=SimpleNamespace(
        members=(ones, np.zeros((0, 4), np.int64), np.zeros(1))))
