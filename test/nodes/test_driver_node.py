"""driver_node and the coupling node on a scene with clutch, gearbox and brake, in-process
(fresh Context) with fake engine/load responders: the lockstep command rule (the samples of
step k in force over [t_k, t_(k+1)]) against the physics stepped by hand, mode diagnostics,
malformed and out-of-range commands, an outside stack sending the commands."""
from __future__ import annotations

import contextlib
import signal
import time

import numpy as np
import pytest
import yaml

rclpy = pytest.importorskip('rclpy')
from geometry_msgs.msg import WrenchStamped  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402
from std_msgs.msg import Float64, Int8  # noqa: E402

from cvj_ros.nodes.command_plan import CommandPlan  # noqa: E402
from cvj_ros.nodes.common import ParameterError, make_executor  # noqa: E402
from cvj_ros.nodes.coupling_node import CouplingNode  # noqa: E402
from cvj_ros.nodes.driver_node import DriverNode  # noqa: E402
from cvj_ros.nodes.qos import DATA_QOS  # noqa: E402

pytestmark = pytest.mark.ros

T_ENGINE, T_LOAD = 60.0, 20.0       # N m, answered by the fake peers at every step
H = 0.001
COMMANDS = [{'t': 0.0, 'clutch': 1.0, 'brake': 1.0, 'gear': 1, 'throttle': 0.2},
            {'t': 0.005, 'brake': 1.0, 'clutch': 1.0},
            {'t': 0.015, 'brake': 0.0},
            {'t': 0.03, 'clutch': 0.0, 'throttle': 0.6},
            {'t': 0.05, 'gear': 2}]


def mode_scene(tmp_path, duration: float = 0.06, commands=COMMANDS) -> str:
    """Engine, clutch, gearbox, halfshaft spring, wheel, brake (values of the hard cases'
    car, lighter wheel so it moves within the run)."""
    data = {
        'name': 'mode_test', 'duration': duration, 'exchange_step': H, 'seed': 3,
        'solver': {'method': 'dopri5', 'rtol': 1e-8, 'atol': 1e-10},
        'engine': {'model': 'linear'}, 'load': {'model': 'constant', 'torque': T_LOAD},
        'initial': {'speed_rad_s': 80.0},
        'driveline': [
            {'type': 'inertia', 'name': 'engine_crank', 'J': 0.2},
            {'type': 'clutch', 'name': 'clutch', 'J_input': 0.05, 'J_output': 0.02,
             'mu_static': 0.4, 'mu_kinetic': 0.3, 'cgeo_m': 0.2, 'normal_force_max': 4000.0},
            {'type': 'gearbox', 'name': 'gearbox', 'J_input': 0.01, 'J_output': 0.02,
             'ratios': [3.5, 2.1, 1.4], 'reverse_ratio': -3.3, 'max_input_rpm': 6500.0},
            {'type': 'spring', 'name': 'halfshaft', 'stiffness': 8000.0, 'damping': 5.0},
            {'type': 'inertia', 'name': 'wheel', 'J': 2.0},
            {'type': 'brake', 'name': 'brake', 'mu_static': 0.5, 'mu_kinetic': 0.4,
             'cgeo_m': 0.25, 'normal_force_max': 40000.0}],
        'commands': commands,
    }
    path = tmp_path / 'mode_scene.yaml'
    path.write_text(yaml.safe_dump(data))
    return str(path)


class FakePeers:
    """Constant engine and load answers; records joint states, command samples and
    diagnostics; ``on_state(k, node)`` may publish more (an outside stack, an intruder)."""

    def __init__(self, ctx, on_state=None, torques=(T_ENGINE, T_LOAD)):
        self.torques = torques
        self.node = rclpy.create_node('fake_peers', context=ctx)
        self.engine_pub = self.node.create_publisher(WrenchStamped, '/engine/wrench', DATA_QOS)
        self.load_pub = self.node.create_publisher(WrenchStamped, '/load/wrench', DATA_QOS)
        self.js: list[JointState] = []
        self.samples: list[tuple[str, float]] = []
        self.on_state = on_state
        self.node.create_subscription(JointState, '/driveline/joint_states', self._on_js, DATA_QOS)
        for topic, typ in (('/engine/throttle', Float64), ('/driveline/clutch', Float64),
                           ('/driveline/gear', Int8), ('/driveline/brake', Float64)):
            self.node.create_subscription(typ, topic,
                                          lambda m, t=topic: self.samples.append((t, float(m.data))),
                                          DATA_QOS)

    def _on_js(self, msg):
        k = len(self.js)
        self.js.append(msg)
        if self.on_state is not None:
            self.on_state(k, self.node)
        for pub, torque in zip((self.engine_pub, self.load_pub), self.torques):
            w = WrenchStamped()
            w.header.stamp = msg.header.stamp
            w.wrench.torque.z = torque
            pub.publish(w)


@contextlib.contextmanager
def wall_bound(seconds: float, what: str):
    """Fail the test with ``AssertionError(what ...)`` once ``seconds`` of wall time have
    passed, inside an executor callback too (SIGALRM; its handler raises in the main thread
    at the next Python bytecode, e.g. in the middle of a compile): the bound holds over the
    whole block, not only between callbacks."""
    def on_alarm(_signum, _frame):
        raise AssertionError(f'{what} within {seconds:g} s of wall time')
    previous = signal.signal(signal.SIGALRM, on_alarm)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0.0)
        signal.signal(signal.SIGALRM, previous)


def warm_kernel(scene: str) -> None:
    """Compile the mode kernel's entry points for ``scene`` in this process, or load them
    from the numba cache (one step stepped by hand), before the bounded loop of :func:`run`:
    a cold compile inside the loop's first callback took 37 s at load 3.5, minutes on a busy
    machine, and is not what the loop's bound is about."""
    by_hand(scene, 1, 'kernel')


# run()'s bound on the loop, start wait to the last answer: with the kernel compiled, the
# 60 exchanges of mode_scene took 0.4 s (python) to 1.4 s (kernel, loaded from the cache;
# its longest callback 1.0 s) of wall time at load 3.5 on 2 cores; 60 s leaves a factor > 40
LOOP_BOUND_S = 60.0


def run(ctx, scene: str, *, driver: bool = True, on_state=None, timeout: float = LOOP_BOUND_S,
        torques=(T_ENGINE, T_LOAD), **params):
    """Run the coupling node (and the driver, the fake peers) on ``scene`` to its end; the
    loop (start wait, exchanges, delivery of the last answers) within ``timeout`` s of wall
    time, callbacks included (:func:`wall_bound`), the kernel compiled before it
    (:func:`warm_kernel`; building the nodes is not bounded here)."""
    overrides = [Parameter('scene', value=scene), Parameter('min_subscribers', value=1)]
    overrides += [Parameter(k, value=v) for k, v in params.items()]
    if params.get('mode_backend', 'auto') != 'python':
        warm_kernel(scene)
    peers = FakePeers(ctx, on_state, torques)
    drv = DriverNode(context=ctx, parameter_overrides=[Parameter('scene', value=scene)]) if driver else None
    node = CouplingNode(context=ctx, parameter_overrides=overrides)
    ex = make_executor('events', ctx)
    for n in (peers.node, drv, node):
        if n is not None:
            ex.add_node(n)
    try:
        with wall_bound(timeout, 'coupling node did not finish'):
            while node.exit_code is None:
                ex.spin_once(timeout_sec=0.05)
            # deliver what is still in flight: every state the node published (a free-run
            # burst publishes several in one callback; the executor runs one callback per
            # spin_once), then the answers to the last ones (at most 10 s for what never comes)
            t1 = time.monotonic()
            while len(peers.js) < node.joint_states_published and time.monotonic() - t1 < 10.0:
                ex.spin_once(timeout_sec=0.01)
            for _ in range(5):
                ex.spin_once(timeout_sec=0.01)
    finally:
        ex.shutdown()
        for n in (peers.node, drv, node):
            if n is not None:
                n.destroy_node()
    return node, peers, drv


def by_hand(scene_path: str, steps: int, backend: str = 'python') -> list[np.ndarray]:
    """The physics stepped as the lockstep rule says: step k's planned samples in force
    over [t_k, t_(k+1)], the fake peers' torques held; velocities at t_0..t_steps."""
    from cvj_ros.physics.hybrid.lockstep import hybrid_lockstep
    from cvj_ros.physics.scene import load_scene
    scene = load_scene(scene_path)
    hl = hybrid_lockstep(scene, backend=backend)
    plan = CommandPlan.from_scene(scene, 1_000_000, steps)
    out = []
    for k in range(steps + 1):
        vals = dict(plan.at(k))
        hl.set_commands(clutch=vals.get('clutch'), brake=vals.get('brake'),
                        gear=None if 'gear' not in vals else int(vals['gear']))
        out.append(hl.joint_states()[1].copy())
        if k < steps:
            hl.advance((k + 1) * 1_000_000 / 1e9, T_ENGINE, T_LOAD)   # t as the node: ns / 1e9
    return out


@pytest.mark.parametrize('backend', ['python', 'kernel'])
def test_driver_plays_the_schedule_and_each_step_uses_its_own_samples(ctx, tmp_path, backend):
    scene = mode_scene(tmp_path)
    node, peers, drv = run(ctx, scene, mode_backend=backend)
    assert node.stepper.backend == backend
    n = 60
    assert node.exit_code == 0 and len(peers.js) == n + 1
    # every sample the plan holds, in order: the bag carries the commands
    plan = CommandPlan.from_scene(__import__('cvj_ros.physics.scene', fromlist=['x']).load_scene(scene),
                                  1_000_000, n)
    topics = {'throttle': '/engine/throttle', 'clutch': '/driveline/clutch',
              'gear': '/driveline/gear', 'brake': '/driveline/brake'}
    want = [(topics[c], v) for _k, row in plan for c, v in row]
    assert sorted(peers.samples) == sorted(want) and drv.published == len(want)
    # the states equal the physics (on the node's backend) stepped by hand under the rule,
    # bit for bit
    ref = by_hand(scene, n, backend)
    got = [np.array(m.velocity) for m in peers.js]
    for k in range(n + 1):
        np.testing.assert_array_equal(got[k], ref[k], err_msg=f'step {k}')
    # the brake held the wheel exactly still until its release, then the clutch pulled it
    wheel = [m.velocity[-1] for m in peers.js]
    assert all(w == 0.0 for w in wheel[:10]) and wheel[-1] > 0.0
    stats = node.loop_stats()
    assert stats['gear.gearbox'] == 2 and stats['brake_state.brake'] == 'slip+'
    assert stats['clutch_state.clutch'] in ('slip+', 'stuck') and stats['stall'] == ''
    assert stats['mode_events'] >= 3 and stats['refused_commands'] == 0


def test_malformed_and_out_of_range_commands_are_dropped_and_named_once(ctx, tmp_path):
    """A stack (commands=external) sending junk on /driveline/clutch (not CDR) and an
    out-of-range brake beside valid samples: the junk never reaches the model, each topic is
    named once (malformed: WARN, counted; out of range: ERROR, refused_commands)."""
    scene = mode_scene(tmp_path, duration=0.03, commands=[{'t': 0.0, 'clutch': 1.0, 'brake': 1.0,
                                                           'gear': 1}])
    pubs = {}

    def stack(k, node):
        if not pubs:
            pubs['clutch'] = node.create_publisher(Float64, '/driveline/clutch', DATA_QOS)
            pubs['brake'] = node.create_publisher(Float64, '/driveline/brake', DATA_QOS)
        if k in (3, 4, 5):
            pubs['clutch'].publish(b'\x07junk')
            pubs['brake'].publish(Float64(data=7.5))
        if k == 6:
            pubs['brake'].publish(Float64(data=0.0))
    node, peers, _ = run(ctx, scene, driver=False, on_state=stack, commands='external')
    assert node.exit_code == 0 and len(peers.js) == 31
    assert node.malformed.counts == {'/driveline/clutch': 3}
    assert node.commands.refused['brake'] == 3 and node.loop_stats()['refused_commands'] == 3
    assert node.hybrid.commands.now.brake == 0.0 and node.hybrid.commands.now.clutch == 1.0


def test_a_second_command_publisher_beside_the_driver_stops_the_run_naming_it(ctx, tmp_path):
    """commands=driver: samples from two publishers on one topic cannot be told apart, so a
    second publisher stops the loop with one line naming it (as on the wrench topics)."""
    scene = mode_scene(tmp_path, duration=0.03)
    pubs = {}

    def intrude(k, node):
        if not pubs:
            pubs['clutch'] = node.create_publisher(Float64, '/driveline/clutch', DATA_QOS)
        if k >= 3:
            pubs['clutch'].publish(Float64(data=1.0))
    node, peers, _ = run(ctx, scene, on_state=intrude)
    assert node.exit_code == 1
    assert '/driveline/clutch: intruder' in node.error_message and 'fake_peers' in node.error_message


def test_an_outside_stack_sends_the_commands(ctx, tmp_path):
    """commands=external, no driver: a sample is in force from the next state published
    after it arrived; the stack here answers state k with its commands for t_(k+1)."""
    scene = mode_scene(tmp_path, duration=0.03, commands=[{'t': 0.0, 'clutch': 1.0, 'brake': 1.0, 'gear': 1}])
    pubs = {}

    def stack(k, node):
        if not pubs:
            pubs['clutch'] = node.create_publisher(Float64, '/driveline/clutch', DATA_QOS)
            pubs['gear'] = node.create_publisher(Int8, '/driveline/gear', DATA_QOS)
            pubs['brake'] = node.create_publisher(Float64, '/driveline/brake', DATA_QOS)
        if k == 5:
            pubs['brake'].publish(Float64(data=0.0))
            pubs['clutch'].publish(Float64(data=0.0))
        if k == 20:
            pubs['clutch'].publish(Float64(data=1.0))
        if k == 22:
            pubs['gear'].publish(Int8(data=0))
    node, peers, _ = run(ctx, scene, driver=False, on_state=stack, commands='external')
    assert node.exit_code == 0 and len(peers.js) == 31
    h = node.hybrid
    assert h.gear() == 0 and h.mode_names()['clutch'] == 'slip+'
    releases = [e for e in h.events if e.element == 'brake' and e.before == 'stuck']
    assert releases and 0.006 <= releases[0].t <= 0.008      # after state 5, within two steps
    assert h.commands.now.clutch == 1.0


def test_a_missing_driver_ends_the_wait_with_one_line(ctx, tmp_path):
    scene = mode_scene(tmp_path, duration=0.01)
    node, peers, _ = run(ctx, scene, driver=False, peer_timeout=0.5, start_timeout=2.0)
    assert node.exit_code == 1
    assert 'driver_node' in node.error_message and '/driveline/clutch' in node.error_message


def test_mode_scene_refuses_other_coupling_schemes(ctx, tmp_path):
    with pytest.raises(ParameterError, match='coupling_scheme'):
        CouplingNode(context=ctx, parameter_overrides=[
            Parameter('scene', value=mode_scene(tmp_path)),
            Parameter('coupling_scheme', value='extrapolate')])


def test_a_stall_ends_the_loop_with_its_line(ctx, tmp_path):
    """Clutch open, the engine answering -100 N m: the crank group (0.25 kg m^2) decelerates at
    400 rad/s^2 from 83.78 rad/s (800 rpm) and crosses the stall speed 52.36 rad/s (500 rpm) at
    (83.78 - 52.36) / 400 = 78.5 ms: the loop stops there, the line on /diagnostics, exit 0."""
    path = mode_scene(tmp_path, duration=0.2, commands=[{'t': 0.0, 'clutch': 1.0, 'brake': 1.0,
                                                         'gear': 1}])
    data = yaml.safe_load(open(path))
    data['engine'] = {'model': 'map', 'stall_rpm': 500.0}
    data['initial'] = {'speed_rpm': 800.0}
    with open(path, 'w') as fh:
        yaml.safe_dump(data, fh)
    node, peers, _ = run(ctx, path, torques=(-100.0, T_LOAD))
    assert node.exit_code == 0
    t_stall = (800.0 - 500.0) * np.pi / 30.0 / 400.0
    assert node.hybrid.stall.startswith('engine stalled at t=') and 'below the stall speed 52.36' in node.hybrid.stall
    t_line = float(node.hybrid.stall.split('t=')[1].split(' s')[0])
    assert t_line == pytest.approx(t_stall, abs=1e-6)
    assert len(peers.js) == int(t_stall / H) + 2          # states t_0 .. the step holding the stall
    assert node.loop_stats()['stall'] == node.hybrid.stall


def test_the_loop_bound_holds_inside_a_callback(ctx, tmp_path):
    """run()'s wall bound fires in the middle of a callback that does not return (here the
    last state's, after which the loop would end: the bound was checked only between
    callbacks, so such a callback overshot it unchecked); the AssertionError comes from
    inside that callback."""
    scene = mode_scene(tmp_path, duration=0.005)
    entered = []

    def stuck_on_the_last_state(k, _node):
        if k == 5:                        # t_5 = the end: the node finishes with this state
            entered.append(k)
            end = time.monotonic() + 600.0
            while time.monotonic() < end:     # as a compile would: Python, not a wait
                pass

    # 10 s: the Python backend's 60 exchanges took 0.4 s at load 3.5 (LOOP_BOUND_S), these 5
    # reach the stuck state well within it on a busy machine, so the bound fires inside it
    with pytest.raises(AssertionError, match='coupling node did not finish within 10 s') as err:
        run(ctx, scene, on_state=stuck_on_the_last_state, mode_backend='python', timeout=10.0)
    assert entered == [5]
    assert any(e.name == 'stuck_on_the_last_state' for e in err.traceback)


def test_wall_bound_interrupts_python_work_and_restores_the_handler():
    """The bound is raised inside running Python code (a busy loop standing for a compile),
    and the previous SIGALRM handler and a disarmed timer are left behind."""
    before = signal.getsignal(signal.SIGALRM)
    with pytest.raises(AssertionError, match='^busy loop within 0.2 s of wall time$'):
        with wall_bound(0.2, 'busy loop'):
            end = time.monotonic() + 600.0
            while time.monotonic() < end:
                pass
    assert signal.getsignal(signal.SIGALRM) is before
    assert signal.getitimer(signal.ITIMER_REAL) == (0.0, 0.0)
