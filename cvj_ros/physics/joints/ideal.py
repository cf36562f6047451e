"""Ideal constant-velocity joint: phi_out = phi_in. The cheapest fidelity of every CV joint.

Conventions: phi_out (rad) equals phi_in (rad) at every angle; ratio 1, slope 0.
No intermediate member, no secondary couple.
"""
from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from cvj_ros.physics.joints.base import JointEval, JointSpec, as_angle_array, check_finite, register
from cvj_ros.physics.joints.hooke import check_fidelity


class IdealCV:
    """Homokinetic joint: phi_out = phi_in, ratio 1, ratio slope 0. No intermediate member."""

    kind = 'ideal_cv'
    fidelity = 'ideal'
    mid_name: str | None = None

    def evaluate(self, phi_in: ArrayLike) -> JointEval:
        phi = as_angle_array(phi_in)
        return JointEval(phi_out=phi.copy(), ratio=np.ones_like(phi), ratio_slope=np.zeros_like(phi))

    def scalar(self, phi_in: float) -> tuple[float, float, float]:
        return phi_in, 1.0, 0.0

    def params(self) -> dict[str, float]:
        return {}

    def nonuniformity(self) -> float:
        """Amplitude of phi_out - phi_in (rad): 0."""
        return 0.0

    def reactions(self, phi_in: float, omega_in: float, torque_in: float) -> dict[str, float]:
        """Output torque (N m) = input torque (power balance with ratio 1)."""
        return {'torque_out': check_finite('torque_in', torque_in)}


def _factory(*, fidelity: str = 'ideal', **_geometry: float) -> IdealCV:
    # Geometry parameters of the joint it stands in for are accepted and ignored, so
    # any CV joint spec can be downgraded to the ideal fidelity unchanged.
    check_fidelity(fidelity, ('ideal',), 'ideal_cv')
    return IdealCV()


register(JointSpec(kind='ideal_cv', factory=_factory, fidelities=('ideal',), params={},
                   source='ideal constant-velocity joint, phi_out = phi_in (cheapest fidelity)'))
