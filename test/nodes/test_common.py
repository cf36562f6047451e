"""CDR encoders of cvj_ros.nodes.common against rclpy's own (de)serialiser, an independent
implementation: same length and the same decoded message for stamps, frame ids and names
of every padding length, and special float values."""
from __future__ import annotations

import math

import numpy as np
import pytest

pytest.importorskip('rclpy')
from geometry_msgs.msg import WrenchStamped  # noqa: E402
from rclpy.serialization import deserialize_message, serialize_message  # noqa: E402
from rosgraph_msgs.msg import Clock  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402

from cvj_ros.nodes.common import ClockEncoder, JointStateEncoder, WrenchStampedEncoder  # noqa: E402


@pytest.mark.parametrize('frame_id', ['', 'a', 'ab', 'abc', 'abcd', 'engine_crank', 'tripod_housing', 'w\u00e4lle'])
def test_wrench_encoder_matches_rclpy(frame_id: str) -> None:
    enc = WrenchStampedEncoder(frame_id)
    assert enc.ok
    values = (1e-300, -0.0, 3.5, math.inf, -2.25e6, 7.0)
    data = enc.encode(2_147_483_647, 999_999_999, *values)
    ref = WrenchStamped()
    ref.header.stamp.sec, ref.header.stamp.nanosec = 2_147_483_647, 999_999_999
    ref.header.frame_id = frame_id
    f, t = ref.wrench.force, ref.wrench.torque
    f.x, f.y, f.z, t.x, t.y, t.z = values
    assert len(data) == len(serialize_message(ref))
    assert deserialize_message(data, WrenchStamped) == ref


@pytest.mark.parametrize('names', [['x'], ['ab', 'c'], ['drive_shaft', 'coupling_input', 'coupling_earring',
                                                        'coupling_output', 'driven_shaft'],
                                   [f's{"_" * i}' for i in range(9)]])
def test_joint_state_encoder_matches_rclpy(names: list[str]) -> None:
    enc = JointStateEncoder(names)
    assert enc.ok
    rng = np.random.default_rng(len(names))
    pos, vel, eff = rng.normal(size=(3, len(names))) * 1e3
    data = enc.encode(17, 250_000_000, pos, vel, eff)
    ref = JointState()
    ref.header.stamp.sec, ref.header.stamp.nanosec = 17, 250_000_000
    ref.name = names
    ref.position, ref.velocity, ref.effort = pos.tolist(), vel.tolist(), eff.tolist()
    assert len(data) == len(serialize_message(ref))
    got = deserialize_message(data, JointState)
    assert got == ref
    assert list(got.position) == pos.tolist()   # bit-exact doubles


def test_clock_encoder_matches_rclpy() -> None:
    enc = ClockEncoder()
    assert enc.ok
    ref = Clock()
    ref.clock.sec, ref.clock.nanosec = 3, 1_000_000
    assert deserialize_message(enc.encode(3, 1_000_000), Clock) == ref
    assert len(enc.encode(3, 1_000_000)) == len(serialize_message(ref))


@pytest.mark.parametrize('frame_id', ['', 'a', 'abc', 'abcd', 'engine_crank', 'wheel_x'])
@pytest.mark.parametrize('torque', [123.456, -0.0, math.nan, -math.inf])
def test_wrench_decoder_reads_rclpy_serialisation(frame_id: str, torque: float) -> None:
    """Stamp and torque.z read from bytes serialised by rclpy (not by our encoder)."""
    from cvj_ros.nodes.common import decode_wrench_stamp_torque_z
    msg = WrenchStamped()
    msg.header.stamp.sec, msg.header.stamp.nanosec = 7, 3_000_001
    msg.header.frame_id = frame_id
    msg.wrench.force.z, msg.wrench.torque.y, msg.wrench.torque.z = 9.0, -8.0, torque
    stamp_ns, value = decode_wrench_stamp_torque_z(serialize_message(msg))
    assert stamp_ns == 7_003_000_001
    assert (math.isnan(value) and math.isnan(torque)) or (value == torque and
                                                           math.copysign(1, value) == math.copysign(1, torque))
