"""Joint kinematics. Importing this package registers every joint model in
:data:`cvj_ros.physics.joints.base.JOINTS`; build one with :func:`make_joint`."""
from __future__ import annotations

import importlib

from cvj_ros.physics.joints.base import FIDELITIES, JOINTS, JointEval, JointModel, make_joint

__all__ = ['FIDELITIES', 'JOINTS', 'JointEval', 'JointModel', 'make_joint']

# Each module registers itself on import. Missing modules (not built yet) are skipped.
for _name in ('ideal', 'gear', 'hooke', 'double_cardan', 'tripod', 'rzeppa', 'lever_hinge', 'chain',
              'runout'):
    try:
        importlib.import_module(f'{__name__}.{_name}')
    except ModuleNotFoundError as _exc:
        if _exc.name != f'{__name__}.{_name}':
            raise
