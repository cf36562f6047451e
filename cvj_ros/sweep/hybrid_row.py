"""The result row of one sweep variant with clutch, gearbox, brake or commands: the mode
model on the compiled kernel (:mod:`cvj_ros.physics.kernel.modes`, a vehicle scene
:mod:`cvj_ros.physics.kernel.tree_modes`; every method with dense output)
or its Python reference (:mod:`cvj_ros.physics.hybrid`; backend 'python' or another method),
summarised as events per element, the first lock-up of each clutch and brake, the final
modes and shaft speeds, the stall, refused commands and the energy residual; a vehicle
scene (a tree): the same per clutch, gearbox, wheel brake and clutch-pack
differential, and the final vehicle speed."""
from __future__ import annotations

import math
from typing import Any

__all__ = ['hybrid_row']


def hybrid_row(scene: Any, options: Any) -> dict[str, Any]:
    """Columns of one mode-scene variant (without ``status`` / ``error``); ``options`` a
    :class:`cvj_ros.sweep.run.RunOptions` (its fidelity and sample step; no order analysis:
    the reference keeps speeds, not shaft torques)."""
    from cvj_ros.physics.hybrid.friction import mode_name
    from cvj_ros.physics.hybrid.from_scene import hybrid_simulation
    sim = hybrid_simulation(scene, fidelity=dict(options.fidelity) or None,
                            sample_dt=options.sample_dt)
    chain = sim.chain
    backend = 'python'
    tree = chain is None          # a vehicle scene: HybridTreeSimulation
    if getattr(options, 'backend', 'kernel') == 'kernel' and tree:
        from cvj_ros.physics.kernel.tree_modes import (KERNEL_TREE_MODE_METHODS,
                                                       KernelHybridTreeSimulation)
        if sim.method in KERNEL_TREE_MODE_METHODS:
            try:
                sim, backend = KernelHybridTreeSimulation.from_reference(sim), 'kernel'
            except NotImplementedError:
                pass                # a joint or engine the kernel does not pack: the reference
    elif getattr(options, 'backend', 'kernel') == 'kernel':
        from cvj_ros.physics.kernel.modes import KERNEL_MODE_METHODS, KernelHybridSimulation
        if sim.method in KERNEL_MODE_METHODS:
            sim, backend = KernelHybridSimulation.from_reference(sim), 'kernel'
    r = sim.run()
    row: dict[str, Any] = {'energy_residual': r.max_energy_residual}
    for key in ('steps', 'nfev', 'events', 'restarts'):
        row[key] = int(r.stats.get(key, 0))
    row['backend'] = backend
    row['t_end'] = float(r.t_end)
    row['stall'] = r.stall is not None
    row['refused_commands'] = sum(1 for s in r.statuses if 'refused' in s)
    mode = r.final_mode
    if tree:      # every clutch, gearbox, wheel brake and clutch-pack differential
        friction = [*sim.clutches, *sim.brake_els, *sim.packs]
        elements = [*sim.clutches, *sim.gearboxes, *sim.brake_els, *sim.packs]
    else:
        friction = [*chain.clutches] + ([chain.brake.name] if chain.brake else [])
        elements = [*chain.clutches, *chain.gearboxes] + friction[len(chain.clutches):]
    for el in elements:
        row[f'{el}.events'] = r.count(el)
    for el in friction:
        locks = [e.t for e in r.events if e.element == el and e.after == 'stuck' and e.t > 0]
        row[f'{el}.first_stuck_s'] = locks[0] if locks else math.nan
    for name, m in mode.clutch.items():
        row[f'{name}.final_mode'] = mode_name(m)
    for name, g in mode.gear.items():
        row[f'{name}.final_gear'] = int(g)
    if tree:
        for name, m in [*mode.brakes.items(), *mode.packs.items()]:
            row[f'{name}.final_mode'] = mode_name(m)
        vel = getattr(r, 'vehicle_speed', None)
        row['vehicle_speed_m_s'] = float(vel[-1]) if vel is not None and r.t.size else math.nan
    elif chain.brake is not None and mode.brake is not None:
        row[f'{chain.brake.name}.final_mode'] = mode_name(mode.brake)
    for i, shaft in enumerate(r.shafts):
        row[f'{shaft}.final_speed'] = float(r.speed[-1, i]) if r.t.size else math.nan
    return row
