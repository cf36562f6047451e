"""Mass imbalance of the load shaft as the load's order-1 Fourier term (docs/imperfections.md):
an eccentric mass m at radius e on a horizontal shaft, at angle phi + phase from the
horizontal, sits at height e sin(phi + phase), so gravity resists the rotation with
T = m g e cos(phi + phase), i.e. ``model: fourier`` with mean M_c, cos [m g e cos(phase)],
sin [-m g e sin(phase)]. Simulated on the compiled kernel, its order-1 speed and shaft torque
are checked against the linearised closed form."""
from __future__ import annotations

import math

import numpy as np
import pytest

from cvj_ros.physics.load import load_from_spec
from cvj_ros.physics.ordinates import ordinate_harmonics
from cvj_ros.physics.scene import parse_scene
from cvj_ros.physics.simulate import Simulation

J1, J2 = 0.128, 0.161          # kg m^2, the KAVZ-685 unit (Davidbaev et al. 2023)
M1, MC, W0 = 623.0, 107.5, 39.0
K1 = (M1 - MC) / W0            # N m s/rad: steady speed W0 under MC
G = 9.81                       # m/s^2


def imbalance_load(me: float, phase: float) -> dict:
    """The load spec of a constant MC plus the gravity torque of imbalance ``me`` (kg m)."""
    return {'model': 'fourier', 'mean': MC, 'cos': [me * G * math.cos(phase)],
            'sin': [-me * G * math.sin(phase)]}


def test_fourier_term_is_the_gravity_torque() -> None:
    me, phase = 0.02, 0.8
    load = load_from_spec(imbalance_load(me, phase), seed=0, field='load')
    for phi in (0.0, 1.0, -2.5, 40.0):
        assert load.torque(0.0, W0, phi) == pytest.approx(
            MC + me * G * math.cos(phi + phase), rel=1e-14, abs=1e-12)


def _order1(tr, col: int, values: np.ndarray, revs: int = 4, m: int = 72) -> complex:
    """a_1 - i b_1 of ``values`` over the angle of column ``col`` (last whole revolutions)."""
    q = tr.position[:, col]
    q0 = 2.0 * math.pi * math.ceil((q[-1] - 2.0 * math.pi * revs) / (2.0 * math.pi))
    out = 0.0 + 0.0j
    for r in range(revs - 1):
        hm = ordinate_harmonics(np.interp(q0 + 2.0 * math.pi * (r + np.arange(m) / m), q, values))
        out += complex(hm.cos_coeffs[0], -hm.sin_coeffs[0])
    return out / (revs - 1)


@pytest.mark.parametrize('me', [0.005, 0.05])
def test_simulated_order_one_matches_the_linearised_response(me: float) -> None:
    """Rigid unit J1 - ideal coupling - J2, engine M1 - K1 omega: with u the speed deviation,
    (J1 + J2) u' + K1 u = -m g e cos(theta), theta = phi + phase, so the speed's order-1
    coefficient (of e^{i theta}) is U = -m g e / (K1 + i (J1 + J2) W0), and the coupling's
    output shaft carries the load plus the driven inertia's torque, m g e + i W0 J2 U. The
    angle deviation x = U / (i W0) enters the load as cos(theta + x): the neglected terms are
    at most O(|U| / W0) relative, bound 2 |U| / W0 (measured <= 0.04 of it for m e =
    0.005-3 kg m: the term linear in x goes to orders 0 and 2, not 1)."""
    phase = -1.1
    scene = {'name': 'imbalance', 'seed': 1, 'duration': 1.0, 'exchange_step': 0.001,
             'solver': {'method': 'dopri5', 'rtol': 1e-11, 'atol': 1e-12},
             'engine': {'model': 'linear', 'm1': M1}, 'load': imbalance_load(me, phase),
             'initial': {'speed_rad_s': W0},
             'driveline': [{'type': 'inertia', 'name': 'drive_shaft', 'J': J1},
                           {'type': 'joint', 'name': 'coupling', 'kind': 'ideal_cv'},
                           {'type': 'inertia', 'name': 'driven_shaft', 'J': J2}]}
    sim = Simulation(parse_scene(scene))
    assert sim.backend == 'kernel', sim.backend_note
    tr = sim.run(1.0, sample_dt=2e-4)
    i_in, i_out = tr.names.index('drive_shaft'), tr.names.index('coupling_output')
    u = -me * G / (K1 + 1j * (J1 + J2) * W0)
    rot = np.exp(1j * phase)
    bound = 2.0 * abs(u) / W0
    got_u = _order1(tr, i_in, tr.velocity[:, i_in])
    got_t = _order1(tr, i_out, tr.effort[:, i_out])
    want_t = (me * G + 1j * W0 * J2 * u) * rot
    assert abs(got_u - u * rot) <= bound * abs(u), (got_u, u * rot)
    assert abs(got_t - want_t) <= bound * abs(want_t), (got_t, want_t)
