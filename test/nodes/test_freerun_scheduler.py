"""Free-run scheduler (cvj_ros.nodes.freerun) with a fake clock, no ROS: every tick is
accounted once (run or skipped), every tick late by >= h is counted as an overrun, the
catch-up policies (skip, burst with its bound) and the drift bound; lateness quantiles
against numpy's exact order statistics."""
from __future__ import annotations

import math

import numpy as np
import pytest

from cvj_ros.nodes.freerun import FreeRunScheduler, LatenessHistogram, Step, run_wakeup

MS = 1_000_000   # ns
W0 = 123_456_789  # ns, arbitrary start of the fake monotonic clock


class FakeLoop:
    """A free-run loop on a fake clock: the timer wakes at the next due time (+ jitter),
    each step costs ``work_ns``, and after the step that completes tick j the process is
    stalled ``stalls[j]`` ns (SIGSTOP, descheduling). Logs every step handed out as
    (clock at hand-out, ticks, ticks done before it)."""

    def __init__(self, sched: FreeRunScheduler, *, work_ns: int = 0, jitter_ns: int = 0,
                 stalls: dict[int, int] | None = None) -> None:
        self.sched, self.work_ns, self.jitter_ns = sched, work_ns, jitter_ns
        self.stalls = dict(stalls or {})
        self.now = W0
        self.log: list[tuple[int, int, int]] = []
        self.drifts: list[int] = []

    def clock(self) -> int:
        return self.now

    def run_step(self, step: Step) -> bool:
        self.log.append((self.now, step.ticks, self.sched.done - step.ticks))
        self.now += self.work_ns
        self.sched.published(self.now)
        self.drifts.append(self.sched.drift_ns)
        self.now += self.stalls.pop(self.sched.done, 0)
        return True

    def run(self) -> None:
        self.sched.start(self.now)
        while not self.sched.finished():
            self.now = max(self.now, self.sched.due_ns(self.sched.done + 1) + self.jitter_ns)
            run_wakeup(self.sched, self.clock, self.run_step)

    def independent_overruns(self, h: int) -> int:
        """Ticks whose work started >= h after their due time W0 + j h, from the log."""
        late = 0
        for start, ticks, before in self.log:
            for j in range(before + 1, before + ticks + 1):
                late += start - (W0 + j * h) >= h
        return late


def check_accounting(loop: FakeLoop, n: int, h: int) -> None:
    s = loop.sched
    assert s.done == n and sum(t for _, t, _ in loop.log) == n       # simulated time = N h
    assert s.ticks_run + s.ticks_skipped == n == s.lateness.n        # every tick once
    assert s.ticks_run == len(loop.log) == s.steps
    assert s.overruns == loop.independent_overruns(h)


def test_on_time_wakeups_run_every_tick_without_overrun():
    h, n = 2 * MS, 500
    loop = FakeLoop(FreeRunScheduler(h, n), work_ns=300_000, jitter_ns=150_000)
    loop.run()
    check_accounting(loop, n, h)
    s = loop.sched
    assert s.ticks_skipped == 0 and s.overruns == 0
    # every tick starts 150 us late (the jitter): p50 = p99 = max = 150 us (bin edge capped at max)
    assert s.lateness.quantile_us(0.5) == pytest.approx(150.0)
    assert s.lateness.max_ns == 150_000
    assert s.drift_ns == 150_000 + 300_000            # lateness + work, exactly


@pytest.mark.parametrize('stall_ms, expected_skipped', [(200, 39), (202, 39), (7, 0), (10, 1)])
def test_skip_counts_every_tick_missed_in_a_stall(stall_ms, expected_skipped):
    # h = 5 ms, no work, wake-ups on time; stalled stall_ms after tick 100 (t = 0.5 s).
    # Closed form: the wake-up after the stall (at W0 + 100 h + S) finds floor(S / h) ticks
    # due; the floor(S / h) - 1 oldest are late by S - i h >= h and skipped, the newest is
    # late by S mod h < h and runs as one step of floor(S / h) h.
    h, n, stall = 5 * MS, 400, stall_ms * MS
    loop = FakeLoop(FreeRunScheduler(h, n, catch_up='skip'), stalls={100: stall})
    loop.run()
    check_accounting(loop, n, h)
    s = loop.sched
    due = stall // h
    assert s.ticks_skipped == max(due - 1, 0) == expected_skipped
    assert s.overruns == expected_skipped
    if due >= 1:
        jump = [t for _, t, before in loop.log if before == 100]
        assert jump == [due]                        # one step jumps to wall time
    # the worst lateness is the oldest missed tick's: S - h (or S when S < h... no tick then)
    if due >= 1:
        assert s.lateness.max_ns == stall - h
    assert max(loop.drifts) < h                     # drift at publication < h (no work)


def test_burst_runs_backlog_back_to_back_within_its_bound():
    # stall 30 ms at h = 5 ms: 6 ticks due, burst_max 10 -> all six run as steps of h
    h, n = 5 * MS, 200
    loop = FakeLoop(FreeRunScheduler(h, n, catch_up='burst', burst_max=10),
                    work_ns=100_000, stalls={50: 30 * MS})
    loop.run()
    check_accounting(loop, n, h)
    s = loop.sched
    assert s.ticks_skipped == 0 and all(t == 1 for _, t, _ in loop.log)
    # ticks 51..56 start at W0 + 50 h + 0.1 ms (work) + 30 ms + i * 0.1 ms: late by
    # 30.1 + 0.1 i - 5 (j - 50) ms -> ticks 51..55 late >= 5 ms, tick 56 late 0.6 ms
    assert s.overruns == 5


def test_burst_bound_then_skip_after_a_long_stall():
    # stall 200 ms at h = 5 ms with burst_max 10. The stall hits after tick 100 inside its
    # wake-up, which then has 9 single steps of budget left: ticks 101..109 run singly, then
    # one step jumps over the rest of the backlog to the tick due at wall time
    h, n = 5 * MS, 400
    loop = FakeLoop(FreeRunScheduler(h, n, catch_up='burst', burst_max=10),
                    work_ns=100_000, stalls={100: 200 * MS})
    loop.run()
    check_accounting(loop, n, h)
    s = loop.sched
    after = [t for _, t, before in loop.log if 100 <= before < 141]
    assert after[:9] == [1] * 9 and after[9] > 1
    assert sum(after[:10]) == 40            # the burst + the jump reach the tick due at wall time
    assert s.ticks_skipped == after[9] - 1 == 30
    assert s.overruns == 39                 # every tick of the backlog but the newest
    # drift during the burst: up to the stall (tick 101 goes out 200.2 ms after tick 100's
    # due time, i.e. 195.2 ms behind wall time); after the jump below h + the burst's work
    i_jump = [i for i, (_, t, before) in enumerate(loop.log) if before >= 100 and t > 1][0]
    assert max(loop.drifts) == 200 * MS + 2 * 100_000 - h
    assert loop.drifts[i_jump] < h + 10 * 100_000
    assert max(loop.drifts[i_jump:]) < h + 10 * 100_000


@pytest.mark.parametrize('catch_up', ['skip', 'burst'])
def test_steps_slower_than_real_time_keep_simulated_time_on_wall_time(catch_up):
    # every step costs 1.5 h: the loop cannot hold the rate; simulated time still tracks
    # wall time (drift at publication < h + work) and about a third of ticks is skipped
    h, n = 2 * MS, 3000
    loop = FakeLoop(FreeRunScheduler(h, n, catch_up=catch_up, burst_max=3), work_ns=3 * MS)
    loop.run()
    check_accounting(loop, n, h)
    s = loop.sched
    assert max(loop.drifts) <= 2 * h + 3 * MS
    wall = loop.now - W0
    assert abs(wall - n * h) <= 2 * h + 3 * MS      # the run ends at wall time ~ N h
    assert s.overruns > 0 and s.ticks_skipped > 0


def test_lateness_histogram_quantiles_match_exact_order_statistics():
    rng = np.random.default_rng(7)
    # lognormal lateness around 100 us with a heavy tail, plus exact zeros
    samples = np.concatenate([rng.lognormal(math.log(100e3), 1.0, 20000).astype(np.int64),
                              np.zeros(100, dtype=np.int64)])
    hist = LatenessHistogram()
    for v in samples:
        hist.add(int(v))
    srt = np.sort(samples)
    for q in (0.5, 0.9, 0.99, 0.999):
        exact_us = srt[math.ceil(q * samples.size) - 1] / 1e3
        got = hist.quantile_us(q)
        # upper bin edge: >= exact and at most one bin (10**0.01 = +2.33 %) above it
        assert exact_us <= got <= exact_us * 10 ** 0.01 + 1e-9
    assert hist.quantile_us(1.0) == hist.max_ns / 1e3 == srt[-1] / 1e3
    assert hist.mean_us() == pytest.approx(samples.mean() / 1e3)
    assert LatenessHistogram().quantile_us(0.99) == 0.0


def test_bad_arguments_raise():
    with pytest.raises(ValueError, match='catch_up'):
        FreeRunScheduler(MS, 10, catch_up='drop')
    with pytest.raises(ValueError):
        FreeRunScheduler(0, 10)


def test_start_with_ticks_done_accounts_them_run_on_time():
    """start(now, ticks_done=1): the first exchange ran before the clock started; it counts as
    run with lateness 0, and tick 2 is due one period after ``now``."""
    s = FreeRunScheduler(1_000, 5)
    s.start(50_000, ticks_done=1)
    assert (s.done, s.ticks_run, s.steps, s.lateness.n, s.lateness.max_ns) == (1, 1, 1, 1, 0)
    assert s.due_ns(2) == 51_000 and s.due_count(50_999) == 0 and s.due_count(51_000) == 1
    s.start(50_000, ticks_done=9)      # never more than the run's ticks
    assert s.finished() and s.done == 5
