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

With clutch, gearbox or wheel brakes (cvj_ros.physics.hybrid.tree) the springs stay
elastic; each gets the lowest omega_n of its locked modes (:func:`mode_tree_spring_omega_n`),
the frequency an explicit solver must step.

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

__all__ = ['mode_tree_spring_omega_n', 'tree_operating_speed', 'tree_spring_inertias',
           'tyre_relaxation_bounds']

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
    return _spring_inertias(_tree(scene, joint_levels))


def _spring_inertias(dl: Any) -> dict[str, dict[str, float]]:
    """:func:`tree_spring_inertias` of the built tree ``dl`` (a TreeDriveline or a ModeTree)."""
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


def mode_tree_spring_omega_n(scene: Scene, joint_levels: Mapping[str, str]) -> dict[str, float]:
    """Per spring of a vehicle tree with clutch, gearbox or wheel brakes
    (cvj_ros.physics.hybrid.tree): the lowest natural frequency (rad/s) of its locked modes,
    min over the gears (each forward gear and reverse) of sqrt(c (1/J_l + 1/J_r)) with the
    gripping tyres' apparent inertias of the mode with every clutch stuck in that gear (a lock
    merges rigid groups, and a constraint only lowers the mobility c^T M^-1 c), and 1/J = 0 on
    a side whose group holds a braked wheel (a stuck brake pins it). Clutch-pack
    differentials are taken slipping (a stuck pack could lower the figure further). Empty
    when the mode tree cannot be built (its run names why)."""
    from cvj_ros.errors import SceneError
    from cvj_ros.physics.fidelity import spring_omega_n
    from cvj_ros.physics.hybrid.chain import Mode
    from cvj_ros.physics.hybrid.friction import FORWARD, STUCK
    from cvj_ros.physics.hybrid.tree import ModeTree
    els = list(iter_elements(scene.driveline))
    kinds = {t: [el for el in els if getattr(el, 'type', '') == t]
             for t in ('clutch', 'gearbox', 'brake')}
    packs = [el.name for el in els if getattr(el, 'kind', '') == 'clutch_pack']
    gearbox = kinds['gearbox'][0] if len(kinds['gearbox']) == 1 else None
    gears = ([g for g in range(-1, len(gearbox.ratios) + 1) if g != 0] if gearbox is not None
             else [0])
    stiffness = {el.name: el.stiffness for el in els if isinstance(el, Spring)}
    low: dict[str, float] = {}
    for gear in gears:
        mode = Mode(clutch={c.name: STUCK for c in kinds['clutch']},
                    gear={g.name: gear for g in kinds['gearbox']},
                    brakes={b.name: FORWARD for b in kinds['brake']},
                    packs={p: FORWARD for p in packs},
                    offsets={i: 0.0 for i in range(len(kinds['clutch']) + len(kinds['gearbox']))})
        try:
            dl = ModeTree(scene, joint_levels, mode)
        except (SceneError, KeyError, ValueError, ZeroDivisionError):
            return {}
        braked = {dl._group_of[dl.wheels[w].section] for _b, w in dl.brakes.values()}
        sides = {law.name: (dl._group_of[left] in braked, dl._group_of[right] in braked)
                 for law, left, right in dl.springs}
        try:
            inertias = _spring_inertias(dl)
        except (ValueError, ZeroDivisionError):     # a singular group: no figure
            return {}
        for name, j in inertias.items():
            pin_l, pin_r = sides[name]
            w = spring_omega_n(stiffness[name], math.inf if pin_l else j['j_left_grip'],
                               math.inf if pin_r else j['j_right_grip'])
            low[name] = min(low.get(name, math.inf), w)
    return low


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
