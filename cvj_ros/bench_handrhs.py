"""A hand-written compiled rhs of `bench.hooke_2dof_scene` (the bench's reference for the price
of evaluating a scene from data): the same equations as kernel/rhs_nb.rhs with the scene's
structure written out, no section walk, no op dispatch.

State (q0, q1, w0, w1[, E_engine, E_load, E_damp]): engine shaft J0 with the linear engine
Te = x M1 - K1 w0 (Kavzarashvili engine line), a linear spring T = k (q0 - q1) + d (w0 - w1),
then section 1: a Hooke joint (phi, r, s) = hooke_stage(q1, cos beta) driving J1 with the
constant load Tl at its output, so M1 = J1 r^2, C1 = J1 r s and
w1' = (T - Tl r - C1 w1^2) / M1 (driveline.py's M(q) qddot + C(q) qdot^2 = Q).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from cvj_ros.physics.kernel.joints_nb import hooke_stage_nb

__all__ = ['hooke_2dof_params', 'hooke_2dof_rhs', 'time_hooke_2dof_calls']


def hooke_2dof_params(scene: object) -> np.ndarray:
    """(J0, J1, k, d, cos beta, x M1, K1, Tl) of `bench.hooke_2dof_scene` (parsed Scene)."""
    el = {e.name: e for e in scene.driveline}           # type: ignore[attr-defined]
    eng, load = scene.engine, scene.load                 # type: ignore[attr-defined]
    return np.array([el['engine_shaft'].J, el['load_shaft'].J, el['spring'].stiffness,
                     el['spring'].damping, math.cos(el['hooke'].params['beta']),
                     float(eng.get('throttle', 1.0)) * eng['m1'], eng['k1'], load['torque']])


@njit(cache=True)
def hooke_2dof_rhs(t, y, p, dy):
    """dy/dt of the 2-DOF engine-spring-Hooke-load model (module docstring), in place."""
    te = p[5] - p[6] * y[2]
    th = y[0] - y[1]
    thd = y[2] - y[3]
    ts = p[2] * th + p[3] * thd
    phi, r, s = hooke_stage_nb(y[1], p[4])
    m = p[1] * r * r
    c = p[1] * r * s
    dy[0] = y[2]
    dy[1] = y[3]
    dy[2] = (te - ts) / p[0]
    dy[3] = (ts - p[7] * r - c * y[3] * y[3]) / m
    if y.shape[0] > 4:
        dy[4] = te * y[2]
        dy[5] = p[7] * r * y[3]
        dy[6] = p[3] * thd * thd


@njit(cache=True)
def time_hooke_2dof_calls(n, t, y, p):
    """Call :func:`hooke_2dof_rhs` n times as outputs_nb.time_rhs_calls calls the kernel's rhs
    (t advancing by 1 ns, a checksum kept); returns the checksum."""
    dy = np.empty(y.shape[0])
    acc = 0.0
    for k in range(n):
        hooke_2dof_rhs(t + k * 1e-9, y, p, dy)
        acc += dy[0]
    return acc
