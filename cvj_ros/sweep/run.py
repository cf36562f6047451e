"""Running a sweep: one variant, chunks of variants, and the executors.

:func:`run_variant` turns one variant's scene dict into one result row: the scene is
validated (:func:`cvj_ros.physics.scene.parse_scene`), simulated offline by
:class:`cvj_ros.physics.simulate.Simulation` (compiled kernel, the scene's fidelity
rule) and reduced to the metrics ``cvj-sim simulate`` prints: per shaft mean speed,
nonuniformity delta, speed / acceleration / torque amplitudes and mean torque over the
steady window, the energy-balance residual, and the solver counters. Its wall time is
returned beside the row, never in it, so rows are the same bytes on any machine.

Executors (all return the same rows; only the timing differs):

* :class:`SerialExecutor` - in this process (``--workers 1``);
* :class:`ProcessExecutor` - a local process pool (``--workers N``, default all cores).
  Workers are forked from a ``forkserver`` that loaded the compiled kernel once
  (:mod:`cvj_ros.sweep.preload`), keep it for all their variants, and ignore SIGINT (the
  parent handles Ctrl-C);
* :class:`DaskExecutor` - a Dask ``distributed`` cluster (``--cluster tcp://host:port``
  or a ``Client``); the workers must be able to import this cvj_ros.

Work is sent in chunks of consecutive variants (:func:`chunk_size`) so the per-task
overhead (pickling, scheduling: ~1 ms a task) stays small against ~10-60 ms a variant.
"""
from __future__ import annotations

import json
import math
import os
import signal
import threading
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from cvj_ros.errors import CvjError, SceneError
from cvj_ros.sweep.spec import SweepError

# solver counters copied into every row (Simulation.summary()['solver'])
SOLVER_COUNTERS = ('naccept', 'nreject', 'nfev', 'njev', 'nlu')
# per-shaft metrics (cvj_ros.physics.metrics.shaft_metrics), in the order simulate prints them
SHAFT_METRICS = ('mean_speed', 'delta', 'speed_amplitude', 'acceleration_amplitude',
                 'mean_torque', 'torque_amplitude')
STATUSES = ('ok', 'invalid', 'failed')


@dataclass(frozen=True)
class RunOptions:
    """How each variant is simulated (part of the sweep definition: changes the rows).

    sample_dt: sample period in s for the metrics (None: the scene's ``sample_step`` or
    ``exchange_step``, exactly as ``cvj-sim simulate``); transient: s skipped before the
    steady window (None: the criterion of cvj_ros.physics.steady); fidelity: forced levels per element name;
    backend: 'kernel' or 'python'; sampling: 'dense' (default: the controller chooses its
    steps and samples come from the method's dense output - measured on kavz685_lever at
    alpha 15 and 30 deg: every metric within 1.9e-3 relative of 'land', ~1.3x less CPU) or
    'land' (steps land on every sample, exactly ``cvj-sim simulate``'s default); orders:
    engine orders 1..orders of a shaft's torque kept per variant (0: none), columns
    ``SHAFT.torque_order<k>`` (N m), see :func:`order_amplitudes`.
    """

    sample_dt: float | None = None
    sampling: str = 'dense'
    orders: int = 4
    orders_shaft: str | None = None     # shaft whose torque is analysed (None: the first)
    transient: float | None = None
    fidelity: Mapping[str, str] = field(default_factory=dict)
    backend: str = 'kernel'

    def to_dict(self) -> dict[str, Any]:
        return {'sample_dt': self.sample_dt, 'transient': self.transient,
                'fidelity': dict(self.fidelity), 'backend': self.backend,
                'sampling': self.sampling, 'orders': self.orders,
                'orders_shaft': self.orders_shaft}


@dataclass(frozen=True)
class Job:
    """What a worker needs: the base scene dict, each axis's keys, and the options.
    ``listed``: per axis, True when its values come from a list that the sweep repeats
    (a grid axis beside others; empty: not known) - the batched path then maps a value on
    its first variant instead of its second (cvj_ros.sweep.batch)."""

    base: Mapping[str, Any]
    keys: tuple[tuple[str | int, ...], ...]
    options: RunOptions
    listed: tuple[bool, ...] = ()


@dataclass
class Outcome:
    """One finished variant: its ``row`` (result columns) and ``wall`` time (s)."""

    index: int
    row: dict[str, Any]
    wall: float


def validate(scene_data: Mapping[str, Any]) -> str | None:
    """None if the variant is a valid scene, else the scene error line (field path first)."""
    from cvj_ros.physics.scene import parse_scene
    try:
        parse_scene(scene_data)
    except CvjError as exc:
        return ' '.join(str(exc).split())
    return None


def metrics_row(summary: Mapping[str, Any]) -> dict[str, Any]:
    """Flatten a Simulation summary into result columns (whether the run reached a steady
    window and where it starts, energy residual, solver counters, backend, then
    ``SHAFT.METRIC`` per shaft in driveline order)."""
    sol = summary['solver']
    win = summary.get('window') or {}
    row: dict[str, Any] = {}
    if win:     # the steady window the metrics cover (cvj_ros.physics.steady)
        row['steady'] = bool(win['steady'])
        row['window_start_s'] = float(win['start_s'])
    row['energy_residual'] = float(summary['energy_residual'])
    for c in SOLVER_COUNTERS:
        row[c] = int(sol.get(c, 0))
    row['backend'] = str(sol.get('backend', 'python'))
    for shaft, m in summary['shafts'].items():
        for k in SHAFT_METRICS:
            row[f'{shaft}.{k}'] = float(m[k])
    return row


def order_amplitudes(trace: Any, orders: int, transient: float | None,
                     shaft: str | None = None, window: Any = None) -> dict[str, float]:
    """Amplitudes (N m) of engine orders 1..``orders`` of the torque of ``shaft`` (default
    the first shaft: the torque the engine shaft passes on) over the first shaft's angle, in
    the steady window of the summary's metrics (:func:`cvj_ros.physics.metrics.steady_window`)
    (:func:`cvj_ros.physics.signal.harmonics_over_angle`, Davidbaev et al. 2023, eqs. 4.1-4.3, 72 points
    per revolution). NaN when the window holds less than one whole revolution or the
    angle is not monotonic (the engine stopped or reversed)."""
    from cvj_ros.physics.metrics import steady_window
    from cvj_ros.physics.signal import harmonics_over_angle
    shaft = shaft or trace.names[0]
    col = trace.column(shaft)
    if window is None:
        window = steady_window(trace.t, trace.names, trace.velocity, trace.effort,
                               transient=transient)
    mask = window.mask(trace.t)
    try:
        h = harmonics_over_angle(trace.position[mask, 0], trace.effort[mask, col],
                                 n_harmonics=orders, samples_per_rev=max(72, 2 * orders + 2))
        amps = [float(a) for a in h.amplitudes]
    except ValueError:
        amps = [math.nan] * orders
    return {f'{shaft}.torque_order{k + 1}': a for k, a in enumerate(amps)}


def run_variant(scene_data: Mapping[str, Any], options: RunOptions) -> tuple[dict[str, Any], float]:
    """Simulate one variant: (row, wall s). row['status'] is 'ok', 'invalid' (scene error,
    row['error'] names the field) or 'failed' (the run raised; row['error'] says what)."""
    from cvj_ros.physics.scene import parse_scene
    from cvj_ros.physics.simulate import Simulation
    t0 = time.perf_counter()
    try:
        scene = parse_scene(scene_data)
    except CvjError as exc:
        return {'status': 'invalid', 'error': ' '.join(str(exc).split())}, time.perf_counter() - t0
    try:
        if scene.has_modes:     # clutch, gearbox, brake, commands: the Python reference
            from cvj_ros.sweep.hybrid_row import hybrid_row
            return ({'status': 'ok', **hybrid_row(scene, options), 'error': ''},
                    time.perf_counter() - t0)
        sim = Simulation(scene, fidelity=dict(options.fidelity) or None, backend=options.backend)
        row = simulation_row(sim, options)
    except CvjError as exc:
        row = {'status': 'failed', 'error': ' '.join(str(exc).split())}
    except Exception as exc:  # noqa: BLE001  (one bad variant must not end a sweep of thousands)
        row = {'status': 'failed', 'error': f'{type(exc).__name__}: {" ".join(str(exc).split())} '
                                            f'(unexpected)'}
    return row, time.perf_counter() - t0


def simulation_row(sim: Any, options: RunOptions, *, compiled: bool = False) -> dict[str, Any]:
    """Run ``sim`` (a Simulation of a scene without modes) and reduce it to an 'ok' row:
    the metrics over the steady window, the torque orders. Raises what the run raises.
    ``compiled``: the window, metrics and energy residual compiled where that covers the
    record (cvj_ros.sweep.reduce: the same floats; the batched path)."""
    trace = sim.run(sample_dt=options.sample_dt, sampling=options.sampling)
    return trace_row(trace, options, compiled=compiled)


def trace_row(trace: Any, options: RunOptions, *, compiled: bool = False,
              reduced: tuple[Any, dict[str, Any]] | None = None) -> dict[str, Any]:
    """The 'ok' row of a run's ``trace`` (:func:`simulation_row` after the run);
    ``reduced``: the (window, summary) of cvj_ros.sweep.reduce.compiled_reduction when the
    caller made it already."""
    if reduced is None and compiled:
        from cvj_ros.sweep.reduce import compiled_reduction
        reduced = compiled_reduction(trace, options)
    if reduced is not None:
        window, summary = reduced
    else:
        from cvj_ros.physics.metrics import steady_window, summarize
        window = steady_window(trace.t, trace.names, trace.velocity, trace.effort,
                               transient=options.transient)
        # the parts of Simulation.summary() a row needs, from the same functions (its
        # window / fidelity-report dicts and texts cost ~0.5 ms a variant and are not kept)
        summary = {'window': {'steady': window.steady, 'start_s': window.start_s},
                   'energy_residual': trace.max_energy_residual, 'solver': trace.solver,
                   'shafts': summarize(trace, window=window)}
    row = {'status': 'ok', **metrics_row(summary)}
    if options.orders > 0:
        try:      # over the metrics' own window; batched: the grids' cos/sin kept (same floats)
            if compiled or reduced is not None:
                from cvj_ros.sweep.orders import order_amplitudes_cached
                row.update(order_amplitudes_cached(trace, options.orders, options.orders_shaft,
                                                   window, increasing=reduced is not None))
            else:
                row.update(order_amplitudes(trace, options.orders, options.transient,
                                            options.orders_shaft, window))
        except KeyError:
            raise SceneError('--orders-shaft', f'no shaft {options.orders_shaft!r}; shafts: '
                             f'{", ".join(trace.names)}') from None
    row['error'] = ''
    return row


_RUNNER = threading.local()     # .key, .runner: this thread's BatchRunner of its last job


def _batch_runner(job: Job) -> Any:
    """This thread's BatchRunner of ``job`` (kept while chunks of the same job arrive: its
    templates and probes serve every chunk a worker runs). Per thread: a runner writes
    each variant into its templates' arrays, so two threads (a Dask worker with several
    threads) must not share one."""
    from cvj_ros.sweep.batch import BatchRunner
    key = json.dumps([job.base, job.keys, job.options.to_dict()], sort_keys=True, default=repr)
    if getattr(_RUNNER, 'key', None) != key:
        _RUNNER.key, _RUNNER.runner = key, BatchRunner(job)
    return _RUNNER.runner


def run_chunk(job: Job, chunk: Sequence[tuple[int, Sequence[Any]]], *,
              batched: bool = True) -> list[Outcome]:
    """Run consecutive variants ``[(index, values), ...]`` of ``job`` (the worker task).

    ``batched`` (default): cvj_ros.sweep.batch, the model built once per structure and
    patched per variant (the same rows); False: :func:`run_variant` for every variant.

    The cyclic garbage collector is paused for the chunk: a variant leaves no reference
    cycles (measured: gc.collect() finds 0 unreachable objects after 64 kavz685_lever
    variants, peak memory +0.25 MB), so its scans of the many short-lived arrays were pure
    cost (~3 % of a variant's CPU). Reference counting frees everything as before. The
    pause is process-wide; with several threads running chunks (a Dask worker with
    threads) whichever found the collector enabled enables it again when it finishes."""
    import gc

    from cvj_ros.sweep.spec import apply_keys
    out = []
    paused = gc.isenabled()
    gc.disable()
    try:
        if batched:
            runner = _batch_runner(job)
            out = [Outcome(index, *runner.run(values)) for index, values in chunk]
        else:
            for index, values in chunk:
                row, wall = run_variant(apply_keys(job.base, job.keys, values), job.options)
                out.append(Outcome(index, row, wall))
    finally:
        if paused:
            gc.enable()
    return out


def chunk_size(n: int, workers: int) -> int:
    """Variants per task: about 16 tasks per worker for load balance and a progress line
    that moves, at most 64 (a chunk of kavz685_lever 2 s variants then lasts ~1-4 s)."""
    return max(1, min(64, math.ceil(n / max(1, workers * 16))))


def chunks(items: Sequence[tuple[int, Sequence[Any]]], size: int) -> list[list[tuple[int, Sequence[Any]]]]:
    return [list(items[i:i + size]) for i in range(0, len(items), size)]


# --- executors ---------------------------------------------------------------------------

class SerialExecutor:
    """Runs the chunks one after another in this process."""

    name = 'serial'

    def __init__(self) -> None:
        self.workers = 1

    def map(self, job: Job, work: list[list[tuple[int, Sequence[Any]]]]) -> Iterator[list[Outcome]]:
        for chunk in work:
            yield run_chunk(job, chunk)

    def cancel(self) -> None:
        pass

    def close(self) -> None:
        pass


def _init_worker() -> None:
    """Process-pool worker start: leave Ctrl-C to the parent (which keeps finished rows and
    stops the pool); a worker that also got SIGINT would die mid-variant and break the pool."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)


class ProcessExecutor:
    """A local pool of ``workers`` processes (spawned; one compiled kernel each)."""

    name = 'local'

    def __init__(self, workers: int) -> None:
        import concurrent.futures as cf
        import multiprocessing as mp
        self.workers = workers
        # forkserver: workers fork from a server that loaded the kernel once (preload.py);
        # no fork of this (possibly threaded) process, no per-worker kernel load. Started
        # now if the caller has not (cvj-sim sweep starts it before its own imports), while
        # the caller builds the sweep and its manifest on the other core
        from cvj_ros.sweep.server import start_fork_server
        start_fork_server()
        ctx = mp.get_context('forkserver')
        self.pool = cf.ProcessPoolExecutor(max_workers=workers, mp_context=ctx,
                                           initializer=_init_worker)
        self.futures: list[Any] = []

    def map(self, job: Job, work: list[list[tuple[int, Sequence[Any]]]]) -> Iterator[list[Outcome]]:
        import concurrent.futures as cf
        from concurrent.futures.process import BrokenProcessPool
        self.futures = [self.pool.submit(run_chunk, job, c) for c in work]
        from cvj_ros.sweep.server import mark_served
        try:
            for fut in cf.as_completed(self.futures):
                result = fut.result()
                mark_served()       # a worker ran: the fork server is past its preload
                yield result
        except BrokenProcessPool:
            raise SweepError('--workers: a worker process died (killed, or out of memory); the '
                             'finished variants are kept: rerun the same command to resume') from None

    def cancel(self) -> None:
        for f in self.futures:
            f.cancel()
        # the running chunks are not needed any more: stop the workers now (our children)
        for proc in list(getattr(self.pool, '_processes', {}).values()):
            proc.terminate()
        self.pool.shutdown(wait=True, cancel_futures=True)

    def close(self) -> None:
        self.pool.shutdown(wait=True, cancel_futures=True)


class DaskExecutor:
    """Runs the chunks on a Dask distributed cluster (a scheduler address or a Client)."""

    name = 'dask'

    def __init__(self, cluster: str | Any) -> None:
        try:
            from distributed import Client
        except ImportError:     # pragma: no cover  (pinned in requirements.txt)
            raise SweepError('--cluster: dask distributed is not installed '
                                 '(pip install distributed)') from None
        if isinstance(cluster, str):
            try:
                self.client = Client(cluster, timeout=10)
            except ValueError as exc:       # malformed address ('host' without a port, ...)
                raise SweepError(f'--cluster {cluster}: not a scheduler address, e.g. '
                                     f'tcp://host:8786 ({" ".join(str(exc).split())[:200]})') from None
            except (OSError, TimeoutError) as exc:
                raise SweepError(f'--cluster {cluster}: cannot connect to the Dask scheduler '
                                     f'({" ".join(str(exc).split())[:200]})') from None
            self.own_client = True
        else:
            self.client = cluster
            self.own_client = False
        self.address = getattr(self.client.scheduler, 'address', str(cluster))
        self.workers = max(1, sum(int(w.get('nthreads', 1)) for w in
                                  self.client.scheduler_info().get('workers', {}).values()))
        self.futures: list[Any] = []

    def map(self, job: Job, work: list[list[tuple[int, Sequence[Any]]]]) -> Iterator[list[Outcome]]:
        from distributed import as_completed
        [job_future] = self.client.scatter([job], broadcast=True)
        self.futures = [self.client.submit(run_chunk, job_future, c, pure=False) for c in work]
        for fut in as_completed(self.futures):
            yield fut.result()

    def cancel(self) -> None:
        if self.futures:
            self.client.cancel(self.futures)

    def close(self) -> None:
        self.futures = []
        if self.own_client:
            self.client.close()


def make_executor(workers: int | None = None, cluster: str | Any | None = None) -> Any:
    """The executor for ``--workers`` / ``--cluster`` (cluster wins; workers default: all
    cores this process may use)."""
    if cluster is not None:
        return DaskExecutor(cluster)
    n = workers if workers is not None else default_workers()
    if n < 1:
        raise SweepError(f'--workers: must be >= 1, got {n}')
    return SerialExecutor() if n == 1 else ProcessExecutor(n)


def default_workers() -> int:
    """Cores this process may run on (sched_getaffinity), else os.cpu_count()."""
    from cvj_ros.sweep.server import usable_cores
    return usable_cores()


ProgressFn = Callable[[int], None]


# --- the driver --------------------------------------------------------------------------

@dataclass
class SweepReport:
    """What one invocation did: counts by status, variants run now and skipped (resume),
    wall seconds of the run phase and in total, and the executor."""

    total: int
    counts: dict[str, int]
    ran: int
    skipped: int
    run_wall: float
    total_wall: float
    executor: str
    workers: int
    complete: bool
    out_dir: str
    first_bad: str | None = None
    first_wall: float = 0.0       # s from the run start to the first finished chunk
    first_count: int = 0          # variants in that chunk

    @property
    def rate(self) -> float:
        """Variants simulated per wall second of the run phase, start-up of the workers and
        kernel load included (0 if none ran)."""
        return self.ran / self.run_wall if self.run_wall > 0 and self.ran else 0.0

    @property
    def steady_rate(self) -> float:
        """Variants per wall second after the first finished chunk (workers started, kernel
        loaded); the plain rate when only one chunk ran."""
        rest, wall = self.ran - self.first_count, self.run_wall - self.first_wall
        return rest / wall if rest > 0 and wall > 0 else self.rate


def execute(sweep: Any, options: RunOptions, out_dir: str | os.PathLike[str], *,
            executor: Any, on_error: str = 'skip', scene_source: str = '<dict>',
            fresh: bool = False, progress: ProgressFn | None = None,
            started: float | None = None) -> SweepReport:
    """Run ``sweep`` (cvj_ros.sweep.spec.Sweep) into ``out_dir`` with ``executor``.

    Variants already in ``out_dir`` (same definition) are skipped; a different definition
    there is an error unless ``fresh``. With ``on_error='stop'`` every variant is validated
    here first and a bad one stops the sweep before anything runs, naming the variant and
    the scene field; a run that fails stops it after the running chunks. With 'skip' the
    workers validate and record bad variants as 'invalid' rows. Ctrl-C
    (KeyboardInterrupt) stops the executor, writes the tables of what finished and
    re-raises. ``started``: wall clock (time.perf_counter) of the command start, for the
    total wall time (default: now)."""
    from cvj_ros.sweep.results import ResultStore, scene_digest, versions
    t_start = time.perf_counter() if started is None else started
    if on_error not in ('skip', 'stop'):
        raise SweepError(f'--on-error: must be skip or stop, got {on_error!r}')
    store = ResultStore(out_dir)
    definition = {'scene': {'source': scene_source, 'name': sweep.base.get('name'),
                            'sha256': scene_digest(sweep.base), 'data': sweep.base},
                  **sweep.definition, 'options': options.to_dict(), 'variants': len(sweep)}
    old = store.read_manifest()
    if old is not None and not fresh:
        if json.loads(json.dumps(old.get('definition'), default=str)) != \
                json.loads(json.dumps(definition, default=str)):
            raise SweepError(f'--out {out_dir}: holds a different sweep (scene, --set, --samples, '
                             f'--seed or run options differ); give another --out, or --fresh to '
                             f'replace it')
    elif fresh:
        store.clear()
    done = store.load_done() if old is not None and not fresh else {}
    skipped = len(done)
    axis_cols = [a.column for a in sweep.axes]

    def label(i: int) -> str:
        """'variant 7 (a=1, b=2)' with the varied fields (fixed ones add nothing)."""
        varied = [f'{a.path}={v}' for a, v in zip(sweep.axes, sweep.variants[i])
                  if a.range is not None or len(a.values) > 1]
        return f'variant {i}' + (f' ({", ".join(varied)})' if varied else '')

    # with --on-error stop, validate every variant to run before simulating any (parse_scene:
    # 0.3-1.3 ms each here, 13 s for 10 000 kavz685_lever variants at load 12); with skip
    # the workers validate (they parse each variant anyway) and return 'invalid' rows
    todo: list[tuple[int, tuple[Any, ...]]] = []
    for i, values in enumerate(sweep.variants):
        if i in done:
            continue
        if on_error == 'stop':
            err = validate(sweep.scene_dict(i))
            if err is not None:
                raise SweepError(f'{label(i)}: {err} (--on-error stop: nothing was run)')
        todo.append((i, values))
    manifest = old if (old is not None and not fresh) else {'format': 'cvj_ros.sweep/1'}
    manifest.update(definition=definition, versions=versions())
    manifest.setdefault('runs', [])
    store.write_manifest(manifest)
    job = Job(base=sweep.base, keys=tuple(a.keys for a in sweep.axes), options=options,
              listed=tuple(a.range is None and 1 < len(a.values) < len(sweep.variants)
                           for a in sweep.axes))
    work = chunks(todo, chunk_size(len(todo), executor.workers))
    t_run = time.perf_counter()
    ran = 0
    first_wall, first_count = 0.0, 0
    complete = False
    stop_error: str | None = None
    try:
        if progress is not None:
            progress(len(done))
        for outcomes in (executor.map(job, work) if work else ()):
            store.append(outcomes)
            for o in outcomes:
                done[o.index] = (o.row, o.wall)
            if not ran:
                first_wall, first_count = time.perf_counter() - t_run, len(outcomes)
            ran += len(outcomes)
            if progress is not None:
                progress(len(done))
            if on_error == 'stop' and any(o.row.get('status') != 'ok' for o in outcomes):
                bad = next(o for o in outcomes if o.row.get('status') != 'ok')
                stop_error = f'{label(bad.index)}: {bad.row.get("error", "")}'
                executor.cancel()
                break
        complete = stop_error is None
    except BaseException:
        executor.cancel()
        raise
    finally:
        run_wall = time.perf_counter() - t_run
        executor.close()
        store.write_tables(axis_cols, sweep.variants, done)
        counts = {s: 0 for s in STATUSES}
        for row, _ in done.values():
            counts[row.get('status', 'failed')] = counts.get(row.get('status', 'failed'), 0) + 1
        complete = complete and len(done) == len(sweep)
        bad = [i for i, (row, _) in done.items() if row.get('status') != 'ok']
        first_bad = f'{label(min(bad))}: {done[min(bad)][0].get("error", "")}' if bad else None
        manifest['runs'].append({'executor': executor.name, 'workers': executor.workers,
                                 'variants_run': ran, 'skipped_done': skipped,
                                 'run_wall_s': run_wall,
                                 'total_wall_s': time.perf_counter() - t_start,
                                 'complete': complete})
        manifest['complete'] = complete
        manifest['counts'] = counts
        store.write_manifest(manifest)
    if stop_error is not None:
        raise SweepError(f'{stop_error} (--on-error stop; {len(done)} finished variants kept in '
                         f'{out_dir})')
    return SweepReport(total=len(sweep), counts=counts, ran=ran, skipped=skipped,
                       run_wall=run_wall, total_wall=time.perf_counter() - t_start,
                       executor=executor.name, workers=executor.workers, complete=complete,
                       out_dir=str(out_dir), first_bad=first_bad, first_wall=first_wall,
                       first_count=first_count)
