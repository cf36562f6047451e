"""Launch the cvj_ros driveline: engine, coupling, load and monitor nodes, and the recorder.

    ros2 launch cvj_ros driveline.launch.py scene:=fwd_halfshaft duration:=5.0
    ros2 launch cvj_ros driveline.launch.py scene:=kavz685_lever mode:=free-run record:=false
    ros2 launch cvj_ros driveline.launch.py external:=load out:=runs/stack   # your stack answers /load/wrench

Arguments (see ``ARGUMENTS``): ``scene`` (name or YAML path), ``mode`` (lockstep |
free-run), ``coupling_scheme`` (zoh | extrapolate | linear_implicit), ``duration`` (s, 0 =
the scene's), ``seed`` (-1 = the scene's), ``external`` (none | load | engine | both: those
peers are NOT started; an outside node must answer, see docs/ros.md), ``record`` (true |
false: ``cvj-sim record OUT`` records every topic to OUT/bag and stops 2 s after the run
goes quiet), ``out``, ``storage`` (mcap | sqlite3), ``monitor`` (true | false),
``nonfinite_torque`` (stop | hold: the coupling node's NaN/inf torque policy),
``run_token`` (auto | none | 8 hex characters: the run identity given to every node and
the recorder, docs/ros.md "Run identity"; auto draws one per launch).

The mapping from launch arguments to node parameters is plain Python
(:func:`node_parameters`), importable without ``launch`` so the test suite checks it
against every node's declared parameters; ``launch``/``launch_ros`` are imported only
inside :func:`generate_launch_description`.
"""
from __future__ import annotations

from typing import Any

PACKAGE = 'cvj_ros'

# argument -> (default, description)
ARGUMENTS: dict[str, tuple[str, str]] = {
    'scene': ('fwd_halfshaft', 'scene name (cvj-sim scenes) or scene YAML path'),
    'mode': ('lockstep', 'loop mode: lockstep | free-run'),
    'coupling_scheme': ('zoh', 'torque coupling at the exchange: zoh | extrapolate | linear_implicit'),
    'duration': ('0.0', 'simulated duration [s]; 0 = the scene duration'),
    'seed': ('-1', 'random seed; -1 = the scene seed'),
    'external': ('none', 'peers an outside node provides instead: none | load | engine | both'),
    'record': ('true', 'record every topic with `cvj-sim record OUT`: true | false'),
    'out': ('runs/launch', 'output directory of the recording (bag in OUT/bag)'),
    'storage': ('mcap', 'bag storage: mcap | sqlite3'),
    'monitor': ('true', 'start monitor_node: true | false'),
    'nonfinite_torque': ('stop', 'a NaN/inf torque answer stops the run (stop) or the last finite '
                                 'torque is held and counted (hold)'),
    'run_token': ('auto', 'run identity in header.frame_id: auto (random per launch) | none | '
                          '8 lowercase hex characters'),
}

CHOICES: dict[str, tuple[str, ...]] = {
    'mode': ('lockstep', 'free-run'),
    'coupling_scheme': ('zoh', 'extrapolate', 'linear_implicit'),
    'external': ('none', 'load', 'engine', 'both'),
    'record': ('true', 'false'),
    'storage': ('mcap', 'sqlite3'),
    'monitor': ('true', 'false'),
    'nonfinite_torque': ('stop', 'hold'),
}

NODE_EXECUTABLES = ('engine_node', 'coupling_node', 'load_node', 'monitor_node')
RECORDER_EXECUTABLE = 'cvj-sim'


def _flag(value: str) -> bool:
    return value.strip().lower() == 'true'


def resolve_run_token(value: str) -> str:
    """The run token for launch argument ``run_token``: 'auto' draws one (8 hex characters
    with at least one of a-d/f, never numeric under --ros-args; cvj_ros.nodes.run_token),
    'none' gives '' (nodes tag nothing), else the value itself if it is 8 lowercase hex
    characters (ValueError naming the argument otherwise)."""
    import re
    import secrets
    value = value.strip()
    if value == 'auto':
        while True:
            token = secrets.token_hex(4)
            if re.search('[a-df]', token):
                return token
    if value == 'none':
        return ''
    if not re.fullmatch('[0-9a-f]{8}', value):
        raise ValueError(f'run_token: must be auto, none or 8 lowercase hex characters, got {value!r}')
    return value


def node_parameters(arguments: dict[str, str]) -> dict[str, dict[str, Any]]:
    """ROS parameters per node to start, from the launch arguments (strings, as launch gives
    them). Nodes an outside peer replaces are absent. Raises ValueError naming a bad argument."""
    args = {k: str(arguments.get(k, default)) for k, (default, _d) in ARGUMENTS.items()}
    for key, choices in CHOICES.items():
        if args[key] not in choices:
            raise ValueError(f'{key}: must be one of {", ".join(choices)}, got {args[key]!r}')
    try:
        duration = float(args['duration'])
        seed = int(args['seed'])
    except ValueError as exc:
        raise ValueError(f'duration/seed: not a number ({exc})') from None
    external = args['external']
    started = ['coupling_node']
    if external not in ('engine', 'both'):
        started.append('engine_node')
    if external not in ('load', 'both'):
        started.append('load_node')
    if _flag(args['monitor']):
        started.append('monitor_node')
    token = resolve_run_token(args['run_token'])
    common: dict[str, Any] = {'scene': args['scene'], 'seed': seed}
    if token:
        common['run_token'] = token
    # subscribers of /driveline/joint_states before step 0: engine + load (ours or outside),
    # monitor, recorder: no message is lost to a late match
    min_subs = 2 + _flag(args['monitor']) + _flag(args['record'])
    params: dict[str, dict[str, Any]] = {
        'coupling_node': dict(common, mode=args['mode'], coupling_scheme=args['coupling_scheme'],
                              duration=duration, min_subscribers=min_subs,
                              nonfinite_torque=args['nonfinite_torque']),
        'engine_node': dict(common),
        'load_node': dict(common),
        'monitor_node': {'scene': args['scene'], **({'run_token': token} if token else {})},
    }
    return {name: params[name] for name in NODE_EXECUTABLES if name in started}


def recorder_arguments(arguments: dict[str, str]) -> list[str] | None:
    """Command-line arguments of ``cvj-sim`` for the recorder, or None when record is false."""
    args = {k: str(arguments.get(k, default)) for k, (default, _d) in ARGUMENTS.items()}
    if not _flag(args['record']):
        return None
    token = resolve_run_token(args['run_token'])
    return (['record', args['out'], '--storage', args['storage'], '--overwrite', '--until-idle', '2.0']
            + (['--run-token', token] if token else []))


def generate_launch_description() -> Any:
    from launch import LaunchDescription
    from launch.actions import DeclareLaunchArgument, OpaqueFunction
    from launch_ros.actions import Node

    def setup(context: Any) -> list[Any]:
        values = {k: context.launch_configurations.get(k, d) for k, (d, _x) in ARGUMENTS.items()}
        values['run_token'] = resolve_run_token(values['run_token']) or 'none'  # one token for all
        actions: list[Any] = []
        rec = recorder_arguments(values)
        if rec is not None:  # first, so it matches every topic before step 0
            actions.append(Node(package=PACKAGE, executable=RECORDER_EXECUTABLE, arguments=rec,
                                output='screen'))
        for name, params in node_parameters(values).items():
            actions.append(Node(package=PACKAGE, executable=name, name=name, parameters=[params],
                                output='screen'))
        return actions

    return LaunchDescription(
        [DeclareLaunchArgument(k, default_value=d, description=x) for k, (d, x) in ARGUMENTS.items()]
        + [OpaqueFunction(function=setup)])
