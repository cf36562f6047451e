"""engine_node in-process: answers joint states with the engine model's torque, echoes stamps,
names the crank frame, rejects bad throttle values and bad parameters."""
from __future__ import annotations

import math
import time

import pytest
import yaml

rclpy = pytest.importorskip('rclpy')
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus  # noqa: E402
from geometry_msgs.msg import WrenchStamped  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402
from std_msgs.msg import Float64  # noqa: E402

from cvj_ros.nodes.common import ParameterError, make_executor, ns_to_stamp  # noqa: E402
from cvj_ros.nodes.engine_node import EngineNode  # noqa: E402
from cvj_ros.nodes.qos import DATA_QOS  # noqa: E402

pytestmark = pytest.mark.ros

M1, K1 = 600.0, 12.5     # linear engine of the test scene, seed 004 eq. 3.23


def two_mass_scene(tmp_path, engine=None) -> str:
    data = {
        'name': 'two_mass_test', 'duration': 0.05, 'exchange_step': 0.001,
        'engine': engine or {'model': 'linear', 'm1': M1, 'k1': K1},
        'load': {'model': 'constant', 'torque': 100.0},
        'initial': {'speed_rad_s': 30.0},
        'driveline': [{'type': 'inertia', 'name': 'engine_crank', 'J': 0.128},
                      {'type': 'spring', 'name': 'shaft', 'stiffness': 715.4, 'damping': 6.35},
                      {'type': 'inertia', 'name': 'wheel', 'J': 0.161}],
    }
    path = tmp_path / 'two_mass.yaml'
    path.write_text(yaml.safe_dump(data))
    return str(path)


class Harness:
    """Peer node: publishes joint states / throttle, collects wrenches and diagnostics."""

    def __init__(self, ctx, node):
        self.peer = rclpy.create_node('peer', context=ctx)
        self.js_pub = self.peer.create_publisher(JointState, '/driveline/joint_states', DATA_QOS)
        self.th_pub = self.peer.create_publisher(Float64, '/engine/throttle', DATA_QOS)
        self.wrenches: list[WrenchStamped] = []
        self.diags: list[DiagnosticArray] = []
        self.peer.create_subscription(WrenchStamped, '/engine/wrench', self.wrenches.append, DATA_QOS)
        self.peer.create_subscription(DiagnosticArray, '/diagnostics', self.diags.append, DATA_QOS)
        self.ex = make_executor('events', ctx)
        self.ex.add_node(self.peer)
        self.ex.add_node(node)
        self.spin_until(lambda: self.js_pub.get_subscription_count() >= 1
                        and self.th_pub.get_subscription_count() >= 1
                        and node.wrench_pub.get_subscription_count() >= 1
                        and node.diag_pub.get_subscription_count() >= 1)

    def spin_until(self, cond, timeout=5.0):
        deadline = time.monotonic() + timeout
        while not cond():
            assert time.monotonic() < deadline, 'condition not reached'
            self.ex.spin_once(timeout_sec=0.02)

    def send_js(self, ns, names, position, velocity):
        msg = JointState()
        msg.header.stamp = ns_to_stamp(ns)
        msg.name, msg.position, msg.velocity = names, position, velocity
        msg.effort = [0.0] * len(names)
        self.js_pub.publish(msg)

    def close(self):
        self.ex.shutdown()
        self.peer.destroy_node()


def make_node(ctx, tmp_path, **params):
    overrides = [Parameter('scene', value=two_mass_scene(tmp_path))]
    overrides += [Parameter(k, value=v) for k, v in params.items()]
    return EngineNode(context=ctx, parameter_overrides=overrides)


def test_answers_with_model_torque_echoed_stamp_and_crank_frame(ctx, tmp_path):
    node = make_node(ctx, tmp_path)
    h = Harness(ctx, node)
    try:
        samples = [(0, 0.0, 0.0), (1_000_000, 0.03, 30.0), (2_500_000_123, 7.5, 41.25)]
        for ns, phi, omega in samples:
            # crank is not the first name: the node must look it up by name
            h.send_js(ns, ['wheel', 'engine_crank'], [0.0, phi], [1e3, omega])
        h.spin_until(lambda: len(h.wrenches) == len(samples))
        for (ns, _phi, omega), w in zip(samples, h.wrenches):
            assert w.header.stamp.sec * 10**9 + w.header.stamp.nanosec == ns
            assert w.header.frame_id == 'engine_crank'
            # closed form of the linear characteristic, seed 004 eq. 3.23, N m
            assert w.wrench.torque.z == pytest.approx(M1 - K1 * omega, rel=1e-12)
            assert w.wrench.force.x == 0.0 and w.wrench.torque.x == 0.0
    finally:
        h.close()
        node.destroy_node()


def test_throttle_nan_and_out_of_range_rejected_valid_applied(ctx, tmp_path):
    node = make_node(ctx, tmp_path)
    h = Harness(ctx, node)
    try:
        for bad in (math.nan, math.inf, 1.5, -0.1):
            h.th_pub.publish(Float64(data=bad))
        h.spin_until(lambda: node.throttle_rejected == 4)
        h.spin_until(lambda: len(h.diags) >= 4)
        assert all(d.status[0].level == DiagnosticStatus.ERROR for d in h.diags)
        assert 'nan' in h.diags[0].status[0].message and '/engine/throttle' in h.diags[0].status[0].message
        h.send_js(0, ['engine_crank', 'wheel'], [0.0, 0.0], [20.0, 20.0])
        h.spin_until(lambda: len(h.wrenches) == 1)
        assert h.wrenches[0].wrench.torque.z == pytest.approx(M1 - K1 * 20.0)   # still full throttle
        h.th_pub.publish(Float64(data=0.5))
        h.spin_until(lambda: node.throttle == 0.5)
        h.send_js(1_000_000, ['engine_crank', 'wheel'], [0.0, 0.0], [20.0, 20.0])
        h.spin_until(lambda: len(h.wrenches) == 2)
        # linear engine with throttle x: M = x M1 - K1 omega
        assert h.wrenches[1].wrench.torque.z == pytest.approx(0.5 * M1 - K1 * 20.0)
    finally:
        h.close()
        node.destroy_node()


def test_non_finite_speed_not_answered(ctx, tmp_path):
    node = make_node(ctx, tmp_path)
    h = Harness(ctx, node)
    try:
        h.send_js(0, ['engine_crank'], [0.0], [math.nan])
        h.spin_until(lambda: len(h.diags) >= 1)
        assert h.diags[0].status[0].level == DiagnosticStatus.ERROR
        assert node.answered == 0 and not h.wrenches
    finally:
        h.close()
        node.destroy_node()


@pytest.mark.parametrize('params, name', [
    ({'throttle': 1.5}, 'throttle'),
    ({'throttle': 0.3, 'seed': -7}, 'seed'),
    ({'engine_spec': '{model: lineer}'}, 'engine_spec'),
    ({'engine_spec': '[1, 2'}, 'engine_spec'),
])
def test_bad_parameters_name_the_parameter(ctx, tmp_path, params, name):
    with pytest.raises(ParameterError) as err:
        make_node(ctx, tmp_path, **params)
    assert str(err.value).startswith(f'{name}:')


def test_bad_scene_names_scene(ctx, tmp_path):
    with pytest.raises(ParameterError) as err:
        EngineNode(context=ctx, parameter_overrides=[Parameter('scene', value='no_such_scene_xyz')])
    assert str(err.value).startswith('scene:')
    with pytest.raises(ParameterError) as err:
        EngineNode(context=ctx)
    assert str(err.value).startswith('scene:')


def test_map_engine_answers_through_the_compiled_formula_with_the_same_bytes() -> None:
    """engine_node answers a map engine through CompiledMapEngineTorque (map_engine_nb's
    entry point): the same bytes as the Python MapEngine.torque at random speeds (both
    directions, past the rev limiter) and crank angles, for fwd_halfshaft's engine and the
    default map with idle governor, stall fade and ripple; the throttle follows
    set_throttle at once; a linear engine is answered as it is."""
    import numpy as np

    from cvj_ros.bench import resolve_scene
    from cvj_ros.nodes.engine_node import answering_source
    from cvj_ros.physics.kernel.sources_nb import CompiledMapEngineTorque
    from cvj_ros.physics.engine import engine_from_spec
    rng = np.random.default_rng(7)
    specs = [dict(resolve_scene('fwd_halfshaft').engine),
             {'model': 'map', 'idle_rpm': 800.0, 'stall_rpm': 400.0, 'cylinders': 4,
              'ripple_amplitude': 0.3}]
    for spec in specs:
        engine = engine_from_spec(spec)
        fast = answering_source(engine)
        assert isinstance(fast, CompiledMapEngineTorque)
        for x in (1.0, 0.37, 0.0):
            engine.set_throttle(x)
            for w, phi in zip(rng.uniform(-100.0, 900.0, 3000), rng.uniform(-50.0, 50.0, 3000)):
                a = engine.torque(0.0, float(w), float(phi))
                b = fast.torque(0.0, float(w), float(phi))
                assert np.float64(a).tobytes() == np.float64(b).tobytes(), (spec, x, w, phi, a, b)
        assert fast.describe() == engine.describe()
    linear = engine_from_spec({'model': 'linear'})
    assert answering_source(linear) is linear


def test_engine_spec_examples_of_the_descriptor_and_the_docs_work(ctx, tmp_path):
    """The ``engine_spec`` example in the parameter's descriptor and in docs/nodes.md, as
    written, build a node whose engine is that spec (they showed M1/K1, which are rejected)."""
    import re
    from pathlib import Path

    from cvj_ros.nodes.engine_node import PARAMS
    desc = next(p for p in PARAMS if p.name == 'engine_spec').description
    docs = (Path(__file__).resolve().parents[2] / 'docs' / 'nodes.md').read_text()
    examples = [re.search(r'e\.g\. "(\{[^"]+\})"', desc).group(1),
                re.search(r'engine_spec:="(\{[^"]+\})"', docs.replace('\n  ', ' ')).group(1)]
    for spec in examples:
        node = make_node(ctx, tmp_path, engine_spec=spec)
        try:   # the linear characteristic M = m1 - k1 omega (Davidbaev et al. 2023, eq. 3.23)
            assert node.engine.torque(0.0, 10.0) == pytest.approx(600.0 - 12.0 * 10.0)
        finally:
            node.destroy_node()


def test_driver_throttle_is_counted_and_a_state_waits_for_its_step(ctx, tmp_path):
    """commands=driver: the n-th throttle sample belongs to the step of the schedule's n-th
    throttle change; a joint state t_k that arrives before the throttle of step k (the two
    come from different processes) is answered only once it is in, with it applied; a state
    of a step without a change is answered at once."""
    path = tmp_path / 'throttle_schedule.yaml'
    data = yaml.safe_load(open(two_mass_scene(tmp_path)))
    # throttle 0.5 at t0, 0.25 from t = 2 ms (steps of h = 1 ms)
    data['commands'] = [{'t': 0.0, 'throttle': 0.5}, {'t': 0.0015, 'throttle': 0.5},
                        {'t': 0.002, 'throttle': 0.25}]
    path.write_text(yaml.safe_dump(data))
    from cvj_ros.nodes.command_plan import CommandPlan
    from cvj_ros.physics.scene import load_scene
    plan = CommandPlan.from_scene(load_scene(str(path)), 1_000_000, 50)
    assert [k for k, _row in plan] == [0, 2] and plan.stamps('throttle') == [0, 2_000_000]
    node = EngineNode(context=ctx, parameter_overrides=[
        Parameter('scene', value=str(path)), Parameter('commands', value='driver')])
    h = Harness(ctx, node)
    names, omega = ['engine_crank', 'wheel'], 20.0
    try:
        h.send_js(0, names, [0.0, 0.0], [omega, omega])          # before the throttle of step 0
        h.spin_until(lambda: node.throttle_waits == 1)
        time.sleep(0.05)
        h.ex.spin_once(timeout_sec=0.02)
        assert h.wrenches == []
        h.th_pub.publish(Float64(data=0.5))
        h.spin_until(lambda: len(h.wrenches) == 1)
        h.send_js(1_000_000, names, [0.0, 0.0], [omega, omega])  # step 1: no change, answered
        h.spin_until(lambda: len(h.wrenches) == 2)
        h.send_js(2_000_000, names, [0.0, 0.0], [omega, omega])  # before the throttle of step 2
        h.spin_until(lambda: node.throttle_waits == 2)
        assert len(h.wrenches) == 2
        h.th_pub.publish(Float64(data=0.25))
        h.spin_until(lambda: len(h.wrenches) == 3)
        # linear engine with throttle x: M = x M1 - K1 omega (as above)
        expect = [0.5, 0.5, 0.25]
        for w, x, ns in zip(h.wrenches, expect, (0, 1_000_000, 2_000_000)):
            assert w.header.stamp.sec * 10**9 + w.header.stamp.nanosec == ns
            assert w.wrench.torque.z == pytest.approx(x * M1 - K1 * omega, rel=1e-12)
    finally:
        h.close()
        node.destroy_node()


def test_commands_driver_needs_a_schedule(ctx, tmp_path):
    with pytest.raises(ParameterError, match='commands'):
        make_node(ctx, tmp_path, commands='driver')


def test_throttle_scale_lockstep_waits_for_the_scale_of_the_step(ctx, tmp_path):
    """throttle_scale=lockstep (a shift schedule's torque intervention): the n-th
    /engine/throttle_scale sample is the factor on the pedal for step n; the joint state t_k
    is answered only once the scale of step k is in, at pedal x scale, whichever of the two
    arrives first; with the driver's throttle counted too (commands=driver) both must be in."""
    path = tmp_path / 'scaled.yaml'
    data = yaml.safe_load(open(two_mass_scene(tmp_path)))
    data['commands'] = [{'t': 0.0, 'throttle': 0.8}]
    path.write_text(yaml.safe_dump(data))
    node = EngineNode(context=ctx, parameter_overrides=[
        Parameter('scene', value=str(path)), Parameter('commands', value='driver'),
        Parameter('throttle_scale', value='lockstep')])
    assert node.scale_lockstep
    h = Harness(ctx, node)
    scale_pub = h.peer.create_publisher(Float64, '/engine/throttle_scale', DATA_QOS)
    names, omega = ['engine_crank', 'wheel'], 20.0
    try:
        h.spin_until(lambda: scale_pub.get_subscription_count() >= 1)
        h.th_pub.publish(Float64(data=0.8))
        h.send_js(0, names, [0.0, 0.0], [omega, omega])          # throttle in, scale not yet
        h.spin_until(lambda: node.throttle_waits == 1)
        time.sleep(0.05)
        h.ex.spin_once(timeout_sec=0.02)
        assert h.wrenches == []
        scale_pub.publish(Float64(data=1.0))
        h.spin_until(lambda: len(h.wrenches) == 1)
        scale_pub.publish(Float64(data=0.25))                    # step 1's scale first
        h.spin_until(lambda: node._scale_taken == 2)
        h.send_js(1_000_000, names, [0.0, 0.0], [omega, omega])
        h.spin_until(lambda: len(h.wrenches) == 2)
        h.send_js(2_000_000, names, [0.0, 0.0], [omega, omega])  # scale of step 2 not in
        h.spin_until(lambda: node.throttle_waits == 2)
        scale_pub.publish(Float64(data=0.5))
        h.spin_until(lambda: len(h.wrenches) == 3)
        for w, s in zip(h.wrenches, (1.0, 0.25, 0.5)):
            assert w.wrench.torque.z == pytest.approx(0.8 * s * M1 - K1 * omega, rel=1e-12)
        assert node.throttle == 0.8 and node.scale == 0.5
    finally:
        h.close()
        node.destroy_node()


def test_throttle_scale_auto_follows_the_scene_and_on_arrival_applies_at_once(ctx, tmp_path):
    node = make_node(ctx, tmp_path)                  # no shift schedule: auto = on_arrival
    assert not node.scale_lockstep
    node.destroy_node()
    node = make_node(ctx, tmp_path, throttle=0.6)
    h = Harness(ctx, node)
    scale_pub = h.peer.create_publisher(Float64, '/engine/throttle_scale', DATA_QOS)
    try:
        h.spin_until(lambda: scale_pub.get_subscription_count() >= 1)
        scale_pub.publish(Float64(data=0.5))
        h.spin_until(lambda: node.scale == 0.5)
        h.send_js(0, ['engine_crank', 'wheel'], [0.0, 0.0], [10.0, 10.0])
        h.spin_until(lambda: len(h.wrenches) == 1)
        assert h.wrenches[0].wrench.torque.z == pytest.approx(0.3 * M1 - K1 * 10.0, rel=1e-12)
        scale_pub.publish(Float64(data=1.5))         # out of range: refused, not applied
        h.spin_until(lambda: node.throttle_rejected == 1)
        assert node.scale == 0.5
        scale_pub.publish(b'\x07junk')               # not CDR: dropped, counted, not applied
        h.spin_until(lambda: node.malformed.total == 1)
        assert node.scale == 0.5 and node.engine.throttle == 0.3
    finally:
        h.close()
        node.destroy_node()
