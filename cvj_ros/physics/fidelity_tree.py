"""Fidelity choice for a vehicle scene's springs and tyres (the tree of cvj_ros.physics.tree).

Springs. The chain rule of cvj_ros.physics.fidelity (rigid when the quasi-static error
e = r^2/(1 - r^2), r = omega_band/omega_n, is within the accuracy target) with the
adjacent inertias of a tree: a spring joins the end of one rigid group (generalised
coordinates u, mass matrix M: a differential makes a group 2-DOF) to the first shaft of
another. Its end angle moves along c = d(phi_end)/du, so the inertia it sees is the
apparent inertia 1/J = c^T M^-1 c (mobility of a multi-body system at one coordinate);
for one spring between two free groups the only non-zero linearised frequency is exactly

    omega_n^2 = c_spring (c_l^T M_l^-1 c_l + c_r^T M_r^-1 c_r).

Tyres. A gripping tyre ties the vehicle's mass to its wheels (omega r = v): each group
holding wheels gets the body's kinetic energy 1/2 m v^2 with v the mean contact speed of
its wheels, M += m g g^T, g = mean(r a_w row_w). More inertia lowers omega_n, so this
grip limit is the conservative one of the two (a freely slipping tyre adds nothing); it
is exact for one group of wheels and counts the body once per group otherwise. Both
omega_n are reported. Averaged, as the chain rule, over 16 angles of every coordinate;
the operating speed is the engine's in the tree's initial state (rolling at the vehicle's
initial speed).

Tyre relaxation (Pacejka 2012, ch. 7: slip relaxation length sigma, time constant
tau = sigma/|v|). It is the standstill regularisation of the slip ratio, so it is always
kept; the report gives what an instantaneous slip would cost at the excitation band, the
first-order lag's amplitude error e = 1 - 1/sqrt(1 + (omega_band tau)^2) (1 at v = 0).
"""
from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from cvj_ros.physics.scene import Scene, Spring, Wheel, iter_elements

__all__ = ['tree_operating_speed', 'tree_spring_inertias', 'tyre_relaxation_bounds']

N_ANGLES = 16


def _tree(scene: Scene, joint_levels: Mapping[str, str]) -> Any:
    """The tree with every spring elastic and the joints at ``joint_levels``."""
    from cvj_ros.physics.tree import TreeDriveline
    levels = dict(joint_levels)
    levels.update({el.name: 'elastic' for el in iter_elements(scene.driveline) if isinstance(el, Spring)})
    return TreeDriveline(scene, levels)


def tree_operating_speed(scene: Scene, joint_levels: Mapping[str, str]) -> float:
    """|engine speed| (rad/s) of the tree's initial state."""
    dl = _tree(scene, joint_levels)
    return abs(float(dl.engine_omega(dl.x0)))


def _group_matrix(dl: Any, kin: Any, g: int, body: bool) -> np.ndarray:
    """Mass matrix of group ``g`` in its coordinates (TreeDriveline._accelerations'
    assembly), with the grip limit's body term when ``body``."""
    coords, secs = dl._groups[g]
    k = len(coords)
    m = np.zeros((k, k))
    for s in secs:
        r = np.asarray(kin.rows[s])
        m += kin.ends[s][3] * np.outer(r, r)
    for i, p in dl._group_spiders[g]:
        m[i, i] += p
    if body:
        wheels = [w for w in dl.wheels if dl._group_of[w.section] == g]
        if wheels:
            grad = np.zeros(k)
            for w in wheels:
                grad += w.tyre.radius * kin.ends[w.section][1] * np.asarray(kin.rows[w.section])
            grad /= len(wheels)
            m += dl.body.mass * np.outer(grad, grad)
    return m


def tree_spring_inertias(scene: Scene, joint_levels: Mapping[str, str]
                         ) -> dict[str, dict[str, float]]:
    """Per spring of the tree: apparent inertias (kg m^2) on its left (end of its group)
    and right side, free tyres (``j_left``, ``j_right``) and gripping tyres
    (``j_left_grip``, ``j_right_grip``); module docstring."""
    dl = _tree(scene, joint_levels)
    n = dl.n_dof
    sums: dict[str, list[float]] = {law.name: [0.0, 0.0, 0.0, 0.0] for law, _l, _r in dl.springs}
    for q in np.linspace(0.0, 2.0 * math.pi, N_ANGLES, endpoint=False):
        x = dl.x0.copy()
        x[:n] += q
        kin = dl._kinematics(x)
        for law, left, right in dl.springs:
            c_l = kin.ends[left][1] * np.asarray(kin.rows[left])
            c_r = np.asarray(kin.rows[right])
            acc = sums[law.name]
            for k, body in enumerate((False, True)):
                m_l = _group_matrix(dl, kin, dl._group_of[left], body)
                m_r = _group_matrix(dl, kin, dl._group_of[right], body)
                acc[2 * k] += 1.0 / float(c_l @ np.linalg.solve(m_l, c_l))
                acc[2 * k + 1] += 1.0 / float(c_r @ np.linalg.solve(m_r, c_r))
    return {name: {'j_left': v[0] / N_ANGLES, 'j_right': v[1] / N_ANGLES,
                   'j_left_grip': v[2] / N_ANGLES, 'j_right_grip': v[3] / N_ANGLES}
            for name, v in sums.items()}


def tyre_relaxation_bounds(scene: Scene, band: float) -> dict[str, dict[str, float]]:
    """Per wheel: relaxation time constant tau = sigma/|v0| (s; inf at standstill) and the
    lag amplitude error at ``band`` (rad/s) of replacing the relaxed slip by the
    instantaneous one (module docstring)."""
    v0 = abs(scene.vehicle.initial_speed or 0.0) if scene.vehicle is not None else 0.0
    out = {}
    for el in iter_elements(scene.driveline):
        if isinstance(el, Wheel):
            sigma = el.relaxation_length
            tau = sigma / v0 if v0 > 0.0 else math.inf
            err = 1.0 - 1.0 / math.sqrt(1.0 + (band * tau) ** 2) if math.isfinite(tau) else 1.0
            out[el.name] = {'time_constant_s': tau, 'lag_error': err}
    return out
