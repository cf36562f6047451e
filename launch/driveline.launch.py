"""Launch the cvj_ros driveline: engine, coupling, load and monitor nodes, and the recorder.

    ros2 launch cvj_ros driveline.launch.py scene:=fwd_halfshaft duration:=5.0
    ros2 launch cvj_ros driveline.launch.py scene:=kavz685_lever mode:=free-run record:=false
    ros2 launch cvj_ros driveline.launch.py external:=load out:=runs/stack   # your stack answers /load/wrench
    ros2 launch cvj_ros driveline.launch.py scene:=launch_clutch_chain driver:=true   # plays its commands

Arguments (see ``ARGUMENTS``): ``scene`` (name or YAML path), ``mode`` (lockstep |
free-run), ``coupling_scheme`` (zoh | extrapolate | linear_implicit), ``duration`` (s, 0 =
the scene's), ``seed`` (-1 = the scene's), ``external`` (none | load | engine | both: those
peers are NOT started; an outside node must answer, see docs/ros.md), ``record`` (true |
false: ``cvj-sim record OUT`` records every topic to OUT/bag and stops 2 s after the run
goes quiet), ``out``, ``storage`` (mcap | sqlite3), ``monitor`` (true | false), ``driver`` (true | false:
driver_node plays the scene's ``commands:`` schedule, else a stack sends the commands,
docs/ros.md "Commands"),
``nonfinite_torque`` (stop | hold: the coupling node's NaN/inf torque policy),
``catch_up`` (skip | burst) and ``realtime_priority`` (0..99) for free-run (docs/ros.md
"Free-run"). The recorder records the run's publishers only (``cvj-sim record --run-only``,
docs/ros.md "Run identity").

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
    'driver': ('false', 'start driver_node, which plays the scene\'s commands: schedule on '
                        '/engine/throttle, /driveline/clutch, /driveline/gear, /driveline/brake '
                        '(true), or a vehicle stack sends them (false): true | false'),
    'nonfinite_torque': ('stop', 'a NaN/inf torque answer stops the run (stop) or the last finite '
                                 'torque is held and counted (hold)'),
    'catch_up': ('skip', 'free-run: missed ticks are dropped, simulated time jumping to wall time '
                         '(skip) or run back to back, at most burst_max (10) per wake-up (burst)'),
    'realtime_priority': ('0', 'free-run: SCHED_FIFO priority 1..99 of the coupling process '
                               '(needs CAP_SYS_NICE); 0 = normal scheduling'),
}

CHOICES: dict[str, tuple[str, ...]] = {
    'mode': ('lockstep', 'free-run'),
    'coupling_scheme': ('zoh', 'extrapolate', 'linear_implicit'),
    'external': ('none', 'load', 'engine', 'both'),
    'record': ('true', 'false'),
    'storage': ('mcap', 'sqlite3'),
    'monitor': ('true', 'false'),
    'driver': ('true', 'false'),
    'nonfinite_torque': ('stop', 'hold'),
    'catch_up': ('skip', 'burst'),
}

NODE_EXECUTABLES = ('engine_node', 'coupling_node', 'load_node', 'monitor_node', 'driver_node')
RECORDER_EXECUTABLE = 'cvj-sim'


def _flag(value: str) -> bool:
    return value.strip().lower() == 'true'


def node_parameters(arguments: dict[str, str]) -> dict[str, dict[str, Any]]:
    """ROS parameters per node to start, from the launch arguments (strings, as launch gives
    them). Nodes an outside peer replaces are absent. Raises ValueError naming a bad argument
    (an unknown scene too, with the nearest shipped name)."""
    args = {k: str(arguments.get(k, default)) for k, (default, _d) in ARGUMENTS.items()}
    for key, choices in CHOICES.items():
        if args[key] not in choices:
            raise ValueError(f'{key}: must be one of {", ".join(choices)}, got {args[key]!r}')
    # the nodes would each refuse an unknown scene; say it once, before any process starts
    from cvj_ros.physics.scene import find_scene
    find_scene(args['scene'])   # SceneError (a ValueError): 'scene: no scene file ...; did you mean'
    try:
        duration = float(args['duration'])
        seed = int(args['seed'])
    except ValueError as exc:
        raise ValueError(f'duration/seed: not a number ({exc})') from None
    try:
        rt_priority = int(args['realtime_priority'])
    except ValueError:
        rt_priority = -1
    if not 0 <= rt_priority <= 99:
        raise ValueError(f'realtime_priority: must be an integer in 0..99, got {args["realtime_priority"]!r}')
    external = args['external']
    started = ['coupling_node']
    if external not in ('engine', 'both'):
        started.append('engine_node')
    if external not in ('load', 'both'):
        started.append('load_node')
    if _flag(args['monitor']):
        started.append('monitor_node')
    if _flag(args['driver']):
        started.append('driver_node')
    common: dict[str, Any] = {'scene': args['scene'], 'seed': seed}
    # subscribers of /driveline/joint_states before step 0: engine + load (ours or outside),
    # monitor, recorder: no message is lost to a late match
    min_subs = 2 + _flag(args['monitor']) + _flag(args['record'])
    params: dict[str, dict[str, Any]] = {
        'coupling_node': dict(common, mode=args['mode'], coupling_scheme=args['coupling_scheme'],
                              duration=duration, min_subscribers=min_subs,
                              nonfinite_torque=args['nonfinite_torque'],
                              # a scene with modes: wait for the driver's samples or take a stack's
                              commands='driver' if _flag(args['driver']) else 'external',
                              **({'catch_up': args['catch_up'], 'realtime_priority': rt_priority}
                                 if args['mode'] == 'free-run' else {})),
        # with the driver in lockstep: answer the state t_k with the throttle of step k (counted)
        # a shift schedule's throttle scale: counted per step in lockstep (auto), as it comes in free-run
        'engine_node': dict(common, **({'commands': 'driver', 'duration': duration}
                                       if _flag(args['driver']) and args['mode'] == 'lockstep'
                                       else {}),
                            **({'throttle_scale': 'on_arrival'} if args['mode'] == 'free-run' else {})),
        'load_node': dict(common),
        'monitor_node': {'scene': args['scene']},
        'driver_node': dict(common, duration=duration),
    }
    return {name: params[name] for name in NODE_EXECUTABLES if name in started}


def recorder_arguments(arguments: dict[str, str]) -> list[str] | None:
    """Command-line arguments of ``cvj-sim`` for the recorder, or None when record is false."""
    args = {k: str(arguments.get(k, default)) for k, (default, _d) in ARGUMENTS.items()}
    if not _flag(args['record']):
        return None
    return ['record', args['out'], '--storage', args['storage'], '--overwrite', '--until-idle', '2.0',
            '--run-only']


def _param_text(name: str, value: Any) -> str:
    """``name:=value`` for ``-p``, which reads the value as YAML: a string that YAML would read
    as another type (``'123'``, ``'true'``) is quoted."""
    import yaml
    text = str(value).lower() if isinstance(value, bool) else str(value)
    if isinstance(value, str) and not isinstance(yaml.safe_load(value or "''"), str):
        text = "'" + value.replace("'", "''") + "'"
    return f'{name}:={text}'


def equivalent_commands(arguments: dict[str, str]) -> list[list[str]]:
    """The processes ``ros2 launch cvj_ros driveline.launch.py <arguments>`` starts, as command
    lines of the installed executables (recorder first, each node under its name with its
    parameters as ``-p``): what to type into one shell each where launch_ros is missing."""
    lines: list[list[str]] = []
    rec = recorder_arguments(arguments)
    if rec is not None:
        lines.append([RECORDER_EXECUTABLE, *rec])
    for name, params in node_parameters(arguments).items():
        cmd = [name, '--ros-args', '-r', f'__node:={name}']
        for key, value in params.items():
            cmd += ['-p', _param_text(key, value)]
        lines.append(cmd)
    return lines


def main(argv: list[str]) -> int:
    """``python launch/driveline.launch.py [name:=value ...]``: print :func:`equivalent_commands`,
    one shell line per process; a bad argument: one line on stderr, exit 2."""
    import shlex
    import sys
    arguments: dict[str, str] = {}
    for item in argv:
        name, sep, value = item.partition(':=')
        if not sep or name not in ARGUMENTS:
            print(f'driveline.launch.py: error: {item}: expected NAME:=VALUE with NAME one of '
                  f'{", ".join(ARGUMENTS)}', file=sys.stderr)
            return 2
        arguments[name] = value
    try:
        lines = equivalent_commands(arguments)
    except ValueError as exc:
        print(f'driveline.launch.py: error: {exc}', file=sys.stderr)
        return 2
    for cmd in lines:
        print(' '.join(shlex.quote(part) for part in cmd))
    return 0


def generate_launch_description() -> Any:
    from launch import LaunchDescription
    from launch.actions import DeclareLaunchArgument, OpaqueFunction
    from launch_ros.actions import Node

    def setup(context: Any) -> list[Any]:
        values = {k: context.launch_configurations.get(k, d) for k, (d, _x) in ARGUMENTS.items()}
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


if __name__ == '__main__':
    import sys as _sys
    _sys.exit(main(_sys.argv[1:]))
