"""Coulomb pack capacities and the mode choice at an event (Modelica PartialFriction)."""
from __future__ import annotations

import pytest

from cvj_ros.errors import SceneError
from cvj_ros.physics.hybrid.friction import (BACKWARD, FORWARD, STUCK, CoulombPack,
                                             decide_mode)


def test_capacities_follow_the_normal_force_law() -> None:
    pack = CoulombPack(mu_s=0.4, mu_k=0.3, cgeo=0.2, fn_max=4000.0)
    assert pack.max_torque == pytest.approx(0.3 * 0.2 * 4000.0)
    assert pack.kinetic(0.5) == pytest.approx(120.0)
    assert pack.static(0.5) == pytest.approx(160.0)
    assert pack.kinetic(0.0) == 0.0


@pytest.mark.parametrize('kw, key', [
    (dict(mu_s=0.2, mu_k=0.3, cgeo=0.2, fn_max=1.0), 'mu_s'),
    (dict(mu_s=0.4, mu_k=0.0, cgeo=0.2, fn_max=1.0), 'mu_k'),
    (dict(mu_s=0.4, mu_k=0.3, cgeo=-1.0, fn_max=1.0), 'cgeo'),
    (dict(mu_s=0.4, mu_k=0.3, cgeo=0.2, fn_max=float('nan')), 'fn_max'),
])
def test_bad_pack_names_the_field(kw: dict, key: str) -> None:
    with pytest.raises(SceneError, match=f'^{key}:'):
        CoulombPack(**kw)


def test_mode_choice() -> None:
    assert decide_mode(1e-3, 0.0, 10.0) == FORWARD
    assert decide_mode(-1e-3, 0.0, 10.0) == BACKWARD
    assert decide_mode(0.0, 9.99, 10.0) == STUCK
    assert decide_mode(0.0, -10.0, 10.0) == STUCK
    assert decide_mode(0.0, 10.01, 10.0) == FORWARD
    assert decide_mode(0.0, -10.01, 10.0) == BACKWARD
    # an open pack never sticks, even without torque
    assert decide_mode(0.0, 0.0, 0.0) == BACKWARD or decide_mode(0.0, 0.0, 0.0) == FORWARD
    assert decide_mode(0.0, 0.0, 0.0) != STUCK
