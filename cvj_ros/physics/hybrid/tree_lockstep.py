"""A vehicle tree with clutch, gearbox and wheel brakes stepped per exchange interval.

The lockstep face of :class:`~cvj_ros.physics.hybrid.tree_sim.HybridTreeSimulation` (the
vehicle mode model's Python reference), as :class:`~cvj_ros.physics.hybrid.lockstep.
HybridLockstep` is the chain's: the coupling node integrates t_k -> t_(k+1) with the engine
torque received for t_k held (zero-order hold) and the commands (clutch pedal, brake, gear)
in force at t_k held; the tyres and the vehicle body are inside the equations (the load
torque is not used). Inside the interval the reference's events run unchanged: stick and
slip of the clutch and of each wheel brake located on the dense output, the stall, and a
``shift_schedule:`` (AutoShift) whose witness, sequence breakpoints (neutral, new gear, clutch
closed) and pedal envelope act inside the model at their own times. The engine node owns the
throttle: the schedule's throttle cut during a shift (effective throttle x (1 - e)) is an output
of the stepper, :meth:`HybridTreeLockstep.throttle_scale` = 1 - e(t_k) at the interval's start
(:attr:`HybridTreeLockstep.cuts_throttle` says whether there is one), which the loop hands to
the engine (a torque intervention, docs/ros.md "Commands"); held over the interval as the
engine torque is.
"""
from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from cvj_ros.errors import CvjError
from cvj_ros.physics.hybrid.events import Witness, crossed, locate
from cvj_ros.physics.hybrid.friction import BACKWARD, FORWARD, STUCK, mode_name
from cvj_ros.physics.hybrid.lockstep import Commands, HeldCommands, HeldTorque
from cvj_ros.physics.hybrid.simulate import ROSENBROCK_METHODS
from cvj_ros.physics.hybrid.tree_sim import HybridTreeSimulation

if TYPE_CHECKING:
    from collections.abc import Mapping

    from cvj_ros.physics.hybrid.tree import ModeTree
    from cvj_ros.physics.scene import Scene

__all__ = ['HybridTreeLockstep']

FloatArray = NDArray[np.float64]


class HybridTreeLockstep(HybridTreeSimulation):
    """Stepper of a vehicle mode scene between exchanges; see the module docstring.

    Args: ``scene``, ``levels`` as :class:`HybridTreeSimulation`; ``commands``: the commands
    at t = 0; ``shift``: the scene's ShiftSchedule or None; stall_speed, method, rtol, atol,
    max_step: as the reference.
    """

    def __init__(self, scene: Scene, levels: Mapping[str, str], *, commands: Commands,
                 shift: Any = None, stall_speed: float | None = None, method: str = 'dopri5',
                 rtol: float = 1e-8, atol: float = 1e-10, max_step: float = math.inf) -> None:
        from cvj_ros.physics.hybrid.shift import AutoShift
        self.commands = HeldCommands(Commands(commands.clutch, commands.brake, int(commands.gear)))
        schedule: Any = self.commands if shift is None else AutoShift(self.commands, shift)
        super().__init__(scene, levels, engine=HeldTorque(), schedule=schedule,
                         duration=math.inf, stall_speed=stall_speed, method=method, rtol=rtol,
                         atol=atol, max_step=max_step)
        self._throttle = False            # the engine node applies the throttle
        self.t = 0.0
        self._t_now = 0.0
        self.stall: str | None = None
        self.stats = {'steps': 0, 'nfev': 0, 'events': 0, 'restarts': 0}
        mode, mt, x = self._initial()
        st = mt.to_state(x, 0.0)
        om = mt.evaluate(0.0, x, self.engine, 0.0, {b: 0.0 for b in self.brake_els},
                         torques=False).wheel_speed
        for name in self.brake_els:
            mode.brakes[name] = BACKWARD if om[name] < 0 else FORWARD   # equal: settle may stick
        mode, st = self._settle(0.0, mode, st)
        mt = self.tree(mode)
        x0, _l = mt.from_state(st, False)
        self.energy0 = mt.energy_total(x0)
        mode, st = self._shift(0.0, mode, st)
        self.mode, self.st = mode, st
        self._changed = False
        self._h: float | None = None      # last accepted step: the next interval's first step

    # --- inputs ------------------------------------------------------------------------

    def set_commands(self, clutch: float | None = None, brake: float | None = None,
                     gear: int | None = None) -> None:
        """Commands in force from the next interval on (None keeps a channel; with a shift
        schedule the gear is the schedule's: a gear command is refused with a status)."""
        now = self.commands.now
        if gear is not None and self.auto is not None and int(gear) != now.gear:
            self._status(self.t, f'gear {int(gear)} refused: the shift_schedule chooses the gear')
        new = Commands(now.clutch if clutch is None else float(clutch),
                       now.brake if brake is None else float(brake),
                       now.gear if gear is None else int(gear))
        if new != now:
            self.commands.now = new
            self._changed = True

    # --- stepping ----------------------------------------------------------------------

    def _at_breakpoint(self, t: float, mode: Any, st: Any, fresh: tuple[str, ...] = ()
                       ) -> tuple[Any, Any]:
        self._t_now = t
        mode, st = self._shift(t, mode, st)
        return self._settle(t, mode, st, fresh)

    def advance(self, t_next: float, T_engine: float, T_load: float = 0.0) -> Any:
        """Integrate t -> ``t_next`` (s) with the engine torque (N m) and the commands held
        (``T_load`` is checked, not used: the tyres carry the load); stops early at a stall
        (``self.stall`` holds its line). Returns the TreeState at the end."""
        if not (math.isfinite(T_engine) and math.isfinite(T_load)):
            raise CvjError(f'non-finite torque (engine {T_engine}, load {T_load})')
        if t_next <= self.t:
            raise CvjError(f'cannot advance from t={self.t} s to t={t_next} s')
        if self.stall is not None:
            return self.st
        self.engine.value = float(T_engine)
        mode, st, t = self.mode, self.st, self.t
        stats = self.stats
        if self._changed:
            mode, st = self._at_breakpoint(t, mode, st)
            self._changed = False
        while t < t_next and self.stall is None:
            self._t_now = t
            t_stop = min(self.schedule.next_breakpoint(t), t_next)
            if t_stop - t <= 1e-12 * max(1.0, abs(t)):
                t = t_stop
                mode, st = self._at_breakpoint(t, mode, st)
                continue
            mt = self.tree(mode)
            y0, _loss = mt.from_state(st, False)
            fun = lambda tt, yy, mt=mt: self._eval(mt, tt, yy, False).ydot  # noqa: E731
            h0 = min(self._h, t_stop - t) if self._h else None
            jac = None
            if self.method in ROSENBROCK_METHODS:
                jac = lambda tt, yy, mt=mt: self._jac(mt, tt, yy)  # noqa: E731
            stepper = self._stepper(fun, t, y0, h0, jac)
            if hasattr(stepper, 'ft_window'):
                stepper.ft_window = (t, t_stop)     # commands jump only at segment ends
            stats['restarts'] += 1
            ws = self._witnesses(mode)
            need_t = any(w.key[0] == 'clutch' and w.key[2] != STUCK for w in ws)
            ev0 = self._eval(mt, t, y0, need_t)
            g_old = [self._g(w, ev0, t, mode) for w in ws]
            late = [w for w, g in zip(ws, g_old) if w.key[0] == 'shift' and g * w.direction >= 0.0]
            if late:            # the clutch locked with the synchronous speed past a shift speed
                _k, name, target = late[0].key
                g = mode.gear[name]
                self.auto.start(t, target)
                stats['events'] += 1
                self._log(t, name, f'gear {g}', f'shift to {target}',
                          'up-shift speed' if target > g else 'down-shift speed')
                continue
            if self.stall_speed is not None and ev0.engine_speed < self.stall_speed:
                self.stall = (f'engine stalled at t={t:.6f} s: {ev0.engine_speed:.2f} rad/s below '
                              f'the stall speed {self.stall_speed:.2f} rad/s')
                break
            while True:
                t_old = stepper.t
                stepper.step(t_stop)
                stats['steps'] += 1
                if stepper.t - t_old < t_stop - t:
                    self._h = stepper.t - t_old
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
                if hits:
                    t_ev, i = min(hits)
                    y_ev = stepper.y if t_ev == stepper.t else stepper.dense(t_ev)
                    st = mt.to_state(y_ev, st.lock_loss)
                    t = t_ev
                    self._t_now = t
                    stats['events'] += 1
                    kind, name, target = ws[i].key
                    if kind == 'stall':
                        self.stall = (f'engine stalled at t={t:.6f} s: speed fell below the stall '
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
                        mode = self._release(t, mode, kind, name, target,
                                             'torque above static capacity')
                    mode, st = self._settle(t, mode, st, (name,))
                    if t >= t_stop:
                        mode, st = self._at_breakpoint(t, mode, st, (name,))
                    break
                g_old = g_new
                if stepper.t >= t_stop:
                    t = t_stop
                    st = mt.to_state(stepper.y, st.lock_loss)
                    mode, st = self._at_breakpoint(t, mode, st)
                    break
            stats['nfev'] += stepper.nfev
        if self.stall is not None and self.stall not in self.statuses:
            self.statuses.append(self.stall)
        self.mode, self.st, self.t = mode, st, t
        return st

    def _stepper(self, fun: Any, t: float, y0: FloatArray, h0: float | None,
                 jac: Any = None) -> Any:
        from cvj_ros.physics.solvers import make_stepper
        return make_stepper(self.method, fun, t, y0, rtol=self.rtol, atol=self.atol, h=h0,
                            max_step=self.max_step, jac=jac)

    # --- outputs -----------------------------------------------------------------------

    @property
    def cuts_throttle(self) -> bool:
        """A shift schedule runs: :meth:`throttle_scale` can fall below 1."""
        return self.auto is not None

    def throttle_scale(self) -> float:
        """Factor 1 - e(t) on the commanded throttle x at the current time t (e the shift
        sequence's envelope, :class:`~cvj_ros.physics.hybrid.shift.AutoShift`; 1.0 outside a
        shift and without a schedule): the engine answering t runs at x (1 - e(t)), the
        offline reference's throttle at t."""
        if self.auto is None:
            return 1.0
        return 1.0 - self.auto.envelope(self.t)

    def _now(self) -> tuple[ModeTree, FloatArray]:
        mt = self.tree(self.mode)
        x, _loss = mt.from_state(self.st, False)
        return mt, x

    @property
    def n_dof(self) -> int:
        """Degrees of freedom of the mode in force (rigid groups merged)."""
        return int(self.tree(self.mode).n_dof)

    def state_vector(self) -> FloatArray:
        """Mode-independent state: section angles and speeds, differential deltas and
        rates, the tail (relaxed slips, v, work integrals)."""
        st = self.st
        return np.concatenate([st.q, st.qd, st.delta, st.ddelta, st.tail]).astype(float)

    def energy_parts(self) -> dict[str, float]:
        """Kinetic (driveline and body) and elastic energy (J) now."""
        mt, x = self._now()
        e = mt.energy(x)
        return {'kinetic': float(e['kinetic']), 'elastic': float(e['elastic'])}

    def energy_residual(self) -> float:
        """(E_kin + E_el - E0 - W_engine + W_damp + W_slip + W_road + W_friction + W_lock)
        / scale, as the reference's record."""
        mt, x = self._now()
        tot = mt.energy_total(x)
        we, wd, ws, wr, wf = mt.works(x)
        ll = self.st.lock_loss
        scale = max(abs(tot), abs(self.energy0), abs(we), abs(wd), abs(ws), abs(wr), abs(wf),
                    abs(ll), 1e-12)
        return (tot - self.energy0 - we + wd + ws + wr + wf + ll) / scale

    def joint_states(self) -> tuple[FloatArray, FloatArray, FloatArray]:
        """(position rad, velocity rad/s, effort N m) per name of :attr:`shaft_names` (every
        shaft of every branch, intermediate members filled): the tree's backward walk
        (TreeDriveline.joint_states) on the forces of the mode in force (slipping clutch and
        brake torques, pinned wheels' holding torques) with the held engine torque."""
        mt, x = self._now()
        return self.joint_state(mt, self.t, x)[:3]

    def mode_names(self) -> dict[str, str]:
        """Element -> its mode now: clutch and brakes 'slip+' / 'stuck' / 'slip-', gearbox
        'gear <n>'."""
        out = {c: mode_name(m) for c, m in self.mode.clutch.items()}
        out.update({g: f'gear {v}' for g, v in self.mode.gear.items()})
        out.update({b: mode_name(m) for b, m in self.mode.brakes.items()})
        out.update({p: mode_name(m) for p, m in self.mode.packs.items()})
        return out

    def gear(self) -> int:
        """The engaged gear (0 without a gearbox)."""
        return next(iter(self.mode.gear.values()), 0)

    def gear_count(self) -> int | None:
        """Forward gears of the gearbox (None without one)."""
        boxes = list(self.gearboxes.values())
        return len(boxes[0].ratios) if boxes else None

    def mode_values(self) -> dict[str, Any]:
        """Loop-diagnostics values: each clutch's and brake's mode, the engaged gear, the shift
        in progress (with a shift schedule), mode events, refused commands, the stall line,
        and the vehicle values (speed, per wheel slip, F_x, F_z, tyre status)."""
        out: dict[str, Any] = {}
        names = self.mode_names()
        for name in self.clutches:
            out[f'clutch_state.{name}'] = names[name]
        for name in self.gearboxes:
            out[f'gear.{name}'] = self.mode.gear[name]
        for name in self.brake_els:
            out[f'brake_state.{name}'] = names[name]
        for name in self.packs:
            out[f'pack_state.{name}'] = names[name]
        if self.auto is not None:
            out['shifting'] = int(self.auto.busy(self.t))
        out['mode_events'] = len(self.events)
        refused = [s for s in self.statuses if 'refused' in s]
        out['refused_commands'] = len(refused)
        if refused:
            out['last_refused'] = refused[-1]
        out['stall'] = self.stall or ''
        mt, x = self._now()
        if np.all(np.isfinite(x)):
            out['vehicle_speed_m_s'] = float(mt.vehicle_speed(x))
            for name, w in mt.wheel_outputs(x).items():
                out[f'{name}.slip'] = float(w['slip'])
                out[f'{name}.fx_N'] = float(w['fx'])
                out[f'{name}.fz_N'] = float(w['fz'])
                out[f'{name}.status'] = int(w['status'])
        return out
