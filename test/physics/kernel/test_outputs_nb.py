"""kernel/outputs_nb.py: the lever hinge's earring angle computed alone (earring_angle) is
bit for bit the exact lever law's phi_out with twist 0 and an identity output stage, which
the intermediate-member fill evaluated before; the fill of a kavz685_lever run gives the
same bytes either way."""
from __future__ import annotations

import math

import numpy as np
import pytest

from cvj_ros.physics.kernel.joints_nb import lever_exact_nb
from cvj_ros.physics.kernel.layout import OP_LEVER_EXACT
from cvj_ros.physics.kernel.outputs_nb import (MID_EARRING, earring_angle, fill_mid_samples,
                                               mid_table)
from cvj_ros.physics.scene import find_scene, load_scene
from cvj_ros.physics.simulate import Simulation


def _bits(x: float) -> int:
    return int(np.array(x, dtype=np.float64).view(np.int64))


@pytest.mark.parametrize('alpha_deg', [0.0, 1e-6, 7.5, 20.0, 45.0, 89.9])
def test_earring_angle_is_the_exact_laws_first_stage_bit_for_bit(alpha_deg):
    a = math.radians(alpha_deg)
    ca, sa2 = math.cos(a), math.sin(a) ** 2
    rng = np.random.default_rng(int(alpha_deg * 1000))
    phis = [0.0, -0.0, 1e-300, -1e-300, math.pi / 2, -math.pi / 2, math.pi, -math.pi,
            2 * math.pi, 1e6, -1e6, *rng.uniform(-100.0, 100.0, 2000).tolist(),
            *rng.uniform(-1e-3, 1e-3, 200).tolist()]
    for phi in phis:
        want = lever_exact_nb(phi, ca, sa2, 0.0, 1.0, 0.0)[0]
        assert _bits(earring_angle(phi, ca)) == _bits(want), (phi, alpha_deg)


def test_fill_of_a_lever_hinge_run_is_unchanged():
    """The earring's angle and speed over a kavz685_lever run (2001 samples), by the
    earring row and by the same row on the exact law (the code the fill used before)."""
    sim = Simulation(load_scene(find_scene('kavz685_lever')))
    tr = sim.run(0.5, sample_dt=0.00025)
    mtab, mfp, python = mid_table(sim.driveline)
    assert mtab.shape[0] == 1 and mtab[0, 2] == MID_EARRING and not python
    old = mtab.copy()
    old[:, 2] = OP_LEVER_EXACT
    pos_a, vel_a = tr.position.copy(), tr.velocity.copy()
    pos_b, vel_b = tr.position.copy(), tr.velocity.copy()
    pos_a[:, mtab[0, 0]] = vel_a[:, mtab[0, 0]] = np.nan
    pos_b[:, mtab[0, 0]] = vel_b[:, mtab[0, 0]] = np.nan
    fill_mid_samples(pos_a, vel_a, mtab, mfp)
    fill_mid_samples(pos_b, vel_b, old, mfp)
    assert np.isfinite(pos_a).all() and np.isfinite(vel_a).all()
    assert pos_a.tobytes() == pos_b.tobytes() and vel_a.tobytes() == vel_b.tobytes()
    assert pos_a.tobytes() == tr.position.tobytes() and vel_a.tobytes() == tr.velocity.tobytes()
