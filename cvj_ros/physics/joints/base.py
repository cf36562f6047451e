"""Common contract of every joint model.

A joint maps the unwrapped input-shaft angle phi_in (rad) to the unwrapped output
angle phi_out (rad). Every model gives, vectorised over numpy arrays:

* ``phi_out``      output angle, continuous over any number of revolutions,
* ``ratio``        dphi_out/dphi_in (-),
* ``ratio_slope``  d2phi_out/dphi_in2 (1/rad),
* ``phi_mid``      the intermediate member's angle where one exists (cage, spider,
                   intermediate yoke, lever earring), else ``None``.

``scalar(phi_in)`` is the fast path the ODE right-hand side uses: the same three
numbers for one Python float, without numpy overhead.

Fidelities: ``ideal`` (phi_out = phi_in), ``closed`` (closed-form approximation),
``exact`` (the joint's full geometry). Not every joint has all three.
"""
from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cvj_ros.errors import GeometryError

FloatArray = NDArray[np.float64]
FIDELITIES = ('ideal', 'closed', 'exact')


@dataclass(frozen=True)
class JointEval:
    """Kinematic state of a joint for an array of input angles (all arrays same shape)."""

    phi_out: FloatArray
    ratio: FloatArray
    ratio_slope: FloatArray
    phi_mid: FloatArray | None = None


@runtime_checkable
class JointModel(Protocol):
    """What the driveline, the nodes and the CLI need from a joint."""

    kind: str        # registry name, e.g. 'hooke'
    fidelity: str    # 'ideal' | 'closed' | 'exact'

    def evaluate(self, phi_in: ArrayLike) -> JointEval:
        """Position, ratio, ratio slope (and intermediate angle) at ``phi_in`` (rad)."""
        ...

    def scalar(self, phi_in: float) -> tuple[float, float, float]:
        """(phi_out, ratio, ratio_slope) for one float ``phi_in`` (rad); fast path."""
        ...

    def params(self) -> dict[str, float]:
        """Geometry parameters in SI units (angles in rad, lengths in m)."""
        ...


def as_angle_array(phi_in: ArrayLike, name: str = 'phi_in') -> FloatArray:
    """Convert to a float64 array and reject NaN/inf with a :class:`GeometryError`."""
    arr = np.asarray(phi_in, dtype=np.float64)
    if not np.all(np.isfinite(arr)):
        raise GeometryError(name, 'must be finite (got NaN or inf)')
    return arr


def check_finite(name: str, value: float) -> float:
    """Return ``float(value)`` or raise :class:`GeometryError` naming ``name``."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise GeometryError(name, f'must be a number, got {value!r}') from None
    if not math.isfinite(v):
        raise GeometryError(name, f'must be finite, got {v}')
    return v


def check_range(name: str, value: float, *, lo: float | None = None, hi: float | None = None,
                lo_open: bool = False, hi_open: bool = True, unit: str = '') -> float:
    """Validate ``lo <= value < hi`` (openness configurable); message in the given unit."""
    v = check_finite(name, value)
    if lo is not None and (v < lo or (lo_open and v == lo)):
        raise GeometryError(name, f'must be {">" if lo_open else ">="} {lo}{unit}, got {v}{unit}')
    if hi is not None and (v > hi or (hi_open and v == hi)):
        raise GeometryError(name, f'must be {"<" if hi_open else "<="} {hi}{unit}, got {v}{unit}')
    return v


# --- registry --------------------------------------------------------------------------

@dataclass(frozen=True)
class JointSpec:
    """Registry entry: how to build a joint kind and what it accepts (for CLI help)."""

    kind: str
    factory: Callable[..., JointModel]     # factory(fidelity=..., **params) -> JointModel
    fidelities: tuple[str, ...]
    params: dict[str, str]                 # param name -> 'unit, meaning, default'
    source: str                            # seed file and equations


JOINTS: dict[str, JointSpec] = {}


def register(spec: JointSpec) -> JointSpec:
    JOINTS[spec.kind] = spec
    return spec


def make_joint(kind: str, *, fidelity: str = 'exact', **params: Any) -> JointModel:
    """Build a joint by registry name. Raises :class:`GeometryError` for unknown kinds."""
    from cvj_ros.physics import joints as _joints  # noqa: F401  (populates the registry)
    if kind not in JOINTS:
        raise GeometryError('kind', f'unknown joint {kind!r}; known: {", ".join(sorted(JOINTS))}')
    spec = JOINTS[kind]
    if fidelity not in spec.fidelities:
        raise GeometryError('fidelity', f'{kind} has fidelities {", ".join(spec.fidelities)}; '
                                        f'got {fidelity!r}')
    return spec.factory(fidelity=fidelity, **params)
