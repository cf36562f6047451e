"""cvj-sim record --until-idle: idle time counts only while the recorder runs, so a process
starved of the CPU for seconds does not take its own pause for the end of the run."""
from __future__ import annotations

import pytest

from cvj_ros.commands.record import IDLE_TICK_MAX_S, IdleClock


def test_idle_counts_polls_not_wall_gaps() -> None:
    clock = IdleClock()
    assert clock.tick(0.0, 0.0) == 0.0          # no message yet: never idle
    assert clock.tick(5.0, 0.0) == 0.0
    clock.tick(5.0, 4.9)                        # first message
    t = 5.0
    for _ in range(10):                         # 10 polls of 20 ms: 0.2 s idle
        t += 0.02
        idle = clock.tick(t, 4.9)
    assert idle == pytest.approx(0.2)
    assert clock.tick(t + 3.0, 4.9) == pytest.approx(0.2 + IDLE_TICK_MAX_S)   # starved 3 s
    assert clock.tick(t + 3.02, 8.0) == 0.0    # a new message resets it


def test_loop_topics_behind_the_joint_states_hold_the_stop() -> None:
    from cvj_ros.commands.record import BEHIND_WAIT_S, behind_topics, idle_stop
    stamps = {'/driveline/joint_states': 300, '/clock': 300, '/engine/wrench': 239,
              '/coupling/cpl/wrench': 240, '/load/wrench': 300, '/load/front_left/wrench': 10,
              '/diagnostics': 100, '/driveline/scene': 0, '/engine/throttle': 5}
    # /diagnostics, the scene and the commands are not one-per-exchange topics
    assert behind_topics(stamps) == ['/coupling/cpl/wrench', '/engine/wrench', '/load/front_left/wrench']
    assert behind_topics({'/clock': 5}) == []          # no joint state yet: nothing to compare
    # the coupling node's own topics can lag too: the answers say how far the run went
    assert behind_topics({'/driveline/joint_states': 268, '/clock': 268, '/engine/wrench': 300,
                          '/diagnostics': 268}) == ['/clock', '/driveline/joint_states']
    behind = behind_topics(stamps)
    assert not idle_stop(2.0, 2.0, behind)             # S reached, answers still on the way
    assert not idle_stop(2.0 + BEHIND_WAIT_S - 0.1, 2.0, behind)
    assert idle_stop(2.0 + BEHIND_WAIT_S, 2.0, behind)  # bounded: a peer that stopped early
    assert idle_stop(2.0, 2.0, [])
    assert not idle_stop(1.9, 2.0, [])



def test_run_end_gives_the_newest_stamp_with_the_topics_behind_it() -> None:
    """The end-of-run note prints each behind topic's stamp and the run's newest stamp: the
    newest over the joint states and loop topics only (a later /diagnostics stamp is not)."""
    from cvj_ros.commands.record import run_end
    stamps = {'/driveline/joint_states': 300, '/clock': 300, '/engine/wrench': 239,
              '/load/wrench': 300, '/diagnostics': 400, '/driveline/scene': 0}
    assert run_end(stamps) == (300, {'/engine/wrench': 239})
    assert run_end({'/clock': 5, '/engine/wrench': 4}) == (0, {})   # no joint state yet


def test_loop_topics_and_one_publisher_topics_share_the_exchange_wrenches() -> None:
    """commands/record.loop_topic (one message per exchange) and the recorder's
    one-publisher set differ on purpose, and share bag.exchange_wrench_topic."""
    from cvj_ros.bag import _one_publisher_topic, exchange_wrench_topic
    from cvj_ros.commands.record import loop_topic
    for topic in ('/engine/wrench', '/load/wrench', '/coupling/tripod/wrench', '/load/front_left/wrench'):
        assert exchange_wrench_topic(topic) and loop_topic(topic) and _one_publisher_topic(topic)
    assert loop_topic('/clock') and not _one_publisher_topic('/clock')
    for topic in ('/driveline/scene', '/engine/throttle_scale', '/driveline/joint_states'):
        assert _one_publisher_topic(topic) and not loop_topic(topic)
    for topic in ('/diagnostics', '/engine/throttle', '/driveline/recorder_ready'):
        assert not loop_topic(topic) and not _one_publisher_topic(topic)
