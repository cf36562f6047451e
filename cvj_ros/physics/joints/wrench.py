"""Reaction wrench of a joint in its housing frame, as published on ``/coupling/<joint>/wrench``.

Housing frame (REP-103 right-handed, frame_id ``<joint>_housing``): z along the housing
(input) shaft axis pointing into the joint, x normal to the bend plane, y = z x x.
One convention for every joint:

* ``torque.z`` (N m): torque the joint delivers to its output shaft (``torque_out`` of
  the model: power balance through the instantaneous ratio, Dziopa eq. 20 for the
  Rzeppa, i torque_in for a gear stage).
* ``torque.x``, ``torque.y`` (N m): bending moment the joint puts on the housing side,
  reacted by its support bearings: the Hooke secondary couple C1 on the input yoke,
  the tripod input-bearing moment (Xiu et al. 2024, section 4, recomputed); 0 where the model
  gives none.
* ``force.x``, ``force.y`` (N): force the housing bearing must supply (tripod);
  ``force.z`` (N): tripod generated axial force, along the output shaft axis (Xiu et al. 2024
  R_z'', recomputed from the exact kinematics; the housing tracks themselves take no
  axial load in the frictionless model). 0 for joints without these forces.

Models without ``reactions()`` have no wrench (``None``).
"""
from __future__ import annotations

from collections.abc import Mapping
from typing import Any

Vector3 = tuple[float, float, float]


def housing_wrench(model: Any, phi_in: float, omega_in: float,
                   torque_in: float) -> tuple[Vector3, Vector3] | None:
    """(force xyz in N, torque xyz in N m) in the housing frame, or ``None``.

    Args:
        model: a joint model (``cvj_ros.physics.joints``); uses its ``reactions()``.
        phi_in: input angle (rad). omega_in: input speed (rad/s).
        torque_in: torque delivered by the input shaft into the joint (N m).
    """
    reactions = getattr(model, 'reactions', None)
    if reactions is None:
        return None
    return wrench_from_reactions(getattr(model, 'kind', ''), reactions(phi_in, omega_in, torque_in))


def wrench_from_reactions(kind: str, r: Mapping[str, float]) -> tuple[Vector3, Vector3]:
    """The housing-frame wrench (module docstring) from a joint model's ``reactions()``
    dict; ``kind`` is the joint's registry name."""
    t_out = float(r.get('torque_out', 0.0))
    if kind == 'hooke':
        # hooke.py frame: input axis y, bend plane y-z, x normal -> housing (x, -z, y).
        return (0.0, 0.0, 0.0), (float(r['secondary_in_x']), -float(r['secondary_in_z']), t_out)
    if kind == 'tripod':
        # tripod.py fixed frame already has z along the housing axis.
        return ((float(r['input_force_x']), float(r['input_force_y']), float(r['axial_force'])),
                (float(r['input_moment_x']), float(r['input_moment_y']), t_out))
    return (0.0, 0.0, 0.0), (0.0, 0.0, t_out)
