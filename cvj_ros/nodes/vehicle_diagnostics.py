"""Per-wheel and vehicle values of a vehicle scene's state for the coupling node's loop
diagnostics (/diagnostics key/values): what the JointState message cannot carry."""
from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ['vehicle_values']


def vehicle_values(driveline: Any, x: np.ndarray) -> dict[str, float | int]:
    """``vehicle_speed_m_s`` and per wheel ``<wheel>.slip`` (relaxed slip ratio, -),
    ``<wheel>.fx_N`` (tyre force), ``<wheel>.fz_N`` (normal load), ``<wheel>.status`` (tyre
    status code of cvj_ros.physics.tyre) at state ``x`` of a TreeDriveline; {} for a chain
    or a non-finite state."""
    if not getattr(driveline, 'is_tree', False) or not np.all(np.isfinite(x)):
        return {}
    out: dict[str, float | int] = {'vehicle_speed_m_s': float(driveline.vehicle_speed(x))}
    for name, w in driveline.wheel_outputs(x).items():
        out[f'{name}.slip'] = float(w['slip'])
        out[f'{name}.fx_N'] = float(w['fx'])
        out[f'{name}.fz_N'] = float(w['fz'])
        out[f'{name}.status'] = int(w['status'])
    return out
