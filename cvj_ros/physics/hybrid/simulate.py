"""Python reference (the oracle) of a chain driveline with clutch, gearbox and brake.

Between events the mode's equations (cvj_ros.physics.hybrid.chain) are integrated by a
persistent stepper with dense output (cvj_ros.physics.solvers); after every accepted step
the witnesses of the present mode are checked (cvj_ros.physics.hybrid.events):

* slipping clutch or brake: slip speed s crossing zero -> try STUCK: merge the two sides
  (momentum-conserving), compute the torque needed to stay stuck; keep STUCK when it is
  within the static capacity mu_s cgeo fn, else slip the other way (Modelica
  PartialFriction's mode choice, :func:`cvj_ros.physics.hybrid.friction.decide_mode`);
* stuck clutch or brake: static capacity minus |stuck torque| crossing zero -> slip in the
  direction of the excess torque;
* engine speed crossing the stall speed downwards -> the run stops, reporting one line.

The event time is the witness's zero on the dense output (Brent); the stepper restarts
from there in the new mode. Command-row times are breakpoints: the stepper lands on them,
a new gear command is applied (neutral always; a gear only with no clutch stuck and when
|i omega_out| <= the gearbox's max input speed, else refused with a status line and not
retried until the command changes; the engagement is a momentum-conserving lock, an ideal synchroniser) and stuck elements whose
capacity no longer holds are released. Every kinetic energy lost in a lock and every joule
of friction work is booked, so the energy residual
(E_kin + E_el - E0 - W_engine + W_load + W_damp + W_friction + W_lock) / scale stays at the
solver's tolerance through every transition.
"""
from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from cvj_ros.errors import SceneError
from cvj_ros.physics.hybrid.chain import Assembly, Evaluation, HybridChain, Mode, SectionState
from cvj_ros.physics.hybrid.chain_jac import mode_jacobian
from cvj_ros.physics.hybrid.commands import CommandSchedule
from cvj_ros.physics.hybrid.elements import Clutch
from cvj_ros.physics.hybrid.events import Witness, crossed, locate, same_instant
from cvj_ros.physics.hybrid.friction import (BACKWARD, FORWARD, STUCK, decide_mode,
                                             mode_name)
from cvj_ros.physics.sections import section_kinematics
from cvj_ros.physics.solvers import make_stepper

__all__ = ['HybridResult', 'HybridSimulation', 'ModeEvent']

FloatArray = NDArray[np.float64]
# the methods that take the mode's analytic Jacobian (solvers._LinearlyImplicit)
ROSENBROCK_METHODS = ('rodas3', 'rodas4', 'rosenbrock', 'ros2')


@dataclass(frozen=True)
class ModeEvent:
    """A transition at t (s) of ``element`` from ``before`` to ``after``, and why."""

    t: float
    element: str
    before: str
    after: str
    cause: str


@dataclass
class HybridResult:
    """Samples (t, speeds of ``shafts``, energy residual, gear), events, status lines."""

    t: FloatArray
    shafts: list[str]
    speed: FloatArray                    # (samples, shafts) rad/s
    energy_residual: FloatArray          # (samples,)
    gear: np.ndarray                     # (samples,) engaged gear
    events: list[ModeEvent]
    statuses: list[str]
    stall: str | None
    final: SectionState
    final_mode: Mode
    t_end: float
    stats: dict[str, int] = field(default_factory=dict)
    # with ``joint_samples`` on the simulation: per sample the joint states' position (rad,
    # unwrapped) and effort (N m, shaft torque), as ``shafts``, and the engine torque (N m)
    position: FloatArray | None = None
    effort: FloatArray | None = None
    engine_torque: FloatArray | None = None

    def column(self, name: str) -> FloatArray:
        return self.speed[:, self.shafts.index(name)]

    def count(self, element: str, after: str | None = None) -> int:
        """Number of events of ``element`` (ending in mode ``after`` when given)."""
        return sum(1 for e in self.events if e.element == element
                   and (after is None or e.after == after))

    @property
    def max_energy_residual(self) -> float:
        return float(np.max(np.abs(self.energy_residual))) if self.energy_residual.size else 0.0


class HybridSimulation:
    """Offline run of a :class:`HybridChain` under a :class:`CommandSchedule`.

    Args:
        chain: the driveline. engine: ``torque(t, omega, phi)`` and ``set_throttle(x)``;
            load: ``torque(t, omega, phi)`` (resisting) on the last inertia.
        schedule: the commands (throttle, clutch, gear, brake over time).
        duration: s. sample_dt: sample spacing (s).
        initial_speed: engine speed at t = 0 (rad/s); it carries through springs, clutches
            not fully open at t = 0 and the gear commanded at t = 0 (behind an open clutch or
            neutral the chain starts at rest) unless ``initial_speeds`` sets the speed of the
            first shaft of a section (e.g. ``{'clutch_output': 0.0}``); angles start at 0.
        stall_speed: engine speed (rad/s) below which the engine counts as stalled (the run
            stops there); None: not checked.
        method, rtol, atol, max_step: the stepper (any method with dense output).
    """

    def __init__(self, chain: HybridChain, *, engine: Any, load: Any, schedule: CommandSchedule,
                 duration: float, sample_dt: float = 1e-2, initial_speed: float = 0.0,
                 initial_speeds: Mapping[str, float] | None = None,
                 stall_speed: float | None = None, method: str = 'dopri5',
                 rtol: float = 1e-8, atol: float = 1e-10, max_step: float = math.inf) -> None:
        self.chain = chain
        self.engine = engine
        self.load = load
        self.schedule = schedule
        self.duration = float(duration)
        self.sample_dt = float(sample_dt)
        self.stall_speed = stall_speed
        self.method, self.rtol, self.atol, self.max_step = method, rtol, atol, max_step
        self._throttle = schedule.has('throttle')    # else the engine keeps its own throttle
        self._gear_seen: int | None = None           # last gear command acted on (or refused)
        self.events: list[ModeEvent] = []
        self.statuses: list[str] = []
        self.initial_speed = float(initial_speed)
        self.initial_speeds = dict(initial_speeds or {})
        for name in self.initial_speeds:
            if name not in chain.shafts or chain.shafts[name][1] != 0:
                raise SceneError(f'initial_speeds.{name}', 'not the first shaft of a section')
        self.joint_samples = False   # True: run() also samples positions, efforts, engine torque
        self._seen: tuple[float, set[tuple]] = (-math.inf, set())   # modes at one instant

    # --- capacities ----------------------------------------------------------------------

    #: the end of the segment being integrated (s): the rhs and witnesses see a command jump
    #: there from the left (commands.Ramp.at); inf during the discrete transitions
    _t_end = math.inf

    def _clutch_fn(self, t: float) -> float:
        return Clutch.normal_force(self.schedule.value('clutch', t, self._t_end))

    def _brake_fn(self, t: float) -> float:
        return min(1.0, max(0.0, self.schedule.value('brake', t, self._t_end)))

    def _capacities(self, t: float) -> tuple[float, float, float, float]:
        """(clutch kinetic, clutch static, brake kinetic, brake static) at t (N m)."""
        ck = cs = bk = bs = 0.0
        if self.chain.clutches:
            f = self._clutch_fn(t)
            pack = next(iter(self.chain.clutches.values()))[0].pack
            ck, cs = pack.kinetic(f), pack.static(f)
        if self.chain.brake is not None:
            f = self._brake_fn(t)
            bk, bs = self.chain.brake.pack.kinetic(f), self.chain.brake.pack.static(f)
        return ck, cs, bk, bs

    def _eval(self, asm: Assembly, mode: Mode, t: float, y: FloatArray) -> Evaluation:
        if self._throttle:
            self.engine.set_throttle(self.schedule.value('throttle', t, self._t_end))
        ck, _cs, bk, _bs = self._capacities(t)
        return self.chain.evaluate(asm, mode, t, y, engine=self.engine, load=self.load,
                                   clutch_kinetic=ck, brake_kinetic=bk)

    def _jac(self, asm: Assembly, mode: Mode, t: float, y: FloatArray) -> FloatArray:
        """Analytic d(ydot)/dy of the mode at (t, y) (hybrid/chain_jac.py), for the
        Rosenbrock methods."""
        if self._throttle:
            self.engine.set_throttle(self.schedule.value('throttle', t, self._t_end))
        ck, _cs, bk, _bs = self._capacities(t)
        return mode_jacobian(self.chain, asm, mode, t, y, engine=self.engine, load=self.load,
                             clutch_kinetic=ck, brake_kinetic=bk)

    # --- witnesses -----------------------------------------------------------------------

    def _witnesses(self, asm: Assembly, mode: Mode) -> list[Witness]:
        ws: list[Witness] = []
        for name, (_cl, b) in self.chain.clutches.items():
            m = mode.clutch[name]
            if m == STUCK:
                ws += [Witness(('clutch', name, FORWARD), -1), Witness(('clutch', name, BACKWARD), -1)]
            else:
                ws.append(Witness(('clutch', name, STUCK), -1 if m == FORWARD else 1))
        if self.chain.brake is not None:
            name = self.chain.brake.name
            if mode.brake == STUCK:
                ws += [Witness(('brake', name, FORWARD), -1), Witness(('brake', name, BACKWARD), -1)]
            else:
                ws.append(Witness(('brake', name, STUCK), -1 if mode.brake == FORWARD else 1))
        if self.stall_speed is not None:
            ws.append(Witness(('stall', 'engine', 0), -1))
        return ws

    def _g(self, w: Witness, ev: Evaluation, t: float, y: FloatArray, n: int) -> float:
        kind, name, target = w.key
        if kind == 'stall':
            return float(y[n]) - self.stall_speed
        _ck, cs, _bk, bs = self._capacities(t)
        if kind == 'clutch':
            b = self.chain.clutches[name][1]
            if target == STUCK:
                return ev.slip[b]
            tst = ev.stuck_torque[b]
            return cs - tst if target == FORWARD else cs + tst
        if target == STUCK:
            return ev.omega_last
        return bs - ev.hold_torque if target == FORWARD else bs + ev.hold_torque

    # --- transitions ---------------------------------------------------------------------

    def _log(self, t: float, element: str, before: str, after: str, cause: str) -> None:
        self.events.append(ModeEvent(t, element, before, after, cause))

    def _apply(self, mode: Mode, st: SectionState, new_locks: list[int]
               ) -> tuple[Assembly, FloatArray, SectionState]:
        """Assemble ``mode``, map ``st`` onto it (booking the lock loss) and back."""
        asm = self.chain.assemble(mode)
        y, loss = self.chain.to_mode(asm, st, new_locks)
        st2 = self.chain.to_sections(asm, y, st)
        st2.lock_loss = st.lock_loss + loss
        return asm, y, st2

    def _try_stick(self, t: float, mode: Mode, st: SectionState, kind: str, name: str,
                   cause: str) -> tuple[Mode, SectionState]:
        """At zero slip: STUCK if the stuck torque is within the static capacity, else
        slip in its direction; returns the chosen mode and state."""
        _ck, cs, _bk, bs = self._capacities(t)
        cand = mode.copy()
        locks: list[int] = []
        if kind == 'clutch':
            b = self.chain.clutches[name][1]
            before = mode.clutch[name]
            cand.clutch[name] = STUCK
            cand.offsets[b] = self.chain.lock_offset(cand, b, st)
            locks = [b]
            cap = cs
        else:
            before = mode.brake
            cand.brake = STUCK
            cap = bs
        asm, y, st2 = self._apply(cand, st, locks)
        ev = self._eval(asm, cand, t, y)
        torque = ev.stuck_torque[locks[0]] if kind == 'clutch' else ev.hold_torque
        new = decide_mode(0.0, torque, cap)
        if new == STUCK:
            self._log(t, name, mode_name(before), 'stuck', cause)
            return cand, st2
        out = mode.copy()
        if kind == 'clutch':
            out.clutch[name] = new
        else:
            out.brake = new
        if new != before:
            self._log(t, name, mode_name(before), mode_name(new), cause)
        return out, st

    def _mark(self, t: float, mode: Mode) -> None:
        """Note ``mode`` as passed through at the instant t."""
        if not same_instant(t, self._seen[0]):
            self._seen = (t, set())
        self._seen[1].add((tuple(sorted(mode.clutch.items())), tuple(sorted(mode.gear.items())),
                           mode.brake))

    def _revisits(self, t: float, mode: Mode, kind: str, name: str) -> bool:
        """Sticking ``name`` would return to a mode already passed through at t."""
        cand = mode.copy()
        if kind == 'clutch':
            cand.clutch[name] = STUCK
        else:
            cand.brake = STUCK
        return same_instant(t, self._seen[0]) and (
            tuple(sorted(cand.clutch.items())), tuple(sorted(cand.gear.items())),
            cand.brake) in self._seen[1]

    def _release(self, t: float, mode: Mode, kind: str, name: str, new: int, cause: str) -> Mode:
        self._mark(t, mode)
        out = mode.copy()
        if kind == 'clutch':
            out.clutch[name] = new
            out.offsets.pop(self.chain.clutches[name][1], None)
        else:
            out.brake = new
        self._log(t, name, 'stuck', mode_name(new), cause)
        return out

    def _settle(self, t: float, mode: Mode, st: SectionState, fresh: tuple[str, ...] = ()
                ) -> tuple[Mode, SectionState]:
        """Release stuck elements whose capacity no longer holds and stick slipping ones at
        exactly zero slip that can hold; repeated until no mode changes (at most 8 rounds).
        Elements in ``fresh`` have just had their mode chosen at this event: they are not
        stuck again (just released, their stuck torque equals the capacity to rounding).
        Nor is an element stuck when that returns to a mode already passed through at this
        instant: a clutch and the brake behind it can each need the other stuck to hold, so
        sticking one again when the other let go repeated stick, stick, release, release at
        one instant and left whichever mode the last round set (a stuck element over its
        capacity); both slipping is the consistent mode there. (A stick to a mode not yet
        passed through stays allowed: an element released before another can be the one
        that holds once the other slips.)"""
        for _ in range(8):
            self._mark(t, mode)
            asm, y, st = self._apply(mode, st, [])
            ev = self._eval(asm, mode, t, y)
            _ck, cs, _bk, bs = self._capacities(t)
            changed = False
            for name, (_cl, b) in self.chain.clutches.items():
                m = mode.clutch[name]
                if m == STUCK:
                    new = decide_mode(0.0, ev.stuck_torque[b], cs)
                    if new != STUCK:
                        mode = self._release(t, mode, 'clutch', name, new, 'capacity below torque')
                        changed = True
                        break
                elif (ev.slip[b] == 0.0 and cs > 0.0 and name not in fresh
                      and not self._revisits(t, mode, 'clutch', name)):
                    m2, st2 = self._try_stick(t, mode, st, 'clutch', name, 'zero slip')
                    if m2.clutch[name] != m:
                        mode, st, changed = m2, st2, True
                        break
            if changed:
                continue
            br = self.chain.brake
            if br is not None:
                if mode.brake == STUCK:
                    new = decide_mode(0.0, ev.hold_torque, bs)
                    if new != STUCK:
                        mode = self._release(t, mode, 'brake', br.name, new, 'capacity below torque')
                        continue
                elif (ev.omega_last == 0.0 and bs > 0.0 and br.name not in fresh
                      and not self._revisits(t, mode, 'brake', br.name)):
                    m2, st2 = self._try_stick(t, mode, st, 'brake', br.name, 'zero speed')
                    if m2.brake != mode.brake:
                        mode, st = m2, st2
                        continue
            break
        return mode, st

    def _shift(self, t: float, mode: Mode, st: SectionState) -> tuple[Mode, SectionState]:
        """Apply the gear command at t (see the module docstring)."""
        for name, (gb, b) in self.chain.gearboxes.items():
            want = self.schedule.gear(t)
            have = mode.gear[name]
            if want == self._gear_seen:
                continue          # no new command (a refused gear is not retried)
            self._gear_seen = want
            if want == have:
                continue
            if not gb.valid_gear(want):
                self._status(t, f'gear {want} refused: {name} has gears -1, 0, 1..{len(gb.ratios)}')
                continue
            if want != 0:
                omega_out = float(st.v[b + 1])
                w_in = abs(gb.ratio(want) * omega_out)
                if w_in > gb.max_input_speed:
                    self._status(t, f'gear {want} refused: input speed {w_in:.1f} rad/s would '
                                    f'exceed {gb.max_input_speed:.1f} rad/s')
                    continue
                stuck = [c for c, m in mode.clutch.items() if m == STUCK]
                if stuck:
                    self._status(t, f'gear {want} refused: clutch {stuck[0]} is not open')
                    continue
            out = mode.copy()
            out.gear[name] = want
            out.offsets.pop(b, None)
            locks = []
            if want != 0:
                out.offsets[b] = self.chain.lock_offset(out, b, st)
                locks = [b]
            _asm, _y, st = self._apply(out, st, locks)
            self._log(t, name, f'gear {have}', f'gear {want}', 'command')
            mode = out
        return mode, st

    def joint_state(self, mode: Mode, st: SectionState, t: float
                    ) -> tuple[FloatArray, FloatArray, FloatArray, float]:
        """(position rad, velocity rad/s, effort N m per shaft of ``chain.shafts``, engine
        torque N m) of the sections' state ``st`` at ``t`` in ``mode``; the
        effort is the shaft torque entering each shaft, walked from each rigid group's first
        shaft with the group's acceleration as ``HybridChain.evaluate`` walks stuck torques
        (engine torque into the first group, the boundary torque into the others)."""
        ch = self.chain
        asm = ch.assemble(mode)
        y, _loss = ch.to_mode(asm, st)
        ev = self._eval(asm, mode, t, y)
        n = len(asm.groups)
        ck = self._capacities(t)[0]
        inflow = [ev.engine_torque] + [0.0] * (n - 1)
        for g, b in enumerate(asm.links):
            bd = ch.boundaries[b]
            if bd.kind == 'spring':
                phi_l, a_l = section_kinematics(asm.groups[g].ops, float(y[g]))[:2]
                thd = a_l * float(y[n + g]) - float(y[n + g + 1])
                inflow[g + 1] = bd.spring.evaluate(phi_l - float(y[g + 1]), thd)[0]
            elif bd.kind == 'clutch':
                inflow[g + 1] = mode.clutch[bd.name] * ck
        where: dict[tuple[int, int], int] = {}    # (section, op) -> index in chain.shafts
        for i, (s, k, role) in enumerate(ch.shafts.values()):
            where[(s, k + (1 if role == 'output' else 0))] = i
        m = len(ch.shafts)
        pos, vel, eff = np.zeros(m), np.zeros(m), np.zeros(m)
        for g, grp in enumerate(asm.groups):
            phi, a, b = float(y[g]), 1.0, 0.0
            v, acc, torque = float(y[n + g]), float(ev.ydot[n + g]), inflow[g]
            sec_at = dict(zip(grp.starts, grp.sections))
            s, base = grp.sections[0], 0
            for k, (jv, fn) in enumerate(grp.ops):
                if k in sec_at:
                    s, base = sec_at[k], k
                i = where.get((s, k - base))
                if i is not None:
                    pos[i], vel[i], eff[i] = phi, a * v, torque
                if fn is None:
                    torque -= jv * (a * acc + b * v * v)
                else:
                    po, r, sd = fn(phi)
                    b = sd * a * a + r * b
                    a = r * a
                    phi = po
                    torque = torque / r
            i = where.get((s, len(grp.ops) - base))
            if i is not None:                     # a joint output at the group's end
                pos[i], vel[i], eff[i] = phi, a * v, torque
        return pos, vel, eff, float(ev.engine_torque)

    def _status(self, t: float, text: str) -> None:
        self.statuses.append(f't={t:.6f} s: {text}')

    # --- the run ---------------------------------------------------------------------------

    def _initial(self) -> tuple[Mode, SectionState]:
        ch = self.chain
        self._seen = (-math.inf, set())
        mode = Mode(clutch={c: FORWARD for c in ch.clutches},
                    gear={g: self.schedule.gear(0.0) for g in ch.gearboxes},
                    brake=None if ch.brake is None else FORWARD)
        for name, (gb, b) in ch.gearboxes.items():
            if not gb.valid_gear(mode.gear[name]):
                raise SceneError('commands', f'gear {mode.gear[name]} at t=0 is not a gear of {name}')
        q = np.zeros(ch.n_sections)
        v = np.zeros(ch.n_sections)
        lead = {sec: name for name, (sec, k, role) in ch.shafts.items() if k == 0 and role != 'output'}
        speed = self.initial_speed
        for s in range(ch.n_sections):
            if s > 0:
                bd = ch.boundaries[s - 1]
                phi_end, a_end, _b, _m, _c = section_kinematics(ch.sections[s - 1], float(q[s - 1]))
                speed = a_end * v[s - 1]
                q[s] = phi_end
                if bd.kind == 'clutch' and self.schedule.value('clutch', 0.0) >= 1.0:
                    speed = 0.0           # behind a clutch open at t = 0: at rest
                if bd.kind == 'gearbox':
                    g = mode.gear[bd.name]
                    speed = 0.0 if g == 0 else speed / ch.gearboxes[bd.name][0].ratio(g)
                    if g:
                        q[s] = phi_end / ch.gearboxes[bd.name][0].ratio(g)
            if lead.get(s) in self.initial_speeds:
                speed = float(self.initial_speeds[lead[s]])
            v[s] = speed
        st = SectionState(q, v, np.zeros(4))
        for name, (gb, b) in ch.gearboxes.items():
            if mode.gear[name] != 0:
                mode.offsets[b] = ch.lock_offset(mode, b, st)
        for name, (_cl, b) in ch.clutches.items():
            s_l = ch.shaft_speed(st, f'{name}_input')
            s_r = ch.shaft_speed(st, f'{name}_output')
            mode.clutch[name] = BACKWARD if s_l < s_r else FORWARD   # equal: settle may stick
        if ch.brake is not None:
            w = float(v[-1])
            mode.brake = BACKWARD if w < 0 else FORWARD
        mode, st = self._settle(0.0, mode, st)
        return mode, st

    def run(self) -> HybridResult:
        ch = self.chain
        self._t_end = math.inf
        mode, st = self._initial()
        st.lock_loss = 0.0
        kin, el = ch.energy(st)
        e0 = kin + el
        names = [n for n, (_s, _k, role) in ch.shafts.items()]
        times = np.arange(0.0, self.duration + 0.5 * self.sample_dt, self.sample_dt)
        times = times[times <= self.duration + 1e-12]
        speed = np.full((times.size, len(names)), np.nan)
        resid = np.full(times.size, np.nan)
        gears = np.zeros(times.size, dtype=int)
        gb_name = next(iter(ch.gearboxes), None)
        k_sample = 0
        stats = {'steps': 0, 'nfev': 0, 'events': 0, 'restarts': 0}
        stall: str | None = None

        js = ((np.full((times.size, len(names)), np.nan), np.full((times.size, len(names)), np.nan),
               np.full(times.size, np.nan)) if self.joint_samples else None)

        def record(t_s: float, s: SectionState, i: int) -> None:
            if js is not None:
                p_, _v, e_, te_ = self.joint_state(mode, s, t_s)
                js[0][i], js[1][i], js[2][i] = p_, e_, te_
            speed[i] = [ch.shaft_speed(s, nm) for nm in names]
            kin_, el_ = ch.energy(s)
            we, wl, wd, wf = (float(x) for x in s.work)
            scale = max(abs(kin_ + el_), abs(e0), abs(we), abs(wl), abs(wd), abs(wf),
                        abs(s.lock_loss), 1e-12)
            resid[i] = (kin_ + el_ - e0 - we + wl + wd + wf + s.lock_loss) / scale
            gears[i] = mode.gear[gb_name] if gb_name else 0

        t = 0.0
        mode, st = self._shift(0.0, mode, st)
        while t < self.duration and stall is None:
            self._t_end = math.inf
            t_stop = min(self.schedule.next_breakpoint(t), self.duration)
            if t_stop - t <= 1e-12 * max(1.0, abs(t)):
                # an event a rounding error before a command row: the row acts now (a step
                # that short would trip the step-size floor)
                t = t_stop
                if t < self.duration:
                    mode, st = self._shift(t, mode, st)
                    mode, st = self._settle(t, mode, st)
                continue
            asm = ch.assemble(mode)
            y0, _loss = ch.to_mode(asm, st)
            n = len(asm.groups)
            fun = lambda tt, yy, asm=asm, mode=mode: self._eval(asm, mode, tt, yy).ydot  # noqa: E731
            jac = None
            if self.method in ROSENBROCK_METHODS:
                jac = lambda tt, yy, asm=asm, mode=mode: self._jac(asm, mode, tt, yy)  # noqa: E731
            self._t_end = t_stop      # a jump at t_stop is seen from the left until it
            stepper = make_stepper(self.method, fun, t, y0, rtol=self.rtol, atol=self.atol,
                                   max_step=self.max_step, jac=jac)
            if jac is not None:
                stepper.ft_window = (t, t_stop)     # commands jump only at segment ends
            stats['restarts'] += 1
            ws = self._witnesses(asm, mode)
            ev0 = self._eval(asm, mode, t, y0)
            g_old = [self._g(w, ev0, t, y0, n) for w in ws]
            if self.stall_speed is not None and float(y0[n]) < self.stall_speed:
                stall = f'engine stalled at t={t:.6f} s: {float(y0[n]):.2f} rad/s below the stall speed {self.stall_speed:.2f} rad/s'
                break
            while True:
                t_old = stepper.t
                stepper.step(t_stop)
                stats['steps'] += 1
                y_new = stepper.y
                ev = self._eval(asm, mode, stepper.t, y_new)
                g_new = [self._g(w, ev, stepper.t, y_new, n) for w in ws]
                hits = []
                for i, w in enumerate(ws):
                    if crossed(w.direction, g_old[i], g_new[i]):
                        def g_of(tau: float, w: Witness = w) -> float:
                            yy = stepper.dense(tau)
                            return self._g(w, self._eval(asm, mode, tau, yy), tau, yy, n)
                        hits.append((locate(g_of, t_old, stepper.t, g_new[i]), i))
                t_end = min(hits)[0] if hits else stepper.t
                while k_sample < times.size and times[k_sample] <= t_end:
                    ts_ = float(times[k_sample])
                    yy = stepper.y if ts_ == stepper.t else stepper.dense(max(ts_, t_old))
                    record(ts_, ch.to_sections(asm, yy, st), k_sample)
                    k_sample += 1
                if hits:
                    t_ev, i = min(hits)
                    y_ev = stepper.y if t_ev == stepper.t else stepper.dense(t_ev)
                    self._t_end = math.inf
                    st = ch.to_sections(asm, y_ev, st)
                    t = t_ev
                    stats['events'] += 1
                    kind, name, target = ws[i].key
                    if kind == 'stall':
                        stall = (f'engine stalled at t={t:.6f} s: speed fell below the stall '
                                 f'speed {self.stall_speed:.2f} rad/s '
                                 f'({self.stall_speed * 30 / math.pi:.0f} rpm)')
                        break
                    if target == STUCK:
                        mode, st = self._try_stick(t, mode, st, kind, name, 'zero slip')
                    else:
                        mode = self._release(t, mode, kind, name, target, 'torque above static capacity')
                    mode, st = self._settle(t, mode, st, (name,))
                    if t >= t_stop and t < self.duration:    # the event is on a command row
                        mode, st = self._shift(t, mode, st)
                        mode, st = self._settle(t, mode, st, (name,))
                    break
                g_old = g_new
                if stepper.t >= t_stop:
                    self._t_end = math.inf
                    t = t_stop
                    st = ch.to_sections(asm, stepper.y, st)
                    if t < self.duration:
                        mode, st = self._shift(t, mode, st)
                        mode, st = self._settle(t, mode, st)
                    break
            stats['nfev'] += stepper.nfev
        self._t_end = math.inf
        if stall is not None:
            self.statuses.append(stall)
        keep = k_sample
        res = HybridResult(times[:keep], names, speed[:keep], resid[:keep], gears[:keep],
                           list(self.events), list(self.statuses), stall, st, mode, t, stats)
        if js is not None:
            res.position, res.effort, res.engine_torque = (a[:keep] for a in js)
        return res
