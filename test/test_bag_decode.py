"""Batch decoding of a bag (cvj_ros.bag_decode through cvj_ros.bag.read_bag) against the
message-by-message rosbags path it replaced: the same arrays bit for bit on run-like bags in
both storages, with messages outside the common layout (another length, big-endian, another
frame), records out of time order across chunks, and the old errors kept."""
from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip('rclpy')
from geometry_msgs.msg import WrenchStamped  # noqa: E402
from rclpy.serialization import serialize_message  # noqa: E402
from rosgraph_msgs.msg import Clock  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402

from cvj_ros import bag, bag_decode  # noqa: E402
from cvj_ros.errors import BagError  # noqa: E402

NAMES = ['crank', 'cpl_input', 'cpl_output', 'wheel']


def _js(k: int, *, names: list[str] = NAMES, n_eff: int | None = None) -> bytes:
    m = JointState()
    m.header.stamp.sec, m.header.stamp.nanosec = divmod(k * 1_000_000 + 7, 1_000_000_000)
    m.header.frame_id = 'driveline'
    m.name = names
    n = len(names)
    m.position = [0.1 * k * (i + 1) for i in range(n)]
    m.velocity = [40.0 + np.sin(0.01 * k + i) for i in range(n)]
    m.effort = [100.0 - k * 1e-3 * i for i in range(n if n_eff is None else n_eff)]
    return bytes(serialize_message(m))


def _wrench(k: int, frame: str = 'wheel') -> bytes:
    m = WrenchStamped()
    m.header.stamp.sec, m.header.stamp.nanosec = divmod(k * 1_000_000, 1_000_000_000)
    m.header.frame_id = frame
    m.wrench.force.x, m.wrench.torque.z = 0.5 * k, 100.0 + np.cos(k)
    return bytes(serialize_message(m))


def _clock(k: int) -> bytes:
    m = Clock()
    m.clock.sec, m.clock.nanosec = divmod(k * 1_000_000, 1_000_000_000)
    return bytes(serialize_message(m))


def _big_endian(le: bytes) -> bytes:
    """A Clock sample re-encoded big-endian (encapsulation 00 00): rosbags reads it, the
    batch reader must leave it to rosbags."""
    sec, nsec = struct.unpack_from('<iI', le, 4)
    return b'\x00\x00\x00\x00' + struct.pack('>iI', sec, nsec)


def _write(path: Path, storage: str, n: int, odd: bool) -> None:
    w = bag.BagWriter(path, storage=storage)
    for topic in ('/clock', '/driveline/joint_states', '/load/wrench'):
        w.add_topic(topic)
    items = []
    for k in range(n):
        ts = k * 1_000_000
        js = _js(k)
        wr = _wrench(k)
        clk = _clock(k)
        if odd and k == 3:
            js = _js(k, n_eff=2)           # effort of another length: a NaN row
        if odd and k == 5:
            wr = _wrench(k, frame='wheel_long_frame')   # another length: one by one
        if odd and k == 7:
            clk = _big_endian(clk)
        items += [('/clock', ts, clk), ('/driveline/joint_states', ts, js), ('/load/wrench', ts, wr)]
    if odd:   # a late answer recorded out of time order, in the next chunk
        items.append(('/load/wrench', 2 * 1_000_000 + 1, _wrench(2)))
    for i in range(0, len(items), 97):
        w.write_batch(items[i:i + 97])
    w.close()


def _slow(path: Path, monkeypatch: pytest.MonkeyPatch, **kw) -> dict:
    with monkeypatch.context() as m:
        m.setattr(bag_decode, 'batch_decodable', lambda _t: False)
        m.setattr(bag, '_plain_mcap_files', lambda _r: None)
        return bag.read_bag(path, **kw)


def _same(a: dict, b: dict) -> None:
    assert a.keys() == b.keys()
    for topic in a:
        for f in ('t', 'record_t', 'position', 'velocity', 'effort', 'force', 'torque', 'value'):
            if hasattr(a[topic], f):
                x, y = getattr(a[topic], f), getattr(b[topic], f)
                assert x.shape == y.shape and np.array_equal(x, y, equal_nan=True), (topic, f)
        for f in ('names', 'frame_id'):
            if hasattr(a[topic], f):
                assert getattr(a[topic], f) == getattr(b[topic], f), (topic, f)


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
@pytest.mark.parametrize('odd', [False, True], ids=['one_layout', 'odd_messages'])
def test_batch_read_equals_message_by_message(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                              storage: str, odd: bool) -> None:
    path = tmp_path / 'b'
    _write(path, storage, 3000, odd)      # > one batch of each topic at BATCH 1024 below
    monkeypatch.setattr(bag_decode, 'BATCH', 1024)
    fast = bag.read_bag(path)
    _same(fast, _slow(path, monkeypatch))
    js = fast['/driveline/joint_states']
    assert js.t.size == 3000 and js.names == NAMES
    if odd:
        assert np.isnan(js.effort[3]).all() and not np.isnan(js.effort[4]).any()
        load = fast['/load/wrench']
        assert load.t.size == 3001 and load.t[3] == load.t[2]     # the late answer, in time order
    if storage == 'mcap':     # the streamed mcap path itself read it (no fall-back to rosbags)
        blocks = list(bag_decode.mcap_messages(str(next(path.glob('*.mcap')))))
        assert sum(len(ts) for b in blocks for ts, _raw in b.values()) == 9000 + odd
    cols = bag.read_bag(path, ['/driveline/joint_states'], columns=('velocity', 'effort'))
    assert cols['/driveline/joint_states'].position.shape == (3000, 0)
    np.testing.assert_array_equal(cols['/driveline/joint_states'].velocity, js.velocity)


def _foreign_js(k: int) -> bytes:
    """Another publisher's JointState (the hostile peer's kinds): other names, at k = 5 1e5
    entries with a velocity array one short."""
    m = JointState()
    m.header.stamp.nanosec = k * 1_000_000
    m.header.frame_id = 'driveline'
    n = 100_000 if k == 5 else 3
    m.name = [f'intruder_{j}' for j in range(n)]
    m.position = [0.0] * n
    m.velocity = [1.0] * (n - 1)
    return bytes(serialize_message(m))


def _mixed_bag(path: Path, storage: str, n: int, *, scene: bool, foreign_first: bool) -> int:
    """The run's joint states 0..n-1 with foreign ones interleaved (every 37th step, and one
    undecodable message); returns how many foreign messages were written."""
    import yaml
    w = bag.BagWriter(path, storage=storage)
    w.add_topic('/driveline/joint_states')
    if scene:
        w.set_custom_data('cvj_ros.scene', yaml.safe_dump({'seed': 1, 'shaft_names': NAMES}))
    items, n_foreign = [], 0
    if foreign_first:
        items.append(('/driveline/joint_states', 0, _foreign_js(0)))
        n_foreign += 1
    for k in range(n):
        items.append(('/driveline/joint_states', k * 1_000_000, _js(k)))
        if k % 37 == 5:
            items.append(('/driveline/joint_states', k * 1_000_000, _foreign_js(k)))
            n_foreign += 1
        if k == 50:        # a length field pointing past the end: does not decode
            items.append(('/driveline/joint_states', k * 1_000_000, b'\x00\x01\x00\x00' + b'\xff' * 40))
            n_foreign += 1
    for i in range(0, len(items), 97):
        w.write_batch(items[i:i + 97])
    w.close()
    return n_foreign


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
@pytest.mark.parametrize('foreign_first', [False, True], ids=['run_first', 'foreign_first'])
def test_foreign_joint_states_are_left_out_and_counted(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                       storage: str, foreign_first: bool) -> None:
    """A bag holding joint states of two layouts (another publisher's recorded by `cvj-sim
    record`) reads as the bag of the run's messages alone; the others are counted. With the
    run's names in the bag's scene a foreign message may come first."""
    n = 3000
    mixed = _mixed_bag(tmp_path / 'mixed', storage, n, scene=True, foreign_first=foreign_first)
    _write(tmp_path / 'clean', storage, n, False)
    monkeypatch.setattr(bag_decode, 'BATCH', 1024)
    got = bag.read_bag(tmp_path / 'mixed')['/driveline/joint_states']
    want = bag.read_bag(tmp_path / 'clean', ['/driveline/joint_states'])['/driveline/joint_states']
    assert got.foreign == mixed and want.foreign == 0
    assert got.names == NAMES and got.t.size == n
    for f in ('t', 'record_t', 'position', 'velocity', 'effort'):
        assert np.array_equal(getattr(got, f), getattr(want, f)), f
    blocks = list(bag.iter_blocks(tmp_path / 'mixed', ['/driveline/joint_states'], block=500))
    assert sum(d['foreign'] for _t, _ty, d in blocks) == mixed
    assert np.array_equal(np.concatenate([d['velocity'] for _t, _ty, d in blocks]), want.velocity)


def test_without_the_scene_the_first_joint_state_names_the_run(tmp_path: Path) -> None:
    mixed = _mixed_bag(tmp_path / 'b', 'mcap', 200, scene=False, foreign_first=False)
    js = bag.read_bag(tmp_path / 'b')['/driveline/joint_states']
    assert js.names == NAMES and js.t.size == 200 and js.foreign == mixed


def test_layouts_of_the_project_messages() -> None:
    lay = bag_decode.joint_state_layout(_js(4))
    assert lay is not None and lay.n == len(NAMES) and len(lay.starts) == 3
    buf = np.frombuffer(_js(4), dtype=np.uint8)[None, :]
    np.testing.assert_array_equal(bag_decode._values(buf, lay.starts[1], lay.n)[0],
                                  [40.0 + np.sin(0.04 + i) for i in range(4)])
    assert bag_decode.joint_state_layout(_js(4, n_eff=2)) is None       # arrays disagree
    assert bag_decode.joint_state_layout(b'\x00\x00' + _js(4)[2:]) is None   # big-endian
    assert bag_decode.joint_state_layout(_js(4)[:30]) is None           # cut short
    w = bag_decode.wrench_layout(_wrench(9))
    assert w is not None and w.n == 6
    assert bag_decode.wrench_layout(_wrench(9)[:-8]) is None
