"""Exact composition of joints in series: phi_out = f_n(... f_2(f_1(phi_in))).

For two stages (chain rule; the general case is applied stage by stage)::

    phi_out     = f2(f1(phi))                                    (rad)
    ratio       = f2'(f1(phi)) f1'(phi)                          (-)
    ratio_slope = f2''(f1(phi)) f1'(phi)^2 + f2'(f1(phi)) f1''(phi)   (1/rad)

Used e.g. for Bugaru & Vasile 2021's driveshaft (eqs. 20-22): tulip-tripod, rigid midshaft,
fixed ball joint, composed exactly rather than by Bugaru & Vasile 2021's truncated eq. 22 and
its eq. 23 (which carries a spurious factor 1.5 in the second term, README "Errors in
the source documents"). Any object meeting the :class:`~cvj_ros.physics.joints.base.JointModel`
contract can be a stage. Each stage's input is the previous stage's output, so
each stage's own zero-position convention applies to the shaft in front of it.
``phi_mid`` is the angle of the shaft after the first stage (the midshaft of a
two-joint driveshaft; ``mid_name`` = 'midshaft').
"""
from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from cvj_ros.errors import GeometryError
from cvj_ros.physics.joints.base import (FIDELITIES, JOINTS, JointEval, JointModel, JointSpec,
                                         as_angle_array, check_finite, make_joint, register)


class Chain:
    """Series composition of ``joints`` (at least one), first joint on the input side."""

    kind = 'chain'
    mid_name = 'midshaft'

    def __init__(self, joints: Sequence[JointModel], *, fidelity: str = 'exact') -> None:
        if isinstance(joints, (str, bytes)) or not isinstance(joints, Sequence) or len(joints) == 0:
            raise GeometryError('joints', 'must be a non-empty list of joints')
        for k, j in enumerate(joints):
            if not isinstance(j, JointModel):
                raise GeometryError(f'joints[{k}]', f'is not a joint model: {j!r}')
        self.joints: tuple[JointModel, ...] = tuple(joints)
        self.fidelity = fidelity

    def params(self) -> dict[str, float]:
        """Stage parameters prefixed ``joints[k].`` (SI units)."""
        out: dict[str, float] = {}
        for k, j in enumerate(self.joints):
            out.update({f'joints[{k}].{name}': v for name, v in j.params().items()})
        return out

    def stages(self, phi_in: ArrayLike) -> list[JointEval]:
        """Each stage's :class:`JointEval` at its own input angle (rad), in order."""
        phi = as_angle_array(phi_in)
        out = []
        for j in self.joints:
            e = j.evaluate(phi)
            out.append(e)
            phi = e.phi_out
        return out

    def evaluate(self, phi_in: ArrayLike) -> JointEval:
        phi = as_angle_array(phi_in)
        ratio = np.ones_like(phi)
        slope = np.zeros_like(phi)
        mid = None
        for k, j in enumerate(self.joints):
            e = j.evaluate(phi)
            slope = e.ratio_slope * ratio * ratio + e.ratio * slope
            ratio = e.ratio * ratio
            phi = e.phi_out
            if k == 0:
                mid = e.phi_mid if len(self.joints) == 1 else e.phi_out.copy()
        return JointEval(phi, ratio, slope, mid)

    def scalar(self, phi_in: float) -> tuple[float, float, float]:
        phi, ratio, slope = phi_in, 1.0, 0.0
        for j in self.joints:
            phi, r, s = j.scalar(phi)
            slope = s * ratio * ratio + r * slope
            ratio = r * ratio
        return phi, ratio, slope

    def nonuniformity(self) -> float:
        """Half peak-to-peak (rad) of phi_out - k phi_in over one input revolution,
        k = mean ratio over that revolution (1 without gears), from 8001 samples."""
        phi = np.linspace(0.0, 2.0 * math.pi, 8001)
        out = self.evaluate(phi).phi_out
        k = (out[-1] - out[0]) / (2.0 * math.pi)
        dev = out - k * phi
        return float(0.5 * (dev.max() - dev.min()))

    def reactions(self, phi_in: float, omega_in: float, torque_in: float) -> dict[str, float]:
        """Torque passed stage by stage (N m): each stage's ``reactions`` where it has
        one (keys prefixed ``joints[k].``), else power balance T/ratio; ``torque_out``
        is the last stage's output torque. ``omega_in`` (rad/s) is propagated as
        omega_k = ratio_k omega_{k-1}."""
        phi, om = check_finite('phi_in', phi_in), check_finite('omega_in', omega_in)
        torque = check_finite('torque_in', torque_in)
        out: dict[str, float] = {}
        for k, j in enumerate(self.joints):
            nxt, r, _ = j.scalar(phi)
            react = getattr(j, 'reactions', None)
            if react is not None:
                d = react(phi, om, torque)
                out.update({f'joints[{k}].{key}': v for key, v in d.items()})
                torque = d.get('torque_out', torque / r)
            else:
                torque = torque / r
            phi, om = nxt, om * r
        out['torque_out'] = torque
        return out


def build_stage(item: JointModel | Mapping[str, Any], fidelity: str, index: int) -> JointModel:
    """A stage from a JointModel, or from a dict ``{'kind': ..., 'fidelity'?: ..., **params}``.

    Without its own ``fidelity`` a dict stage takes the chain's fidelity if its kind
    has it, else its most detailed one."""
    if isinstance(item, JointModel):
        return item
    if not isinstance(item, Mapping) or 'kind' not in item:
        raise GeometryError(f'joints[{index}]', "must be a joint model or a dict with 'kind'")
    spec = dict(item)
    kind = spec.pop('kind')
    fid = spec.pop('fidelity', None)
    if fid is None:
        known = JOINTS[kind].fidelities if kind in JOINTS else FIDELITIES
        fid = fidelity if fidelity in known else known[-1]
    try:
        return make_joint(kind, fidelity=fid, **spec)
    except GeometryError as exc:
        raise GeometryError(f'joints[{index}].{exc.parameter}',
                            str(exc).split(': ', 1)[-1]) from None


def _factory(*, fidelity: str = 'exact', joints: Sequence[Any] = (), **extra: Any) -> Chain:
    if extra:
        raise GeometryError(sorted(extra)[0], 'unknown parameter for chain (known: joints)')
    if isinstance(joints, (str, bytes)) or not isinstance(joints, Sequence) or len(joints) == 0:
        raise GeometryError('joints', 'must be a non-empty list of joints')
    return Chain([build_stage(j, fidelity, k) for k, j in enumerate(joints)], fidelity=fidelity)


register(JointSpec(kind='chain', factory=_factory, fidelities=FIDELITIES,
                   params={'joints': "list of JointModel or {'kind': ..., 'fidelity'?: ..., params}"},
                   source='chain rule; Bugaru & Vasile 2021, eqs. 20-22 (composition, eq. 23 not copied)'))
