"""Round-trip measurements (cvj_ros.nodes.roundtrip): in-process and inter-process.

No timing assertions: the figures depend on the machine. Checked: the measurement
completes with the requested count, its statistics are ordered and positive, the echo
processes end, and bad arguments are rejected naming the argument.
"""
from __future__ import annotations

import math

import pytest

from cvj_ros.nodes.roundtrip import (main, measure_round_trip, measure_round_trip_ipc,
                                     measure_round_trip_peers)


def _check_stats(r: dict, n: int) -> None:
    assert r['n'] == n
    for key in ('us_mean', 'us_p50', 'us_p95'):
        assert math.isfinite(r[key]) and r[key] > 0.0
    assert r['us_p50'] <= r['us_p95']


@pytest.mark.parametrize('echoes', [1, 2])
def test_inter_process_round_trip_completes(echoes: int) -> None:
    r = measure_round_trip_ipc(60, 'events', echoes=echoes, warmup=10, timeout=60.0)
    _check_stats(r, 60)
    assert r['echoes'] == echoes and r['processes'] == echoes + 1
    assert r['executor'] == 'events'


def test_in_process_round_trip_completes() -> None:
    _check_stats(measure_round_trip(60, 'events', warmup=10), 60)


@pytest.mark.parametrize('peers', [1, 2])
def test_in_process_round_trip_with_answering_peers_completes(peers: int) -> None:
    """The composed loop's topology (issue 10): a round trip ends when every peer answered."""
    r = measure_round_trip_peers(60, peers, warmup=10)
    _check_stats(r, 60)
    assert r['peers'] == peers
    with pytest.raises(ValueError, match='^peers:'):
        measure_round_trip_peers(10, 0)


@pytest.mark.parametrize(('kwargs', 'field'), [
    ({'n': 0}, 'n:'), ({'executor': 'multi'}, 'executor:'), ({'echoes': 0}, 'echoes:'),
])
def test_bad_arguments_name_the_argument(kwargs: dict, field: str) -> None:
    args = {'n': 10, 'executor': 'events'} | kwargs
    with pytest.raises(ValueError, match=f'^{field}'):
        measure_round_trip_ipc(**args)


def test_echo_usage_error(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(['echo', '/only_one_topic']) == 2
    assert 'expected PING_TOPIC PONG_TOPIC EXECUTOR' in capsys.readouterr().err


def test_run_profile_keeps_the_dds_event_thread_out_of_every_sample() -> None:
    """The run's Fast DDS profile (cvj_ros.nodes.qos: NACK suppression 20 ms) stops every
    sample sent to a reader in another process from waking the writer's event thread. With
    Fast DDS's default 0 each answer of an echo process restarts the idle nack-suppression
    timer: >= 1 wake of its event thread per round trip (measured: 2.0-2.9 per round trip
    with the default, 0.07-0.09 with the profile). With 20 ms the event thread wakes only on
    time: its writer's heartbeat and nack-suppression timers and its reader's heartbeat
    response, each at most once per 20 ms, and the 0.25 s announcements - under 250 per
    second. Bound per round trip: 0.5 + 250/s x the mean round trip (0.55 at 200 us; on a
    machine so slow that a round trip takes ms the time-driven wakes are allowed for)."""
    r = measure_round_trip_ipc(400, 'events', echoes=1, warmup=20, timeout=60.0)
    if r['event_thread_wakes'] is None:
        pytest.skip('no Fast DDS event thread visible in /proc (other RMW or not Linux)')
    assert r['event_thread_wakes'] < 0.5 + 250.0 * r['us_mean'] * 1e-6, r
