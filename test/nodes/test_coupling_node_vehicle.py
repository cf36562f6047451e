"""coupling_node and load_node in-process (fresh Context) on a vehicle scene (fwd_axle):
joint-state names of every branch, the tyres and body integrated inside (a /load/wrench
answer changes nothing), the states equal the offline exchange loop on the same
TreeDriveline, and load_node's 0 N m answer on the last wheel."""
from __future__ import annotations

import numpy as np
import pytest

rclpy = pytest.importorskip('rclpy')
from rclpy.parameter import Parameter  # noqa: E402

from cvj_ros.nodes.coupling_node import CouplingNode  # noqa: E402
from cvj_ros.physics.scene import find_scene, load_scene  # noqa: E402
from test.nodes.test_coupling_node import T_ENGINE, FakePeers, ns  # noqa: E402

pytestmark = pytest.mark.ros

H = 1e-3
N = 20


def _run(ctx, load_torque: float, wrenches: dict[str, list] | None = None
         ) -> tuple[CouplingNode, FakePeers]:
    """fwd_axle for N exchanges; the fake peers answer T_ENGINE and ``load_torque`` (and
    collect /coupling/<joint>/wrench into ``wrenches[joint]`` for each key given)."""
    import time

    from geometry_msgs.msg import WrenchStamped

    from cvj_ros.nodes.common import make_executor
    from cvj_ros.nodes.qos import DATA_QOS, coupling_wrench_topic
    overrides = [Parameter('scene', value='fwd_axle'), Parameter('min_subscribers', value=1),
                 Parameter('duration', value=N * H), Parameter('exchange_step', value=H)]
    peers = FakePeers(ctx, lambda topic, k, stamp: [(stamp, T_ENGINE if topic == 'engine' else load_torque)])
    for joint, got in (wrenches or {}).items():
        peers.node.create_subscription(WrenchStamped, coupling_wrench_topic(joint), got.append, DATA_QOS)
    node = CouplingNode(context=ctx, parameter_overrides=overrides)
    ex = make_executor('events', ctx)
    ex.add_node(peers.node)
    ex.add_node(node)
    t0 = time.monotonic()
    try:
        while node.exit_code is None:
            assert time.monotonic() - t0 < 120, 'coupling node did not finish'
            ex.spin_once(timeout_sec=0.05)
        # every state the node published is delivered (its exit follows the publication of
        # the last one; a fixed number of spins stood for "long enough")
        t1 = time.monotonic()
        while len(peers.js) < node.joint_states_published and time.monotonic() - t1 < 10.0:
            ex.spin_once(timeout_sec=0.01)
        for _ in range(5):
            ex.spin_once(timeout_sec=0.01)
        t1 = time.monotonic()       # the last step's wrenches go out after its joint state
        while wrenches and any(len(g) < len(peers.js) for g in wrenches.values()) \
                and time.monotonic() - t1 < 5.0:
            ex.spin_once(timeout_sec=0.05)
    finally:
        ex.shutdown()
        peers.node.destroy_node()
        node.destroy_node()
    return node, peers


def _offline(load_torque: float, states: list | None = None) -> tuple[list[str], np.ndarray, np.ndarray]:
    """Names, positions and speeds at t_k of the exchange loop without ROS (the coupling
    node's stepper and joint-state walk, engine torque held at T_ENGINE); the states x_k
    appended to ``states`` if given."""
    from cvj_ros.physics.cosim import CoupledStepper
    from cvj_ros.physics.tree import TreeDriveline
    sc = load_scene(find_scene('fwd_axle'))
    dl = TreeDriveline.from_scene(sc, track_energy=True)
    st = CoupledStepper(dl, scheme='zoh', method=sc.solver.method, rtol=sc.solver.rtol,
                        atol=sc.solver.atol, h=sc.solver.h)
    x = np.array(dl.x0)
    pos, vel = [], []
    for k in range(N + 1):
        names, p, v, _e = dl.joint_states(x, T_ENGINE, load_torque)
        if states is not None:
            states.append(np.array(x))
        pos.append(p)
        vel.append(v)
        if k < N:
            x = st.advance((k + 1) * 1_000_000 / 1e9, T_ENGINE, load_torque)   # the node's t_(k+1)
    return names, np.array(pos), np.array(vel)


def test_vehicle_scene_publishes_every_branch_and_equals_the_offline_exchange_loop(ctx):
    node, peers = _run(ctx, load_torque=5000.0)      # a load answer is unused: tyres inside
    assert node.exit_code == 0
    assert len(peers.js) == N + 1
    assert [ns(m.header.stamp) for m in peers.js] == [k * 1_000_000 for k in range(N + 1)]
    names, pos, vel = _offline(load_torque=0.0)
    assert list(peers.js[0].name) == names
    for shaft in ('engine_crank', 'differential_carrier', 'differential_left', 'differential_right',
                  'tripod_left_spider', 'rzeppa_right_cage', 'wheel_left', 'wheel_right'):
        assert shaft in names
    # depth first: the differential's four shafts, then the left branch, then the right one
    order = ['differential_input', 'differential_carrier', 'differential_left', 'differential_right',
             'tripod_left_input', 'wheel_left', 'tripod_right_input', 'wheel_right']
    assert [names.index(n) for n in order] == sorted(names.index(n) for n in order)
    assert names[-1] == 'wheel_right' and names.index('wheel_left') + 1 == names.index('tripod_right_input')
    got_p = np.array([m.position for m in peers.js])
    got_v = np.array([m.velocity for m in peers.js])
    # same stepper and walk on the same torques: only serialisation (float64, exact) between
    np.testing.assert_array_equal(got_v, vel)
    np.testing.assert_array_equal(got_p, pos)
    # the loop diagnostics carry what JointState cannot: vehicle speed, per-wheel tyre values
    from cvj_ros.physics.tree import TreeDriveline
    dl = TreeDriveline.from_scene(load_scene(find_scene('fwd_axle')))
    stats = node.loop_stats()
    assert stats['vehicle_speed_m_s'] == float(node.x[dl._iv])
    assert 13.0 < stats['vehicle_speed_m_s'] < 14.5          # 50 km/h = 13.9 m/s start, 20 ms
    wheels = dl.wheel_outputs(node.x)
    for w in ('wheel_left', 'wheel_right'):
        assert stats[f'{w}.fx_N'] == wheels[w]['fx'] and stats[f'{w}.slip'] == wheels[w]['slip']
        assert stats[f'{w}.fz_N'] > 0 and stats[f'{w}.status'] == 0
    # compiled stepper (tree kernel, engine torque from the input block); every branch's
    # joints publish their reaction wrench (test_reaction_wrench_of_every_branch_joint)
    assert node.stepper.backend == 'kernel'
    assert node.reaction_joints == ['gearbox', 'tripod_left', 'rzeppa_left', 'tripod_right', 'rzeppa_right']


def test_reaction_wrench_of_every_branch_joint(ctx):
    """/coupling/<joint>/wrench of each joint of both halfshafts (and the gearbox): one per
    exchange, stamped as the joint state, frame ``<joint>_housing``, equal to the offline
    TreeDriveline.reactions at the same state and engine torque (test_tree_reactions.py
    holds those to an independent walk)."""
    from cvj_ros.physics.joints.wrench import wrench_from_reactions
    from cvj_ros.physics.tree import TreeDriveline
    joints = ['gearbox', 'tripod_left', 'rzeppa_left', 'tripod_right', 'rzeppa_right']
    got: dict[str, list] = {j: [] for j in joints}
    node, peers = _run(ctx, load_torque=0.0, wrenches=got)
    assert node.exit_code == 0 and node.outputs.backend == 'kernel'
    states: list[np.ndarray] = []
    _offline(load_torque=0.0, states=states)
    dl = TreeDriveline.from_scene(load_scene(find_scene('fwd_axle')))
    for j in joints:
        msgs = got[j]
        assert [ns(m.header.stamp) for m in msgs] == [ns(m.header.stamp) for m in peers.js], j
        assert {m.header.frame_id for m in msgs} == {f'{j}_housing'}
        for k in range(1, N + 1):           # from step 1 on the held engine torque is T_ENGINE
            force, torque = wrench_from_reactions(dl.joint_models[j].kind,
                                                  dl.reactions(states[k], T_ENGINE)[j])
            w = msgs[k].wrench
            np.testing.assert_allclose([w.force.x, w.force.y, w.force.z], force, rtol=1e-12, atol=1e-9)
            np.testing.assert_allclose([w.torque.x, w.torque.y, w.torque.z], torque, rtol=1e-12, atol=1e-9)
    # the halfshafts differ (angles and lengths): so do their tripods' reactions
    assert got['tripod_left'][-1].wrench.force.y != got['tripod_right'][-1].wrench.force.y


def test_load_node_answers_zero_on_the_last_wheel_of_a_vehicle_scene(ctx):
    from cvj_ros.nodes.load_node import LoadNode
    node = LoadNode(context=ctx, parameter_overrides=[Parameter('scene', value='awd_4x4')])
    try:
        from cvj_ros.physics.scene import Wheel, iter_elements
        sc = load_scene(find_scene('awd_4x4'))
        wheels = [el.name for el in iter_elements(sc.driveline) if isinstance(el, Wheel)]
        assert node.shaft == wheels[-1]
        assert node.load.torque(0.3, 50.0, 1.0) == 0.0 and node.load.slope(0.3, 50.0, 1.0) == 0.0
    finally:
        node.destroy_node()


# --- wheel_load=external: one /load/<wheel>/wrench answer per wheel -------------------------

C_ROAD = 3.0        # N m s/rad: the tiny responder's wheel load T_w = C_ROAD omega_w


class WheelPeers:
    """A tiny outside road: answers /engine/wrench with T_ENGINE and every
    /load/<wheel>/wrench with C_ROAD times that wheel's speed, stamps echoed; ``skip`` wheels
    have a publisher (so the loop starts) but never answer."""

    def __init__(self, ctx, wheels: list[str], skip: tuple[str, ...] = (), before=None) -> None:
        from geometry_msgs.msg import WrenchStamped
        from sensor_msgs.msg import JointState

        from cvj_ros.nodes.qos import DATA_QOS
        from cvj_ros.nodes.wheel_loads import wheel_wrench_topic
        self.node = rclpy.create_node('wheel_peers', context=ctx)
        self.engine_pub = self.node.create_publisher(WrenchStamped, '/engine/wrench', DATA_QOS)
        pubs = {w: self.node.create_publisher(WrenchStamped, wheel_wrench_topic(w), DATA_QOS)
                for w in wheels}
        self.wheel_pubs = {w: pub for w, pub in pubs.items() if w not in skip}
        self.js: list = []
        self._msg = WrenchStamped
        # before(wheel, k, stamp) -> [(stamp, torque)]: sent on that wheel ahead of its answer
        self.before = before or (lambda wheel, k, stamp: [])
        self.node.create_subscription(JointState, '/driveline/joint_states', self._on_js, DATA_QOS)

    def _on_js(self, msg) -> None:
        from builtin_interfaces.msg import Time
        self.js.append(msg)
        names = list(msg.name)
        for w, pub in self.wheel_pubs.items():
            for (sec, nsec), torque in self.before(w, len(self.js) - 1, msg.header.stamp):
                extra = self._msg()
                extra.header.stamp = Time(sec=sec, nanosec=nsec)
                extra.wrench.torque.z = torque
                pub.publish(extra)
        for pub, torque in [(self.engine_pub, T_ENGINE)] + [
                (pub, C_ROAD * msg.velocity[names.index(w)]) for w, pub in self.wheel_pubs.items()]:
            w = self._msg()
            w.header.stamp = msg.header.stamp
            w.wrench.torque.z = torque
            pub.publish(w)


def _run_wheels(ctx, skip: tuple[str, ...] = (), before=None, **params):
    import time

    from cvj_ros.nodes.common import make_executor
    overrides = [Parameter('scene', value='fwd_axle'), Parameter('min_subscribers', value=1),
                 Parameter('duration', value=N * H), Parameter('exchange_step', value=H),
                 Parameter('wheel_load', value='external')]
    overrides += [Parameter(k, value=v) for k, v in params.items()]
    peers = WheelPeers(ctx, ['wheel_left', 'wheel_right'], skip, before)
    node = CouplingNode(context=ctx, parameter_overrides=overrides)
    ex = make_executor('events', ctx)
    ex.add_node(peers.node)
    ex.add_node(node)
    t0 = time.monotonic()
    try:
        while node.exit_code is None:
            assert time.monotonic() - t0 < 120, 'coupling node did not finish'
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
        peers.node.destroy_node()
        node.destroy_node()
    return node, peers


def test_outside_wheel_loads_are_integrated_as_the_offline_loop_with_the_same_answers(ctx):
    node, peers = _run_wheels(ctx)
    assert node.exit_code == 0 and len(peers.js) == N + 1
    assert node.stepper.backend == 'python'          # the kernel has no wheel-torque input
    # offline: the same stepper on the same TreeDriveline, each wheel's torque the
    # responder's rule at t_k, engine torque T_ENGINE
    from cvj_ros.physics.cosim import CoupledStepper
    from cvj_ros.physics.tree import TreeDriveline
    sc = load_scene(find_scene('fwd_axle'))
    dl = TreeDriveline.from_scene(sc, track_energy=True)
    dl.set_wheel_torques([0.0, 0.0])
    st = CoupledStepper(dl, scheme='zoh', method=sc.solver.method, rtol=sc.solver.rtol,
                        atol=sc.solver.atol, h=sc.solver.h)
    x = np.array(dl.x0)
    vel = []
    for k in range(N + 1):
        names, _p, v, _e = dl.joint_states(x, T_ENGINE)
        vel.append(v)
        if k < N:
            dl.set_wheel_torques([C_ROAD * v[names.index(w)] for w in ('wheel_left', 'wheel_right')])
            x = st.advance((k + 1) * 1_000_000 / 1e9, T_ENGINE, 0.0)
    np.testing.assert_array_equal(np.array([m.velocity for m in peers.js]), np.array(vel))
    # and the wheels' effort is the answered torque (~C_ROAD * 46 rad/s = 139 N m), not the
    # tyres' (which would carry the car's 1500 kg)
    last = peers.js[-1]
    i = list(last.name).index('wheel_left')
    assert last.effort[i] == pytest.approx(C_ROAD * last.velocity[i], rel=1e-2)


def test_a_wheel_that_never_answers_ends_the_loop_naming_its_topic(ctx):
    node, _peers = _run_wheels(ctx, skip=('wheel_right',), peer_timeout=0.5)
    assert node.exit_code == 1
    assert ('lockstep: no answer on /load/wheel_right/wrench for t=0 s (step 0) within '
            'peer_timeout=0.5 s; is the outside wheel-load node running?') in node.error_message


def test_external_wheel_load_needs_a_vehicle_scene(ctx, tmp_path):
    from cvj_ros.nodes.common import ParameterError
    from test.nodes.test_coupling_node import scene_file
    with pytest.raises(ParameterError, match='wheel_load: external needs a vehicle scene'):
        CouplingNode(context=ctx, parameter_overrides=[
            Parameter('scene', value=scene_file(tmp_path)), Parameter('wheel_load', value='external')])


def test_monitor_reads_joints_inside_the_branches(ctx):
    """The monitor's joint angle limits and internal members (tripod spider, Rzeppa cage:
    no shaft limit) come from every branch of a vehicle scene, not only the main chain."""
    from cvj_ros.nodes.monitor_node import MonitorNode
    node = MonitorNode(context=ctx, parameter_overrides=[Parameter('scene', value='fwd_axle')])
    try:
        assert {'tripod_left_spider', 'tripod_right_spider', 'rzeppa_left_cage',
                'rzeppa_right_cage'} <= node.internal_members
        assert node.joint_limits['tripod_left'][0] == 6.0       # beta_deg of the left tripod
        assert node.joint_limits['rzeppa_left'][0] == 8.0       # delta_deg of the left Rzeppa
        assert node.joint_limits['tripod_right'][0] == 3.0
    finally:
        node.destroy_node()


def test_wrong_stamps_and_duplicates_on_a_wheel_are_ignored_and_counted(ctx):
    """From step 1 on, each wheel first gets an absurd answer stamped one step late (the
    previous stamp, a duplicate of the answer already taken): all ignored and counted, the
    run equals the clean one (the same answers for t_k are integrated)."""
    def before(wheel, k, stamp):
        if k == 0:
            return []
        prev = stamp.sec * 10**9 + stamp.nanosec - 1_000_000
        return [(divmod(prev, 10**9), 1e4 if wheel == 'wheel_left' else -1e4)]
    node, peers = _run_wheels(ctx, before=before)
    clean, clean_peers = _run_wheels(ctx)
    assert node.exit_code == 0 and clean.exit_code == 0
    # steps 1..N-1, two wheels; the extras for the final state t_N arrive after the loop ended
    assert node.ignored_stamps == 2 * (N - 1) and clean.ignored_stamps == 0
    assert '/load/wheel_left/wrench' in node.wrong_stamp
    np.testing.assert_array_equal(np.array([m.velocity for m in peers.js]),
                                  np.array([m.velocity for m in clean_peers.js]))


def test_nonfinite_wheel_torque_is_rejected_naming_its_topic(ctx):
    def before(wheel, k, stamp):
        return [((stamp.sec, stamp.nanosec), float('nan'))] if (wheel, k) == ('wheel_right', 3) else []
    node, _peers = _run_wheels(ctx, before=before)
    assert node.exit_code == 1 and node.rejected_torques == 1
    assert node.error_message.startswith('/load/wheel_right/wrench: torque.z not finite (nan) at stamp 0.003 s')


@pytest.mark.parametrize('wheel_load', ['internal', 'external'])
def test_vehicle_joint_state_and_outside_wheel_rhs_are_compiled(ctx, wheel_load):
    """The per-exchange joint state of a vehicle scene is the compiled walk (the Python one
    cost 1-2 ms per 1 ms exchange); with outside wheel loads the Python stepper integrates
    the compiled right-hand side (docs/ros.md, "Vehicle scenes in the ROS loop")."""
    from cvj_ros.physics.kernel.tree_wheel_rhs import CompiledWheelLoadRhs
    from cvj_ros.physics.state_outputs import TreeKernelStateOutputs
    node = CouplingNode(context=ctx, parameter_overrides=[
        Parameter('scene', value='fwd_axle'), Parameter('wheel_load', value=wheel_load)])
    try:
        assert isinstance(node.outputs, TreeKernelStateOutputs)
        if wheel_load == 'external':
            assert node.stepper.backend == 'python'
            assert isinstance(node.stepper.driveline, CompiledWheelLoadRhs)
        else:
            assert node.stepper.backend == 'kernel'
    finally:
        node.destroy_node()
