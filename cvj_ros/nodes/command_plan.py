"""Vehicle-stack commands on the lockstep loop: their topics, checked decoding, and the plan
a driver plays (docs/ros.md, "Commands").

Topics (standard messages): ``/engine/throttle`` (std_msgs/Float64, pedal 0..1),
``/driveline/clutch`` (std_msgs/Float64, pedal 0 engaged .. 1 open), ``/driveline/gear``
(std_msgs/Int8, -1 reverse, 0 neutral, 1..N), ``/driveline/brake`` (std_msgs/Float64, 0..1
of capacity).

Lockstep rule. A schedule is sampled at the exchange times t_k = k h (integer ns): the value
of a channel at step k is the schedule's at t_k (ramps sampled, gear the last row at or
before t_k). The driver publishes, on /clock = t_k, every played channel whose step-k value
differs from its step-(k-1) value (every played channel at k = 0). The coupling node knows
the same plan from the scene: it publishes the joint state stamped t_k only once the samples
of step k are in (so the engine node has the throttle of t_k before it answers t_k), and the
clutch, brake and gear of step k are in force over [t_k, t_(k+1)]. Integer nanoseconds and
per-publisher ordering make that one outcome for a scene, seed and schedule.
"""
from __future__ import annotations

import math
import struct
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

__all__ = ['BRAKE_TOPIC', 'CHANNEL_TOPICS', 'CLUTCH_TOPIC', 'CommandError', 'CommandPlan',
           'GEAR_TOPIC', 'THROTTLE_SCALE_TOPIC', 'THROTTLE_TOPIC', 'check_command',
           'decode_clock_ns', 'decode_command', 'throttle_scale_stamps']

THROTTLE_TOPIC = '/engine/throttle'
CLUTCH_TOPIC = '/driveline/clutch'
GEAR_TOPIC = '/driveline/gear'
BRAKE_TOPIC = '/driveline/brake'
#: the shift schedule's torque intervention on the engine (coupling node -> engine node)
THROTTLE_SCALE_TOPIC = '/engine/throttle_scale'
#: channel -> topic, in the order the driver publishes a step's samples
CHANNEL_TOPICS = {'throttle': THROTTLE_TOPIC, 'clutch': CLUTCH_TOPIC, 'gear': GEAR_TOPIC,
                  'brake': BRAKE_TOPIC}
NS_PER_S = 1_000_000_000
_MAX_BYTES = 1 << 16      # a Float64 / Int8 / Clock is a few bytes; anything this big is junk


class CommandError(ValueError):
    """A command sample that cannot be used: undecodable (``malformed`` True) or out of range."""

    def __init__(self, message: str, *, malformed: bool) -> None:
        super().__init__(message)
        self.malformed = malformed


def _encapsulation(data: bytes, need: int, what: str) -> bool:
    """True for big-endian CDR; CommandError (malformed) unless ``data`` is CDR of >= need bytes."""
    size = len(data)
    if size > _MAX_BYTES:
        raise CommandError(f'oversized: {size} bytes', malformed=True)
    if size < 4 or data[0] != 0 or data[1] > 1:
        raise CommandError(f'not CDR: {size} bytes starting {bytes(data[:4]).hex() or "(empty)"}',
                           malformed=True)
    if size < need:
        raise CommandError(f'cut short: {size} bytes, a {what} has {need}', malformed=True)
    return data[1] == 0


def decode_command(channel: str, data: bytes) -> float:
    """The value of a serialised sample of ``channel`` (Float64, or Int8 for ``gear``),
    checked before it is read; CommandError (malformed) otherwise."""
    if channel == 'gear':
        _encapsulation(data, 5, 'std_msgs/Int8')
        return float(struct.unpack_from('<b', data, 4)[0])
    big = _encapsulation(data, 12, 'std_msgs/Float64')
    return struct.unpack_from('>d' if big else '<d', data, 4)[0]


def decode_clock_ns(data: bytes) -> int:
    """rosgraph_msgs/Clock of serialised CDR as integer ns; CommandError (malformed) otherwise."""
    big = _encapsulation(data, 12, 'rosgraph_msgs/Clock')
    sec, nanosec = struct.unpack_from('>iI' if big else '<iI', data, 4)
    return sec * NS_PER_S + nanosec


def check_command(channel: str, value: float, n_gears: int | None = None) -> float:
    """``value`` if it is a valid ``channel`` command, else CommandError (not malformed)
    saying why: throttle, clutch, brake finite in 0..1; gear an integer -1..N (any integer
    when ``n_gears`` is None; a gear the box lacks is refused by the model with a status)."""
    if not math.isfinite(value):
        raise CommandError(f'must be finite, got {value}', malformed=False)
    if channel == 'gear':
        lo, hi = -1, (127 if n_gears is None else n_gears)
        if value != int(value) or not lo <= value <= hi:
            raise CommandError(f'must be an integer gear in -1..{hi}, got {value:g}', malformed=False)
        return value
    if not 0.0 <= value <= 1.0:
        raise CommandError(f'must be in 0..1, got {value:g}', malformed=False)
    return value


@dataclass(frozen=True)
class CommandPlan:
    """A schedule sampled at the exchange steps 0..n_steps of h_ns; see the module docstring.
    ``steps[k]``: the (channel, value) samples published for step k, in
    :data:`CHANNEL_TOPICS` order."""

    h_ns: int
    steps: dict[int, tuple[tuple[str, float], ...]]
    channels: tuple[str, ...]

    @classmethod
    def from_schedule(cls, schedule: Any, h_ns: int, n_steps: int) -> CommandPlan:
        """``schedule``: a :class:`cvj_ros.physics.hybrid.commands.CommandSchedule`."""
        played = tuple(c for c in CHANNEL_TOPICS if schedule.has(c))
        steps: dict[int, tuple[tuple[str, float], ...]] = {}
        last: dict[str, float] = {}
        for k in range(n_steps + 1):
            t = k * h_ns / NS_PER_S
            row = []
            for c in played:
                v = float(schedule.gear(t)) if c == 'gear' else float(schedule.value(c, t))
                if last.get(c) != v:
                    row.append((c, v))
                    last[c] = v
            if row:
                steps[k] = tuple(row)
        return cls(h_ns, steps, played)

    @classmethod
    def from_scene(cls, scene: Any, h_ns: int, n_steps: int) -> CommandPlan:
        from cvj_ros.physics.hybrid.commands import CommandSchedule
        schedule = CommandSchedule([(r['t'], {k: v for k, v in r.items() if k != 't'})
                                    for r in scene.commands])
        return cls.from_schedule(schedule, h_ns, n_steps)

    def at(self, k: int) -> tuple[tuple[str, float], ...]:
        """Samples of step k (empty when nothing changes)."""
        return self.steps.get(k, ())

    def __iter__(self) -> Iterator[tuple[int, tuple[tuple[str, float], ...]]]:
        return iter(sorted(self.steps.items()))

    def stamps(self, channel: str) -> list[int]:
        """Step times t_k (integer ns) of the samples of ``channel``, in the order the driver
        publishes them: the n-th sample on its topic belongs to step ``stamps[n] / h``."""
        return [k * self.h_ns for k, row in sorted(self.steps.items())
                for c, _v in row if c == channel]

    def record_stamps(self) -> dict[str, list[int]]:
        """Topic -> :meth:`stamps` of every played channel: the record times of a run's
        command samples (:meth:`cvj_ros.bag.BagRecorder.set_command_stamps`)."""
        return {CHANNEL_TOPICS[c]: self.stamps(c) for c in self.channels}


def throttle_scale_stamps(scene: Any, h_ns: int, n_steps: int) -> dict[str, list[int]]:
    """``{THROTTLE_SCALE_TOPIC: [t_0 .. t_N]}`` (ns) for a scene with a shift schedule (the
    coupling node publishes the throttle scale of every step k before the state t_k in
    lockstep: the n-th sample belongs to step n), else ``{}``."""
    if getattr(scene, 'shift_schedule', None) is None:
        return {}
    return {THROTTLE_SCALE_TOPIC: [k * h_ns for k in range(n_steps + 1)]}
