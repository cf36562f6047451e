"""Mode elements (friction clutch, gearbox, brake) of a chain driveline, with stick and slip
solved as modes and transitions located on the stepper's dense output (docs/clutch_gearbox.md).
Pure Python reference; no ROS import. Names load on first use (PEP 562), so parsing a scene
does not import the solvers."""
from __future__ import annotations

import importlib
from typing import Any

_WHERE = {
    'HybridChain': 'chain', 'Mode': 'chain', 'SectionState': 'chain',
    'CommandSchedule': 'commands',
    'Brake': 'elements', 'Clutch': 'elements', 'Gearbox': 'elements',
    'BACKWARD': 'friction', 'FORWARD': 'friction', 'STUCK': 'friction', 'CoulombPack': 'friction',
    'HybridResult': 'simulate', 'HybridSimulation': 'simulate', 'ModeEvent': 'simulate',
}

__all__ = sorted(_WHERE)


def __getattr__(name: str) -> Any:
    if name not in _WHERE:
        raise AttributeError(f'module {__name__!r} has no attribute {name!r}')
    return getattr(importlib.import_module(f'{__name__}.{_WHERE[name]}'), name)
