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
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np

from cvj_ros.errors import CvjError
from cvj_ros.physics.hybrid.friction import STUCK
from cvj_ros.physics.hybrid.tree_lockstep import HybridTreeLockstep
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
        super().__init__(*args, **kwargs)
        if self.method not in KERNEL_TREE_MODE_METHODS:
            raise NotImplementedError(
                f'compiled kernel: vehicle mode scenes run with '
                f'{", ".join(KERNEL_TREE_MODE_METHODS)}, not {self.method!r}')
        self._stand_in = LinearEngine(m1=0.0, k1=0.0)
        self._stand_in.set_throttle(1.0)
        _base_tables(self.probe, self._stand_in)      # NotImplementedError when it does not pack
        self._arrays: dict[tuple, tuple[np.ndarray, np.ndarray, tuple[int, int, int]]] = {}

    def _arrays_of(self, mt: Any, mode: Any) -> tuple[np.ndarray, np.ndarray]:
        ws = tuple(w.key for w in self._witnesses(mode))
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

    def _run_segment(self, mt: Any, mode: Any, t: float, t_stop: float, y0: np.ndarray
                     ) -> tuple[np.ndarray, float, int]:
        ip, fp = self._arrays_of(mt, mode)
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
            y, t_end, ev_i = self._run_segment(mt, mode, t, t_stop, y0)
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
