"""Compiled engine / load torque models (issue 9).

``engine_eval(t, omega, phi, ip, fp, ioff, foff) -> (T, dT/domega, dT/dphi)`` (N m,
N m s/rad, N m/rad); ``load_eval`` likewise (positive load torque resists). Codes and
parameter layout: ``kernel/layout.py``. Covered: linear engine (seed 004 eq. 3.23,
M = x M1 - K1 omega), constant load (seed 004 eq. 3.21, optional tanh(omega/s) sign).
"""
from __future__ import annotations

import math

from numba import njit

from cvj_ros.physics.kernel.layout import ENGINE_LINEAR, LOAD_CONSTANT


@njit(cache=True)
def engine_eval(t, omega, phi, ip, fp, ioff, foff):
    """Engine torque and slopes; ip[ioff] is the model code (rhs passes layout.H_ENGINE),
    fp[foff:] its parameters."""
    code = ip[ioff]
    if code == ENGINE_LINEAR:
        return fp[foff] * fp[foff + 1] - fp[foff + 2] * omega, -fp[foff + 2], 0.0
    return 0.0, 0.0, 0.0


@njit(cache=True)
def load_eval(t, omega, phi, ip, fp, ioff, foff):
    """Load torque (resisting) and slopes; ip[ioff] is the code (layout.H_LOAD)."""
    code = ip[ioff]
    if code == LOAD_CONSTANT:
        s = fp[foff + 1]
        if s == 0.0:
            return fp[foff], 0.0, 0.0
        th = math.tanh(omega / s)
        return fp[foff] * th, fp[foff] * (1.0 - th * th) / s, 0.0
    return 0.0, 0.0, 0.0
