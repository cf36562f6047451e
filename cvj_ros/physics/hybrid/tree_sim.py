"""Python reference (the oracle) of a vehicle tree with clutch, gearbox and wheel brakes.

The event loop of the chain reference (cvj_ros.physics.hybrid.simulate, same witnesses, same
Brent location on the dense output, same mode choice) on the tree's equations per mode
(cvj_ros.physics.hybrid.tree.ModeTree):

* slipping clutch: slip speed crossing zero -> try STUCK (a plastic lock, the kinetic energy
  lost booked), kept when the stuck torque is within mu_s cgeo fn; stuck clutch: the margin
  mu_s cgeo fn -/+ T_stuck crossing zero -> slip;
* slipping wheel brake: the wheel speed crossing zero -> try STUCK (the wheel's section is
  pinned: its speed is exactly 0.0 from then on); stuck: the margin to T_hold -> slip;
* engine speed below the stall speed -> the run stops with one status line;
* with a shift schedule (cvj_ros.physics.hybrid.shift), while every clutch is locked (not
  during a launch or a shift): the synchronous input speed crossing an up- or down-shift
  speed starts a shift sequence (an event ``shift``); already past it when the clutch
  locks, the shift starts at the lock.

Command rows and the shift sequence's steps are breakpoints; a gear command is applied
there (refused with a status when a clutch is stuck or the engine would over-speed, as on
the chain). The energy residual
(E_kin + E_el - E0 - W_engine + W_damp + W_slip + W_road + W_friction + W_lock) / scale
stays at the solver's tolerance through every transition.

Start: the engine at the scene's initial speed; behind an open clutch or neutral the
driveline rolls with the vehicle (``vehicle.initial_speed``, else at rest); with the clutch
closed on an engaged gear the vehicle's speed sets the engine's. A car starting at rest
starts with its tyres' relaxed slip carrying the grade force (a car that has been standing:
ModeTree.equilibrium_slip), so a held car is at rest, not settling.
"""
from __future__ import annotations

import itertools
import math
from collections.abc import Mapping
from typing import Any

import numpy as np
from numpy.typing import NDArray

from cvj_ros.errors import SceneError
from cvj_ros.physics.hybrid.chain import Mode
from cvj_ros.physics.hybrid.elements import Clutch
from cvj_ros.physics.hybrid.events import Witness, crossed, locate, same_instant
from cvj_ros.physics.hybrid.friction import BACKWARD, FORWARD, STUCK, decide_mode, mode_name
from cvj_ros.physics.hybrid.simulate import ROSENBROCK_METHODS, HybridResult, ModeEvent
from cvj_ros.physics.hybrid.tree import ModeTree, TreeEvaluation, TreeState
from cvj_ros.physics.hybrid.tree_jac import tree_mode_jacobian
from cvj_ros.physics.scene import Scene, Spring, iter_elements
from cvj_ros.physics.solvers import make_stepper

__all__ = ['HybridTreeSimulation']

FloatArray = NDArray[np.float64]


class HybridTreeSimulation:
    """Offline run of a vehicle scene with mode elements under a command schedule.

    Args:
        scene: a vehicle scene (``scene.vehicle``) whose trunk holds the clutch and gearbox
            and whose wheels may carry brakes. levels: joint / spring fidelity levels.
        engine: ``torque(t, omega, phi)``, ``set_throttle(x)``.
        schedule: CommandSchedule, or AutoShift (cvj_ros.physics.hybrid.shift) with a
            shift schedule.
        duration, sample_dt (s); stall_speed (rad/s) or None; method, rtol, atol, max_step:
            the stepper (a method with dense output).
    """

    def __init__(self, scene: Scene, levels: Mapping[str, str], *, engine: Any, schedule: Any,
                 duration: float, sample_dt: float = 1e-2, stall_speed: float | None = None,
                 method: str = 'dopri5', rtol: float = 1e-8, atol: float = 1e-10,
                 max_step: float = math.inf) -> None:
        self.scene = scene
        self.levels = dict(levels)
        self.engine = engine
        self.schedule = schedule
        self.auto = schedule if hasattr(schedule, 'start') else None
        self.duration = float(duration)
        self.sample_dt = float(sample_dt)
        self.stall_speed = stall_speed
        self.method, self.rtol, self.atol, self.max_step = method, rtol, atol, max_step
        self._throttle = schedule.has('throttle')
        self._gear_seen: int | None = None
        self.events: list[ModeEvent] = []
        self.statuses: list[str] = []
        self._cache: dict[tuple, ModeTree] = {}
        self._seen: tuple[float, set[tuple]] = (-math.inf, set())   # modes at one instant
        self._released: tuple[float, set[str]] = (-math.inf, set())   # _release, _settle
        els = list(iter_elements(scene.driveline))
        self.clutches = {el.name: el for el in els if getattr(el, 'type', '') == 'clutch'}
        self.gearboxes = {el.name: el for el in els if getattr(el, 'type', '') == 'gearbox'}
        self.brake_els = {el.name: el for el in els if getattr(el, 'type', '') == 'brake'}
        if len(self.gearboxes) > 1:
            raise SceneError('driveline', 'at most one gearbox (the gear command drives it)')
        packs = {id(c.pack): c.pack for c in self.clutches.values()}
        self._clutch_pack = next(iter(self.clutches.values())).pack if self.clutches else None
        if len(packs) > 1:
            raise SceneError('driveline', 'one clutch pedal drives every clutch: give one clutch')
        self.chain = None        # no chain (hybrid_summary reads the chain's output brake there)
        self.packs = [el.name for el in els if getattr(el, 'kind', '') == 'clutch_pack']
        probe = Mode(clutch={c: FORWARD for c in self.clutches}, gear={g: 0 for g in self.gearboxes},
                     brakes={b: FORWARD for b in self.brake_els}, packs={p: FORWARD for p in self.packs})
        self.probe = self.tree(probe)
        self.shaft_names = list(self.probe.shaft_names)
        self.joint_samples = False   # True: run() also samples positions, efforts, engine torque

    # --- modes -----------------------------------------------------------------------------

    def tree(self, mode: Mode) -> ModeTree:
        """The ModeTree of ``mode`` (cached by mode and offsets)."""
        key = (tuple(sorted(mode.clutch.items())), tuple(sorted(mode.gear.items())),
               tuple(sorted((k, v == STUCK) for k, v in mode.brakes.items())),
               tuple(sorted(mode.packs.items())), tuple(sorted(mode.offsets.items())))
        mt = self._cache.get(key)
        if mt is None:
            if len(self._cache) > 256:
                self._cache.clear()
            mt = ModeTree(self.scene, self.levels, mode)
            self._cache[key] = mt
        mt.mode = mode          # the slip directions (FORWARD / BACKWARD) are read at evaluation
        return mt

    #: the end of the segment being integrated (s): the rhs and witnesses see a command jump
    #: there from the left (commands.Ramp.at); inf during the discrete transitions
    _t_end = math.inf

    def _capacities(self, t: float) -> tuple[float, float, dict[str, float], dict[str, float]]:
        """(clutch kinetic, clutch static, brake kinetic by name, brake static by name) (N m)."""
        ck = cs = 0.0
        if self._clutch_pack is not None:
            f = Clutch.normal_force(self.schedule.value('clutch', t, self._t_end))
            ck, cs = self._clutch_pack.kinetic(f), self._clutch_pack.static(f)
        b = min(1.0, max(0.0, self.schedule.value('brake', t, self._t_end)))
        bk = {n: el.pack.kinetic(b) for n, el in self.brake_els.items()}
        bs = {n: el.pack.static(b) for n, el in self.brake_els.items()}
        return ck, cs, bk, bs

    def _eval(self, mt: ModeTree, t: float, x: FloatArray, torques: bool = True) -> TreeEvaluation:
        if self._throttle:
            self.engine.set_throttle(self.schedule.value('throttle', t, self._t_end))
        ck, _cs, bk, _bs = self._capacities(t)
        return mt.evaluate(t, x, self.engine, ck, bk, torques=torques)

    def _jac(self, mt: ModeTree, t: float, x: FloatArray) -> FloatArray:
        """Analytic d(xdot)/dx of the mode at (t, x) (hybrid/tree_jac.py), for the
        Rosenbrock methods."""
        if self._throttle:
            self.engine.set_throttle(self.schedule.value('throttle', t))
        ck, _cs, bk, _bs = self._capacities(t)
        return tree_mode_jacobian(mt, t, x, self.engine, ck, bk)

    def joint_state(self, mt: ModeTree, t: float, x: FloatArray
                    ) -> tuple[FloatArray, FloatArray, FloatArray, float]:
        """(position rad, velocity rad/s, effort N m per name of :attr:`shaft_names`, engine
        torque N m) at (t, x) in the mode of ``mt``: the tree's backward walk
        (TreeDriveline.joint_states) on the forces of that mode (slipping clutch and brake
        torques, pinned wheels' holding torques), intermediate members filled."""
        made: list[Any] = []
        forces = mt._forces

        def keep(*args: Any, **kw: Any) -> Any:
            made.append(forces(*args, **kw))
            return made[-1]

        mt._forces = keep                  # type: ignore[method-assign]
        try:
            self._eval(mt, t, x, False)
        finally:
            del mt._forces
        fo = made[0]
        pos, vel, eff, _start = mt._walk(x, fo.T_engine, kin=mt._kinematics(x), fo=fo)
        pos, vel = np.array(pos, dtype=float), np.array(vel, dtype=float)
        if mt._mid_index:
            mt.fill_mid(pos[None, :], vel[None, :])
        return pos, vel, np.asarray(eff, dtype=float), float(fo.T_engine)

    @staticmethod
    def _joint_arrays(n: int, m: int) -> tuple[FloatArray, FloatArray, FloatArray]:
        """NaN-filled (positions, efforts) of n samples by m shafts and engine torques."""
        return np.full((n, m), np.nan), np.full((n, m), np.nan), np.full(n, np.nan)

    def _apply(self, mode: Mode, st: TreeState, fresh: bool) -> tuple[ModeTree, FloatArray, TreeState]:
        mt = self.tree(mode)
        x, loss = mt.from_state(st, fresh)
        st2 = mt.to_state(x, st.lock_loss + (loss if fresh else 0.0))
        return mt, x, st2

    # --- witnesses -------------------------------------------------------------------------

    def _witnesses(self, mode: Mode) -> list[Witness]:
        ws: list[Witness] = []
        for name, m in mode.clutch.items():
            if m == STUCK:
                ws += [Witness(('clutch', name, FORWARD), -1), Witness(('clutch', name, BACKWARD), -1)]
            else:
                ws.append(Witness(('clutch', name, STUCK), -1 if m == FORWARD else 1))
        for name, m in mode.brakes.items():
            if m == STUCK:
                ws += [Witness(('brake', name, FORWARD), -1), Witness(('brake', name, BACKWARD), -1)]
            else:
                ws.append(Witness(('brake', name, STUCK), -1 if m == FORWARD else 1))
        for name, m in mode.packs.items():
            if m == STUCK:
                ws += [Witness(('pack', name, FORWARD), -1), Witness(('pack', name, BACKWARD), -1)]
            else:
                ws.append(Witness(('pack', name, STUCK), -1 if m == FORWARD else 1))
        if self.stall_speed is not None:
            ws.append(Witness(('stall', 'engine', 0), -1))
        locked = all(m == STUCK for m in mode.clutch.values())
        if self.auto is not None and locked:
            for name, g in mode.gear.items():
                if g >= 1 and not self.auto.busy(self._t_now):
                    if self.auto.schedule.up(g) is not None:
                        ws.append(Witness(('shift', name, g + 1), 1))
                    if self.auto.schedule.down(g) is not None:
                        ws.append(Witness(('shift', name, g - 1), -1))
        return ws

    def _g(self, w: Witness, ev: TreeEvaluation, t: float, mode: Mode) -> float:
        kind, name, target = w.key
        if kind == 'stall':
            return ev.engine_speed - self.stall_speed
        if kind == 'shift':
            g = mode.gear[name]
            sync = self.gearboxes[name].ratio(g) * ev.gearbox_output[name]
            lim = self.auto.schedule.up(g) if target > g else self.auto.schedule.down(g)
            return sync - lim
        if kind == 'pack':
            if target == STUCK:
                return ev.pack_slip[name]
            tst = ev.pack_stuck[name]
            cap = ev.pack_static[name]
            return cap - tst if target == FORWARD else cap + tst
        _ck, cs, _bk, bs = self._capacities(t)
        if kind == 'clutch':
            if target == STUCK:
                return ev.slip[name]
            tst = ev.stuck_torque[name]
            return cs - tst if target == FORWARD else cs + tst
        if target == STUCK:
            return ev.wheel_speed[name]
        th = ev.hold[name]
        return bs[name] - th if target == FORWARD else bs[name] + th

    # --- transitions -----------------------------------------------------------------------

    def _log(self, t: float, element: str, before: str, after: str, cause: str) -> None:
        self.events.append(ModeEvent(t, element, before, after, cause))

    def _status(self, t: float, text: str) -> None:
        self.statuses.append(f't={t:.6f} s: {text}')

    def _try_stick(self, t: float, mode: Mode, st: TreeState, kind: str, name: str,
                   cause: str) -> tuple[Mode, TreeState]:
        """At zero slip (clutch) or zero wheel speed (brake): STUCK if the torque needed is
        within the static capacity, else slip in its direction."""
        _ck, cs, _bk, bs = self._capacities(t)
        cand = mode.copy()
        if kind == 'clutch':
            before = mode.clutch[name]
            cand.clutch[name] = STUCK
            idx = self.probe.clutch_link[name]
            cand.offsets[idx] = self.tree(mode).lock_offset(idx, st, 1.0)
            cap = cs
        elif kind == 'pack':
            before = mode.packs[name]
            cand.packs[name] = STUCK
            d = self.probe.packs[name][1]
            cand.offsets[-(d + 1)] = st.delta[d]
        else:
            before = mode.brakes[name]
            cand.brakes[name] = STUCK
            cap = bs[name]
        mt, x, st2 = self._apply(cand, st, True)
        ev = self._eval(mt, t, x)
        if kind == 'pack':
            torque, cap = ev.pack_stuck[name], ev.pack_static[name]
        else:
            torque = ev.stuck_torque[name] if kind == 'clutch' else ev.hold[name]
        new = decide_mode(0.0, torque, cap)
        if new == STUCK:
            self._log(t, name, mode_name(before), 'stuck', cause)
            return cand, st2
        out = mode.copy()
        if kind == 'clutch':
            out.clutch[name] = new
        elif kind == 'pack':
            out.packs[name] = new
        else:
            out.brakes[name] = new
        if new != before:
            self._log(t, name, mode_name(before), mode_name(new), cause)
        return out, st

    @staticmethod
    def _mode_key(mode: Mode) -> tuple:
        """The discrete part of ``mode`` (every element's mode and the gears, no offsets)."""
        return (tuple(sorted(mode.clutch.items())), tuple(sorted(mode.gear.items())),
                tuple(sorted(mode.brakes.items())), tuple(sorted(mode.packs.items())))

    def _mark(self, t: float, mode: Mode) -> None:
        """Note ``mode`` as passed through at the instant t (events.same_instant)."""
        if not same_instant(t, self._seen[0]):
            self._seen = (t, set())
        self._seen[1].add(self._mode_key(mode))

    @staticmethod
    def _modes_of(mode: Mode, kind: str) -> dict[str, int]:
        """``mode``'s modes of one kind of friction element ('clutch', 'brake', 'pack')."""
        return {'clutch': mode.clutch, 'brake': mode.brakes, 'pack': mode.packs}[kind]

    def _revisits(self, t: float, mode: Mode, kind: str, name: str) -> bool:
        """Sticking ``name`` would return to a mode already passed through at t."""
        cand = mode.copy()
        self._modes_of(cand, kind)[name] = STUCK
        return same_instant(t, self._seen[0]) and self._mode_key(cand) in self._seen[1]

    def _release(self, t: float, mode: Mode, kind: str, name: str, new: int, cause: str) -> Mode:
        self._mark(t, mode)
        if not same_instant(t, self._released[0]):
            self._released = (t, set())
        self._released[1].add(name)
        out = mode.copy()
        if kind == 'clutch':
            out.clutch[name] = new
            out.offsets.pop(self.probe.clutch_link[name], None)
        elif kind == 'pack':
            out.packs[name] = new
            out.offsets.pop(-(self.probe.packs[name][1] + 1), None)
        else:
            out.brakes[name] = new
        self._log(t, name, 'stuck', mode_name(new), cause)
        return out

    def _settle(self, t: float, mode: Mode, st: TreeState, fresh: tuple[str, ...] = ()
                ) -> tuple[Mode, TreeState]:
        """Release stuck elements whose capacity no longer holds, stick slipping ones at
        exactly zero slip that can hold, repeated until no mode changes (at most 16 rounds).
        Not stuck again at this instant: an element in ``fresh`` (the event's) or released
        at it before this call (two brakes behind an open differential reach their capacity
        together: the second one's witness fires at the same instant, and re-sticking the
        first, its hold equal to its capacity to rounding, only releases it again); nor, as
        on the chain (HybridSimulation._settle), an element whose stick returns to a mode
        already passed through at this instant (a clutch and a clutch-pack differential can
        cycle stick, release, stick, ...), while a stick to a mode not passed through yet
        stays allowed (a clutch released before the pack holds again once the pack slips).
        Ending in a mode inconsistent at t (_violations: the settle never turns a slip's
        direction), or after its rounds, the deciding elements' modes are chosen together
        (_joint)."""
        if same_instant(t, self._released[0]):
            fresh = tuple(fresh) + tuple(sorted(self._released[1]))
        for _ in range(16):
            self._mark(t, mode)
            mt, x, st = self._apply(mode, st, False)
            ev = self._eval(mt, t, x)
            _ck, cs, _bk, bs = self._capacities(t)
            changed = False
            for name, m in mode.clutch.items():
                if m == STUCK:
                    new = decide_mode(0.0, ev.stuck_torque[name], cs)
                    if new != STUCK:
                        mode = self._release(t, mode, 'clutch', name, new, 'capacity below torque')
                        changed = True
                        break
                elif (ev.slip[name] == 0.0 and cs > 0.0 and name not in fresh
                      and not self._revisits(t, mode, 'clutch', name)):
                    m2, st2 = self._try_stick(t, mode, st, 'clutch', name, 'zero slip')
                    if m2.clutch[name] != m:
                        mode, st, changed = m2, st2, True
                        break
            if changed:
                continue
            for name, m in mode.brakes.items():
                if m == STUCK:
                    new = decide_mode(0.0, ev.hold[name], bs[name])
                    if new != STUCK:
                        mode = self._release(t, mode, 'brake', name, new, 'capacity below torque')
                        changed = True
                        break
                elif (ev.wheel_speed[name] == 0.0 and bs[name] > 0.0 and name not in fresh
                      and not self._revisits(t, mode, 'brake', name)):
                    m2, st2 = self._try_stick(t, mode, st, 'brake', name, 'zero speed')
                    if m2.brakes[name] != m:
                        mode, st, changed = m2, st2, True
                        break
            if changed:
                continue
            for name, m in mode.packs.items():
                if m == STUCK:
                    new = decide_mode(0.0, ev.pack_stuck[name], ev.pack_static[name])
                    if new != STUCK:
                        mode = self._release(t, mode, 'pack', name, new, 'capacity below torque')
                        changed = True
                        break
                elif (ev.pack_slip[name] == 0.0 and name not in fresh
                      and not self._revisits(t, mode, 'pack', name)):
                    m2, st2 = self._try_stick(t, mode, st, 'pack', name, 'zero slip')
                    if m2.packs[name] != m:
                        mode, st, changed = m2, st2, True
                        break
            if not changed:
                if not self._violations(t, mode, st, (mt, x, ev)):
                    return mode, st
                break
        # inconsistent, or the rounds used up (the mode changed after its last evaluation)
        return self._joint(t, mode, st, fresh)

    #: at most this many elements (stuck, or slipping at zero slip) are chosen together by
    #: :meth:`_joint` (3**n modes); beyond it the one-at-a-time result stands with a status
    JOINT_MAX = 6

    #: the step (s) along a mode's derivative that reads a zero slip's direction
    _H_DIRECTION = 1e-7

    def _at_zero(self, t: float, mode: Mode, ev: TreeEvaluation) -> list[tuple[str, str]]:
        """(kind, name) of the elements deciding at t: stuck, or slipping at exactly zero
        slip (zero wheel speed) with a static capacity > 0; clutches, brakes, packs in
        scene order."""
        _ck, cs, _bk, bs = self._capacities(t)
        out: list[tuple[str, str]] = []
        for name, m in mode.clutch.items():
            if m == STUCK or (ev.slip[name] == 0.0 and cs > 0.0):
                out.append(('clutch', name))
        for name, m in mode.brakes.items():
            if m == STUCK or (ev.wheel_speed[name] == 0.0 and bs[name] > 0.0):
                out.append(('brake', name))
        for name, m in mode.packs.items():
            if m == STUCK or ev.pack_slip[name] == 0.0:
                out.append(('pack', name))
        return out

    def _violations(self, t: float, mode: Mode, st: TreeState,
                    held: tuple[ModeTree, FloatArray, TreeEvaluation] | None = None
                    ) -> list[str]:
        """Names of the elements ``mode`` is inconsistent for at (t, st): stuck beyond its
        static capacity (decide_mode), or slipping at zero slip with a static capacity > 0
        while its slip, one step _H_DIRECTION along the mode's derivative, has the sign
        opposite to its mode (its friction assumes the other direction). ``held``: (tree,
        state, evaluation) of ``mode`` at st from _apply(mode, st, False), its stuck elements
        already known to hold (the settle's last round); None evaluates and checks all."""
        full = held is None
        if held is None:
            mt, x, _st = self._apply(mode, st, False)
            ev = self._eval(mt, t, x)
        else:
            mt, x, ev = held
        _ck, cs, _bk, bs = self._capacities(t)
        bad: list[str] = []
        moving: list[tuple[str, str, int]] = []
        for kind, name in self._at_zero(t, mode, ev):
            m = self._modes_of(mode, kind)[name]
            if m != STUCK:
                moving.append((kind, name, m))
            elif full:
                if kind == 'clutch':
                    torque, cap = ev.stuck_torque[name], cs
                elif kind == 'brake':
                    torque, cap = ev.hold[name], bs[name]
                else:
                    torque, cap = ev.pack_stuck[name], ev.pack_static[name]
                if decide_mode(0.0, torque, cap) != STUCK:
                    bad.append(name)
        if moving:
            ev_h = self._eval(mt, t, x + self._H_DIRECTION * ev.ydot)
            for kind, name, m in moving:
                s = {'clutch': ev_h.slip, 'brake': ev_h.wheel_speed, 'pack': ev_h.pack_slip}[kind]
                if s[name] * m < 0.0:
                    bad.append(name)
        return bad

    def _joint(self, t: float, mode: Mode, st: TreeState, fresh: tuple[str, ...]
               ) -> tuple[Mode, TreeState]:
        """The one-at-a-time settle ended inconsistent (or used up its rounds): choose the
        modes of the elements deciding at t (_at_zero) together. Of their 3**n stick / slip+
        / slip- combinations (an element in ``fresh``, not stuck, only slips) the consistent
        ones (_violations) are ranked by the most elements kept as the one-at-a-time result
        had them, then the most stuck (stuck wherever static friction can hold: maximal
        sticking, a common choice among the several solutions a complementarity formulation
        of stick-slip friction can have), then the first in scene order (clutches, brakes,
        packs; each stuck, slip+, slip-). None consistent, or more than
        JOINT_MAX elements: the one-at-a-time result stands, with a status line; so does a
        consistent one (rounds used up)."""
        if not self._violations(t, mode, st):
            return mode, st
        mt, x, _st = self._apply(mode, st, False)
        ev = self._eval(mt, t, x)
        deciding = self._at_zero(t, mode, ev)
        if len(deciding) > self.JOINT_MAX:
            self._status(t, f'{len(deciding)} friction elements decide at once (at most '
                            f'{self.JOINT_MAX} are chosen together): '
                            f'{", ".join(self._violations(t, mode, st))} left inconsistent')
            return mode, st
        have = [self._modes_of(mode, k)[n] for k, n in deciding]
        choices = [(FORWARD, BACKWARD) if n in fresh and m != STUCK else (STUCK, FORWARD, BACKWARD)
                   for (_k, n), m in zip(deciding, have)]
        base = self.tree(mode)
        best: tuple[tuple[int, int], Mode, TreeState] | None = None
        for combo in itertools.product(*choices):
            cand = mode.copy()
            for (kind, name), m_old, m in zip(deciding, have, combo):
                self._modes_of(cand, kind)[name] = m
                if kind == 'clutch':
                    i = self.probe.clutch_link[name]
                    cand.offsets.pop(i, None)
                    if m == STUCK:
                        cand.offsets[i] = (mode.offsets[i] if m_old == STUCK
                                           else base.lock_offset(i, st, 1.0))
                elif kind == 'pack':
                    d = self.probe.packs[name][1]
                    cand.offsets.pop(-(d + 1), None)
                    if m == STUCK:
                        cand.offsets[-(d + 1)] = (mode.offsets[-(d + 1)] if m_old == STUCK
                                                  else st.delta[d])
            _mt, _x, st2 = self._apply(cand, st, True)
            if self._violations(t, cand, st2):
                continue
            score = (sum(a == b for a, b in zip(combo, have)), sum(m == STUCK for m in combo))
            if best is None or score > best[0]:
                best = (score, cand, st2)
        if best is None:
            self._status(t, f'no consistent mode of {", ".join(n for _k, n in deciding)}: '
                            f'{", ".join(self._violations(t, mode, st))} left inconsistent')
            return mode, st
        _score, cand, st2 = best
        self._mark(t, mode)
        for (kind, name), m_old in zip(deciding, have):
            m = self._modes_of(cand, kind)[name]
            if m == m_old:
                continue
            if m_old == STUCK:
                if not same_instant(t, self._released[0]):
                    self._released = (t, set())
                self._released[1].add(name)
            self._log(t, name, mode_name(m_old), mode_name(m), 'modes chosen together')
        return cand, st2

    def _shift(self, t: float, mode: Mode, st: TreeState) -> tuple[Mode, TreeState]:
        """Apply the gear command at t: neutral always; a gear only with no clutch stuck and
        |i omega_out| within the gearbox's max input speed (else a status, not retried
        until the command changes); engaged through a plastic lock (ideal synchroniser)."""
        for name, gb in self.gearboxes.items():
            want = self.schedule.gear(t)
            have = mode.gear[name]
            if want == self._gear_seen:
                continue
            self._gear_seen = want
            if want == have:
                continue
            if not gb.valid_gear(want):
                self._status(t, f'gear {want} refused: {name} has gears -1, 0, 1..{len(gb.ratios)}')
                continue
            idx = self.probe.gearbox_link[name]
            if want != 0:
                omega_out = st.qd[self.probe.links[idx].right]
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
            out.offsets.pop(idx, None)
            if want != 0:
                out.offsets[idx] = self.tree(mode).lock_offset(idx, st, 1.0 / gb.ratio(want))
            _mt, _x, st = self._apply(out, st, want != 0)
            self._log(t, name, f'gear {have}', f'gear {want}', 'command')
            mode = out
        return mode, st

    # --- start -----------------------------------------------------------------------------

    def _fill(self, mt: ModeTree, w_engine: float, w_cut: float) -> FloatArray:
        """Mode state with the engine at w_engine (rad/s), every section behind an unlocked
        link starting at w_cut, springs at their initial twist with zero rate."""
        sc = self.scene
        n = mt.n_dof
        twist0 = {el.name: el.initial_twist for el in iter_elements(sc.driveline)
                  if isinstance(el, Spring)}
        x = np.zeros(mt._n_state)
        c0 = mt.sections[0].coord
        x[c0], x[n + c0] = sc.initial_angle, w_engine
        feed = {right: ('spring', left, law) for law, left, right in mt.springs}
        for lk in mt.links:
            if not lk.locked:
                feed[lk.right] = ('link', lk.left, lk)
        for s, sec in enumerate(mt.sections):
            if s == 0 or sec.coord < 0:
                continue
            kin = mt._kinematics(x)
            kind, left, obj = feed[s]
            if kind == 'spring':
                x[sec.coord] = kin.ends[left][0] - twist0[obj.name]
                x[n + sec.coord] = kin.ends[left][1] * kin.qd[left]
            else:
                x[sec.coord] = mt.input_end(kin, obj)[0]
                x[n + sec.coord] = w_cut
        return x

    def _initial(self) -> tuple[Mode, ModeTree, FloatArray]:
        sc = self.scene
        self._seen, self._released = (-math.inf, set()), (-math.inf, set())
        gear0 = self.schedule.gear(0.0)
        for name, gb in self.gearboxes.items():
            if not gb.valid_gear(gear0):
                raise SceneError('commands', f'gear {gear0} at t=0 is not a gear of {name}')
        pedal0 = self.schedule.value('clutch', 0.0) if self.clutches else 1.0
        mode = Mode(clutch={c: (STUCK if pedal0 < 1.0 else FORWARD) for c in self.clutches},
                    gear={g: gear0 for g in self.gearboxes},
                    brakes={b: FORWARD for b in self.brake_els}, packs={p: FORWARD for p in self.packs})
        for name, i in self.probe.clutch_link.items():
            if mode.clutch[name] == STUCK:
                mode.offsets[i] = 0.0
        for name, i in self.probe.gearbox_link.items():
            if mode.gear[name] != 0:
                mode.offsets[i] = 0.0
        mt = self.tree(mode)
        r = mt.wheels[0].tyre.radius
        x = self._fill(mt, sc.initial_speed, 0.0)
        v_spec = sc.vehicle.initial_speed
        if v_spec is not None:
            cut = self._fill(mt, 0.0, 1.0) - self._fill(mt, 0.0, 0.0)
            w_cut = mt.first_wheel_speed(cut)
            if w_cut != 0.0:
                x = x + cut * ((v_spec / r - mt.first_wheel_speed(x)) / w_cut)
            else:
                w_unit = mt.first_wheel_speed(self._fill(mt, 1.0, 0.0))
                if w_unit == 0.0:
                    raise SceneError('vehicle.initial_speed_m_s', 'the first wheel does not turn '
                                                                  'with the engine (check the ratios)')
                x = self._fill(mt, v_spec / r / w_unit, 0.0)
            v0 = v_spec
        else:
            v0 = mt.first_wheel_speed(x) * r
        n = mt.n_dof
        x[mt._iv] = v0
        if v0 == 0.0:
            kin = mt._kinematics(x)
            if all(kin.qd[w.section] == 0.0 for w in mt.wheels):
                x[2 * n:2 * n + mt.n_wheel] = mt.equilibrium_slip()
        return mode, mt, x

    # --- the run ---------------------------------------------------------------------------

    def run(self) -> HybridResult:
        self._t_now = 0.0
        mode, mt, x = self._initial()
        st = mt.to_state(x, 0.0)
        om = mt.evaluate(0.0, x, self.engine, 0.0, {b: 0.0 for b in self.brake_els},
                         torques=False).wheel_speed
        for name in self.brake_els:
            mode.brakes[name] = BACKWARD if om[name] < 0 else FORWARD   # equal: settle may stick
        mode, st = self._settle(0.0, mode, st)
        mt = self.tree(mode)
        x0, _l = mt.from_state(st, False)
        e0 = mt.energy_total(x0)
        names = self.shaft_names
        times = np.arange(0.0, self.duration + 0.5 * self.sample_dt, self.sample_dt)
        times = times[times <= self.duration + 1e-12]
        speed = np.full((times.size, len(names)), np.nan)
        resid = np.full(times.size, np.nan)
        gears = np.zeros(times.size, dtype=int)
        vel = np.full(times.size, np.nan)
        gb_name = next(iter(self.gearboxes), None)
        k_sample = 0
        stats = {'steps': 0, 'nfev': 0, 'events': 0, 'restarts': 0}
        stall: str | None = None

        js = self._joint_arrays(times.size, len(names)) if self.joint_samples else None

        def record(m: ModeTree, xx: FloatArray, lock_loss: float, md: Mode, i: int) -> None:
            speed[i] = m.shaft_speeds(xx)
            tot = m.energy_total(xx)
            we, wd, ws, wr, wf = m.works(xx)
            scale = max(abs(tot), abs(e0), abs(we), abs(wd), abs(ws), abs(wr), abs(wf),
                        abs(lock_loss), 1e-12)
            resid[i] = (tot - e0 - we + wd + ws + wr + wf + lock_loss) / scale
            gears[i] = md.gear[gb_name] if gb_name else 0
            vel[i] = m.vehicle_speed(xx)
            if js is not None:
                p_, _v, e_, te_ = self.joint_state(m, float(times[i]), xx)
                js[0][i], js[1][i], js[2][i] = p_, e_, te_

        t = 0.0
        mode, st = self._shift(0.0, mode, st)
        while t < self.duration and stall is None:
            self._t_now = t
            self._t_end = math.inf
            t_stop = min(self.schedule.next_breakpoint(t), self.duration)
            if t_stop - t <= 1e-12 * max(1.0, abs(t)):
                t = t_stop
                if t < self.duration:
                    mode, st = self._shift(t, mode, st)
                    mode, st = self._settle(t, mode, st)
                continue
            mt = self.tree(mode)
            y0, _loss = mt.from_state(st, False)
            fun = lambda tt, yy, mt=mt: self._eval(mt, tt, yy, False).ydot  # noqa: E731
            jac = None
            if self.method in ROSENBROCK_METHODS:
                jac = lambda tt, yy, mt=mt: self._jac(mt, tt, yy)  # noqa: E731
            self._t_end = t_stop      # a jump at t_stop is seen from the left until it
            stepper = make_stepper(self.method, fun, t, y0, rtol=self.rtol, atol=self.atol,
                                   max_step=self.max_step, jac=jac)
            if hasattr(stepper, 'ft_window'):
                stepper.ft_window = (t, t_stop)     # commands jump only at segment ends
            stats['restarts'] += 1
            ws = self._witnesses(mode)
            need_t = any(w.key[0] == 'clutch' and w.key[2] != STUCK for w in ws)
            ev0 = self._eval(mt, t, y0, need_t)
            g_old = [self._g(w, ev0, t, mode) for w in ws]
            late = [w for w, g in zip(ws, g_old) if w.key[0] == 'shift' and g * w.direction >= 0.0]
            if late:
                # the clutch has just locked (or a shift ended) with the synchronous speed
                # already past a shift speed: the shift starts now
                _k, name, target = late[0].key
                g = mode.gear[name]
                self.auto.start(t, target)
                stats['events'] += 1
                self._log(t, name, f'gear {g}', f'shift to {target}',
                          'up-shift speed' if target > g else 'down-shift speed')
                continue
            if self.stall_speed is not None and ev0.engine_speed < self.stall_speed:
                stall = (f'engine stalled at t={t:.6f} s: {ev0.engine_speed:.2f} rad/s below the '
                         f'stall speed {self.stall_speed:.2f} rad/s')
                break
            while True:
                t_old = stepper.t
                stepper.step(t_stop)
                stats['steps'] += 1
                y_new = stepper.y
                ev = self._eval(mt, stepper.t, y_new, need_t)
                g_new = [self._g(w, ev, stepper.t, mode) for w in ws]
                hits = []
                for i, w in enumerate(ws):
                    if crossed(w.direction, g_old[i], g_new[i]):
                        def g_of(tau: float, w: Witness = w) -> float:
                            yy = stepper.dense(tau)
                            return self._g(w, self._eval(mt, tau, yy, need_t), tau, mode)
                        hits.append((locate(g_of, t_old, stepper.t, g_new[i]), i))
                t_end = min(hits)[0] if hits else stepper.t
                while k_sample < times.size and times[k_sample] <= t_end:
                    ts_ = float(times[k_sample])
                    yy = stepper.y if ts_ == stepper.t else stepper.dense(max(ts_, t_old))
                    record(mt, yy, st.lock_loss, mode, k_sample)
                    k_sample += 1
                if hits:
                    t_ev, i = min(hits)
                    y_ev = stepper.y if t_ev == stepper.t else stepper.dense(t_ev)
                    self._t_end = math.inf
                    st = mt.to_state(y_ev, st.lock_loss)
                    t = t_ev
                    self._t_now = t
                    stats['events'] += 1
                    kind, name, target = ws[i].key
                    if kind == 'stall':
                        stall = (f'engine stalled at t={t:.6f} s: speed fell below the stall '
                                 f'speed {self.stall_speed:.2f} rad/s '
                                 f'({self.stall_speed * 30 / math.pi:.0f} rpm)')
                        break
                    if kind == 'shift':
                        g = mode.gear[name]
                        self.auto.start(t, target)
                        self._log(t, name, f'gear {g}', f'shift to {target}',
                                  'up-shift speed' if target > g else 'down-shift speed')
                        break
                    if target == STUCK:
                        mode, st = self._try_stick(t, mode, st, kind, name,
                                                   'zero speed' if kind == 'brake' else 'zero slip')
                    else:
                        mode = self._release(t, mode, kind, name, target, 'torque above static capacity')
                    mode, st = self._settle(t, mode, st, (name,))
                    if t >= t_stop and t < self.duration:
                        mode, st = self._shift(t, mode, st)
                        mode, st = self._settle(t, mode, st, (name,))
                    break
                g_old = g_new
                if stepper.t >= t_stop:
                    self._t_end = math.inf
                    t = t_stop
                    st = mt.to_state(stepper.y, st.lock_loss)
                    if t < self.duration:
                        self._t_now = t
                        mode, st = self._shift(t, mode, st)
                        mode, st = self._settle(t, mode, st)
                    break
            stats['nfev'] += stepper.nfev
        self._t_end = math.inf
        if stall is not None:
            self.statuses.append(stall)
        keep = k_sample
        res = HybridResult(times[:keep], list(names), speed[:keep], resid[:keep], gears[:keep],
                           list(self.events), list(self.statuses), stall, st, mode, t, stats)
        res.vehicle_speed = vel[:keep]          # type: ignore[attr-defined]
        if js is not None:
            res.position, res.effort, res.engine_torque = (a[:keep] for a in js)
        return res
