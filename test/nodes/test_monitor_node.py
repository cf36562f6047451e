"""monitor_node in-process: nonuniformity of a known synthetic speed signal, levels from
thresholds, joint angle vs recommended limit, loop metrics taken from coupling diagnostics."""
from __future__ import annotations

import math
import time

import numpy as np
import pytest
import yaml

rclpy = pytest.importorskip('rclpy')
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402
from std_msgs.msg import String  # noqa: E402

from cvj_ros.nodes.common import ParameterError, make_executor, ns_to_stamp  # noqa: E402
from cvj_ros.nodes.monitor_node import MonitorNode  # noqa: E402
from cvj_ros.nodes.qos import DATA_QOS, LATCHED_QOS  # noqa: E402

pytestmark = pytest.mark.ros


def values(status: DiagnosticStatus) -> dict[str, float]:
    return {kv.key: float(kv.value) for kv in status.values}


def test_nonuniformity_levels_joint_angle_and_loop(ctx):
    node = MonitorNode(context=ctx, parameter_overrides=[
        Parameter('publish_every', value=500), Parameter('window', value=0.4)])
    peer = rclpy.create_node('peer', context=ctx)
    js_pub = peer.create_publisher(JointState, '/driveline/joint_states', DATA_QOS)
    diag_pub = peer.create_publisher(DiagnosticArray, '/diagnostics', DATA_QOS)
    scene_pub = peer.create_publisher(String, '/driveline/scene', LATCHED_QOS)
    got: list[DiagnosticArray] = []
    peer.create_subscription(DiagnosticArray, '/diagnostics',
                             lambda m: got.append(m) if m.status[0].name.startswith('monitor') else None,
                             DATA_QOS)
    ex = make_executor('events', ctx)
    ex.add_node(peer)
    ex.add_node(node)

    def spin_until(cond, timeout=5.0):
        deadline = time.monotonic() + timeout
        while not cond():
            assert time.monotonic() < deadline
            ex.spin_once(timeout_sec=0.02)

    try:
        spin_until(lambda: js_pub.get_subscription_count() >= 1 and diag_pub.get_subscription_count() >= 2
                   and scene_pub.get_subscription_count() >= 1 and node.diag_pub.get_subscription_count() >= 2)
        scene = {'driveline': [
            {'type': 'inertia', 'name': 'a', 'J': 1.0},
            {'type': 'joint', 'name': 'tri', 'kind': 'tripod', 'params': {'beta_deg': 28.0}},
            {'type': 'joint', 'name': 'rz', 'kind': 'rzeppa', 'params': {'beta_deg': 21.0},
             'limits': {'max_angle_deg': 15.0}},
            {'type': 'inertia', 'name': 'b', 'J': 1.0}]}
        scene_pub.publish(String(data=yaml.safe_dump({'scene': scene, 'seed': 0})))
        spin_until(lambda: len(node.joint_limits) == 2)
        kv = [KeyValue(key='energy_residual', value='0.004'), KeyValue(key='real_time_factor', value='3.5')]
        diag_pub.publish(DiagnosticArray(status=[DiagnosticStatus(name='coupling_node: loop', values=kv)]))
        spin_until(lambda: 'energy_residual' in node.loop_values)
        # 1 s at 1 ms: smooth shaft 40 (1 + 0.03 sin 2 pi 5 t), rough shaft 40 (1 + 0.1 sin ...),
        # standstill shaft; the window holds the last 0.4 s = two whole periods incl. peaks and troughs
        eps = {'smooth': 0.03, 'rough': 0.1}
        for k in range(1000):
            t = k * 1e-3
            s = math.sin(2 * math.pi * 5 * t)
            msg = JointState()
            msg.header.stamp = ns_to_stamp(k * 1_000_000)
            msg.name = ['smooth', 'rough', 'still', 'rz_cage']
            msg.position = [0.0, 0.0, 0.0, 0.0]
            msg.velocity = [40 * (1 + eps['smooth'] * s), 40 * (1 + eps['rough'] * s), 0.0,
                            40 * (1 + eps['rough'] * s)]
            msg.effort = [100 + 7 * s, 0.0, 0.0, 0.0]
            js_pub.publish(msg)
        spin_until(lambda: len(got) >= 2)
        last = {st.name: st for st in got[-1].status}
        assert got[-1].header.stamp.sec * 10**9 + got[-1].header.stamp.nanosec == 999_000_000
        smooth, rough = values(last['monitor: smooth']), values(last['monitor: rough'])
        # closed form: (max - min)/mean of w0 (1 + eps sin) = 2 eps
        assert smooth['nonuniformity'] == pytest.approx(0.06, rel=1e-4)
        assert rough['nonuniformity'] == pytest.approx(0.2, rel=1e-4)
        assert smooth['torque_amplitude_nm'] == pytest.approx(7.0, rel=1e-4)
        assert smooth['samples'] == 401
        assert last['monitor: smooth'].level == DiagnosticStatus.OK       # 0.06 < 0.11
        assert last['monitor: rough'].level == DiagnosticStatus.ERROR     # 0.2 >= 0.15
        assert last['monitor: still'].level == DiagnosticStatus.OK and last['monitor: still'].message == 'standstill'
        # the Rzeppa's cage is a joint member, not a shaft: reported, no threshold
        cage = last['monitor: rz_cage']
        assert values(cage)['nonuniformity'] == pytest.approx(0.2, rel=1e-4)
        assert cage.level == DiagnosticStatus.OK and 'internal member' in cage.message
        assert last['monitor: joint tri'].level == DiagnosticStatus.WARN  # 28 > 25 deg (seed 000)
        assert last['monitor: joint rz'].level == DiagnosticStatus.ERROR  # 21 > 15 + 5 deg (scene limit)
        loop = last['monitor: loop']
        assert loop.level == DiagnosticStatus.WARN and 'energy residual' in loop.message
        assert values(loop)['real_time_factor'] == pytest.approx(3.5)
    finally:
        ex.shutdown()
        peer.destroy_node()
        node.destroy_node()


def test_bad_threshold_parameter_named(ctx):
    with pytest.raises(ParameterError) as err:
        MonitorNode(context=ctx, parameter_overrides=[Parameter('nonuniformity_warn', value=float('nan'))])
    assert str(err.value).startswith('nonuniformity_warn:')
    with pytest.raises(ParameterError) as err:
        MonitorNode(context=ctx, parameter_overrides=[Parameter('window', value=0.0)])
    assert str(err.value).startswith('window:')


def test_a_standing_start_is_a_state_and_steady_running_is_judged_about_the_trend(ctx):
    """A scene with a clutch: while the coupling node's loop status says the clutch slips
    (a launch) a shaft whose speed rises from rest is reported at OK, not judged; once the
    window is wholly in steady running (clutch stuck, a gear engaged) a speed ramp is judged
    about its trend (no nonuniformity) and a ripple on it keeps its level (0.2 -> ERROR)."""
    node = MonitorNode(context=ctx, parameter_overrides=[
        Parameter('publish_every', value=100), Parameter('window', value=0.4)])
    node._use_scene({'driveline': [{'type': 'inertia', 'name': 'a', 'J': 1.0},
                                   {'type': 'clutch', 'name': 'clutch'},
                                   {'type': 'inertia', 'name': 'b', 'J': 1.0}]})
    assert node.states.expect_modes
    node.take_samples()

    def status(modes: dict[str, str], t_ns: int) -> None:
        node._take_loop_status('coupling_node', [('coupling_node: loop', list(modes.items()))], t_ns)

    def feed(k0: int, k1: int, ripple: float) -> dict[str, DiagnosticStatus]:
        for k in range(k0, k1):
            t = k * 1e-3
            s = math.sin(2 * math.pi * 5 * t)
            msg = JointState()
            msg.header.stamp = ns_to_stamp(k * 1_000_000)
            msg.name = ['ramp', 'rough']
            msg.position, msg.effort = [0.0, 0.0], [0.0, 0.0]
            w = 50.0 * t
            msg.velocity = [w, w * (1 + ripple * s)]
            node._on_joint_states(msg, publish=False)
        return {st.name: st for st in (status_message(x) for x in node.compute())}

    from cvj_ros.nodes.diagnostics import status_message
    slipping = {'clutch_state.clutch': 'slip+', 'gear.gearbox': '1', 'shifting': '0',
                'stall': '', 'mode_events': '1'}
    status(slipping, 0)
    status(slipping, 900_000_000)
    last = feed(0, 1000, 0.1)                    # 0 -> 50 rad/s while the clutch slips
    assert values(last['monitor: ramp'])['nonuniformity'] > 0.5
    assert last['monitor: ramp'].level == DiagnosticStatus.OK
    assert 'not judged: clutch slipping' in last['monitor: ramp'].message
    modes = last['monitor: modes']
    assert modes.level == DiagnosticStatus.OK and modes.message == 'clutch slipping'
    locked = dict(slipping, **{'clutch_state.clutch': 'stuck', 'mode_events': '2'})
    status(locked, 1_000_000_000)                # the lock (an event since the last status)
    status(locked, 1_100_000_000)
    last = feed(1000, 1600, 0.1)                 # window 1.2 .. 1.6 s: wholly locked
    ramp, rough = last['monitor: ramp'], last['monitor: rough']
    assert values(ramp)['nonuniformity_about_trend'] == pytest.approx(0.0, abs=1e-9)
    assert ramp.level == DiagnosticStatus.OK and 'about the speed trend' in ramp.message
    # 50 t (1 + 0.1 sin 10 pi t) over 1.2..1.6 s, two periods: the ripple about the trend,
    # +-0.1 x 80 rad/s at its largest, over the mean 70 rad/s
    assert values(rough)['nonuniformity_about_trend'] == pytest.approx(2 * 0.1 * 80 / 70, rel=0.05)
    assert rough.level == DiagnosticStatus.ERROR
    assert last['monitor: modes'].message == 'steady running'
    stalled = dict(locked, stall='engine stalled at t=1.600000 s')
    status(stalled, 1_600_000_000)
    last = feed(1600, 1700, 0.1)
    assert last['monitor: rough'].level == DiagnosticStatus.OK
    assert last['monitor: modes'].level == DiagnosticStatus.WARN
    assert last['monitor: modes'].message == 'engine stalled at t=1.600000 s'
    node.destroy_node()


def test_a_loop_status_is_used_from_its_stamp_on_whichever_arrived_first(ctx):
    """The coupling node publishes its loop status of t_100 after the joint state of t_100;
    a monitor whose executor took that status before the joint state of t_99 (busy, separate
    processes) must publish the same statuses at t_99 as one that took them in stamp order
    (composed): the status counts from its stamp on, not from its arrival."""
    from cvj_ros.nodes.diagnostics import status_message
    node = MonitorNode(context=ctx, parameter_overrides=[Parameter('publish_every', value=100)])

    def feed(k0: int, k1: int) -> None:
        for k in range(k0, k1):
            msg = JointState()
            msg.header.stamp = ns_to_stamp(k * 1_000_000)
            msg.name, msg.position, msg.effort = ['a'], [0.0], [0.0]
            msg.velocity = [40.0]
            node._on_joint_states(msg, publish=False)

    def names() -> set[str]:
        return {status_message(x).name for x in node.compute()}

    loop = [('coupling_node: loop', [('energy_residual', '1e-9'), ('real_time_factor', '12')])]
    feed(0, 50)
    node._take_loop_status('coupling_node', loop, 100_000_000)   # early: stamped t_100
    feed(50, 100)
    assert 'monitor: loop' not in names() and node.loop_values == {}   # publication at t_99
    feed(100, 101)
    assert 'monitor: loop' in names() and node.loop_values['real_time_factor'] == 12.0
    # in stamp order, an already reached stamp is used at once
    node._take_loop_status('coupling_node', [('coupling_node: loop', [('real_time_factor', '7')])],
                           50_000_000)
    assert node.loop_values['real_time_factor'] == 7.0
    node.destroy_node()
