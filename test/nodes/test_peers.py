"""Run identity by publisher (cvj_ros.nodes.peers; it replaced the run token in
header.frame_id): plain frame names on everything the nodes publish, the graph helpers, the
rule in each node that checks it, in-process - the coupling node (a publisher that appears
after step 0 is named as an intruder, checked against the closed-form momentum balance),
engine/load responders, monitor_node - and BagRecorder(run_only=True): malformed messages,
joint states of other names, loop-topic messages while two publishers are matched and a
/clock going backwards never reach the bag."""
from __future__ import annotations

import importlib.util
import time
from pathlib import Path

import pytest
import yaml

rclpy = pytest.importorskip('rclpy')
from builtin_interfaces.msg import Time  # noqa: E402
from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from geometry_msgs.msg import WrenchStamped  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rclpy.serialization import serialize_message  # noqa: E402
from rosgraph_msgs.msg import Clock  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402
from std_msgs.msg import Float64, String  # noqa: E402

from cvj_ros import bag  # noqa: E402
from cvj_ros.nodes import peers  # noqa: E402
from cvj_ros.nodes.common import (JointStateEncoder, decode_wrench_header_torque_z,  # noqa: E402
                                  make_executor)
from cvj_ros.nodes.coupling_node import CouplingNode  # noqa: E402
from cvj_ros.nodes.qos import DATA_QOS, LATCHED_QOS  # noqa: E402

pytestmark = pytest.mark.ros

# the two-mass scene and its constants (one definition: test/nodes/test_coupling_node.py)
_tm_spec = importlib.util.spec_from_file_location(
    '_two_mass', Path(__file__).resolve().parents[1] / 'nodes' / 'test_coupling_node.py')
_two_mass = importlib.util.module_from_spec(_tm_spec)
_tm_spec.loader.exec_module(_two_mass)
J1, J2, T_LOAD, W0 = _two_mass.J1, _two_mass.J2, _two_mass.T_LOAD, _two_mass.W0
T_ENGINE = 150.0                 # N m (the answerers' constant engine torque)
DURATION, H = 0.02, 0.001       # s


# --- the graph helpers -------------------------------------------------------------------------

def test_publisher_endpoints_name_nodes_and_gids(ctx) -> None:
    a = rclpy.create_node('peer_a', context=ctx)
    b = rclpy.create_node('peer_b', namespace='/ns', context=ctx)
    try:
        a.create_publisher(WrenchStamped, '/engine/wrench', DATA_QOS)
        b.create_publisher(WrenchStamped, '/engine/wrench', DATA_QOS)
        deadline = time.monotonic() + 5
        while len(peers.publisher_endpoints(a, '/engine/wrench')) < 2 and time.monotonic() < deadline:
            time.sleep(0.02)
        eps = peers.publisher_endpoints(a, '/engine/wrench')
        assert sorted(e.node for e in eps) == ['/ns/peer_b', '/peer_a']
        assert all(len(e.gid) >= 32 and int(e.gid, 16) >= 0 for e in eps) and eps[0].gid != eps[1].gid
        known = frozenset(e.gid for e in eps if e.node == '/peer_a')
        assert [e.node for e in peers.strangers(eps, known)] == ['/ns/peer_b']
        text = peers.describe(eps)
        assert '/peer_a (gid ' in text and '/ns/peer_b (gid ' in text
        assert peers.describe([]) == 'none in the ROS graph yet'
    finally:
        a.destroy_node()
        b.destroy_node()


def test_other_type_publishers_names_a_publisher_of_another_type(ctx) -> None:
    """A std_msgs/String publisher on /load/wrench: a WrenchStamped subscription never matches
    it (its publisher count stays 0), the graph names it with its type."""
    a = rclpy.create_node('observer', context=ctx)
    b = rclpy.create_node('wrong_stack', context=ctx)
    try:
        assert peers.other_type_publishers(a, '/load/wrench') == ''
        assert peers.other_type_publishers(None, '/load/wrench') == ''
        b.create_publisher(String, '/load/wrench', DATA_QOS)
        b.create_publisher(WrenchStamped, '/engine/wrench', DATA_QOS)
        deadline = time.monotonic() + 5
        while not peers.other_type_publishers(a, '/load/wrench') and time.monotonic() < deadline:
            time.sleep(0.02)
        assert peers.other_type_publishers(a, '/load/wrench') == '/wrong_stack as std_msgs/msg/String'
        assert peers.other_type_publishers(a, '/engine/wrench') == ''
    finally:
        a.destroy_node()
        b.destroy_node()


def test_joint_state_encoder_with_plain_frame_matches_rclpy() -> None:
    import numpy as np
    from rclpy.serialization import deserialize_message
    enc = JointStateEncoder(['crank', 'wheel'], 'driveline')
    assert enc.ok
    msg = deserialize_message(enc.encode(0, 5, np.array([1.0, 2.0]), np.zeros(2), np.zeros(2)), JointState)
    assert msg.header.frame_id == 'driveline' and list(msg.name) == ['crank', 'wheel']


# --- coupling node ----------------------------------------------------------------------------

def scene_file(tmp_path: Path) -> str:
    return _two_mass.scene_file(tmp_path, DURATION, H, name='two_mass_peers')


class Answerers:
    """Engine and load answerers in one test node; every answer echoes the joint-state stamp
    with frame_id ``frame(k)`` for joint state k (constant torques); ``on_state(k)`` is
    called first."""

    def __init__(self, ctx, frame=lambda k: '', on_state=None) -> None:
        self.node = rclpy.create_node('answerers', context=ctx)
        self.pubs = {'engine': self.node.create_publisher(WrenchStamped, '/engine/wrench', DATA_QOS),
                     'load': self.node.create_publisher(WrenchStamped, '/load/wrench', DATA_QOS)}
        self.js: list[JointState] = []
        self.scene: list[String] = []
        self.diag: list[DiagnosticArray] = []
        self.frame, self.on_state = frame, on_state
        self.node.create_subscription(JointState, '/driveline/joint_states', self._on_js, DATA_QOS)
        self.node.create_subscription(String, '/driveline/scene', self.scene.append, LATCHED_QOS)
        self.node.create_subscription(DiagnosticArray, '/diagnostics', self.diag.append, DATA_QOS)

    def _on_js(self, msg: JointState) -> None:
        k = len(self.js)
        if self.on_state is not None:
            self.on_state(k)
        self.js.append(msg)
        for topic, pub in self.pubs.items():
            w = WrenchStamped()
            w.header.stamp = msg.header.stamp
            w.header.frame_id = self.frame(k)
            w.wrench.torque.z = T_ENGINE if topic == 'engine' else T_LOAD
            pub.publish(w)


def run_coupling(ctx, tmp_path: Path, peers_: Answerers, timeout: float = 8.0, **params) -> CouplingNode:
    overrides = [Parameter('scene', value=scene_file(tmp_path)), Parameter('min_subscribers', value=1)]
    overrides += [Parameter(k, value=v) for k, v in params.items()]
    node = CouplingNode(context=ctx, parameter_overrides=overrides)
    ex = make_executor('events', ctx)
    ex.add_node(peers_.node)
    ex.add_node(node)
    t0 = time.monotonic()
    try:
        while node.exit_code is None:
            assert time.monotonic() - t0 < timeout, 'coupling node did not finish'
            ex.spin_once(timeout_sec=0.05)
        # every state the node published is delivered (its exit follows the publication of
        # the last one; a fixed number of spins stood for "long enough")
        t1 = time.monotonic()
        while len(peers_.js) < node.joint_states_published and time.monotonic() - t1 < 10.0:
            ex.spin_once(timeout_sec=0.01)
        for _ in range(5):
            ex.spin_once(timeout_sec=0.01)
    finally:
        ex.shutdown()
        peers_.node.destroy_node()
        node.destroy_node()
    return node


def momentum_ok(js: JointState) -> bool:
    """Closed form: d/dt (J1 w1 + J2 w2) = T_engine - T_load for constant torques (the
    spring and damper are internal), so at every stamp the momentum is exactly known."""
    t = js.header.stamp.sec + 1e-9 * js.header.stamp.nanosec
    momentum = J1 * js.velocity[0] + J2 * js.velocity[1]
    return momentum == pytest.approx((J1 + J2) * W0 + (T_ENGINE - T_LOAD) * t, rel=1e-8)


def test_coupling_node_publishes_plain_frames_and_no_run_token(ctx, tmp_path: Path) -> None:
    answerers = Answerers(ctx, frame=lambda k: 'anything@5eed1234' if k % 2 else '')
    node = run_coupling(ctx, tmp_path, answerers)
    assert node.exit_code == 0, node.error_message
    assert len(answerers.js) == round(DURATION / H) + 1
    assert {js.header.frame_id for js in answerers.js} == {'driveline'}
    # answers are taken whatever their frame_id: an outside node only echoes the stamp
    assert all(momentum_ok(js) for js in answerers.js)
    scene = yaml.safe_load(answerers.scene[0].data)
    assert 'run_token' not in scene and scene['shaft_names'] == ['engine_crank', 'wheel']
    assert {d.header.frame_id for d in answerers.diag} == {'coupling_node'}
    assert not hasattr(node, 'run_token')


def test_unanswered_state_0_beside_another_runs_publisher_names_it(ctx, tmp_path: Path) -> None:
    """Another run's engine publisher discovered only after step 0 went out (slower than the
    start settle): the node stops with the line naming that publisher as the intruder
    besides its peer and the domain, not with 'is engine_node running?' (seen in CI:
    test_faults_processes, second run on one domain)."""
    other: list = []

    def on_state(k: int) -> None:
        if not other:      # the other run's engine appears once our state 0 is out
            n = rclpy.create_node('other_runs_engine', context=ctx)
            other.append((n, n.create_publisher(WrenchStamped, '/engine/wrench', DATA_QOS)))
    try:
        node = run_coupling(ctx, tmp_path, Answerers(ctx, on_state=on_state), peer_timeout=0.5)
    finally:
        for n, _pub in other:
            n.destroy_node()
    assert node.exit_code == 1
    assert '/engine/wrench: intruder /other_runs_engine (gid ' in node.error_message, node.error_message
    assert "this run's peer /answerers (gid " in node.error_message
    assert 'ROS_DOMAIN_ID=' in node.error_message and '\n' not in node.error_message


# --- engine / load responders -----------------------------------------------------------------

class _Capture:
    def __init__(self) -> None:
        self.sent: list[tuple[int, bytes, float]] = []

    def publish(self, data) -> None:
        self.sent.append(decode_wrench_header_torque_z(
            data if isinstance(data, bytes) else serialize_message(data)))


def _js(k: int, frame: str = 'driveline', names=('engine_crank', 'wheel')) -> JointState:
    msg = JointState(name=list(names), position=[0.1 * k] * len(names), velocity=[30.0] * len(names))
    msg.header.stamp = Time(sec=0, nanosec=k * 1_000_000)
    msg.header.frame_id = frame
    return msg


def test_recorder_tells_which_answers_are_behind_the_joint_states(ctx, tmp_path: Path) -> None:
    """cvj-sim record --until-idle waits while an answer topic's newest stamp is behind the
    newest joint state (commands/record.behind_topics on BagRecorder.last_stamp)."""
    from cvj_ros.commands.record import behind_topics
    node = rclpy.create_node('rec_behind_test', context=ctx)
    writer = bag.BagWriter(tmp_path / 'b')
    try:
        rec = bag.BagRecorder(node, writer, discover_period=0.0)
        feed = _feeder(rec)
        for k in range(3):
            feed('/clock', Clock(clock=Time(sec=0, nanosec=k * 1_000_000)))
            feed('/driveline/joint_states', _js(k))
            feed('/load/wrench', _wrench('wheel', k))
            if k < 2:
                feed('/engine/wrench', _wrench('engine_crank', k))
        assert rec.last_stamp['/driveline/joint_states'] == 2_000_000
        assert behind_topics(rec.last_stamp) == ['/engine/wrench']
        feed('/engine/wrench', _wrench('engine_crank', 2))
        assert behind_topics(rec.last_stamp) == []
    finally:
        writer.close()
        node.destroy_node()


def test_coupling_node_counts_graph_subscriptions_its_writers_have_not_matched(
        ctx, tmp_path: Path, monkeypatch) -> None:
    """The hand-start gate's condition (CouplingNode.unmatched_subscriptions): a subscription
    the ROS graph shows on an own data topic, of its type and a compatible QoS, that the
    writer has not matched; an incompatible one (transient_local against the volatile writer)
    never matches and is not waited for."""
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    node = CouplingNode(context=ctx, parameter_overrides=[
        Parameter('scene', value=scene_file(tmp_path)), Parameter('min_subscribers', value=1)])
    reader = rclpy.create_node('clock_reader', context=ctx)
    ex = make_executor('events', ctx)
    try:
        ex.add_node(node)
        ex.add_node(reader)
        reader.create_subscription(Clock, '/clock', lambda m: None, DATA_QOS)
        reader.create_subscription(Clock, '/clock', lambda m: None, QoSProfile(
            depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL))
        deadline = time.monotonic() + 30.0       # discovery within one process (generous)
        while (len(node.get_subscriptions_info_by_topic('/clock')) < 2
               or node.clock_pub.get_subscription_count() < 1):
            assert time.monotonic() < deadline, 'the readers were not discovered'
            ex.spin_once(timeout_sec=0.02)
        assert node.unmatched_subscriptions() == []
        real = node.get_subscriptions_info_by_topic
        extra = [i for i in real('/clock') if i.qos_profile.durability == DurabilityPolicy.VOLATILE]
        monkeypatch.setattr(node, 'get_subscriptions_info_by_topic',
                            lambda t: list(real(t)) + (extra if t == '/clock' else []))
        assert node.unmatched_subscriptions() == ['/clock (1 of 2 subscriptions matched)']
    finally:
        ex.shutdown()
        reader.destroy_node()
        node.destroy_node()


def test_coupling_node_waits_until_the_recorders_readers_match_what_it_sees(ctx, tmp_path: Path) -> None:
    """The reader side of the hand-start gate: `cvj-sim record`'s ReadyAnnouncer reports its
    readers' matches whenever they change; the coupling node compares them with the
    publishers in its graph (CouplingNode.recorders_not_ready): a recorder not heard from, a
    publisher not matched yet (here a throttle publisher that appears after the recorder
    said all matched), a best-effort publisher (never matches a reliable reader: not waited
    for); malformed reports are ignored."""
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    from cvj_ros.commands.record import ReadyAnnouncer
    node = CouplingNode(context=ctx, parameter_overrides=[
        Parameter('scene', value=scene_file(tmp_path)), Parameter('min_subscribers', value=1)])
    rec_node = rclpy.create_node('cvj_recorder', context=ctx)
    other = rclpy.create_node('late_driver', context=ctx)
    writer = bag.BagWriter(tmp_path / 'b')
    ex = make_executor('events', ctx)

    def spin_until(cond, what: str) -> None:
        deadline = time.monotonic() + 30.0       # discovery within one process (generous)
        while not cond():
            assert time.monotonic() < deadline, what
            ready.poll()
            ex.spin_once(timeout_sec=0.02)
    try:
        rec = bag.BagRecorder(rec_node, writer, discover_period=0.0)
        other.create_publisher(Clock, '/clock', QoSProfile(depth=1, reliability=ReliabilityPolicy.BEST_EFFORT))

        class _Host:        # what cvj-sim record's loop holds: .node and .recorder
            pass
        host = _Host()
        host.node, host.recorder = rec_node, rec
        for n in (node, rec_node, other):
            ex.add_node(n)
        assert node.recorders_not_ready() == []          # no recorder in the graph
        ready = ReadyAnnouncer(host)
        spin_until(lambda: node.count_publishers('/driveline/recorder_ready') == 1, 'ready publisher')
        spin_until(lambda: not node.recorders_not_ready(), str(node.recorders_not_ready()))
        assert any(i.node_name == 'best_effort_clock' or i.node_name == 'late_driver'
                   for i in node.get_publishers_info_by_topic('/clock'))
        (token, matched), = node.recorder_matches.items()
        assert 'cvj_recorder pid' in token and matched['/clock'] == 1    # the coupling node's own
        other.create_publisher(Float64, '/engine/throttle', DATA_QOS)     # a driver appears
        spin_until(lambda: node.count_publishers('/engine/throttle') == 1, 'throttle publisher')
        if node.recorder_matches[token].get('/engine/throttle', 0) < 1:  # not matched by the recorder yet
            assert any('/engine/throttle (0 of 1 publishers matched' in line for line in node.recorders_not_ready())
        spin_until(lambda: not node.recorders_not_ready(), str(node.recorders_not_ready()))
        for bad in ('', 'not json', '[]', '{"recorder": "x"}', '{"recorder": "x", "matched": {"/clock": "1"}}'):
            node._on_recorder_ready(String(data=bad))
        assert list(node.recorder_matches) == [token]
    finally:
        ex.shutdown()
        writer.close()
        for n in (other, rec_node, node):
            n.destroy_node()


def test_load_node_answers_with_its_shaft_frame_and_not_beside_a_second_publisher(ctx, tmp_path: Path) -> None:
    """load_node answers every joint state with frame_id = its shaft whatever the state's
    frame_id; while /driveline/joint_states has two publishers it answers none (counted in
    foreign_states): whose they are cannot be told."""
    from cvj_ros.nodes.load_node import LoadNode
    node = LoadNode(context=ctx, parameter_overrides=[Parameter('scene', value=scene_file(tmp_path))])
    pubs = [rclpy.create_node(f'js_pub_{i}', context=ctx) for i in range(2)]
    try:
        cap = node.wrench_pub = _Capture()
        for k, frame in enumerate(['driveline', 'driveline@5eed1234', '']):
            node._on_joint_states_raw(serialize_message(_js(k, frame)))
        assert [(s, f.decode()) for s, f, _ in cap.sent] == [(0, 'wheel'), (1_000_000, 'wheel'),
                                                           (2_000_000, 'wheel')]
        assert all(tz == pytest.approx(T_LOAD) for *_, tz in cap.sent)
        for p in pubs:
            p.create_publisher(JointState, '/driveline/joint_states', DATA_QOS)
        deadline = time.monotonic() + 5
        while node.js_sub.get_publisher_count() < 2 and time.monotonic() < deadline:
            time.sleep(0.02)
        node._on_joint_states_raw(serialize_message(_js(3)))
        assert len(cap.sent) == 3 and node.foreign_states == 1
    finally:
        for p in pubs:
            p.destroy_node()
        node.destroy_node()


def test_nodes_have_no_run_token_parameter(ctx, tmp_path: Path) -> None:
    from cvj_ros.nodes import coupling_node, engine_node, load_node, monitor_node
    for mod in (coupling_node, engine_node, load_node, monitor_node):
        assert 'run_token' not in {p.name for p in mod.PARAMS}, mod.__name__


# --- monitor -------------------------------------------------------------------------------

def test_monitor_ignores_loop_messages_while_two_publishers(ctx, tmp_path: Path) -> None:
    from cvj_ros.nodes.monitor_node import MonitorNode
    node = MonitorNode(context=ctx, parameter_overrides=[Parameter('publish_every', value=10**6)])
    pubs = [rclpy.create_node(f'js_pub_{i}', context=ctx) for i in range(2)]
    try:
        data = serialize_message(_js(0))
        node._on_joint_states_raw(data)
        assert len(node._js_batch) == 1 and node.foreign_messages == 0
        for p in pubs:
            p.create_publisher(JointState, '/driveline/joint_states', DATA_QOS)
        deadline = time.monotonic() + 5
        while node.js_sub.get_publisher_count() < 2 and time.monotonic() < deadline:
            time.sleep(0.02)
        node._on_joint_states_raw(data)
        assert len(node._js_batch) == 1 and node.foreign_messages == 1
    finally:
        for p in pubs:
            p.destroy_node()
        node.destroy_node()


# --- recorder --------------------------------------------------------------------------------

def _feeder(rec: bag.BagRecorder):
    def feed(topic: str, msg) -> bool:
        msgtype = bag.topic_type(topic)
        data = msg if isinstance(msg, bytes) else serialize_message(msg)
        return rec._on_message(topic, msgtype, data, stamped=msgtype in bag.STAMPED_TYPES,
                               is_clock=topic == bag.CLOCK_TOPIC)
    return feed


def _wrench(frame: str, k: int) -> WrenchStamped:
    w = WrenchStamped()
    w.header.stamp = Time(sec=0, nanosec=k * 1_000_000)
    w.header.frame_id = frame
    return w


def test_recorder_drops_malformed_and_foreign_layouts(ctx, tmp_path: Path) -> None:
    node = rclpy.create_node('rec_run_only_test', context=ctx)
    writer = bag.BagWriter(tmp_path / 'b')
    try:
        rec = bag.BagRecorder(node, writer, discover_period=0.0, run_only=True)
        feed = _feeder(rec)
        bad = [b'', b'\x00', b'\xff' * 40, b'\x00\x01\x00\x00' + b'\xff' * 12]
        for topic in ('/driveline/joint_states', '/engine/wrench', '/clock', '/diagnostics',
                      '/driveline/scene', '/engine/throttle'):
            for data in bad:
                feed(topic, data)
        feed('/driveline/scene', String(data=yaml.safe_dump({'shaft_names': ['engine_crank', 'wheel']})))
        feed('/driveline/scene', String(data=yaml.safe_dump({'shaft_names': ['x']})))   # a second
        # another publisher's /clock, the only one before our states: kept back, not ours
        feed('/clock', Clock(clock=Time(sec=0, nanosec=50_000_000)))
        for k in range(3):
            feed('/clock', Clock(clock=Time(sec=0, nanosec=k * 1_000_000)))
            feed('/driveline/joint_states', _js(k))
            # foreign JointStates: wrong names, wrong sizes, 1e5 entries
            feed('/driveline/joint_states', _js(k, names=('intruder_0', 'intruder_1', 'intruder_2')))
            big = JointState(name=[f'n{i}' for i in range(100_000)])
            feed('/driveline/joint_states', big)
            feed('/load/wrench', _wrench('wheel', k))
            feed('/engine/wrench', _wrench('engine_crank', k))
        feed('/diagnostics', DiagnosticArray())
        rec.loop_ended = True
        feed('/clock', Clock(clock=Time(sec=0, nanosec=3_000_000)))
        # a Float64 is any 8 bytes after the encapsulation: the last one is a number (NaN),
        # recorded as sent (engine_node rejects it)
        assert rec.counts == {'/driveline/scene': 1, '/clock': 3, '/driveline/joint_states': 3,
                              '/load/wrench': 3, '/engine/wrench': 3, '/diagnostics': 1,
                              '/engine/throttle': 1}
        assert rec.foreign == {'/driveline/scene': 1, '/driveline/joint_states': 3, '/clock': 2}
        # 1e5 names: beyond the decoder's limit, malformed
        assert rec.malformed == {'/driveline/joint_states': 4 + 3, '/engine/wrench': 4, '/clock': 4,
                                 '/diagnostics': 4, '/driveline/scene': 4, '/engine/throttle': 3}
        rec.destroy()
        writer.close()
        data = bag.read_bag(tmp_path / 'b')
        assert [round(v * 1e9) for v in data['/clock'].value] == [0, 1_000_000, 2_000_000]
        assert data['/driveline/joint_states'].names == ['engine_crank', 'wheel']
    finally:
        writer.close()
        node.destroy_node()


def test_recorder_drops_loop_messages_while_two_publishers(ctx, tmp_path: Path) -> None:
    node = rclpy.create_node('rec_two_pubs_test', context=ctx)
    writer = bag.BagWriter(tmp_path / 'b')
    pubs = [rclpy.create_node(f'w_pub_{i}', context=ctx) for i in range(2)]
    try:
        rec = bag.BagRecorder(node, writer, discover_period=0.0, run_only=True)
        feed = _feeder(rec)
        assert feed('/engine/wrench', _wrench('engine_crank', 0))
        for p in pubs:
            p.create_publisher(WrenchStamped, '/engine/wrench', DATA_QOS)
        deadline = time.monotonic() + 5
        while rec._subs['/engine/wrench'].get_publisher_count() < 2 and time.monotonic() < deadline:
            time.sleep(0.02)
        assert not feed('/engine/wrench', _wrench('engine_crank', 1))
        assert feed('/diagnostics', DiagnosticArray())      # several publishers by design
        for p in pubs[1:]:                                  # the second one leaves again
            p.destroy_node()
        del pubs[1:]
        deadline = time.monotonic() + 5
        while rec._subs['/engine/wrench'].get_publisher_count() > 1 and time.monotonic() < deadline:
            time.sleep(0.02)
        assert not feed('/engine/wrench', _wrench('engine_crank', 2))   # for the rest of the run
        # joint states: a copy of a stamp already written is not the run's
        assert feed('/driveline/joint_states', _js(0)) and not feed('/driveline/joint_states', _js(0))
        assert rec.foreign == {'/engine/wrench': 2, '/driveline/joint_states': 1}
        rec.destroy()
    finally:
        writer.close()
        for p in pubs:
            p.destroy_node()
        node.destroy_node()


def test_recorder_keeps_its_own_clock_beside_a_clock_going_backwards(ctx, tmp_path: Path) -> None:
    """An intruder's /clock running backwards from 100 s interleaved with the run's own: every
    own /clock is written (0, h, 2h, ...), every intruder sample is counted as not the run's."""
    node = rclpy.create_node('rec_clock_back_test', context=ctx)
    writer = bag.BagWriter(tmp_path / 'b')
    try:
        rec = bag.BagRecorder(node, writer, discover_period=0.0, run_only=True)
        feed = _feeder(rec)
        n = 50
        for k in range(n):
            feed('/clock', Clock(clock=Time(sec=100 - k, nanosec=0)))           # intruder
            feed('/clock', Clock(clock=Time(sec=0, nanosec=k * 1_000_000)))      # own
            feed('/driveline/joint_states', _js(k))
            feed('/clock', Clock(clock=Time(sec=0, nanosec=max(k - 3, 0) * 1_000_000)))   # intruder
        rec.loop_ended = True
        assert rec.counts['/clock'] == n and rec.foreign == {'/clock': 2 * n}
        rec.destroy()
        writer.close()
        values = bag.read_bag(tmp_path / 'b', ['/clock'])['/clock'].value
        assert [round(v * 1e9) for v in values] == [k * 1_000_000 for k in range(n)]
    finally:
        writer.close()
        node.destroy_node()


def test_recorder_clock_repeats_dropped_and_early_clock_kept_back(ctx, tmp_path: Path) -> None:
    """/clock of another publisher with the SAME values (an intruder copying the run's
    clock): a value not newer than the last written is dropped and counted. A run's own /clock ahead of its joint states by more than one step (the
    recorder took the /clock queue before the state queue) is kept back, not dropped, and
    written once the state arrives: the bag's /clock is exactly 0, h, 2h, ... ."""
    node = rclpy.create_node('rec_clock_test', context=ctx)
    writer = bag.BagWriter(tmp_path / 'b')
    try:
        rec = bag.BagRecorder(node, writer, discover_period=0.0, run_only=True)

        def feed(topic: str, msg) -> None:
            msgtype = bag.topic_type(topic)
            rec._on_message(topic, msgtype, serialize_message(msg),
                            stamped=msgtype in bag.STAMPED_TYPES, is_clock=topic == bag.CLOCK_TOPIC)

        def clock(k: int) -> Clock:
            return Clock(clock=Time(sec=0, nanosec=k * 1_000_000))

        for k in range(3):
            feed('/clock', clock(k))
            feed('/driveline/joint_states', _js(k))
            feed('/clock', clock(k))                 # the intruder's copy: a repeat
        # the recorder is behind on joint states: /clock 3, 4, 5 come first
        for k in (3, 4, 5):
            feed('/clock', clock(k))
        for k in (3, 4, 5):
            feed('/driveline/joint_states', _js(k))
            feed('/clock', clock(k))                 # repeats again
        rec.loop_ended = True
        assert rec.counts['/clock'] == 6 and rec.counts['/driveline/joint_states'] == 6
        assert rec.foreign == {'/clock': 6}
        rec.destroy()
        writer.close()
        values = bag.read_bag(tmp_path / 'b', ['/clock'])['/clock'].value
        assert [round(v * 1e9) for v in values] == [k * 1_000_000 for k in range(6)]
    finally:
        writer.close()
        node.destroy_node()


def test_recorder_keeps_a_whole_pending_clock_chain(ctx, tmp_path: Path) -> None:
    """When a whole short run's /clock came in before its first two joint states (a loop
    faster than the recorder's wake-ups, or a joint state repaired late), the samples that
    continue the chain s0, s0 + step, ... are ours and kept; another run's /clock kept back
    (50 ms, not connected to the chain) and a duplicate value are still dropped."""
    node = rclpy.create_node('rec_chain_test', context=ctx)
    writer = bag.BagWriter(tmp_path / 'b')
    try:
        rec = bag.BagRecorder(node, writer, discover_period=0.0, run_only=True)

        def feed(topic: str, msg) -> None:
            msgtype = bag.topic_type(topic)
            rec._on_message(topic, msgtype, serialize_message(msg),
                            stamped=msgtype in bag.STAMPED_TYPES, is_clock=topic == bag.CLOCK_TOPIC)

        feed('/clock', Clock(clock=Time(sec=0, nanosec=50_000_000)))     # another run's
        for k in range(21):                                             # the whole run: 0..20 ms
            feed('/clock', Clock(clock=Time(sec=0, nanosec=k * 1_000_000)))
        feed('/clock', Clock(clock=Time(sec=0, nanosec=7_000_000)))      # duplicate value
        for k in range(21):
            feed('/driveline/joint_states', _js(k))
        rec.loop_ended = True                        # the 50 ms sample is still kept back: counted
        assert rec.counts['/clock'] == 21 and rec.foreign == {'/clock': 2}
        rec.destroy()
        writer.close()
        clock = bag.read_bag(tmp_path / 'b', ['/clock'])['/clock']
        assert [round(v * 1e9) for v in clock.value] == [k * 1_000_000 for k in range(21)]
    finally:
        writer.close()
        node.destroy_node()


# --- launch file and `cvj-sim record --run-only` ------------------------------------------------

def _launch_module():
    import importlib.util
    path = Path(__file__).resolve().parents[2] / 'launch' / 'driveline.launch.py'
    spec = importlib.util.spec_from_file_location('driveline_launch_peers', path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_launch_gives_no_token_and_records_the_run_only() -> None:
    mod = _launch_module()
    params = mod.node_parameters({})
    assert len(params) == 4 and all('run_token' not in p for p in params.values())
    assert 'run_token' not in mod.ARGUMENTS
    assert mod.recorder_arguments({})[-1] == '--run-only'


def test_record_has_no_run_token_option(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from cvj_ros.cli import main
    with pytest.raises(SystemExit) as exc:
        main(['record', str(tmp_path / 'rec'), '--run-token', '0badc0de', '--duration', '0.1'])
    assert exc.value.code == 2 and '--run-token' in capsys.readouterr().err
    assert not (tmp_path / 'rec' / 'bag').exists()
