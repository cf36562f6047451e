"""The coupling node's physics for a scene with clutch, gearbox, brake or commands.

:func:`build_hybrid` wraps :func:`cvj_ros.physics.hybrid.lockstep.hybrid_lockstep` (the one
call into the physics, so its backend can change) in the three faces the coupling node uses
for a plain driveline: a driveline (shaft names, energy residual), a stepper
(``advance(t, T_engine, T_load)``; each interval on the compiled kernel or the Python
reference) and state outputs (joint states per exchange; no reaction wrenches). :func:`mode_values` are the mode figures of the loop diagnostics.
"""
from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

__all__ = ['HybridDriveline', 'HybridOutputs', 'HybridStepper', 'build_hybrid', 'gear_count',
           'mode_values']


class HybridDriveline:
    """Driveline face: ``shaft_names``, ``n_dof`` (rigid groups now), energy residual."""

    track_energy = True
    joint_models: dict[str, Any] = {}
    fidelity_report: dict[str, Any] = {}

    def __init__(self, hybrid: Any) -> None:
        self.hybrid = hybrid
        self.shaft_names = list(hybrid.shaft_names)
        self.x0 = self.state()

    @property
    def n_dof(self) -> int:
        if hasattr(self.hybrid, 'n_dof'):          # a vehicle tree (HybridTreeLockstep)
            return int(self.hybrid.n_dof)
        return len(self.hybrid.chain.assemble(self.hybrid.mode).groups)

    def state(self) -> np.ndarray:
        if hasattr(self.hybrid, 'state_vector'):
            return self.hybrid.state_vector()
        st = self.hybrid.st
        return np.concatenate([st.q, st.v])

    def energy(self, x: np.ndarray) -> dict[str, float]:
        if hasattr(self.hybrid, 'energy_parts'):
            return self.hybrid.energy_parts()
        kin, el = self.hybrid.chain.energy(self.hybrid.st)
        return {'kinetic': kin, 'elastic': el}

    def energy_residual(self, x: np.ndarray, e0: float) -> float:
        return float(self.hybrid.energy_residual())


class HybridStepper:
    """Stepper face: integrates the mode model between exchanges; ``backend`` 'kernel' or
    'python' as the model's (``backend_fallback``: why 'auto' ran the reference)."""

    def __init__(self, hybrid: Any, driveline: HybridDriveline) -> None:
        self.hybrid = hybrid
        self.driveline = driveline
        self.x = driveline.x0
        self.backend = getattr(hybrid, 'backend', 'python')
        self.backend_fallback = getattr(hybrid, 'backend_fallback', None)

    def advance(self, t_next: float, T_engine: float, T_load: float) -> np.ndarray:
        self.hybrid.advance(t_next, T_engine, T_load)
        self.x = self.driveline.state()
        return self.x


class HybridOutputs:
    """State-outputs face: joint states from the mode model (no reaction wrenches)."""

    backend = 'python'
    joints: list[str] = []

    def __init__(self, hybrid: Any) -> None:
        self.hybrid = hybrid

    def joint_states(self, x: np.ndarray, T_engine: float, T_load: float
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return self.hybrid.joint_states()

    def wrenches(self, x: np.ndarray, T_engine: float, T_load: float, joint_state: Any
                 ) -> dict[str, Any]:
        return {}


def build_hybrid(scene: Any, *, method: str | None, rtol: float | None, atol: float | None,
                 fidelity: Mapping[str, str] | None, backend: str = 'auto'
                 ) -> tuple[HybridDriveline, HybridStepper]:
    """(driveline, stepper) of a mode scene; ``driveline.state_outputs`` the outputs face.
    ``backend``: auto (the compiled kernel where it covers the method), kernel or python
    (:func:`~cvj_ros.physics.hybrid.lockstep.hybrid_lockstep`)."""
    from cvj_ros.physics.hybrid.lockstep import hybrid_lockstep
    hybrid = hybrid_lockstep(scene, method=method, rtol=rtol, atol=atol, fidelity=fidelity,
                             backend=backend)
    driveline = HybridDriveline(hybrid)
    driveline.state_outputs = HybridOutputs(hybrid)
    return driveline, HybridStepper(hybrid, driveline)


def gear_count(hybrid: Any) -> int | None:
    """Forward gears of the scene's gearbox (None without one)."""
    if hasattr(hybrid, 'gear_count'):              # a vehicle tree
        return hybrid.gear_count()
    boxes = list(hybrid.chain.gearboxes.values())
    return len(boxes[0][0].ratios) if boxes else None


def mode_values(hybrid: Any) -> dict[str, Any]:
    """Loop-diagnostics values of the mode model: engaged gear, each clutch's and the brake's
    mode (slip+ / stuck / slip-), the mode events so far, the refused commands and the stall
    line (empty while the engine runs); a vehicle tree adds the vehicle values
    (HybridTreeLockstep.mode_values)."""
    if hasattr(hybrid, 'mode_values'):
        return hybrid.mode_values()
    out: dict[str, Any] = {}
    names = hybrid.mode_names()
    for name, (_cl, _b) in hybrid.chain.clutches.items():
        out[f'clutch_state.{name}'] = names[name]
    for name in hybrid.chain.gearboxes:
        out[f'gear.{name}'] = hybrid.mode.gear[name]
    if hybrid.chain.brake is not None:
        out[f'brake_state.{hybrid.chain.brake.name}'] = names[hybrid.chain.brake.name]
    out['mode_events'] = len(hybrid.events)
    refused = [s for s in hybrid.statuses if 'refused' in s]
    out['refused_commands'] = len(refused)
    if refused:
        out['last_refused'] = refused[-1]
    out['stall'] = hybrid.stall or ''
    return out

