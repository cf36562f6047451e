"""Hostile peers against the lockstep loop, in-process (docs/robustness.md, "Hostile peers").

A coupling node runs a two-mass scene for 20 ms at h = 1 ms with honest engine and load
answerers of constant torque (150 and 100 N m), so every joint state has a closed form: the
momentum J1 w1 + J2 w2 = (J1 + J2) w0 + (T_e - T_l) t_k (the spring and damper are internal).
One integrated foreign answer (50 N m for 1 ms) moves it by 0.05 kg m^2/s, far outside the
1e-8 relative check. Each attack (hostile_peer.HostilePeer) must leave every published state
on that line, and the run either ends normally with the undisturbed result or stops with one
line naming the intruder and its topic. Malformed CDR on every input topic of the coupling,
engine, load and monitor nodes is dropped, counted, named once, and never a traceback.
"""
from __future__ import annotations

import importlib.util
import time
from pathlib import Path

import pytest

rclpy = pytest.importorskip('rclpy')
from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from geometry_msgs.msg import WrenchStamped  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402
from std_msgs.msg import Float64, String  # noqa: E402

from cvj_ros.nodes.common import make_executor  # noqa: E402
from cvj_ros.nodes.coupling_node import CouplingNode  # noqa: E402
from cvj_ros.nodes.qos import DATA_QOS  # noqa: E402

pytestmark = pytest.mark.ros

_spec = importlib.util.spec_from_file_location('_hostile_peer', Path(__file__).with_name('hostile_peer.py'))
hostile_peer = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(hostile_peer)
HostilePeer, malformed_samples = hostile_peer.HostilePeer, hostile_peer.malformed_samples

# the two-mass scene and its constants (one definition: test/nodes/test_coupling_node.py)
_tm_spec = importlib.util.spec_from_file_location(
    '_two_mass', Path(__file__).resolve().parents[1] / 'nodes' / 'test_coupling_node.py')
_two_mass = importlib.util.module_from_spec(_tm_spec)
_tm_spec.loader.exec_module(_two_mass)
J1, J2, T_LOAD, W0 = _two_mass.J1, _two_mass.J2, _two_mass.T_LOAD, _two_mass.W0
T_ENGINE = 150.0                 # N m (the answerers' constant engine torque)
DURATION, H = 0.02, 0.001        # s
N_STEPS = round(DURATION / H)


def scene_file(tmp_path: Path) -> str:
    return _two_mass.scene_file(tmp_path, DURATION, H, name='two_mass_hostile')


class HonestPeers:
    """Engine and load answerers of constant torque in one node; ``inject(k)`` lists
    (topic, raw bytes) sent from the same publishers right before the answers to state k;
    ``before(k)`` is called first (an attack starts there)."""

    def __init__(self, ctx, inject=None, before=None) -> None:
        self.before = before
        self.node = rclpy.create_node('honest_peers', context=ctx)
        self.pubs = {'/engine/wrench': self.node.create_publisher(WrenchStamped, '/engine/wrench', DATA_QOS),
                     '/load/wrench': self.node.create_publisher(WrenchStamped, '/load/wrench', DATA_QOS)}
        self.js: list[JointState] = []
        self.inject = inject
        self.node.create_subscription(JointState, '/driveline/joint_states', self._on_js, DATA_QOS)

    def _on_js(self, msg: JointState) -> None:
        k = len(self.js)
        if self.before is not None:
            self.before(k)
        self.js.append(msg)
        for topic, data in (self.inject(k) if self.inject else ()):
            self.pubs[topic].publish(data)
        for topic, torque in (('/engine/wrench', T_ENGINE), ('/load/wrench', T_LOAD)):
            w = WrenchStamped()
            w.header.stamp = msg.header.stamp
            w.header.frame_id = msg.name[0] if topic == '/engine/wrench' else msg.name[-1]
            w.wrench.torque.z = torque
            self.pubs[topic].publish(w)


def on_the_line(js: JointState) -> bool:
    """The closed-form momentum balance at the state's stamp."""
    t = js.header.stamp.sec + js.header.stamp.nanosec * 1e-9
    momentum = J1 * js.velocity[0] + J2 * js.velocity[1]
    return momentum == pytest.approx((J1 + J2) * W0 + (T_ENGINE - T_LOAD) * t, rel=1e-8)


def run_loop(ctx, tmp_path: Path, *, attack=None, inject=None, extra_nodes=(), timeout: float = 15.0,
             **params):
    """Run the coupling node with honest peers; ``attack(hostile, k)`` is called at every
    joint state k the honest peers see (start an attack there). Returns (node, peers, hostile)."""
    overrides = [Parameter('scene', value=scene_file(tmp_path)), Parameter('min_subscribers', value=1),
                 Parameter('peer_timeout', value=3.0)]
    overrides += [Parameter(k, value=v) for k, v in params.items()]
    hostile = HostilePeer(ctx)
    peers = HonestPeers(ctx, inject, None if attack is None else lambda k: attack(hostile, k))
    node = CouplingNode(context=ctx, parameter_overrides=overrides)
    ex = make_executor('events', ctx)
    for n in (hostile.node, peers.node, node, *extra_nodes):
        ex.add_node(n)
    t0 = time.monotonic()
    try:
        while node.exit_code is None:
            assert time.monotonic() - t0 < timeout, 'coupling node did not finish'
            ex.spin_once(timeout_sec=0.05)
        # every state the node published is delivered (its exit follows the publication of
        # the last one; a fixed number of spins stood for "long enough")
        t1 = time.monotonic()
        while len(peers.js) < node.joint_states_published and time.monotonic() - t1 < 10.0:
            ex.spin_once(timeout_sec=0.01)
        for _ in range(5):
            ex.spin_once(timeout_sec=0.01)
    finally:
        ex.shutdown()
        for n in (hostile.node, peers.node, node, *extra_nodes):
            n.destroy_node()
    return node, peers, hostile


def assert_undisturbed_or_named(node, peers, topic: str) -> None:
    """Every state on the closed-form line; the run finished, or stopped with one line
    naming the intruder node and ``topic``."""
    assert peers.js and all(on_the_line(js) for js in peers.js)
    if node.exit_code == 0:
        assert len(peers.js) == N_STEPS + 1
        return
    assert node.exit_code == 1
    line = node.error_message
    assert '\n' not in line
    assert f'{topic}: intruder /hostile (gid ' in line, line


# --- identity: forged echo, flood, second engine, foreign joint states ---------------------

@pytest.mark.parametrize('topic', ['/engine/wrench', '/load/wrench'])
def test_forged_echo_mid_run_never_integrated(ctx, tmp_path, topic) -> None:
    def attack(hostile, k):
        if k == 5:
            hostile.forge_echo(topic)
    node, peers, hostile = run_loop(ctx, tmp_path, attack=attack)
    assert hostile.sent.get(topic, 0) >= 1
    assert_undisturbed_or_named(node, peers, topic)
    assert node.exit_code == 1 and 'stopped at t=' in node.error_message


@pytest.mark.parametrize('mode', ['lockstep', 'free-run'])
def test_forged_echo_present_at_start_is_an_ambiguity_naming_both(ctx, tmp_path, mode) -> None:
    # the intruder's publisher exists before step 0: the start check names both publishers
    # and state 0 never goes out (free-run too: before, it published state 0, then stopped
    # at its first graph check naming an intruder)
    ctx_nodes = []
    hostile = HostilePeer(ctx)
    hostile.publisher('/engine/wrench', WrenchStamped)
    ctx_nodes.append(hostile.node)
    peers = HonestPeers(ctx)
    ctx_nodes.append(peers.node)
    node = CouplingNode(context=ctx, parameter_overrides=[
        Parameter('scene', value=scene_file(tmp_path)), Parameter('min_subscribers', value=1),
        Parameter('mode', value=mode)])
    ctx_nodes.append(node)
    ex = make_executor('events', ctx)
    for n in ctx_nodes:
        ex.add_node(n)
    t0 = time.monotonic()
    try:
        while node.exit_code is None and time.monotonic() - t0 < 10:
            ex.spin_once(timeout_sec=0.05)
    finally:
        ex.shutdown()
        for n in ctx_nodes:
            n.destroy_node()
    assert node.exit_code == 1 and not peers.js and node.joint_states_published == 0
    line = node.error_message
    assert line.startswith(f'{mode}: /engine/wrench has 2 publishers: ') and '\n' not in line
    assert '/hostile (gid ' in line and '/honest_peers (gid ' in line


def test_flood_at_10_khz_never_integrated(ctx, tmp_path) -> None:
    def attack(hostile, k):
        if k == 3:
            hostile.flood('/load/wrench')
    node, peers, _hostile = run_loop(ctx, tmp_path, attack=attack)
    assert_undisturbed_or_named(node, peers, '/load/wrench')


def test_second_engine_node_mid_run_is_named(ctx, tmp_path) -> None:
    from cvj_ros.nodes.engine_node import EngineNode
    engines = []

    def attack(hostile, k):
        if k == 4 and not engines:    # a real engine_node with other parameters joins
            engines.append(EngineNode(context=ctx, parameter_overrides=[
                Parameter('scene', value=scene_file(tmp_path)), Parameter('throttle', value=0.3)]))
            executor = hostile.node.executor
            executor.add_node(engines[0])
    node, peers, _hostile = run_loop(ctx, tmp_path, attack=attack)
    for e in engines:
        e.destroy_node()
    assert peers.js and all(on_the_line(js) for js in peers.js)
    assert node.exit_code == 1 and '/engine/wrench: intruder /engine_node (gid ' in node.error_message


def test_foreign_joint_states_stop_the_run_and_are_not_answered(ctx, tmp_path) -> None:
    sent = []

    def attack(hostile, k):
        if k == 5 and not sent:
            sent.append(1)
            hostile.foreign_joint_states(4)
    # 0.5 s simulated: the loop looks at the graph every 10 ms of wall time
    node, peers, _hostile = run_loop(ctx, tmp_path, attack=attack, duration=0.5)
    assert peers.js and all(on_the_line(js) for js in peers.js if js.name == ['engine_crank', 'wheel'])
    assert node.exit_code == 1
    assert '/driveline/joint_states: intruder /hostile (gid ' in node.error_message


# --- malformed CDR on every input topic --------------------------------------------------------

@pytest.mark.parametrize('topic', ['/engine/wrench', '/load/wrench'])
def test_malformed_answers_from_the_peer_are_dropped_and_the_run_is_undisturbed(ctx, tmp_path, topic) -> None:
    samples = malformed_samples('wrench')

    def inject(k):
        return [(topic, data) for data in samples] if k in (0, 7) else ()
    node, peers, _hostile = run_loop(ctx, tmp_path, inject=inject)
    assert node.exit_code == 0, node.error_message
    assert len(peers.js) == N_STEPS + 1 and all(on_the_line(js) for js in peers.js)
    # every sample the middleware delivered before the run ended (the oversized one may
    # come after it)
    assert set(node.malformed.counts) == {topic}
    assert 2 * len(samples) - 2 <= node.malformed.counts[topic] <= 2 * len(samples)
    assert node.loop_stats()['malformed_messages'] == node.malformed.counts[topic]


def _spin(ex, cond, timeout=5.0) -> None:
    t0 = time.monotonic()
    while not cond() and time.monotonic() - t0 < timeout:
        ex.spin_once(timeout_sec=0.02)


def test_malformed_joint_states_and_throttle_never_crash_engine_and_load(ctx, tmp_path, caplog) -> None:
    from cvj_ros.nodes.engine_node import EngineNode
    from cvj_ros.nodes.load_node import LoadNode
    scene = scene_file(tmp_path)
    engine = EngineNode(context=ctx, parameter_overrides=[Parameter('scene', value=scene)])
    load = LoadNode(context=ctx, parameter_overrides=[Parameter('scene', value=scene)])
    hostile = HostilePeer(ctx)
    answers: list[WrenchStamped] = []
    listener = rclpy.create_node('listener', context=ctx)
    listener.create_subscription(WrenchStamped, '/engine/wrench', answers.append, DATA_QOS)
    listener.create_subscription(WrenchStamped, '/load/wrench', answers.append, DATA_QOS)
    ex = make_executor('events', ctx)
    for n in (engine, load, hostile.node, listener):
        ex.add_node(n)
    js_bad = malformed_samples('joint_states')
    throttle_bad = malformed_samples('float64')
    try:
        hostile.publisher('/driveline/joint_states', JointState)
        hostile.publisher('/engine/throttle', Float64)
        _spin(ex, lambda: engine.js_sub.get_publisher_count() and load.js_sub.get_publisher_count()
              and engine.throttle_sub.get_publisher_count())
        for data in js_bad:
            hostile.send('/driveline/joint_states', JointState, data)
        # Fast DDS refuses to send a sample longer than a bounded type's largest (a Float64:
        # 12 bytes); what it sent is what the node gets
        throttle_bad = [d for d in throttle_bad if hostile.send('/engine/throttle', Float64, d)]
        # a joint state without the responders' shafts
        js = JointState(name=['a', 'b'], position=[0.0, 0.0], velocity=[1.0, 1.0])
        hostile.send('/driveline/joint_states', JointState, js)
        n_js = len(js_bad) + 1
        # a Float64 is any 8 bytes after a CDR encapsulation: the others are malformed, these
        # are numbers (out of 0..1: rejected by the range check, counted apart)
        not_float = sum(1 for d in throttle_bad if len(d) < 12 or d[:2] not in (b'\x00\x00', b'\x00\x01')
                        or len(d) > 1 << 20)
        _spin(ex, lambda: engine.malformed.counts.get('/driveline/joint_states', 0) >= n_js
              and load.malformed.total >= n_js
              and engine.malformed.counts.get('/engine/throttle', 0) >= not_float)
        assert engine.exit_code is None and load.exit_code is None
        assert engine.malformed.counts == {'/driveline/joint_states': n_js,
                                           '/engine/throttle': not_float}
        assert load.malformed.counts == {'/driveline/joint_states': n_js}
        # still answering the good ones
        good = JointState(name=['engine_crank', 'wheel'], position=[0.0, 0.0], velocity=[W0, W0])
        good.header.stamp.nanosec = 5_000_000
        hostile.send('/driveline/joint_states', JointState, good)
        _spin(ex, lambda: len(answers) >= 2)
        assert sorted(a.header.stamp.nanosec for a in answers) == [5_000_000, 5_000_000]
    finally:
        ex.shutdown()
        for n in (engine, load, hostile.node, listener):
            n.destroy_node()
    assert 'Traceback' not in caplog.text


def test_malformed_inputs_never_crash_the_monitor(ctx, tmp_path) -> None:
    from cvj_ros.nodes.monitor_node import MonitorNode
    monitor = MonitorNode(context=ctx, parameter_overrides=[Parameter('publish_every', value=1)])
    hostile = HostilePeer(ctx)
    ex = make_executor('events', ctx)
    for n in (monitor, hostile.node):
        ex.add_node(n)
    plan = [('/driveline/joint_states', JointState, malformed_samples('joint_states')),
            ('/engine/wrench', WrenchStamped, malformed_samples('wrench')),
            ('/load/wrench', WrenchStamped, malformed_samples('wrench')),
            ('/diagnostics', DiagnosticArray,
             [d + b'coupling_node' for d in malformed_samples('diagnostics')]),
            ('/driveline/scene', String, malformed_samples('string'))]
    try:
        for topic, cls, _samples in plan:
            hostile.publisher(topic, cls)
        _spin(ex, lambda: all(s.get_publisher_count() for s in (monitor.js_sub, monitor.engine_sub,
                                                                 monitor.load_sub, monitor.diag_sub,
                                                                 monitor.scene_sub)))
        for topic, cls, samples in plan:
            for data in samples:
                hostile.send(topic, cls, data)
        expected = sum(len(s) for _t, _c, s in plan)
        _spin(ex, lambda: (monitor.take_samples() or monitor.malformed.total) >= expected - 2)
        monitor.take_samples()
        monitor.compute()
        assert monitor.exit_code is None
        counts = monitor.malformed.counts
        assert set(counts) == {t for t, _c, _s in plan}, counts
    finally:
        ex.shutdown()
        for n in (monitor, hostile.node):
            n.destroy_node()


def test_free_run_stops_for_foreign_joint_states(ctx, tmp_path) -> None:
    """Free-run holds the same rule: engine and load would stop answering beside a second
    joint-state publisher and the loop would run on held torques; it stops, naming it."""
    sent = []

    def attack(hostile, k):
        if k == 5 and not sent:
            sent.append(1)
            hostile.foreign_joint_states(4)
    node, peers, _hostile = run_loop(ctx, tmp_path, attack=attack, mode='free-run', duration=2.0,
                                     exchange_step=0.002, timeout=20.0)
    assert node.exit_code == 1, node.error_message
    assert node.error_message.startswith('free-run: /driveline/joint_states: intruder /hostile (gid ')
