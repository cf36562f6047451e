"""`_Recorder.host` (cvj_ros/orchestrate/recorder.py): the observers `cvj-sim run` hosts in its
own process, on the recorder's context - a hosted monitor is fed the joint states the recorder
takes (no DDS reader of its own), publishes its statuses and the recorder records them; a bad
parameter is the node's one-line CvjError; a failing callback ends only that node (its feed
stops, the recorder goes on) and is reported as its exit status 1."""
from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import pytest

from cvj_ros import bag as bagmod
from cvj_ros.errors import CvjError
from cvj_ros.nodes.qos import DIAGNOSTICS_TOPIC as DIAGNOSTICS
from cvj_ros.orchestrate.recorder import HOSTED_IN_RUN, _Recorder

NAMES = ['drive_shaft', 'driven_shaft']


def _publisher(domain: int) -> tuple[Any, Any, Any]:
    import rclpy
    from rclpy.context import Context
    from rclpy.signals import SignalHandlerOptions
    from sensor_msgs.msg import JointState

    from cvj_ros.nodes.qos import DATA_QOS, JOINT_STATES_TOPIC
    ctx = Context()
    rclpy.init(context=ctx, domain_id=domain, signal_handler_options=SignalHandlerOptions.NO)
    node = rclpy.create_node('fake_coupling', context=ctx)
    return ctx, node, node.create_publisher(JointState, JOINT_STATES_TOPIC, DATA_QOS)


def _joint_state(k: int) -> Any:
    from sensor_msgs.msg import JointState
    msg = JointState()
    msg.header.stamp.sec, msg.header.stamp.nanosec = 0, k * 1_000_000
    msg.header.frame_id = 'driveline'
    msg.name = NAMES
    msg.position = [0.1 * k, 0.1 * k]
    msg.velocity = [100.0 + (k % 3), 100.0]
    msg.effort = [5.0, 5.0]
    return msg


def _wait(cond: Any, timeout: float = 10.0) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if cond():
            return True
        time.sleep(0.02)
    return cond()


def _run_hosted(tmp_path: Path, domain: int, n: int,
                done: Any = None) -> tuple[dict[str, int], _Recorder]:
    import rclpy
    writer = bagmod.BagWriter(tmp_path / 'bag', storage='mcap')
    rec = _Recorder(writer, [], domain)
    ctx = None
    try:
        rec.host('monitor_node', ['--ros-args', '-p', 'publish_every:=10'], log=tmp_path / 'monitor_node.log')
        ctx, node, pub = _publisher(domain)
        # the recorder's reader, matched from both sides (another participant: the writer's
        # count alone does not say the reader knows the writer, and it drops samples until then)
        assert _wait(lambda: pub.get_subscription_count() >= 1
                     and rec.publisher_count(bagmod.JOINT_STATES_TOPIC) >= 1)
        time.sleep(0.2)
        assert pub.get_subscription_count() == 1      # the monitor's is fed by it: no reader of its own
        for k in range(n):
            pub.publish(_joint_state(k))
        _wait(lambda: rec.recorder.counts.get(DIAGNOSTICS, 0) >= n // 10
              and rec.recorder.counts.get(bagmod.JOINT_STATES_TOPIC, 0) >= n
              and (done is None or done(rec)))
        node.destroy_node()
    finally:
        if ctx is not None and ctx.ok():
            rclpy.shutdown(context=ctx)
        rec.close()
        writer.close()
    return dict(writer.counts), rec


def test_hosted_monitor_reads_joint_states_and_its_statuses_are_recorded(tmp_path: Path, ros_domain: int) -> None:
    assert HOSTED_IN_RUN == ('monitor_node',)
    counts, rec = _run_hosted(tmp_path, ros_domain, 30)
    assert counts[bagmod.JOINT_STATES_TOPIC] == 30
    assert counts[DIAGNOSTICS] == 3                  # one per 10 samples
    diags = bagmod.read_bag(tmp_path / 'bag', [DIAGNOSTICS])[DIAGNOSTICS]
    names = {st['name'] for statuses in diags.statuses for st in statuses}
    assert {f'monitor: {n}' for n in NAMES} <= names               # the monitor's, per shaft
    assert rec.hosted_exit_codes() == {'monitor_node': 0} and rec.host_errors == {}
    assert not any(t.is_alive() for t in rec._hosted_threads)     # close() ended the node's thread


def test_bad_parameter_is_the_nodes_one_line_error(tmp_path: Path, ros_domain: int) -> None:
    writer = bagmod.BagWriter(tmp_path / 'bag', storage='mcap')
    rec = _Recorder(writer, [], ros_domain)
    try:
        with pytest.raises(CvjError, match='^window'):
            rec.host('monitor_node', ['--ros-args', '-p', 'window:=-1.0'])
        assert rec.hosted == {}
    finally:
        rec.close()
        writer.close()


def test_failing_callback_ends_the_node_thread_with_exit_status_1(
        tmp_path: Path, ros_domain: int, monkeypatch: pytest.MonkeyPatch) -> None:
    from cvj_ros.nodes import monitor_node

    def broken(self: Any, data: bytes) -> None:
        raise RuntimeError('monitor broke')
    monkeypatch.setattr(monitor_node.MonitorNode, '_on_joint_states_raw', broken)
    counts, rec = _run_hosted(tmp_path, ros_domain, 5, done=lambda rec: rec.host_errors)
    assert counts[bagmod.JOINT_STATES_TOPIC] == 5                 # the recorder went on
    assert rec.host_errors == {'monitor_node': 'monitor_node: RuntimeError: monitor broke'}
    assert rec.hosted_exit_codes() == {'monitor_node': 1}
    assert 'RuntimeError: monitor broke' in (tmp_path / 'monitor_node.log').read_text()
    assert rec.recorder.observers.get(bagmod.JOINT_STATES_TOPIC) == []   # its feed stopped
