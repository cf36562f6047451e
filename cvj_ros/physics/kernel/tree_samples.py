"""Compiled offline samples of a vehicle scene: :class:`TreeKernelSamples` gives what
``TreeDriveline.sample_outputs`` gives per sample (engine torque, sum F_x r, shaft
positions, speeds and torques with members left as their joint's input, energy residual,
per wheel slip, F_x, F_z and status) with the walk, forces and wheel values from
``kernel/tree_outputs_nb.tree_sample`` (the same numbers as the Python reference). The
engine torque and the energy residual stay the driveline's own Python (the engine is a
Python callable; the residual needs the work integrals only with ``track_energy``).
"""
from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = ['TreeKernelSamples']

FloatArray = NDArray[np.float64]


class TreeKernelSamples:
    """Per-sample outputs of a TreeDriveline (module docstring); NotImplementedError when it
    does not pack into kernel data. Building it compiles or loads the numba function."""

    def __init__(self, driveline: Any) -> None:
        from cvj_ros.physics.kernel import entry_point
        from cvj_ros.physics.kernel import tree_outputs_nb as TO
        from cvj_ros.physics.kernel.layout import build_model
        if not getattr(driveline, 'is_tree', False) or driveline.wheel_torques is not None:
            raise NotImplementedError('compiled tree samples: a vehicle scene on its tyres')
        self._dl = driveline
        self._model = build_model(driveline)
        self._tab, self._ends = TO.tree_tables(driveline)
        n = len(driveline.shaft_names)
        self._wheel_t = np.zeros(max(driveline.n_wheel, 1))
        self._wheels = np.zeros((max(driveline.n_wheel, 1), 4))
        self._n = driveline.n_dof
        self._c0 = driveline.sections[0].coord
        x0 = np.array(driveline.x0, dtype=np.float64)
        self._fn = entry_point(TO.tree_sample, (x0, self._model.ip, self._model.fp, 0.0,
                                                self._wheel_t, self._tab, self._ends, np.empty(n),
                                                np.empty(n), np.empty(n), self._wheels))

    def __call__(self, t: float, x: FloatArray, engine_fn: Callable[..., float], e0: float,
                 pos: FloatArray, vel: FloatArray, eff: FloatArray
                 ) -> tuple[float, float, float, list[tuple[float, float, float, int]]]:
        """pos/vel/eff (C-contiguous float64 rows) filled in place for the finite state x at
        t; returns (engine torque N m, sum F_x r N m, energy residual (NaN without work
        integrals), per wheel (slip, F_x, F_z, status))."""
        dl = self._dl
        xl = x.tolist()
        te = engine_fn(t, xl[self._n + self._c0], xl[self._c0])    # as TreeDriveline._forces
        y = np.ascontiguousarray(x, dtype=np.float64)
        tl = self._fn(y, self._model.ip, self._model.fp, float(te), self._wheel_t, self._tab,
                      self._ends, pos, vel, eff, self._wheels)
        res = dl.energy_residual(x, e0) if dl.track_energy else math.nan
        wheels = [(float(r[0]), float(r[1]), float(r[2]), int(r[3]))
                  for r in self._wheels[:dl.n_wheel].tolist()]
        return te, tl, res, wheels
