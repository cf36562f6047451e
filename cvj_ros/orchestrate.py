"""`cvj-sim run`: launch a driveline run as ROS processes and record it to a bag.

Like a launch file: engine_node, load_node, monitor_node and coupling_node each run as
their own process (the console scripts, ``--ros-args -p ...``); the recorder
(:class:`cvj_ros.bag.BagRecorder`) runs inside the ``cvj-sim`` process. Why there: the
bag's lifetime then belongs to the process that handles Ctrl-C/SIGTERM and decides the
shutdown order, so the bag is finalised on every exit path without inter-process
signalling, and the message counts/wall times feed the report directly; the
orchestrator itself only sleeps, so it costs no extra core on a 2-core machine.

Sequence: validate everything (scene, options, load bag) -> create the run directory
``OUT`` (``OUT/bag`` the rosbag2 bag, ``OUT/logs/<node>.log`` the node outputs,
``OUT/report.json``) -> start the recorder (subscribed before any node exists, so the
coupling node sees it matched before step 0) -> start engine, load, monitor, coupling ->
wait for the coupling node to exit -> wait until the recorder is drained -> SIGINT the
other nodes (SIGTERM, then SIGKILL after a grace period) -> close the bag -> report.

Domain: all processes share the caller's ``ROS_DOMAIN_ID``; when it is unset the run
picks ``1 + pid % 100`` (stated in the report) instead of the crowded default 0.
``ROS_AUTOMATIC_DISCOVERY_RANGE`` defaults to ``LOCALHOST``.

Exit status: 0 finished; 1 runtime error (the coupling node's ERROR line is printed, e.g.
a peer that stopped answering); 2 bad scene/option (before any process starts);
130/143 stopped by SIGINT/SIGTERM (bag complete and readable).
"""
from __future__ import annotations

import json
import math
import os
import re
import shutil
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, TextIO

import numpy as np

from cvj_ros import bag as bagmod
from cvj_ros.errors import CvjError

NODE_ORDER = ('engine_node', 'load_node', 'monitor_node', 'coupling_node')  # coupling last
MODES = ('lockstep', 'free-run')
# What a run writes into its directory (all of it is replaced by --overwrite).
RUN_ENTRIES = ('bag', 'logs', 'report.json', 'load_override.npz', 'fastdds_profile.xml')
SCHEMES = ('zoh', 'extrapolate', 'linear_implicit')


@dataclass
class RunOptions:
    """Options of one run (CLI flags of ``cvj-sim run``).

    Attributes:
        scene: scene name or YAML path.
        out: run directory (bag at ``out/bag``).
        duration: simulated seconds (None = scene duration).
        seed: random seed (None = scene seed).
        storage: ``'mcap'`` or ``'sqlite3'``.
        mode: ``'lockstep'`` or ``'free-run'``.
        scheme: coupling scheme ``'zoh' | 'extrapolate' | 'linear_implicit'``.
        exchange_step: s (None = scene exchange step).
        load_from_bag: bag whose /load/wrench torque becomes the load of this run.
        overwrite: replace a previous run in ``out`` (only the files a run writes).
        peer_timeout: s, the coupling node's lockstep wait bound.
        grace: s between SIGINT and SIGTERM (and SIGTERM and SIGKILL) when stopping nodes.
        start_timeout: s to wait for the engine/load nodes to connect before the coupling starts.
        external: peers not started by the run (``'engine'``, ``'load'``): an outside node
            answers on their topic instead (see :data:`EXTERNAL_PEERS`).
        external_timeout: s to wait for the outside peers to publish their topic.
        nonfinite_torque: the coupling node's NaN/inf torque policy, ``'stop'`` or ``'hold'``.
        catch_up: free-run catch-up policy ``'skip'`` or ``'burst'`` (cvj_ros.nodes.freerun).
        burst_max: free-run burst bound (ticks back to back per wake-up, >= 1).
        rt_priority: free-run: SCHED_FIFO priority of the coupling loop thread (0 = off).
    """
    scene: str
    out: Path
    duration: float | None = None
    seed: int | None = None
    storage: str = 'mcap'
    mode: str = 'lockstep'
    scheme: str = 'zoh'
    fail_on: str = 'never'       # exit 1 when the monitor recorded: 'error' | 'warn' | 'never'
    exchange_step: float | None = None
    load_from_bag: Path | None = None
    overwrite: bool = False
    peer_timeout: float = 5.0
    grace: float = 3.0
    start_timeout: float = 20.0
    external: tuple[str, ...] = ()
    external_timeout: float = 30.0
    nonfinite_torque: str = 'stop'
    catch_up: str = 'skip'
    burst_max: int = 10
    rt_priority: int = 0
    composed: bool = False       # every node and the recorder in this process (cvj_ros.composed)
    executor: str = 'events'     # composed mode: 'events' (EventsExecutor) or 'single'


@dataclass
class RunResult:
    """Outcome of a run: exit status, paths, timings (wall s), counts, metrics, error line."""
    exit_code: int
    out: Path
    bag: Path
    scene_path: str
    domain_id: int
    sim_duration: float
    exchange_step: float
    steps_expected: int
    wall_time: float
    loop_wall_time: float | None
    wall_per_step: float | None
    real_time_factor: float | None
    counts: dict[str, int]
    node_exit_codes: dict[str, int | None]
    error: str | None = None
    stopped_by: str | None = None
    metrics: dict[str, Any] = field(default_factory=dict)
    phases: dict[str, float] = field(default_factory=dict)   # wall s since start of each phase end
    external: list[str] = field(default_factory=list)        # peers answered by outside nodes
    settings: dict[str, Any] = field(default_factory=dict)    # seed, mode, scheme, storage, fidelity


@dataclass
class _Prepared:
    options: RunOptions
    scene: Any
    scene_path: Path
    duration: float
    exchange_step: float
    seed: int | None
    load_series: tuple[np.ndarray, np.ndarray] | None
    coupling_topics: list[str]
    nodes: tuple[str, ...]


def prepare(options: RunOptions) -> _Prepared:
    """Validate the scene and every option; raises a CvjError naming the field, starts nothing."""
    from cvj_ros.physics.scene import Joint, find_scene, load_scene
    scene_path = find_scene(options.scene).resolve()
    scene = load_scene(scene_path)
    if options.mode not in MODES:
        raise CvjError(f'--mode: must be one of {", ".join(MODES)}, got {options.mode!r}')
    if options.scheme not in SCHEMES:
        raise CvjError(f'--scheme: must be one of {", ".join(SCHEMES)}, got {options.scheme!r}')
    if options.catch_up not in ('skip', 'burst'):
        raise CvjError(f'--catch-up: must be skip or burst, got {options.catch_up!r}')
    if not 1 <= options.burst_max <= 10**6:
        raise CvjError(f'--burst-max: must be an integer in 1..1000000, got {options.burst_max}')
    if not 0 <= options.rt_priority <= 99:
        raise CvjError(f'--rt-priority: must be an integer in 0..99, got {options.rt_priority}')
    if options.storage not in bagmod.STORAGES:
        raise CvjError(f'--storage: must be one of {", ".join(bagmod.STORAGES)}, got {options.storage!r}')
    duration = scene.duration if options.duration is None else float(options.duration)
    if not (math.isfinite(duration) and duration > 0):
        raise CvjError(f'--duration: must be a finite number > 0, got {options.duration}')
    h = scene.exchange_step if options.exchange_step is None else float(options.exchange_step)
    if not (math.isfinite(h) and h > 0):
        raise CvjError(f'--exchange-step: must be a finite number > 0, got {options.exchange_step}')
    if h > duration:
        raise CvjError(f'--exchange-step: {h} s is longer than the duration {duration} s')
    unknown = [e for e in options.external if e not in EXTERNAL_PEERS]
    if unknown:
        raise CvjError(f'--external: must be {", ".join(EXTERNAL_PEERS)} or both, got {unknown[0]!r}')
    if options.load_from_bag is not None and 'load' in options.external:
        raise CvjError('--load-from-bag: cannot be combined with --external load (no load_node '
                       'is started to play the recorded load)')
    if not options.external_timeout > 0:
        raise CvjError(f'--external-timeout: must be > 0, got {options.external_timeout}')
    if options.nonfinite_torque not in ('stop', 'hold'):
        raise CvjError(f'--nonfinite-torque: must be stop or hold, got {options.nonfinite_torque!r}')
    if options.seed is not None and not 0 <= options.seed < 2**31:
        raise CvjError(f'--seed: must be in 0..2**31-1, got {options.seed}')
    if not options.peer_timeout > 0:
        raise CvjError(f'peer_timeout: must be > 0, got {options.peer_timeout}')
    out = Path(options.out)
    if out.exists() and not out.is_dir():
        raise CvjError(f'--out: {out} is not a directory')
    previous = [e for e in RUN_ENTRIES if (out / e).exists()]
    if previous and not options.overwrite:
        raise CvjError(f'--out: {out} holds a previous run ({", ".join(previous)}; use --overwrite)')
    load_series = None
    if options.load_from_bag is not None:
        try:
            load_series = bagmod.load_torque_series(options.load_from_bag)
        except CvjError as exc:
            raise CvjError(f'--load-from-bag: {exc}') from None
        if load_series[0].size < 2:
            raise CvjError(f'--load-from-bag: {options.load_from_bag}: needs >= 2 /load/wrench samples')
    joints = [el.name for el in scene.driveline if isinstance(el, Joint)]
    import importlib.util
    outside = {EXTERNAL_PEERS[e][0] for e in options.external}
    nodes = tuple(n for n in NODE_ORDER if n not in outside
                  and importlib.util.find_spec(f'cvj_ros.nodes.{n}') is not None)
    for required in ('engine_node', 'load_node', 'coupling_node'):
        if required in outside:
            continue
        if required not in nodes:
            raise CvjError(f'{required}: module cvj_ros.nodes.{required} is not installed')
    return _Prepared(options, scene, scene_path, duration, h, options.seed, load_series,
                     [f'/coupling/{j}/wrench' for j in joints], nodes)


def _domain_env() -> tuple[dict[str, str], int]:
    from cvj_ros.nodes.qos import dds_environment
    # localhost discovery, Fast DDS, synchronous publication (cvj_ros.nodes.qos.dds_environment)
    env = dds_environment(dict(os.environ))
    if not env.get('ROS_DOMAIN_ID'):
        env['ROS_DOMAIN_ID'] = str(1 + os.getpid() % 100)
    try:
        domain = int(env['ROS_DOMAIN_ID'])
    except ValueError:
        raise CvjError(f'ROS_DOMAIN_ID: must be an integer, got {env["ROS_DOMAIN_ID"]!r}') from None
    return env, domain


def node_command(name: str) -> list[str]:
    """How to start node ``name``: the console script next to this Python, else on PATH,
    else ``python -c 'from cvj_ros.nodes.<name> import main; main()'``. Every node flushes
    its publishers before it exits (cvj_ros.nodes.common.flush_publishers)."""
    exe = Path(sys.executable).with_name(name)
    if exe.exists():
        return [str(exe)]
    found = shutil.which(name)
    if found:
        return [found]
    return [sys.executable, '-c', f'from cvj_ros.nodes.{name} import main; main()']


def node_parameters(prep: _Prepared, name: str, *, load_override: Path | None,
                    run_token: str = '') -> dict[str, Any]:
    """ROS parameters given to node ``name`` (see docs/ros.md and each node's PARAMS);
    ``run_token``: the run's identity (cvj_ros.nodes.run_token), '' = none."""
    o = prep.options
    params: dict[str, Any] = {'scene': str(prep.scene_path)}
    if run_token:
        params['run_token'] = run_token
    if prep.seed is not None:
        params['seed'] = int(prep.seed)
    if name == 'coupling_node':
        params.update(mode=o.mode, coupling_scheme=o.scheme, exchange_step=float(prep.exchange_step),
                      duration=float(prep.duration), peer_timeout=float(o.peer_timeout),
                      nonfinite_torque=o.nonfinite_torque,
                      **({'catch_up': o.catch_up, 'burst_max': int(o.burst_max),
                          'realtime_priority': int(o.rt_priority)} if o.mode == 'free-run' else {}),
                      # engine, load, the recorder (and monitor) see /driveline/joint_states before step 0
                      min_subscribers=3 + ('monitor_node' in prep.nodes))
    if load_override is not None and name in ('coupling_node', 'load_node'):
        params['load_override'] = str(load_override)
    return params


def _ros_args(params: dict[str, Any]) -> list[str]:
    args = ['--ros-args']
    for k, v in params.items():
        if isinstance(v, bool):
            v = str(v).lower()
        elif isinstance(v, float):
            v = repr(v)
        args += ['-p', f'{k}:={v}']
    return args


try:  # loaded in the parent: the child between fork and exec must not import anything
    import ctypes
    _LIBC: Any = ctypes.CDLL('libc.so.6', use_errno=True)
except OSError:  # not glibc Linux
    _LIBC = None


def _die_with_parent() -> None:
    """In the child: get SIGTERM if cvj-sim dies (Linux PR_SET_PDEATHSIG = 1), so no node is orphaned."""
    if _LIBC is not None:
        _LIBC.prctl(1, int(signal.SIGTERM))


class _Recorder:
    """BagRecorder on its own rclpy context, taking messages in a background thread of this process."""

    def __init__(self, writer: bagmod.BagWriter, topics: Sequence[str], domain_id: int, *,
                 hold: Sequence[str] = (), run_token: str = '') -> None:
        import rclpy
        from rclpy.signals import SignalHandlerOptions
        self.ctx = rclpy.context.Context()
        rclpy.init(context=self.ctx, domain_id=domain_id,
                   signal_handler_options=SignalHandlerOptions.NO)
        self.node = rclpy.create_node('cvj_recorder', context=self.ctx)
        self.recorder = bagmod.BagRecorder(self.node, writer, topics=topics, run_token=run_token)
        self.recorder.hold = frozenset(hold)     # before the first message can arrive
        self._stop = threading.Event()
        self.thread = threading.Thread(target=self._spin, name='recorder', daemon=True)
        self.thread.start()

    def _spin(self) -> None:
        # BagRecorder.spin takes every queued sample per wake. Executors were measured too slow
        # or lossy here: SingleThreadedExecutor fell ~0.7 s behind a 200-step run, and
        # rclpy.experimental.EventsExecutor left samples unread (24 of 101 joint states).
        self.recorder.spin(self._stop)

    def publisher_count(self, topic: str) -> int:
        """Publishers matched by the recorder's subscription of ``topic``."""
        sub = self.recorder._subs.get(topic)
        return 0 if sub is None else sub.get_publisher_count()

    def drain(self, *, expected: dict[str, int], idle: float, bound: float) -> None:
        """Wait until ``expected`` counts are reached, or no message for ``idle`` s; at most ``bound`` s."""
        deadline = time.monotonic() + bound
        start = time.monotonic()
        while time.monotonic() < deadline:
            counts = self.recorder.counts
            if expected and all(counts.get(t, 0) >= n for t, n in expected.items()):
                return
            last = max(self.recorder.last_message_wall, start)
            if time.monotonic() - last > idle:
                return
            time.sleep(0.02)

    def close(self) -> None:
        import rclpy
        self._stop.set()
        self.thread.join(2.0)
        try:
            self.recorder.destroy()
            self.node.destroy_node()
        finally:
            if self.ctx.ok():
                rclpy.shutdown(context=self.ctx)


def _stop_processes(procs: dict[str, subprocess.Popen[bytes]], names: Sequence[str], grace: float) -> None:
    """SIGINT ``names``; after ``grace`` s SIGTERM the survivors; after another ``grace`` SIGKILL."""
    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGKILL):
        alive = [n for n in names if procs[n].poll() is None]
        if not alive:
            return
        for n in alive:
            try:
                procs[n].send_signal(sig)
            except ProcessLookupError:
                pass
        deadline = time.monotonic() + grace
        while time.monotonic() < deadline and any(procs[n].poll() is None for n in alive):
            time.sleep(0.02)
    for n in names:
        procs[n].wait()


_LOG_LEVEL = re.compile(r'\[(ERROR|FATAL)\]')


def error_line(log_path: Path) -> str | None:
    """The last ERROR/FATAL line (rclpy logging) or ``<prog>: error:`` line of a node log."""
    try:
        lines = log_path.read_text(errors='replace').splitlines()
    except OSError:
        return None
    for line in reversed(lines):
        if _LOG_LEVEL.search(line) or ': error:' in line:
            return line.strip()
    rest = [line.strip() for line in lines if line.strip()]
    return rest[-1] if rest else None  # e.g. the last line of a traceback


PEER_TOPICS = {'engine_node': '/engine/wrench', 'load_node': '/load/wrench'}
# How long "our peers are up, nobody else is" must hold before a lockstep loop starts (s).
# The recorder's participant exists from before the peers were started (>= ~1 s of process
# start), so another run's endpoints have usually been discovered already; this covers a
# slow discovery under load at the cost of 0.3 s per run.
DISCOVERY_SETTLE_S = 0.3
LOOP_TOPICS = (bagmod.JOINT_STATES_TOPIC, bagmod.CLOCK_TOPIC, bagmod.SCENE_TOPIC,
               '/engine/wrench', '/load/wrench')
# --external NAME: (the node it replaces, what the outside node must publish)
EXTERNAL_PEERS = {
    'engine': ('engine_node', 'the engine torque on the first shaft, torque.z in N m (driving '
                              'positive)'),
    'load': ('load_node', 'the resisting torque on the last shaft, torque.z in N m (positive '
                          'opposes positive rotation)'),
}


def external_wait_line(external: Sequence[str], domain: int, timeout: float) -> str:
    """The one line printed while a run waits for outside peers: which topic, what to publish."""
    parts = [f'{PEER_TOPICS[EXTERNAL_PEERS[e][0]]} ({EXTERNAL_PEERS[e][1]})' for e in external]
    return (f'cvj-sim run: waiting up to {timeout:g} s for an outside node on ROS_DOMAIN_ID={domain} '
            f'to publish {" and ".join(parts)}: subscribe to /driveline/joint_states and answer '
            f'every message with a geometry_msgs/WrenchStamped whose header (stamp, frame_id) '
            f'echoes the joint state\'s (docs/ros.md, "Outside nodes")')


def _signal_name(signum: int) -> str:
    try:
        return signal.Signals(signum).name
    except ValueError:
        return f'signal {signum}'


def _wait_for_peers(recorder: _Recorder, procs: dict[str, subprocess.Popen[bytes]], logs: Path,
                    stop_signal: list[int], timeout: float, *, lockstep: bool = True,
                    domain: int | None = None, external: Sequence[str] = (),
                    external_timeout: float = 30.0) -> str | None:
    """Wait until the recorder matched engine/load publishers; an error line if a peer died or
    ``timeout`` (s; ``external_timeout`` for outside peers) passed, else None."""
    t0 = time.monotonic()
    deadline = t0 + timeout
    outside = {EXTERNAL_PEERS[e][0]: e for e in external}
    settled_since: float | None = None
    dom = domain if domain is not None else os.environ.get('ROS_DOMAIN_ID', '0')
    while not stop_signal:
        # another run on this domain: stop before our coupling node publishes a single state
        # into the other run's bag (its own watchdog can take 0.25 s and more under load).
        # Our coupling node is not started yet, so any joint-state publisher is another run's;
        # engine/load counts alone cannot tell: the other run's peers, discovered before ours
        # start, made a count of 1 look like "our peer is up" (measured: the second run then
        # started and mixed into the first one's bag).
        n_js = recorder.publisher_count(bagmod.JOINT_STATES_TOPIC)
        extra = ([f'{bagmod.JOINT_STATES_TOPIC} has {n_js} publishers'] if n_js > 0 else []) + \
            [f'{topic} has {n} publishers' for topic in PEER_TOPICS.values()
             if (n := recorder.publisher_count(topic)) > 1]
        if extra and lockstep:
            return (f'lockstep: {", ".join(extra)} (expected {0 if n_js else 1}) on ROS_DOMAIN_ID='
                    f'{dom} before the loop started: another run or '
                    'node shares this domain; give each run its own ROS_DOMAIN_ID')
        missing = [n for n, topic in PEER_TOPICS.items() if recorder.publisher_count(topic) < 1]
        if not missing:
            # hold the all-clear for DISCOVERY_SETTLE_S: endpoints of another run on the
            # domain may still be arriving
            now = time.monotonic()
            settled_since = now if settled_since is None else settled_since
            if not lockstep or now - settled_since >= DISCOVERY_SETTLE_S:
                return None
            time.sleep(0.02)
            continue
        settled_since = None
        for name in missing:
            rc = procs[name].poll() if name in procs else None
            if rc is not None:
                return f'{name}: ' + (error_line(logs / f'{name}.log') or f'exited with status {rc}')
        now = time.monotonic()
        for name in missing:
            if name in outside and now > t0 + external_timeout:
                return (f'--external {outside[name]}: no outside node published {PEER_TOPICS[name]} '
                        f'on ROS_DOMAIN_ID={domain} within --external-timeout={external_timeout:g} s; '
                        f'start it on that domain (e.g. ROS_DOMAIN_ID={domain} python3 '
                        f'examples/vehicle_stack.py --ros-args -p use_sim_time:=true)')
        if now > deadline and any(name not in outside for name in missing):
            name = next(n for n in missing if n not in outside)
            return f'{name}: {PEER_TOPICS[name]} not connected within {timeout:g} s'
        time.sleep(0.02)
    return None


def run(options: RunOptions, *, stream: TextIO | None = None,
        on_started: Callable[[dict[str, subprocess.Popen[bytes]]], None] | None = None) -> RunResult:
    """Run a scene as ROS processes, record the bag, print the report to ``stream``.

    Args:
        options: the run options.
        stream: where the report goes (default stdout).
        on_started: called with the node processes once all are started (tests use it to
            kill a peer).

    Returns:
        The :class:`RunResult` (also written to ``out/report.json``).

    Raises:
        CvjError: bad scene or option, before any process starts.
    """
    if options.composed:   # one process, one executor: cvj_ros.composed
        from cvj_ros.composed import run_composed
        return run_composed(options, stream=stream)
    stream = sys.stdout if stream is None else stream
    prep = prepare(options)
    env, domain = _domain_env()
    out = Path(options.out)
    for entry in RUN_ENTRIES:  # --overwrite removes the previous run's files, nothing else
        path = out / entry
        if path.is_dir():
            shutil.rmtree(path)
        elif path.exists():
            path.unlink()
    logs = out / 'logs'
    logs.mkdir(parents=True, exist_ok=True)
    env['ROS_LOG_DIR'] = str(logs / 'ros')
    from cvj_ros.nodes.qos import dds_environment
    dds_environment(env, profile_dir=str(out))   # writes out/fastdds_profile.xml unless the user set one
    load_override = None
    if prep.load_series is not None:
        load_override = out / 'load_override.npz'
        np.savez(load_override, t=prep.load_series[0], torque=prep.load_series[1])

    stop_signal: list[int] = []
    previous = {}

    def on_signal(signum: int, _frame: Any) -> None:
        stop_signal.append(signum)
    in_main = threading.current_thread() is threading.main_thread()
    if in_main:
        for sig in (signal.SIGINT, signal.SIGTERM):
            previous[sig] = signal.signal(sig, on_signal)

    wall0 = time.monotonic()
    phases: dict[str, float] = {}

    def mark(name: str) -> None:
        phases[name] = round(time.monotonic() - wall0, 4)
    writer = bagmod.BagWriter(out / 'bag', storage=options.storage)
    # run identity: every node and the recorder drop messages tagged with another token
    from cvj_ros.nodes.run_token import new_run_token
    run_token = new_run_token()
    writer.set_custom_data('cvj_ros.run_token', run_token)
    for key, value in (('cvj_ros.scene_path', str(prep.scene_path)), ('cvj_ros.mode', options.mode),
                       ('cvj_ros.coupling_scheme', options.scheme),
                       ('cvj_ros.seed', '' if prep.seed is None else str(prep.seed)),
                       ('cvj_ros.duration', repr(prep.duration)),
                       ('cvj_ros.exchange_step', repr(prep.exchange_step)),
                       ('cvj_ros.external', ','.join(options.external))):
        writer.set_custom_data(key, value)
    procs: dict[str, subprocess.Popen[bytes]] = {}
    log_files: list[Any] = []
    recorder: _Recorder | None = None
    error: str | None = None
    stopped_by: str | None = None
    steps = int(round(prep.duration / prep.exchange_step))
    from cvj_ros.progress import Progress
    # simulated time, real-time factor, ETA on stderr at most once a second, only on a terminal
    progress = Progress(prep.duration, label='cvj-sim run')
    try:
        # lockstep: nothing of ours flows on the loop topics before our coupling node starts
        recorder = _Recorder(writer, prep.coupling_topics, domain,
                             hold=(tuple(LOOP_TOPICS) + tuple(prep.coupling_topics))
                             if options.mode == 'lockstep' else (), run_token=run_token)
        for name in prep.nodes:
            if stop_signal or error is not None:
                break
            if name == 'coupling_node':
                # volatile topics lose what is published before a match: the coupling node (which
                # makes the peers talk) starts only once the recorder sees the peers' publishers
                if options.external:
                    progress.clear()
                    print(external_wait_line(options.external, domain, options.external_timeout),
                          file=stream, flush=True)
                error = _wait_for_peers(recorder, procs, logs, stop_signal, options.start_timeout,
                                        lockstep=options.mode == 'lockstep', domain=domain,
                                        external=options.external,
                                        external_timeout=options.external_timeout)
                mark('peers_connected')
                if error is not None or stop_signal:
                    break
                recorder.recorder.hold = frozenset()
            params = node_parameters(prep, name, load_override=load_override, run_token=run_token)
            fh = open(logs / f'{name}.log', 'wb')
            log_files.append(fh)
            procs[name] = subprocess.Popen(
                node_command(name) + _ros_args(params), stdout=fh, stderr=subprocess.STDOUT,
                stdin=subprocess.DEVNULL, env=env, start_new_session=True, preexec_fn=_die_with_parent)
        if on_started is not None and not stop_signal:
            on_started(procs)
        coupling = procs.get('coupling_node')
        while coupling is not None and coupling.poll() is None and not stop_signal:
            for name, p in procs.items():  # a peer rejected its parameters: no point waiting
                if name != 'coupling_node' and p.poll() == 2 and error is None:
                    error = f'{name}: ' + (error_line(logs / f'{name}.log') or 'bad parameter (exit 2)')
            if error is not None:
                break
            states = recorder.recorder.counts.get(bagmod.JOINT_STATES_TOPIC, 0)
            if 'loop_started' not in phases and states:
                mark('loop_started')
                print(f'cvj-sim run: loop running (domain {domain}), recording to {out / "bag"}',
                      file=stream, flush=True)
            if states:
                progress.update((states - 1) * prep.exchange_step)
            time.sleep(0.02)
        progress.close()
        mark('coupling_exited')
        if recorder is not None:
            recorder.recorder.loop_ended = True   # later /clock beyond our last state: not ours
        if stop_signal or error is not None:
            stopped_by = {signal.SIGINT: 'SIGINT', signal.SIGTERM: 'SIGTERM'}.get(
                stop_signal[0], str(stop_signal[0])) if stop_signal else None
            if 'coupling_node' in procs:
                _stop_processes(procs, ['coupling_node'], options.grace)
            recorder.drain(expected={}, idle=0.3, bound=2.0)
        else:
            rc = procs['coupling_node'].returncode
            lockstep_ok = rc == 0 and options.mode == 'lockstep'
            # lockstep: N+1 states and clocks are in flight when the coupling node exits
            recorder.drain(expected={t: steps + 1 for t in (bagmod.CLOCK_TOPIC, bagmod.JOINT_STATES_TOPIC)}
                           if lockstep_ok else {}, idle=2.0 if lockstep_ok else 0.5, bound=5.0)
            # the peers answer the final state too (no one waits for those answers)
            recorder.drain(expected={t: steps + 1 for t in PEER_TOPICS.values()} if lockstep_ok else {},
                           idle=0.5, bound=2.0)
            if rc is not None and rc < 0:  # killed by a signal: its log holds no error line
                error = f'coupling_node: killed by {_signal_name(-rc)} (exit status {rc})'
            elif rc != 0:
                line = error_line(logs / 'coupling_node.log')
                error = f'coupling_node: {line}' if line else f'coupling_node: exited with status {rc}'
        mark('drained')
        _stop_processes(procs, [n for n in procs if n != 'coupling_node'] + ['coupling_node']
                        if 'coupling_node' in procs else list(procs), options.grace)
    finally:
        progress.close()   # erase the progress line (idempotent) before any other output
        # the bag is finalised on every path (errors, signals): everything recorded stays readable
        try:
            if procs:
                _stop_processes(procs, list(procs), options.grace)
        finally:
            rec_state = None
            foreign_dropped: dict[str, int] = {}
            if recorder is not None:
                rec_state = (dict(recorder.recorder.first_wall), dict(recorder.recorder.last_wall))
                foreign_dropped = dict(recorder.recorder.foreign)
                recorder.close()
            writer.close()
            for fh in log_files:
                fh.close()
            if in_main:
                for sig, handler in previous.items():
                    signal.signal(sig, handler)
    mark('bag_closed')
    wall = time.monotonic() - wall0
    counts = dict(writer.counts)
    js = bagmod.JOINT_STATES_TOPIC
    loop_wall = wall_per_step = None
    if rec_state and js in rec_state[0] and counts.get(js, 0) > 1:
        loop_wall = rec_state[1][js] - rec_state[0][js]
        wall_per_step = loop_wall / (counts[js] - 1)
    sim_done = (counts.get(js, 1) - 1) * prep.exchange_step if counts.get(js) else 0.0
    rtf = sim_done / loop_wall if loop_wall else None
    if stop_signal:
        code = 130 if stop_signal[0] == signal.SIGINT else 128 + int(stop_signal[0])
    elif error is not None:
        code = 1
    else:
        code = 0
    result = RunResult(
        exit_code=code, out=out, bag=out / 'bag', scene_path=str(prep.scene_path), domain_id=domain,
        sim_duration=sim_done, exchange_step=prep.exchange_step, steps_expected=steps,
        wall_time=wall, loop_wall_time=loop_wall, wall_per_step=wall_per_step, real_time_factor=rtf,
        counts=counts, node_exit_codes={n: p.returncode for n, p in procs.items()}, error=error,
        stopped_by=stopped_by, phases=phases, external=list(options.external))
    return finish_result(result, options, prep, stream=stream, run_token=run_token,
                         foreign_dropped=foreign_dropped)


def finish_result(result: RunResult, options: RunOptions, prep: _Prepared, *, stream: TextIO,
                  run_token: str, foreign_dropped: dict[str, int],
                  settings: dict[str, Any] | None = None) -> RunResult:
    """The tail of every run (separate processes or composed): metrics read back from the bag,
    loop counters, run identity, free-run timing, monitor statuses, settings, --fail-on,
    report.json and the printed report."""
    loop_wall = result.loop_wall_time
    try:
        result.metrics = bag_metrics(result.bag)
    except CvjError as exc:
        result.metrics = {'error': str(exc)}
    try:
        counters = loop_counters(result.bag)
    except CvjError:
        counters = {}
    if counters:
        result.metrics['loop_counters'] = counters
    # messages of another run on this domain that the recorder dropped (cvj_ros.nodes.run_token)
    result.metrics['run_identity'] = {'run_token': run_token, 'foreign_dropped': foreign_dropped}
    if options.mode == 'free-run':
        try:
            timing = free_run_timing(result.bag)
        except CvjError:
            timing = {}
        if timing:
            result.metrics['free_run'] = timing
            # skipped ticks advance simulated time without a joint state: the simulated
            # span is ticks handled x h, not (joint states - 1) x h
            if timing.get('ticks_handled'):
                result.sim_duration = timing['ticks_handled'] * prep.exchange_step
                if loop_wall:
                    result.real_time_factor = result.sim_duration / loop_wall
    try:
        result.metrics['monitor'] = monitor_statuses(result.bag)
    except CvjError:
        pass
    result.settings = {'seed': prep.seed if prep.seed is not None else prep.scene.seed,
                       'mode': options.mode, 'scheme': options.scheme,
                       'storage': options.storage, **(settings or {})}
    fid = _recorded_fidelity(result.bag)
    if fid:
        result.settings['fidelity'] = fid
    mon = result.metrics.get('monitor', {})
    if result.exit_code == 0 and (
            (options.fail_on == 'error' and mon.get('error')) or
            (options.fail_on == 'warn' and (mon.get('error') or mon.get('warn')))):
        result.exit_code = 1
        result.error = (f'monitor: {mon.get("error", 0)} ERROR and {mon.get("warn", 0)} WARN '
                        f'statuses (--fail-on {options.fail_on}); worst: {mon.get("worst")}')
    (result.out / 'report.json').write_text(json.dumps(_jsonable(asdict(result)), indent=2))
    print_report(result, stream)
    return result


def _recorded_fidelity(bag: Path) -> str | None:
    """'joint=level ...' from the recorded /driveline/scene message, if any."""
    try:
        from cvj_ros.analysis import _scene_summary
        msgs = bagmod.read_bag(bag, [bagmod.SCENE_TOPIC]).get(bagmod.SCENE_TOPIC)
        text = msgs.data[0] if msgs is not None and getattr(msgs, 'data', None) else None
    except (CvjError, AttributeError, IndexError):
        return None
    return _scene_summary(text).get('fidelity') if text else None


def _jsonable(value: Any) -> Any:
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, Path):
        return str(value)
    if isinstance(value, (np.floating, np.integer)):
        return value.item()
    return value


def bag_metrics(bag: Path, *, transient: float | None = None) -> dict[str, Any]:
    """Key metrics of a run bag over its steady window (:mod:`cvj_ros.physics.steady`, the
    definition ``simulate`` and ``analyze`` share: found by its criterion, or starting
    ``transient`` s after the first sample when given).

    ``window_s``: [start, end] (s); ``window``: the window's evidence
    (:meth:`SteadyWindow.to_dict`) and ``window_text`` its one-line description;
    ``shafts``: per JointState name ``mean_speed`` (rad/s), ``delta`` = speed nonuniformity
    (w_max - w_min)/w_mean (-, seed 004), ``speed_amplitude`` (rad/s),
    ``acceleration_amplitude`` (rad/s^2), ``mean_torque`` and ``torque_amplitude`` =
    (max - min)/2 (N m, seed 004 section 3.3.2) of the shaft torque; ``wrenches``: per
    WrenchStamped topic ``mean_torque`` and ``torque_amplitude`` of torque.z (N m) over the
    same time window.
    """
    from cvj_ros.physics import metrics
    data = bagmod.read_bag(bag, None)
    out: dict[str, Any] = {'shafts': {}, 'wrenches': {}}
    js = data.get(bagmod.JOINT_STATES_TOPIC)
    if js is None or js.t.size < 3:
        return out
    win = metrics.steady_window(js.t, js.names, js.velocity, js.effort, transient=transient)
    mask = win.mask(js.t)
    out['window_s'] = [float(js.t[mask][0]), float(js.t[mask][-1])]
    out['window'] = win.to_dict()
    out['window_text'] = win.describe()
    out['shafts'] = metrics.shaft_metrics(js.t, js.names, js.velocity, js.effort, window=win)
    for topic, series in data.items():
        if isinstance(series, bagmod.WrenchSeries) and series.t.size >= 3:
            m = (series.t >= out['window_s'][0]) & (series.t <= out['window_s'][1])
            if np.count_nonzero(m) < 2:
                continue
            tz = series.torque_z[m]
            out['wrenches'][topic] = {'mean_torque': float(np.mean(tz)),
                                      'torque_amplitude': metrics.amplitude(tz)}
    return out


LOOP_COUNTERS = ('ignored_stamps', 'rejected_torques', 'held_torques')
# run identity (cvj_ros.nodes.run_token): answers of another run / without a token
IDENTITY_COUNTERS = ('foreign_answers', 'untokened_answers')


def loop_counters(bag: Path) -> dict[str, int]:
    """The coupling node's last recorded counters (``/diagnostics`` status ``coupling_node:
    loop``): ignored stamps, rejected and held (``nonfinite_torque=hold``) torques."""
    diags = bagmod.read_bag(bag, ['/diagnostics']).get('/diagnostics')
    if diags is None:
        return {}
    for statuses in reversed(diags.statuses):
        for st in statuses:
            if st['name'] == 'coupling_node: loop':
                return {k: int(float(st['values'][k])) for k in LOOP_COUNTERS + IDENTITY_COUNTERS
                        if k in st['values']}
    return {}


FREE_RUN_KEYS = ('catch_up', 'ticks_handled', 'ticks_run', 'ticks_skipped', 'overruns',
                 'lateness_us_p50', 'lateness_us_p99', 'lateness_us_max', 'lateness_us_mean',
                 'drift_s', 'drift_max_s', 'realtime_priority')


def free_run_timing(bag: Path) -> dict[str, Any]:
    """Free-run deadline figures of the coupling node's last recorded loop diagnostics:
    catch-up policy, ticks run/skipped, overruns (ticks late by >= one exchange step),
    lateness p50/p99/max/mean (us), drift (s; wall time since start - simulated time at the
    last publication, and its largest magnitude); empty when not recorded."""
    diags = bagmod.read_bag(bag, ['/diagnostics']).get('/diagnostics')
    if diags is None:
        return {}
    for statuses in reversed(diags.statuses):
        for st in statuses:
            if st['name'] == 'coupling_node: loop' and 'overruns' in st['values']:
                vals = st['values']
                return {k: (vals[k] if k == 'catch_up' else
                            int(float(vals[k])) if k.startswith(('ticks', 'overruns', 'realtime'))
                            else float(vals[k]))
                        for k in FREE_RUN_KEYS if k in vals}
    return {}


def monitor_statuses(bag: Path) -> dict[str, Any]:
    """WARN and ERROR statuses recorded on /diagnostics (every node but the coupling loop's
    counters, reported on their own): counts, the first of each level and the first of the
    worst level seen, each as 't = T s NAME: MESSAGE'."""
    diags = bagmod.read_bag(bag, ['/diagnostics']).get('/diagnostics')
    out: dict[str, Any] = {'warn': 0, 'error': 0}
    if diags is None:
        return out
    for t, statuses in zip(diags.t, diags.statuses):
        for st in statuses:
            level = int(st['level'])
            if st['name'] == 'coupling_node: loop' or level not in (1, 2):
                continue
            key = 'warn' if level == 1 else 'error'
            out[key] += 1
            out.setdefault(f'first_{key}', f't = {float(t):.6g} s {st["name"]}: '
                                           f'{st["message"] or st["values"]}')
    worst = 'error' if out['error'] else ('warn' if out['warn'] else None)
    if worst:
        out['worst'] = f'{worst.upper()} ' + out[f'first_{worst}']
    return out


def print_report(r: RunResult, stream: TextIO) -> None:
    """The short human report of a run."""
    p = lambda s='': print(s, file=stream)  # noqa: E731
    status = 'finished' if r.exit_code == 0 else (f'stopped by {r.stopped_by}' if r.stopped_by else 'FAILED')
    p(f'cvj-sim run: {status}  scene={r.scene_path}  domain={r.domain_id}'
      + (f'  external={",".join(r.external)}' if r.external else ''))
    if r.error:
        p(f'  error: {r.error}')
    p(f'  simulated {r.sim_duration:.6g} s in {max(0, r.counts.get(bagmod.JOINT_STATES_TOPIC, 0) - 1)} exchange steps '
      f'of {r.exchange_step:.6g} s (expected {r.steps_expected})')
    rtf = f'{r.real_time_factor:.3g}' if r.real_time_factor else 'n/a'
    per = f'{r.wall_per_step * 1e6:.0f} us' if r.wall_per_step else 'n/a'
    loop = f'{r.loop_wall_time:.3f} s' if r.loop_wall_time is not None else 'n/a'
    p(f'  wall time {r.wall_time:.2f} s (loop {loop}), real-time factor {rtf}, wall per exchange step {per}')
    shafts = r.metrics.get('shafts', {})
    if shafts:
        p(f'  steady window {r.metrics.get("window_text", "")}:')
        if 'window' in r.metrics:
            p(f'    ({r.metrics["window"]["criterion"]})')
        p(f'    {"shaft":24s} {"mean speed rad/s":>16s} {"nonuniformity":>14s} {"torque ampl N m":>16s}')
        for name, m in shafts.items():
            p(f'    {name:24s} {m["mean_speed"]:16.4f} {m["delta"]:14.3e} {m["torque_amplitude"]:16.4f}')
    for topic, m in r.metrics.get('wrenches', {}).items():
        p(f'    {topic:24s} mean torque {m["mean_torque"]:.4f} N m, amplitude {m["torque_amplitude"]:.4f} N m')
    if 'error' in r.metrics:
        p(f'  metrics: {r.metrics["error"]}')
    identity = r.metrics.get('run_identity', {})
    foreign = r.metrics.get('loop_counters', {}).get('foreign_answers', 0)
    dropped = sum(identity.get('foreign_dropped', {}).values())
    if foreign or dropped:
        p(f'  another run on this domain: the loop ignored {foreign} of its answers, the recorder '
          f'dropped {dropped} of its messages (this run token {identity.get("run_token")})')
    counters = {k: v for k, v in r.metrics.get('loop_counters', {}).items() if k in LOOP_COUNTERS}
    if any(counters.values()):   # WARN level in /diagnostics: say it in the report too
        p('  WARN coupling loop: ' + ', '.join(f'{k.replace("_", " ")} {v}' for k, v in counters.items())
          + (' (non-finite answers replaced by the last finite torque, --nonfinite-torque hold)'
             if counters.get('held_torques') else ''))
    fr = r.metrics.get('free_run', {})
    if fr:
        rt = f', SCHED_FIFO {fr["realtime_priority"]}' if fr.get('realtime_priority') else ''
        p(f'  free-run (catch-up {fr.get("catch_up")}{rt}): {fr.get("ticks_run", 0)} ticks run, '
          f'{fr.get("ticks_skipped", 0)} skipped, {fr.get("overruns", 0)} overruns (late by >= 1 step); '
          f'lateness p50 {fr.get("lateness_us_p50", 0):.0f} us, p99 {fr.get("lateness_us_p99", 0):.0f} us, '
          f'max {fr.get("lateness_us_max", 0):.0f} us; drift {1e3 * fr.get("drift_s", 0):.3f} ms '
          f'(max {1e3 * fr.get("drift_max_s", 0):.3f} ms)')
    mon = r.metrics.get('monitor', {})
    if mon.get('warn') or mon.get('error'):
        p(f'  monitor: {mon.get("error", 0)} ERROR and {mon.get("warn", 0)} WARN statuses; '
          f'worst: {mon.get("worst")}')
        for key in ('first_error', 'first_warn'):
            if key in mon:
                p(f'    first {key[6:].upper()}: {mon[key]}')
    if r.settings:
        p('  settings: ' + ', '.join(f'{k} {v}' for k, v in r.settings.items()))
    p('  messages: ' + ', '.join(f'{t} {n}' for t, n in sorted(r.counts.items())))
    p(f'  bag: {r.bag}')
