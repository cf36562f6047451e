"""Ideal constant-velocity joint: phi_out = phi_in. The cheapest fidelity of every CV joint."""
from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from cvj_ros.physics.joints.base import JointEval, JointSpec, as_angle_array, register


class IdealCV:
    """Homokinetic joint: phi_out = phi_in, ratio 1, ratio slope 0. No intermediate member."""

    kind = 'ideal_cv'
    fidelity = 'ideal'

    def evaluate(self, phi_in: ArrayLike) -> JointEval:
        phi = as_angle_array(phi_in)
        return JointEval(phi_out=phi.copy(), ratio=np.ones_like(phi), ratio_slope=np.zeros_like(phi))

    def scalar(self, phi_in: float) -> tuple[float, float, float]:
        return phi_in, 1.0, 0.0

    def params(self) -> dict[str, float]:
        return {}


def _factory(*, fidelity: str = 'ideal', **_ignored: float) -> IdealCV:
    return IdealCV()


register(JointSpec(kind='ideal_cv', factory=_factory, fidelities=('ideal',), params={},
                   source='DESIGN.md section 4 (cheapest fidelity)'))
