"""Outside wheel loads on a compiled right-hand side: :class:`CompiledWheelLoadRhs` wraps a
vehicle scene's TreeDriveline so that ``rhs(t, x, T_engine, T_load)`` - what the Python
steppers of cvj_ros.physics.cosim.CoupledStepper call - runs
``kernel/tree_outputs_nb.tree_rhs_wheels`` (the tree's equations with every tyre replaced by
its outside resisting torque, F_x = T_w / r, in TreeDriveline.rhs's order of operations)
with the torques of ``driveline.set_wheel_torques`` read at every call. Everything else is
the wrapped driveline's. The kernel steppers themselves have no per-wheel input yet
(kernel/tree_nb.py), so the stepping stays Python; only the ~150 us Python right-hand side
per stage becomes a compiled call.
"""
from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = ['CompiledWheelLoadRhs']

FloatArray = NDArray[np.float64]


class CompiledWheelLoadRhs:
    """A TreeDriveline whose ``rhs`` is compiled under outside wheel loads (module
    docstring). NotImplementedError when the driveline does not pack into kernel data.
    Building it compiles or loads the numba function and evaluates once."""

    def __init__(self, driveline: Any) -> None:
        from cvj_ros.physics.kernel import entry_point
        from cvj_ros.physics.kernel import tree_outputs_nb as TO
        from cvj_ros.physics.kernel.layout import build_model
        from cvj_ros.physics.tree import TreeDriveline
        if type(driveline) is not TreeDriveline:      # not the mode-aware tree either
            raise NotImplementedError('compiled wheel loads: a vehicle scene only')
        held, driveline.wheel_torques = driveline.wheel_torques, None
        try:
            self._model = build_model(driveline)    # the tables; the torques come per call
        finally:
            driveline.wheel_torques = held
        self._dl = driveline
        self._wheel_t = np.zeros(max(driveline.n_wheel, 1))
        x0 = np.array(driveline.x0, dtype=np.float64)
        self._n_state = x0.size
        self._fn = entry_point(TO.tree_rhs_wheels, (0.0, x0, self._model.ip, self._model.fp, 0.0,
                                                    self._wheel_t, np.empty(x0.size)))

    def __getattr__(self, name: str) -> Any:
        return getattr(self._dl, name)

    def rhs(self, t: float, x: FloatArray, T_engine: float, T_load: float = 0.0) -> FloatArray:
        """dx/dt: compiled with the driveline's outside wheel torques; the driveline's own
        ``rhs`` (the tyres) when none are set."""
        torques = self._dl.wheel_torques
        if torques is None:
            return self._dl.rhs(t, x, T_engine, T_load)
        self._wheel_t[:len(torques)] = torques
        dy = np.empty(self._n_state)
        self._fn(float(t), np.ascontiguousarray(x, dtype=np.float64), self._model.ip,
                 self._model.fp, float(T_engine), self._wheel_t, dy)
        return dy
