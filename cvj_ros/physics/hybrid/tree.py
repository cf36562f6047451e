"""A vehicle driveline (tree: differentials, wheels, tyres, body) with mode elements: its
equations in one mode.

Trunk links. A clutch or gearbox in the trunk (before the differential) owns two inertias,
``<name>_input`` (ending the section it sits in) and ``<name>_output`` (starting the next).
Unlocked (a slipping clutch, a gearbox in neutral) the output side is a new group root with
its own coordinate, as behind a spring, and the link passes the torque
ts = mode mu_k cgeo fn (clutch, sign of the slip s = omega_input - omega_output; Modelica
Clutch) or 0 (neutral): -ts a_end on the input section, +ts on the output section. Locked (a
stuck clutch, an engaged gear) the input section ends in the coupling op
phi_out = k phi_in + offset (k = 1 clutch, 1/i gear; the offset keeps the angles continuous)
and the output section hangs on it as a locked differential's side does: the two sides merge
into one group (cvj_ros.physics.tree, Lagrange on the group's coordinates).

Wheel brakes. A brake element right after a wheel acts between that wheel and the ground.
Slipping it adds -mode mu_k cgeo fn to the wheel shaft (mode = sign of the wheel speed);
stuck it *pins* the wheel's section: the section must be a group root of its own (the wheel
sits behind a halfshaft spring, no differential between), so its one coordinate is held
with qddot = 0 and qdot = 0 exactly, and the brake resists T_hold = Q / a_w, the generalised
force of everything else on the section over the wheel's ratio a_w.

The mode (cvj_ros.physics.hybrid.chain.Mode, shared with the chain) says per clutch
STUCK / FORWARD / BACKWARD, per gearbox its gear, per brake (``Mode.brakes``) its mode and
the offsets of the locked links (by link index). State x per mode: as TreeDriveline
(u, udot, relaxed slips, v, W_engine, W_damp, W_slip, W_road) plus W_friction (J).
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np
from numpy.typing import NDArray

from cvj_ros.errors import SceneError
from cvj_ros.physics.hybrid.chain import Mode
from cvj_ros.physics.hybrid.elements import Brake, Clutch, Gearbox
from cvj_ros.physics.hybrid.friction import STUCK
from cvj_ros.physics.scene import Scene
from cvj_ros.physics.sections import Shaft, section_kinematics
from cvj_ros.physics.differential import Differential as DiffModel
from cvj_ros.physics.tree import TreeDriveline, _cholesky_solve, _Forces, _Kin

__all__ = ['Link', 'ModeTree', 'TreeEvaluation', 'TreeState']

FloatArray = NDArray[np.float64]
N_TREE_WORK = 5     # W_engine, W_damp, W_slip, W_road, W_friction


@dataclass(frozen=True)
class Link:
    """A clutch or gearbox in the trunk: its element, input (left) and output (right)
    section, locked in this mode, coupling ratio k when locked."""

    element: Clutch | Gearbox
    left: int
    right: int
    locked: bool
    k: float


@dataclass
class TreeState:
    """Mode-independent state: every section's angle and speed (rad, rad/s), every
    differential's delta and rate (0 when locked), the tail (relaxed slips, v, work
    integrals) and the kinetic energy lost in locks (J)."""

    q: list[float]
    qd: list[float]
    delta: list[float]
    ddelta: list[float]
    tail: FloatArray
    lock_loss: float = 0.0


@dataclass
class TreeEvaluation:
    """Right-hand side and witness quantities at (t, x) in one mode."""

    ydot: FloatArray
    engine_torque: float
    slip: dict[str, float]              # unlocked clutch -> slip speed (rad/s)
    stuck_torque: dict[str, float]      # locked clutch -> transmitted torque (N m)
    hold: dict[str, float]              # pinned brake -> torque it must resist (N m)
    wheel_speed: dict[str, float]       # brake -> its wheel's speed (rad/s)
    gearbox_output: dict[str, float]    # gearbox -> output-shaft speed (rad/s)
    engine_speed: float
    pack_slip: dict[str, float] = field(default_factory=dict)     # omega_L - omega_R (rad/s)
    pack_stuck: dict[str, float] = field(default_factory=dict)    # (T_R - T_L)/2 needed (N m)
    pack_static: dict[str, float] = field(default_factory=dict)   # static capacity (N m)


def _coupling(k: float, off: float) -> Callable[[float], tuple[float, float, float]]:
    def fn(p: float) -> tuple[float, float, float]:
        return k * p + off, k, 0.0
    return fn


class ModeTree(TreeDriveline):
    """A vehicle scene's tree in one mode (module docstring); built per mode."""

    def __init__(self, scene: Scene, levels: Mapping[str, str], mode: Mode) -> None:
        self.mode = mode
        self.links: list[Link] = []
        self.brakes: dict[str, tuple[Brake, int]] = {}     # name -> (brake, wheel index)
        self.packs: dict[str, tuple[Any, int]] = {}         # clutch-pack diff -> (element, index)
        super().__init__(scene, levels, track_energy=True)
        if len(self.packs) > 1:
            raise SceneError(sorted(self.packs)[1], 'one clutch-pack differential per scene (the '
                                                    "reference solves one pack's torque sensing)")
        self._n_state += 1                                  # W_friction
        self.pinned: dict[str, int] = {}                    # stuck brake -> its coordinate
        for name, (br, w) in self.brakes.items():
            sec = self.wheels[w].section
            root = self.sections[sec]
            grp = self._groups[self._group_of[sec]]
            if root.parent >= 0 or len(grp[0]) != 1 or len(grp[1]) != 1:
                raise SceneError(f'{name}', f'brake {name!r}: its wheel {self.wheels[w].name!r} must '
                                            'sit behind a spring (a halfshaft) with no differential '
                                            'or clutch between, so a stuck brake holds it alone')
            if mode.brakes.get(name) == STUCK:
                self.pinned[name] = root.coord
        self._pinned_coords = set(self.pinned.values())
        self.clutch_link = {lk.element.name: i for i, lk in enumerate(self.links)
                            if isinstance(lk.element, Clutch)}
        self.gearbox_link = {lk.element.name: i for i, lk in enumerate(self.links)
                             if isinstance(lk.element, Gearbox)}

    # --- construction hooks -------------------------------------------------------------

    def _initial_state(self) -> FloatArray:
        return np.zeros(self._n_state)        # the simulation sets the start (hybrid.tree_sim)

    def _diff_model(self, el: Any) -> DiffModel:
        if el.kind != 'clutch_pack':
            return super()._diff_model(el)
        d = len(self.diffs)
        self.packs[el.name] = (el, d)
        stuck = self.mode.packs.get(el.name) == STUCK
        if stuck:
            self._lock_delta[d] = self.mode.offsets[-(d + 1)]
        return DiffModel(kind='locked' if stuck else 'open', ratio=el.ratio, J_carrier=el.J_carrier,
                         J_spider=el.J_spider, spider_ratio=el.spider_ratio)

    def _add_mode_element(self, el: Any, s: int, path: str) -> int:
        if isinstance(el, Brake):
            end = self.sections[s].end
            if end[0] != 'wheel':
                raise SceneError(path, f'brake {el.name!r} must follow a wheel (it acts on it)')
            self.brakes[el.name] = (el, end[1])
            return s
        if self.sections[s].parent >= 0 and self.sections[s].diff >= 0:
            raise SceneError(path, f'{el.type} {el.name!r}: clutches and gearboxes sit in the trunk, '
                                   'before the first differential')
        k = self._add_op(s, (el.J_input, None), f'{el.name}_input')
        self.shafts.append(Shaft(f'{el.name}_input', s, k, 'inertia'))
        idx = len(self.links)
        if isinstance(el, Clutch):
            locked = self.mode.clutch[el.name] == STUCK
            ratio = 1.0
        else:
            gear = self.mode.gear[el.name]
            locked = gear != 0
            ratio = 1.0 / el.ratio(gear) if locked else 1.0
        if locked:
            self._add_op(s, (0.0, _coupling(ratio, self.mode.offsets[idx])), el.name)
            new = self._new_section(s, -1, 0)
        else:
            new = self._new_section(-1, -1, 0)
        self.sections[s].end = ('link', idx)
        self.links.append(Link(el, s, new, locked, ratio))
        k = self._add_op(new, (el.J_output, None), f'{el.name}_output')
        self.shafts.append(Shaft(f'{el.name}_output', new, k, 'inertia'))
        return new

    # --- equations ----------------------------------------------------------------------

    def _accelerations(self, kin: _Kin, fo: _Forces) -> list[float]:
        acc = super()._accelerations(kin, fo)
        for c in self._pinned_coords:
            acc[c] = 0.0
        return acc

    def _link_end_torque(self, idx: int, start_t: list[float], fo: _Forces) -> float:
        lk = self.links[idx]
        return start_t[lk.right] if lk.locked else fo.link_t[idx]   # type: ignore[attr-defined]

    def input_end(self, kin: _Kin, lk: Link) -> tuple[float, float]:
        """(phi, a) of the link's input shaft (before its coupling op when locked)."""
        ops = self._sec_ops[lk.left]
        if lk.locked:
            ops = ops[:-1]
        e = section_kinematics(ops, kin.q[lk.left])
        return e[0], e[1]

    def evaluate(self, t: float, x: FloatArray, engine: Any, clutch_kinetic: float,
                 brake_kinetic: Mapping[str, float], *, torques: bool = True) -> TreeEvaluation:
        """dx/dt and the witness quantities at (t, x); ``clutch_kinetic`` (N m) the clutches'
        kinetic capacity, ``brake_kinetic`` per brake (N m). ``torques``: compute the stuck
        clutches' torques (a backward walk; skipped when no witness needs them)."""
        n = self.n_dof
        kin = self._kinematics(x)
        fo = self._forces(t, x, kin, engine.torque, 0.0)
        qf = fo.q
        p_fric = 0.0
        link_t = [0.0] * len(self.links)
        slip: dict[str, float] = {}
        for i, lk in enumerate(self.links):
            if lk.locked:
                continue
            _phi, a_l = self.input_end(kin, lk)
            s = a_l * kin.qd[lk.left] - kin.qd[lk.right]
            ts = 0.0
            if isinstance(lk.element, Clutch):
                ts = self.mode.clutch[lk.element.name] * clutch_kinetic
                slip[lk.element.name] = s
                p_fric += ts * s
            link_t[i] = ts
            qf[lk.left] -= ts * a_l
            qf[lk.right] += ts
        fo.link_t = link_t                                  # type: ignore[attr-defined]
        extra = [0.0] * self.n_wheel
        wheel_speed: dict[str, float] = {}
        hold: dict[str, float] = {}
        for name, (_br, w) in self.brakes.items():
            sec = self.wheels[w].section
            a_w = kin.ends[sec][1]
            om = a_w * kin.qd[sec]
            wheel_speed[name] = om
            if name in self.pinned:
                continue
            tb = self.mode.brakes[name] * brake_kinetic[name]
            qf[sec] -= tb * a_w
            extra[w] += tb
            p_fric += tb * om
        for name in self.pinned:
            w = self.brakes[name][1]
            sec = self.wheels[w].section
            th = qf[sec] / kin.ends[sec][1]
            hold[name] = th
            extra[w] += th
        fo.wheel_extra = extra
        pack_slip: dict[str, float] = {}
        pack_stuck: dict[str, float] = {}
        pack_static: dict[str, float] = {}
        for name, (el, d) in self.packs.items():
            di = self.diffs[d]
            if di.coord < 0:                                  # stuck: torque needed, capacity
                st_t = self._walk(x, fo.T_engine, kin=kin, fo=fo)[3]
                t_l, t_r = st_t[di.left], st_t[di.right]
                pack_stuck[name] = 0.5 * (t_r - t_l)
                pack_static[name] = el.static_ratio * (el.preload + el.torque_bias * abs(t_l + t_r))
                continue
            s_lr = kin.qd[di.left] - kin.qd[di.right]
            pack_slip[name] = s_lr
            tb = self._pack_bias(x, kin, fo, el, di, self.mode.packs[name])
            qf[di.left] -= tb
            qf[di.right] += tb
            p_fric += tb * s_lr
        acc = self._accelerations(kin, fo)
        xl = x.tolist()
        out = [0.0] * self._n_state
        out[:n] = xl[n:2 * n]
        out[n:2 * n] = acc
        v = xl[self._iv]
        for i, wh in enumerate(self.wheels):
            out[2 * n + i] = wh.tyre.slip_rate(xl[2 * n + i], fo.omega[i], v)
        out[self._iv] = self.body.acceleration(v, sum(fo.fx))
        w_e = xl[n + self.sections[0].coord]
        j = self._iv + 1
        out[j] = fo.T_engine * w_e
        out[j + 1] = fo.p_damp
        out[j + 2] = fo.p_slip
        out[j + 3] = self.body.resistance(v) * v
        out[j + 4] = p_fric
        stuck: dict[str, float] = {}
        if torques and any(lk.locked for lk in self.links if isinstance(lk.element, Clutch)):
            start_t = self._walk(x, fo.T_engine, kin=kin, fo=fo)[3]
            for lk in self.links:
                if lk.locked and isinstance(lk.element, Clutch):
                    stuck[lk.element.name] = start_t[lk.right]
        gb_out = {lk.element.name: kin.qd[lk.right] for lk in self.links
                  if isinstance(lk.element, Gearbox)}
        return TreeEvaluation(np.array(out), fo.T_engine, slip, stuck, hold, wheel_speed, gb_out, w_e,
                              pack_slip, pack_stuck, pack_static)

    def _pack_bias(self, x: FloatArray, kin: _Kin, fo: _Forces, el: Any, di: Any, m: int) -> float:
        """Bias torque T_b (N m) of a slipping clutch pack: T_b = m (T_p + k |T_c|) with T_c
        = T_L + T_R the carrier torque, itself affine in T_b through the dynamics:
        T_c = T_c0 + B T_b (two backward walks, at T_b = 0 and 1). With s = sign(T_c):
        T_b = m (T_p + k s T_c0) / (1 - m k s B), the s that is consistent."""
        if el.torque_bias == 0.0:
            return m * el.preload
        qf = fo.q

        q_l, q_r = qf[di.left], qf[di.right]

        def carrier(tb: float) -> float:
            qf[di.left], qf[di.right] = q_l - tb, q_r + tb
            st_t = self._walk(x, fo.T_engine, kin=kin, fo=fo)[3]
            qf[di.left], qf[di.right] = q_l, q_r
            return st_t[di.left] + st_t[di.right]

        tc0 = carrier(0.0)
        b = carrier(1.0) - tc0
        k, tp = el.torque_bias, el.preload
        first = 1.0 if tc0 >= 0.0 else -1.0
        for s in (first, -first):
            tb = m * (tp + k * s * tc0) / (1.0 - m * k * s * b)
            if s * (tc0 + b * tb) >= 0.0:
                return tb
        return m * (tp + k * abs(tc0))

    # --- state maps ---------------------------------------------------------------------

    def to_state(self, x: FloatArray, lock_loss: float) -> TreeState:
        """Mode state x -> TreeState."""
        kin = self._kinematics(x)
        n = self.n_dof
        delta = [float(x[d.coord]) if d.coord >= 0 else self._lock_delta.get(i, 0.0)
                 for i, d in enumerate(self.diffs)]
        ddelta = [float(x[n + d.coord]) if d.coord >= 0 else 0.0 for d in self.diffs]
        return TreeState(list(kin.q), list(kin.qd), delta, ddelta,
                         np.array(x[2 * n:], dtype=float), lock_loss)

    def from_state(self, st: TreeState, fresh: bool) -> tuple[FloatArray, float]:
        """TreeState -> mode state x and the kinetic energy lost (J). Angles are taken as
        they are; with ``fresh`` (a lock made now) every group takes the speeds of the
        plastic impact, the projection of the old speeds in the kinetic-energy metric:
        M_u udot = sum_s M_s r_s qdot_s,old + sum_d P_d e_d deltadot_old (the generalised
        momentum along the group's remaining motion is kept); a pinned section stops."""
        n = self.n_dof
        x = np.zeros(self._n_state)
        for s, sec in enumerate(self.sections):
            if sec.coord >= 0:
                x[sec.coord] = st.q[s]
                x[n + sec.coord] = st.qd[s]
        for d_i, d in enumerate(self.diffs):
            if d.coord >= 0:
                x[d.coord] = st.delta[d_i]
                x[n + d.coord] = st.ddelta[d_i]
        x[2 * n:] = st.tail
        for c in self._pinned_coords:
            x[n + c] = 0.0
        ke_before = self.section_energy(st)
        if fresh:
            kin = self._kinematics(x)
            for (coords, secs), spiders in zip(self._groups, self._group_spiders):
                k = len(coords)
                m = [[0.0] * k for _ in range(k)]
                f = [0.0] * k
                for s in secs:
                    ms = kin.ends[s][3]
                    rl = kin.rows[s]
                    for i in range(k):
                        f[i] += ms * rl[i] * st.qd[s]
                        for j in range(i + 1):
                            m[i][j] += ms * rl[i] * rl[j]
                for i, p in spiders:
                    m[i][i] += p
                    d_i = next(di for di, d in enumerate(self.diffs) if d.coord == coords[i])
                    f[i] += p * st.ddelta[d_i]
                for c, u in zip(coords, _cholesky_solve(m, f)):
                    x[n + c] = 0.0 if c in self._pinned_coords else u
        ke_after = self.driveline_energy(x)
        return x, ke_before - ke_after

    def section_energy(self, st: TreeState) -> float:
        """Driveline kinetic energy (J) of a TreeState in this mode's sections."""
        ke = 0.0
        for s in range(len(self.sections)):
            m = section_kinematics(self._sec_ops[s], st.q[s])[3]
            ke += 0.5 * m * st.qd[s] ** 2
        for d_i, d in enumerate(self.diffs):
            ke += 0.5 * d.model.spider_inertia * st.ddelta[d_i] ** 2
        return ke

    def driveline_energy(self, x: FloatArray) -> float:
        """Driveline kinetic energy (J, without the body) of mode state x."""
        kin = self._kinematics(x)
        ke = sum(0.5 * kin.ends[s][3] * kin.qd[s] ** 2 for s in range(len(self.sections)))
        n = self.n_dof
        for d in self.diffs:
            if d.coord >= 0:
                ke += 0.5 * d.model.spider_inertia * float(x[n + d.coord]) ** 2
        return ke

    def lock_offset(self, idx: int, st: TreeState, k: float) -> float:
        """Offset of link ``idx`` locked now at ratio k: q_out - k phi_in (rad)."""
        lk = self.links[idx]
        ops = self._sec_ops[lk.left][:-1] if lk.locked else self._sec_ops[lk.left]
        phi_in = section_kinematics(ops, st.q[lk.left])[0]
        return st.q[lk.right] - k * phi_in

    def energy_total(self, x: FloatArray) -> float:
        """Kinetic (driveline and body) plus elastic energy (J)."""
        e = self.energy(x)
        return e['kinetic'] + e['elastic']

    def works(self, x: FloatArray) -> tuple[float, ...]:
        """(W_engine, W_damp, W_slip, W_road, W_friction) (J)."""
        return tuple(float(v) for v in x[self._iv + 1:self._iv + 1 + N_TREE_WORK])

    def shaft_speeds(self, x: FloatArray) -> list[float]:
        """Speed (rad/s) of every named shaft (``shaft_names``), mid members as their input."""
        kin = self._kinematics(x)
        out = []
        for sh in self.shafts:
            a = 1.0
            phi = kin.q[sh.section]
            upto = sh.op_index + (1 if sh.role == 'output' else 0)
            for _jv, fn in self._sec_ops[sh.section][:upto]:
                if fn is not None:
                    phi, r, _b = fn(phi)
                    a *= r
            out.append(a * kin.qd[sh.section])
        return out

    def first_wheel_speed(self, x: FloatArray) -> float:
        kin = self._kinematics(x)
        s = self.wheels[0].section
        return kin.ends[s][1] * kin.qd[s]

    def equilibrium_slip(self) -> float:
        """Relaxed slip kappa' (the same at every wheel) whose tyre forces hold the body at
        rest: sum F_x = m g sin(theta) (rolling resistance and drag vanish at v = 0); 0 on
        the flat. Brent's method on the model's own forces, kappa' within the peak slip."""
        from scipy.optimize import brentq
        need = self.body.climbing()
        if need == 0.0:
            return 0.0
        peak = min(w.tyre.mf.peak_slip() for w in self.wheels)

        def excess(k: float) -> float:
            grips = [w.tyre.mu * w.tyre.mf.shape(k) for w in self.wheels]
            fz = self.body.normal_loads([w.share for w in self.wheels],
                                        [w.axle for w in self.wheels], grips, 0.0)
            return sum(w.tyre.force(k, f)[0] for w, f in zip(self.wheels, fz)) - need

        lo, hi = (0.0, peak) if need > 0 else (-peak, 0.0)
        if excess(lo) * excess(hi) > 0:
            raise SceneError('vehicle.grade_percent', 'the tyres cannot hold the car at rest on '
                                                      'this grade (beyond their peak force)')
        return float(brentq(excess, lo, hi, xtol=1e-15, rtol=4 * float(np.finfo(float).eps)))

    def coordinate_of(self, section: int) -> int:
        return self.sections[section].coord

    @property
    def n_tail(self) -> int:
        return self._n_state - 2 * self.n_dof
