"""`cvj-sim run SCENE --out DIR`: run a scene as ROS processes (lockstep by default) into a bag."""
from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

NAME = 'run'
# every file of the run (bag, report.json, logs) is closed when run() returns: skip the
# interpreter's teardown of numba/LLVM/rclpy objects (measured 0.5-0.7 s after a run's report
# under load), so Ctrl-C / SIGTERM end the command within 2 s (cli.exit_without_teardown)
EXIT_WITHOUT_TEARDOWN = True
HELP = 'run a scene as ROS 2 node processes and record a rosbag2 bag'
DESCRIPTION = """Start engine_node, load_node, monitor_node and coupling_node (each its own
process) plus a bag recorder on one localhost-only ROS domain (ROS_DOMAIN_ID, or one
picked from the pid when unset), wait for the coupling node to finish, stop the rest,
close the bag and print a report (real-time factor, speeds, nonuniformity, torque
amplitudes, message counts). OUT/bag is the bag, OUT/logs the node outputs,
OUT/report.json the report. Ctrl-C / SIGTERM stop every process and leave a readable bag.

exit status: 0 finished, 1 runtime error (e.g. a peer stopped answering),
             2 bad scene or option (nothing started), 130/143 interrupted.

examples:
  cvj-sim run kavz685_lever --out runs/kavz --duration 2
  cvj-sim run kavz685_lever --out runs/kavz --composed   # all nodes in one process
  cvj-sim run fwd_halfshaft --out runs/fwd --scheme linear_implicit --storage sqlite3
  cvj-sim run fwd_halfshaft --out runs/replay_load --load-from-bag runs/fwd/bag
  cvj-sim run fwd_halfshaft --out runs/stack --external load   # + your stack answering /load/wrench
  cvj-sim run launch_clutch_chain --out runs/launch --external driver   # + your stack sending the commands

On a terminal, stderr shows a progress line (simulated time, real-time factor, ETA) at
most once a second; nothing when stderr is not a terminal.
"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('scene', help='scene name (e.g. kavz685_lever) or scene YAML path')
    parser.add_argument('--out', required=True, type=Path, help='run directory (bag at OUT/bag)')
    parser.add_argument('--duration', type=float, default=None, help='simulated seconds (default: scene)')
    parser.add_argument('--seed', type=int, default=None, help='random seed (default: scene seed)')
    parser.add_argument('--storage', choices=('mcap', 'sqlite3'), default='mcap', help='bag storage (default mcap)')
    parser.add_argument('--mode', choices=('lockstep', 'free-run'), default='lockstep',
                        help='lockstep (deterministic, default) or free-run (wall clock)')
    parser.add_argument('--scheme', choices=('zoh', 'extrapolate', 'linear_implicit'), default='zoh',
                        help='coupling scheme of the exchanged torques (default zoh)')
    parser.add_argument('--exchange-step', type=float, default=None, metavar='S',
                        help='exchange step in s (default: scene)')
    parser.add_argument('--load-from-bag', type=Path, default=None, metavar='BAG',
                        help="use a bag's recorded /load/wrench torque as this run's load")
    parser.add_argument('--peer-timeout', type=float, default=5.0, metavar='S',
                        help='lockstep wait bound for engine/load answers in s (default 5)')
    parser.add_argument('--external', choices=('load', 'engine', 'both', 'driver'), default=None,
                        action='append',
                        help='do not start that peer: an outside node (your vehicle stack) answers '
                             'on /load/wrench (a vehicle scene: /load/<wheel>/wrench for every '
                             'wheel) and/or /engine/wrench instead; driver: it sends the '
                             'commands (/engine/throttle, /driveline/clutch, /driveline/gear, '
                             '/driveline/brake) instead of driver_node; repeatable; recorded as usual')
    parser.add_argument('--external-timeout', type=float, default=30.0, metavar='S',
                        help='longest wait for the outside node to publish, s (default 30)')
    parser.add_argument('--nonfinite-torque', choices=('stop', 'hold'), default='stop',
                        help='a NaN/inf torque answer stops the run (default) or the last finite '
                             'torque is held, counted with a WARN')
    parser.add_argument('--catch-up', choices=('skip', 'burst'), default='skip',
                        help='free-run: ticks missed (late by a whole step) are dropped and simulated '
                             'time jumps to wall time (skip, default), or run back to back up to '
                             '--burst-max per wake-up, then dropped (burst)')
    parser.add_argument('--burst-max', type=int, default=10, metavar='N',
                        help='free-run, --catch-up burst: most ticks run back to back (default 10)')
    parser.add_argument('--rt-priority', type=int, default=0, metavar='P',
                        help='free-run: run the coupling loop thread under SCHED_FIFO priority P '
                             '(1..99; needs CAP_SYS_NICE, else a warning); 0 = normal (default)')
    parser.add_argument('--fail-on', choices=('error', 'warn', 'never'), default='never',
                        help='exit 1 when the monitor recorded an ERROR status, any WARN or ERROR, '
                             'or never (default: the report always lists them; the nonuniformity '
                             'thresholds also fire in start-up transients of sound scenes)')
    parser.add_argument('--composed', action='store_true',
                        help='host every node and the recorder in this one process on one '
                             'EventsExecutor (same nodes, topics and bag; faster, see docs/ros.md)')
    parser.add_argument('--mode-backend', choices=('auto', 'kernel', 'python'), default='auto',
                        help='scenes with clutch, gearbox, brake or commands: the coupling node '
                             'steps the mode model on the compiled kernel (auto, the default, for '
                             'dopri5/dop853; kernel) or the Python reference (python)')
    parser.add_argument('--executor', choices=('auto', 'events', 'single'), default='auto',
                        help='--composed: rclpy executor: events (EventsExecutor, faster; its '
                             'memory grows with every exchange), single (SingleThreadedExecutor, '
                             'flat memory) or auto (default: events up to 1e5 exchanges, else single)')
    parser.add_argument('--no-intra-process', dest='intra_process', action='store_false',
                        help='--composed: hand the loop topics to the hosted nodes through DDS '
                             'too, instead of in-process (slower; for comparison)')
    parser.add_argument('--overwrite', action='store_true', help='replace a previous run in OUT (only the files a run writes)')


def run(args: argparse.Namespace) -> int:
    from cvj_ros.orchestrate import RunOptions, run as run_scene
    from cvj_ros.orchestrate.report import command_started
    result = run_scene(RunOptions(started=command_started(),
        scene=args.scene, out=args.out, duration=args.duration, seed=args.seed, storage=args.storage,
        mode=args.mode, scheme=args.scheme, exchange_step=args.exchange_step,
        load_from_bag=args.load_from_bag, overwrite=args.overwrite, peer_timeout=args.peer_timeout,
        external=tuple(dict.fromkeys(p for e in (args.external or ())
                                     for p in (('engine', 'load') if e == 'both' else (e,)))),
        external_timeout=args.external_timeout, nonfinite_torque=args.nonfinite_torque,
        fail_on=args.fail_on, catch_up=args.catch_up, burst_max=args.burst_max,
        rt_priority=args.rt_priority, composed=args.composed, executor=args.executor,
        intra_process=args.intra_process, mode_backend=args.mode_backend))
    import sys
    for note in degenerate_notes(result):
        print(f'  note: {note}')
    if result.error:
        print(f'cvj-sim: error: {result.error}', file=sys.stderr)
    return result.exit_code


def degenerate_notes(result: Any) -> list[str]:
    """After a run: the exchange step too coarse for the scene's fastest mode, a stall, else a
    speed trend that dominates the window's speed nonuniformity (the report's
    ``speed_trend``) (:mod:`cvj_ros.physics.degenerate`; the joint angle limits are the
    monitor's in a ROS run). Empty when the run recorded nothing to judge."""
    shafts = (result.metrics or {}).get('shafts') or {}
    if not shafts or not result.scene_path:
        return []
    from cvj_ros.physics import degenerate as dg
    from cvj_ros.physics.driveline import Driveline
    from cvj_ros.physics.scene import load_scene
    notes = []
    try:
        scene = load_scene(result.scene_path)
    except Exception:   # noqa: BLE001 (a note, never a failure of the run)
        return []
    try:                # chains; a vehicle tree or a mode scene has no Driveline
        mode = dg.fastest_mode(Driveline.from_scene(scene))
    except Exception:   # noqa: BLE001
        mode = None
    line = dg.coarse_step_line(float(result.exchange_step), mode, 'exchange step') if mode else None
    if line:
        notes.append(line)
    stall = dg.stall_line({n: float(m.get('mean_speed', float('nan'))) for n, m in shafts.items()},
                          float(scene.initial_speed))
    if stall:
        notes.append(stall)
    elif (result.metrics or {}).get('speed_trend'):
        notes.append(result.metrics['speed_trend'])
    return notes
