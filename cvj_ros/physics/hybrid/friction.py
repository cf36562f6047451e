"""Coulomb friction with stick and slip modes (clutch, brake).

Capacity (Modelica.Mechanics.Rotational.Components.Clutch / Brake, Otter, Elmqvist &
Mattsson 1999): the friction torque of a pack with effective geometry ``cgeo`` (m: mean
friction radius times the number of friction interfaces) under the normal force
fn = fn_max * f_n, f_n in 0..1, is

    T_kinetic = mu_k cgeo fn,        T_static = mu_s cgeo fn      (N m).

Modes (Modelica ``PartialFriction``: Backward / Stuck / Forward with ``pre(mode)``):
``FORWARD`` (+1) slips with slip speed s > 0 and transmits +T_kinetic; ``BACKWARD`` (-1)
the mirror; ``STUCK`` (0) holds s = 0 exactly while the torque it must transmit to stay stuck,
T_stuck, satisfies |T_stuck| <= T_static. :func:`decide_mode` is the mode choice at an
event (a located zero of the slip speed, a stuck-torque margin, or a command step).
"""
from __future__ import annotations

from dataclasses import dataclass

from cvj_ros.errors import SceneError

__all__ = ['BACKWARD', 'FORWARD', 'STUCK', 'CoulombPack', 'decide_mode', 'mode_name']

FORWARD = 1
STUCK = 0
BACKWARD = -1
_NAMES = {FORWARD: 'slip+', STUCK: 'stuck', BACKWARD: 'slip-'}


def mode_name(mode: int) -> str:
    """'slip+', 'stuck' or 'slip-'."""
    return _NAMES[mode]


@dataclass(frozen=True)
class CoulombPack:
    """Friction pack: mu_s >= mu_k > 0 (-), cgeo (m) > 0, fn_max (N) > 0 (Modelica names)."""

    mu_s: float
    mu_k: float
    cgeo: float
    fn_max: float

    def __post_init__(self) -> None:
        for key in ('mu_k', 'cgeo', 'fn_max'):
            v = getattr(self, key)
            if not (v > 0.0 and v < float('inf')):
                raise SceneError(key, f'must be > 0 and finite, got {v!r}')
        if not (self.mu_s >= self.mu_k and self.mu_s < float('inf')):
            raise SceneError('mu_s', f'must be >= mu_k ({self.mu_k}) and finite, got {self.mu_s!r}')

    @property
    def max_torque(self) -> float:
        """Kinetic capacity at full normal force, mu_k cgeo fn_max (N m)."""
        return self.mu_k * self.cgeo * self.fn_max

    def kinetic(self, f_n: float) -> float:
        """T_kinetic = mu_k cgeo fn_max f_n (N m)."""
        return self.mu_k * self.cgeo * self.fn_max * f_n

    def static(self, f_n: float) -> float:
        """T_static = mu_s cgeo fn_max f_n (N m)."""
        return self.mu_s * self.cgeo * self.fn_max * f_n


def decide_mode(slip: float, stuck_torque: float, static_capacity: float) -> int:
    """Mode at an event: sign of a nonzero ``slip`` (rad/s); at slip 0, STUCK when
    |stuck_torque| <= static_capacity (N m) and the capacity is > 0 (an open pack never
    sticks), else the direction the excess torque drives
    the slip (FORWARD when stuck_torque > capacity). Pass slip = 0.0 for a located zero."""
    if slip > 0.0:
        return FORWARD
    if slip < 0.0:
        return BACKWARD
    if static_capacity > 0.0 and abs(stuck_torque) <= static_capacity:
        return STUCK
    return FORWARD if stuck_torque > 0.0 else BACKWARD
