"""Shaft runout / eccentricity: the once-per-revolution transmission error of an offset axis.

Geometry (the slotted-link drive of a Whitworth quick-return mechanism, any kinematics
textbook, e.g. Uicker, Pennock & Shigley, Theory of Machines and Mechanisms): the driving
member carries its contact (pin, roller, bolt) at radius r about the input axis; the
driven shaft turns about an axis offset by the eccentricity e < r, and its angle is the
direction of the contact seen from its own axis. The driven axis lies at e from the driving
one in the direction pi - phase (housing frame), so the contact points straight away from it
at x = 0, where x = phi_in + phase; with k = e/r the direction of r e^{i phi} + e e^{-i phase}
is::

    phi_out     = phi_in - atan2(k sin x, 1 + k cos x)
    ratio       = 1 - k (k + cos x) / D,          D = 1 + 2 k cos x + k^2
    ratio_slope = k (1 - k^2) sin x / D^2

The output turns monotonically (ratio between 1/(1 + k) and 1/(1 - k)) for 0 <= k < 1, and
phi_out - phi_in is bounded, so the position stays continuous over revolutions. Order
signature (the series of arg(1 + k e^{ix}) = Im log(1 + k e^{ix})):

    phi_out - phi_in = sum_{n >= 1} (-1)^n (k^n / n) sin(n x),

a first order of amplitude k (rad) and every higher order n falling as k^n / n; at small k
a pure once-per-revolution transmission error k sin(x + pi). With no runout (k = 0) it is
the identity. Fidelities: ``ideal`` (phi_out = phi_in, the runout switched off) and
``exact`` (the law above).
"""
from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from cvj_ros.errors import GeometryError
from cvj_ros.physics.joints.base import (JointEval, JointSpec, as_angle_array, check_finite,
                                         register)
from cvj_ros.physics.joints.hooke import check_fidelity

__all__ = ['Runout', 'runout_scalar']

RUNOUT_FIDELITIES = ('ideal', 'exact')


def runout_scalar(phi: float, k: float, phase: float) -> tuple[float, float, float]:
    """(phi_out rad, ratio -, ratio_slope 1/rad) of an offset axis with k = e/r (-) and
    ``phase`` (rad) at input angle ``phi`` (module docstring). Plain float function, also
    compiled by cvj_ros/physics/kernel/joints_nb.py."""
    x = phi + phase
    s, c = math.sin(x), math.cos(x)
    d = 1.0 + 2.0 * k * c + k * k
    return (phi - math.atan2(k * s, 1.0 + k * c), 1.0 - k * (k + c) / d,
            k * (1.0 - k * k) * s / (d * d))


class Runout:
    """Eccentric output axis: ``eccentricity`` e (m) at the driving radius ``radius`` r (m),
    0 <= e < r, ``phase`` (rad); phi_out = phi_in - atan2(k sin x, 1 + k cos x), k = e/r."""

    kind = 'runout'
    mid_name: str | None = None

    def __init__(self, eccentricity: float = 0.0, radius: float = 0.05, phase: float = 0.0, *,
                 fidelity: str = 'exact') -> None:
        r = check_finite('radius', radius)
        if not r > 0.0:
            raise GeometryError('radius', f'must be > 0 m, got {r:g} m')
        e = check_finite('eccentricity', eccentricity)
        if not 0.0 <= e < r:
            raise GeometryError('eccentricity', f'must be >= 0 and < the radius ({r:g} m), '
                                                f'got {e:g} m')
        self.eccentricity, self.radius = e, r
        self.phase = check_finite('phase', phase)
        self.fidelity = check_fidelity(fidelity, RUNOUT_FIDELITIES, self.kind)
        self.k = e / r if self.fidelity == 'exact' else 0.0

    def params(self) -> dict[str, float]:
        return {'eccentricity': self.eccentricity, 'radius': self.radius, 'phase': self.phase}

    def kernel_params(self) -> tuple[float, float]:
        """(k = e/r, phase rad): the arguments of :func:`runout_scalar` after phi."""
        return self.k, self.phase

    def evaluate(self, phi_in: ArrayLike) -> JointEval:
        phi = as_angle_array(phi_in)
        k = self.k
        x = phi + self.phase
        s, c = np.sin(x), np.cos(x)
        d = 1.0 + 2.0 * k * c + k * k
        return JointEval(phi - np.arctan2(k * s, 1.0 + k * c), 1.0 - k * (k + c) / d,
                         k * (1.0 - k * k) * s / (d * d))

    def scalar(self, phi_in: float) -> tuple[float, float, float]:
        if self.k == 0.0:
            return phi_in, 1.0, 0.0
        return runout_scalar(phi_in, self.k, self.phase)

    def nonuniformity(self) -> float:
        """Amplitude of phi_out - phi_in (rad): asin(k), reached where cos x = -k."""
        return math.asin(self.k)

    def reactions(self, phi_in: float, omega_in: float, torque_in: float) -> dict[str, float]:
        """Output torque (N m) = input torque / ratio (lossless power balance)."""
        t = check_finite('torque_in', torque_in)
        return {'torque_out': t / self.scalar(check_finite('phi_in', phi_in))[1]}


def _factory(*, fidelity: str = 'exact', eccentricity: float = 0.0, radius: float = 0.05,
             phase: float = 0.0, **extra: float) -> Runout:
    if extra:
        raise GeometryError(sorted(extra)[0], 'unknown parameter for runout '
                                              '(known: eccentricity, radius, phase)')
    return Runout(eccentricity, radius, phase, fidelity=fidelity)


register(JointSpec(
    kind='runout', factory=_factory, fidelities=RUNOUT_FIDELITIES,
    params={'eccentricity': 'm, offset e of the driven axis from the driving one, 0 <= e < '
                            'radius, default 0',
            'radius': 'm, radius r of the driving contact, default 0.05',
            'phase': 'rad, input angle of the offset (x = phi_in + phase), default 0'},
    source='eccentric (offset) axis of a slotted-link drive, Whitworth quick-return geometry '
           '(Uicker, Pennock & Shigley); order n amplitude k^n/n, k = e/r'))
