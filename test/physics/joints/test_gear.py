"""Gear stage: phi_out = phi_in / i exactly, lossless torque, parameter errors."""
from __future__ import annotations

import numpy as np
import pytest

from cvj_ros.errors import GeometryError
from cvj_ros.physics.joints import make_joint


@pytest.mark.parametrize('i', [3.9, 0.8, -2.5])
def test_constant_ratio(i: float) -> None:
    gear = make_joint('gear', gear_ratio=i)
    phi = np.array([0.0, 1.0, -7.5, 1e6])
    ev = gear.evaluate(phi)
    assert ev.phi_out == pytest.approx(phi / i, rel=1e-15)
    assert np.all(ev.ratio == 1.0 / i) and np.all(ev.ratio_slope == 0.0) and ev.phi_mid is None
    # power balance: T_in omega_in = T_out omega_out
    r = gear.reactions(0.0, 100.0, 40.0)
    assert r['torque_out'] * (100.0 / i) == pytest.approx(40.0 * 100.0)
    assert r['torque_housing'] == pytest.approx(40.0 * i - 40.0)


@pytest.mark.parametrize('bad', [0.0, float('nan'), float('inf'), 'x'])
def test_bad_ratio(bad) -> None:
    with pytest.raises(GeometryError, match=r'^gear_ratio'):
        make_joint('gear', gear_ratio=bad)
