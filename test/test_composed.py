"""The composed container's timed spins (cvj_ros.composed.ComposedDriveline._spin)."""
from __future__ import annotations

import time

import pytest

pytest.importorskip('rclpy')


@pytest.mark.parametrize('executor', ['events', 'single'])
def test_timed_spins_reuse_one_timer(ctx, executor: str) -> None:
    """A spin per progress tick must not leave anything behind: a timer created and destroyed
    per spin keeps a weak reference in the node's callback group (and native memory in
    rclpy), which over an hour of 0.25 s ticks, and the many more short spins of a busy
    EventsExecutor, grows the run. The container re-arms one timer instead."""
    from cvj_ros.composed import ComposedDriveline
    comp = ComposedDriveline(ctx, executor=executor)
    try:
        group = comp._container.default_callback_group
        comp.spin_for(0.002)
        entities, timers = len(group.entities), len(list(comp._container.timers))
        t0 = time.monotonic()
        for _ in range(50):
            comp.spin_for(0.002)
        assert time.monotonic() - t0 >= 50 * 0.002 * 0.9     # each spin lasted its period
        assert len(group.entities) == entities
        assert len(list(comp._container.timers)) == timers
        comp.spin_for(0.003)               # another period: the old timer goes, one new one
        assert len(list(comp._container.timers)) == timers
    finally:
        comp.executor.shutdown()
        comp._container.destroy_node()


def test_auto_executor_is_events_for_short_runs_and_single_for_long_ones() -> None:
    """``--executor auto``: the faster EventsExecutor up to AUTO_EVENTS_MAX_EXCHANGES, the
    SingleThreadedExecutor (flat memory) beyond and for a container without an end, saying
    so; an explicit choice is kept."""
    from cvj_ros.composed import AUTO_EVENTS_MAX_EXCHANGES, resolve_executor
    assert resolve_executor('auto', 5000) == ('events', None)
    assert resolve_executor('auto', AUTO_EVENTS_MAX_EXCHANGES) == ('events', None)
    kind, note = resolve_executor('auto', AUTO_EVENTS_MAX_EXCHANGES + 1)
    assert kind == 'single' and f'for {AUTO_EVENTS_MAX_EXCHANGES + 1} exchanges' in note
    assert resolve_executor('auto', None)[0] == 'single'
    assert resolve_executor('events', 10 ** 7) == ('events', None)
    assert resolve_executor('single', 10) == ('single', None)
