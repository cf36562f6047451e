"""monitor_node reads /engine/wrench and /load/wrench as raw CDR (no Python message per
sample): the torque window statistics against a closed form."""
from __future__ import annotations

import math
import time

import pytest

rclpy = pytest.importorskip('rclpy')
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus  # noqa: E402
from geometry_msgs.msg import WrenchStamped  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402

from cvj_ros.nodes.common import make_executor, ns_to_stamp  # noqa: E402
from cvj_ros.nodes.monitor_node import MonitorNode  # noqa: E402
from cvj_ros.nodes.qos import DATA_QOS  # noqa: E402

pytestmark = pytest.mark.ros


def test_torque_windows_from_raw_answers(ctx):
    node = MonitorNode(context=ctx, parameter_overrides=[
        Parameter('publish_every', value=1000), Parameter('window', value=0.4)])
    peer = rclpy.create_node('peer', context=ctx)
    js_pub = peer.create_publisher(JointState, '/driveline/joint_states', DATA_QOS)
    eng_pub = peer.create_publisher(WrenchStamped, '/engine/wrench', DATA_QOS)
    load_pub = peer.create_publisher(WrenchStamped, '/load/wrench', DATA_QOS)
    got: list[DiagnosticArray] = []
    peer.create_subscription(DiagnosticArray, '/diagnostics', got.append, DATA_QOS)
    ex = make_executor('events', ctx)
    ex.add_node(peer)
    ex.add_node(node)

    def spin_until(cond, timeout=10.0):
        deadline = time.monotonic() + timeout
        while not cond():
            assert time.monotonic() < deadline
            ex.spin_once(timeout_sec=0.02)

    def wrench(pub, k: int, torque: float) -> None:
        msg = WrenchStamped()
        msg.header.stamp = ns_to_stamp(k * 1_000_000)
        msg.header.frame_id = 'shaft'
        msg.wrench.torque.z = torque
        msg.wrench.force.x = 1e9      # must not be read as torque.z
        pub.publish(msg)

    try:
        spin_until(lambda: min(p.get_subscription_count() for p in (js_pub, eng_pub, load_pub)) >= 1
                   and node.diag_pub.get_subscription_count() >= 1)
        # 1 s at 1 ms: engine 100 + 7 sin(2 pi 5 t), load 80 + 3 cos(2 pi 5 t)
        for k in range(1000):
            t = k * 1e-3
            wrench(eng_pub, k, 100 + 7 * math.sin(2 * math.pi * 5 * t))
            wrench(load_pub, k, 80 + 3 * math.cos(2 * math.pi * 5 * t))
            if k % 100 == 0:   # keep the queues short (depth 1000)
                spin_until(lambda: node.load_torque.window(1e9)[1].shape[0] >= k + 1)
        spin_until(lambda: node.load_torque.window(1e9)[1].shape[0] >= 1000
                   and node.engine_torque.window(1e9)[1].shape[0] >= 1000)
        js = JointState()
        js.header.stamp = ns_to_stamp(999_000_000)
        js.header.frame_id = 'driveline'
        js.name, js.position, js.velocity, js.effort = ['a'], [0.0], [40.0], [0.0]
        for _ in range(1000):   # publish_every = 1000 joint states -> one /diagnostics
            js_pub.publish(js)
        spin_until(lambda: any(st.name == 'monitor: torques' for m in got for st in m.status))
        st = next(st for m in got for st in m.status if st.name == 'monitor: torques')
        vals = {kv.key: float(kv.value) for kv in st.values}
        assert st.level == DiagnosticStatus.OK
        # the window = the samples k = 599..999 (t_end - 0.4 s .. t_end, both ends): mean and
        # (max - min)/2 of the closed-form signal there; the values travel as 6-significant-digit
        # strings (diag_status), hence rel 1e-5
        ks = range(599, 1000)
        eng = [100 + 7 * math.sin(2 * math.pi * 5 * k * 1e-3) for k in ks]
        load = [80 + 3 * math.cos(2 * math.pi * 5 * k * 1e-3) for k in ks]
        assert vals['engine_torque_mean_nm'] == pytest.approx(sum(eng) / len(eng), rel=1e-5)
        assert vals['engine_torque_amplitude_nm'] == pytest.approx((max(eng) - min(eng)) / 2, rel=1e-5)
        assert vals['load_torque_mean_nm'] == pytest.approx(sum(load) / len(load), rel=1e-5)
        assert vals['load_torque_amplitude_nm'] == pytest.approx((max(load) - min(load)) / 2, rel=1e-5)
        assert vals['engine_torque_amplitude_nm'] == pytest.approx(7.0, rel=1e-5)   # peaks sampled
    finally:
        ex.shutdown()
        peer.destroy_node()
        node.destroy_node()


def test_collected_samples_stay_bounded_with_a_large_publish_every(ctx):
    """The monitor collects samples and reads them into its (fixed-size) windows when it
    publishes; with publish_every far above the run length the collection is read every
    MAX_COLLECTED samples instead of growing with the run."""
    from cvj_ros.nodes import monitor_node as mn
    from cvj_ros.nodes.cdr import JointStateEncoder, WrenchStampedEncoder
    node = MonitorNode(context=ctx, parameter_overrides=[
        Parameter('publish_every', value=10**9), Parameter('capacity', value=500)])
    try:
        js = JointStateEncoder(['a', 'b'])
        we = WrenchStampedEncoder('shaft')
        for k in range(2500):
            sec, ns = divmod(k * 1_000_000, 10**9)
            node._on_joint_states_raw(js.encode(sec, ns, [0.0, 1.0], [40.0, 41.0], [1.0, 2.0]))
            node._collect_engine(we.encode(sec, ns, 0, 0, 0, 0, 0, 5.0))
            assert len(node._js_batch) < mn.MAX_COLLECTED
            assert len(node._engine_batch) < mn.MAX_COLLECTED and not node._load_batch
        assert node.samples + len(node._js_batch) == 2500 and node.published == 0
        t, z = node.engine_torque.window(1e9)           # reading takes the rest
        assert t.size == 500 and t[-1] == pytest.approx(2.499) and (z == 5.0).all()
        assert node.samples == 2500 and node._js_batch == []
    finally:
        node.destroy_node()


def test_bulk_reading_gives_the_statuses_of_reading_one_by_one(ctx, monkeypatch):
    """The collected samples are read as blocks (cvj_ros.nodes.cdr.read_joint_state_block,
    read_wrench_torque_z_block); a block breaks where the names or array lengths change.
    The statuses must be those of feeding the same samples one at a time through
    _on_joint_states (the path for samples that are not one layout)."""
    import numpy as np

    from cvj_ros.nodes.cdr import JointStateDecoder, JointStateEncoder, WrenchStampedEncoder
    from cvj_ros.nodes import monitor_node as mn
    from cvj_ros.nodes.diagnostics import Status
    blocks: list[int] = []

    def counted(batch, decoder, **kw):
        block = read(batch, decoder, **kw)
        blocks.append(0 if block is None else len(batch))
        return block
    read = mn.read_joint_state_block
    monkeypatch.setattr(mn, 'read_joint_state_block', counted)
    params = [Parameter('publish_every', value=10**9), Parameter('window', value=0.25)]
    bulk = MonitorNode(context=ctx, parameter_overrides=params)
    single = MonitorNode(context=ctx, parameter_overrides=params)
    try:
        enc3 = JointStateEncoder(['a', 'b', 'c'], 'driveline')
        enc2 = JointStateEncoder(['a', 'b'], 'driveline')
        we = WrenchStampedEncoder('shaft')
        decode = JointStateDecoder().decode
        samples = []
        for k in range(700):
            sec, ns = divmod(k * 1_000_000, 10**9)
            t = k * 1e-3
            enc = enc2 if 300 <= k < 320 else enc3          # names change twice
            w = 50 + 5 * np.sin(2 * np.pi * 7 * t + np.arange(enc.n))
            samples.append(enc.encode(sec, ns, w * t, w, -w))
            bulk._on_joint_states_raw(samples[-1])
            bulk._collect_engine(we.encode(sec, ns, 0, 0, 0, 0, 0, 10 + t))
            bulk._collect_load(we.encode(sec, ns, 0, 0, 0, 0, 0, 20 - t))
            if k % 97 == 0:
                bulk.take_samples()                          # blocks of different sizes
        for k, data in enumerate(samples):
            single._on_joint_states(decode(data), publish=False)
            single._on_torque_raw(we.encode(*divmod(k * 1_000_000, 10**9), 0, 0, 0, 0, 0, 10 + k * 1e-3),
                                  single._engine_torque)
            single._on_torque_raw(we.encode(*divmod(k * 1_000_000, 10**9), 0, 0, 0, 0, 0, 20 - k * 1e-3),
                                  single._load_torque)
        got, want = bulk.compute(), single.compute()
        assert all(isinstance(st, Status) for st in got)
        assert [st.name for st in got] == ['monitor: a', 'monitor: b', 'monitor: c', 'monitor: torques']
        assert got == want
        assert bulk.samples == single.samples == 700
        assert sum(blocks) > 600 and 0 in blocks      # mostly blocks; the name changes one by one
    finally:
        bulk.destroy_node()
        single.destroy_node()
