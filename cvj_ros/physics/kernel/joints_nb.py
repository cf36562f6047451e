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
from cvj_ros.physics.joints.tripod import tripod_closed_scalar, tripod_series_scalar
from cvj_ros.physics.joints.lever_hinge import lever_hinge_closed_scalar, lever_hinge_exact_scalar
from cvj_ros.physics.joints.runout import runout_scalar
from cvj_ros.physics.kernel.layout import (OP_GEAR, OP_HOOKE, OP_HOOKE_PHASED, OP_JOINT_IDENTITY,
                                          OP_LEVER_CLOSED, OP_LEVER_EXACT, OP_TRIPOD_CLOSED,
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
tripod_series_nb = njit(cache=True)(tripod_series_scalar)
runout_nb = njit(cache=True)(runout_scalar)
# the two commonest exact stages, inlined into joint_eval (and so into the rhs): no call,
# no tuple return; the same source, the same bits
hooke_stage_inline_nb = njit(cache=True, inline='always')(hooke_stage_scalar)
tripod_series_inline_nb = njit(cache=True, inline='always')(tripod_series_scalar)


@njit(cache=True, inline='always')
def tripod_series_at(phi, fp, off):
    """tripod_series_scalar with its nc coefficients at fp[off + 1:]; the slice lives here, not
    in joint_eval, so joint_eval stays small enough to inline."""
    nc = int(fp[off])
    return tripod_series_inline_nb(phi, fp[off + 1:off + 1 + nc])


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
