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
