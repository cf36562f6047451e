"""launch/driveline.launch.py, verified as far as this machine allows.

No launch/launch_ros wheels or Debian packages exist for this machine kind (no ROS
install), so the launch description itself is not executed here. What is checked: the file
compiles; its argument -> parameter mapping (plain Python, importable without `launch`)
gives every node only parameters that node declares, with values its descriptors accept;
external peers are left out; every executable it names is a console script of setup.py
(test/e2e/test_colcon.py checks they exist in a colcon install tree, next to the
installed launch file); and with `launch_ros` importable the description is generated.
test_launch_processes.py runs it with stand-in launch classes and real processes.
"""
from __future__ import annotations

import importlib
import importlib.util
import py_compile
import re
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
LAUNCH = REPO / 'launch' / 'driveline.launch.py'


def _launch_module():
    spec = importlib.util.spec_from_file_location('driveline_launch', LAUNCH)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _declared(node: str) -> dict:
    mod = importlib.import_module(f'cvj_ros.nodes.{node}')
    return {p.name: p for p in mod.PARAMS}


def test_launch_file_compiles() -> None:
    py_compile.compile(str(LAUNCH), doraise=True)


@pytest.mark.parametrize('external', ['none', 'load', 'engine', 'both'])
@pytest.mark.parametrize('record', ['true', 'false'])
def test_parameters_match_the_nodes_declared_parameters(external: str, record: str) -> None:
    pytest.importorskip('rclpy')
    mod = _launch_module()
    args = {'external': external, 'record': record, 'duration': '5.0', 'seed': '7',
            'mode': 'free-run', 'coupling_scheme': 'linear_implicit', 'nonfinite_torque': 'hold',
            'catch_up': 'burst', 'realtime_priority': '10'}
    params = mod.node_parameters(args)
    assert 'coupling_node' in params
    assert ('load_node' in params) == (external in ('none', 'engine'))
    assert ('engine_node' in params) == (external in ('none', 'load'))
    for node, values in params.items():
        declared = _declared(node)
        for name, value in values.items():
            assert name in declared, f'{node}: launch passes {name!r}, the node declares no such parameter'
            declared[name].validate(value)   # raises naming the parameter if out of range/type
    cp = params['coupling_node']
    assert cp['mode'] == 'free-run' and cp['coupling_scheme'] == 'linear_implicit'
    assert cp['duration'] == 5.0 and cp['seed'] == 7
    assert cp['nonfinite_torque'] == 'hold'
    assert cp['catch_up'] == 'burst' and cp['realtime_priority'] == 10
    # engine + load (ours or outside) + monitor + recorder see the first joint state
    assert cp['min_subscribers'] == 3 + (record == 'true')


def test_driver_argument_starts_driver_node_and_sets_the_command_rule() -> None:
    pytest.importorskip('rclpy')
    mod = _launch_module()
    on = mod.node_parameters({'scene': 'launch_clutch_chain', 'driver': 'true', 'duration': '2.0'})
    off = mod.node_parameters({'scene': 'launch_clutch_chain'})
    assert on['driver_node'] == {'scene': 'launch_clutch_chain', 'seed': -1, 'duration': 2.0}
    assert on['coupling_node']['commands'] == 'driver'
    assert 'driver_node' not in off and off['coupling_node']['commands'] == 'external'
    # the engine node counts the driver's throttle samples (lockstep), else applies on arrival
    assert on['engine_node']['commands'] == 'driver' and on['engine_node']['duration'] == 2.0
    assert 'commands' not in off['engine_node']
    free = mod.node_parameters({'scene': 'launch_clutch_chain', 'driver': 'true', 'mode': 'free-run'})
    assert 'commands' not in free['engine_node']
    for node, values in on.items():
        declared = _declared(node)
        for name, value in values.items():
            declared[name].validate(value)


def test_choices_match_the_nodes_choices() -> None:
    pytest.importorskip('rclpy')
    mod = _launch_module()
    coupling = _declared('coupling_node')
    assert set(mod.CHOICES['mode']) == set(coupling['mode'].choices)
    assert set(mod.CHOICES['coupling_scheme']) == set(coupling['coupling_scheme'].choices)
    assert set(mod.CHOICES['nonfinite_torque']) == set(coupling['nonfinite_torque'].choices)
    assert set(mod.CHOICES['catch_up']) == set(coupling['catch_up'].choices)


def test_bad_argument_names_the_argument() -> None:
    mod = _launch_module()
    with pytest.raises(ValueError, match='^external: must be one of'):
        mod.node_parameters({'external': 'wheel'})
    with pytest.raises(ValueError, match='duration'):
        mod.node_parameters({'duration': 'fast'})
    with pytest.raises(ValueError, match='^realtime_priority: must be an integer in 0..99'):
        mod.node_parameters({'mode': 'free-run', 'realtime_priority': '100'})
    with pytest.raises(ValueError, match='^catch_up: must be one of'):
        mod.node_parameters({'catch_up': 'drop'})


def test_recorder_command_is_cvj_sim_record() -> None:
    mod = _launch_module()
    assert mod.recorder_arguments({'record': 'false'}) is None
    rec = mod.recorder_arguments({'out': 'runs/x', 'storage': 'sqlite3'})
    assert rec[:2] == ['record', 'runs/x'] and rec[rec.index('--storage') + 1] == 'sqlite3'
    from cvj_ros.cli import build_parser
    ns = build_parser().parse_args(rec)     # the recorder's arguments parse as `cvj-sim record`
    assert ns.command == 'record' and ns.until_idle == 2.0


def test_every_executable_is_a_console_script() -> None:
    mod = _launch_module()
    setup = (REPO / 'setup.py').read_text()
    nodes = re.search(r"NODES = \[(.*?)\]", setup).group(1)
    scripts = set(re.findall(r"'(\w+)'", nodes)) | {'cvj-sim'}
    for exe in (*mod.NODE_EXECUTABLES, mod.RECORDER_EXECUTABLE):
        assert exe in scripts, exe
    assert "glob('launch/*.launch.py')" in setup   # installed to share/cvj_ros/launch


def test_generates_a_launch_description_where_launch_ros_exists() -> None:
    pytest.importorskip('launch_ros', reason='no launch_ros for this machine kind (see module docstring)')
    mod = _launch_module()
    assert mod.generate_launch_description().entities


def test_unknown_scene_is_one_line_before_any_process(tmp_path: Path) -> None:
    """A mistyped scene is refused by the launch file itself (one line, exit 2, the nearest
    shipped name), not by every node it would start."""
    mod = _launch_module()
    with pytest.raises(ValueError, match="^scene: .*'fwd_halfshat'; did you mean 'fwd_halfshaft'"):
        mod.node_parameters({'scene': 'fwd_halfshat'})
    proc = subprocess.run([sys.executable, str(LAUNCH), 'scene:=fwd_halfshat'],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and proc.stdout == '', proc
    assert proc.stderr.splitlines() == [
        "driveline.launch.py: error: scene: no scene file or shipped scene 'fwd_halfshat'; "
        "did you mean 'fwd_halfshaft'?"], proc.stderr
    scene = tmp_path / 'mine.yaml'
    scene.write_text((REPO / 'config' / 'scenes' / 'kavz685_lever.yaml').read_text())
    assert mod.node_parameters({'scene': str(scene)})['coupling_node']['scene'] == str(scene)
