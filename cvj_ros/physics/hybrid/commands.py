"""Command schedule of a vehicle stack: time -> throttle, clutch, gear, brake.

Rows ``(t, {channel: value})`` in ascending time. ``throttle`` (0..1), ``clutch`` (pedal,
0 engaged .. 1 open) and ``brake`` (0..1 of capacity) are piecewise linear between the
rows that set them and held before the first and after the last; two rows at the same
time make a step (the later row holds from that time on; an integration segment that ends
on the step sees it from the left: ``Ramp.at``). ``gear`` (-1 reverse,
0 neutral, 1..N) is a step: the last row at or before t. Every row time is a breakpoint
of the integration (the inputs are smooth between rows).
"""
from __future__ import annotations

import bisect
import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass

from cvj_ros.errors import SceneError

__all__ = ['CHANNELS', 'CommandSchedule', 'Ramp']

CHANNELS = ('throttle', 'clutch', 'gear', 'brake')


@dataclass(frozen=True)
class Ramp:
    """Piecewise-linear channel through (times, values); held outside; 0 with no rows."""

    times: tuple[float, ...]
    values: tuple[float, ...]

    def __call__(self, t: float) -> float:
        ts = self.times
        if not ts:
            return 0.0
        k = bisect.bisect_right(ts, t)       # rows at or before t
        if k == 0:
            return self.values[0]
        if k == len(ts):
            return self.values[-1]
        t0, t1 = ts[k - 1], ts[k]
        v0, v1 = self.values[k - 1], self.values[k]
        return v0 + (v1 - v0) * (t - t0) / (t1 - t0)

    def at(self, t: float, t_end: float = math.inf) -> float:
        """The value at t (s) inside an integrated segment that ends at t_end (s): at or
        beyond t_end a jump there (two rows at t_end) is seen from the left, the value of
        its first row, so the segment's last stage and its witnesses see the command before
        the jump; otherwise the value at t."""
        ts = self.times
        if t >= t_end and ts:
            j = bisect.bisect_left(ts, t_end)
            if j + 1 < len(ts) and ts[j] == t_end and ts[j + 1] == t_end:
                return self.values[j]
        return self(t)


class CommandSchedule:
    """Validated schedule; see the module docstring. Errors name ``commands[i].<key>``."""

    def __init__(self, rows: Iterable[tuple[float, Mapping[str, float]]], *,
                 field: str = 'commands') -> None:
        series: dict[str, tuple[list[float], list[float]]] = {c: ([], []) for c in CHANNELS}
        last = -math.inf
        for i, (t, row) in enumerate(rows):
            path = f'{field}[{i}]'
            if isinstance(t, bool) or not isinstance(t, (int, float)) or not math.isfinite(t) or t < 0:
                raise SceneError(f'{path}.t', f'must be a finite time >= 0 s, got {t!r}')
            if t < last:
                raise SceneError(f'{path}.t', f'rows must be in ascending time, got {t} after {last}')
            last = float(t)
            for c, v in row.items():
                if c not in CHANNELS:
                    raise SceneError(f'{path}.{c}', f'unknown channel; one of {", ".join(CHANNELS)}')
                series[c][0].append(float(t))
                series[c][1].append(self._check(c, v, f'{path}.{c}'))
        self._gear_times = [t for t in series['gear'][0]]
        self._gear_values = [int(v) for v in series['gear'][1]]
        self.channels = {c: Ramp(tuple(series[c][0]), tuple(series[c][1]))
                         for c in ('throttle', 'clutch', 'brake')}
        self.breakpoints = sorted({t for c in CHANNELS for t in series[c][0]})

    @staticmethod
    def _check(channel: str, v: float, path: str) -> float:
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise SceneError(path, f'must be a finite number, got {v!r}')
        if channel == 'gear':
            if int(v) != v:
                raise SceneError(path, f'must be an integer gear (-1 reverse, 0 neutral, 1..N), got {v!r}')
            return float(v)
        if not 0.0 <= v <= 1.0:
            raise SceneError(path, f'must be in 0..1, got {v!r}')
        return float(v)

    def has(self, channel: str) -> bool:
        """A row sets ``channel``."""
        if channel == 'gear':
            return bool(self._gear_times)
        return bool(self.channels[channel].times)

    def value(self, channel: str, t: float, t_end: float = math.inf) -> float:
        """Channel ``throttle``, ``clutch`` or ``brake`` at t (s); inside a segment that ends
        at t_end, a jump at t_end seen from the left (:meth:`Ramp.at`)."""
        return self.channels[channel].at(t, t_end)

    def gear(self, t: float) -> int:
        """Commanded gear at t (s): the last row at or before t (0 before any)."""
        k = bisect.bisect_right(self._gear_times, t)
        return self._gear_values[k - 1] if k else 0

    def next_breakpoint(self, t: float) -> float:
        """First row time strictly after t (inf when none)."""
        k = bisect.bisect_right(self.breakpoints, t)
        return self.breakpoints[k] if k < len(self.breakpoints) else math.inf
