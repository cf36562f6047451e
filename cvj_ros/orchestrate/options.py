"""What a run is: its options, its result, and the validated run (:func:`prepare`, before any
process starts; every bad value is a CvjError naming the field)."""
from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from cvj_ros import bag as bagmod
from cvj_ros.errors import CvjError


NODE_ORDER = ('engine_node', 'load_node', 'monitor_node', 'driver_node', 'coupling_node')  # coupling last
MODES = ('lockstep', 'free-run')
# What a run writes into its directory (all of it is replaced by --overwrite).
RUN_ENTRIES = ('bag', 'logs', 'report.json', 'load_override.npz', 'fastdds_profile.xml')
SCHEMES = ('zoh', 'extrapolate', 'linear_implicit')


# outside nodes that may stand in for a peer (--external): node it replaces, what it answers
EXTERNAL_PEERS = {
    'engine': ('engine_node', 'the engine torque on the first shaft, torque.z in N m (driving '
                              'positive)'),
    'load': ('load_node', 'the resisting torque on the last shaft, torque.z in N m (positive '
                          'opposes positive rotation)'),
}
#: --external driver: an outside stack sends the commands (throttle, clutch, gear, brake)
#: instead of driver_node; the coupling node takes them as they come (commands=external)
EXTERNAL_COMMANDS = 'driver'


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
        rt_priority: free-run: SCHED_FIFO priority of the coupling process's threads (0 = off).
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
    executor: str = 'auto'       # composed mode: 'auto', 'events' (EventsExecutor) or 'single'
    intra_process: bool = True   # composed mode: loop topics through the in-process bus (nodes/intra.py)
    # scenes with clutch, gearbox, brake or commands: the coupling node's mode_backend
    mode_backend: str = 'auto'
    # time.monotonic() when the command started (the report's wall time counts from it;
    # None: from the start of the run's set-up)
    started: float | None = None


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
    # vehicle scene with --external load: the start wait's peers (orchestrate.vehicle)
    peers: tuple[dict[str, str], dict[str, str]] | None = None


def prepare_kernel(prep: _Prepared, options: RunOptions) -> float:
    """Compile the run's cold kernel entry points before anything starts
    (:func:`cvj_ros.physics.kernel.prepare.prepare_run`: both halves in two processes, lines
    on stderr); returns the wall seconds it took, 0.0 when everything was cached."""
    import time

    from cvj_ros.physics.kernel.prepare import prepare_run
    t0 = time.monotonic()
    if not prepare_run(prep.scene_path, prep.scene, scheme=options.scheme,
                       exchange_step=prep.exchange_step):
        return 0.0
    return round(time.monotonic() - t0, 4)


def prepare(options: RunOptions) -> _Prepared:
    """Validate the scene and every option; raises a CvjError naming the field, starts nothing."""
    from cvj_ros.physics.scene import Joint, find_scene, iter_elements, load_scene
    scene_path = find_scene(options.scene).resolve()
    scene = load_scene(scene_path)
    if scene.has_modes and scene.is_tree and 'load' in options.external:
        raise CvjError('--external load: a vehicle scene with clutch, gearbox or brakes runs its '
                       'built-in tyres (the mode model takes no outside wheel loads yet)')
    if scene.has_modes and options.scheme != 'zoh':   # clutch, gearbox, brake, commands
        raise CvjError(f'--scheme: a scene with clutch, gearbox, brake or commands runs with zoh '
                       f'(the mode model holds the received torques), got {options.scheme!r}')
    if options.mode not in MODES:
        raise CvjError(f'--mode: must be one of {", ".join(MODES)}, got {options.mode!r}')
    if options.mode_backend not in ('auto', 'kernel', 'python'):
        raise CvjError(f'--mode-backend: must be auto, kernel or python, got {options.mode_backend!r}')
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
    # a spring no explicit solver can step over this run (the coupling node refuses it too)
    from cvj_ros.physics.simulate import scene_explicit_step_check
    scene_explicit_step_check(scene, scene.solver.method, duration)
    unknown = [e for e in options.external if e not in EXTERNAL_PEERS and e != EXTERNAL_COMMANDS]
    if unknown:
        raise CvjError(f'--external: must be {", ".join(EXTERNAL_PEERS)}, {EXTERNAL_COMMANDS} or a '
                       f'combination, got {unknown[0]!r}')
    if EXTERNAL_COMMANDS in options.external and not scene.has_modes:
        raise CvjError(f'--external {EXTERNAL_COMMANDS}: {scene_path.name} has no clutch, gearbox, '
                       f'brake or commands to drive (the throttle goes to the engine node as it is)')
    if scene.is_tree:
        from cvj_ros.orchestrate.vehicle import check_vehicle_options
        check_vehicle_options(scene_path, options)
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
        check_finite_series(options.load_from_bag, *load_series)
    # reaction wrench topics: every joint of a chain or of every branch of a vehicle scene
    # (a vehicle scene with modes publishes none: its mode model gives no reactions)
    joints = ([] if scene.is_tree and scene.has_modes else
              [el.name for el in iter_elements(scene.driveline) if isinstance(el, Joint)])
    peers = None
    if scene.is_tree:
        from cvj_ros.orchestrate.vehicle import vehicle_peers
        peers = vehicle_peers(scene, options.external)
    import importlib.util
    outside = {EXTERNAL_PEERS[e][0] for e in options.external if e in EXTERNAL_PEERS}
    if EXTERNAL_COMMANDS in options.external or not scene.commands:
        outside.add('driver_node')     # nothing to play, or an outside stack plays it
    nodes = tuple(n for n in NODE_ORDER if n not in outside
                  and importlib.util.find_spec(f'cvj_ros.nodes.{n}') is not None)
    for required in ('engine_node', 'load_node', 'coupling_node'):
        if required in outside:
            continue
        if required not in nodes:
            raise CvjError(f'{required}: module cvj_ros.nodes.{required} is not installed')
    check_writable_out(out)   # last: a run refused for another reason creates nothing
    # the recorder's topics beyond the loop's: reaction wrenches, outside wheel loads
    extra = [f'/coupling/{j}/wrench' for j in joints]
    if peers is not None:
        extra += [t for t in peers[0].values() if t.startswith('/load/')]
    return _Prepared(options, scene, scene_path, duration, h, options.seed, load_series,
                     extra, nodes, peers)


def check_finite_series(bag: Any, t: np.ndarray, torque: np.ndarray) -> None:
    """Refuse a recorded load with a non-finite stamp or torque (the coupling node would stop
    at its first use, after every process started): CvjError naming ``--load-from-bag``,
    the bag, the first bad sample and its time."""
    bad = ~(np.isfinite(t) & np.isfinite(torque))
    if bad.any():
        i = int(np.argmax(bad))
        raise CvjError(f'--load-from-bag: {bag}: /load/wrench torque.z not finite ({torque[i]:g} N m) '
                       f'at t = {t[i]:.9g} s (sample {i} of {t.size}, {int(bad.sum())} such); '
                       'a recorded load must be finite')


def check_writable_out(out: Path) -> None:
    """Make sure the run directory ``out`` can be created and written (a read-only file
    system, a parent that is a file, /proc, no permission): CvjError naming ``--out`` and the
    reason, before any process starts. Creates ``out`` (the run would) and removes the probe."""
    import errno
    import tempfile
    try:
        out.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=out):
            pass
    except OSError as exc:
        reason = exc.strerror or errno.errorcode.get(exc.errno or 0, type(exc).__name__)
        where = f' ({exc.filename})' if exc.filename and str(exc.filename) != str(out) else ''
        raise CvjError(f'--out: {out}: cannot write the run directory: {reason}{where}') from None


def _domain_env() -> tuple[dict[str, str], int]:
    from cvj_ros.nodes.qos import dds_environment, domain_id
    # localhost discovery, Fast DDS, synchronous publication (cvj_ros.nodes.qos.dds_environment)
    env = dds_environment(dict(os.environ))
    if not env.get('ROS_DOMAIN_ID', '').strip():
        env['ROS_DOMAIN_ID'] = str(1 + os.getpid() % 100)
    return env, domain_id(env)
