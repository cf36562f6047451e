"""Hooke (cardan) joint.

Conventions: bend angle beta between the shafts (0 <= beta < 90 deg). phi_in = 0 when
the driving yoke lies in the bend plane; phi_out = 0 at the same instant (the driven
yoke is then perpendicular to the bend plane). Positive rotation is the same sense
on both shafts (right hand about each shaft's own axis, pointing away from the joint
on the input side, towards it on the output side).

Position function (seed 002 eq. 10; DESIGN.md section 4)::

    tan(phi_out) = tan(phi_in) / cos(beta)

written without branch cuts as phi_out = phi_in + d(phi_in) with the bounded deviation

    d = atan2(sin(phi) cos(phi) (1 - cos b), cos(b) cos^2(phi) + sin^2(phi)),  |d| < pi/2,

so phi_out is continuous over any number of revolutions. Ratio and slope::

    ratio       = cos b / (sin^2 phi + cos^2 b cos^2 phi)        (= cos b/(1 - sin^2 b cos^2 phi))
    ratio_slope = -cos b sin^2 b sin(2 phi) / (sin^2 phi + cos^2 b cos^2 phi)^2

The ratio swings between cos(beta) (phi = pi/2) and 1/cos(beta) (phi = 0).
"""
from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from cvj_ros.physics.joints.base import JointEval, JointSpec, as_angle_array, check_range, register


class Hooke:
    """Single Hooke joint with bend angle ``beta`` (rad), 0 <= beta < pi/2."""

    kind = 'hooke'

    def __init__(self, beta: float, *, fidelity: str = 'exact') -> None:
        self.beta = check_range('beta', beta, lo=0.0, hi=math.pi / 2, hi_open=True, unit=' rad')
        self.fidelity = fidelity
        self._c = math.cos(self.beta)
        self._s2 = math.sin(self.beta) ** 2

    def params(self) -> dict[str, float]:
        return {'beta': self.beta}

    def evaluate(self, phi_in: ArrayLike) -> JointEval:
        phi = as_angle_array(phi_in)
        if self.fidelity == 'ideal':
            return JointEval(phi.copy(), np.ones_like(phi), np.zeros_like(phi))
        c = self._c
        s, co = np.sin(phi), np.cos(phi)
        den = c * c * co * co + s * s
        dev = np.arctan2(s * co * (1.0 - c), c * co * co + s * s)
        ratio = c / den
        slope = -c * self._s2 * np.sin(2.0 * phi) / (den * den)
        return JointEval(phi + dev, ratio, slope)

    def scalar(self, phi_in: float) -> tuple[float, float, float]:
        if self.fidelity == 'ideal':
            return phi_in, 1.0, 0.0
        c = self._c
        s, co = math.sin(phi_in), math.cos(phi_in)
        den = c * c * co * co + s * s
        dev = math.atan2(s * co * (1.0 - c), c * co * co + s * s)
        return phi_in + dev, c / den, -c * self._s2 * 2.0 * s * co / (den * den)


def hooke_ratio(phi_in: ArrayLike, beta: float) -> np.ndarray:
    """Closed-form velocity ratio cos b / (1 - sin^2 b cos^2 phi) (DESIGN.md section 4)."""
    phi = np.asarray(phi_in, dtype=float)
    return math.cos(beta) / (1.0 - math.sin(beta) ** 2 * np.cos(phi) ** 2)


def _factory(*, fidelity: str = 'exact', beta: float = 0.0, **_ignored: float) -> Hooke:
    return Hooke(beta, fidelity=fidelity)


register(JointSpec(kind='hooke', factory=_factory, fidelities=('ideal', 'exact'),
                   params={'beta': 'rad, bend angle, 0 <= beta < pi/2'},
                   source='seed 002 eq. 10; DESIGN.md section 4'))
