"""launch/driveline.launch.py run as launch_ros would run it, with real processes.

No launch/launch_ros wheels exist for this machine kind, so the launch description is
executed with stub classes of ``launch``/``launch_ros`` (:func:`launch_command_lines`): the
stubs record each action, and the command lines are built as launch_ros's ``Node`` action
builds them (launch_ros ``actions/node.py``, Jazzy): ``<executable> <arguments...>
--ros-args`` always, then ``-r __node:=<name>`` when the action names the node, then
``--params-file <file>`` per parameter dictionary, the file holding ``{'/**':
{'ros__parameters': <dict>}}`` as launch_ros writes it (yaml.dump) when no namespace is
given. Those lines are then run as processes, all started at once as ``ros2 launch``
does: the recorder must accept the ``--ros-args`` launch_ros appends, and the coupling
node must not start before every subscriber the launch file announces (engine, load,
monitor, recorder) has matched, so the bag is complete.
"""
from __future__ import annotations

import importlib.util
import os
import shlex
import shutil
import signal
import subprocess
import sys
import time
import types
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest
import yaml

REPO = Path(__file__).resolve().parents[2]
LAUNCH = REPO / 'launch' / 'driveline.launch.py'
BIN = Path(sys.executable).parent
H = 1e-3
DURATION = 0.3
N = int(round(DURATION / H))
SCENE = {
    'name': 'launch_lines', 'description': 'launch-equivalent run', 'seed': 3,
    'duration': DURATION, 'exchange_step': H,
    'solver': {'method': 'dopri5', 'rtol': 1e-8, 'atol': 1e-10},
    'engine': {'model': 'linear'}, 'load': {'model': 'constant', 'torque': 20.0},
    'initial': {'speed_rpm': 300.0},
    'driveline': [
        {'type': 'inertia', 'name': 'crank', 'J': 0.128},
        {'type': 'spring', 'name': 'bush', 'stiffness': 715.4, 'damping': 6.35},
        {'type': 'joint', 'name': 'cpl', 'kind': 'hooke', 'params': {'beta_deg': 15.0}},
        {'type': 'inertia', 'name': 'wheel', 'J': 0.5},
    ],
}


class _Action:
    def __init__(self, **kwargs: Any) -> None:
        self.kwargs = kwargs


@contextmanager
def _stub_launch() -> Iterator[None]:
    """``launch``, ``launch.actions`` and ``launch_ros.actions`` as stub modules whose
    classes keep their keyword arguments (restored afterwards)."""
    names = ('launch', 'launch.actions', 'launch_ros', 'launch_ros.actions')
    saved = {n: sys.modules.get(n) for n in names}

    class LaunchDescription:
        def __init__(self, entities: list[Any]) -> None:
            self.entities = list(entities)

    class DeclareLaunchArgument(_Action):
        def __init__(self, name: str, **kwargs: Any) -> None:
            super().__init__(**kwargs)
            self.name = name

    class OpaqueFunction(_Action):
        pass

    class Node(_Action):
        pass

    launch = types.ModuleType('launch')
    launch.LaunchDescription = LaunchDescription
    actions = types.ModuleType('launch.actions')
    actions.DeclareLaunchArgument = DeclareLaunchArgument
    actions.OpaqueFunction = OpaqueFunction
    launch_ros = types.ModuleType('launch_ros')
    ros_actions = types.ModuleType('launch_ros.actions')
    ros_actions.Node = Node
    sys.modules.update({'launch': launch, 'launch.actions': actions,
                        'launch_ros': launch_ros, 'launch_ros.actions': ros_actions})
    try:
        yield
    finally:
        for n, mod in saved.items():
            if mod is None:
                sys.modules.pop(n, None)
            else:
                sys.modules[n] = mod


def launch_command_lines(arguments: dict[str, str], params_dir: Path) -> list[tuple[str, list[str]]]:
    """(label, command line) per process ``ros2 launch cvj_ros driveline.launch.py
    <arguments>`` starts, in the launch description's order, built as launch_ros's Node
    action builds them; parameter files are written to ``params_dir``."""
    spec = importlib.util.spec_from_file_location('driveline_launch_lines', LAUNCH)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    with _stub_launch():
        desc = mod.generate_launch_description()
    config = {}
    nodes = []
    for entity in desc.entities:
        kind = type(entity).__name__
        if kind == 'DeclareLaunchArgument':
            config[entity.name] = arguments.get(entity.name, entity.kwargs['default_value'])
        elif kind == 'OpaqueFunction':
            context = types.SimpleNamespace(launch_configurations=dict(config))
            nodes += entity.kwargs['function'](context)
    unknown = set(arguments) - set(config)
    assert not unknown, f'not launch arguments: {unknown}'
    lines = []
    for i, node in enumerate(nodes):
        kw = node.kwargs
        assert kw['package'] == 'cvj_ros'
        cmd = [str(BIN / kw['executable']), *kw.get('arguments', []), '--ros-args']
        if kw.get('name') is not None:
            cmd += ['-r', f'__node:={kw["name"]}']
        for j, params in enumerate(kw.get('parameters') or []):
            path = params_dir / f'launch_params_{i}_{j}'
            path.write_text(yaml.dump({'/**': {'ros__parameters': params}}, default_flow_style=False))
            cmd += ['--params-file', str(path)]
        lines.append((kw.get('name') or kw['executable'], cmd))
    return lines


def test_command_lines_are_launch_ros_lines(tmp_path: Path) -> None:
    """The builder follows the launch file: the recorder first (cvj-sim record ... --ros-args),
    then each node under its name with one parameter file."""
    lines = dict(launch_command_lines({'scene': 'kavz685_lever'}, tmp_path))
    assert list(lines)[0] == 'cvj-sim'
    rec = lines['cvj-sim']
    assert rec[1:3] == ['record', 'runs/launch'] and rec[-1] == '--ros-args'
    assert '--run-only' in rec
    for node in ('engine_node', 'coupling_node', 'load_node', 'monitor_node'):
        cmd = lines[node]
        assert cmd[1:4] == ['--ros-args', '-r', f'__node:={node}'] and cmd[4] == '--params-file'
        params = yaml.safe_load(Path(cmd[5]).read_text())['/**']['ros__parameters']
        assert params['scene'] == 'kavz685_lever' and 'run_token' not in params


def test_cvj_sim_accepts_what_launch_appends(tmp_path: Path) -> None:
    """`cvj-sim record ... --ros-args` parses to the same options as without it."""
    from cvj_ros.cli import build_parser
    from cvj_ros.rosargs import remove_ros_args
    rec = dict(launch_command_lines({'out': str(tmp_path)}, tmp_path))['cvj-sim']
    ns = build_parser('record').parse_args(remove_ros_args(rec[1:]))
    assert ns.out == str(tmp_path) and ns.until_idle == 2.0


def _parsed_p(cmd: list[str]) -> dict[str, Any]:
    """The ``-p name:=value`` pairs of a command line, each value read as YAML as rcl reads it."""
    return {cmd[i + 1].partition(':=')[0]: yaml.safe_load(cmd[i + 1].partition(':=')[2])
            for i, part in enumerate(cmd) if part == '-p'}


def _without(cmd: list[str], option: str) -> list[str]:
    """A command line without ``--ros-args`` and without each ``option VALUE`` pair."""
    out, skip = [], False
    for part in cmd:
        if skip:
            skip = False
        elif part == option:
            skip = True
        elif part != '--ros-args':
            out.append(part)
    return out


@pytest.mark.parametrize('arguments', [
    {'scene': 'kavz685_lever'},
    {'scene': 'launch_clutch_chain', 'driver': 'true', 'mode': 'free-run', 'catch_up': 'burst'},
    {'scene': '123', 'external': 'load', 'record': 'false', 'monitor': 'false', 'duration': '1.5'},
], ids=['default', 'driver-free-run', 'external-no-record'])
def test_printed_equivalent_is_the_launch_ros_lines(arguments: dict[str, str], tmp_path: Path,
                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    """`python launch/driveline.launch.py ARG:=VALUE ...` prints, per process, the executable,
    arguments and node name launch_ros builds, with the parameter file's values as `-p` (a
    string YAML would read as a number stays a string: a scene file named '123' in the working
    directory): shell lines a stranger without launch_ros can run instead."""
    shutil.copy(REPO / 'config' / 'scenes' / 'kavz685_lever.yaml', tmp_path / '123')
    monkeypatch.chdir(tmp_path)
    out = subprocess.run([sys.executable, str(LAUNCH), *(f'{k}:={v}' for k, v in arguments.items())],
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 0 and out.stderr == '', out.stderr
    printed = [shlex.split(line) for line in out.stdout.splitlines()]
    built = launch_command_lines(arguments, tmp_path)
    assert [cmd[0] for cmd in printed] == [Path(cmd[0]).name for _, cmd in built]
    for mine, (_, theirs) in zip(printed, built):
        files = [theirs[i + 1] for i, part in enumerate(theirs) if part == '--params-file']
        params = {}
        for f in files:
            params.update(yaml.safe_load(Path(f).read_text())['/**']['ros__parameters'])
        assert _parsed_p(mine) == params
        assert _without(mine[1:], '-p') == _without(theirs[1:], '--params-file')


def test_printed_equivalent_bad_argument_is_one_line() -> None:
    for args, words in ((['mode:=fast'], 'mode: must be one of lockstep, free-run'),
                        (['scen:=x'], 'scen:=x: expected NAME:=VALUE')):
        out = subprocess.run([sys.executable, str(LAUNCH), *args], capture_output=True, text=True,
                             timeout=60)
        assert out.returncode == 2 and out.stdout == ''
        assert out.stderr.count('\n') == 1 and words in out.stderr, out.stderr


def _start(cmd: list[str], log: Path) -> subprocess.Popen:
    return subprocess.Popen(cmd, stdout=open(log, 'wb'), stderr=subprocess.STDOUT,
                            stdin=subprocess.DEVNULL, env=dict(os.environ), start_new_session=True)


def _stop_all(procs: dict[str, subprocess.Popen]) -> None:
    for p in procs.values():
        if p.poll() is None:
            os.killpg(p.pid, signal.SIGINT)
    for p in procs.values():
        try:
            p.wait(timeout=15)
        except subprocess.TimeoutExpired:
            os.killpg(p.pid, signal.SIGKILL)
            p.wait()


def check_complete_bag(bag_path: Path, n_steps: int) -> dict[str, int]:
    """Every exchange of the run is in the bag: n_steps + 1 joint states and /clock
    messages from t = 0, n_steps answers of engine and load, the scene message. Returns the
    message count per topic."""
    from cvj_ros import bag
    data = bag.read_bag(bag_path)
    js = data[bag.JOINT_STATES_TOPIC]
    assert len(js.t) == n_steps + 1, f'{len(js.t)} of {n_steps + 1} joint states'
    assert js.t[0] == 0.0
    counts = {topic: len(getattr(series, 't', ())) for topic, series in data.items()}
    assert counts.get('/clock', 0) >= n_steps + 1, counts
    assert counts['/engine/wrench'] >= n_steps and counts['/load/wrench'] >= n_steps, counts
    assert bag.SCENE_TOPIC in data
    return counts


@pytest.mark.e2e
def test_launch_equivalent_run_records_a_complete_bag(tmp_path: Path) -> None:
    scene = tmp_path / 'scene.yaml'
    scene.write_text(yaml.safe_dump(SCENE, sort_keys=False))
    out = tmp_path / 'out'
    lines = launch_command_lines({'scene': str(scene), 'out': str(out)}, tmp_path)
    procs: dict[str, subprocess.Popen] = {}
    try:
        for label, cmd in lines:        # all at once, as ros2 launch starts them
            procs[label] = _start(cmd, tmp_path / f'{label}.log')
        # the coupling node ends the run (exit 0), the recorder 2 s after the last message
        deadline = time.monotonic() + 300
        for label in ('coupling_node', 'cvj-sim'):
            rc = procs[label].wait(timeout=max(1.0, deadline - time.monotonic()))
            assert rc == 0, (label, (tmp_path / f'{label}.log').read_text()[-3000:])
    finally:
        _stop_all(procs)
    assert 'unrecognized arguments' not in (tmp_path / 'cvj-sim.log').read_text()
    check_complete_bag(out / 'bag', N)


CLUTCH_DURATION = 1.6      # the launch's throttle ramp (1.0-1.3 s) and the clutch's from 1.5 s
CLUTCH_TOPICS = ('/engine/throttle', '/driveline/clutch', '/driveline/brake',
                 '/engine/throttle_scale', '/driveline/joint_states', '/engine/wrench', '/clock')


@pytest.mark.e2e
def test_launch_equivalent_run_records_the_commands_as_cvj_sim_run(tmp_path: Path) -> None:
    """launch_clutch with the launch file's driver (driver:=true): the recorder, started by
    the launch file without being told the schedule, learns it from the latched
    /driveline/scene, so the bag's command topics (driver's samples and the coupling node's
    throttle scale) equal `cvj-sim run`'s, record times included; so do the loop topics."""
    out = tmp_path / 'out'
    lines = launch_command_lines({'scene': 'launch_clutch', 'out': str(out), 'driver': 'true',
                                  'duration': str(CLUTCH_DURATION)}, tmp_path)
    from cvj_ros.orchestrate.processes import node_command
    # a venv installed before driver_node existed has no console script for it: run the
    # module as `cvj-sim run` does (node_command)
    lines = [(label, cmd if Path(cmd[0]).exists() else node_command(Path(cmd[0]).name) + cmd[1:])
             for label, cmd in lines]
    procs: dict[str, subprocess.Popen] = {}
    try:
        for label, cmd in lines:
            procs[label] = _start(cmd, tmp_path / f'{label}.log')
        deadline = time.monotonic() + 600
        for label in ('coupling_node', 'cvj-sim'):
            rc = procs[label].wait(timeout=max(1.0, deadline - time.monotonic()))
            assert rc == 0, (label, (tmp_path / f'{label}.log').read_text()[-3000:])
    finally:
        _stop_all(procs)
    ref = tmp_path / 'ref'
    r = subprocess.run([str(BIN / 'cvj-sim'), 'run', 'launch_clutch', '--out', str(ref),
                        '--duration', str(CLUTCH_DURATION), '--composed'],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    spec = importlib.util.spec_from_file_location(
        'e2e_run_composed', REPO / 'test' / 'e2e' / 'test_run_composed.py')
    composed = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(composed)
    got, want = composed.raw_messages(out / 'bag'), composed.raw_messages(ref / 'bag')
    n = int(round(CLUTCH_DURATION / 1e-3))
    assert len(want['/engine/throttle_scale']) == n + 1
    assert len(want['/engine/throttle']) > 300          # the ramp: one sample per step
    for topic in CLUTCH_TOPICS:
        assert got[topic] == want[topic], topic
