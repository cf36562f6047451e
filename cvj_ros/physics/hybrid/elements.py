"""Mode elements of a chain driveline: friction clutch, gearbox, output-shaft brake.

Each splits the chain (cvj_ros.physics.hybrid.chain): a clutch or gearbox owns two
inertias, its shafts ``<name>_input`` and ``<name>_output``; a brake acts between the
chain's last inertia (the output shaft) and the ground. Units SI: kg m^2, m, N, rad/s.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

from cvj_ros.errors import SceneError
from cvj_ros.physics.hybrid.friction import CoulombPack

__all__ = ['Brake', 'Clutch', 'Gearbox', 'ModeElement']


def _positive(name: str, key: str, v: float) -> None:
    if not (v > 0.0 and math.isfinite(v)):
        raise SceneError(f'{name}.{key}', f'must be > 0 and finite, got {v!r}')


@dataclass(frozen=True)
class Clutch:
    """Friction clutch between ``<name>_input`` (J_input, engine side) and ``<name>_output``
    (J_output, friction disc). Pedal p in 0 (engaged) .. 1 (open) gives the normalised
    normal force f_n = 1 - p (Modelica Clutch's ``f_normalized``)."""

    name: str
    J_input: float
    J_output: float
    pack: CoulombPack
    type: str = field(default='clutch', init=False)

    def __post_init__(self) -> None:
        _positive(self.name, 'J_input', self.J_input)
        _positive(self.name, 'J_output', self.J_output)

    @staticmethod
    def normal_force(pedal: float) -> float:
        """f_n = 1 - pedal, clipped to 0..1 (-)."""
        return min(1.0, max(0.0, 1.0 - pedal))


@dataclass(frozen=True)
class Gearbox:
    """Gearbox between ``<name>_input`` and ``<name>_output``: forward ratios i_1..i_N and a
    reverse ratio i_R (omega_in / omega_out, i_R < 0), neutral 0 decouples the sides.
    ``max_input_speed`` (rad/s): a gear whose input speed at the present output speed,
    |i omega_out|, would exceed it is refused (the engine would over-speed)."""

    name: str
    J_input: float
    J_output: float
    ratios: tuple[float, ...]
    reverse_ratio: float
    max_input_speed: float
    type: str = field(default='gearbox', init=False)

    def __post_init__(self) -> None:
        _positive(self.name, 'J_input', self.J_input)
        _positive(self.name, 'J_output', self.J_output)
        _positive(self.name, 'max_input_speed', self.max_input_speed)
        if not self.ratios:
            raise SceneError(f'{self.name}.ratios', 'must list at least one forward ratio')
        for k, r in enumerate(self.ratios):
            _positive(self.name, f'ratios[{k}]', r)
        if not (self.reverse_ratio < 0.0 and math.isfinite(self.reverse_ratio)):
            raise SceneError(f'{self.name}.reverse_ratio', f'must be < 0, got {self.reverse_ratio!r}')

    def ratio(self, gear: int) -> float:
        """i of ``gear`` (-1 reverse, 1..N forward); ValueError for neutral or out of range."""
        if gear == -1:
            return self.reverse_ratio
        if 1 <= gear <= len(self.ratios):
            return self.ratios[gear - 1]
        raise ValueError(f'{self.name}: no ratio for gear {gear}')

    def valid_gear(self, gear: int) -> bool:
        return -1 <= gear <= len(self.ratios)


@dataclass(frozen=True)
class Brake:
    """Brake between the chain's output shaft and the ground; command b in 0..1 is the
    normalised normal force (fraction of capacity)."""

    name: str
    pack: CoulombPack
    type: str = field(default='brake', init=False)


ModeElement = Clutch | Gearbox | Brake
