"""Run identity (issue 10 item 4, cvj_ros.nodes.run_token): the token format and parsers
against rclpy's own serialisation, and the filter of every node that checks it, in-process:
the coupling node (answers of another run are never integrated, checked against the
closed-form momentum balance), engine/load responders, monitor_node and BagRecorder."""
from __future__ import annotations

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
from std_msgs.msg import String  # noqa: E402

from cvj_ros import bag  # noqa: E402
from cvj_ros.nodes import run_token as rt  # noqa: E402
from cvj_ros.nodes.common import (JointStateEncoder, ParameterError,  # noqa: E402
                                  decode_wrench_header_torque_z, make_executor)
from cvj_ros.nodes.coupling_node import CouplingNode  # noqa: E402
from cvj_ros.nodes.qos import DATA_QOS, LATCHED_QOS  # noqa: E402

pytestmark = pytest.mark.ros

OURS, OTHER = '0badc0de', '5eed1234'
J1, J2 = 0.128, 0.161          # kg m^2 (seed 004 KAVZ-685)
T_ENGINE, T_LOAD = 150.0, 100.0  # N m
T_FOREIGN = 1.0e4               # N m: another run's answer; integrated once it would move
#                                the momentum by 1e4 * 1e-3 = 10 kg m^2/s >> the 1e-8 check
W0 = 30.0                       # rad/s
DURATION, H = 0.02, 0.001       # s


# --- token format and parsers ---------------------------------------------------------------

def test_new_tokens_are_8_hex_and_differ() -> None:
    tokens = {rt.new_run_token() for _ in range(1000)}
    assert all(rt.TOKEN_RE.match(t) for t in tokens)
    # never numeric under ROS parameter YAML (an all-digit token became an INTEGER parameter)
    assert all(not isinstance(yaml.safe_load(t), (int, float)) for t in tokens)
    assert all(any(c in 'abcdf' for c in t) for t in tokens)
    assert len(tokens) == 1000        # P(any collision in 1000 draws) = ~1e3^2 / 2^33 = 1.2e-4


@pytest.mark.parametrize('frame, token', [
    ('driveline@0badc0de', '0badc0de'), ('wheel@5eed1234', '5eed1234'),
    ('a@b@0badc0de', '0badc0de'),            # the last '@' counts
    ('wheel', None), ('', None), ('@', ''),
])
def test_frame_token(frame: str, token: str | None) -> None:
    assert rt.frame_token(frame) == token
    assert rt.frame_token_bytes(frame.encode()) == (None if token is None else token.encode())


def test_is_foreign_only_for_another_token() -> None:
    assert rt.is_foreign(f'wheel@{OTHER}', OURS)
    assert not rt.is_foreign(f'wheel@{OURS}', OURS)
    assert not rt.is_foreign('wheel', OURS)            # untagged: an outside node, accepted
    assert not rt.is_foreign(f'wheel@{OTHER}', '')     # an untagged node accepts everything
    assert rt.tag_frame('wheel', '') == 'wheel' and rt.tag_frame('wheel', OURS) == f'wheel@{OURS}'


@pytest.mark.parametrize('bad', ['XYZ', '0BADC0DE', '0badc0d', '0badc0de0', ' 0badc0de'])
def test_check_run_token_rejects(bad: str) -> None:
    with pytest.raises(ValueError, match='8 lowercase hex'):
        rt.check_run_token(bad)
    assert rt.check_run_token('') == '' and rt.check_run_token(OURS) == OURS


@pytest.mark.parametrize('frame', ['', 'a', 'abc', 'abcd', f'driveline@{OURS}', f'w\u00e4lle@{OTHER}'])
def test_cdr_frame_id_reads_rclpy_serialisation(frame: str) -> None:
    """The raw-path readers against rclpy's serialiser (every Header-first type we check)."""
    js = JointState(name=['a', 'b'], position=[1.0, 2.0])
    js.header.frame_id = frame
    w = WrenchStamped()
    w.header.stamp = Time(sec=3, nanosec=250_000_000)
    w.header.frame_id = frame
    w.wrench.torque.z = -2.5
    d = DiagnosticArray()
    d.header.frame_id = frame
    for msg in (js, w, d):
        assert rt.cdr_frame_id(serialize_message(msg)) == frame.encode()
    assert decode_wrench_header_torque_z(serialize_message(w)) == (3_250_000_000, frame.encode(), -2.5)
    assert rt.cdr_is_foreign(serialize_message(w), OURS) == (frame.endswith(f'@{OTHER}'))


def test_joint_state_encoder_with_frame_matches_rclpy() -> None:
    import numpy as np
    from rclpy.serialization import deserialize_message
    enc = JointStateEncoder(['crank', 'wheel'], f'driveline@{OURS}')
    assert enc.ok
    msg = deserialize_message(enc.encode(1, 2, np.ones(2), np.zeros(2), np.ones(2)), JointState)
    assert msg.header.frame_id == f'driveline@{OURS}' and list(msg.name) == ['crank', 'wheel']


# --- coupling node ----------------------------------------------------------------------------

def scene_file(tmp_path: Path) -> str:
    data = {
        'name': 'two_mass_token', 'duration': DURATION, 'exchange_step': H,
        'solver': {'method': 'dopri5', 'rtol': 1e-10, 'atol': 1e-12},
        'engine': {'model': 'linear'}, 'load': {'model': 'constant', 'torque': T_LOAD},
        'initial': {'speed_rad_s': W0},
        'driveline': [{'type': 'inertia', 'name': 'engine_crank', 'J': J1},
                      {'type': 'spring', 'name': 'shaft', 'stiffness': 715.4, 'damping': 6.35},
                      {'type': 'inertia', 'name': 'wheel', 'J': J2}],
    }
    path = tmp_path / 'scene.yaml'
    path.write_text(yaml.safe_dump(data))
    return str(path)


class TaggedPeers:
    """Engine and load answerers in one test node; ``frames(k, js_frame)`` lists the
    (frame_id, torque factor) answers sent per topic for joint state k, in order."""

    def __init__(self, ctx, frames) -> None:
        self.node = rclpy.create_node('tagged_peers', context=ctx)
        self.pubs = {'engine': self.node.create_publisher(WrenchStamped, '/engine/wrench', DATA_QOS),
                     'load': self.node.create_publisher(WrenchStamped, '/load/wrench', DATA_QOS)}
        self.js: list[JointState] = []
        self.scene: list[String] = []
        self.frames = frames
        self.node.create_subscription(JointState, '/driveline/joint_states', self._on_js, DATA_QOS)
        self.node.create_subscription(String, '/driveline/scene', self.scene.append, LATCHED_QOS)

    def _on_js(self, msg: JointState) -> None:
        k = len(self.js)
        self.js.append(msg)
        for frame, foreign in self.frames(k, msg.header.frame_id):
            for topic, pub in self.pubs.items():
                w = WrenchStamped()
                w.header.stamp = msg.header.stamp
                w.header.frame_id = frame
                w.wrench.torque.z = T_FOREIGN if foreign else (T_ENGINE if topic == 'engine' else T_LOAD)
                pub.publish(w)


def run_coupling(ctx, tmp_path: Path, frames, timeout: float = 8.0, **params):
    overrides = [Parameter('scene', value=scene_file(tmp_path)), Parameter('min_subscribers', value=1)]
    overrides += [Parameter(k, value=v) for k, v in params.items()]
    peers = TaggedPeers(ctx, frames)
    node = CouplingNode(context=ctx, parameter_overrides=overrides)
    ex = make_executor('events', ctx)
    ex.add_node(peers.node)
    ex.add_node(node)
    t0 = time.monotonic()
    try:
        while node.exit_code is None:
            assert time.monotonic() - t0 < timeout, 'coupling node did not finish'
            ex.spin_once(timeout_sec=0.05)
        for _ in range(5):
            ex.spin_once(timeout_sec=0.01)
    finally:
        ex.shutdown()
        peers.node.destroy_node()
        node.destroy_node()
    return node, peers


def momentum_ok(js: JointState) -> bool:
    """Closed form: d/dt (J1 w1 + J2 w2) = T_engine - T_load for constant torques (the
    spring and damper are internal), so after DURATION the momentum is exactly known; one
    integrated foreign answer (1e4 N m for 1 ms) would move it by >= 10 kg m^2/s."""
    momentum = J1 * js.velocity[0] + J2 * js.velocity[1]
    return momentum == pytest.approx((J1 + J2) * W0 + (T_ENGINE - T_LOAD) * DURATION, rel=1e-8)


def test_coupling_node_ignores_answers_of_another_run(ctx, tmp_path: Path) -> None:
    """Every state is answered first by 'another run' (right stamp, its token, 1e4 N m)
    and then with our token: the foreign answers are counted, never integrated."""
    node, peers = run_coupling(ctx, tmp_path, lambda k, f: [(f'x@{OTHER}', True), (f, False)],
                               run_token=OURS)
    n = round(DURATION / H)
    assert node.exit_code == 0
    assert len(peers.js) == n + 1
    assert all(m.header.frame_id == f'driveline@{OURS}' for m in peers.js)
    assert yaml.safe_load(peers.scene[0].data)['run_token'] == OURS
    assert momentum_ok(peers.js[-1])
    assert node.ignored_stamps == 0 and node.untokened_answers == 0
    # both topics, every state up to t_(N-1) at least (the answers to t_N may arrive after exit)
    assert node.foreign_answers >= 2 * n
    assert node.loop_stats()['foreign_answers'] == node.foreign_answers


def test_coupling_node_accepts_untagged_answers(ctx, tmp_path: Path) -> None:
    """An outside node that echoes only the stamp (frame_id 'wheel') keeps working."""
    node, peers = run_coupling(ctx, tmp_path, lambda k, f: [('wheel', False)], run_token=OURS)
    assert node.exit_code == 0 and momentum_ok(peers.js[-1])
    assert node.untokened_answers >= 2 * round(DURATION / H) and node.foreign_answers == 0


def test_untagged_coupling_node_accepts_everything(ctx, tmp_path: Path) -> None:
    """run_token '' (ros2 run): joint states untagged, no answer filtered."""
    node, peers = run_coupling(ctx, tmp_path, lambda k, f: [(f'wheel@{OTHER}', False)])
    assert node.exit_code == 0 and momentum_ok(peers.js[-1])
    assert peers.js[0].header.frame_id == '' and node.foreign_answers == 0


def test_only_foreign_answers_time_out(ctx, tmp_path: Path) -> None:
    node, _ = run_coupling(ctx, tmp_path, lambda k, f: [(f'x@{OTHER}', True)],
                           run_token=OURS, peer_timeout=0.3)
    assert node.exit_code == 1 and node.k == 0 and node.foreign_answers >= 2


def test_unanswered_state_0_beside_another_runs_publisher_names_it(ctx, tmp_path: Path) -> None:
    """Another run's engine publisher discovered only after step 0 went out (slower than the
    start settle) and state 0 answered only with the other run's token: the node stops with
    the line naming that publisher as the intruder besides its peer and the domain, not
    with 'is engine_node running?' (seen in CI: test_faults_processes, second run on one
    domain)."""
    other: list = []

    def frames(k: int, frame: str) -> list:
        if not other:      # the other run's engine appears once our state 0 is out
            node = rclpy.create_node('other_runs_engine', context=ctx)
            other.append((node, node.create_publisher(WrenchStamped, '/engine/wrench', DATA_QOS)))
        return [(f'x@{OTHER}', True)]
    try:
        node, _ = run_coupling(ctx, tmp_path, frames, run_token=OURS, peer_timeout=0.5)
    finally:
        for n, _pub in other:
            n.destroy_node()
    assert node.exit_code == 1 and node.k == 0
    # a publisher that appeared after step 0 is an intruder, named against the peer
    assert '/engine/wrench: intruder /other_runs_engine (gid ' in node.error_message, node.error_message
    assert "this run's peer /tagged_peers (gid " in node.error_message
    assert 'ROS_DOMAIN_ID=' in node.error_message


def test_bad_run_token_is_a_parameter_error(ctx, tmp_path: Path) -> None:
    with pytest.raises(ParameterError, match='^run_token'):
        CouplingNode(context=ctx, parameter_overrides=[
            Parameter('scene', value=scene_file(tmp_path)), Parameter('run_token', value='XYZ')])


# --- engine / load responders -----------------------------------------------------------------

class _Capture:
    def __init__(self) -> None:
        self.sent: list[tuple[int, bytes, float]] = []

    def publish(self, data) -> None:
        self.sent.append(decode_wrench_header_torque_z(
            data if isinstance(data, bytes) else serialize_message(data)))


def _js(frame: str, k: int) -> JointState:
    msg = JointState(name=['engine_crank', 'wheel'], position=[0.1 * k, 0.0], velocity=[30.0, 30.0])
    msg.header.stamp = Time(sec=0, nanosec=k * 1_000_000)
    msg.header.frame_id = frame
    return msg


@pytest.mark.parametrize('node_token', [OURS, ''])
def test_load_node_answers_its_run_only(ctx, tmp_path: Path, node_token: str) -> None:
    """Tagged load_node: joint states of another run are not answered (counted); its own and
    untagged ones are, frame_id '<shaft>@<token>' / '<shaft>'. Untagged load_node: answers
    every run, each with that run's token."""
    from cvj_ros.nodes.load_node import LoadNode
    node = LoadNode(context=ctx, parameter_overrides=[
        Parameter('scene', value=scene_file(tmp_path)), Parameter('run_token', value=node_token)])
    try:
        cap = node.wrench_pub = _Capture()
        for k, frame in enumerate([f'driveline@{OURS}', f'driveline@{OTHER}', 'driveline',
                                   f'driveline@{OURS}', f'driveline@{OTHER}']):
            node._on_joint_states(_js(frame, k))
        frames = [(s, f.decode()) for s, f, _ in cap.sent]
        if node_token:
            assert frames == [(0, f'wheel@{OURS}'), (2_000_000, 'wheel'), (3_000_000, f'wheel@{OURS}')]
            assert node.foreign_states == 2
        else:
            assert [f for _, f in frames] == [f'wheel@{OURS}', f'wheel@{OTHER}', 'wheel',
                                              f'wheel@{OURS}', f'wheel@{OTHER}']
            assert node.foreign_states == 0
        assert all(tz == pytest.approx(T_LOAD) for *_, tz in cap.sent)
    finally:
        node.destroy_node()


def test_engine_node_rejects_bad_run_token(ctx, tmp_path: Path) -> None:
    from cvj_ros.nodes.engine_node import EngineNode
    with pytest.raises(ParameterError, match='^run_token'):
        EngineNode(context=ctx, parameter_overrides=[
            Parameter('scene', value=scene_file(tmp_path)), Parameter('run_token', value='nope')])


# --- monitor -------------------------------------------------------------------------------

def test_monitor_ignores_another_runs_messages(ctx, tmp_path: Path) -> None:
    from cvj_ros.nodes.monitor_node import MonitorNode
    node = MonitorNode(context=ctx, parameter_overrides=[Parameter('run_token', value=OURS)])
    try:
        node._on_joint_states(_js(f'driveline@{OTHER}', 0))
        assert node.samples == 0 and node.foreign_messages == 1
        node._on_joint_states(_js(f'driveline@{OURS}', 1))
        node._on_joint_states(_js('driveline', 2))            # untagged: accepted
        assert node.samples == 2
        diag = DiagnosticArray()
        diag.header.frame_id = f'coupling_node@{OTHER}'
        from cvj_ros.nodes.common import OK, diag_status
        diag.status = [diag_status('coupling_node: loop', OK, 'running', {'real_time_factor': 9.0})]
        node._on_diagnostics(diag)
        assert 'real_time_factor' not in node.loop_values
        diag.header.frame_id = f'coupling_node@{OURS}'
        node._on_diagnostics(diag)
        assert node.loop_values['real_time_factor'] == 9.0
        scene = {'scene': {'driveline': [{'type': 'joint', 'name': 'j', 'kind': 'tripod',
                                          'params': {'beta_deg': 10.0}}]}}
        node._on_scene(String(data=yaml.safe_dump({**scene, 'run_token': OTHER})))
        assert node.joint_limits == {}
        node._on_scene(String(data=yaml.safe_dump({**scene, 'run_token': OURS})))
        assert set(node.joint_limits) == {'j'}
        assert node.foreign_messages == 3
    finally:
        node.destroy_node()


# --- recorder --------------------------------------------------------------------------------

def test_recorder_drops_another_runs_messages(ctx, tmp_path: Path) -> None:
    """BagRecorder with a token, fed serialised messages directly (no DDS traffic): another
    run's joint states, answers, reaction wrenches, diagnostics and scene are dropped and
    counted; untagged ones are kept; after loop_ended a /clock beyond the latest own state
    is kept back and counted as another run's; a /clock before the run's first two states is kept back
    and written only if it lies within them."""
    node = rclpy.create_node('rec_token_test', context=ctx)
    writer = bag.BagWriter(tmp_path / 'b')
    try:
        rec = bag.BagRecorder(node, writer, discover_period=0.0, run_token=OURS)

        def feed(topic: str, msg) -> None:
            msgtype = bag.topic_type(topic)
            rec._on_message(topic, msgtype, serialize_message(msg),
                            stamped=msgtype in bag.STAMPED_TYPES, is_clock=topic == bag.CLOCK_TOPIC)

        def wrench(frame: str, k: int) -> WrenchStamped:
            w = WrenchStamped()
            w.header.stamp = Time(sec=0, nanosec=k * 1_000_000)
            w.header.frame_id = frame
            return w

        diag_other, diag_ours = DiagnosticArray(), DiagnosticArray()
        diag_other.header.frame_id, diag_ours.header.frame_id = f'x@{OTHER}', f'x@{OURS}'
        feed('/driveline/scene', String(data=yaml.safe_dump({'run_token': OTHER})))
        feed('/driveline/scene', String(data=yaml.safe_dump({'run_token': OURS})))
        # another run's /clock, the only one matched before our coupling node came up: kept
        # back until our first two states (0, 1 ms) show it is not ours
        feed('/clock', Clock(clock=Time(sec=0, nanosec=50_000_000)))
        for k in range(3):
            feed('/clock', Clock(clock=Time(sec=0, nanosec=k * 1_000_000)))
            feed('/driveline/joint_states', _js(f'driveline@{OTHER}', k))
            feed('/driveline/joint_states', _js(f'driveline@{OURS}', k))
            feed('/load/wrench', wrench(f'wheel@{OTHER}', k))
            feed('/load/wrench', wrench(f'wheel@{OURS}', k))
            feed('/engine/wrench', wrench('engine_crank', k))          # untagged: kept
            feed('/coupling/cardan/wrench', wrench(f'cardan_housing@{OTHER}', k))
        feed('/diagnostics', diag_other)
        feed('/diagnostics', diag_ours)
        rec.loop_ended = True
        # after the loop ended, own /clock never passes the last own state (2 ms): 3 ms and
        # 9 ms stay kept back (a state still in flight could claim them) and count as
        # another run's, like the 50 ms one
        feed('/clock', Clock(clock=Time(sec=0, nanosec=3_000_000)))
        feed('/clock', Clock(clock=Time(sec=0, nanosec=9_000_000)))
        assert rec.counts == {'/driveline/scene': 1, '/clock': 3, '/driveline/joint_states': 3,
                              '/load/wrench': 3, '/engine/wrench': 3, '/diagnostics': 1}
        assert rec.foreign == {'/driveline/scene': 1, '/driveline/joint_states': 3, '/load/wrench': 3,
                               '/coupling/cardan/wrench': 3, '/diagnostics': 1, '/clock': 3}
        assert yaml.safe_load(rec.scene_text)['run_token'] == OURS
        rec.destroy()
        writer.close()
        clock = bag.read_bag(tmp_path / 'b', ['/clock'])['/clock']
        assert [round(v * 1e9) for v in clock.value] == [0, 1_000_000, 2_000_000]
    finally:
        writer.close()
        node.destroy_node()


def test_recorder_clock_repeats_dropped_and_early_clock_kept_back(ctx, tmp_path: Path) -> None:
    """/clock of another run with the SAME values while the match count still says one
    publisher (CI: Fast DDS delivered an intruder's /clock before counting its match; 23
    repeated values were written): a value not newer than the last written is dropped and
    counted. A run's own /clock ahead of its joint states by more than one step (the
    recorder took the /clock queue before the state queue) is kept back, not dropped, and
    written once the state arrives: the bag's /clock is exactly 0, h, 2h, ... ."""
    node = rclpy.create_node('rec_clock_test', context=ctx)
    writer = bag.BagWriter(tmp_path / 'b')
    try:
        rec = bag.BagRecorder(node, writer, discover_period=0.0, run_token=OURS)

        def feed(topic: str, msg) -> None:
            msgtype = bag.topic_type(topic)
            rec._on_message(topic, msgtype, serialize_message(msg),
                            stamped=msgtype in bag.STAMPED_TYPES, is_clock=topic == bag.CLOCK_TOPIC)

        def clock(k: int) -> Clock:
            return Clock(clock=Time(sec=0, nanosec=k * 1_000_000))

        for k in range(3):
            feed('/clock', clock(k))
            feed('/driveline/joint_states', _js(f'driveline@{OURS}', k))
            feed('/clock', clock(k))                 # the intruder's copy: a repeat
        # the recorder is behind on joint states: /clock 3, 4, 5 come first
        for k in (3, 4, 5):
            feed('/clock', clock(k))
        for k in (3, 4, 5):
            feed('/driveline/joint_states', _js(f'driveline@{OURS}', k))
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
        rec = bag.BagRecorder(node, writer, discover_period=0.0, run_token=OURS)

        def feed(topic: str, msg) -> None:
            msgtype = bag.topic_type(topic)
            rec._on_message(topic, msgtype, serialize_message(msg),
                            stamped=msgtype in bag.STAMPED_TYPES, is_clock=topic == bag.CLOCK_TOPIC)

        feed('/clock', Clock(clock=Time(sec=0, nanosec=50_000_000)))     # another run's
        for k in range(21):                                             # the whole run: 0..20 ms
            feed('/clock', Clock(clock=Time(sec=0, nanosec=k * 1_000_000)))
        feed('/clock', Clock(clock=Time(sec=0, nanosec=7_000_000)))      # duplicate value
        for k in range(21):
            feed('/driveline/joint_states', _js(f'driveline@{OURS}', k))
        rec.loop_ended = True                        # the 50 ms sample is still kept back: counted
        assert rec.counts['/clock'] == 21 and rec.foreign == {'/clock': 2}
        rec.destroy()
        writer.close()
        clock = bag.read_bag(tmp_path / 'b', ['/clock'])['/clock']
        assert [round(v * 1e9) for v in clock.value] == [k * 1_000_000 for k in range(21)]
    finally:
        writer.close()
        node.destroy_node()


# --- launch file and `cvj-sim record --run-token` ------------------------------------------------

def _launch_module():
    import importlib.util
    path = Path(__file__).resolve().parents[2] / 'launch' / 'driveline.launch.py'
    spec = importlib.util.spec_from_file_location('driveline_launch_token', path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_launch_gives_one_token_to_every_node_and_the_recorder() -> None:
    mod = _launch_module()
    params = mod.node_parameters({'run_token': OURS})
    assert {p['run_token'] for p in params.values()} == {OURS} and len(params) == 4
    assert mod.recorder_arguments({'run_token': OURS})[-2:] == ['--run-token', OURS]
    auto = mod.node_parameters({})                       # default 'auto': one token per call
    tokens = {p['run_token'] for p in auto.values()}
    assert len(tokens) == 1 and rt.TOKEN_RE.match(tokens.pop())
    assert all('run_token' not in p for p in mod.node_parameters({'run_token': 'none'}).values())
    assert '--run-token' not in mod.recorder_arguments({'run_token': 'none'})
    with pytest.raises(ValueError, match='^run_token: must be auto, none or 8'):
        mod.node_parameters({'run_token': 'XYZ'})


def test_record_rejects_a_bad_run_token(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from cvj_ros.cli import main
    assert main(['record', str(tmp_path / 'rec'), '--run-token', 'XYZ', '--duration', '0.1']) == 2
    err = capsys.readouterr().err
    assert err.startswith('cvj-sim: error: --run-token: must be empty or 8 lowercase hex') and err.count('\n') == 1
    assert not (tmp_path / 'rec' / 'bag').exists()
