"""Free-run scheduling: wall-clock ticks at the exchange step, catch-up policy, lateness.

Pure Python (no ROS), driven by any monotonic nanosecond clock, so the logic is tested
with a fake clock (test/nodes/test_freerun_scheduler.py); the coupling node runs it with
``time.monotonic_ns`` (CLOCK_MONOTONIC, the clock of its steady-time wake-up timer).

Schedule. The loop starts at wall time ``w0`` (ns). Tick j (j = 1..N) is due at
``w0 + j h`` and advances simulated time from t_(j-1) = (j-1) h to t_j = j h, so simulated
time tracks wall time: at the wall instant the state t_j is published, wall time since
``w0`` minus t_j (the *drift*, s) is that tick's lateness plus the work done for it. Ticks
run before the clock starts (``start(now, ticks_done)``: the coupling node's first exchange)
count as run on time, and the clock is set so that the last of them was due at ``now``.

Lateness of a tick = wall time at which its work starts - its due time (ns, >= 0 as the
scheduler never starts a tick before it is due). A tick whose lateness is at least one
exchange step h started after the next tick was already due: it is an *overrun*. Every
tick is accounted exactly once, run or skipped: ``ticks_run + ticks_skipped == ticks
handled``, and ``overruns`` counts each tick late by >= h, skipped ones included (a
skipped tick's lateness is taken when it is dropped).

Catch-up when a wake-up finds n > 1 ticks due (the process was descheduled, stopped, or a
step took longer than h):

* ``skip``: the n - 1 oldest are dropped (counted in ``ticks_skipped``) and one exchange
  step of n h integrates straight to the newest due time (torques held over it), so
  simulated time jumps to wall time at once; the peers are not asked at the skipped times.
* ``burst``: the missed ticks run one by one back to back (each publishes its state; the
  torques are those last received, the peers' answers to burst states arrive after the
  burst), re-reading the clock before each; after ``burst_max`` ticks in one wake-up the
  remaining backlog is skipped as above. The burst bound keeps a long stall (seconds) from
  turning into seconds of back-to-back steps during which no answer is read.

Lateness quantiles come from :class:`LatenessHistogram` (log bins, 100 per decade: the
reported p50/p99 is the upper edge of the bin holding the quantile, at most 2.3 % above
the exact order statistic, and never above the exact maximum).
"""
from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

CATCH_UP_POLICIES = ('skip', 'burst')

NS_PER_US = 1_000


class LatenessHistogram:
    """Streaming lateness statistics (ns in, us out): count, mean, max, quantiles.

    Bins: one for lateness < 1 us, then 100 log-spaced bins per decade from 1 us to 1000 s
    (bin edges 10**(i/100) us, relative width 10**0.01 - 1 = 2.3 %), one for larger values.
    Adding a sample costs one log10 (about 1 us in CPython); memory is fixed (902 ints).
    """

    PER_DECADE = 100
    DECADES = 9          # 1 us .. 1e9 us = 1000 s

    def __init__(self) -> None:
        self.counts = [0] * (self.PER_DECADE * self.DECADES + 2)
        self.n = 0
        self.sum_ns = 0
        self.max_ns = 0

    def add(self, lateness_ns: int) -> None:
        """Record one tick's lateness (ns; negative values count as 0)."""
        lateness_ns = max(int(lateness_ns), 0)
        self.n += 1
        self.sum_ns += lateness_ns
        if lateness_ns > self.max_ns:
            self.max_ns = lateness_ns
        us = lateness_ns / NS_PER_US
        if us < 1.0:
            i = 0
        else:
            i = 1 + int(math.log10(us) * self.PER_DECADE)
            i = min(i, len(self.counts) - 1)
        self.counts[i] += 1

    def _upper_edge_us(self, i: int) -> float:
        return 1.0 if i == 0 else 10.0 ** (i / self.PER_DECADE)

    def quantile_us(self, q: float) -> float:
        """Upper bound (us) of the q-quantile (0 < q <= 1; order statistic ceil(q n)),
        within one bin (<= 2.3 %) of the exact value and capped at the exact maximum;
        0 before the first sample."""
        if self.n == 0:
            return 0.0
        rank = max(1, math.ceil(q * self.n))
        seen = 0
        for i, c in enumerate(self.counts):
            seen += c
            if seen >= rank:
                return min(self._upper_edge_us(i), self.max_ns / NS_PER_US)
        return self.max_ns / NS_PER_US

    def mean_us(self) -> float:
        return self.sum_ns / self.n / NS_PER_US if self.n else 0.0


@dataclass
class Step:
    """One exchange step the loop must run now.

    Attributes:
        ticks: exchange steps of h it spans (1, or n > 1 when n - 1 ticks were skipped).
        lateness_ns: lateness of the tick it completes (its start - its due time, ns).
    """
    ticks: int
    lateness_ns: int


class FreeRunScheduler:
    """Which exchange steps to run when (see module docstring for the policy).

    Use: :meth:`start` once, then on every wake-up call :meth:`next_step` with the current
    clock reading, run the returned step, and call again until it returns None.

    Args:
        period_ns: exchange step h (ns, >= 1).
        total_ticks: N, the number of ticks of the run (simulated duration / h).
        catch_up: ``'skip'`` or ``'burst'``.
        burst_max: burst: most ticks run back to back in one wake-up (>= 1).
    """

    def __init__(self, period_ns: int, total_ticks: int, *, catch_up: str = 'skip',
                 burst_max: int = 10) -> None:
        if catch_up not in CATCH_UP_POLICIES:
            raise ValueError(f'catch_up: must be one of {", ".join(CATCH_UP_POLICIES)}, got {catch_up!r}')
        if period_ns < 1 or total_ticks < 1 or burst_max < 1:
            raise ValueError('period_ns, total_ticks and burst_max must be >= 1')
        self.period_ns = int(period_ns)
        self.total_ticks = int(total_ticks)
        self.catch_up = catch_up
        self.burst_max = int(burst_max)
        self.start_ns: int | None = None
        self.done = 0              # ticks handled (run or skipped) = simulated time / h
        self.ticks_run = 0         # ticks whose state was computed on their own (steps of h)
        self.ticks_skipped = 0
        self.overruns = 0          # ticks late by >= h (skipped ones included)
        self.steps = 0             # exchange steps run (a skip jump is one step)
        self.wakeups = 0
        self.lateness = LatenessHistogram()
        self.drift_ns = 0          # wall since start - simulated time, at the last publication
        self.drift_max_ns = 0      # largest |drift| seen
        self._in_burst = 0         # ticks run back to back in the current wake-up

    def start(self, now_ns: int, ticks_done: int = 0) -> None:
        """Start the clock: tick j is due at ``now_ns + (j - ticks_done) h``.

        ``ticks_done`` ticks (at most all) already ran before the clock started, each on its
        own with lateness 0 (the coupling node runs the first exchange as soon as the
        answers to the initial state are in, and starts the clock when its state goes out),
        so the last of them is due at ``now_ns``. With 0, step 0 (the initial state) goes
        out at ``now_ns``."""
        ticks_done = min(max(int(ticks_done), 0), self.total_ticks)
        self.start_ns = int(now_ns) - ticks_done * self.period_ns
        for _ in range(ticks_done):
            self.lateness.add(0)
        self.done = self.ticks_run = self.steps = ticks_done

    def due_ns(self, tick: int) -> int:
        """Wall time (ns) at which tick ``tick`` (1-based) is due."""
        assert self.start_ns is not None, 'start() first'
        return self.start_ns + tick * self.period_ns

    def due_count(self, now_ns: int) -> int:
        """Ticks due by ``now_ns`` and not handled yet (never past the last tick)."""
        assert self.start_ns is not None, 'start() first'
        elapsed = now_ns - self.start_ns
        due_total = min(elapsed // self.period_ns, self.total_ticks) if elapsed >= 0 else 0
        return max(int(due_total) - self.done, 0)

    def finished(self) -> bool:
        return self.done >= self.total_ticks

    def begin_wakeup(self) -> None:
        """A timer wake-up begins (resets the burst budget)."""
        self.wakeups += 1
        self._in_burst = 0

    def next_step(self, now_ns: int) -> Step | None:
        """The step to run at ``now_ns``, or None when no tick is due (wake-up over).

        Accounts the lateness of every tick it hands out or skips."""
        n = self.due_count(now_ns)
        if n == 0:
            return None
        if self.catch_up == 'burst' and (n == 1 or self._in_burst < self.burst_max):
            ticks = 1                       # the oldest due tick on its own
        else:
            ticks = n                       # skip the n - 1 oldest, jump to the newest
            if self.catch_up == 'burst':
                self._in_burst = self.burst_max   # budget spent: the wake-up ends after this
        first = self.done + 1
        for j in range(first, first + ticks):
            late = now_ns - self.due_ns(j)
            self.lateness.add(late)
            if late >= self.period_ns:
                self.overruns += 1
        self.ticks_skipped += ticks - 1
        self.ticks_run += 1
        self.steps += 1
        self._in_burst += 1
        self.done += ticks
        return Step(ticks=ticks, lateness_ns=max(now_ns - self.due_ns(self.done), 0))

    def published(self, now_ns: int) -> None:
        """The state of the last step went out at ``now_ns``: update the drift."""
        assert self.start_ns is not None, 'start() first'
        self.drift_ns = (now_ns - self.start_ns) - self.done * self.period_ns
        self.drift_max_ns = max(self.drift_max_ns, abs(self.drift_ns))

    def stats(self) -> dict[str, float | int | str]:
        """Counters and lateness/drift figures for /diagnostics (us, s as named)."""
        lat = self.lateness
        return {
            'catch_up': self.catch_up, 'ticks_handled': self.done, 'ticks_run': self.ticks_run,
            'ticks_skipped': self.ticks_skipped, 'overruns': self.overruns,
            'lateness_us_p50': lat.quantile_us(0.5), 'lateness_us_p99': lat.quantile_us(0.99),
            'lateness_us_max': lat.max_ns / NS_PER_US, 'lateness_us_mean': lat.mean_us(),
            'drift_s': self.drift_ns / 1e9, 'drift_max_s': self.drift_max_ns / 1e9,
        }


def run_wakeup(scheduler: FreeRunScheduler, clock: Callable[[], int],
               run_step: Callable[[Step], bool]) -> int:
    """One timer wake-up: hand out and run steps until none is due (or ``run_step`` returns
    False, e.g. the run ended or failed). ``run_step`` integrates, publishes the state and
    calls :meth:`FreeRunScheduler.published` with the publication time. Returns the
    number of steps run."""
    scheduler.begin_wakeup()
    n = 0
    while not scheduler.finished():
        step = scheduler.next_step(clock())
        if step is None:
            break
        ok = run_step(step)      # publishes the state and calls scheduler.published()
        n += 1
        if not ok:
            break
    return n
