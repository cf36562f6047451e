"""The vehicle lockstep mode model (:class:`~cvj_ros.physics.hybrid.tree_lockstep.
HybridTreeLockstep`) with each exchange interval's integration on the compiled kernel.

Per interval [t_k, t_(k+1)] the engine torque and the clutch and brake commands are held;
in the kernel's mode arrays (:func:`kernel.tree_modes.tree_mode_arrays`) that is a linear
engine with throttle 1, m1 = T_engine, k1 = 0 (torque 1 T - 0 omega = T exactly) and
one-row ramps holding the clutch pedal and the brake (a shift schedule's envelope on the
pedal is evaluated in the kernel). :func:`tree_modes_nb.tree_mode_segment` integrates
each mode segment up to its earliest witness crossing (one compiled call); the discrete
decisions (stick, release, the shift schedule's triggers, gear commands, settle, stall)
and the joint-state outputs stay the Python reference's. A mode's arrays are built once
per (mode, witnesses, shift sequence) and reused; only the three held inputs are written
per interval. Each interval starts with the step the previous one ended with, as the
reference lockstep.

The exchange's Python around the segments reuses what it computed (the same numbers as the
reference's path, bit for bit: test_tree_modes_lockstep.py): a ModeTree keeps its last
kinematics and walk (:mod:`cvj_ros.physics.hybrid.tree_reuse`), :meth:`_capacities` its
last capacities (keyed by t, the held commands, the shift sequence), :meth:`_eval` its
last evaluation and forces keyed by every input (mode tree, slip directions, t, state bytes,
held engine torque, capacities), so the joint state of t_(k+1) takes the settle's evaluation
at t_(k+1) when the commands did not change in between; mode states without a lock are made
by :func:`~cvj_ros.physics.kernel.tree_modes.mode_state` (no kinetic-energy evaluations).
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np

from cvj_ros.errors import CvjError
from cvj_ros.physics.hybrid.friction import STUCK
from cvj_ros.physics.hybrid.tree_lockstep import HybridTreeLockstep
from cvj_ros.physics.hybrid.tree_reuse import reuse_tree
from cvj_ros.physics.kernel import layout as L
from cvj_ros.physics.kernel.modes import KIND_TREE, run_segment
from cvj_ros.physics.kernel.tree_modes import (KERNEL_TREE_MODE_METHODS, MB_RAMP_B, MB_RAMP_C,
                                               _base_tables, _STATUS,
                                               mode_state, tree_mode_arrays)

__all__ = ['KernelHybridTreeLockstep']


def _mode_key(mode: Any) -> tuple:
    return (tuple(sorted(mode.clutch.items())), tuple(sorted(mode.gear.items())),
            tuple(sorted(mode.brakes.items())), tuple(sorted(mode.packs.items())),
            tuple(sorted(mode.offsets.items())))


class KernelHybridTreeLockstep(HybridTreeLockstep):
    """:class:`HybridTreeLockstep` whose :meth:`advance` integrates on the compiled kernel
    (tree_modes.KERNEL_TREE_MODE_METHODS); same arguments. NotImplementedError when the scene does not pack."""

    backend = 'kernel'

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        from cvj_ros.physics.engine import LinearEngine
        self._last_eval: tuple | None = None
        self._last_fo: Any = None
        self._last_caps: tuple | None = None
        self._last_tree: tuple | None = None
        super().__init__(*args, **kwargs)
        if self.method not in KERNEL_TREE_MODE_METHODS:
            raise NotImplementedError(
                f'compiled kernel: vehicle mode scenes run with '
                f'{", ".join(KERNEL_TREE_MODE_METHODS)}, not {self.method!r}')
        self._stand_in = LinearEngine(m1=0.0, k1=0.0)
        self._stand_in.set_throttle(1.0)
        _base_tables(self.probe, self._stand_in)      # NotImplementedError when it does not pack
        self._arrays: dict[tuple, tuple[np.ndarray, np.ndarray, tuple[int, int, int]]] = {}

    # --- reuse within an exchange (module docstring) -------------------------------------

    def tree(self, mode: Any) -> Any:
        """The reference's ModeTree of ``mode`` with its last kinematics and walk kept; a
        mode with the same contents as the last call's (its dicts item for item, in order:
        equal contents, so the reference's sorted key is equal too) takes the last tree
        without building that key."""
        snap = (tuple(mode.clutch.items()), tuple(mode.gear.items()), tuple(mode.brakes.items()),
                tuple(mode.packs.items()), tuple(mode.offsets.items()))
        last = self._last_tree
        if last is not None and last[0] == snap:
            mt = last[1]
            mt.mode = mode          # as the reference: the slip directions are read from it
            return mt
        mt = reuse_tree(super().tree(mode))
        self._last_tree = (snap, mt)
        return mt

    def _eval(self, mt: Any, t: float, x: np.ndarray, torques: bool = True) -> Any:
        """The reference's evaluation, the last one kept with its forces (``_last_fo``): keyed
        by the mode tree, its slip directions, t, x's bytes, the held engine torque and the
        capacities; a torques=True result also serves torques=False."""
        if self._throttle:
            self.engine.set_throttle(self.schedule.value('throttle', t))
        ck, _cs, bk, _bs = self._capacities(t)
        m = mt.mode
        key = (id(mt), tuple(m.clutch.items()), tuple(m.brakes.items()), tuple(m.packs.items()),
               t, float(self.engine.value), ck, tuple(bk.items()), x.tobytes())
        last = self._last_eval
        if last is not None and last[0] == key and (last[2] or not torques):
            return last[1]
        made: list[Any] = []
        forces = mt._forces

        def keep(*args: Any, **kw: Any) -> Any:
            made.append(forces(*args, **kw))
            return made[-1]

        mt._forces = keep
        try:
            ev = mt.evaluate(t, x, self.engine, ck, bk, torques=torques)
        finally:
            del mt._forces
        self._last_eval = (key, ev, torques, mt)       # mt held: its id stays unique
        self._last_fo = made[0]
        return ev

    def _capacities(self, t: float) -> tuple[float, float, dict[str, float], dict[str, float]]:
        """The reference's capacities, the last kept: keyed by t, the held commands and the
        shift sequence (AutoShift.value's inputs)."""
        now = self.commands.now
        key = (t, now.clutch, now.brake, now.gear, None if self.auto is None else self.auto.seq)
        last = self._last_caps
        if last is not None and last[0] == key:
            return last[1]
        caps = super()._capacities(t)
        self._last_caps = (key, caps)
        return caps

    def _apply(self, mode: Any, st: Any, fresh: bool) -> tuple[Any, np.ndarray, Any]:
        if fresh:
            return super()._apply(mode, st, fresh)
        mt = self.tree(mode)
        x = mode_state(mt, st)            # from_state(st, False)'s x; its loss is not used
        return mt, x, mt.to_state(x, st.lock_loss)

    def _now(self) -> tuple[Any, np.ndarray]:
        mt = self.tree(self.mode)
        return mt, mode_state(mt, self.st)

    def joint_states(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """As :meth:`HybridTreeLockstep.joint_states` (the same numbers), on the kept
        evaluation and walk when their inputs are unchanged."""
        mt, x = self._now()
        self._eval(mt, self.t, x, False)
        fo = self._last_fo
        pos, vel, eff, _start = mt._walk(x, fo.T_engine, kin=mt._kinematics(x), fo=fo)
        pos, vel = np.array(pos, dtype=float), np.array(vel, dtype=float)
        if mt._mid_index:
            self._fill_mid(mt, pos, vel)
        return pos, vel, np.array(eff, dtype=float)

    def _fill_mid(self, mt: Any, pos: np.ndarray, vel: np.ndarray) -> None:
        """``mt.fill_mid`` on one sample: the members with a compiled form by
        ``outputs_nb.fill_mid_one`` (the same formula and numbers), the rest in Python."""
        from cvj_ros.physics.kernel import entry_point_once
        from cvj_ros.physics.kernel import outputs_nb as O
        tab = mt.__dict__.get('_mid_tables')
        if tab is None:
            tab = mt._mid_tables = O.mid_table(mt)
        mtab, mfp, python = tab
        if len(mtab):
            entry_point_once(O.fill_mid_one, (pos, vel, mtab, mfp))(pos, vel, mtab, mfp)
        if python:
            mt.fill_mid(pos[None, :], vel[None, :], members=python)

    def _arrays_of(self, mt: Any, mode: Any, witnesses: list[Any]
                   ) -> tuple[np.ndarray, np.ndarray]:
        ws = tuple(w.key for w in witnesses)
        seq = self.auto.seq if self.auto is not None else None
        key = (_mode_key(mode), ws, seq)
        hit = self._arrays.get(key)
        if hit is None:
            if len(self._arrays) >= 64:
                self._arrays.clear()
            ip, fp = tree_mode_arrays(self, mt, mode, self._stand_in)
            mb = int(ip[-1])
            slots = (int(ip[L.H_ENGINE_F]) + 1, int(ip[mb + MB_RAMP_C]) + 2,
                     int(ip[mb + MB_RAMP_B]) + 2)
            hit = self._arrays[key] = (ip, fp, slots)
        ip, fp, (e, c, b) = hit
        now = self.commands.now
        fp[e], fp[c], fp[b] = float(self.engine.value), float(now.clutch), float(now.brake)
        return ip, fp

    def _run_segment(self, mt: Any, mode: Any, t: float, t_stop: float, y0: np.ndarray,
                     witnesses: list[Any]
                     ) -> tuple[np.ndarray, float, int]:
        ip, fp = self._arrays_of(mt, mode, witnesses)
        y = np.array(y0, dtype=np.float64)
        ns = y.size
        atol = np.full(ns, float(self.atol)) if np.ndim(self.atol) == 0 else \
            np.asarray(self.atol, dtype=np.float64)
        out_i = np.zeros(7, np.int64)
        out_f = np.zeros(3)
        h0 = min(self._h, t_stop - t) if self._h else 0.0
        run_segment(KIND_TREE, self.method, t, t_stop, y, ip, fp, self.rtol, atol,
                    self.max_step, h0, np.zeros(0), 0, np.zeros((0, ns)), np.zeros(0), out_i,
                    out_f)
        if out_i[0] != 0:
            raise CvjError(f'compiled kernel: integration failed near t={t:.6f} s: '
                           f'{_STATUS.get(int(out_i[0]), "status " + str(int(out_i[0])))}')
        self.stats['steps'] += int(out_i[3])
        self.stats['nfev'] += int(out_i[4])
        if out_i[3] > 0 and out_f[2] < t_stop - t:
            self._h = float(out_f[2])
        return y, float(out_f[0]), int(out_i[1])

    def advance(self, t_next: float, T_engine: float, T_load: float = 0.0) -> Any:
        """As :meth:`HybridTreeLockstep.advance`, each mode segment one compiled call."""
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
            y0 = mode_state(mt, st)
            stats['restarts'] += 1
            ws = self._witnesses(mode)
            shifts = [w for w in ws if w.key[0] == 'shift']
            if shifts:              # the reference's g at the start: the synchronous speed
                qd = mt._kinematics(y0).qd
                late = []
                for w in shifts:
                    _k, name, target = w.key
                    g = mode.gear[name]
                    lk = mt.links[mt.gearbox_link[name]]
                    lim = self.auto.schedule.up(g) if target > g else self.auto.schedule.down(g)
                    if (self.gearboxes[name].ratio(g) * qd[lk.right] - lim) * w.direction >= 0.0:
                        late.append(w)
                if late:
                    _k, name, target = late[0].key
                    g = mode.gear[name]
                    self.auto.start(t, target)
                    stats['events'] += 1
                    self._log(t, name, f'gear {g}', f'shift to {target}',
                              'up-shift speed' if target > g else 'down-shift speed')
                    continue
            w_e = float(y0[mt.n_dof + mt.sections[0].coord])
            if self.stall_speed is not None and w_e < self.stall_speed:
                self.stall = (f'engine stalled at t={t:.6f} s: {w_e:.2f} rad/s below '
                              f'the stall speed {self.stall_speed:.2f} rad/s')
                break
            y, t_end, ev_i = self._run_segment(mt, mode, t, t_stop, y0, ws)
            st = mt.to_state(y, st.lock_loss)
            if ev_i < 0:
                t = t_stop
                mode, st = self._at_breakpoint(t, mode, st)
                continue
            t = t_end
            self._t_now = t
            stats['events'] += 1
            kind, name, target = ws[ev_i].key
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
                continue
            if target == STUCK:
                mode, st = self._try_stick(t, mode, st, kind, name,
                                           'zero speed' if kind == 'brake' else 'zero slip')
            else:
                mode = self._release(t, mode, kind, name, target, 'torque above static capacity')
            mode, st = self._settle(t, mode, st, (name,))
            if t >= t_stop:
                mode, st = self._at_breakpoint(t, mode, st, (name,))
        if self.stall is not None and self.stall not in self.statuses:
            self.statuses.append(self.stall)
        self.mode, self.st, self.t = mode, st, t
        return st
