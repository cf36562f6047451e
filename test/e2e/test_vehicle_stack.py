"""End to end: an outside vehicle stack (examples/vehicle_stack.py, standard messages only)
answers the load in place of load_node, nodes started by hand, recorded by `cvj-sim record`.

Checks that the stack's torques are the ones in the bag (each answer equals the example's
road-load law at the wheel speed of the joint state it answers, stamp and frame echoed)
and the ones the driveline integrated: the wheel's effort at t_k is the load answered for
t_(k-1) (coupling_node's documented effort convention), and an offline CoupledStepper fed
with the recorded engine and load torques reproduces every recorded speed (same ZOH
arithmetic and solver; bound 1e-9 relative = 1e3 x the solver's rtol 1e-12 floor of
repeated identical arithmetic, which in practice is bit-identical).
"""
from __future__ import annotations

import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from cvj_ros import bag

pytestmark = pytest.mark.e2e

REPO = Path(__file__).resolve().parents[2]
BIN = Path(sys.executable).parent
H = 1e-3
DURATION = 0.3
N = int(round(DURATION / H))
SCENE = {
    'name': 'e2e_stack', 'description': 'e2e: outside stack answers the road load', 'seed': 5,
    'duration': DURATION, 'exchange_step': H,
    'solver': {'method': 'dopri5', 'rtol': 1e-9, 'atol': 1e-11},
    'engine': {'model': 'linear'}, 'load': {'model': 'constant', 'torque': 0.0},
    'initial': {'speed_rpm': 300.0},
    'driveline': [
        {'type': 'inertia', 'name': 'crank', 'J': 0.128},
        {'type': 'spring', 'name': 'bush', 'stiffness': 715.4, 'damping': 6.35},
        {'type': 'joint', 'name': 'cpl', 'kind': 'hooke', 'fidelity': 'exact', 'params': {'beta_deg': 15.0}},
        {'type': 'inertia', 'name': 'wheel', 'J': 2.0},
    ],
}


def _road_torque(omega: float) -> float:
    """examples/vehicle_stack.py's law with its default parameters (N m)."""
    m, r, cr, cd, a, rho = 1300.0, 0.3, 0.012, 0.3, 2.2, 1.2
    v = omega * r
    return (m * 9.80665 * cr * math.tanh(v / 0.1) + 0.5 * rho * cd * a * v * abs(v)) * r


def _start(cmd: list[str], log: Path) -> subprocess.Popen:
    return subprocess.Popen(cmd, stdout=open(log, 'wb'), stderr=subprocess.STDOUT,
                            stdin=subprocess.DEVNULL, env=dict(os.environ), start_new_session=True)


def test_outside_stack_answers_the_load_and_is_recorded(tmp_path: Path) -> None:
    scene = tmp_path / 'scene.yaml'
    scene.write_text(yaml.safe_dump(SCENE, sort_keys=False))
    procs: dict[str, subprocess.Popen] = {}
    try:
        procs['record'] = _start([str(BIN / 'cvj-sim'), 'record', str(tmp_path / 'out'),
                                  '--until-idle', '3'], tmp_path / 'record.log')
        procs['stack'] = _start([sys.executable, str(REPO / 'examples' / 'vehicle_stack.py'),
                                 '--ros-args', '-p', 'use_sim_time:=true'], tmp_path / 'stack.log')
        procs['engine'] = _start([str(BIN / 'engine_node'), '--ros-args', '-p', f'scene:={scene}'],
                                 tmp_path / 'engine.log')
        # engine + stack + recorder subscribe to the joint states before step 0 (bounded wait
        # inside coupling_node: start_timeout)
        coupling = subprocess.run(
            [str(BIN / 'coupling_node'), '--ros-args', '-p', f'scene:={scene}', '-p', 'min_subscribers:=3',
             '-p', 'start_timeout:=60.0', '-p', 'peer_timeout:=30.0'],
            capture_output=True, text=True, timeout=240, env=dict(os.environ))
        assert coupling.returncode == 0, coupling.stdout[-2000:] + coupling.stderr[-2000:]
        assert procs['record'].wait(timeout=60) == 0
    finally:
        for p in procs.values():
            if p.poll() is None:
                os.killpg(p.pid, signal.SIGINT)
        for p in procs.values():
            try:
                p.wait(timeout=10)
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, signal.SIGKILL)
    assert 'answered' in (tmp_path / 'stack.log').read_text()
    check_stack_torques(tmp_path / 'out' / 'bag', scene)


def check_stack_torques(bag_path: Path, scene: Path, *, stack_law: bool = True) -> None:
    """The stack's load answers are in the bag (stamp echoed, the example's road-load law
    when ``stack_law``), the wheel effort is the answered load, and an offline
    CoupledStepper fed with the recorded torques reproduces every recorded speed."""
    data = bag.read_bag(bag_path)
    js = data[bag.JOINT_STATES_TOPIC]
    load = data['/load/wrench']
    eng = data['/engine/wrench']
    assert len(js.t) == N + 1
    assert bag.SCENE_TOPIC in data          # the latched scene message was recorded
    i_wheel = js.shaft('wheel')
    # every joint state answered once, stamp echoed (t equal), torque = the stack's law
    assert len(load.t) >= N and np.array_equal(load.t[:N], js.t[:N])
    if stack_law:
        expected = np.array([_road_torque(w) for w in js.velocity[:N, i_wheel]])
        np.testing.assert_allclose(load.torque_z[:N], expected, rtol=1e-12, atol=1e-12)
    assert np.ptp(load.torque_z[:N]) > 1.0  # the load varies: the check is not vacuous
    # the integrated load: wheel effort at t_k = load answered for t_(k-1)
    np.testing.assert_allclose(js.effort[1:N + 1, i_wheel], load.torque_z[:N], rtol=1e-12, atol=1e-12)
    # and the speeds are what those torques integrate to
    from cvj_ros.physics.cosim import CoupledStepper
    from cvj_ros.physics.driveline import Driveline
    from cvj_ros.physics.scene import load_scene
    sc = load_scene(scene)
    dl = Driveline.from_scene(sc)
    cs = CoupledStepper(dl, scheme='zoh', method=sc.solver.method, rtol=sc.solver.rtol, atol=sc.solver.atol)
    i_crank = js.shaft('crank')
    worst = 0.0
    for k in range(N):
        x = cs.advance((k + 1) * H, float(eng.torque_z[k]), float(load.torque_z[k]))
        _names, _pos, vel, _eff = dl.joint_states(x, 0.0, 0.0)
        for i in (i_crank, i_wheel):
            worst = max(worst, abs(vel[i] - js.velocity[k + 1, i]) / max(1.0, abs(vel[i])))
    assert worst < 1e-9, worst


def _run_external(tmp_path: Path, scene: Path, stack_cmd: list[str] | None, *extra: str,
                  timeout: float = 240.0) -> tuple[int, str, str]:
    """`cvj-sim run SCENE --external load` with ``stack_cmd`` started once the run says it
    waits (bounded by the run's own --external-timeout); returns exit code, stdout, stderr."""
    run = subprocess.Popen([str(BIN / 'cvj-sim'), 'run', str(scene), '--out', str(tmp_path / 'run'),
                            '--external', 'load', '--peer-timeout', '30', *extra],
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                           stdin=subprocess.DEVNULL, env=dict(os.environ), start_new_session=True)
    stack = None
    try:
        first = run.stdout.readline()        # the wait line comes before any node answers
        assert first.startswith('cvj-sim run: waiting up to'), first
        if stack_cmd is not None:
            stack = _start(stack_cmd, tmp_path / 'stack.log')
        out, err = run.communicate(timeout=timeout)
    finally:
        for p in (run, stack):
            if p is not None and p.poll() is None:
                os.killpg(p.pid, signal.SIGINT)
                try:
                    p.wait(timeout=10)
                except subprocess.TimeoutExpired:
                    os.killpg(p.pid, signal.SIGKILL)
    return run.returncode, first + out, err


def test_run_external_load_with_the_example_stack(tmp_path: Path) -> None:
    """`cvj-sim run --external load` + examples/vehicle_stack.py: the run starts everything
    but load_node, waits for the stack, records its torques, which are the integrated ones."""
    scene = tmp_path / 'scene.yaml'
    scene.write_text(yaml.safe_dump(SCENE, sort_keys=False))
    code, out, err = _run_external(tmp_path, scene, [
        sys.executable, str(REPO / 'examples' / 'vehicle_stack.py'), '--ros-args', '-p',
        'use_sim_time:=true'])
    assert code == 0, out + err
    assert f'waiting up to 30 s for an outside node on ROS_DOMAIN_ID={os.environ["ROS_DOMAIN_ID"]} ' \
           'to publish /load/wrench (the resisting torque' in out
    assert 'external=load' in out
    assert not (tmp_path / 'run' / 'logs' / 'load_node.log').exists()   # load_node not started
    check_stack_torques(tmp_path / 'run' / 'bag', scene)
    info = bag.bag_info(tmp_path / 'run' / 'bag')
    assert info.counts['/load/wrench'] >= N


def test_run_external_bounded_wait_names_the_topic(tmp_path: Path) -> None:
    """Nobody answers: after --external-timeout the run ends with one line naming the topic,
    the domain and how to start the stack; exit 1, no traceback."""
    scene = tmp_path / 'scene.yaml'
    scene.write_text(yaml.safe_dump(SCENE, sort_keys=False))
    t0 = time.monotonic()
    code, out, err = _run_external(tmp_path, scene, None, '--external-timeout', '2')
    wall = time.monotonic() - t0
    assert code == 1, out + err
    domain = os.environ['ROS_DOMAIN_ID']
    assert (f'cvj-sim: error: --external load: no outside node published /load/wrench on '
            f'ROS_DOMAIN_ID={domain} within --external-timeout=2 s; start it on that domain') in err, err
    assert 'Traceback' not in out + err
    assert wall < 2 + 30   # the 2 s bound + process start and stop (measured ~6 s here)


@pytest.mark.parametrize('layout', ['separate', 'composed'])
def test_run_external_names_a_publisher_of_the_wrong_type(tmp_path: Path, ctx: Any,
                                                          layout: str) -> None:
    """An outside node that publishes /load/wrench as std_msgs/String: the run never matches
    it; the line after --external-timeout names it and its type instead of 'no outside node
    published'. The 10 s leave the run's recorder time to discover the publisher, which exists
    before the run starts (discovery bounds elsewhere: 20-60 s for whole runs)."""
    import rclpy
    from std_msgs.msg import String
    scene = tmp_path / 'scene.yaml'
    scene.write_text(yaml.safe_dump(SCENE, sort_keys=False))
    node = rclpy.create_node('wrong_stack', context=ctx)
    try:
        node.create_publisher(String, '/load/wrench', 10)
        extra = ['--composed'] if layout == 'composed' else []
        code, out, err = _run_external(tmp_path, scene, None, '--external-timeout', '10', *extra)
    finally:
        node.destroy_node()
    assert code == 1, out + err
    domain = os.environ['ROS_DOMAIN_ID']
    assert (f'cvj-sim: error: --external load: /load/wrench is published by /wrong_stack as '
            f'std_msgs/msg/String, not geometry_msgs/msg/WrenchStamped, on ROS_DOMAIN_ID={domain} '
            f'(no geometry_msgs/msg/WrenchStamped publisher within --external-timeout=10 s)') in err, err
    assert 'Traceback' not in out + err


NOW_STACK = """
import sys
sys.path.insert(0, {examples!r})
import vehicle_stack


class NowStampingStack(vehicle_stack.VehicleStack):
    # the sim-time trap: stamp the answer with get_clock().now() instead of echoing
    def on_joint_states(self, msg):
        msg.header.stamp = self.get_clock().now().to_msg()
        super().on_joint_states(msg)


vehicle_stack.VehicleStack = NowStampingStack
sys.exit(vehicle_stack.main())
"""


def test_run_external_stack_stamping_with_sim_time_now(tmp_path: Path) -> None:
    """A stack that stamps its answers with get_clock().now() under use_sim_time: /clock t_k
    goes out before the joint state t_k, so its clock is at t_k when it answers (run
    finishes, torques integrated); if its executor still takes a joint state before the
    clock, the run ends with the one stamp line, not with "is load_node running?"."""
    scene = tmp_path / 'scene.yaml'
    scene.write_text(yaml.safe_dump(SCENE, sort_keys=False))
    script = tmp_path / 'now_stack.py'
    script.write_text(NOW_STACK.format(examples=str(REPO / 'examples')))
    code, out, err = _run_external(tmp_path, scene, [sys.executable, str(script), '--ros-args', '-p',
                                                     'use_sim_time:=true'], '--peer-timeout', '5')
    assert 'is load_node running' not in out + err
    if code == 0:
        check_stack_torques(tmp_path / 'run' / 'bag', scene)
    else:
        assert code == 1 and 'answers on /load/wrench are stamped' in err and \
            'echo the joint-state stamp' in err, out + err
    print(f'now()-stamping stack: exit {code}', err.strip().splitlines()[-1:] if code else '')


NAN_STACK = """
import math
import sys
sys.path.insert(0, {examples!r})
import vehicle_stack


class NanStack(vehicle_stack.VehicleStack):
    # a stack glitch: NaN road load for the joint states stamped 0.100 and 0.101 s
    def on_joint_states(self, msg):
        self._t_ns = msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
        super().on_joint_states(msg)

    def road_torque(self, omega):
        return math.nan if self._t_ns in (100_000_000, 101_000_000) else super().road_torque(omega)


vehicle_stack.VehicleStack = NanStack
sys.exit(vehicle_stack.main())
"""


def test_run_external_nonfinite_torque_hold(tmp_path: Path) -> None:
    """--nonfinite-torque hold: two NaN answers of the outside stack are replaced by the last
    finite load, the run finishes, held_torques = 2 in /diagnostics (WARN) and in the report."""
    scene = tmp_path / 'scene.yaml'
    scene.write_text(yaml.safe_dump(SCENE, sort_keys=False))
    script = tmp_path / 'nan_stack.py'
    script.write_text(NAN_STACK.format(examples=str(REPO / 'examples')))
    code, out, err = _run_external(tmp_path, scene, [sys.executable, str(script), '--ros-args', '-p',
                                                     'use_sim_time:=true'], '--nonfinite-torque', 'hold')
    assert code == 0, out + err
    assert 'WARN coupling loop: ignored stamps 0, rejected torques 0, held torques 2' in out, out
    data = bag.read_bag(tmp_path / 'run' / 'bag')
    js, load = data[bag.JOINT_STATES_TOPIC], data['/load/wrench']
    assert len(js.t) == N + 1
    k = int(np.searchsorted(js.t, 0.1 - 1e-12))       # index of t = 0.100 s
    assert np.isnan(load.torque_z[k]) and np.isnan(load.torque_z[k + 1])   # recorded as sent
    i_wheel = js.shaft('wheel')
    # the integrated load at t_(k+1) and t_(k+2) is the held last finite value (answer k-1)
    # (rtol 1e-12 as above: the effort goes through the joint-state arithmetic, ~1 ulp here)
    np.testing.assert_allclose(js.effort[k + 1:k + 3, i_wheel], load.torque_z[k - 1], rtol=1e-12)
    assert load.torque_z[k - 1] != load.torque_z[k + 2]   # the load moves on afterwards
    assert np.all(np.isfinite(js.velocity))
    last = [s for statuses in data['/diagnostics'].statuses for s in statuses
            if s['name'] == 'coupling_node: loop'][-1]
    assert last['values']['held_torques'] == '2' and last['level'] == 1   # WARN
