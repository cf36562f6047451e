"""JointStateDecoder against rclpy's own serialiser: every field bit for bit, for name and
frame lengths that exercise every alignment (1-9 characters), empty sequences, NaN/inf."""
from __future__ import annotations

import math

import pytest

pytest.importorskip('rclpy')
from rclpy.serialization import serialize_message  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402

from cvj_ros.nodes.cdr import JointStateDecoder  # noqa: E402


def _msg(frame: str, names: list[str], n_eff: int | None = None) -> JointState:
    m = JointState()
    m.header.stamp.sec, m.header.stamp.nanosec = 12, 345_000_001
    m.header.frame_id = frame
    m.name = names
    k = len(names)
    m.position = [0.1 * i - 1e300 for i in range(k)]
    m.velocity = [math.pi * (i + 1) for i in range(k)]
    m.effort = [(-1.0) ** i * 7.5 for i in range(k if n_eff is None else n_eff)]
    return m


CASES = [_msg('driveline', ['crank', 'cpl_input', 'cpl_output', 'driven']),
         _msg('driveline@0123abcd', ['a', 'bb', 'ccc', 'dddd', 'eeeee', 'ffffff', 'ggggggg', 'hhhhhhhh', 'iiiiiiiii']),
         _msg('', []),
         _msg('x', ['only'], n_eff=0),
         _msg('fr', ['s1', 's2'])]


@pytest.mark.parametrize('msg', CASES, ids=lambda m: f'{m.header.frame_id or "empty"}-{len(m.name)}')
def test_decoder_matches_rclpy(msg: JointState) -> None:
    dec = JointStateDecoder()
    for _ in range(2):        # second pass: the cached name list
        v = dec.decode(serialize_message(msg))
        assert (v.header.stamp.sec, v.header.stamp.nanosec) == (12, 345_000_001)
        assert v.header.frame_id == msg.header.frame_id
        assert v.name == list(msg.name)
        for field in ('position', 'velocity', 'effort'):
            assert list(getattr(v, field)) == list(getattr(msg, field)), field   # exact


def test_decoder_nonfinite_and_name_change() -> None:
    dec = JointStateDecoder()
    m = _msg('d', ['a', 'b'])
    m.velocity = [math.nan, math.inf]
    v = dec.decode(serialize_message(m))
    assert math.isnan(v.velocity[0]) and v.velocity[1] == math.inf
    v2 = dec.decode(serialize_message(_msg('d', ['a', 'c'])))
    assert v2.name == ['a', 'c']


def test_one_decoder_across_changing_frames_and_names() -> None:
    """The fast path (frame_id and name bytes compared with the previous sample's) switches
    correctly between frames of other lengths (other name offsets), name lists that extend
    one another, and back."""
    seq = CASES + [_msg('d', ['a', 'b']), _msg('d', ['a', 'b', 'c']), _msg('longer_frame', ['a', 'b']),
                   _msg('d', ['a', 'b'])] + CASES[::-1]
    dec = JointStateDecoder()
    for msg in seq + seq:
        v = dec.decode(serialize_message(msg))
        assert v.header.frame_id == msg.header.frame_id
        assert v.name == list(msg.name)
        for field in ('position', 'velocity', 'effort'):
            assert list(getattr(v, field)) == list(getattr(msg, field)), field
