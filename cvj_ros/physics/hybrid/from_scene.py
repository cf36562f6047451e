"""A scene with mode elements or commands (``Scene.has_modes``) as a HybridSimulation, and the
summary `cvj-sim simulate` prints for it (events per element, status lines, energy)."""
from __future__ import annotations

import math
import time
from collections.abc import Mapping
from typing import Any

from cvj_ros.errors import SceneError
from cvj_ros.physics.hybrid.chain import HybridChain
from cvj_ros.physics.hybrid.commands import CommandSchedule
from cvj_ros.physics.hybrid.friction import mode_name
from cvj_ros.physics.hybrid.scene_keys import DENSE_METHODS
from cvj_ros.physics.hybrid.simulate import HybridResult, HybridSimulation
from cvj_ros.physics.scene import Joint, Scene, Spring, iter_elements

__all__ = ['DENSE_METHODS', 'format_hybrid_summary', 'hybrid_simulation', 'hybrid_summary',
           'run_hybrid']

RPM = math.pi / 30.0


def hybrid_simulation(scene: Scene, *, method: str | None = None, rtol: float | None = None,
                      atol: float | None = None, fidelity: Mapping[str, str] | None = None,
                      duration: float | None = None, sample_dt: float | None = None
                      ) -> Any:
    """The scene's chain, engine, load and commands (a HybridSimulation; a vehicle scene's
    tree: a HybridTreeSimulation, with its shift schedule when given). Joints and springs
    take their scene fidelity ('auto': joints at their best model, springs elastic;
    ``accuracy_target`` is not applied here) or ``fidelity``; the stall speed is the
    engine's ``stall_rpm`` when > 0."""
    from cvj_ros.physics.engine import engine_from_spec
    from cvj_ros.physics.load import load_from_spec
    method = method or scene.solver.method
    if method not in DENSE_METHODS:
        raise SceneError('solver.method', f'a scene with clutch, gearbox, brake or commands needs an '
                                          f'adaptive method with dense output ({", ".join(DENSE_METHODS)}), '
                                          f'got {method!r}')
    levels: dict[str, str] = {}
    for el in iter_elements(scene.driveline):
        if isinstance(el, Joint) and el.fidelity != 'auto':
            levels[el.name] = el.fidelity
        elif isinstance(el, Spring) and el.fidelity == 'rigid':
            levels[el.name] = 'rigid'
    names = {el.name for el in iter_elements(scene.driveline)}
    for name, level in (fidelity or {}).items():
        if name not in names:
            raise SceneError('--fidelity', f'no element {name!r} in the scene')
        levels[name] = level
    engine = engine_from_spec(scene.engine, field='engine')
    if scene.is_tree:
        return _tree_simulation(scene, levels, engine, method=method, rtol=rtol, atol=atol,
                                duration=duration, sample_dt=sample_dt)
    chain = HybridChain(scene.driveline, levels=levels)
    load = load_from_spec(scene.load, seed=scene.seed, field='load')
    schedule = CommandSchedule([(r['t'], {k: v for k, v in r.items() if k != 't'})
                                for r in scene.commands])
    stall_rpm = float(getattr(engine, 'stall_rpm', 0.0) or 0.0)
    return HybridSimulation(
        chain, engine=engine, load=load, schedule=schedule,
        duration=scene.duration if duration is None else duration,
        sample_dt=sample_dt or scene.sample_step or scene.exchange_step,
        initial_speed=scene.initial_speed, stall_speed=stall_rpm * RPM if stall_rpm > 0 else None,
        method=method, rtol=scene.solver.rtol if rtol is None else rtol,
        atol=scene.solver.atol if atol is None else atol,
        max_step=scene.solver.max_step or math.inf)


def _tree_simulation(scene: Scene, levels: Mapping[str, str], engine: Any, *, method: str,
                     rtol: float | None, atol: float | None, duration: float | None,
                     sample_dt: float | None) -> Any:
    from cvj_ros.physics.hybrid.shift import AutoShift
    from cvj_ros.physics.hybrid.tree_sim import HybridTreeSimulation
    schedule: Any = CommandSchedule([(r['t'], {k: v for k, v in r.items() if k != 't'})
                                     for r in scene.commands])
    if scene.shift_schedule is not None:
        schedule = AutoShift(schedule, scene.shift_schedule)
    stall_rpm = float(getattr(engine, 'stall_rpm', 0.0) or 0.0)
    return HybridTreeSimulation(
        scene, levels, engine=engine, schedule=schedule,
        duration=scene.duration if duration is None else duration,
        sample_dt=sample_dt or scene.sample_step or scene.exchange_step,
        stall_speed=stall_rpm * RPM if stall_rpm > 0 else None,
        method=method, rtol=scene.solver.rtol if rtol is None else rtol,
        atol=scene.solver.atol if atol is None else atol,
        max_step=scene.solver.max_step or math.inf)


def hybrid_summary(scene: Scene, sim: HybridSimulation, result: HybridResult, wall: float,
                   note: str) -> dict[str, Any]:
    """JSON-able summary: events per element and new mode, the event list, status lines,
    final speeds and modes, energy residual, solver counters, wall time."""
    counts: dict[str, dict[str, int]] = {}
    for e in result.events:
        counts.setdefault(e.element, {}).setdefault(e.after, 0)
        counts[e.element][e.after] += 1
    mode = result.final_mode
    final_modes = {**{c: mode_name(m) for c, m in mode.clutch.items()},
                   **{g: f'gear {v}' for g, v in mode.gear.items()}}
    if sim.chain is not None and sim.chain.brake is not None and mode.brake is not None:
        final_modes[sim.chain.brake.name] = mode_name(mode.brake)
    final_modes.update({b: mode_name(m) for b, m in mode.brakes.items()})
    final_modes.update({p: mode_name(m) for p, m in mode.packs.items()})
    sim_time = result.t_end or 1.0
    return {'scene': scene.name, 'duration': result.t_end,
            'wall_time': wall, 'wall_per_sim_second': wall / sim_time,
            'solver': {'method': sim.method, 'rtol': sim.rtol, 'atol': sim.atol,
                       'backend': 'python', 'backend_fallback': note, **result.stats},
            'energy_residual': result.max_energy_residual,
            'events': counts,
            'event_list': [{'t': e.t, 'element': e.element, 'before': e.before, 'after': e.after,
                            'cause': e.cause} for e in result.events],
            'statuses': list(result.statuses), 'stall': result.stall,
            'final_modes': final_modes,
            'final_speeds': {n: float(result.speed[-1, i]) for i, n in enumerate(result.shafts)}
            if result.t.size else {},
            **({'final_vehicle_speed_m_s': float(result.vehicle_speed[-1])}
               if getattr(result, 'vehicle_speed', None) is not None and result.t.size else {})}


def format_hybrid_summary(s: dict[str, Any]) -> str:
    """Human-readable text of :func:`hybrid_summary`."""
    sol = s['solver']
    lines = [f"scene {s['scene']}: {s['duration']:g} s simulated, wall {s['wall_time']:.3f} s "
             f"({s['wall_per_sim_second']:.4g} s per simulated s)",
             f"solver {sol['method']} rtol {sol['rtol']:g} atol {sol['atol']:g}: {sol['steps']} steps, "
             f"{sol['nfev']} rhs evaluations, {sol['events']} located events, "
             f"{sol['restarts']} restarts",
             'backend python' + (f" ({sol['backend_fallback']})" if sol['backend_fallback'] else ''),
             f"energy balance residual {s['energy_residual']:.3e} (relative, friction and lock "
             f"losses booked)"]
    for el, c in s['events'].items():
        lines.append(f"events {el}: " + ', '.join(f'{n} -> {m}' for m, n in sorted(c.items())))
    lines.append('final: ' + ', '.join(f'{k} {v}' for k, v in s['final_modes'].items()))
    if 'final_vehicle_speed_m_s' in s:
        v = s['final_vehicle_speed_m_s']
        lines.append(f'vehicle speed {v:.4g} m/s ({v * 3.6:.4g} km/h)')
    for line in s['statuses']:
        lines.append(f'status {line}')
    lines.append(f"{'shaft':<24}{'final rad/s':>14}")
    for name, w in s['final_speeds'].items():
        lines.append(f'{name:<24}{w:>14.6g}')
    return '\n'.join(lines)


def run_hybrid(scene: Scene, **kw: Any) -> tuple[HybridSimulation, HybridResult, float]:
    """Build and run; (simulation, result, wall seconds)."""
    sim = hybrid_simulation(scene, **kw)
    t0 = time.perf_counter()
    result = sim.run()
    return sim, result, time.perf_counter() - t0
