"""Automated shift schedule (automated manual gearbox): when to shift and the shift sequence.

Rule. In gear g (1..N) the gearbox's *synchronous input speed* w_g = i_g omega_out (the
engine speed the gear imposes when the clutch is locked; independent of clutch slip, so a
slipping launch does not trigger it) is watched as a witness on the dense output: crossing
the up-shift speed U_g upwards starts g -> g+1 (g < N), crossing the down-shift speed D_g
downwards starts g -> g-1 (g > 1). The schedule is refused when it would hunt: after an
up-shift at U_g the new synchronous speed U_g i_{g+1}/i_g must lie above D_{g+1} (the same
inequality puts the speed after a down-shift at D_{g+1}, D_{g+1} i_g/i_{g+1}, below U_g).

Sequence from the trigger time t_s (open clutch -> neutral -> new ratio -> close clutch):
an envelope e(t) rises linearly 0 -> 1 over ``open_time``, holds 1 for ``neutral_time`` and
falls 1 -> 0 over ``close_time``; the effective clutch pedal is p + (1 - p) e and the
effective throttle x (1 - e) (p, x the commanded values); neutral is engaged at
t_s + open_time, the new gear at t_s + open_time + neutral_time, each a breakpoint. A new
shift starts only once the previous sequence has ended.
"""
from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from cvj_ros.errors import SceneError
from cvj_ros.physics.hybrid.commands import CommandSchedule

__all__ = ['SHIFT_KEYS', 'AutoShift', 'ShiftSchedule', 'check_no_gear_rows', 'parse_shift_schedule',
           'shift_schedule_dict']

SHIFT_KEYS = ('upshift_rpm', 'downshift_rpm', 'open_s', 'neutral_s', 'close_s', 'start_gear')
RPM = math.pi / 30.0


@dataclass(frozen=True)
class ShiftSchedule:
    """Up-shift speeds U_1..U_{N-1} and down-shift speeds D_2..D_N (rad/s, synchronous input
    speed), the sequence's open, neutral and close times (s) and the gear at t = 0."""

    upshift: tuple[float, ...]
    downshift: tuple[float, ...]
    open_time: float
    neutral_time: float
    close_time: float
    start_gear: int = 1

    @property
    def duration(self) -> float:
        """Time from the trigger to the clutch closed again (s)."""
        return self.open_time + self.neutral_time + self.close_time

    def up(self, gear: int) -> float | None:
        """U_gear (rad/s), None in the top gear."""
        return self.upshift[gear - 1] if 1 <= gear <= len(self.upshift) else None

    def down(self, gear: int) -> float | None:
        """D_gear (rad/s), None in 1st."""
        return self.downshift[gear - 2] if 2 <= gear <= len(self.downshift) + 1 else None


def _speeds(raw: Any, n: int, path: str) -> tuple[float, ...]:
    vals = raw if isinstance(raw, list) else [raw] * n
    if len(vals) != n:
        raise SceneError(path, f'must be one speed or a list of {n} (one per gear), got {len(vals)}')
    out = []
    for k, v in enumerate(vals):
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not (math.isfinite(v) and v > 0):
            raise SceneError(f'{path}[{k}]' if isinstance(raw, list) else path,
                             f'must be a speed > 0 (rpm), got {v!r}')
        out.append(float(v) * RPM)
    return tuple(out)


def parse_shift_schedule(raw: Any, gearbox: Any) -> ShiftSchedule:
    """``shift_schedule:`` {upshift_rpm, downshift_rpm (one value or one per gear), open_s,
    neutral_s, close_s, start_gear} against the gearbox's ratios (SceneError naming the
    field)."""
    from cvj_ros.physics.scene import _check_keys, _mapping, _number
    d = _mapping(raw, 'shift_schedule')
    _check_keys(d, SHIFT_KEYS, 'shift_schedule')
    if gearbox is None:
        raise SceneError('shift_schedule', 'the driveline has no gearbox')
    ratios = gearbox.ratios
    n = len(ratios)
    if n < 2:
        raise SceneError('shift_schedule', f'{gearbox.name} has one forward gear: nothing to shift')
    for key in ('upshift_rpm', 'downshift_rpm'):
        if key not in d:
            raise SceneError(f'shift_schedule.{key}', 'missing (rpm, synchronous input speed)')
    up = _speeds(d['upshift_rpm'], n - 1, 'shift_schedule.upshift_rpm')
    down = _speeds(d['downshift_rpm'], n - 1, 'shift_schedule.downshift_rpm')
    times = {k: _number(d.get(k, dflt), f'shift_schedule.{k}', positive=True, hi=10.0)
             for k, dflt in (('open_s', 0.1), ('neutral_s', 0.1), ('close_s', 0.4))}
    start = d.get('start_gear', 1)
    if isinstance(start, bool) or not isinstance(start, int) or not 1 <= start <= n:
        raise SceneError('shift_schedule.start_gear', f'must be a forward gear 1..{n}, got {start!r}')
    if max(up) * 1.0 > gearbox.max_input_speed:
        raise SceneError('shift_schedule.upshift_rpm', f'above the gearbox max_input_rpm '
                                                      f'{gearbox.max_input_speed / RPM:.0f}')
    for g in range(1, n):
        after_up = up[g - 1] * ratios[g] / ratios[g - 1]      # g -> g+1 at U_g
        if not after_up > down[g - 1]:
            raise SceneError('shift_schedule.downshift_rpm',
                             f'gear hunting: the up-shift {g} -> {g + 1} at {up[g - 1] / RPM:.0f} rpm '
                             f'lands at {after_up / RPM:.0f} rpm, not above gear {g + 1}\'s down-shift '
                             f'speed {down[g - 1] / RPM:.0f} rpm')
        # (the down-shift g+1 -> g at D_{g+1} then lands at D_{g+1} i_g/i_{g+1} < U_g: the
        # same inequality)
    return ShiftSchedule(up, down, times['open_s'], times['neutral_s'], times['close_s'], start)


def shift_schedule_dict(s: ShiftSchedule) -> dict[str, Any]:
    """Scene-file form (inverse of :func:`parse_shift_schedule`)."""
    return {'upshift_rpm': [u / RPM for u in s.upshift], 'downshift_rpm': [x / RPM for x in s.downshift],
            'open_s': s.open_time, 'neutral_s': s.neutral_time, 'close_s': s.close_time,
            'start_gear': s.start_gear}


class AutoShift:
    """A CommandSchedule with the shift schedule's sequences laid over it (module
    docstring): the same ``value``, ``gear``, ``has``, ``next_breakpoint`` interface."""

    def __init__(self, base: CommandSchedule, schedule: ShiftSchedule) -> None:
        self.base = base
        self.schedule = schedule
        self.gear_now = schedule.start_gear     # the gear outside a sequence
        self.seq: tuple[float, int, int] | None = None     # (t_start, from, to)
        self.shifts: list[tuple[float, int, int]] = []

    def start(self, t: float, to: int) -> None:
        """Begin the sequence gear_now -> ``to`` at t (s)."""
        self.seq = (t, self.gear_now, to)
        self.shifts.append(self.seq)

    def busy(self, t: float) -> bool:
        """A sequence is running at t."""
        return self.seq is not None and t < self.seq[0] + self.schedule.duration

    def envelope(self, t: float) -> float:
        """The sequence's envelope e(t) in 0..1 (module docstring; 0 outside a sequence)."""
        return self._envelope(t)

    def _envelope(self, t: float) -> float:
        if self.seq is None:
            return 0.0
        s = self.schedule
        tau = t - self.seq[0]
        if tau <= 0.0 or tau >= s.duration:
            return 0.0
        if tau < s.open_time:
            return tau / s.open_time
        if tau <= s.open_time + s.neutral_time:
            return 1.0
        return 1.0 - (tau - s.open_time - s.neutral_time) / s.close_time

    def has(self, channel: str) -> bool:
        return channel in ('throttle', 'clutch', 'gear') or self.base.has(channel)

    def value(self, channel: str, t: float, t_end: float = math.inf) -> float:
        v = self.base.value(channel, t, t_end)
        e = self._envelope(t)
        if channel == 'clutch':
            return v + (1.0 - v) * e
        if channel == 'throttle':
            return v * (1.0 - e)
        return v

    def gear(self, t: float) -> int:
        if self.seq is not None:
            t0, g_from, g_to = self.seq
            s = self.schedule
            if t >= t0 + s.open_time + s.neutral_time:
                self.gear_now = g_to
                return g_to
            if t >= t0 + s.open_time:
                return 0
            if t >= t0:
                return g_from
        return self.gear_now

    def next_breakpoint(self, t: float) -> float:
        nb = self.base.next_breakpoint(t)
        if self.seq is not None:
            t0, s = self.seq[0], self.schedule
            for tb in (t0 + s.open_time, t0 + s.open_time + s.neutral_time, t0 + s.duration):
                if tb > t:
                    nb = min(nb, tb)
        return nb


def check_no_gear_rows(rows: Sequence[Mapping[str, Any]]) -> None:
    """With a shift schedule the gear is the schedule's: a ``gear`` row is an error."""
    for i, r in enumerate(rows):
        if 'gear' in r:
            raise SceneError(f'commands[{i}].gear', 'the shift_schedule chooses the gear; give either '
                                                    'gear rows (step by step) or a shift_schedule')
