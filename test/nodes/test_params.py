"""Parameter files and process-level parameter validation of the nodes."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from cvj_ros.nodes import coupling_node, driver_node, engine_node, load_node, monitor_node

ROOT = Path(__file__).resolve().parents[2]
PARAMS_DIR = ROOT / 'config' / 'params'
NODES = {'engine_node': engine_node, 'load_node': load_node, 'coupling_node': coupling_node,
         'monitor_node': monitor_node, 'driver_node': driver_node}
BIN = Path(sys.executable).parent


def scene_file(tmp_path) -> str:
    data = {'name': 'two_mass_test', 'duration': 0.01, 'exchange_step': 0.001,
            'engine': {'model': 'linear'}, 'load': {'model': 'constant', 'torque': 100.0},
            'driveline': [{'type': 'inertia', 'name': 'engine_crank', 'J': 0.128},
                          {'type': 'spring', 'name': 'shaft', 'stiffness': 715.4},
                          {'type': 'inertia', 'name': 'wheel', 'J': 0.161}]}
    path = tmp_path / 'scene.yaml'
    path.write_text(yaml.safe_dump(data))
    return str(path)


@pytest.mark.parametrize('name', sorted(NODES))
def test_params_file_matches_declared_parameters(name):
    data = yaml.safe_load((PARAMS_DIR / f'{name}.yaml').read_text())
    params = data['/**']['ros__parameters']
    specs = {s.name: s for s in NODES[name].PARAMS}
    assert set(params) == set(specs)
    for key, value in params.items():
        # every value in the file passes the node's own validation (scene aside: resolved at start)
        specs[key].validate(value)


@pytest.mark.parametrize('name', sorted(NODES))
def test_param_descriptors_have_description_and_ranges(name):
    for spec in NODES[name].PARAMS:
        d = spec.descriptor()
        assert d.description
        if spec.lo is not None and spec.hi is not None:
            assert d.floating_point_range or d.integer_range, spec.name


def _env():
    env = dict(os.environ)
    env.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    return env


@pytest.mark.e2e
def test_bad_parameter_exits_2_with_one_line(tmp_path):
    proc = subprocess.run([str(BIN / 'coupling_node'), '--ros-args', '-p', f'scene:={scene_file(tmp_path)}',
                           '-p', 'coupling_scheme:=zoh2'], capture_output=True, text=True, timeout=30,
                          env=_env())
    assert proc.returncode == 2
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip() and '[INFO]' not in ln]
    assert lines == ["coupling_node: error: coupling_scheme: must be one of zoh, extrapolate, "
                     "linear_implicit; got 'zoh2'"]
    assert 'Traceback' not in proc.stderr
    proc = subprocess.run([str(BIN / 'engine_node'), '--ros-args', '-p', 'scene:=no_such_scene_q'],
                          capture_output=True, text=True, timeout=30, env=_env())
    assert proc.returncode == 2 and proc.stderr.startswith('engine_node: error: scene:')
    # a value of the wrong type: rclpy's sentence ("Trying to set parameter ...: seed") as one line
    proc = subprocess.run([str(BIN / 'load_node'), '--ros-args', '-p', f'scene:={scene_file(tmp_path)}',
                           '-p', 'seed:=abc'], capture_output=True, text=True, timeout=30, env=_env())
    assert proc.returncode == 2
    assert proc.stderr.strip() == "load_node: error: seed: must be of type INTEGER, got 'abc' (STRING)"


def test_rclpy_type_rejection_becomes_one_short_reason():
    from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException
    from rclpy.parameter import Parameter

    from cvj_ros.nodes.parameters import _rclpy_reason
    exc = InvalidParameterTypeException(Parameter('seed', value='abc'), Parameter.Type.INTEGER)
    assert _rclpy_reason(exc) == "must be of type INTEGER, got 'abc' (STRING)"
    exc = InvalidParameterTypeException(Parameter('rate', value=[1, 2]), 'DOUBLE')
    assert _rclpy_reason(exc) == "must be of type DOUBLE, got '[1, 2]' (INTEGER_ARRAY)"
    # any other rejection keeps rclpy's last line
    exc = InvalidParameterValueException('rate', -1.0, 'must be >= 0')
    assert _rclpy_reason(exc) == str(exc).strip().splitlines()[-1]


@pytest.mark.e2e
def test_node_runs_alone_with_params_file_and_stops_on_sigint(tmp_path):
    proc = subprocess.Popen([str(BIN / 'load_node'), '--ros-args', '--params-file',
                             str(PARAMS_DIR / 'load_node.yaml'), '-p', f'scene:={scene_file(tmp_path)}'],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=_env())
    try:
        deadline = time.monotonic() + 15
        line = ''
        while 'waiting for /driveline/joint_states' not in line:
            assert time.monotonic() < deadline and proc.poll() is None, proc.stderr.read()
            line = proc.stderr.readline()
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=10) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
