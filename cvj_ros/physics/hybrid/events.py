"""Witness functions and their zeros on a stepper's dense output.

A witness g(t, y) with a direction d (-1: it must cross from > 0 to <= 0, +1: from < 0 to
>= 0) triggers in a step [t_old, t_new] when its values at the two ends have crossed in that
direction (scipy.integrate's ``find_active_events``); its time is the zero of
tau -> g(tau, dense(tau)) in that step by Brent's method with xtol = rtol = 4 eps (scipy's
``solve_event_equation``). The earliest triggered witness wins; the step past it is
discarded and the integration restarts from dense(t_event) in the new mode.
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.optimize import brentq

__all__ = ['Witness', 'crossed', 'earliest', 'locate', 'same_instant']

_EPS = float(np.finfo(float).eps)


@dataclass(frozen=True)
class Witness:
    """``key`` names the transition it stands for; ``direction`` -1 or +1."""

    key: tuple
    direction: int


def same_instant(t: float, t0: float) -> bool:
    """t and t0 (s) are one instant: within the run loops' rounding rule for an event just
    before a command row (1e-12 max(1 s, |t|))."""
    return abs(t - t0) <= 1e-12 * max(1.0, abs(t))


def crossed(direction: int, g_old: float, g_new: float) -> bool:
    """The witness crossed zero in ``direction`` between two values."""
    if direction < 0:
        return g_old > 0.0 and g_new <= 0.0
    return g_old < 0.0 and g_new >= 0.0


def locate(g_of_t: Callable[[float], float], t_old: float, t_new: float,
           g_new: float) -> float:
    """Zero of ``g_of_t`` in (t_old, t_new] (s), Brent's method on the dense output."""
    if g_new == 0.0:
        return t_new
    return float(brentq(g_of_t, t_old, t_new, xtol=4 * _EPS, rtol=4 * _EPS))


def earliest(candidates: Sequence[tuple[float, int]]) -> tuple[float, int]:
    """(t, index) of the earliest located event; ties go to the lower index."""
    return min(candidates)
