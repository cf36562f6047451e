"""replay_node: raw bytes, own /clock, rate, topic selection, loop; CLI and executable errors."""
from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from cvj_ros import bag

pytestmark = pytest.mark.ros

N = 20
H_NS = 10_000_000  # 10 ms of simulated time per sample


def _make_bag(path: Path, *, foreign: bool = False) -> dict[str, list[bytes]]:
    """A bag of N steps; ``foreign``: another publisher's joint states (other names and sizes,
    one undecodable) interleaved on /driveline/joint_states, 4 in all (not in the result)."""
    ts = bag.typestore()
    Time = ts.types['builtin_interfaces/msg/Time']
    Header = ts.types['std_msgs/msg/Header']
    V = ts.types['geometry_msgs/msg/Vector3']
    W = ts.types['geometry_msgs/msg/Wrench']
    WS = ts.types['geometry_msgs/msg/WrenchStamped']
    JS = ts.types['sensor_msgs/msg/JointState']
    Clk = ts.types['rosgraph_msgs/msg/Clock']
    sent: dict[str, list[bytes]] = {'/load/wrench': [], '/driveline/joint_states': [], '/clock': []}
    with bag.BagWriter(path) as w:
        for topic in sent:
            w.add_topic(topic)
        for k in range(N):
            stamp = Time(sec=0, nanosec=k * H_NS)
            h = Header(stamp=stamp, frame_id='wheel')
            msgs = {
                '/clock': Clk(clock=stamp),
                '/driveline/joint_states': JS(header=h, name=['wheel'], position=np.array([0.1 * k]),
                                              velocity=np.array([5.0]), effort=np.array([1.0])),
                '/load/wrench': WS(header=h, wrench=W(force=V(x=0.0, y=0.0, z=0.0),
                                                      torque=V(x=0.0, y=0.0, z=float(k)))),
            }
            for topic, m in msgs.items():
                data = bytes(ts.serialize_cdr(m, bag.topic_type(topic)))
                sent[topic].append(data)
                w.write(topic, k * H_NS, data)
            if foreign and k % 5 == 2:
                other = JS(header=h, name=['intruder_0', 'intruder_1', 'intruder_2'],
                           position=np.zeros(3), velocity=np.ones(2), effort=np.zeros(0))
                data = bytes(ts.serialize_cdr(other, 'sensor_msgs/msg/JointState'))
                w.write('/driveline/joint_states', k * H_NS, data if k != 12 else data[:20] + b'\xff' * 8)
    return sent


def _replay(bag_path: Path, params: dict, *, until: int, timeout: float = 10.0):
    import rclpy
    from rclpy.parameter import Parameter
    from geometry_msgs.msg import WrenchStamped
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import JointState
    from cvj_ros.nodes.qos import DATA_QOS
    from cvj_ros.nodes.replay_node import ReplayNode

    got: dict[str, list[tuple[float, bytes]]] = {'/load/wrench': [], '/driveline/joint_states': [],
                                                 '/clock': []}
    ctx = rclpy.context.Context()
    rclpy.init(context=ctx)
    try:
        sub = rclpy.create_node('replay_sink', context=ctx)
        for topic, cls in (('/load/wrench', WrenchStamped), ('/driveline/joint_states', JointState),
                           ('/clock', Clock)):
            sub.create_subscription(cls, topic, lambda d, t=topic: got[t].append((time.monotonic(), d)),
                                    DATA_QOS, raw=True)
        overrides = [Parameter('bag', value=str(bag_path)), Parameter('start_delay', value=0.3)]
        overrides += [Parameter(k, value=v) for k, v in params.items()]
        node = ReplayNode(context=ctx, parameter_overrides=overrides)
        ex = rclpy.executors.SingleThreadedExecutor(context=ctx)
        ex.add_node(sub)
        ex.add_node(node)
        deadline = time.monotonic() + timeout
        while len(got['/load/wrench']) < until and time.monotonic() < deadline:
            ex.spin_once(timeout_sec=0.05)
        node.stop()
        node.join(3)
        for _ in range(5):
            ex.spin_once(timeout_sec=0.02)
        ex.shutdown()
        node.destroy_node()
        sub.destroy_node()
    finally:
        rclpy.shutdown(context=ctx)
    return got, node


def test_replay_publishes_raw_bytes_with_own_clock(tmp_path: Path) -> None:
    sent = _make_bag(tmp_path / 'b')
    got, node = _replay(tmp_path / 'b', {'rate': 1.0}, until=N)
    assert [d for _, d in got['/load/wrench']] == sent['/load/wrench']
    assert [d for _, d in got['/driveline/joint_states']] == sent['/driveline/joint_states']
    clocks = [bag.cdr_stamp_ns(d) for _, d in got['/clock']]
    assert clocks == [k * H_NS for k in range(N)]  # own clock: one per record time
    assert node.exit_code == 0 and node.messages_published == 2 * N
    # pacing at rate 1: first to last data message spans (N-1) * 10 ms = 0.19 s of wall time.
    # Lower bound: pacing never runs early (0.8: timer granularity). Upper bound: 0.1 s of
    # scheduling delay allowed (a loaded 2-core machine; measured < 0.03 s idle), still far
    # below what a pacing bug of 2x would give (0.38 s).
    span = got['/load/wrench'][-1][0] - got['/load/wrench'][0][0]
    assert 0.8 * (N - 1) * H_NS * 1e-9 < span < 0.19 + 0.1


def test_replay_leaves_out_another_publishers_joint_states(tmp_path: Path) -> None:
    """A bag with joint states of another layout interleaved (`cvj-sim record` on a busy
    domain) replays the run's messages only and names the rest in one line."""
    sent = _make_bag(tmp_path / 'b', foreign=True)
    got, node = _replay(tmp_path / 'b', {'rate': 4.0}, until=N)
    assert [d for _, d in got['/driveline/joint_states']] == sent['/driveline/joint_states']
    assert node.exit_code == 0 and node.foreign == {'/driveline/joint_states': 4}
    lines = [line for line in node.summary().splitlines() if 'not the run' in line]
    assert lines == ["replay: left out 4 messages not the run's (other joint names, undecodable): "
                     '4 on /driveline/joint_states']


def test_rate_and_topic_selection(tmp_path: Path) -> None:
    sent = _make_bag(tmp_path / 'b')
    got, _ = _replay(tmp_path / 'b', {'rate': 4.0, 'topics': ['/load/*']}, until=N)
    assert [d for _, d in got['/load/wrench']] == sent['/load/wrench']
    assert got['/driveline/joint_states'] == []
    span = got['/load/wrench'][-1][0] - got['/load/wrench'][0][0]
    # 4x faster than the 0.19 s of recorded time (0.0475 s); a rate ignored gives 0.19 s. Bound
    # between the two: 0.0475 s + 0.07 s of scheduling delay on a loaded machine.
    assert span < 0.19 / 4 + 0.07


def test_loop_starts_over(tmp_path: Path) -> None:
    sent = _make_bag(tmp_path / 'b')
    got, node = _replay(tmp_path / 'b', {'rate': 10.0, 'loop': True, 'topics': ['/load/wrench']},
                        until=2 * N + 3)
    data = [d for _, d in got['/load/wrench']]
    assert data[:2 * N] == sent['/load/wrench'] * 2
    assert node.loops >= 2


def test_bad_parameters_exit_2_naming_them(tmp_path: Path) -> None:
    from cvj_ros.cli import main
    _make_bag(tmp_path / 'b')
    exe = Path(sys.executable).with_name('replay_node')
    env = dict(os.environ)
    r = subprocess.run([str(exe), '--ros-args', '-p', f'bag:={tmp_path / "missing"}'],
                       capture_output=True, text=True, timeout=30, env=env)
    assert r.returncode == 2 and 'error: bag:' in r.stderr and 'no such bag' in r.stderr
    assert 'Traceback' not in r.stderr
    r = subprocess.run([str(exe), '--help'], capture_output=True, text=True, timeout=30)
    assert r.returncode == 0 and 'rate' in r.stdout
    assert main(['replay', str(tmp_path / 'missing')]) == 2
    assert main(['replay', str(tmp_path / 'b'), '--topics', '/engine/wrench']) == 2
    assert main(['replay', str(tmp_path / 'b'), '--rate', '0']) == 2


def test_replay_recorded_again_gives_the_same_bag(tmp_path: Path) -> None:
    """Bag -> replay_node -> BagRecorder (executor-free take loop) -> bag: identical messages and
    record times, including the latched scene and /clock (replay's own clock = record times)."""
    import threading

    import rclpy
    from rclpy.parameter import Parameter
    from cvj_ros.nodes.replay_node import ReplayNode

    _make_bag(tmp_path / 'a')
    ts = bag.typestore()
    scene = bytes(ts.serialize_cdr(ts.types['std_msgs/msg/String'](data='seed: 1\n'), 'std_msgs/msg/String'))
    with bag.BagWriter(tmp_path / 'src', storage='sqlite3') as w:  # a's messages plus a scene message
        for topic, msgtype, t, data in bag.read_raw(tmp_path / 'a'):
            w.add_topic(topic, msgtype)
            w.write(topic, t, data)
        w.add_topic('/driveline/scene')
        w.write('/driveline/scene', 0, scene)
    ctx = rclpy.context.Context()
    rclpy.init(context=ctx)
    stop = threading.Event()
    try:
        rec_node = rclpy.create_node('rec', context=ctx)
        writer = bag.BagWriter(tmp_path / 'copy')
        recorder = bag.BagRecorder(rec_node, writer)
        thread = threading.Thread(target=recorder.spin, args=(stop,), daemon=True)
        thread.start()
        node = ReplayNode(context=ctx, parameter_overrides=[
            Parameter('bag', value=str(tmp_path / 'src')), Parameter('start_delay', value=0.5),
            Parameter('rate', value=5.0)])
        node.join(10)
        assert node.exit_code == 0
        deadline = time.monotonic() + 5
        while sum(writer.counts.values()) < 3 * N + 1 and time.monotonic() < deadline:
            time.sleep(0.02)
        stop.set()
        thread.join(2)
        recorder.destroy()
        writer.close()
        node.destroy_node()
        rec_node.destroy_node()
    finally:
        stop.set()
        rclpy.shutdown(context=ctx)
    original = sorted((t, ts_, d) for t, _, ts_, d in bag.read_raw(tmp_path / 'src'))
    copy = sorted((t, ts_, d) for t, _, ts_, d in bag.read_raw(tmp_path / 'copy'))
    assert copy == original


def test_cvj_sim_replay_says_what_it_published(tmp_path: Path) -> None:
    """`cvj-sim replay` used to print nothing and exit 0 (issue 14): it now ends with one
    summary line (messages, topics, passes, bag-time span, wall time, rate) and a count per
    topic."""
    _make_bag(tmp_path / 'b')
    exe = Path(sys.executable).with_name('cvj-sim')
    r = subprocess.run([str(exe), 'replay', str(tmp_path / 'b'), '--rate', '10'],
                       capture_output=True, text=True, timeout=60, env=dict(os.environ))
    assert r.returncode == 0, r.stderr
    lines = r.stdout.strip().splitlines()
    assert lines[0].startswith(f'replay: published {2 * N} messages on 2 topics, 1 pass(es) over '
                               f'{(N - 1) * H_NS * 1e-9:.6g} s of bag time in '), lines
    assert lines[0].endswith('(rate 10x, /clock from the bag stamps)'), lines[0]
    assert sorted(line.split() for line in lines[1:]) == [['/driveline/joint_states', str(N)],
                                                          ['/load/wrench', str(N)]]
