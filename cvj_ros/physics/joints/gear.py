"""Constant-ratio joint for a gearbox stage or a final drive.

Convention: gear ratio i = omega_in / omega_out (-), so phi_out = phi_in / i (rad),
ratio dphi_out/dphi_in = 1/i, slope 0; both shafts at zero together. A negative i
reverses the sense of rotation (an external gear pair without idler). Lossless:
power balance gives torque_out = i torque_in (N m). (docs/contracts.md.)
"""
from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from cvj_ros.errors import GeometryError
from cvj_ros.physics.joints.base import JointEval, JointSpec, as_angle_array, check_finite, register
from cvj_ros.physics.joints.hooke import check_fidelity


class Gear:
    """Gear stage with ratio ``gear_ratio`` = omega_in / omega_out (-), nonzero and finite."""

    kind = 'gear'
    mid_name: str | None = None

    def __init__(self, gear_ratio: float, *, fidelity: str = 'exact') -> None:
        i = check_finite('gear_ratio', gear_ratio)
        if not 1e-6 <= abs(i) <= 1e6:
            raise GeometryError('gear_ratio', f'must satisfy 1e-6 <= |i| <= 1e6 (omega_in / omega_out), '
                                              f'got {i:g}')
        self.gear_ratio = i
        self.fidelity = check_fidelity(fidelity, ('exact',), self.kind)
        self._k = 1.0 / i

    def params(self) -> dict[str, float]:
        return {'gear_ratio': self.gear_ratio}

    def evaluate(self, phi_in: ArrayLike) -> JointEval:
        phi = as_angle_array(phi_in)
        return JointEval(phi * self._k, np.full_like(phi, self._k), np.zeros_like(phi))

    def scalar(self, phi_in: float) -> tuple[float, float, float]:
        return phi_in * self._k, self._k, 0.0

    def nonuniformity(self) -> float:
        """Velocity nonuniformity (rad): 0, the ratio is constant."""
        return 0.0

    def reactions(self, phi_in: float, omega_in: float, torque_in: float) -> dict[str, float]:
        """Lossless torques (N m): ``torque_out`` = i torque_in (power balance), and
        ``torque_housing`` = torque_out - torque_in, the moment the mount applies to the
        gearbox about the (coaxial) shaft axis. ``phi_in``, ``omega_in`` do not enter."""
        t1 = check_finite('torque_in', torque_in)
        t2 = self.gear_ratio * t1
        return {'torque_out': t2, 'torque_housing': t2 - t1}


def _factory(*, fidelity: str = 'exact', gear_ratio: float = 1.0, **extra: float) -> Gear:
    if extra:
        raise GeometryError(sorted(extra)[0], 'unknown parameter for gear (known: gear_ratio)')
    return Gear(gear_ratio, fidelity=fidelity)


register(JointSpec(kind='gear', factory=_factory, fidelities=('exact',),
                   params={'gear_ratio': '-, omega_in/omega_out, nonzero (negative reverses), default 1'},
                   source='constant ratio, power balance'))
