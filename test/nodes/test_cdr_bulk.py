"""The bulk and in-place CDR readers and the DiagnosticArray encoder/decoder against rclpy's
own serialiser: blocks of joint states and wrenches read at once give every sample's fields
bit for bit, anything that is not one layout is refused (None: read one by one), the shaft
reader follows layout changes, and DiagnosticArray bytes round-trip through rclpy."""
from __future__ import annotations

import math

import numpy as np
import pytest

pytest.importorskip('rclpy')
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue  # noqa: E402
from geometry_msgs.msg import WrenchStamped  # noqa: E402
from rclpy.serialization import deserialize_message, serialize_message  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402

from cvj_ros.nodes.cdr import (DiagnosticArrayEncoder, JointStateDecoder,  # noqa: E402
                               ShaftReader, decode_diagnostic_array, read_joint_state_block,
                               read_wrench_torque_z_block)


def _js(k: int, *, frame: str = 'driveline@0123abcd', names: list[str] | None = None,
        n_eff: int | None = None) -> bytes:
    m = JointState()
    m.header.stamp.sec, m.header.stamp.nanosec = k // 7 - 2, (k * 123_456_789) % 1_000_000_000
    m.header.frame_id = frame
    m.name = names if names is not None else ['crank', 'cpl_input', 'x', 'driven_shaft_5']
    n = len(m.name)
    m.position = [0.1 * k * (i + 1) - 1e300 * (k == 3 and i == 0) for i in range(n)]
    m.velocity = [math.pi * (i + 1) + k if not (k == 5 and i == 1) else math.nan for i in range(n)]
    m.effort = [(-1.0) ** i * 7.5 * k for i in range(n if n_eff is None else n_eff)]
    return serialize_message(m)


def _wrench(k: int, frame: str = 'driven_shaft@0123abcd') -> bytes:
    m = WrenchStamped()
    m.header.stamp.sec, m.header.stamp.nanosec = k, 1000 * k + 7
    m.header.frame_id = frame
    m.wrench.force.x, m.wrench.torque.y, m.wrench.torque.z = 1.0, 2.0, -3.5 * k + 0.125
    return serialize_message(m)


@pytest.mark.parametrize('frame', ['', 'd', 'driveline', 'driveline@0123abcd'])
def test_joint_state_block_is_every_sample_bit_for_bit(frame: str) -> None:
    batch = [_js(k, frame=frame) for k in range(12)]
    block = read_joint_state_block(batch, JointStateDecoder())
    assert block is not None
    assert block.frame_id == frame and block.name == ['crank', 'cpl_input', 'x', 'driven_shaft_5']
    for k, data in enumerate(batch):
        m = deserialize_message(data, JointState)
        assert block.stamp_ns[k] == m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec
        for field in ('position', 'velocity', 'effort'):
            np.testing.assert_array_equal(getattr(block, field)[k], np.array(getattr(m, field)))


def test_joint_state_block_refuses_mixed_layouts() -> None:
    dec = JointStateDecoder()
    base = [_js(k) for k in range(4)]
    assert read_joint_state_block(base, dec) is not None
    assert read_joint_state_block([], dec) is None
    # another frame of the same length, other names, short effort, big-endian-like flag
    assert read_joint_state_block(base + [_js(9, frame='driveline@9999abcd')], dec) is None
    assert read_joint_state_block(base + [_js(9, names=['crank', 'cpl_input', 'y', 'driven_shaft_5'])],
                                  dec) is None
    assert read_joint_state_block(base + [_js(9, n_eff=2)], dec) is None
    assert read_joint_state_block([_js(1, n_eff=2)], dec) is None
    flipped = bytearray(base[0])
    flipped[1] = 0
    assert read_joint_state_block([bytes(flipped)], dec) is None


def test_wrench_block_and_refusals() -> None:
    batch = [_wrench(k) for k in range(9)]
    got = read_wrench_torque_z_block(batch)
    assert got is not None
    stamp_ns, frame, z = got
    assert frame == b'driven_shaft@0123abcd'
    assert list(stamp_ns) == [k * 1_000_000_000 + 1000 * k + 7 for k in range(9)]
    assert list(z) == [-3.5 * k + 0.125 for k in range(9)]
    assert read_wrench_torque_z_block(batch + [_wrench(1, 'driven_shaft@9999abcd')]) is None
    assert read_wrench_torque_z_block(batch + [_wrench(1, 'engine')]) is None
    assert read_wrench_torque_z_block([]) is None


def test_shaft_reader_follows_layouts_and_refuses_what_it_cannot_read() -> None:
    reader = ShaftReader('x')
    for data in [_js(k) for k in range(3)] + [_js(4, frame='')] + [_js(6, names=['x', 'a'])]:
        m = deserialize_message(data, JointState)
        i = list(m.name).index('x')
        sec, nanosec, frame, pos, vel = reader.read(data)
        assert (sec, nanosec, frame) == (m.header.stamp.sec, m.header.stamp.nanosec, m.header.frame_id)
        assert (pos, vel) == (m.position[i], m.velocity[i])
    assert reader.read(_js(1, names=['a', 'b'])) is None           # no such shaft
    assert reader.read(_js(1, n_eff=1)) is None                    # short effort array
    assert ShaftReader('crank').read(_js(3))[3] == -1e300


def _diag() -> DiagnosticArray:
    msg = DiagnosticArray()
    msg.header.stamp.sec, msg.header.stamp.nanosec = 17, 999_999_999
    msg.header.frame_id = 'monitor_node@0123abcd'
    msg.status = [
        DiagnosticStatus(level=DiagnosticStatus.WARN, name='monitor: crank', message='nonuniformity 0.12',
                         hardware_id='cvj_ros', values=[KeyValue(key='speed_mean_rad_s', value='104.7'),
                                                        KeyValue(key='samples', value='1001')]),
        DiagnosticStatus(level=DiagnosticStatus.OK, name='é', message='', hardware_id='', values=[]),
        DiagnosticStatus(level=DiagnosticStatus.ERROR, name='abc', message='x' * 5, hardware_id='h',
                         values=[KeyValue(key='k' * i, value='v' * (7 - i)) for i in range(7)]),
    ]
    return msg


def _plain(msg: DiagnosticArray) -> list[tuple]:
    return [(st.level, st.name, st.message, st.hardware_id, [(kv.key, kv.value) for kv in st.values])
            for st in msg.status]


def test_diagnostic_array_encoder_round_trips_through_rclpy() -> None:
    enc = DiagnosticArrayEncoder()
    assert enc.ok
    msg = _diag()
    data = enc.encode(17 * 1_000_000_000 + 999_999_999, msg.header.frame_id, _plain(msg))
    assert len(data) == len(serialize_message(msg))
    assert deserialize_message(data, DiagnosticArray) == msg


def test_diagnostic_array_decoder_reads_rclpy_bytes() -> None:
    msg = _diag()
    stamp_ns, frame, statuses = decode_diagnostic_array(serialize_message(msg))
    assert stamp_ns == 17 * 1_000_000_000 + 999_999_999
    assert frame == msg.header.frame_id
    assert statuses == _plain(msg)


def test_blocks_ignore_alignment_padding() -> None:
    """rclpy leaves CDR alignment padding uninitialised: samples that differ only there are
    one layout (frame 'abc' + NUL ends at payload 8 + 4 + 4 = 16... padding after it)."""
    js = [bytearray(_js(k, frame='d')) for k in range(5)]      # 'd' + NUL: 2 padding bytes
    for k, data in enumerate(js):
        data[4 + 8 + 4 + 2] = k                                   # first padding byte
    block = read_joint_state_block([bytes(d) for d in js], JointStateDecoder())
    assert block is not None and block.frame_id == 'd'
    ws = [bytearray(_wrench(k, 'ab')) for k in range(5)]       # payload 8+4+3 = 15 -> pad to 16
    for k, data in enumerate(ws):
        data[4 + 15] = 100 + k
    got = read_wrench_torque_z_block([bytes(d) for d in ws])
    assert got is not None and got[1] == b'ab'
