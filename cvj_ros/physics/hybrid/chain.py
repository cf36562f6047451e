"""A chain driveline with mode elements (clutch, gearbox, brake): its equations per mode.

The chain (engine -> load) is split into rigid *sections* at its springs, as in
cvj_ros.physics.driveline, and also at every clutch and gearbox. Between two sections sits
a *boundary*: a spring (elastic torque), a clutch or a gearbox. A mode (:class:`Mode`) says
per clutch STUCK / FORWARD / BACKWARD, per gearbox the engaged gear (0 neutral) and for
the brake STUCK / FORWARD / BACKWARD. A stuck clutch or engaged gearbox *locks* its boundary:
the sections on both sides merge into one rigid group, as a joint does,
through the coupling phi_out = k phi_in + offset (k = 1 clutch, k = 1/i gear; the offset
keeps the angles continuous at the lock). Each group is one degree of freedom q (the angle of
its first shaft) with M(q) qddot + C(q) qdot^2 = Q, M = sum J_i a_i^2, C = sum J_i a_i b_i.

An unlocked boundary between groups g and g+1 transmits ts: spring ts = T(theta, thetadot),
theta = phi_end(q_g) - q_{g+1}; slipping clutch ts = mode mu_k cgeo fn (Coulomb, sign of the
slip s = a_end v_g - v_{g+1}); neutral ts = 0. ts acts with -ts a_end on group g and +ts on
g+1. Engine torque on the first shaft, load (and a slipping brake, mode mu_k cgeo fn) on the
last, resisting. A stuck brake pins the last group: q fixed, qdot = 0 exactly.

Stuck torques (for the witnesses): a stuck clutch transmits the shaft torque at its place in
the group, found by walking the group from its left end with the group's acceleration (torque
minus J (a qddot + b qdot^2) per inertia, divided by the ratio at each joint), as
Driveline.joint_states does; a stuck brake holds T_hold = Q_rest / a_last, the generalised
force of everything else on the pinned group.

State per mode: [q_g..., qdot_g..., W_engine, W_load, W_damp, W_friction] (rad, rad/s, J).
Mode-independent state: :class:`SectionState`, every section's (q, qdot), from which energies
and shaft speeds follow.
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from types import SimpleNamespace
from typing import Any, Callable

import numpy as np
from numpy.typing import NDArray

from cvj_ros.errors import SceneError
from cvj_ros.physics.hybrid.elements import Brake, Clutch, Gearbox, ModeElement
from cvj_ros.physics.hybrid.friction import STUCK
from cvj_ros.physics.scene import Element, Inertia, check_layout
from cvj_ros.physics.sections import Op, SpringLaw, build_sections, section_kinematics

__all__ = ['Assembly', 'Boundary', 'Evaluation', 'HybridChain', 'Mode', 'SectionState', 'N_WORK']

FloatArray = NDArray[np.float64]
N_WORK = 4      # W_engine, W_load, W_damp, W_friction


@dataclass(frozen=True)
class Boundary:
    """Between sections k and k+1: kind 'spring' (``spring`` set), 'clutch' or 'gearbox'."""

    kind: str
    name: str
    spring: SpringLaw | None = None


@dataclass
class Mode:
    """Discrete state: clutch modes (name -> -1/0/+1), gears (name -> gear, 0 neutral),
    brake mode (None without brake), the coupling offsets of locked boundaries (rad) and,
    on a vehicle tree, each wheel brake's mode (name -> -1/0/+1; the chain's single
    output-shaft brake uses ``brake``) and each clutch-pack differential's (name -> -1/0/+1;
    its fixed delta when stuck in ``offsets`` under the key -(differential index + 1))."""

    clutch: dict[str, int] = field(default_factory=dict)
    gear: dict[str, int] = field(default_factory=dict)
    brake: int | None = None
    offsets: dict[int, float] = field(default_factory=dict)
    brakes: dict[str, int] = field(default_factory=dict)
    packs: dict[str, int] = field(default_factory=dict)

    def copy(self) -> Mode:
        return replace(self, clutch=dict(self.clutch), gear=dict(self.gear),
                       offsets=dict(self.offsets), brakes=dict(self.brakes),
                       packs=dict(self.packs))


@dataclass
class SectionState:
    """Every section's angle q (rad) and speed qdot (rad/s), plus the work integrals
    (W_engine, W_load, W_damp, W_friction) and the kinetic energy lost in locks (J)."""

    q: FloatArray
    v: FloatArray
    work: FloatArray
    lock_loss: float = 0.0


@dataclass(frozen=True)
class Group:
    ops: tuple[Op, ...]
    sections: tuple[int, ...]            # section indices, left to right
    starts: tuple[int, ...]              # op index where each section starts
    couplings: tuple[tuple[int, int], ...]   # (op index, boundary index) of locked boundaries


@dataclass(frozen=True)
class Assembly:
    """The groups of one mode and the unlocked boundaries between them."""

    groups: tuple[Group, ...]
    links: tuple[int, ...]               # boundary index between group g and g+1
    pinned: bool                         # last group held by a stuck brake


@dataclass
class Evaluation:
    """Right-hand side and witness quantities at (t, y) in one assembly."""

    ydot: FloatArray
    engine_torque: float
    load_torque: float
    slip: dict[int, float]               # unlocked clutch boundary -> slip speed (rad/s)
    stuck_torque: dict[int, float]       # locked clutch boundary -> transmitted torque (N m)
    hold_torque: float                   # stuck brake: torque it must resist (N m)
    omega_last: float                    # output-shaft speed (rad/s)


def _coupling(k: float, off: float) -> Callable[[float], tuple[float, float, float]]:
    def fn(p: float) -> tuple[float, float, float]:
        return k * p + off, k, 0.0
    return fn


class HybridChain:
    """Structure of a chain with mode elements; see the module docstring.

    Args:
        elements: engine -> load: Inertia, Spring, Joint (cvj_ros.physics.scene), Clutch,
            Gearbox; a Brake only as the last element (it acts on the last inertia).
        levels: joint / spring fidelity levels by name (default: joints at their best
            fidelity, springs elastic).
    """

    def __init__(self, elements: Sequence[Element | ModeElement], *,
                 levels: Mapping[str, str] | None = None) -> None:
        levels = dict(levels or {})
        segments: list[list[Element]] = [[]]
        cuts: list[ModeElement] = []
        self.brake: Brake | None = None
        for i, el in enumerate(elements):
            if isinstance(el, Brake):
                if i != len(elements) - 1:
                    raise SceneError(f'driveline[{i}]', 'a brake must be the last element '
                                                        '(it acts on the output shaft)')
                self.brake = el
            elif isinstance(el, (Clutch, Gearbox)):
                segments[-1].append(Inertia(f'{el.name}_input', el.J_input))
                segments.append([Inertia(f'{el.name}_output', el.J_output)])
                cuts.append(el)
            else:
                if getattr(el, 'variation', ()):
                    raise SceneError(f'driveline[{i}].stiffness_variation',
                                     'not available with a clutch, gearbox or brake yet')
                if getattr(el, 'imbalance', None) is not None:
                    raise SceneError(f'driveline[{i}].imbalance',
                                     'not available with a clutch, gearbox or brake yet')
                segments[-1].append(el)
        self.sections: list[tuple[Op, ...]] = []
        self.boundaries: list[Boundary] = []
        self.shafts: dict[str, tuple[int, int, str]] = {}   # name -> (section, op, role)
        self.clutches: dict[str, tuple[Clutch, int]] = {}
        self.gearboxes: dict[str, tuple[Gearbox, int]] = {}
        for s_i, seg in enumerate(segments):
            if not seg:
                raise SceneError('driveline', 'empty chain segment')
            check_layout(tuple(seg))
            chain = build_sections(SimpleNamespace(driveline=tuple(seg)), levels)
            base = len(self.sections)
            if s_i > 0:
                el = cuts[s_i - 1]
                b = len(self.boundaries)
                self.boundaries.append(Boundary(el.type, el.name))
                if isinstance(el, Clutch):
                    self.clutches[el.name] = (el, b)
                else:
                    self.gearboxes[el.name] = (el, b)
            for k, sec in enumerate(chain.ops):
                self.sections.append(sec)
                if k < len(chain.springs):
                    sp = chain.springs[k]
                    self.boundaries.append(Boundary('spring', sp.name, sp))
            for sh in chain.shafts:
                if sh.role != 'mid':
                    if sh.name in self.shafts:
                        raise SceneError('driveline', f'shaft name {sh.name!r} made twice')
                    self.shafts[sh.name] = (base + sh.section, sh.op_index, sh.role)
        if len({id(c.pack) for c, _b in self.clutches.values()}) > 1:
            # the one `clutch` command channel and its capacity (simulate._capacities)
            raise SceneError('driveline', 'one clutch pedal drives every clutch: give one clutch')
        if len(self.gearboxes) > 1:
            raise SceneError('driveline', 'at most one gearbox (the gear command drives it)')
        self.n_sections = len(self.sections)
        self.first_shaft = elements[0].name

    # --- modes -> groups ---------------------------------------------------------------

    def locked(self, mode: Mode, b: int) -> bool:
        bd = self.boundaries[b]
        if bd.kind == 'clutch':
            return mode.clutch[bd.name] == STUCK
        if bd.kind == 'gearbox':
            return mode.gear[bd.name] != 0
        return False

    def coupling_ratio(self, mode: Mode, b: int) -> float:
        """k = dphi_out/dphi_in of a locked boundary: 1 (clutch) or 1/i (gear)."""
        bd = self.boundaries[b]
        if bd.kind == 'gearbox':
            gb = self.gearboxes[bd.name][0]
            return 1.0 / gb.ratio(mode.gear[bd.name])
        return 1.0

    def assemble(self, mode: Mode) -> Assembly:
        groups: list[Group] = []
        links: list[int] = []
        ops: list[Op] = list(self.sections[0])
        secs, starts, coup = [0], [0], []
        for b in range(len(self.boundaries)):
            if self.locked(mode, b):
                coup.append((len(ops), b))
                ops.append((0.0, _coupling(self.coupling_ratio(mode, b), mode.offsets[b])))
                starts.append(len(ops))
                secs.append(b + 1)
                ops.extend(self.sections[b + 1])
            else:
                groups.append(Group(tuple(ops), tuple(secs), tuple(starts), tuple(coup)))
                links.append(b)
                ops, secs, starts, coup = list(self.sections[b + 1]), [b + 1], [0], []
        groups.append(Group(tuple(ops), tuple(secs), tuple(starts), tuple(coup)))
        pinned = self.brake is not None and mode.brake == STUCK
        return Assembly(tuple(groups), tuple(links), pinned)

    # --- state maps --------------------------------------------------------------------

    @staticmethod
    def _starts(group: Group, q: float) -> list[tuple[float, float]]:
        """(phi, a) at each section start of ``group`` at group angle q."""
        phi, a = q, 1.0
        out = []
        nxt = 0
        for k, (_jv, fn) in enumerate(group.ops):
            if nxt < len(group.starts) and group.starts[nxt] == k:
                out.append((phi, a))
                nxt += 1
            if fn is not None:
                po, r, _s = fn(phi)
                a = r * a
                phi = po
        while nxt < len(group.starts):       # a section that starts after the last op
            out.append((phi, a))
            nxt += 1
        return out

    def to_sections(self, asm: Assembly, y: FloatArray, work_base: SectionState) -> SectionState:
        """Mode state y -> SectionState (lock_loss carried from ``work_base``)."""
        n = len(asm.groups)
        q = np.empty(self.n_sections)
        v = np.empty(self.n_sections)
        for g, grp in enumerate(asm.groups):
            for s, (phi, a) in zip(grp.sections, self._starts(grp, float(y[g]))):
                q[s] = phi
                v[s] = a * float(y[n + g])
        return SectionState(q, v, np.array(y[2 * n:2 * n + N_WORK], dtype=float),
                            work_base.lock_loss)

    def to_mode(self, asm: Assembly, st: SectionState, new_locks: Sequence[int] = ()
                ) -> tuple[FloatArray, float]:
        """SectionState -> mode state y and the kinetic energy lost (J). A group holding a
        boundary in ``new_locks`` takes the momentum-conserving speed
        v = sum A_s M_s v_s / sum A_s^2 M_s (A_s: the group's a at section s, M_s its
        generalised inertia; a plastic impact); a pinned group v = 0."""
        n = len(asm.groups)
        y = np.zeros(2 * n + N_WORK)
        loss = 0.0
        fresh = set(new_locks)
        for g, grp in enumerate(asm.groups):
            q0 = float(st.q[grp.sections[0]])
            y[g] = q0
            pinned = asm.pinned and g == n - 1
            if not pinned and not fresh.intersection(b for _k, b in grp.couplings):
                y[n + g] = st.v[grp.sections[0]]
                continue
            ke_before = 0.0
            num = den = 0.0
            for s, (_phi, a) in zip(grp.sections, self._starts(grp, q0)):
                m_s = section_kinematics(self.sections[s], float(st.q[s]))[3]
                vs = float(st.v[s])
                ke_before += 0.5 * m_s * vs * vs
                num += a * m_s * vs
                den += a * a * m_s
            vg = 0.0 if pinned else num / den
            y[n + g] = vg
            loss += ke_before - 0.5 * den * vg * vg
        y[2 * n:] = st.work
        return y, loss

    def lock_offset(self, mode: Mode, b: int, st: SectionState) -> float:
        """Offset of boundary b locked now: q_right - k phi_end(q_left) (rad)."""
        k = self.coupling_ratio(mode, b)
        phi_end = section_kinematics(self.sections[b], float(st.q[b]))[0]
        return float(st.q[b + 1]) - k * phi_end

    # --- energies and shafts -----------------------------------------------------------

    def energy(self, st: SectionState) -> tuple[float, float]:
        """(kinetic, elastic) energy (J) from section states."""
        kin = 0.0
        for s, ops in enumerate(self.sections):
            m = section_kinematics(ops, float(st.q[s]))[3]
            kin += 0.5 * m * float(st.v[s]) ** 2
        el = 0.0
        for b, bd in enumerate(self.boundaries):
            if bd.kind == 'spring':
                phi_l = section_kinematics(self.sections[b], float(st.q[b]))[0]
                el += bd.spring.evaluate(phi_l - float(st.q[b + 1]), 0.0)[3]
        return kin, el

    def shaft_speed(self, st: SectionState, name: str) -> float:
        """Speed (rad/s) of a named inertia or joint input/output shaft."""
        s, k, role = self.shafts[name]
        phi, a = float(st.q[s]), 1.0
        for jv, fn in self.sections[s][:k + (1 if role == 'output' else 0)]:
            if fn is not None:
                phi, r, _b = fn(phi)
                a *= r
        return a * float(st.v[s])

    # --- right-hand side -----------------------------------------------------------------

    def evaluate(self, asm: Assembly, mode: Mode, t: float, y: FloatArray, *, engine: Any,
                 load: Any, clutch_kinetic: float, brake_kinetic: float) -> Evaluation:
        """ydot and witness quantities; ``clutch_kinetic`` / ``brake_kinetic``: kinetic
        capacities mu_k cgeo fn at t (N m)."""
        groups = asm.groups
        n = len(groups)
        yl = y.tolist()
        kin = [section_kinematics(g.ops, yl[i]) for i, g in enumerate(groups)]
        qf = [0.0] * n
        v0 = yl[n]
        t_e = engine.torque(t, v0, yl[0])
        phi_last, a_last = kin[-1][0], kin[-1][1]
        omega_last = a_last * yl[2 * n - 1]
        t_l = load.torque(t, omega_last, phi_last)
        qf[0] += t_e
        qf[-1] -= t_l * a_last
        p_damp = p_fric = 0.0
        if self.brake is not None and not asm.pinned:
            tb = mode.brake * brake_kinetic
            qf[-1] -= tb * a_last
            p_fric += tb * omega_last
        inflow = [t_e] + [0.0] * (n - 1)     # torque entering each group at its first shaft
        slip: dict[int, float] = {}
        for g, b in enumerate(asm.links):
            bd = self.boundaries[b]
            phi_l, a_l = kin[g][0], kin[g][1]
            thd = a_l * yl[n + g] - yl[n + g + 1]
            if bd.kind == 'spring':
                ts, _k, _kd, _v, pd = bd.spring.evaluate(phi_l - yl[g + 1], thd)
                p_damp += pd
            elif bd.kind == 'clutch':
                ts = mode.clutch[bd.name] * clutch_kinetic
                p_fric += ts * thd
                slip[b] = thd
            else:
                ts = 0.0
            qf[g] -= ts * a_l
            qf[g + 1] += ts
            inflow[g + 1] = ts
        ydot = np.zeros(2 * n + N_WORK)
        acc = [0.0] * n
        for g in range(n):
            ydot[g] = yl[n + g]
            acc[g] = (qf[g] - kin[g][4] * yl[n + g] ** 2) / kin[g][3]
        hold = 0.0
        if asm.pinned:
            hold = qf[-1] / a_last
            acc[-1] = 0.0
            ydot[n - 1] = 0.0
        for g in range(n):
            ydot[n + g] = acc[g]
        ydot[2 * n] = t_e * v0
        ydot[2 * n + 1] = t_l * omega_last
        ydot[2 * n + 2] = p_damp
        ydot[2 * n + 3] = p_fric
        stuck: dict[int, float] = {}
        for g, grp in enumerate(groups):
            want = [(k, b) for k, b in grp.couplings if self.boundaries[b].kind == 'clutch']
            if want:
                stuck.update(self._walk_torques(grp, yl[g], yl[n + g], acc[g], inflow[g], want))
        return Evaluation(ydot, t_e, t_l, slip, stuck, hold, omega_last)

    @staticmethod
    def _walk_torques(grp: Group, q: float, v: float, acc: float, torque: float,
                      want: Sequence[tuple[int, int]]) -> dict[int, float]:
        """Shaft torque just before each wanted coupling op (N m)."""
        phi, a, b = q, 1.0, 0.0
        out: dict[int, float] = {}
        targets = dict(want)
        for k, (jv, fn) in enumerate(grp.ops):
            if k in targets:
                out[targets[k]] = torque
            if fn is None:
                torque -= jv * (a * acc + b * v * v)
            else:
                po, r, s = fn(phi)
                b = s * a * a + r * b
                a = r * a
                phi = po
                torque = torque / r
        return out
