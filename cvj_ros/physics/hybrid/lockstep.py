"""A chain with clutch, gearbox and brake stepped per exchange interval (the lockstep loop).

The coupling node integrates the driveline from t_k to t_(k+1) with the engine and load
torques received for t_k held constant (zero-order hold, as :class:`~cvj_ros.physics.cosim.
CoupledStepper`) and the commands (clutch pedal, brake, gear) in force at t_k held over the
interval. Inside the interval the model is the Python reference's
(:class:`~cvj_ros.physics.hybrid.simulate.HybridSimulation`): stick and slip transitions are
located on the stepper's dense output, a changed gear command goes through neutral and a
momentum-conserving lock, a pedal snapped open releases a stuck clutch at t_k. Commands set
with :meth:`HybridLockstep.set_commands` act from the next :meth:`HybridLockstep.advance` on.

``hybrid_lockstep(scene, backend=...)`` is the one entry point the nodes use: this
reference, or each interval on the compiled kernel
(:mod:`cvj_ros.physics.kernel.modes_lockstep`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from cvj_ros.errors import CvjError
from cvj_ros.physics.hybrid.events import Witness, crossed, locate
from cvj_ros.physics.hybrid.friction import STUCK, mode_name
from cvj_ros.physics.hybrid.simulate import ROSENBROCK_METHODS, HybridSimulation
from cvj_ros.physics.sections import section_kinematics
from cvj_ros.physics.solvers import make_stepper

if TYPE_CHECKING:
    from collections.abc import Mapping

    from cvj_ros.physics.hybrid.chain import HybridChain, SectionState
    from cvj_ros.physics.scene import Scene

__all__ = ['BACKENDS', 'Commands', 'HeldCommands', 'HeldTorque', 'HybridLockstep', 'hybrid_lockstep']

FloatArray = NDArray[np.float64]


@dataclass
class Commands:
    """Commands held over an exchange interval: clutch pedal (0 engaged .. 1 open), brake
    (0..1 of capacity), gear (-1 reverse, 0 neutral, 1..N)."""

    clutch: float = 0.0
    brake: float = 0.0
    gear: int = 0


class HeldCommands:
    """The schedule interface of :class:`HybridSimulation` over held :class:`Commands`: every
    channel is constant until :meth:`HybridLockstep.set_commands` changes it."""

    def __init__(self, commands: Commands) -> None:
        self.now = commands

    def has(self, channel: str) -> bool:
        return channel != 'throttle'       # the engine node applies the throttle

    def value(self, channel: str, t: float, t_end: float = math.inf) -> float:
        return float(getattr(self.now, channel))

    def gear(self, t: float) -> int:
        return int(self.now.gear)

    def next_breakpoint(self, t: float) -> float:
        return math.inf


class HeldTorque:
    """A torque received from a peer, held over the interval (N m); ``torque(t, omega, phi)``
    as the engine and load models, ``set_throttle`` ignored (the engine node owns it)."""

    def __init__(self, value: float = 0.0) -> None:
        self.value = value

    def torque(self, t: float, omega: float, phi: float) -> float:
        return self.value

    def slope(self, t: float, omega: float, phi: float = 0.0) -> float:
        """dT/domega = 0 (held)."""
        return 0.0

    def set_throttle(self, x: float) -> None:
        return None


class HybridLockstep(HybridSimulation):
    """Stepper of a :class:`HybridChain` between exchanges; see the module docstring.

    Args: as :class:`HybridSimulation` without ``engine``, ``load``, ``schedule`` and
    ``duration``; ``commands``: the commands at t = 0.
    """

    backend = 'python'     # the compiled twin: cvj_ros.physics.kernel.modes_lockstep

    def __init__(self, chain: HybridChain, *, commands: Commands, initial_speed: float = 0.0,
                 initial_speeds: Mapping[str, float] | None = None,
                 stall_speed: float | None = None, method: str = 'dopri5', rtol: float = 1e-8,
                 atol: float = 1e-10, max_step: float = math.inf) -> None:
        self.commands = HeldCommands(Commands(commands.clutch, commands.brake, int(commands.gear)))
        super().__init__(chain, engine=HeldTorque(), load=HeldTorque(), schedule=self.commands,
                         duration=math.inf, initial_speed=initial_speed,
                         initial_speeds=initial_speeds, stall_speed=stall_speed, method=method,
                         rtol=rtol, atol=atol, max_step=max_step)
        self.t = 0.0
        self.stall: str | None = None
        self.stats = {'steps': 0, 'nfev': 0, 'events': 0, 'restarts': 0}
        self.mode, self.st = self._initial()
        self.st.lock_loss = 0.0
        self.mode, self.st = self._shift(0.0, self.mode, self.st)
        self._changed = False
        self._h: float | None = None      # last accepted step: the next interval's first step
        kin, el = chain.energy(self.st)
        self.energy0 = kin + el
        self.shaft_names = list(chain.shafts)

    # --- inputs ------------------------------------------------------------------------

    def set_commands(self, clutch: float | None = None, brake: float | None = None,
                     gear: int | None = None) -> None:
        """Commands in force from the next interval on (None keeps a channel)."""
        now = self.commands.now
        new = Commands(now.clutch if clutch is None else float(clutch),
                       now.brake if brake is None else float(brake),
                       now.gear if gear is None else int(gear))
        if new != now:
            self.commands.now = new
            self._changed = True

    # --- stepping ----------------------------------------------------------------------

    def _begin(self, t_next: float, T_engine: float, T_load: float
               ) -> tuple[Any, SectionState, float] | None:
        """The start of :meth:`advance`: checks the torques (N m) and ``t_next`` (s), holds the
        torques, applies a command change (shift, then settle); None after a stall, else
        (mode, sections, t) to integrate from."""
        if not (math.isfinite(T_engine) and math.isfinite(T_load)):
            raise CvjError(f'non-finite torque (engine {T_engine}, load {T_load})')
        if t_next <= self.t:
            raise CvjError(f'cannot advance from t={self.t} s to t={t_next} s')
        if self.stall is not None:
            return None
        self.engine.value = float(T_engine)
        self.load.value = float(T_load)
        mode, st, t = self.mode, self.st, self.t
        if self._changed:
            mode, st = self._shift(t, mode, st)
            mode, st = self._settle(t, mode, st)
            self._changed = False
        return mode, st, t

    def advance(self, t_next: float, T_engine: float, T_load: float) -> SectionState:
        """Integrate t -> ``t_next`` (s) with the torques (N m) and commands held; stops early
        at a stall (``self.stall`` holds its line). Returns the section state at the end."""
        begun = self._begin(t_next, T_engine, T_load)
        if begun is None:
            return self.st
        mode, st, t = begun
        ch = self.chain
        while t < t_next and self.stall is None:
            if t_next - t <= 1e-12 * max(1.0, abs(t)):
                t = t_next
                break
            asm = ch.assemble(mode)
            y0, _loss = ch.to_mode(asm, st)
            n = len(asm.groups)
            fun = lambda tt, yy, asm=asm, mode=mode: self._eval(asm, mode, tt, yy).ydot  # noqa: E731
            h0 = min(self._h, t_next - t) if self._h else None
            jac = None
            if self.method in ROSENBROCK_METHODS:
                jac = lambda tt, yy, asm=asm, mode=mode: self._jac(asm, mode, tt, yy)  # noqa: E731
            stepper = make_stepper(self.method, fun, t, y0, rtol=self.rtol, atol=self.atol,
                                   h=h0, max_step=self.max_step, jac=jac)
            if jac is not None:
                stepper.ft_window = (t, t_next)     # commands change only between intervals
            self.stats['restarts'] += 1
            ws = self._witnesses(asm, mode)
            ev0 = self._eval(asm, mode, t, y0)
            g_old = [self._g(w, ev0, t, y0, n) for w in ws]
            if self.stall_speed is not None and float(y0[n]) < self.stall_speed:
                self.stall = (f'engine stalled at t={t:.6f} s: {float(y0[n]):.2f} rad/s below '
                              f'the stall speed {self.stall_speed:.2f} rad/s')
                break
            while True:
                t_old = stepper.t
                stepper.step(t_next)
                self.stats['steps'] += 1
                if stepper.t - t_old < t_next - t:
                    self._h = stepper.t - t_old
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
                if hits:
                    t_ev, i = min(hits)
                    y_ev = stepper.y if t_ev == stepper.t else stepper.dense(t_ev)
                    st = ch.to_sections(asm, y_ev, st)
                    t = t_ev
                    self.stats['events'] += 1
                    kind, name, target = ws[i].key
                    if kind == 'stall':
                        self.stall = (f'engine stalled at t={t:.6f} s: speed fell below the stall '
                                      f'speed {self.stall_speed:.2f} rad/s '
                                      f'({self.stall_speed * 30 / math.pi:.0f} rpm)')
                        break
                    if target == STUCK:
                        mode, st = self._try_stick(t, mode, st, kind, name, 'zero slip')
                    else:
                        mode = self._release(t, mode, kind, name, target,
                                             'torque above static capacity')
                    mode, st = self._settle(t, mode, st, (name,))
                    break
                g_old = g_new
                if stepper.t >= t_next:
                    t = t_next
                    st = ch.to_sections(asm, stepper.y, st)
                    break
            self.stats['nfev'] += stepper.nfev
        if self.stall is not None and self.stall not in self.statuses:
            self.statuses.append(self.stall)
        self.mode, self.st, self.t = mode, st, t
        return st

    # --- outputs -----------------------------------------------------------------------

    def mode_names(self) -> dict[str, str]:
        """Element -> its mode now: clutch and brake 'slip+' / 'stuck' / 'slip-', gearbox
        'gear <n>'."""
        out = {c: mode_name(m) for c, m in self.mode.clutch.items()}
        out.update({g: f'gear {v}' for g, v in self.mode.gear.items()})
        if self.chain.brake is not None and self.mode.brake is not None:
            out[self.chain.brake.name] = mode_name(self.mode.brake)
        return out

    def gear(self) -> int:
        """The engaged gear (0 without a gearbox)."""
        return next(iter(self.mode.gear.values()), 0)

    def energy_residual(self) -> float:
        """(E_kin + E_el - E0 - W_engine + W_load + W_damp + W_friction + W_lock) / scale."""
        kin, el = self.chain.energy(self.st)
        we, wl, wd, wf = (float(x) for x in self.st.work)
        scale = max(abs(kin + el), abs(self.energy0), abs(we), abs(wl), abs(wd), abs(wf),
                    abs(self.st.lock_loss), 1e-12)
        return (kin + el - self.energy0 - we + wl + wd + wf + self.st.lock_loss) / scale

    def joint_states(self) -> tuple[FloatArray, FloatArray, FloatArray]:
        """(position rad, velocity rad/s, effort N m) per name of :attr:`shaft_names` now, with
        the held engine torque (:meth:`HybridSimulation.joint_state`)."""
        return self.joint_state(self.mode, self.st, self.t)[:3]


BACKENDS = ('auto', 'kernel', 'python')


def hybrid_lockstep(scene: Scene, *, method: str | None = None, rtol: float | None = None,
                    atol: float | None = None, fidelity: Mapping[str, str] | None = None,
                    backend: str = 'python') -> Any:
    """The scene's chain (a HybridLockstep) or vehicle tree (a HybridTreeLockstep) stepped
    per exchange, its commands at t = 0 in force (the scene's ``commands:`` schedule at 0,
    else pedal 0, brake 0, neutral). The backend behind the coupling node for scenes with
    clutch, gearbox, brake or commands. ``backend``: ``'python'`` this reference,
    ``'kernel'`` each interval on the compiled kernel
    (:class:`~cvj_ros.physics.kernel.modes_lockstep.KernelHybridLockstep`, a vehicle
    :class:`~cvj_ros.physics.kernel.tree_modes_lockstep.KernelHybridTreeLockstep`; dopri5,
    dop853, rodas3, rodas4, rosenbrock, tsit5, vern6; CvjError otherwise), ``'auto'`` the kernel where it covers the scene and
    method and numba is installed, else the reference (``backend_fallback`` says why)."""
    if backend not in BACKENDS:
        raise CvjError(f'backend: must be one of {", ".join(BACKENDS)}, got {backend!r}')
    from cvj_ros.physics.hybrid.from_scene import hybrid_simulation
    sim = hybrid_simulation(scene, method=method, rtol=rtol, atol=atol, fidelity=fidelity)
    s = getattr(sim.schedule, 'base', sim.schedule)      # under a shift schedule: the commands
    c0 = Commands(s.value('clutch', 0.0), s.value('brake', 0.0), s.gear(0.0))
    if getattr(scene, 'is_tree', False):     # a vehicle: cvj_ros.physics.hybrid.tree_lockstep
        from cvj_ros.physics.hybrid.tree_lockstep import HybridTreeLockstep
        tcls: Any = HybridTreeLockstep
        tfall = None
        if backend != 'python':
            import importlib.util
            if importlib.util.find_spec('numba') is None:
                tfall = 'compiled kernel: numba is not installed'
            else:
                from cvj_ros.physics.kernel.tree_modes_lockstep import KernelHybridTreeLockstep
                tcls = KernelHybridTreeLockstep
        kw = dict(commands=c0, shift=scene.shift_schedule, stall_speed=sim.stall_speed,
                  method=sim.method, rtol=sim.rtol, atol=sim.atol, max_step=sim.max_step)
        try:
            tree = tcls(scene, sim.levels, **kw)
        except NotImplementedError as exc:
            tfall = str(exc)
            tree = HybridTreeLockstep(scene, sim.levels, **kw)
        if tfall is not None and backend == 'kernel':
            raise CvjError(f'backend: {tfall}')
        tree.backend_fallback = tfall
        return tree
    cls: type[HybridLockstep] = HybridLockstep
    fallback = None
    if backend != 'python':
        import importlib.util

        from cvj_ros.physics.kernel.modes import KERNEL_MODE_METHODS
        if importlib.util.find_spec('numba') is None:
            fallback = 'compiled kernel: numba is not installed'
        elif sim.method not in KERNEL_MODE_METHODS:
            fallback = (f'compiled kernel: mode scenes run with {", ".join(KERNEL_MODE_METHODS)}, '
                        f'not {sim.method!r}')
        if fallback is None:
            from cvj_ros.physics.kernel.modes_lockstep import KernelHybridLockstep
            cls = KernelHybridLockstep
        elif backend == 'kernel':
            raise CvjError(f'backend: {fallback}')
    out = cls(sim.chain, commands=c0, initial_speed=sim.initial_speed,
              stall_speed=sim.stall_speed, method=sim.method, rtol=sim.rtol,
              atol=sim.atol, max_step=sim.max_step)
    out.backend_fallback = fallback
    return out
