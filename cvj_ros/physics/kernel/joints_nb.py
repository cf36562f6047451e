"""Compiled joint position functions: (phi_out, ratio, ratio_slope) per op code.

Each joint formula is written once, as a plain float function in its joint module
(``cvj_ros/physics/joints/*.py``, source paper and equation in that docstring); this module compiles
that same function with numba, so the numpy/Python API and the kernel cannot drift apart.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit
from numba.extending import overload


@overload(math.fmod)
def _math_fmod(x, y):
    """numba has no math.fmod; C fmod via np.fmod (exact, same result as math.fmod)."""
    def impl(x, y):
        return np.fmod(x, y)
    return impl


from cvj_ros.physics.joints.double_cardan import double_cardan_scalar
from cvj_ros.physics.joints.hooke import hooke_phased_scalar, hooke_stage_scalar
from cvj_ros.physics.joints.tripod import TWO_PI_3, tripod_closed_scalar, tripod_series_reduced
from cvj_ros.physics.joints.lever_hinge import lever_hinge_closed_scalar, lever_hinge_exact_scalar
from cvj_ros.physics.joints.runout import runout_scalar
from cvj_ros.physics.kernel.layout import (OP_GEAR, OP_HOOKE, OP_HOOKE_PHASED, OP_JOINT_IDENTITY,
                                          OP_LEVER_CLOSED, OP_LEVER_EXACT, OP_LEVER_RATIO,
                                          OP_TRIPOD_CLOSED,
                                          OP_TRIPOD_SERIES, OP_DOUBLE_CARDAN, OP_RUNOUT)


hooke_stage_nb = njit(cache=True)(hooke_stage_scalar)


@overload(hooke_stage_scalar)
def _hooke_stage_in_jit(phi, cos_beta):
    """Calls of the plain hooke_stage_scalar inside other compiled plain joint functions
    (double cardan) compile the same Python source."""
    def impl(phi, cos_beta):
        return hooke_stage_nb(phi, cos_beta)
    return impl
hooke_phased_nb = njit(cache=True)(hooke_phased_scalar)
double_cardan_nb = njit(cache=True)(double_cardan_scalar)
lever_closed_nb = njit(cache=True)(lever_hinge_closed_scalar)
lever_exact_nb = njit(cache=True)(lever_hinge_exact_scalar)
tripod_closed_nb = njit(cache=True)(tripod_closed_scalar)


def _lever_exact_ratio(phi_in, ca, sa2, twist, ca2, sa22):
    """(ratio -, ratio_slope 1/rad) of ``lever_hinge_exact_scalar`` (Davidbaev et al. 2023:
    two cross stages in series, tan(c) = tan(phi) / cos a, then the tilted second stage):
    the same operations in the same order without the output angle's last atan2, so the
    same two floats (test/physics/kernel/test_outputs_nb.py)."""
    s, c = math.sin(phi_in), math.cos(phi_in)
    den1 = 1.0 - sa2 * c * c
    h1 = ca / den1
    h2 = -ca * sa2 * 2.0 * s * c / (den1 * den1)
    c2 = phi_in + math.atan2(s * c * (1.0 - ca), ca * c * c + s * s) + twist
    s_, c_ = math.sin(c2), math.cos(c2)
    den2 = 1.0 - sa22 * s_ * s_
    g1 = ca2 / den2
    g2 = ca2 * sa22 * 2.0 * s_ * c_ / (den2 * den2)
    return g1 * h1, g2 * h1 * h1 + g1 * h2


#: inlined into the sample walk (outputs_nb.joint_ratio); called, as lever_exact_nb is,
#: from joint_eval (OP_LEVER_RATIO), so the inlined rhs stays small
lever_exact_ratio = njit(cache=True, inline='always')(_lever_exact_ratio)
lever_ratio_nb = njit(cache=True)(_lever_exact_ratio)
runout_nb = njit(cache=True)(runout_scalar)
# the two commonest exact stages, inlined into joint_eval (and so into the rhs): no call,
# no tuple return; the same source, the same bits
hooke_stage_inline_nb = njit(cache=True, inline='always')(hooke_stage_scalar)
tripod_series_reduced_inline_nb = njit(cache=True, inline='always')(tripod_series_reduced)


def _tripod_series_libm(phi_in, coeffs):
    """tripod_series_scalar compiled: the period reduced by libm fmod, as the Python joint
    does (tripod_series_scalar itself calls the plain tripod_series_reduced, which numba
    cannot resolve from a compiled caller), then the series."""
    return tripod_series_reduced_inline_nb(phi_in, math.fmod(phi_in, TWO_PI_3), coeffs)


tripod_series_nb = njit(cache=True)(_tripod_series_libm)
tripod_series_inline_nb = njit(cache=True, inline='always')(_tripod_series_libm)

#: TWO_PI_3 = C_HI + C_LO exactly, C_HI with 26 significant bits (the low 27 of the
#: mantissa cleared) and so C_LO with at most 27: k C_HI and k C_LO are exact for |k| < 2^25
_C_BITS = np.array([TWO_PI_3]).view(np.uint64)[0] & ~np.uint64((1 << 27) - 1)
C_HI = float(np.array([_C_BITS], dtype=np.uint64).view(np.float64)[0])
C_LO = TWO_PI_3 - C_HI
INV_TWO_PI_3 = 1.0 / TWO_PI_3
#: beyond this many periods (|phi| > 7e7 rad) the reduction falls back to fmod
REDUCE_Q_MAX = 33554432.0      # 2^25


@njit(cache=True, inline='always')
def fmod_two_pi_3(phi):
    """math.fmod(phi, TWO_PI_3), the same bits (signed zeros included), without the libm call:
    k = trunc(phi / TWO_PI_3) (from a product, corrected by one period below), then
    r = (phi - k C_HI) - k C_LO (Cody & Waite 1980 with an exact two-part constant). Both
    products are exact for |k| < 2^25, the first difference is exact (Sterbenz: phi and
    k C_HI within a factor 2), and phi - k TWO_PI_3 is a multiple of ulp(TWO_PI_3) below
    4 in magnitude, so representable: the second difference is exact too, as is the one-
    period correction when the product's rounding put k one off."""
    q = phi * INV_TWO_PI_3
    if not abs(q) < REDUCE_Q_MAX:
        return math.fmod(phi, TWO_PI_3)
    k = float(int(q))
    r = (phi - k * C_HI) - k * C_LO
    if phi >= 0.0:
        if r < 0.0:
            r += TWO_PI_3
        elif r >= TWO_PI_3:
            r -= TWO_PI_3
    elif r > 0.0:
        r -= TWO_PI_3
    elif r <= -TWO_PI_3:
        r += TWO_PI_3
    if r == 0.0:
        return math.copysign(0.0, phi)
    return r


@njit(cache=True, inline='always')
def tripod_series_at(phi, fp, off):
    """tripod_series_scalar with its nc coefficients at fp[off + 1:] and the period reduced
    by :func:`fmod_two_pi_3` (the same bits as its fmod); the slice lives here, not in
    joint_eval, so joint_eval stays small enough to inline."""
    nc = int(fp[off])
    return tripod_series_reduced_inline_nb(phi, fmod_two_pi_3(phi), fp[off + 1:off + 1 + nc])


@njit(cache=True, inline='always')
def joint_eval(code, phi, fp, off):
    """(phi_out rad, ratio -, ratio_slope 1/rad) of the joint op ``code`` at input angle phi."""
    if code == OP_HOOKE:
        return hooke_stage_inline_nb(phi, fp[off])
    if code == OP_DOUBLE_CARDAN:
        return double_cardan_nb(phi, fp[off], fp[off + 1], fp[off + 2])
    if code == OP_TRIPOD_SERIES:
        return tripod_series_at(phi, fp, off)
    if code == OP_TRIPOD_CLOSED:
        return tripod_closed_nb(phi, fp[off])
    if code == OP_LEVER_EXACT:
        return lever_exact_nb(phi, fp[off], fp[off + 1], fp[off + 2], fp[off + 3], fp[off + 4])
    if code == OP_LEVER_RATIO:     # nothing reads its output angle: not computed
        r, s = lever_ratio_nb(phi, fp[off], fp[off + 1], fp[off + 2], fp[off + 3], fp[off + 4])
        return math.nan, r, s
    if code == OP_LEVER_CLOSED:
        return lever_closed_nb(phi, fp[off], fp[off + 1], fp[off + 2], fp[off + 3], fp[off + 4])
    if code == OP_GEAR:
        k = fp[off]
        return phi * k, k, 0.0        # joints/gear.py Gear.scalar
    if code == OP_JOINT_IDENTITY:
        return phi, 1.0, 0.0
    if code == OP_HOOKE_PHASED:    # last: its code in the inlined rhs must not slow the others
        return hooke_phased_nb(phi, fp[off], fp[off + 1], fp[off + 2], fp[off + 3])
    if code == OP_RUNOUT:          # after the others, for the same reason
        return runout_nb(phi, fp[off], fp[off + 1])
    return phi, 1.0, 0.0   # unreachable: layout.build_model rejects unknown joints
