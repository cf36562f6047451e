"""Angular misalignment out of the bend plane: a two-joint propshaft whose second joint's bend
plane is turned by g from the first's (non-coplanar shafts), built from a scene file's keys
(``phase_deg``, ``bend_plane_deg``), against the closed-form order content.

Closed form (docs/imperfections.md). A single Hooke joint deviates by the exact series
d(theta) = sum_n (q^n / n) sin(2 n theta), q = tan^2(beta/2) (the series of
tan(phi_out) = tan(theta)/cos(beta), Bugaru & Vasile 2021 eq. 10). Joint 2 sees theta2 =
phi_mid + psi2 - gamma2 with psi2 = 90 deg (in phase) or 0 (90 deg out of phase) and gamma2 =
180 deg + g (Z) or g (W); to first order in q the pair gives

    phi_out - phi_in = Im(z e^{2 i phi_in}) + Im(z^2/2 e^{4 i phi_in}) + mean + O(q^3),
    z = q1 - s q2 e^{-2 i g},  s = +1 in phase, -1 out of phase,

so only even orders, order 2 of amplitude |z| = sqrt(q1^2 + q2^2 - 2 s q1 q2 cos 2g) (2 q
|sin g| for equal angles in phase) and order 4 of |z|^2 / 2. The next terms are cubic in q:
asserted |error| <= (q1 + q2)^3 (measured 0.04-0.25 of it).
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from cvj_ros.physics.driveline import Driveline
from cvj_ros.physics.ordinates import ordinate_harmonics
from cvj_ros.physics.scene import parse_scene


def propshaft(beta1: float, beta2: float, g: float, *, in_phase: bool = True,
              layout: str = 'Z') -> dict:
    """A rigid two-piece propshaft scene: Hooke, centre shaft, Hooke whose bend plane is
    turned by ``g`` deg out of the coplanar Z (180 deg) or W (0 deg) layout."""
    rear = {'beta_deg': beta2, 'phase_deg': 90.0 if in_phase else 0.0,
            'bend_plane_deg': (180.0 if layout == 'Z' else 0.0) + g}
    return {'name': 'propshaft', 'duration': 0.1, 'engine': {'model': 'linear', 'm1': 623.0},
            'load': {'model': 'constant', 'torque': 107.5}, 'initial': {'speed_rad_s': 39.0},
            'driveline': [{'type': 'inertia', 'name': 'gearbox', 'J': 0.1},
                          {'type': 'joint', 'name': 'front', 'kind': 'hooke',
                           'params': {'beta_deg': beta1}},
                          {'type': 'inertia', 'name': 'centre', 'J': 0.05},
                          {'type': 'joint', 'name': 'rear', 'kind': 'hooke', 'params': rear},
                          {'type': 'inertia', 'name': 'axle', 'J': 0.1}]}


@pytest.mark.parametrize('beta1, beta2, g, in_phase, layout', [
    (6.0, 6.0, 10.0, True, 'Z'), (6.0, 6.0, 10.0, True, 'W'), (6.0, 6.0, 0.0, True, 'Z'),
    (5.0, 8.0, 30.0, True, 'Z'), (6.0, 6.0, 10.0, False, 'Z'), (15.0, 15.0, 45.0, True, 'W'),
    (4.0, 4.0, 90.0, True, 'Z')])
def test_order_content_of_a_non_coplanar_propshaft(beta1: float, beta2: float, g: float,
                                                   in_phase: bool, layout: str) -> None:
    dl = Driveline.from_scene(parse_scene(propshaft(beta1, beta2, g, in_phase=in_phase,
                                                    layout=layout)))
    assert dl.n_dof == 1                 # one rigid section: the law the kernel walks
    m = 64
    phi = 2.0 * math.pi * np.arange(m) / m
    out = np.array([dl._section(0, float(p))[0] for p in phi])
    hm = ordinate_harmonics(out - phi)
    q1, q2 = (math.tan(math.radians(b) / 2.0) ** 2 for b in (beta1, beta2))
    z = q1 - (1.0 if in_phase else -1.0) * q2 * np.exp(-2j * math.radians(g))
    bound = (q1 + q2) ** 3
    # Im(w e^{i n phi}) = Im(w) cos(n phi) + Re(w) sin(n phi): a_n = Im w, b_n = Re w
    for n, w in ((2, z), (4, z * z / 2.0)):
        assert abs(hm.cos_coeffs[n - 1] - w.imag) <= bound, n
        assert abs(hm.sin_coeffs[n - 1] - w.real) <= bound, n
    odd = hm.amplitudes[0::2]
    assert np.max(odd) < 1e-14          # no odd order: each law has period pi in its angle
    if in_phase and beta1 == beta2:
        want = 2.0 * q1 * abs(math.sin(math.radians(g)))
        assert hm.amplitudes[1] == pytest.approx(want, abs=bound)


def test_equal_angles_in_phase_and_coplanar_stay_homokinetic() -> None:
    """g = 0: the scene's coplanar in-phase propshaft, every order below 1e-15 rad."""
    dl = Driveline.from_scene(parse_scene(propshaft(10.0, 10.0, 0.0)))
    phi = np.linspace(0.0, 2.0 * math.pi, 64, endpoint=False)
    out = np.array([dl._section(0, float(p))[0] for p in phi])
    assert np.max(np.abs(out - phi)) < 1e-14
