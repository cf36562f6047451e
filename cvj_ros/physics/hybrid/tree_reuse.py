"""Last-result reuse of a vehicle mode tree's kinematics and backward walk.

Within one exchange the vehicle mode lockstep passes the same state through
:meth:`~cvj_ros.physics.tree.TreeDriveline._kinematics` several times (the end of an
interval's ``to_state``, the settle's ``evaluate``, the joint state's walk) and, with a
clutch stuck, through the same backward walk twice (the stuck torque in ``evaluate``, then the
joint state). Both are pure functions of their arguments, so each keeps its last result keyed
by the exact arguments (the state's bytes; for the walk also the engine torque and the very
kinematics and forces objects): a repeated call returns the objects the first call made, the
same numbers bit for bit. :func:`reuse_tree` installs both on a ModeTree instance.
"""
from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ['LastKinematics', 'LastWalk', 'reuse_tree']


class LastKinematics:
    """``mt._kinematics(x)`` with its last result kept; x as a float64 ndarray is keyed by
    its bytes (anything else is evaluated afresh). Callers only read the returned _Kin."""

    __slots__ = ('fn', 'key', 'value')

    def __init__(self, fn: Any) -> None:
        self.fn = fn
        self.key: bytes | None = None
        self.value: Any = None

    def __call__(self, x: Any) -> Any:
        if not (isinstance(x, np.ndarray) and x.dtype == np.float64):
            return self.fn(x)
        key = x.tobytes()
        if key != self.key:
            self.value = self.fn(x)
            self.key = key
        return self.value


class LastWalk:
    """``mt._walk(x, T_engine, kin=, fo=)`` with its last result kept when ``kin`` and ``fo``
    are given: keyed by x's bytes, T_engine and the identity of kin and fo (held, so an id is
    never reused while keyed). Only for trees whose evaluation walks once per set of forces
    (no clutch-pack differential: its bias solve walks the same forces object with two
    trial torques written into it)."""

    __slots__ = ('fn', 'key', 'value', 'held')

    def __init__(self, fn: Any) -> None:
        self.fn = fn
        self.key: tuple | None = None
        self.value: Any = None
        self.held: tuple = ()

    def __call__(self, x: Any, T_engine: float, *, kin: Any = None, fo: Any = None) -> Any:
        if kin is None or fo is None or not isinstance(x, np.ndarray):
            return self.fn(x, T_engine, kin=kin, fo=fo)
        key = (x.tobytes(), float(T_engine), id(kin), id(fo))
        if key != self.key:
            self.value = self.fn(x, T_engine, kin=kin, fo=fo)
            self.key = key
            self.held = (kin, fo)
        return self.value


def reuse_tree(mt: Any) -> Any:
    """``mt`` (a ModeTree) with :class:`LastKinematics` and, without clutch packs,
    :class:`LastWalk` installed on the instance (once); returns ``mt``."""
    d = mt.__dict__
    if not isinstance(d.get('_kinematics'), LastKinematics):
        mt._kinematics = LastKinematics(mt._kinematics)
        if not mt.packs:
            mt._walk = LastWalk(mt._walk)
    return mt
