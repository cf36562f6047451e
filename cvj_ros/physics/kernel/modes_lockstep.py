"""The lockstep mode model (:class:`~cvj_ros.physics.hybrid.lockstep.HybridLockstep`) with
each exchange interval's integration on the compiled kernel.

Per interval [t_k, t_(k+1)] the engine and load torques and the clutch and brake commands
are held; in the kernel's mode arrays (:meth:`KernelHybridSimulation.mode_arrays`) that is
a linear engine with throttle 1, m1 = T_engine, k1 = 0 (torque 1 T - 0 omega = T exactly),
a constant load without speed scale (T_load), and one-row ramps holding the clutch pedal and
the brake. :func:`segment_nb.mode_segment` integrates each mode segment up to its earliest
witness crossing (one compiled call); the discrete decisions at an event (stick, release,
shift, settle, stall) and the joint-state outputs stay the Python reference's, as in
:class:`KernelHybridSimulation`. A mode's arrays are built once and reused while the run
stays in (or returns to) it; only the four held inputs are written per interval. Each interval starts with the step size the previous one
ended with (the reference lockstep carries its step the same way).
"""
from __future__ import annotations

import math
from types import SimpleNamespace
from typing import Any

import numpy as np

from cvj_ros.physics.hybrid.friction import STUCK
from cvj_ros.physics.hybrid.lockstep import HybridLockstep
from cvj_ros.physics.kernel.modes import (MH_ENGINE_F, MH_LOAD_F, MH_RAMP_B, MH_RAMP_C,
                                          KernelHybridSimulation)

__all__ = ['KernelHybridLockstep']

_NO_SAMPLES = np.zeros(0)


def _mode_key(mode: Any) -> tuple:
    """A hashable key of a :class:`~cvj_ros.physics.hybrid.chain.Mode`'s content."""
    return (tuple(mode.clutch.items()), tuple(mode.gear.items()), mode.brake,
            tuple(mode.offsets.items()), tuple(mode.brakes.items()), tuple(mode.packs.items()))


class KernelHybridLockstep(HybridLockstep, KernelHybridSimulation):
    """:class:`HybridLockstep` whose :meth:`advance` integrates on the compiled kernel
    (modes.KERNEL_MODE_METHODS); same arguments. ``backend`` is ``'kernel'``."""

    backend = 'kernel'

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.carry_step = True
        self._h_carry = 0.0
        self._slots: tuple[int, int, int, int] = (0, 0, 0, 0)
        self._arrays: dict[tuple, tuple[np.ndarray, np.ndarray, int]] = {}
        self._assemblies: dict[tuple, Any] = {}     # chain.assemble per mode (a pure function)

    def _build_base(self) -> None:
        """The shared arrays with stand-ins for the held inputs (module docstring); notes
        the fp slots of T_engine, T_load, the clutch pedal and the brake."""
        from cvj_ros.physics.engine import LinearEngine
        from cvj_ros.physics.load import ConstantLoad
        held = (self.engine, self.load, self.schedule, self._throttle)
        one = SimpleNamespace(times=[0.0], values=[0.0])
        self.engine = LinearEngine(m1=0.0, k1=0.0)
        self.engine.set_throttle(1.0)
        self.load = ConstantLoad(torque=0.0)
        self.schedule = SimpleNamespace(channels={'throttle': SimpleNamespace(times=[], values=[]),
                                                  'clutch': one, 'brake': one})
        self._throttle = False
        try:
            super()._build_base()
        finally:
            self.engine, self.load, self.schedule, self._throttle = held
        head = self._base[3]
        self._slots = (head[MH_ENGINE_F] + 1, head[MH_LOAD_F], head[MH_RAMP_C] + 2,
                       head[MH_RAMP_B] + 2)

    def mode_arrays(self, asm: Any, mode: Any) -> tuple[np.ndarray, np.ndarray, int]:
        """:meth:`KernelHybridSimulation.mode_arrays`, built once per mode (the arrays depend
        on the mode alone: a run revisits few) with the held inputs written in each call."""
        hit = self._arrays.get(_mode_key(mode))
        if hit is None:
            if len(self._arrays) >= 64:      # offsets differ per lock: keep the cache small
                self._arrays.clear()
            hit = self._arrays[_mode_key(mode)] = super().mode_arrays(asm, mode)
        fp = hit[1]
        e, l_, c, b = self._slots
        now = self.commands.now
        fp[e], fp[l_], fp[c], fp[b] = (self.engine.value, self.load.value, float(now.clutch),
                                       float(now.brake))
        return hit

    def advance(self, t_next: float, T_engine: float, T_load: float) -> Any:
        """As :meth:`HybridLockstep.advance`, each mode segment one compiled call."""
        begun = self._begin(t_next, T_engine, T_load)
        if begun is None:
            return self.st
        mode, st, t = begun
        ch = self.chain
        while t < t_next and self.stall is None:
            if t_next - t <= 1e-12 * max(1.0, abs(t)):
                t = t_next
                break
            key = _mode_key(mode)
            asm = self._assemblies.get(key)
            if asm is None:
                if len(self._assemblies) >= 64:
                    self._assemblies.clear()
                asm = self._assemblies[key] = ch.assemble(mode)
            y0, _loss = ch.to_mode(asm, st)
            n = len(asm.groups)
            self.stats['restarts'] += 1
            if self.stall_speed is not None and float(y0[n]) < self.stall_speed:
                self.stall = (f'engine stalled at t={t:.6f} s: {float(y0[n]):.2f} rad/s below '
                              f'the stall speed {self.stall_speed:.2f} rad/s')
                break
            y, t_end, ev_i, _k, _y = self._segment(asm, mode, t, t_next, y0, _NO_SAMPLES, 0)
            st = ch.to_sections(asm, y, st)
            if ev_i < 0:
                t = t_next
                break
            t = t_end
            self.stats['events'] += 1
            kind, name, target = self._witnesses(asm, mode)[ev_i].key
            if kind == 'stall':
                self.stall = (f'engine stalled at t={t:.6f} s: speed fell below the stall '
                              f'speed {self.stall_speed:.2f} rad/s '
                              f'({self.stall_speed * 30 / math.pi:.0f} rpm)')
                break
            if target == STUCK:
                mode, st = self._try_stick(t, mode, st, kind, name, 'zero slip')
            else:
                mode = self._release(t, mode, kind, name, target, 'torque above static capacity')
            mode, st = self._settle(t, mode, st, (name,))
        if self.stall is not None and self.stall not in self.statuses:
            self.statuses.append(self.stall)
        self.mode, self.st, self.t = mode, st, t
        return st
