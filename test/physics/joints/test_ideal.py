"""Ideal CV joint: identity, accepts the geometry of the joint it replaces."""
from __future__ import annotations

import numpy as np
import pytest

from cvj_ros.errors import GeometryError
from cvj_ros.physics.joints import make_joint


def test_identity_and_downgrade() -> None:
    joint = make_joint('ideal_cv', fidelity='ideal', beta=0.3, r=0.02)
    phi = np.array([-3.0, 0.0, 2e5])
    ev = joint.evaluate(phi)
    assert np.array_equal(ev.phi_out, phi) and np.all(ev.ratio == 1) and np.all(ev.ratio_slope == 0)
    assert joint.reactions(0.1, 5.0, 12.0) == {'torque_out': 12.0}
    with pytest.raises(GeometryError, match='^fidelity'):
        make_joint('ideal_cv', fidelity='exact')
