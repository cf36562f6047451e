"""Outside wheel loads of a vehicle scene: one /load/<wheel>/wrench answer per wheel per step.

With ``wheel_load:=external`` the coupling node takes each wheel's resisting torque
(``torque.z``, N m, positive opposes positive rotation; the stamp echoes the joint-state
stamp, as on /load/wrench) from ``/load/<wheel>/wrench`` instead of the built-in tyre
(cvj_ros.physics.tree.TreeDriveline.set_wheel_torques: F_x = T / r on the wheel and the
body). :class:`WheelAnswers` collects the answers of one exchange step without rclpy: the
step's load port is complete when every wheel has answered that step's stamp once.
"""
from __future__ import annotations

from collections.abc import Sequence

__all__ = ['WHEEL_LOAD_MODES', 'WheelAnswers', 'wheel_wrench_topic']

#: coupling_node ``wheel_load`` values: the built-in tyres, or outside nodes per wheel
WHEEL_LOAD_MODES = ('internal', 'external')


def wheel_wrench_topic(wheel: str) -> str:
    """The topic an outside node answers a wheel's load on: ``/load/<wheel>/wrench``."""
    return f'/load/{wheel}/wrench'


class WheelAnswers:
    """One answer per wheel for one stamp (integer ns).

    ``offer(i, stamp_ns, value)`` records wheel i's torque for ``stamp_ns`` (a new stamp
    starts a new set); it returns True exactly once per stamp, when the set becomes complete,
    and False for a duplicate (the first answer stands) or while wheels are missing.
    ``values`` are the torques of the latest set (N m, wheel order), ``missing(stamp_ns)``
    the topics of the wheels that have not answered that stamp.
    """

    def __init__(self, wheels: Sequence[str]) -> None:
        if not wheels:
            raise ValueError('wheel answers: a vehicle scene has at least one wheel')
        self.wheels = list(wheels)
        self.topics = [wheel_wrench_topic(w) for w in self.wheels]
        self.values = [0.0] * len(self.wheels)
        self._have = [False] * len(self.wheels)
        self._stamp: int | None = None

    def offer(self, i: int, stamp_ns: int, value: float) -> bool:
        if stamp_ns != self._stamp:
            self._stamp = stamp_ns
            self._have = [False] * len(self.wheels)
        if self._have[i]:
            return False
        self._have[i] = True
        self.values[i] = float(value)
        return all(self._have)

    def answered(self, i: int, stamp_ns: int) -> bool:
        """True when wheel i has answered ``stamp_ns`` already."""
        return stamp_ns == self._stamp and self._have[i]

    def missing(self, stamp_ns: int) -> list[str]:
        """Topics without an answer stamped ``stamp_ns``."""
        if stamp_ns != self._stamp:
            return list(self.topics)
        return [t for t, have in zip(self.topics, self._have) if not have]
