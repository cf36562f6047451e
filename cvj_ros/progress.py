"""A progress line for long work (`cvj-sim run`, `simulate`, `bench`).

One line, rewritten in place with a carriage return, at most once per ``interval`` (1 s
wall) and only when the stream is a terminal: piped or redirected output (logs, CI, JSON
on stdout) stays exactly as before. Two kinds:

* simulated time (``unit='s'``): ``t=12.3/60 s simulated (20%), real-time factor 1.02,
  ETA 47 s`` - real-time factor = simulated seconds per wall second since the first
  update, ETA = remaining simulated time / that factor;
* a count (any other ``unit``, e.g. ``'runs'``): ``12/140 runs (9%), ETA 3 min 5 s`` -
  ETA = remaining count x mean wall time per item so far.

The clock (``time.monotonic`` by default) and the stream are injectable, so the rate limit
and the TTY rule are tested without waiting or a terminal (test/test_progress.py).
"""
from __future__ import annotations

import sys
import time
from collections.abc import Callable
from typing import TextIO


def format_duration(seconds: float) -> str:
    """``47 s``, ``3 min 5 s``, ``2 h 01 min`` (wall seconds, rounded)."""
    s = int(round(max(seconds, 0.0)))
    if s < 60:
        return f'{s} s'
    if s < 3600:
        return f'{s // 60} min {s % 60} s'
    return f'{s // 3600} h {(s % 3600) // 60:02d} min'


def is_terminal(stream: TextIO) -> bool:
    """True when ``stream`` is an interactive terminal (``isatty()``; False if it has none)."""
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError):   # no isatty, or a closed file
        return False


class Progress:
    """Progress of ``total`` units of work on ``stream`` (see the module docstring).

    Args:
        total: simulated seconds (``unit='s'``) or number of items.
        label: prefix of the line, e.g. ``'cvj-sim run'``.
        unit: ``'s'`` for simulated time, else the name of the counted items.
        stream: where the line goes (default ``sys.stderr``).
        clock: wall clock in seconds (default :attr:`default_clock`, ``time.monotonic``).
        interval: least wall seconds between two lines (default 1 s).
        enabled: force on/off; default: on exactly when ``stream`` is a terminal.
    """

    default_clock: Callable[[], float] = staticmethod(time.monotonic)   # tests replace it

    def __init__(self, total: float, *, label: str, unit: str = 's', stream: TextIO | None = None,
                 clock: Callable[[], float] | None = None, interval: float = 1.0,
                 enabled: bool | None = None) -> None:
        self.total = float(total)
        self.label = label
        self.unit = unit
        self.stream = sys.stderr if stream is None else stream
        self.clock = Progress.default_clock if clock is None else clock
        self.interval = interval
        self.enabled = is_terminal(self.stream) if enabled is None else enabled
        self._t0: float | None = None       # wall time of the first update
        self._next = 0.0                    # earliest wall time of the next line
        self._width = 0                     # length of the line on screen (0 = none shown)
        self.lines = 0                      # lines written so far

    def text(self, done: float, now: float) -> str:
        """The progress line for ``done`` units at wall time ``now`` (s)."""
        assert self._t0 is not None
        wall = now - self._t0
        frac = min(max(done / self.total, 0.0), 1.0) if self.total > 0 else 1.0
        if self.unit == 's':
            head = f'{self.label}: t={done:.4g}/{self.total:.4g} s simulated ({100 * frac:.0f}%)'
            rate = done / wall if wall > 0 and done > 0 else None
            if rate is None:
                return head
            eta = (self.total - done) / rate
            return f'{head}, real-time factor {rate:.3g}, ETA {format_duration(eta)}'
        head = f'{self.label}: {done:g}/{self.total:g} {self.unit} ({100 * frac:.0f}%)'
        if done <= 0 or wall <= 0:
            return head
        return f'{head}, ETA {format_duration((self.total - done) * wall / done)}'

    def update(self, done: float) -> None:
        """Report ``done`` units; writes a line if enabled and ``interval`` s passed since the last."""
        if not self.enabled:
            return
        now = self.clock()
        if self._t0 is None:
            self._t0 = now
            self._next = now + self.interval   # the first line after one interval: no flash
            return
        if now < self._next:
            return
        self._next = now + self.interval
        line = self.text(done, now)
        pad = max(self._width - len(line), 0)
        self.stream.write('\r' + line + ' ' * pad)
        self.stream.flush()
        self._width = len(line)
        self.lines += 1

    def clear(self) -> None:
        """Erase the line on screen (before other output, and at the end)."""
        if self._width:
            self.stream.write('\r' + ' ' * self._width + '\r')
            self.stream.flush()
            self._width = 0

    close = clear
