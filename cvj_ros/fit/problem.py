"""The model side of a fit: scene parameters -> the simulated torque's mean and order amplitudes.

Each parameter is a scene field addressed as ``cvj-sim sweep --set`` addresses it
(:func:`cvj_ros.sweep.spec.resolve_path`) with a range LO:HI. A parameter vector is written
into a copy of the scene dict, validated (:func:`cvj_ros.physics.scene.parse_scene`) and
simulated offline on the compiled core (:class:`cvj_ros.physics.simulate.Simulation`, dense
sampling). The torque of ``shaft`` is analysed over the angle of ``angle_shaft``
(:func:`cvj_ros.physics.signal.harmonics_over_angle`, 72 points per revolution) over a fixed
number of whole revolutions for every evaluation, so the analysed window does not jump when a
parameter changes the speed: the ``revolutions`` starting at ``start_time`` (s, the window of a
measured time series, analysed the same way), else the last ``revolutions`` of the run.
"""
from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from cvj_ros.errors import CvjError, SceneError
from cvj_ros.sweep.spec import SweepError, parse_spec, resolve_path

__all__ = ['FitParameter', 'FitProblem', 'parse_fit_parameter', 'FIT_RTOL', 'FIT_ATOL']

FloatArray = NDArray[np.float64]
# tighter than the scenes' 1e-6: the finite-difference Jacobian divides solver noise by a
# step of 1e-3 of a parameter's range (docs/fit.md)
FIT_RTOL = 1e-9
FIT_ATOL = 1e-11


@dataclass(frozen=True)
class FitParameter:
    """One ``--fit PATH=LO:HI``: the path as written, its canonical field, keys, range."""

    text: str
    path: str
    field: str
    keys: tuple[str | int, ...]
    lo: float
    hi: float

    def value(self, u: float) -> float:
        """The parameter at normalised coordinate u (0 at LO, 1 at HI)."""
        return self.lo + u * (self.hi - self.lo)


def parse_fit_parameter(base: Mapping[str, Any], text: str) -> FitParameter:
    """``PATH=LO:HI`` against the scene dict ``base``; SweepError naming ``--fit``."""
    path, sep, spec = text.partition('=')
    path = path.strip()
    where = f'--fit {path or text}'
    if not sep or not path:
        raise SweepError(f'--fit {text!r}: expected PATH=LO:HI, e.g. '
                         f"'driveline[bushings].stiffness=300:1500'")
    keys, canon = resolve_path(base, path, where)
    values, rng, _log = parse_spec(spec, where, random=True)
    if rng is None or values:
        raise SweepError(f'{where}: expected a range LO:HI, got {spec.strip()!r}')
    return FitParameter(text=text, path=path, field=canon, keys=keys, lo=rng[0], hi=rng[1])


@dataclass
class FitProblem:
    """Scene dict ``base`` with ``params`` free; the prediction is [mean, A_1..A_orders] (N m)
    of the torque of ``shaft`` over the angle of ``angle_shaft``.

    ``duration``: s simulated per evaluation (None: the scene's); ``revolutions``: whole
    revolutions analysed (None: set by the first evaluation to the whole revolutions in the
    second half of its run, then kept); ``start_time``: s where they start (None: they end
    at the end of the run).
    """

    base: Mapping[str, Any]
    params: Sequence[FitParameter]
    orders: int
    shaft: str | None = None
    angle_shaft: str | None = None
    duration: float | None = None
    revolutions: int | None = None
    start_time: float | None = None
    evaluations: int = 0
    _cache: dict[tuple[float, ...], FloatArray] = field(default_factory=dict)

    def scene_dict(self, values: Sequence[float]) -> dict[str, Any]:
        from cvj_ros.sweep.spec import apply_keys
        return apply_keys(self.base, [p.keys for p in self.params], [float(v) for v in values])

    def predict(self, values: Sequence[float]) -> FloatArray:
        """[mean, A_1 .. A_orders] (N m) of the model at parameter ``values``."""
        key = tuple(float(v) for v in values)
        if key in self._cache:
            return self._cache[key]
        out = self._simulate(key)
        self._cache[key] = out
        return out

    def trace(self, values: Sequence[float]) -> Any:
        """The simulated trace at ``values`` (for plots)."""
        from cvj_ros.physics.scene import parse_scene
        from cvj_ros.physics.simulate import Simulation
        scene = parse_scene(self.scene_dict(values))
        sim = Simulation(scene, rtol=FIT_RTOL, atol=FIT_ATOL)
        dur = self.duration if self.duration is not None else scene.duration
        return sim.run(dur, sampling='dense')

    def _simulate(self, values: tuple[float, ...]) -> FloatArray:
        from cvj_ros.physics.signal import harmonics_over_angle
        try:
            tr = self.trace(values)
        except CvjError as exc:
            shown = ', '.join(f'{p.path}={v:g}' for p, v in zip(self.params, values))
            raise SceneError('--fit', f'the model fails at {shown}: '
                             f'{" ".join(str(exc).split())}') from None
        self.evaluations += 1
        shaft = self.shaft or tr.names[0]
        angle_shaft = self.angle_shaft or shaft
        for opt, name in (('--shaft', shaft), ('--angle-shaft', angle_shaft)):
            if name not in tr.names:
                raise SceneError(opt, f'no shaft {name!r}; shafts: {", ".join(tr.names)}')
        phi = tr.position[:, tr.column(angle_shaft)]
        torque = tr.effort[:, tr.column(shaft)]
        if phi[-1] < phi[0]:        # reverse rotation: analyse over the turned angle
            phi = -phi
        m = max(72, 2 * self.orders + 2)
        dphi = 2 * math.pi / m
        if self.revolutions is None:
            half = phi[tr.t >= tr.t[-1] / 2]
            self.revolutions = int(math.floor((half[-1] - half[0] - 2 * dphi) / (2 * math.pi)))
            if self.revolutions < 1:
                raise SceneError('--fit', f'the model turns less than one revolution in the '
                                 f'second half of its {tr.t[-1]:g} s run; give a longer --duration')
        if self.start_time is None:
            mask = phi >= phi[-1] - self.revolutions * 2 * math.pi - 2 * dphi
        else:       # from the first grid angle after start_time, as the measured series
            after = tr.t >= self.start_time
            if not np.any(after):
                raise SceneError('--duration', f'the model run ({tr.t[-1]:g} s) ends before the '
                                 f'measured window starts ({self.start_time:g} s)')
            start = math.ceil(phi[after][0] / dphi - 1e-9) * dphi
            mask = after & (phi <= start + self.revolutions * 2 * math.pi + dphi)
        try:
            h = harmonics_over_angle(phi[mask], torque[mask], n_harmonics=self.orders,
                                     samples_per_rev=m)
        except ValueError as exc:
            raise SceneError('--fit', f'the model\'s {angle_shaft} angle cannot be analysed '
                             f'({exc}): the shaft stopped or reversed') from None
        if h.revolutions != self.revolutions:
            shown = ', '.join(f'{p.path}={v:g}' for p, v in zip(self.params, values))
            raise SceneError('--duration', f'the model turns {h.revolutions} whole revolutions '
                             f'in the analysed window at {shown}, the measurement '
                             f'{self.revolutions}; give a longer --duration')
        return np.concatenate([[h.mean], h.amplitudes])
