"""Compiled joint functions (cvj_ros/physics/kernel/joints_nb.py) against the plain joint
functions they compile: the same bits.

The tripod's period reduction is the kernel's own (fmod_two_pi_3: a two-part constant
instead of libm's fmod); it must give fmod's bits for every float, so the kernel's exact
tripod stays bit for bit the Python joint's (Tripod.scalar), whose fmod is libm's.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from cvj_ros.physics.joints.tripod import TWO_PI_3, Tripod
from cvj_ros.physics.kernel.joints_nb import (C_HI, C_LO, REDUCE_Q_MAX, fmod_two_pi_3,
                                             joint_eval)
from cvj_ros.physics.kernel.layout import OP_TRIPOD_SERIES


@njit(cache=False)
def _reduce_all(phis, out):
    for i in range(phis.size):
        out[i] = fmod_two_pi_3(phis[i])


def _bits(x: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(x).view(np.uint64)


def test_the_two_part_constant_is_exact():
    """C_HI + C_LO is TWO_PI_3 exactly, C_HI has 26 significant bits (so k C_HI is exact
    for |k| < 2^25) and C_LO at most 27."""
    assert C_HI + C_LO == TWO_PI_3
    for part, bits in ((C_HI, 26), (C_LO, 27)):
        m, _e = math.frexp(part)
        assert (abs(m) * 2.0 ** bits).is_integer()


def test_fmod_two_pi_3_has_fmods_bits():
    """Random angles over 1e-300..1e9 rad (both sides of the fallback at 2^25 periods), exact
    multiples of the period and their neighbours an ulp or two away (where the quotient's
    rounding puts k one off), multiples of C_HI, signed zeros, subnormals, inf and nan: the
    bits of math.fmod, element by element."""
    rng = np.random.default_rng(11)
    parts = [rng.uniform(-s, s, 20_000) for s in (1e-300, 1e-3, 1.0, 40.0, 1e4, 1e6, 7e7, 1e9)]
    k = np.arange(-3_000_000, 3_000_000, 97, dtype=float)
    near = k * TWO_PI_3
    parts += [near, np.nextafter(near, np.inf), np.nextafter(near, -np.inf),
              np.nextafter(np.nextafter(near, np.inf), np.inf), k * C_HI, k * C_HI + k * C_LO,
              np.array([0.0, -0.0, TWO_PI_3, -TWO_PI_3, 5e-324, -5e-324, np.inf, -np.inf, np.nan,
                        REDUCE_Q_MAX * TWO_PI_3, -REDUCE_Q_MAX * TWO_PI_3])]
    phis = np.concatenate(parts)
    got = np.empty_like(phis)
    _reduce_all(phis, got)
    want = np.array([math.fmod(p, TWO_PI_3) if math.isfinite(p) else math.nan for p in phis])
    nan = np.isnan(want)
    assert np.array_equal(np.isnan(got), nan)
    bad = np.flatnonzero(_bits(got[~nan]) != _bits(want[~nan]))
    assert bad.size == 0, phis[~nan][bad[:5]]


def test_kernel_exact_tripod_has_the_python_joints_bits():
    """joint_eval's exact tripod (series with the kernel's reduction) against Tripod.scalar
    (libm fmod) at Xiu et al. 2024's and Bugaru & Vasile 2021's geometries, angles from a
    standstill to 1e5 revolutions, both signs."""
    rng = np.random.default_rng(12)
    phis = np.concatenate([rng.uniform(-1e2, 1e2, 3000), rng.uniform(-6.3e5, 6.3e5, 3000),
                           np.arange(-30, 30) * TWO_PI_3])
    for beta_deg, r, l in ((20.0, 0.026, 0.7), (15.0, 0.0264, 0.24)):
        joint = Tripod(math.radians(beta_deg), r, l)
        coeffs = list(joint._coeff_list)
        fp = np.array([0.0, float(len(coeffs)), *coeffs])
        for phi in phis:
            assert joint_eval(OP_TRIPOD_SERIES, phi, fp, 1) == joint.scalar(phi), (beta_deg, phi)
