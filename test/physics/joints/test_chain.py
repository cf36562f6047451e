"""Chain of joints: exact composition f2(f1(phi)) against hand composition, the chain rule
against finite differences (also in test_registry.py), a foreign JointModel, and seed
002's driveshaft (tulip-tripod + midshaft + fixed ball joint, eqs. 20-22)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from cvj_ros.physics.joints import JOINTS, JointEval, make_joint
from cvj_ros.physics.joints.chain import Chain

D = math.radians


class Wobble:
    """A joint written elsewhere: phi_out = phi + a sin(2 phi) (only the contract)."""

    kind = 'wobble'
    fidelity = 'exact'

    def __init__(self, a: float) -> None:
        self.a = a

    def evaluate(self, phi_in):
        phi = np.asarray(phi_in, dtype=float)
        return JointEval(phi + self.a * np.sin(2 * phi), 1 + 2 * self.a * np.cos(2 * phi),
                         -4 * self.a * np.sin(2 * phi))

    def scalar(self, phi_in: float):
        return (phi_in + self.a * math.sin(2 * phi_in), 1 + 2 * self.a * math.cos(2 * phi_in),
                -4 * self.a * math.sin(2 * phi_in))

    def params(self):
        return {'a': self.a}


def test_composition_is_exact() -> None:
    h = make_joint('hooke', beta=D(25.0))
    w = Wobble(0.05)
    chain = make_joint('chain', joints=[h, w, {'kind': 'gear', 'gear_ratio': 2.0}])
    phi = np.linspace(-10, 10, 201)
    ev = chain.evaluate(phi)
    e1 = h.evaluate(phi)
    e2 = w.evaluate(e1.phi_out)
    assert np.array_equal(ev.phi_out, e2.phi_out / 2.0)
    assert np.array_equal(ev.phi_mid, e1.phi_out)                 # shaft after the first joint
    # chain rule written out for three stages: ratio = r3 r2 r1, slope = ...
    r1, s1, r2, s2 = e1.ratio, e1.ratio_slope, e2.ratio, e2.ratio_slope
    assert np.allclose(ev.ratio, 0.5 * r2 * r1, rtol=1e-14, atol=0)
    assert np.allclose(ev.ratio_slope, 0.5 * (s2 * r1 ** 2 + r2 * s1), rtol=1e-12, atol=1e-15)
    # finite differences of the composed position (independent of the chain rule)
    hh = 1e-4
    num = (chain.evaluate(phi + hh).ratio - chain.evaluate(phi - hh).ratio) / (2 * hh)
    assert np.abs(num - ev.ratio_slope).max() < 1e-6
    r = chain.reactions(0.4, 20.0, 100.0)
    assert r['torque_out'] * chain.scalar(0.4)[1] == pytest.approx(100.0, rel=1e-12)
    assert 'joints[0].secondary_in' in r and 'joints[2].torque_housing' in r


def test_nonuniformity_of_hooke_plus_identity() -> None:
    # a Hooke joint followed by an identity stage: the closed-form Hooke amplitude
    b = D(30.0)
    chain = Chain([make_joint('hooke', beta=b), Wobble(0.0)])
    assert chain.nonuniformity() == pytest.approx(make_joint('hooke', beta=b).nonuniformity(), rel=1e-7)


def test_fidelity_passes_down() -> None:
    chain = make_joint('chain', fidelity='ideal', joints=[{'kind': 'hooke', 'beta': 0.5},
                                                          {'kind': 'gear', 'gear_ratio': 4.0}])
    assert chain.joints[0].fidelity == 'ideal' and chain.joints[1].fidelity == 'exact'
    assert chain.scalar(1.0) == (0.25, 0.25, 0.0)


@pytest.mark.skipif('tripod' not in JOINTS, reason='tripod joint (part B) not built')
def test_seed002_driveshaft_nonuniformity() -> None:
    # seed 002: tulip-tripod beta1 = 15 deg, r1/l = 0.11; bowl-balls joint treated with the
    # same law (its eqs. 12-18 equal the tripod's), beta2 = 47 deg, r2/l = 0.09.
    l = 0.7
    chain = make_joint('chain', fidelity='closed', joints=[
        {'kind': 'tripod', 'beta': D(15.0), 'r': 0.11 * l, 'l': l},
        {'kind': 'ideal_cv'},                                             # rigid midshaft
        {'kind': 'tripod', 'beta': D(47.0), 'r': 0.09 * l, 'l': l}])
    amp1 = 0.11 / 2 * math.tan(D(15)) * math.tan(D(7.5)) ** 2
    amp2 = 0.09 / 2 * math.tan(D(47)) * math.tan(D(23.5)) ** 2
    assert amp2 == pytest.approx(9.1e-3, rel=0.01)     # DESIGN.md 5: rad, not 0.009 deg
    nonu = chain.nonuniformity()
    # the two third harmonics are in phase (same zero), so the amplitudes add to first order
    assert nonu == pytest.approx(amp1 + amp2, rel=0.02)
