"""coupling_node's recorder gate (``record_lag_max``): the loop never publishes a state more
than record_lag_max past what the run's recorder reports on /driveline/recorded, goes on as
the recorder catches up, and stops with one line naming the topic when it stops reporting."""
from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

rclpy = pytest.importorskip('rclpy')
from rosgraph_msgs.msg import Clock  # noqa: E402

from cvj_ros.nodes.qos import LATCHED_QOS, RECORDED_TOPIC  # noqa: E402

_spec = importlib.util.spec_from_file_location('_coupling_tests', Path(__file__).with_name('test_coupling_node.py'))
_cn = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(_cn)

pytestmark = pytest.mark.ros

H_NS = 1_000_000          # the two-mass scene's exchange step (test_coupling_node.scene_file)
LAG_S = 0.005             # 5 steps


class GatedPeers(_cn.FakePeers):
    """Engine, load and a recorder that reports the newest joint-state stamp it has seen on
    /driveline/recorded every REPORT_S of wall time (a writer flushing periodically), until
    it has reported ``stop_after`` times. ``excess`` collects, per joint state, how far its
    stamp is past the last value reported before it arrived (ns)."""

    REPORT_S = 0.02
    stop_after = 10**9

    def __init__(self, ctx, behave=None):
        super().__init__(ctx, behave)
        self.recorded_pub = self.node.create_publisher(Clock, RECORDED_TOPIC, LATCHED_QOS)
        self.reported = -1
        self.reports = 0
        self.excess: list[int] = []
        self.node.create_timer(self.REPORT_S, self._report)

    def _on_js(self, msg):
        self.excess.append(_cn.ns(msg.header.stamp) - max(self.reported, 0))
        super()._on_js(msg)

    def _report(self):
        if not self.js or self.reports >= self.stop_after:
            return
        newest = _cn.ns(self.js[-1].header.stamp)
        if newest > self.reported:
            c = Clock()
            c.clock.sec, c.clock.nanosec = divmod(newest, 1_000_000_000)
            self.recorded_pub.publish(c)
            self.reported = newest
            self.reports += 1


def test_the_loop_stays_within_record_lag_max_of_what_is_recorded(ctx, tmp_path):
    # 0.02 s of 1 ms steps with a 5-step lead: the loop must wait for the recorder's reports
    node, peers, _ = _cn.run(ctx, tmp_path, peers_cls=GatedPeers, record_lag_max=LAG_S, timeout=20.0)
    assert node.exit_code == 0 and len(peers.js) == 21
    # every state went out at most record_lag_max past the last report sent before it (the
    # node can only have seen that one or an older one)
    assert max(peers.excess) <= int(LAG_S * 1e9), peers.excess
    stats = node.loop_stats()
    assert stats['record_waits'] >= 2 and stats['record_wait_us_mean'] > 0
    # the momentum balance of the ungated loop holds: the gate changes when, not what
    last = peers.js[-1]
    momentum = _cn.J1 * last.velocity[0] + _cn.J2 * last.velocity[1]
    assert momentum == pytest.approx((_cn.J1 + _cn.J2) * _cn.W0 + (_cn.T_ENGINE - _cn.T_LOAD) * 0.02,
                                     rel=1e-8)


class SilentRecorder(GatedPeers):
    stop_after = 1          # one report, then nothing: a recorder that died


def test_a_recorder_that_stops_reporting_stops_the_loop_naming_the_topic(ctx, tmp_path):
    node, peers, wall = _cn.run(ctx, tmp_path, peers_cls=SilentRecorder, record_lag_max=LAG_S,
                                peer_timeout=0.3, timeout=20.0)
    assert node.exit_code == 1
    assert RECORDED_TOPIC in node.error_message and 'peer_timeout=0.3' in node.error_message
    assert 'record_lag_max=0.005' in node.error_message
    assert len(peers.js) < 21


def test_no_gate_by_default(ctx, tmp_path):
    node, peers, _ = _cn.run(ctx, tmp_path)
    assert node.exit_code == 0 and node.recorded_sub is None and len(peers.js) == 21
    assert 'record_waits' not in node.loop_stats()
