"""Hand-written compiled right-hand sides of two scenes, `bench.hooke_2dof_scene` and the
shipped `stiff` scene (the bench's reference for the price of evaluating a scene from data):
the same equations as kernel/rhs_nb.rhs with the scene's structure written out, no section
walk, no op dispatch.

stiff: the same without the joint, r = 1, s = 0: w1' = (T - Tl) / J1.

hooke_2dof:
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
from cvj_ros.physics.kernel.rhs_nb import rhs

__all__ = ['hooke_2dof_params', 'hooke_2dof_rhs', 'stiff_params', 'stiff_rhs', 'time_hooke_2dof_calls',
           'time_kernel_calls', 'time_stiff_calls', 'timing_states']


def timing_states(x0: np.ndarray, count: int = 16, seed: int = 0) -> np.ndarray:
    """``count`` states around ``x0`` (rows; angles +-0.5 rad, speeds +-5 %) for the timing
    loops: a loop over one fixed state would let the compiler hoist a hand-written rhs that
    does not read t out of the loop."""
    rng = np.random.default_rng(seed)
    n = (x0.size - 3) // 2 if x0.size % 2 else x0.size // 2
    ys = np.repeat(x0[None, :], count, axis=0).astype(float)
    ys[:, :n] += rng.uniform(-0.5, 0.5, (count, n))
    ys[:, n:2 * n] *= 1.0 + rng.uniform(-0.05, 0.05, (count, n))
    return np.ascontiguousarray(ys)


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
def time_hooke_2dof_calls(n, t, ys, p):
    """Call :func:`hooke_2dof_rhs` n times cycling through the states (rows of ``ys``), the
    time advancing by 1 ns a call, summing dy[2] + dy[3] so no call is loop-invariant or
    dead (the same loop as :func:`time_kernel_calls`); returns the sum."""
    dy = np.empty(ys.shape[1])
    m = ys.shape[0]
    acc = 0.0
    for k in range(n):
        hooke_2dof_rhs(t + k * 1e-9, ys[k % m], p, dy)
        acc += dy[2] + dy[3]
    return acc


@njit(cache=True)
def time_kernel_calls(n, t, ys, ip, fp):
    """The kernel's rhs (kernel/rhs_nb.rhs) in the loop of :func:`time_hooke_2dof_calls`."""
    dy = np.empty(ys.shape[1])
    m = ys.shape[0]
    acc = 0.0
    for k in range(n):
        rhs(t + k * 1e-9, ys[k % m], ip, fp, dy)
        acc += dy[2] + dy[3]
    return acc


def stiff_params(scene: object) -> np.ndarray:
    """(J0, J1, k, d, x M1, K1, Tl) of the shipped `stiff` scene (parsed Scene)."""
    el = {e.name: e for e in scene.driveline}           # type: ignore[attr-defined]
    eng, load = scene.engine, scene.load                 # type: ignore[attr-defined]
    return np.array([el['drive'].J, el['driven'].J, el['stiff_spring'].stiffness,
                     el['stiff_spring'].damping, float(eng.get('throttle', 1.0)) * eng['m1'],
                     eng['k1'], load['torque']])


@njit(cache=True)
def stiff_rhs(t, y, p, dy):
    """dy/dt of the stiff scene (two inertias, a linear spring, linear engine, constant load)."""
    te = p[4] - p[5] * y[2]
    th = y[0] - y[1]
    thd = y[2] - y[3]
    ts = p[2] * th + p[3] * thd
    dy[0] = y[2]
    dy[1] = y[3]
    dy[2] = (te - ts) / p[0]
    dy[3] = (ts - p[6]) / p[1]
    if y.shape[0] > 4:
        dy[4] = te * y[2]
        dy[5] = p[6] * y[3]
        dy[6] = p[3] * thd * thd


@njit(cache=True)
def time_stiff_calls(n, t, ys, p):
    """:func:`time_hooke_2dof_calls` for :func:`stiff_rhs`."""
    dy = np.empty(ys.shape[1])
    m = ys.shape[0]
    acc = 0.0
    for k in range(n):
        stiff_rhs(t + k * 1e-9, ys[k % m], p, dy)
        acc += dy[2] + dy[3]
    return acc
