"""The separate-process recorder's front (cvj_ros/orchestrate/recorder.py, recorder_front): it
asks its writer for a flush at every hand-off that brings loop messages past the disk, so what
/driveline/recorded reports follows each wake of the take loop. With a flush only once the
hand-off was 0.1 s past the disk, the disk fell up to that plus a wake (0.05 s of record time
at 2.5x real time) behind the loop, and the coupling node's gate (record_lag_max = 0.15 s)
held an unloaded loop every few wakes."""
from __future__ import annotations

from cvj_ros import bag as bagmod
from cvj_ros.orchestrate.recorder import GATE_TOPICS, RECORDER_COALESCE_S, recorder_front

MS = 1_000_000


class _Writer:
    """What a BatchingWriter uses of a BagWriter; records the hand-offs and flush requests."""

    def __init__(self) -> None:
        self.durable_ns = -1
        self.durable_topics: dict[str, int] = {}
        self.calls: list[str] = []

    def add_topic(self, topic: str, msgtype: str | None = None) -> None:
        pass

    def write_batch(self, items: list[tuple[str, int, bytes]]) -> None:
        self.calls.append('batch')

    def request_flush(self) -> None:
        self.calls.append('flush')
        # as the writer thread would once it has flushed
        self.durable_topics = dict(self._newest)
        self.durable_ns = max(self._newest.values())


def test_every_hand_off_of_loop_messages_asks_for_a_flush() -> None:
    w = _Writer()
    front = recorder_front(w)
    topics = sorted(GATE_TOPICS)
    for t in topics:
        front.add_topic(t)
    # wakes 20 ms of record time apart (RECORDER_COALESCE_S of wall time at 1x real time),
    # each taking the loop messages of 20 exchange steps of 1 ms
    assert RECORDER_COALESCE_S == 0.02
    step = 0
    for wake in range(6):
        w._newest = {}
        items = []
        for _ in range(20):
            step += 1
            for t in topics:
                items.append((t, step * MS, b''))
                w._newest[t] = step * MS
        front.write_many(items)
        front.flush()                       # the end of the wake (BagRecorder.spin)
        assert w.calls[-2:] == ['batch', 'flush'], (wake, w.calls)
        # the disk then holds the wake's newest loop messages: the gate's lead is this wake's
        assert min(w.durable_topics[t] for t in GATE_TOPICS) == step * MS
    assert w.calls.count('flush') == 6
    assert front.flush_lag_ns is not None and front.flush_lag_ns < bagmod.MAX_LAG_S * 1e9


class _FlushingWriter:
    """The writer side of ``_Recorder._report_recorded``: a script of flushes, each one the
    durable_topics it leaves; ``wait_flush`` hands out the next one only when asked for a flush
    beyond those seen, and records what it was asked."""

    def __init__(self, flushes: list[dict[str, int]]) -> None:
        self.script = flushes
        self.flushes = 0
        self.durable_topics: dict[str, int] = {}
        self.durable_ns = -1
        self.asked: list[int] = []
        self._thread = self            # is_alive()
        self.stop: object = None

    def is_alive(self) -> bool:
        return True

    def wait_flush(self, seen: int, timeout: float) -> int:
        self.asked.append(seen)
        if seen < self.flushes:        # a flush it has not seen yet: at once
            return self.flushes
        if self.flushes == len(self.script):
            self.stop.set()            # nothing more: end the loop
            return self.flushes
        self.durable_topics = self.script[self.flushes]
        self.durable_ns = max(self.durable_topics.values())
        self.flushes += 1
        return self.flushes


def test_recorded_thread_waits_for_each_next_flush_and_reports_the_oldest_loop_topic() -> None:
    """/clock is flushed ahead of the answers (its stamp is the newest): the thread must still
    ask for the flush after the last one it has seen each time (a real writer then blocks),
    never spin on a stamp that is already in, and publish the oldest loop topic's stamp once
    per advance."""
    import threading
    from types import SimpleNamespace

    from cvj_ros.orchestrate.recorder import _Recorder
    loop = {t: 0 for t in GATE_TOPICS}
    script = []
    for k in (1, 2, 2, 3):       # the third flush moves /clock only: nothing new to report
        script.append({**loop, **{t: k * MS for t in GATE_TOPICS if t != '/load/wrench'},
                       '/load/wrench': (k - 1) * MS, '/clock': (k + 1) * MS})
    w = _FlushingWriter(script)
    published: list[int] = []
    stop = threading.Event()
    w.stop = stop
    fake = SimpleNamespace(_stop=stop, ctx=SimpleNamespace(ok=lambda: True), writer=w,
                           recorded_pub=SimpleNamespace(publish=lambda m: published.append(
                               m.clock.sec * 1_000_000_000 + m.clock.nanosec)))
    _Recorder._report_recorded(fake)
    assert w.asked == [0, 1, 2, 3, 4]          # each wait: for a flush beyond those seen
    assert published == [0, 1 * MS, 2 * MS]    # the oldest loop topic (/load/wrench), per advance
