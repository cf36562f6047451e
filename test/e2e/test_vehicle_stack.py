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
    data = bag.read_bag(tmp_path / 'out' / 'bag')
    js = data[bag.JOINT_STATES_TOPIC]
    load = data['/load/wrench']
    eng = data['/engine/wrench']
    assert len(js.t) == N + 1
    assert bag.SCENE_TOPIC in data          # the latched scene message was recorded
    i_wheel = js.shaft('wheel')
    # every joint state answered once, stamp echoed (t equal), torque = the stack's law
    assert len(load.t) >= N and np.array_equal(load.t[:N], js.t[:N])
    expected = np.array([_road_torque(w) for w in js.velocity[:N, i_wheel]])
    np.testing.assert_allclose(load.torque_z[:N], expected, rtol=1e-12, atol=1e-12)
    assert np.ptp(expected) > 1.0           # the load varies: the check is not vacuous
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
