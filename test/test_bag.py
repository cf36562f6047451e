"""Bags: raw round trip (mcap, sqlite3), typed reading, stamps from CDR, errors, recorder."""
from __future__ import annotations

import contextlib
import re
import struct
import time
from collections.abc import Iterator
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import yaml

from cvj_ros import bag
from cvj_ros.errors import BagError


def _ts():
    return bag.typestore()


def _joint_state(t: float, k: int) -> bytes:
    ts = _ts()
    Time = ts.types['builtin_interfaces/msg/Time']
    Header = ts.types['std_msgs/msg/Header']
    JS = ts.types['sensor_msgs/msg/JointState']
    sec = int(t)
    msg = JS(header=Header(stamp=Time(sec=sec, nanosec=round((t - sec) * 1e9)), frame_id=''),
             name=['engine_crank', 'wheel'],
             position=np.array([0.1 * k, 0.2 * k]), velocity=np.array([10.0 + k, 9.0 + k]),
             effort=np.array([100.0, -50.0 * k]))
    return bytes(ts.serialize_cdr(msg, 'sensor_msgs/msg/JointState'))


def _wrench(t: float, tz: float, frame: str = 'wheel') -> bytes:
    ts = _ts()
    Time = ts.types['builtin_interfaces/msg/Time']
    Header = ts.types['std_msgs/msg/Header']
    V = ts.types['geometry_msgs/msg/Vector3']
    W = ts.types['geometry_msgs/msg/Wrench']
    WS = ts.types['geometry_msgs/msg/WrenchStamped']
    sec = int(t)
    msg = WS(header=Header(stamp=Time(sec=sec, nanosec=round((t - sec) * 1e9)), frame_id=frame),
             wrench=W(force=V(x=1.0, y=2.0, z=3.0), torque=V(x=0.0, y=0.0, z=tz)))
    return bytes(ts.serialize_cdr(msg, 'geometry_msgs/msg/WrenchStamped'))


def _string(text: str) -> bytes:
    ts = _ts()
    return bytes(ts.serialize_cdr(ts.types['std_msgs/msg/String'](data=text), 'std_msgs/msg/String'))


def _write_sample(path: Path, storage: str) -> list[tuple[str, int, bytes]]:
    msgs: list[tuple[str, int, bytes]] = [('/driveline/scene', 0, _string('scene: {name: x}\nseed: 3\n'))]
    for k in range(5):
        t = 0.01 * k
        msgs.append(('/driveline/joint_states', round(t * 1e9), _joint_state(t, k)))
        msgs.append(('/load/wrench', round(t * 1e9), _wrench(t, 100.0 + k)))
    with bag.BagWriter(path, storage=storage) as w:
        for topic in {m[0] for m in msgs}:
            w.add_topic(topic)
        w.set_custom_data('cvj_ros.seed', '3')
        for topic, ts, data in msgs:
            w.write(topic, ts, data)
    return msgs


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_raw_round_trip_is_byte_identical(tmp_path: Path, storage: str) -> None:
    path = tmp_path / 'b'
    msgs = _write_sample(path, storage)
    back = bag.read_raw(path)
    assert sorted((t, ts, d) for t, _, ts, d in back) == sorted(msgs)
    info = bag.bag_info(path)
    assert info.storage == storage
    assert info.counts == {'/driveline/scene': 1, '/driveline/joint_states': 5, '/load/wrench': 5}
    assert info.custom_data == {'cvj_ros.seed': '3'}


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_typed_reading(tmp_path: Path, storage: str) -> None:
    path = tmp_path / 'b'
    _write_sample(path, storage)
    data = bag.read_bag(path)
    js = data['/driveline/joint_states']
    assert js.names == ['engine_crank', 'wheel']
    np.testing.assert_allclose(js.t, 0.01 * np.arange(5), atol=1e-12)
    np.testing.assert_allclose(js.velocity[:, 0], 10.0 + np.arange(5))
    np.testing.assert_allclose(js.effort[:, 1], -50.0 * np.arange(5))
    assert js.velocity[:, js.shaft('wheel')][2] == 11.0
    w = data['/load/wrench']
    np.testing.assert_allclose(w.torque_z, 100.0 + np.arange(5))
    np.testing.assert_allclose(w.force[:, 2], 3.0)
    assert w.frame_id == 'wheel'
    assert data['/driveline/scene'].data == ['scene: {name: x}\nseed: 3\n']
    assert bag.read_scene_message(path) == {'scene': {'name': 'x'}, 'seed': 3}
    t, tz = bag.load_torque_series(path)
    np.testing.assert_allclose(t, 0.01 * np.arange(5), atol=1e-12)
    np.testing.assert_allclose(tz, 100.0 + np.arange(5))
    assert set(bag.read_bag(path, ['/load/*'])) == {'/load/wrench'}


def test_cdr_stamp_matches_rclpy_serialiser() -> None:
    """Stamp read from raw bytes equals the stamp rclpy itself serialised (independent CDR writer)."""
    rclpy_serialization = pytest.importorskip('rclpy.serialization')
    from geometry_msgs.msg import WrenchStamped
    from rosgraph_msgs.msg import Clock
    m = WrenchStamped()
    m.header.stamp.sec, m.header.stamp.nanosec = 12, 345_678_901
    m.header.frame_id = 'engine_crank'
    assert bag.cdr_stamp_ns(rclpy_serialization.serialize_message(m)) == 12_345_678_901
    c = Clock()
    c.clock.sec, c.clock.nanosec = 0, 5_000_000
    assert bag.cdr_stamp_ns(rclpy_serialization.serialize_message(c)) == 5_000_000
    # rosbags' serialiser agrees too
    assert bag.cdr_stamp_ns(_wrench(1.25, 0.0)) == 1_250_000_000


def test_errors_name_the_bag_or_topic(tmp_path: Path) -> None:
    with pytest.raises(BagError, match=r'^.*nope: no such bag'):
        bag.read_bag(tmp_path / 'nope')
    (tmp_path / 'empty').mkdir()
    with pytest.raises(BagError, match='no metadata.yaml'):
        bag.read_bag(tmp_path / 'empty')
    path = tmp_path / 'b'
    _write_sample(path, 'mcap')
    run_dir = tmp_path / 'run'                 # `cvj-sim run --out run` writes run/bag
    run_dir.mkdir()
    _write_sample(run_dir / 'bag', 'mcap')
    with pytest.raises(BagError, match=rf'^{re.escape(str(run_dir))}: not a rosbag2 bag but a run '
                                       rf'directory; its bag is {re.escape(str(run_dir / "bag"))}$'):
        bag.read_bag(run_dir)
    with pytest.raises(BagError, match=r'^/engine/wrench: topic not in bag'):
        bag.load_torque_series(path, '/engine/wrench')
    with pytest.raises(BagError, match='exists already'):
        bag.BagWriter(path)
    with pytest.raises(BagError, match='^storage:'):
        bag.BagWriter(tmp_path / 'c', storage='rosbag1')
    bag.BagWriter(path, overwrite=True).close()  # overwrite replaces it
    assert bag.bag_info(path).counts == {}


def test_topic_types_follow_contract() -> None:
    assert bag.topic_type('/coupling/tripod/wrench') == 'geometry_msgs/msg/WrenchStamped'
    assert bag.topic_type('/coupling/a/b/wrench') is None     # * stays inside one name segment
    assert bag.topic_type('/rosout') is None
    assert bag.topic_type('/clock') == 'rosgraph_msgs/msg/Clock'


@pytest.mark.ros
@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_recorder_writes_raw_messages_at_sim_time(tmp_path: Path, storage: str) -> None:
    """Publish through rclpy; the bag holds the same bytes, record time = header stamp or last /clock."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.serialization import serialize_message
    from geometry_msgs.msg import WrenchStamped
    from rosgraph_msgs.msg import Clock
    from std_msgs.msg import Float64, String

    ctx = rclpy.context.Context()
    rclpy.init(context=ctx)
    try:
        node = rclpy.create_node('rec_test', context=ctx)
        pub_node = rclpy.create_node('pub_test', context=ctx)
        ex = SingleThreadedExecutor(context=ctx)
        ex.add_node(node)
        ex.add_node(pub_node)
        writer = bag.BagWriter(tmp_path / 'b', storage=storage)
        rec = bag.BagRecorder(node, writer, topics=['/coupling/rzeppa/wrench'])
        qos = bag.recorder_qos()
        pubs = {
            '/clock': pub_node.create_publisher(Clock, '/clock', qos),
            '/load/wrench': pub_node.create_publisher(WrenchStamped, '/load/wrench', qos),
            '/coupling/rzeppa/wrench': pub_node.create_publisher(WrenchStamped, '/coupling/rzeppa/wrench', qos),
            '/engine/throttle': pub_node.create_publisher(Float64, '/engine/throttle', qos),
        }
        scene_pub = pub_node.create_publisher(String, '/driveline/scene', bag.recorder_qos(latched=True))
        deadline = time.monotonic() + 5
        while any(p.get_subscription_count() == 0 for p in pubs.values()) and time.monotonic() < deadline:
            ex.spin_once(timeout_sec=0.05)
        sent = []
        for k in range(20):
            c = Clock()
            c.clock.nanosec = 1_000_000 * k
            pubs['/clock'].publish(c)
            w = WrenchStamped()
            w.header.stamp.nanosec = 1_000_000 * k
            w.wrench.torque.z = float(k)
            pubs['/load/wrench'].publish(w)
            sent.append(serialize_message(w))
            pubs['/coupling/rzeppa/wrench'].publish(w)
        deadline = time.monotonic() + 5
        while writer.counts.get('/load/wrench', 0) < 20 or writer.counts.get('/clock', 0) < 20:
            ex.spin_once(timeout_sec=0.05)
            assert time.monotonic() < deadline, writer.counts
        pubs['/engine/throttle'].publish(Float64(data=0.5))
        scene_pub.publish(String(data='seed: 7\n'))  # after /clock 19 ms: still recorded at t0 = 0
        deadline = time.monotonic() + 5
        while not writer.counts.get('/engine/throttle') or not writer.counts.get('/driveline/scene'):
            ex.spin_once(timeout_sec=0.05)
            assert time.monotonic() < deadline, writer.counts
        rec.destroy()
        writer.close()
        ex.shutdown()
        node.destroy_node()
        pub_node.destroy_node()
    finally:
        rclpy.shutdown(context=ctx)
    raw = bag.read_raw(tmp_path / 'b', ['/load/wrench'])
    # serialize_message leaves CDR alignment padding uninitialised (once b'g::' after frame_id's
    # terminator), so equal lengths and equal decoded messages, not equal padding bytes, are asserted.
    from rclpy.serialization import deserialize_message
    assert [len(d) for *_, d in raw] == [len(s) for s in sent]
    assert [deserialize_message(d, WrenchStamped) == deserialize_message(s, WrenchStamped)
            for (*_, d), s in zip(raw, sent)] == [True] * 20
    assert [ts for _, _, ts, _ in raw] == [1_000_000 * k for k in range(20)]
    throttle = bag.read_raw(tmp_path / 'b', ['/engine/throttle'])
    assert throttle[0][2] == 19_000_000  # latest /clock time
    assert bag.read_raw(tmp_path / 'b', ['/driveline/scene'])[0][2] == 0
    assert bag.bag_info(tmp_path / 'b').custom_data['cvj_ros.scene'] == 'seed: 7\n'
    assert yaml.safe_load(bag.read_bag(tmp_path / 'b', ['/driveline/scene'])['/driveline/scene'].data[0]) == {'seed': 7}
    np.testing.assert_allclose(bag.read_bag(tmp_path / 'b', ['/coupling/rzeppa/wrench'])[
        '/coupling/rzeppa/wrench'].torque_z, np.arange(20.0))


@pytest.mark.ros
def test_recorder_stamps_a_played_schedule_at_its_steps(tmp_path: Path) -> None:
    """set_command_stamps: the n-th sample on a command topic is recorded at its step's time
    whatever /clock the recorder has taken when it arrives; samples beyond the schedule (and
    topics without one) at the latest /clock."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rosgraph_msgs.msg import Clock
    from std_msgs.msg import Float64, Int8

    ctx = rclpy.context.Context()
    rclpy.init(context=ctx)
    try:
        node = rclpy.create_node('rec_test', context=ctx)
        pub_node = rclpy.create_node('pub_test', context=ctx)
        ex = SingleThreadedExecutor(context=ctx)
        ex.add_node(node)
        ex.add_node(pub_node)
        writer = bag.BagWriter(tmp_path / 'b')
        rec = bag.BagRecorder(node, writer)
        rec.set_command_stamps({'/engine/throttle': [2_000_000, 5_000_000]})
        qos = bag.recorder_qos()
        pubs = {'/clock': pub_node.create_publisher(Clock, '/clock', qos),
                '/engine/throttle': pub_node.create_publisher(Float64, '/engine/throttle', qos),
                '/driveline/gear': pub_node.create_publisher(Int8, '/driveline/gear', qos)}
        deadline = time.monotonic() + 5
        while any(p.get_subscription_count() == 0 for p in pubs.values()) and time.monotonic() < deadline:
            ex.spin_once(timeout_sec=0.05)
        for k in range(20):
            c = Clock()
            c.clock.nanosec = 1_000_000 * k
            pubs['/clock'].publish(c)
        deadline = time.monotonic() + 5
        while writer.counts.get('/clock', 0) < 20:
            ex.spin_once(timeout_sec=0.05)
            assert time.monotonic() < deadline, writer.counts
        for x in (0.5, 0.25, 0.75):          # all arrive after /clock 19 ms
            pubs['/engine/throttle'].publish(Float64(data=x))
        pubs['/driveline/gear'].publish(Int8(data=2))
        deadline = time.monotonic() + 5
        while writer.counts.get('/engine/throttle', 0) < 3 or not writer.counts.get('/driveline/gear'):
            ex.spin_once(timeout_sec=0.05)
            assert time.monotonic() < deadline, writer.counts
        rec.destroy()
        writer.close()
        ex.shutdown()
        node.destroy_node()
        pub_node.destroy_node()
    finally:
        rclpy.shutdown(context=ctx)
    throttle = bag.read_raw(tmp_path / 'b', ['/engine/throttle'])
    assert [ts for _, _, ts, _ in throttle] == [2_000_000, 5_000_000, 19_000_000]
    assert [ts for _, _, ts, _ in bag.read_raw(tmp_path / 'b', ['/driveline/gear'])] == [19_000_000]


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_writer_accepts_writes_from_other_threads(tmp_path: Path, storage: str) -> None:
    """Recorder callbacks run on executor threads; sqlite3 objects are bound to their thread."""
    import threading
    w = bag.BagWriter(tmp_path / 'b', storage=storage)
    w.add_topic('/load/wrench')

    def writer(offset: int) -> None:
        for k in range(50):
            w.write('/load/wrench', (offset + k) * 1000, _wrench((offset + k) * 1e-6, float(offset + k)))
    threads = [threading.Thread(target=writer, args=(i * 50,)) for i in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    w.close()
    _, tz = bag.load_torque_series(tmp_path / 'b')
    np.testing.assert_array_equal(tz, np.arange(100.0))


def test_wait_flush_wakes_on_a_flush_that_moves_only_an_older_topic(tmp_path: Path) -> None:
    """BagWriter.wait_flush waits for the next flush, not for a newer stamp of any topic: a
    flush of /load/wrench at t = 1 ms behind a /clock at 2 ms leaves durable_ns at 2 ms but
    moves durable_topics (what the recorder gate reports), and must wake the waiter. Waiting
    for durable_ns + 1 there returned at once and made cvj-sim's /driveline/recorded
    thread spin."""
    w = bag.BagWriter(tmp_path / 'b')
    try:
        w.add_topic('/clock')
        w.add_topic('/load/wrench')
        w.write('/clock', 2_000_000, _stamped_cdr(2_000_000, b''))
        w.request_flush()
        first = w.wait_flush(0, 30.0)        # 30 s: only a stuck writer thread reaches it
        assert first >= 1 and w.durable_ns == 2_000_000
        w.write('/load/wrench', 1_000_000, _wrench(1e-3, 5.0))
        w.request_flush()
        second = w.wait_flush(first, 30.0)
        assert second > first
        assert w.durable_topics['/load/wrench'] == 1_000_000
        assert w.durable_ns == 2_000_000          # the newest stamp did not move
        # no flush asked for: the wait ends at its timeout with the same count
        assert w.wait_flush(second, 0.05) == second
    finally:
        w.close()


def test_run_report_metrics_from_bag_match_closed_form(tmp_path: Path) -> None:
    """A bag with omega = W (1 + e sin(2 pi f t)) and torque T0 + A cos(...): delta = 2 e, amplitude A."""
    from cvj_ros.orchestrate import bag_metrics
    ts = _ts()
    Time = ts.types['builtin_interfaces/msg/Time']
    Header = ts.types['std_msgs/msg/Header']
    JS = ts.types['sensor_msgs/msg/JointState']
    W, e, f, T0, A = 40.0, 0.01, 25.0, 100.0, 7.5
    n = 2001  # 2 s at 1 ms: every 0.2 s slice holds 5 whole periods: steady from the start
    with bag.BagWriter(tmp_path / 'b') as w:
        w.add_topic('/driveline/joint_states')
        w.add_topic('/load/wrench')
        for k in range(n):
            t = k * 1e-3
            s = np.sin(2 * np.pi * f * t)
            msg = JS(header=Header(stamp=Time(sec=int(t), nanosec=round((t - int(t)) * 1e9)), frame_id=''),
                     name=['wheel'], position=np.array([W * t]), velocity=np.array([W * (1 + e * s)]),
                     effort=np.array([T0 + A * np.cos(2 * np.pi * f * t)]))
            w.write('/driveline/joint_states', k * 1_000_000, bytes(ts.serialize_cdr(msg, 'sensor_msgs/msg/JointState')))
            w.write('/load/wrench', k * 1_000_000, _wrench(t, T0 + A * s))
    m = bag_metrics(tmp_path / 'b')
    wheel = m['shafts']['wheel']
    assert wheel['mean_speed'] == pytest.approx(W, rel=1e-4)
    assert wheel['delta'] == pytest.approx(2 * e, rel=1e-3)
    assert wheel['torque_amplitude'] == pytest.approx(A, rel=1e-3)
    assert wheel['acceleration_amplitude'] == pytest.approx(W * e * 2 * np.pi * f, rel=1e-2)
    assert m['wrenches']['/load/wrench']['torque_amplitude'] == pytest.approx(A, rel=1e-3)
    assert m['window_s'] == pytest.approx([0.0, 2.0])
    assert m['window']['steady'] is True and m['window']['source'] == 'criterion'


def test_recorder_keeps_ten_seconds_of_a_1ms_loop_when_it_lags() -> None:
    """The loop does not wait for the recorder: its readers keep the newest ``depth``
    samples. Depth 10000 = 10 s at h = 1 ms (a starved recorder once lost the first 100 of
    1108 states at depth 1000); reliability and durability as the publishers'."""
    pytest.importorskip('rclpy')
    from cvj_ros.nodes import qos
    q = bag.recorder_qos()
    assert q.depth >= 10_000
    assert (q.reliability, q.durability, q.history) == (
        qos.DATA_QOS.reliability, qos.DATA_QOS.durability, qos.DATA_QOS.history)
    assert bag.recorder_qos(latched=True) is qos.LATCHED_QOS


def test_fast_mcap_writes_are_rosbags_bytes(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """BagWriter writes mcap message records itself (bag._mcap_batch_writer, one struct.pack
    per message): the file must be the one rosbags' own Writer.write gives in the same
    writer (same flushes), byte for byte, across chunk boundaries and with single and
    batched writes mixed."""
    msgs: list[tuple[str, int, bytes]] = []
    for k in range(6000):        # 6 s of record time, > 1 MiB: chunks closed by size and by flush
        t = 0.001 * k
        msgs.append(('/driveline/joint_states', round(t * 1e9), _joint_state(t, k)))
        msgs.append(('/load/wrench', round(t * 1e9), _wrench(t, 100.0 + k)))

    # chunks closed by record time only (the wall-time flush would make the two files differ)
    monkeypatch.setattr(bag, 'FLUSH_WALL_S', 1e9)

    def write(path: Path) -> bytes:
        with bag.BagWriter(path, storage='mcap') as w:
            w.add_topic('/driveline/joint_states')
            w.add_topic('/load/wrench')
            for topic, ts, data in msgs[:1001]:
                w.write(topic, ts, data)
            for i in range(1001, len(msgs), 777):
                w.write_batch(msgs[i:i + 777])
        assert bag.bag_info(path).counts == {'/driveline/joint_states': 6000, '/load/wrench': 6000}
        return (path / f'{path.name}.mcap').read_bytes()
    ours = write(tmp_path / 'ours' / 'bag')   # same name: the file name is in the mcap metadata
    monkeypatch.setattr(bag, '_mcap_batch_writer', lambda writer: None)   # rosbags' Writer.write
    ref = write(tmp_path / 'ref' / 'bag')
    assert len(ours) > 2**20
    assert ours == ref


@contextlib.contextmanager
def _spinning_recorder(path: Path, *, coalesce: float) -> Iterator[SimpleNamespace]:
    """A BagRecorder over a BatchingWriter (as the orchestrator's separate-process recorder:
    only spin flushes the front) spinning in a thread with ``coalesce``, and a publisher of
    /load/wrench in its own context, matched. Yields writer, front, rec, stop, thread and
    ``send(k)`` (a wrench stamped k ms with torque z = k); afterwards stops the spin and
    closes everything."""
    import threading

    import rclpy
    from geometry_msgs.msg import WrenchStamped

    ctx, pub_ctx = rclpy.context.Context(), rclpy.context.Context()
    rclpy.init(context=ctx)
    rclpy.init(context=pub_ctx)
    stop = threading.Event()
    try:
        node = rclpy.create_node('rec_spin', context=ctx)
        pub_node = rclpy.create_node('pub_spin', context=pub_ctx)
        writer = bag.BagWriter(path)
        front = bag.BatchingWriter(writer)
        rec = bag.BagRecorder(node, front)
        thread = threading.Thread(target=rec.spin, args=(stop,), kwargs={'coalesce': coalesce},
                                  daemon=True)
        thread.start()
        pub = pub_node.create_publisher(WrenchStamped, '/load/wrench', bag.recorder_qos())
        # both sides matched: the writer knowing the recorder's reader does not mean the
        # reader (another participant) knows the writer, and it drops samples until it does
        reader = next(s for s in node.subscriptions if s.topic_name == '/load/wrench')
        deadline = time.monotonic() + 10
        while pub.get_subscription_count() == 0 or reader.get_publisher_count() == 0:
            assert time.monotonic() < deadline, 'recorder subscription not matched'
            time.sleep(0.01)

        def send(k: int) -> None:
            w = WrenchStamped()
            w.header.stamp.nanosec = 1_000_000 * k
            w.wrench.torque.z = float(k)
            pub.publish(w)

        yield SimpleNamespace(writer=writer, front=front, rec=rec, pub=pub, stop=stop,
                              thread=thread, send=send)
        stop.set()
        thread.join(5)
        rec.destroy()
        writer.close()
        node.destroy_node()
        pub_node.destroy_node()
    finally:
        stop.set()
        rclpy.shutdown(context=ctx)
        rclpy.shutdown(context=pub_ctx)


@pytest.mark.ros
def test_recorder_spin_coalesces_wakes_and_loses_nothing(tmp_path: Path) -> None:
    """spin(coalesce=c) over a BatchingWriter (the separate-process recorder,
    orchestrate.RECORDER_COALESCE_S): every message of a fast publisher in the bag, in order,
    although nothing flushes the front but spin itself; and at most one wake per c s while
    they arrive (the wait after a productive wake is c: the bound is the loop's own rule,
    not a timing guess)."""
    n, c = 200, 0.02
    with _spinning_recorder(tmp_path / 'b', coalesce=c) as r:
        sent = []
        t0 = time.monotonic()
        for k in range(n):
            r.send(k)
            sent.append(k)
            time.sleep(0.0005)
        deadline = time.monotonic() + 10
        while r.writer.counts.get('/load/wrench', 0) < n:   # handed to the writer thread
            assert time.monotonic() < deadline, (r.writer.counts, r.front.counts)
            time.sleep(0.005)
        t1 = time.monotonic()
        r.stop.set()
        r.thread.join(2)
        wakes = r.rec.wakes
    # content, not bytes: rclpy leaves the CDR alignment padding uninitialised
    raw = bag.read_raw(tmp_path / 'b', ['/load/wrench'])
    assert len(raw) == len(sent) == n
    assert [ts for _, _, ts, _ in raw] == [1_000_000 * k for k in range(n)]
    np.testing.assert_array_equal(bag.read_bag(tmp_path / 'b', ['/load/wrench'])['/load/wrench'].torque_z,
                                  np.arange(float(n)))
    assert 1 <= wakes <= (t1 - t0) / c + 2, (wakes, t1 - t0)


@pytest.mark.ros
def test_recorder_spin_stopped_in_its_coalesce_wait_takes_what_is_queued(tmp_path: Path) -> None:
    """A stop that comes while spin waits out its coalesce time (orchestrate's 20 ms) takes
    the messages that arrived meanwhile before spin returns: acknowledged by the recorder's
    reader (in its queue), they are in the bag. The coalesce wait here is 60 s, so every
    message after the first is in that window."""
    from rclpy.duration import Duration

    with _spinning_recorder(tmp_path / 'b', coalesce=60.0) as r:
        deadline = time.monotonic() + 10
        r.send(0)
        while r.front.counts.get('/load/wrench', 0) < 1:   # taken: spin is now in its wait
            assert time.monotonic() < deadline, r.front.counts
            time.sleep(0.005)
        for k in range(1, 6):
            r.send(k)
        assert r.pub.wait_for_all_acked(Duration(seconds=10))   # in the recorder's queue
        assert r.front.counts['/load/wrench'] == 1              # not taken yet
        r.stop.set()
        r.thread.join(5)
        assert not r.thread.is_alive()
    np.testing.assert_array_equal(bag.read_bag(tmp_path / 'b', ['/load/wrench'])['/load/wrench'].torque_z,
                                  np.arange(6.0))


@pytest.mark.parametrize('storage', bag.STORAGES)
def test_empty_bag_reads_as_no_series(tmp_path, storage: str) -> None:
    """A bag without messages (a run stopped at once) reads as empty, not as an internal
    error text that a report would show."""
    for i, topics in enumerate(([], [bag.JOINT_STATES_TOPIC])):
        path = tmp_path / f'bag{i}'
        with bag.BagWriter(path, storage=storage) as w:
            for t in topics:
                w.add_topic(t)
        data = bag.read_bag(path)
        assert set(data) <= set(topics) and all(len(series.t) == 0 for series in data.values())


def test_scene_command_stamps_learn_the_schedule_from_the_scene_message() -> None:
    """A recorder not told the schedule (started by hand or by the launch file) takes the
    record times of the driver's samples and the throttle scale from /driveline/scene: the
    same lists `cvj-sim run` hands it (CommandPlan.record_stamps, one scale per step in
    lockstep); none for an outside stack's commands or a text it cannot read."""
    from cvj_ros.nodes.command_plan import CommandPlan
    from cvj_ros.nodes.common import scene_dict
    from cvj_ros.physics.scene import find_scene, load_scene
    scene = load_scene(find_scene('launch_clutch'))
    msg = {'scene': scene_dict(scene), 'seed': 1, 'mode': 'lockstep', 'exchange_step': 0.001,
           'duration': 1.6, 'commands': 'driver'}
    got = bag.scene_command_stamps(yaml.safe_dump(msg))
    want = CommandPlan.from_scene(scene, 1_000_000, 1600).record_stamps()
    assert {t: got[t] for t in want} == want and len(want['/engine/throttle']) > 300
    assert got['/engine/throttle_scale'] == [k * 1_000_000 for k in range(1601)]
    external = bag.scene_command_stamps(yaml.safe_dump(dict(msg, commands='external')))
    assert list(external) == ['/engine/throttle_scale']
    assert list(bag.scene_command_stamps(yaml.safe_dump(dict(msg, mode='free-run')))) == list(want)
    assert bag.scene_command_stamps('{not: [yaml') == {}
    assert bag.scene_command_stamps(yaml.safe_dump(dict(msg, exchange_step='x'))) == {}


class _FakeSubscription:
    """A subscription whose queue holds ``samples`` (what BagRecorder._take_queued takes)."""

    def __init__(self, samples: list[bytes]) -> None:
        self.samples = list(samples)
        self.handle = self
        self.pointer = id(self)
        self.msg_type = None

    def __enter__(self) -> '_FakeSubscription':
        return self

    def __exit__(self, *exc: object) -> None:
        return None

    def take_message(self, _msg_type: object, _raw: bool) -> tuple[bytes, dict] | None:
        return (self.samples.pop(0), {}) if self.samples else None

    def get_publisher_count(self) -> int:
        return 1


def _stamped_cdr(stamp_ns: int, tag: bytes) -> bytes:
    sec, nsec = divmod(stamp_ns, 1_000_000_000)
    return b'\x00\x01\x00\x00' + struct.pack('<iI', sec, nsec) + tag


def test_recorder_feeds_observers_in_loop_order_not_topic_by_topic() -> None:
    """One wake that takes 150 joint states and then their 150 answers (the recorder takes
    topic by topic) feeds the observers state t_k, answer t_k, state t_k+1, ...: a hosted
    monitor that publishes at every 100th state then has the answers of its window (a CI run
    showed its first status without torques when it was fed topic by topic)."""
    rec = bag.BagRecorder.__new__(bag.BagRecorder)
    rec.run_only = False
    rec._on_message = lambda *a, **k: True
    seen: list[bytes] = []
    rec.observers = {bag.JOINT_STATES_TOPIC: [seen.append], '/engine/wrench': [seen.append],
                     '/load/wrench': [seen.append], '/diagnostics': [seen.append]}
    n = 150
    subs = {topic: _FakeSubscription([_stamped_cdr(k * 1_000_000, tag + b'%d' % k) for k in range(n)])
            for topic, tag in ((bag.JOINT_STATES_TOPIC, b'js'), ('/engine/wrench', b'en'),
                               ('/load/wrench', b'ld'))}
    # a loop status stamped t_100 (the coupling node's): after the state t_100 and its answers
    subs['/diagnostics'] = _FakeSubscription([_stamped_cdr(100_000_000, b'dg')])
    entries = [(topic, sub, topic != '/diagnostics', False,
                bag.TOPIC_TYPES.get(topic, 'geometry_msgs/msg/WrenchStamped'))
               for topic, sub in sorted(subs.items())]
    rec._take_queued(entries, None)
    expected = [_stamped_cdr(k * 1_000_000, tag + b'%d' % k) for k in range(n) for tag in (b'js', b'en', b'ld')]
    expected.insert(3 * 101, _stamped_cdr(100_000_000, b'dg'))
    assert seen == expected
    # big-endian samples are ordered by their stamp too
    assert bag._feed_order(b'\x00\x00\x00\x00' + struct.pack('>iI', 2, 5) + b'x', 'sensor_msgs/msg/JointState') == 2_000_000_005
    assert bag._feed_order(b'\x00\x01', 'sensor_msgs/msg/JointState') == -1
    assert bag._feed_order(_stamped_cdr(5, b'x'), 'std_msgs/msg/String') == -1


def test_recorder_with_observers_takes_every_subscription_at_a_wake() -> None:
    """The wait found only the joint states ready (their first sample was in; the answer to
    it not yet), and by the time the recorder thread took them - late, on a busy machine -
    150 states and their 150 answers had arrived: with observers the answers are taken in
    the same wake, so a hosted monitor's status at the 100th state has the answers of its
    window (taken a wake later, its first status had no torques). Without observers only
    the ready subscriptions are taken (a plain recorder's wake stays as cheap as before)."""
    def wake(observed: bool) -> tuple[list[bytes], dict[str, _FakeSubscription]]:
        rec = bag.BagRecorder.__new__(bag.BagRecorder)
        rec.run_only = False
        rec._on_message = lambda *a, **k: True
        seen: list[bytes] = []
        rec.observers = ({bag.JOINT_STATES_TOPIC: [seen.append], '/engine/wrench': [seen.append]}
                         if observed else {})
        subs = {topic: _FakeSubscription([_stamped_cdr(k * 1_000_000, tag + b'%d' % k)
                                          for k in range(150)])
                for topic, tag in ((bag.JOINT_STATES_TOPIC, b'js'), ('/engine/wrench', b'en'))}
        entries = [(topic, sub, True, False, bag.TOPIC_TYPES[topic]) for topic, sub in subs.items()]
        rec._take_queued(entries, {subs[bag.JOINT_STATES_TOPIC].pointer})
        return seen, subs
    seen, subs = wake(observed=True)
    assert seen == [_stamped_cdr(k * 1_000_000, tag + b'%d' % k) for k in range(150) for tag in (b'js', b'en')]
    assert not subs['/engine/wrench'].samples
    seen, subs = wake(observed=False)
    assert seen == [] and len(subs['/engine/wrench'].samples) == 150 and not subs[bag.JOINT_STATES_TOPIC].samples
