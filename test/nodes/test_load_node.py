"""load_node in-process: load model torque at the output shaft speed, echoed stamp, frame id,
recorded time-series override, parameter errors naming the parameter."""
from __future__ import annotations

import math
import time

import numpy as np
import pytest
import yaml

rclpy = pytest.importorskip('rclpy')
from geometry_msgs.msg import WrenchStamped  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402

from cvj_ros.nodes.common import ParameterError, make_executor, ns_to_stamp  # noqa: E402
from cvj_ros.nodes.load_node import LoadNode  # noqa: E402
from cvj_ros.nodes.qos import DATA_QOS  # noqa: E402

pytestmark = pytest.mark.ros

MC, SCALE = 107.5, 2.0     # constant load with tanh sign: T = Mc tanh(omega / scale)


def scene_file(tmp_path) -> str:
    data = {
        'name': 'two_mass_test', 'duration': 0.05, 'exchange_step': 0.001,
        'engine': {'model': 'linear'},
        'load': {'model': 'constant', 'torque': MC, 'speed_scale': SCALE},
        'driveline': [{'type': 'inertia', 'name': 'engine_crank', 'J': 0.128},
                      {'type': 'spring', 'name': 'shaft', 'stiffness': 715.4, 'damping': 6.35},
                      {'type': 'inertia', 'name': 'wheel', 'J': 0.161}],
    }
    path = tmp_path / 'scene.yaml'
    path.write_text(yaml.safe_dump(data))
    return str(path)


def exchange(ctx, node, samples):
    """Publish joint states (ns, omega of 'wheel'), return the answers."""
    peer = rclpy.create_node('peer', context=ctx)
    pub = peer.create_publisher(JointState, '/driveline/joint_states', DATA_QOS)
    got: list[WrenchStamped] = []
    peer.create_subscription(WrenchStamped, '/load/wrench', got.append, DATA_QOS)
    ex = make_executor('events', ctx)
    ex.add_node(peer)
    ex.add_node(node)
    try:
        deadline = time.monotonic() + 5
        while pub.get_subscription_count() < 1 or node.wrench_pub.get_subscription_count() < 1:
            assert time.monotonic() < deadline
            ex.spin_once(timeout_sec=0.02)
        for ns, omega in samples:
            msg = JointState()
            msg.header.stamp = ns_to_stamp(ns)
            msg.name = ['engine_crank', 'wheel']
            msg.position, msg.velocity, msg.effort = [0.0, 1.0], [99.0, omega], [0.0, 0.0]
            pub.publish(msg)
        while len(got) < len(samples):
            assert time.monotonic() < deadline
            ex.spin_once(timeout_sec=0.02)
    finally:
        ex.shutdown()
        peer.destroy_node()
    return got


def test_answers_resisting_torque_of_output_shaft(ctx, tmp_path):
    node = LoadNode(context=ctx, parameter_overrides=[Parameter('scene', value=scene_file(tmp_path))])
    samples = [(0, 0.0), (1_000_000, 1.0), (3_000_000_007, -4.0)]
    try:
        got = exchange(ctx, node, samples)
    finally:
        node.destroy_node()
    for (ns, omega), w in zip(samples, got):
        assert w.header.stamp.sec * 10**9 + w.header.stamp.nanosec == ns
        assert w.header.frame_id == 'wheel'
        assert w.wrench.torque.z == pytest.approx(MC * math.tanh(omega / SCALE), rel=1e-12, abs=1e-12)


def test_load_override_time_series(ctx, tmp_path):
    series = tmp_path / 'torque.npz'
    np.savez(series, t=np.array([0.0, 1.0, 2.0]), torque=np.array([10.0, 30.0, 30.0]))
    node = LoadNode(context=ctx, parameter_overrides=[Parameter('scene', value=scene_file(tmp_path)),
                                                      Parameter('load_override', value=str(series))])
    try:
        got = exchange(ctx, node, [(250_000_000, 5.0), (1_500_000_000, 5.0)])
    finally:
        node.destroy_node()
    # linear interpolation between samples: 10 + 20 * 0.25 at t = 0.25 s; 30 at 1.5 s
    assert got[0].wrench.torque.z == pytest.approx(15.0)
    assert got[1].wrench.torque.z == pytest.approx(30.0)


def test_bad_parameters_name_the_parameter(ctx, tmp_path):
    bad_series = tmp_path / 'bad.yaml'
    bad_series.write_text(yaml.safe_dump({'t': [0.0, 2.0, 1.0], 'torque': [1.0, 2.0, 3.0]}))
    cases = [('load_override', str(tmp_path / 'missing.npz')), ('load_override', str(bad_series)),
             ('load_spec', '{model: konstant}'), ('seed', -3)]
    for name, value in cases:
        with pytest.raises(ParameterError) as err:
            LoadNode(context=ctx, parameter_overrides=[Parameter('scene', value=scene_file(tmp_path)),
                                                       Parameter(name, value=value)])
        assert str(err.value).startswith(f'{name}:'), str(err.value)
