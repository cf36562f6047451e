"""Equations of motion of a branching vehicle driveline: differentials, wheels, tyres, body.

Sections. As in cvj_ros.physics.driveline, the driveline is cut at its elastic springs into
rigid *sections* (op lists of inertias and joints, cvj_ros.physics.sections). Here sections
form a tree: a differential ends its section (ring ratio i as a gear op phi_c = phi_in / i,
then the carrier inertia J_c) and starts two child sections, each beginning with its side
gear (J_side). A child's first-shaft angle follows its parent forward:

    q_L = phi_end(q_parent) + delta,   q_R = phi_end(q_parent) - delta

(delta = (phi_L - phi_R)/2, the differential's own coordinate; a locked one has none.)

Groups. Sections joined by differentials (no spring between) move as one *group* with
generalised coordinates u = [q_root, delta_1, ...]. Each section's speed is linear in the
group speeds, qdot_s = r_s . udot (r_parent scaled by a_end, plus +/-1 on delta), and its
acceleration qddot_s = r_s . uddot + k_s with k_s = a_end k_parent + b_end qdot_parent^2.
With each section's kinetic energy 1/2 M_s(q_s) qdot_s^2 (M_s, C_s = M_s'/2 as in
driveline.py) and the spiders' 1/2 P delta_dot^2 (cvj_ros.physics.differential), Lagrange
(equivalently Kane's method; r_s is the gradient of q_s, so the two agree) gives

    [sum_s M_s r_s r_s^T + sum_d P_d e_d e_d^T] uddot = sum_s r_s (Q_s - C_s qdot_s^2 - M_s k_s)
                                                        + bias torques of viscous couplings

Q_s: engine torque on the first inertia, spring torques (-T a_end left, +T right), the
tyre's -F_x r a_end at a wheel. The small SPD system is solved by Cholesky in plain Python
(no BLAS in the integration path).

Wheels and body. Each wheel carries a relaxed slip state kappa' and a magic-formula tyre
(cvj_ros.physics.tyre); the vehicle speed v follows cvj_ros.physics.vehicle. State::

    x = [u (n), udot (n), kappa' (wheels), v, (W_engine, W_damp, W_slip, W_road)]

Energy: E_kin (driveline + 1/2 m v^2) + E_el - E0 - W_engine + W_damp + W_slip + W_road = 0
with W_damp the springs' and viscous couplings' dissipation, W_slip = int sum F_x (omega r - v)
dt (tyre slip work) and W_road = int (F_roll + F_grade + F_aero) v dt.

JointState names: as driveline.py per branch, in depth-first order (a differential's
``<diff>_input``, ``<diff>_carrier``, ``<diff>_left`` and ``<diff>_right`` (side gears), then
the left branch's shafts to its wheel, then the right branch's); a wheel shaft carries the
wheel's name.
"""
from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from cvj_ros.errors import SceneError
from cvj_ros.physics.differential import Differential as DiffModel
from cvj_ros.physics.joints import JOINTS, make_joint
from cvj_ros.physics.scene import Differential, Inertia, Joint, Scene, Spring, Wheel
from cvj_ros.physics.sections import Op, Shaft, SpringLaw, section_kinematics
from cvj_ros.physics.tyre import TYRE_NO_LOAD, TYRE_OK, MagicFormula, Tyre
from cvj_ros.physics.vehicle import VehicleBody

__all__ = ['TreeDriveline', 'TreeSection']

FloatArray = NDArray[np.float64]
N_WORK = 4   # W_engine, W_damp, W_slip, W_road


@dataclass
class TreeSection:
    """One rigid section of the tree: op list, names, how it hangs on its parent."""

    ops: list[Op] = field(default_factory=list)
    names: list[str] = field(default_factory=list)
    parent: int = -1        # parent section through a differential, -1 = group root
    diff: int = -1          # the differential joining it to its parent
    sign: int = 0           # +1 left, -1 right branch
    coord: int = -1         # group root: its coordinate index
    end: tuple[str, int] = ('none', -1)   # ('wheel' | 'spring' | 'diff', index)


@dataclass(frozen=True)
class _DiffInfo:
    name: str
    model: DiffModel
    parent: int
    left: int
    right: int
    coord: int              # delta's coordinate, -1 when locked


@dataclass(frozen=True)
class _WheelInfo:
    name: str
    section: int
    tyre: Tyre
    share: float
    axle: int               # +1 front, -1 rear, 0 none


def _ratio_fn(k: float) -> Callable[[float], tuple[float, float, float]]:
    def fn(phi: float) -> tuple[float, float, float]:
        return phi * k, k, 0.0
    return fn


def _cholesky_solve(m: list[list[float]], f: list[float]) -> list[float]:
    """Solve M x = f for a small symmetric positive definite M (Cholesky M = L L^T, plain
    floats; only the lower triangle of M is read)."""
    n = len(f)
    low = [[0.0] * n for _ in range(n)]
    for i in range(n):
        li = low[i]
        for j in range(i + 1):
            lj = low[j]
            acc = m[i][j]
            for k in range(j):
                acc -= li[k] * lj[k]
            li[j] = math.sqrt(acc) if i == j else acc / lj[j]
    y = [0.0] * n
    for i in range(n):
        acc = f[i]
        li = low[i]
        for k in range(i):
            acc -= li[k] * y[k]
        y[i] = acc / li[i]
    x = [0.0] * n
    for i in reversed(range(n)):
        acc = y[i]
        for k in range(i + 1, n):
            acc -= low[k][i] * x[k]
        x[i] = acc / low[i][i]
    return x


class TreeDriveline:
    """Equations of motion of a vehicle scene (``scene.vehicle`` set); module docstring.

    Offers what cvj_ros.physics.simulate needs of a Driveline: ``x0``, ``n_dof``,
    ``rhs_sources``, ``energy``, ``energy_residual``, ``joint_states_fast``, ``fill_mid``,
    ``shaft_names``; and per-wheel outputs (:meth:`wheel_outputs`).
    """

    is_tree = True

    def __init__(self, scene: Scene, levels: Mapping[str, str], *, track_energy: bool = False) -> None:
        if scene.vehicle is None:
            raise SceneError('vehicle', 'a tree driveline needs a vehicle scene')
        self.scene = scene
        self.levels = dict(levels)
        self.track_energy = track_energy
        self.sections: list[TreeSection] = []
        self.springs: list[tuple[SpringLaw, int, int]] = []
        self.diffs: list[_DiffInfo] = []
        self.wheels: list[_WheelInfo] = []
        self.shafts: list[Shaft] = []
        self.joint_models: dict[str, Any] = {}
        self._lock_delta: dict[int, float] = {}     # locked differential -> its fixed delta (rad)
        self._n_coord = 0
        root = self._new_section(-1, -1, 0)
        self._add_chain(scene.driveline, root, 'driveline')
        self.shaft_names = [s.name for s in self.shafts]
        dup = {n for n in self.shaft_names if self.shaft_names.count(n) > 1}
        if dup:
            raise SceneError('driveline', f'shaft name {sorted(dup)[0]!r} made twice (a joint names its '
                                          'shafts <name>_input/_output/_<member>, a differential '
                                          '<name>_input/_carrier/_left/_right); rename one element')
        self._mid_index = [(i, i - 1) for i, sh in enumerate(self.shafts) if sh.role == 'mid']
        # groups: coordinates of each group, in coordinate order
        self.n_dof = self._n_coord
        v = scene.vehicle
        self.body = VehicleBody(mass=v.mass, grade_percent=v.grade_percent,
                                rolling_coeff=v.rolling_coeff,
                                drag_area=v.drag_coeff * v.frontal_area, air_density=v.air_density,
                                speed_scale=v.speed_scale, cg_height=v.cg_height,
                                wheelbase=v.wheelbase, front_share=v.front_share)
        self.n_wheel = len(self.wheels)
        # outside wheel loads (:meth:`set_wheel_torques`): None = the tyres give F_x
        self.wheel_torques: list[float] | None = None
        self._iv = 2 * self.n_dof + self.n_wheel          # index of v in x
        self._n_state = self._iv + 1 + (N_WORK if track_energy else 0)
        self._groups = self._make_groups()
        self._prepare_tables()
        self.x0 = self._initial_state()

    # --- construction -------------------------------------------------------------------

    @classmethod
    def from_scene(cls, scene: Scene, *, fidelity: Mapping[str, str] | None = None,
                   track_energy: bool = False) -> TreeDriveline:
        """Resolve fidelity (cvj_ros.physics.fidelity) and build; as Driveline.from_scene."""
        from cvj_ros.physics.fidelity import choose_fidelity
        if scene.has_modes:      # clutch, gearbox, brakes, commands: cvj_ros.physics.hybrid
            from cvj_ros.physics.hybrid.scene_keys import mode_gap
            raise SceneError(*mode_gap(scene))
        report = choose_fidelity(scene, overrides=fidelity)
        dl = cls(scene, report.levels, track_energy=track_energy)
        dl.fidelity_report = report
        return dl

    def _new_section(self, parent: int, diff: int, sign: int) -> int:
        sec = TreeSection(parent=parent, diff=diff, sign=sign)
        if parent < 0:
            sec.coord = self._n_coord
            self._n_coord += 1
        self.sections.append(sec)
        return len(self.sections) - 1

    def _add_op(self, s: int, op: Op, name: str) -> int:
        self.sections[s].ops.append(op)
        self.sections[s].names.append(name)
        return len(self.sections[s].ops) - 1

    def _add_chain(self, chain: tuple[Any, ...], s: int, path: str) -> None:
        for i, el in enumerate(chain):
            p = f'{path}[{i}]'
            if isinstance(el, Inertia):
                k = self._add_op(s, (el.J, None), el.name)
                self.shafts.append(Shaft(el.name, s, k, 'inertia'))
            elif isinstance(el, Joint):
                level = self.levels.get(el.name) or JOINTS[el.kind].fidelities[-1]
                try:
                    model = make_joint(el.kind, fidelity=level, **dict(el.params))
                except ValueError as exc:
                    raise SceneError(p, str(exc)) from None
                self.joint_models[el.name] = model
                k = self._add_op(s, (0.0, model.scalar), el.name)
                self.shafts.append(Shaft(f'{el.name}_input', s, k, 'input'))
                mid = getattr(model, 'mid_name', None)
                if mid:
                    self.shafts.append(Shaft(f'{el.name}_{mid}', s, k, 'mid', model))
                self.shafts.append(Shaft(f'{el.name}_output', s, k, 'output'))
            elif isinstance(el, Spring):
                if self.levels.get(el.name, 'elastic') == 'rigid':
                    continue
                if el.variation:
                    raise SceneError(f'{p}.stiffness_variation', 'not available in a vehicle '
                                                                 'scene yet (chain scenes only)')
                g = 0.5 * el.backlash
                law = SpringLaw(el.name, el.stiffness, el.damping,
                                el.k2 if el.law == 'progressive' else 0.0, g, el.backlash_smoothing * g)
                new = self._new_section(-1, -1, 0)
                self.sections[s].end = ('spring', len(self.springs))
                self.springs.append((law, s, new))
                s = new
            elif isinstance(el, Wheel):
                k = self._add_op(s, (el.J, None), el.name)
                self.shafts.append(Shaft(el.name, s, k, 'inertia'))
                tyre = Tyre(mu=el.mu, radius=el.radius, mf=MagicFormula(el.B, el.C, el.E),
                            sigma=el.relaxation_length)
                axle = {'front': 1, 'rear': -1}.get(el.axle or '', 0)
                self.sections[s].end = ('wheel', len(self.wheels))
                self.wheels.append(_WheelInfo(el.name, s, tyre, el.load_share, axle))
            elif getattr(el, 'type', '') in ('clutch', 'gearbox', 'brake'):
                s = self._add_mode_element(el, s, p)
            elif isinstance(el, Differential):
                model = self._diff_model(el)
                k = self._add_op(s, (0.0, _ratio_fn(1.0 / el.ratio)), el.name)
                self.shafts.append(Shaft(f'{el.name}_input', s, k, 'input'))
                k = self._add_op(s, (el.J_carrier, None), f'{el.name}_carrier')
                self.shafts.append(Shaft(f'{el.name}_carrier', s, k, 'inertia'))
                d = len(self.diffs)
                coord = -1
                if model.has_dof:
                    coord = self._n_coord
                    self._n_coord += 1
                self.sections[s].end = ('diff', d)
                sides = []
                for side, sign, branch in (('left', 1, el.left), ('right', -1, el.right)):
                    c = self._new_section(s, d, sign)
                    k = self._add_op(c, (el.J_side, None), f'{el.name}_{side}')
                    self.shafts.append(Shaft(f'{el.name}_{side}', c, k, 'inertia'))
                    sides.append((c, branch, f'{p}.{side}'))
                self.diffs.append(_DiffInfo(el.name, model, s, sides[0][0], sides[1][0], coord))
                for c, branch, bp in sides:
                    self._add_chain(branch, c, bp)

    def _add_mode_element(self, el: Any, s: int, path: str) -> int:
        """A clutch, gearbox or brake in section ``s``; returns the section the chain goes
        on in. Only the mode-aware tree (cvj_ros.physics.hybrid.tree) takes them."""
        raise SceneError(path, f'{el.type} {el.name!r}: stick/slip and gear modes run on the '
                               'mode-aware reference (`cvj-sim simulate`), not here')

    def _diff_model(self, el: Differential) -> DiffModel:
        """The differential's model (the mode-aware tree maps a clutch pack to locked or open)."""
        return DiffModel(kind=el.kind, ratio=el.ratio, J_carrier=el.J_carrier,
                         J_spider=el.J_spider, spider_ratio=el.spider_ratio, viscous=el.viscous)

    def _make_groups(self) -> list[tuple[list[int], list[int]]]:
        """Per group: (its coordinates, its sections), sections in tree order."""
        group_of: list[int] = []
        groups: list[tuple[list[int], list[int]]] = []
        for s, sec in enumerate(self.sections):
            if sec.parent < 0:
                groups.append(([sec.coord], [s]))
                group_of.append(len(groups) - 1)
            else:
                g = group_of[sec.parent]
                group_of.append(g)
                groups[g][1].append(s)
                c = self.diffs[sec.diff].coord if sec.diff >= 0 else -1
                if c >= 0 and c not in groups[g][0]:
                    groups[g][0].append(c)
        self._group_of = group_of
        return groups

    def _prepare_tables(self) -> None:
        """Per section: its ops as a tuple, its group and the local index of its joining
        differential's delta (-1: none); per group: its spider inertias by local index.
        Rows r_s are kept in group-local coordinates (a group has 1 + its differentials')."""
        self._sec_ops = [tuple(sec.ops) for sec in self.sections]
        self._group_size = [len(self._groups[g][0]) for g in self._group_of]
        local = {}
        for coords, _secs in self._groups:
            for i, c in enumerate(coords):
                local[c] = i
        self._sec_local = []
        for sec in self.sections:
            if sec.parent < 0 or sec.diff < 0:     # a root, or a locked link's output side
                self._sec_local.append(-1)
            else:
                c = self.diffs[sec.diff].coord
                self._sec_local.append(local[c] if c >= 0 else -1)
        self._group_spiders = [[(local[d.coord], d.model.spider_inertia) for d in self.diffs
                                if d.coord in coords and d.model.spider_inertia != 0.0]
                               for coords, _secs in self._groups]

    def _initial_state(self) -> FloatArray:
        """Rigid start: first inertia at the scene's angle and speed, springs at their initial
        twist with zero rate, differentials at delta = 0 with equal side speeds, relaxed slips
        0; the vehicle at ``vehicle.initial_speed`` (then the driveline rolls without slip
        at the first wheel: omega r = v) or at the first wheel's omega r."""
        sc = self.scene
        twist0 = {el.name: el.initial_twist for el in _iter(sc.driveline) if isinstance(el, Spring)}
        x = np.zeros(self._n_state)

        def fill(q0: float, v0: float) -> None:
            n = self.n_dof
            x[self.sections[0].coord], x[n + self.sections[0].coord] = q0, v0
            kin = self._kinematics(x)
            for k, (law, left, right) in enumerate(self.springs):
                phi, a = kin.ends[left][0], kin.ends[left][1]
                c = self.sections[right].coord
                x[c] = phi - twist0[law.name]
                x[n + c] = a * kin.qd[left]
                kin = self._kinematics(x)
            self._kin0 = kin

        v_spec = sc.vehicle.initial_speed
        fill(sc.initial_angle, sc.initial_speed if v_spec is None else 1.0)
        w0 = self.wheels[0]
        kin = self._kin0
        wheel_speed = kin.ends[w0.section][1] * kin.qd[w0.section]
        if v_spec is None:
            v0 = wheel_speed * w0.tyre.radius
        else:
            if wheel_speed == 0.0:
                raise SceneError('vehicle.initial_speed_m_s', 'the first wheel does not turn with '
                                                              'the engine (check the ratios)')
            fill(sc.initial_angle, v_spec / (wheel_speed * w0.tyre.radius))
            v0 = v_spec
        x[self._iv] = v0
        return x

    # --- kinematics -----------------------------------------------------------------------

    def _kinematics(self, x: FloatArray) -> _Kin:
        """Section angles, speeds, rows r_s (group-local), bias accelerations k_s and end
        kinematics."""
        n = self.n_dof
        xl = x.tolist() if isinstance(x, np.ndarray) else list(x)
        ns = len(self.sections)
        q = [0.0] * ns
        qd = [0.0] * ns
        rows: list[list[float]] = [[]] * ns
        bias = [0.0] * ns
        ends: list[tuple[float, float, float, float, float]] = [(0.0, 0.0, 0.0, 0.0, 0.0)] * ns
        ops = self._sec_ops
        sec_local = self._sec_local
        group_size = self._group_size
        for s, sec in enumerate(self.sections):
            if sec.parent < 0:
                c = sec.coord
                q[s], qd[s] = xl[c], xl[n + c]
                row = [0.0] * group_size[s]
                row[0] = 1.0
            else:
                p = sec.parent
                phi_p, a_p, b_p = ends[p][0], ends[p][1], ends[p][2]
                row = [a_p * r for r in rows[p]]
                q[s], qd[s] = phi_p, a_p * qd[p]
                i = sec_local[s]
                if i >= 0:
                    c = self.diffs[sec.diff].coord
                    q[s] += sec.sign * xl[c]
                    qd[s] += sec.sign * xl[n + c]
                    row[i] += sec.sign
                elif self._lock_delta and sec.diff in self._lock_delta:
                    q[s] += sec.sign * self._lock_delta[sec.diff]   # a pack stuck at delta != 0
                bias[s] = a_p * bias[p] + b_p * qd[p] * qd[p]
            rows[s] = row
            ends[s] = section_kinematics(ops[s], q[s])
        return _Kin(q, qd, rows, bias, ends)

    # --- forces -----------------------------------------------------------------------------

    def _forces(self, t: float, x: FloatArray, kin: _Kin, engine_fn: Callable[..., float] | None,
                T_engine: float) -> _Forces:
        n = self.n_dof
        xl = x.tolist()
        ns = len(self.sections)
        qf = [0.0] * ns
        if engine_fn is not None:
            T_engine = engine_fn(t, xl[n + self.sections[0].coord], xl[self.sections[0].coord])
        qf[0] += T_engine
        p_damp = 0.0
        spring_t = []
        for law, left, right in self.springs:
            phi_l, a_l = kin.ends[left][0], kin.ends[left][1]
            th = phi_l - kin.q[right]
            thd = a_l * kin.qd[left] - kin.qd[right]
            ts, _k, _kd, _v, pd = law.evaluate(th, thd)
            p_damp += pd
            spring_t.append(ts)
            qf[left] -= ts * a_l
            qf[right] += ts
        bias_t = []
        for d in self.diffs:
            tb = d.model.bias_torque(kin.qd[d.left], kin.qd[d.right])
            bias_t.append(tb)
            if tb != 0.0:
                qf[d.left] -= tb
                qf[d.right] += tb
                p_damp += tb * (kin.qd[d.left] - kin.qd[d.right])
        v = xl[self._iv]
        kappa = xl[2 * n:2 * n + self.n_wheel]
        grips = [w.tyre.mu * w.tyre.mf.shape(k) for w, k in zip(self.wheels, kappa)]
        fz = self.body.normal_loads([w.share for w in self.wheels], [w.axle for w in self.wheels],
                                    grips, v)
        fx, status, omega = [], [], []
        p_slip = 0.0
        outside = self.wheel_torques
        for i, (w, k, f_z) in enumerate(zip(self.wheels, kappa, fz)):
            if outside is None:
                f, st = w.tyre.force(k, f_z)
            else:           # an outside node's resisting torque T_w: F_x = T_w / r
                f, st = outside[i] / w.tyre.radius, TYRE_OK
            a_w = kin.ends[w.section][1]
            om = a_w * kin.qd[w.section]
            fx.append(f)
            status.append(st)
            omega.append(om)
            qf[w.section] -= f * w.tyre.radius * a_w
            p_slip += f * (om * w.tyre.radius - v)
        return _Forces(T_engine, qf, spring_t, bias_t, fx, fz, status, omega, p_damp, p_slip)

    def _accelerations(self, kin: _Kin, fo: _Forces) -> list[float]:
        """Generalised accelerations uddot (rad/s^2) of every coordinate, group by group:
        M = sum_s M_s r_s r_s^T + sum_d P_d e_d e_d^T, f = sum_s r_s (Q_s - C_s qdot_s^2 - M_s k_s)."""
        acc = [0.0] * self.n_dof
        ends, rows, qd, bias, qf = kin.ends, kin.rows, kin.qd, kin.bias, fo.q
        for (coords, secs), spiders in zip(self._groups, self._group_spiders):
            k = len(coords)
            if k == 1:
                m0 = f0 = 0.0
                for s in secs:
                    ms = ends[s][3]
                    r = rows[s][0]
                    m0 += ms * r * r
                    f0 += r * (qf[s] - ends[s][4] * qd[s] * qd[s] - ms * bias[s])
                acc[coords[0]] = f0 / m0
                continue
            m = [[0.0] * k for _ in range(k)]
            f = [0.0] * k
            for s in secs:
                ms = ends[s][3]
                rl = rows[s]
                gen = qf[s] - ends[s][4] * qd[s] * qd[s] - ms * bias[s]
                for i in range(k):
                    ri = rl[i]
                    if ri == 0.0:
                        continue
                    f[i] += ri * gen
                    mi = m[i]
                    for j in range(i + 1):      # the lower triangle (all Cholesky reads)
                        mi[j] += ms * ri * rl[j]
            for i, p in spiders:
                m[i][i] += p
            for c, a in zip(coords, _cholesky_solve(m, f)):
                acc[c] = a
        return acc

    # --- right-hand side --------------------------------------------------------------------

    def rhs_sources(self, t: float, x: FloatArray, engine: Any, load: Any = None) -> FloatArray:
        """dx/dt with the engine torque evaluated inside (``load`` unused: the tyres and the
        body are the load)."""
        return self._rhs(t, x, engine.torque, 0.0)

    def rhs(self, t: float, x: FloatArray, T_engine: float, T_load: float = 0.0) -> FloatArray:
        """dx/dt for a given engine torque (N m); ``T_load`` unused."""
        return self._rhs(t, x, None, T_engine)

    def _rhs(self, t: float, x: FloatArray, engine_fn: Callable[..., float] | None,
             T_engine: float) -> FloatArray:
        n = self.n_dof
        kin = self._kinematics(x)
        fo = self._forces(t, x, kin, engine_fn, T_engine)
        acc = self._accelerations(kin, fo)
        out = [0.0] * self._n_state
        xl = x.tolist()
        out[:n] = xl[n:2 * n]
        out[n:2 * n] = acc
        v = xl[self._iv]
        for i, w in enumerate(self.wheels):
            out[2 * n + i] = w.tyre.slip_rate(xl[2 * n + i], fo.omega[i], v)
        out[self._iv] = self.body.acceleration(v, sum(fo.fx))
        if self.track_energy:
            j = self._iv + 1
            out[j] = fo.T_engine * xl[n + self.sections[0].coord]
            out[j + 1] = fo.p_damp
            out[j + 2] = fo.p_slip
            out[j + 3] = self.body.resistance(v) * v
        return np.array(out)

    def jacobian_fd(self, t: float, x: FloatArray, engine: Any) -> FloatArray:
        """d(rhs)/dx by central differences (h = 1e-6 max(1, |x_j|)), for the Rosenbrock
        steppers; the analytic Jacobian of the tree is not written yet."""
        x = np.asarray(x, dtype=float)
        jac = np.empty((x.size, x.size))
        for j in range(x.size):
            h = 1e-6 * max(1.0, abs(float(x[j])))
            xp, xm = x.copy(), x.copy()
            xp[j] += h
            xm[j] -= h
            jac[:, j] = (self.rhs_sources(t, xp, engine) - self.rhs_sources(t, xm, engine)) / (2 * h)
        return jac

    # --- views ------------------------------------------------------------------------------

    @property
    def state_names(self) -> list[str]:
        """Names of the entries of x: each coordinate's '<first shaft>.angle' (a group root) or
        '<diff>.delta' (rad), then '.speed' / '.delta_rate', then '<wheel>.slip', 'vehicle.speed'
        (m/s) and with track_energy 'W_engine', 'W_damp', 'W_slip', 'W_road' (J)."""
        names = [''] * self.n_dof
        for s, sec in enumerate(self.sections):
            if sec.coord >= 0:
                names[sec.coord] = next(sh.name for sh in self.shafts if sh.section == s)
        for d in self.diffs:
            if d.coord >= 0:
                names[d.coord] = f'{d.name}.delta'
        pos = [nm if nm.endswith('.delta') else f'{nm}.angle' for nm in names]
        vel = [f'{nm}_rate' if nm.endswith('.delta') else f'{nm}.speed' for nm in names]
        out = pos + vel + [f'{w.name}.slip' for w in self.wheels] + ['vehicle.speed']
        return out + (['W_engine', 'W_damp', 'W_slip', 'W_road'] if self.track_energy else [])

    def engine_omega(self, x: FloatArray) -> float:
        """Speed of the first inertia (rad/s)."""
        return float(x[self.n_dof + self.sections[0].coord])

    def engine_phi(self, x: FloatArray) -> float:
        """Angle of the first inertia (rad)."""
        return float(x[self.sections[0].coord])

    def set_wheel_torques(self, torques: list[float] | None) -> None:
        """Outside wheel loads: ``torques[i]`` (N m, resisting, wheel order of
        :attr:`wheel_names`) replaces wheel i's tyre, F_x = T_i / r_i on the wheel shaft
        (-F_x r) and on the body (+F_x), so the body, the slip work and the energy balance
        stay as with tyres; None restores the tyres. The relaxed slip keeps integrating
        (unused). The compiled kernel has no input for them: build_model refuses."""
        if torques is not None and len(torques) != self.n_wheel:
            raise ValueError(f'wheel torques: {self.n_wheel} needed, got {len(torques)}')
        self.wheel_torques = None if torques is None else [float(v) for v in torques]

    @property
    def wheel_names(self) -> list[str]:
        """The wheels' names (their shafts' JointState names), depth first."""
        return [w.name for w in self.wheels]

    def load_omega(self, x: FloatArray) -> float:
        """0.0: a vehicle scene has no load port (the tyres and the body are in the equations,
        ``T_load`` is unused), so a load slope acts on nothing (cvj_ros.physics.cosim)."""
        return 0.0

    def vehicle_speed(self, x: FloatArray) -> float:
        """v (m/s)."""
        return float(x[self._iv])

    def energy(self, x: FloatArray, kin: _Kin | None = None) -> dict[str, float]:
        """Kinetic (driveline and body) and elastic energy (J); ``kin``: x's kinematics if
        already computed."""
        if kin is None:
            kin = self._kinematics(x)
        ke = sum(0.5 * kin.ends[s][3] * kin.qd[s] * kin.qd[s] for s in range(len(self.sections)))
        n = self.n_dof
        for d in self.diffs:
            if d.coord >= 0:
                dd = float(x[n + d.coord])
                ke += 0.5 * d.model.spider_inertia * dd * dd
        v = float(x[self._iv])
        ke += 0.5 * self.body.mass * v * v
        el = 0.0
        for law, left, right in self.springs:
            el += law.evaluate(kin.ends[left][0] - kin.q[right], 0.0)[3]
        return {'kinetic': ke, 'elastic': el}

    def energy_residual(self, x: FloatArray, e0: float, kin: _Kin | None = None) -> float:
        """(E_kin + E_el - E0 - W_engine + W_damp + W_slip + W_road) / max(energy scale)."""
        if not self.track_energy:
            raise ValueError('energy_residual needs a TreeDriveline built with track_energy=True')
        e = self.energy(x, kin)
        tot = e['kinetic'] + e['elastic']
        we, wd, ws, wr = (float(v) for v in x[self._iv + 1:self._iv + 1 + N_WORK])
        scale = max(abs(tot), abs(e0), abs(we), abs(wd), abs(ws), abs(wr), 1e-12)
        return (tot - e0 - we + wd + ws + wr) / scale

    def wheel_outputs(self, x: FloatArray) -> dict[str, dict[str, float]]:
        """Per wheel: omega (rad/s), slip (relaxed, -), F_x and F_z (N), status (tyre.TYRE_*)."""
        kin = self._kinematics(x)
        fo = self._forces(0.0, x, kin, None, 0.0)
        n = self.n_dof
        return {w.name: {'omega': fo.omega[i], 'slip': float(x[2 * n + i]), 'fx': fo.fx[i],
                         'fz': fo.fz[i], 'status': fo.status[i]}
                for i, w in enumerate(self.wheels)}

    def tyre_torque(self, x: FloatArray) -> float:
        """sum F_x r over the wheels (N m): the road's total resisting torque (Trace.load_torque)."""
        out = self.wheel_outputs(x)
        return sum(o['fx'] * w.tyre.radius for o, w in zip(out.values(), self.wheels))

    def no_load_wheels(self, x: FloatArray) -> list[str]:
        """Wheels whose tyre has status NO_LOAD (F_z <= 0) at x."""
        return [k for k, o in self.wheel_outputs(x).items() if o['status'] == TYRE_NO_LOAD]

    def joint_states(self, x: FloatArray, T_engine: float, T_load: float = 0.0
                     ) -> tuple[list[str], FloatArray, FloatArray, FloatArray]:
        """(names, position rad, velocity rad/s, effort N m) of every shaft; effort as in
        Driveline.joint_states: the torque a shaft passes towards the wheels (a wheel's: F_x r)."""
        pos, vel, eff = self.joint_states_fast(x, T_engine, T_load)
        if self._mid_index:
            self.fill_mid(pos[None, :], vel[None, :])
        return list(self.shaft_names), pos, vel, eff

    def joint_states_fast(self, x: FloatArray, T_engine: float, T_load: float = 0.0
                          ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """As :meth:`joint_states`, intermediate members left as their joint's input."""
        return self._walk(x, T_engine)[:3]

    def reactions(self, x: FloatArray, T_engine: float, T_load: float = 0.0
                  ) -> dict[str, dict[str, float]]:
        """Per joint whose model has ``reactions(phi_in, omega_in, torque_in)``: its dict, at
        the joint's ``<joint>_input`` shaft of :meth:`joint_states_fast` (angle, speed and the
        torque entering the joint from the engine side, as Driveline.reactions passes them
        along a chain). ``T_load`` is unused (the wheels' road torques are inside)."""
        pos, vel, eff, _start = self._walk(x, T_engine)
        col = {name: i for i, name in enumerate(self.shaft_names)}
        out: dict[str, dict[str, float]] = {}
        for name, model in self.joint_models.items():
            if hasattr(model, 'reactions'):
                i = col[f'{name}_input']
                out[name] = dict(model.reactions(float(pos[i]), float(vel[i]), float(eff[i])))
        return out

    def fill_mid(self, position: FloatArray, velocity: FloatArray, *, members: Any = None) -> None:
        """Intermediate-member columns (Driveline.fill_mid, same numbers)."""
        from cvj_ros.physics.driveline import Driveline
        Driveline.fill_mid(self, position, velocity, members=members)  # type: ignore[arg-type]

    def sample_outputs(self, t: float, x: FloatArray, engine_fn: Callable[..., float], e0: float
                       ) -> tuple[float, float, FloatArray, FloatArray, FloatArray, float, list[tuple]]:
        """Everything a run records at one sample, from one kinematics and force pass:
        (engine torque, sum F_x r (N m), shaft positions, speeds, torques (as
        :meth:`joint_states_fast`), energy residual (NaN without work integrals), per wheel
        (slip, F_x, F_z, status)). The same numbers as the separate methods."""
        n = self.n_dof
        kin = self._kinematics(x)
        fo = self._forces(t, x, kin, engine_fn, 0.0)
        tl = 0.0
        for f, w in zip(fo.fx, self.wheels):
            tl += f * w.tyre.radius
        pos, vel, eff, _start = self._walk(x, fo.T_engine, kin=kin, fo=fo)
        res = self.energy_residual(x, e0, kin) if self.track_energy else math.nan
        wheels = [(float(x[2 * n + i]), fo.fx[i], fo.fz[i], fo.status[i])
                  for i in range(self.n_wheel)]
        return fo.T_engine, tl, pos, vel, eff, res, wheels

    def _walk(self, x: FloatArray, T_engine: float, *, kin: _Kin | None = None,
              fo: _Forces | None = None) -> tuple[FloatArray, FloatArray, FloatArray, list[float]]:
        """Shaft positions, speeds, torques; and each section's start torque (N m), from a
        backward walk of every section (deepest first) from its end torque: a wheel's F_x r,
        a spring's torque, or a differential's side torques summed (the carrier passes
        T_L + T_R: along phi_c at fixed delta neither the spiders nor the coupling work).
        ``kin``, ``fo``: x's kinematics and forces at T_engine if already computed."""
        if kin is None:
            kin = self._kinematics(x)
        if fo is None:
            fo = self._forces(0.0, x, kin, None, T_engine)
        acc = self._accelerations(kin, fo)
        ns = len(self.sections)
        start_t = [0.0] * ns
        states: list[list[tuple[tuple[float, float, float], tuple[float, float, float]]]] = [[]] * ns
        for s in reversed(range(ns)):
            sec = self.sections[s]
            coords = self._groups[self._group_of[s]][0]
            qdd = sum(r * acc[c] for r, c in zip(kin.rows[s], coords)) + kin.bias[s]
            kind, idx = sec.end
            if kind == 'wheel':
                t_end = fo.fx[idx] * self.wheels[idx].tyre.radius
                if fo.wheel_extra:
                    t_end += fo.wheel_extra[idx]
            elif kind == 'link':
                t_end = self._link_end_torque(idx, start_t, fo)
            elif kind == 'spring':
                t_end = fo.spring_t[idx]
            elif kind == 'diff':
                d = self.diffs[idx]
                t_end = start_t[d.left] + start_t[d.right]
            else:
                t_end = 0.0
            # forward: (phi, a, b) before each op
            phi, a, b = kin.q[s], 1.0, 0.0
            fw = []
            for jv, fn in sec.ops:
                before = (phi, a, b)
                if fn is not None:
                    po, r, sl = fn(phi)
                    b = sl * a * a + r * b
                    a = r * a
                    phi = po
                    fw.append((before, (phi, a, b), r))
                else:
                    fw.append((before, before, 1.0))
            torque = t_end
            st: list[Any] = [None] * len(sec.ops)
            for k in reversed(range(len(sec.ops))):
                jv, fn = sec.ops[k]
                (pb, ab, bb), (pa, aa, ba), r = fw[k]
                after = (pa, aa * kin.qd[s], torque)
                if fn is None:
                    torque += jv * (aa * qdd + ba * kin.qd[s] ** 2)
                else:
                    torque *= r
                st[k] = ((pb, ab * kin.qd[s], torque), after)
            states[s] = st
            start_t[s] = torque
        m = len(self.shafts)
        pos, vel, eff = np.zeros(m), np.zeros(m), np.zeros(m)
        for i, sh in enumerate(self.shafts):
            before, after = states[sh.section][sh.op_index]
            phi, om, tq = before if sh.role in ('input', 'mid') else after
            pos[i], vel[i], eff[i] = phi, om, (0.0 if sh.role == 'mid' else tq)
        return pos, vel, eff, start_t

    def _link_end_torque(self, idx: int, start_t: list[float], fo: _Forces) -> float:
        """Torque at the end of a section ending in a mode link (mode-aware tree only)."""
        raise NotImplementedError

    def section_start_torques(self, x: FloatArray, T_engine: float) -> list[float]:
        """Torque entering each section at its first shaft (N m), from the backward walk;
        the root's equals T_engine and a spring's right section's that spring's torque when
        the equations hold (the tests' consistency check)."""
        return self._walk(x, T_engine)[3]


@dataclass
class _Kin:
    q: list[float]
    qd: list[float]
    rows: list[list[float]]
    bias: list[float]
    ends: list[tuple[float, float, float, float, float]]


@dataclass
class _Forces:
    T_engine: float
    q: list[float]
    spring_t: list[float]
    bias_t: list[float]
    fx: list[float]
    fz: list[float]
    status: list[int]
    omega: list[float]
    p_damp: float
    p_slip: float
    wheel_extra: list[float] = field(default_factory=list)   # brake torque per wheel (N m)


def _iter(chain: tuple[Any, ...]) -> Any:
    from cvj_ros.physics.scene import iter_elements
    return iter_elements(chain)
