"""Composed mode: engine, load, monitor and coupling nodes plus the bag recorder in ONE process.

ROS 2's answer to process hops is composition: the nodes stay separate nodes (own name,
own parameters, own publishers and subscriptions on the same topics) but share one process
and one executor. rclcpp has a component container; rclpy has none, so this module is its
equivalent for the cvj_ros nodes:

* :class:`ComposedDriveline` creates the node classes of ``cvj_ros.nodes`` (EngineNode,
  LoadNode, MonitorNode, CouplingNode, and a ``cvj_recorder`` node with a
  :class:`cvj_ros.bag.BagRecorder`) on one rclpy Context and spins them on one
  ``rclpy.experimental.EventsExecutor`` (falls back to the SingleThreadedExecutor, with the
  reason stated, when the EventsExecutor cannot be created). Every message still goes
  through DDS (Fast DDS delivers inside the process without a socket), so the topics and the
  bag are the same as with one process per node, message for message
  (test/e2e/test_run_composed.py).
* :func:`run_composed` is ``cvj-sim run SCENE --composed``: the same validation, bag,
  report and exit statuses as :func:`cvj_ros.orchestrate.run`, with the nodes inside the
  ``cvj-sim`` process instead of child processes.
* :func:`main` is the ``driveline_composed`` console script for a ROS install
  (``ros2 run cvj_ros driveline_composed --ros-args -p scene:=kavz685_lever``): ``-p``
  parameters go to every hosted node (each takes the ones it declares), ``--without NODE``
  leaves a node out so it can run alone (``ros2 run cvj_ros load_node ...``) or be replaced
  by an outside node, ``--record DIR`` writes a bag from inside the process.

Why one executor and not one thread per node: the lockstep exchange is a chain of callbacks
(coupling publishes the state -> engine and load answer -> coupling integrates and publishes
the next state). On one executor each link is a queue hand-off in the same thread; with
threads every link would also wait for the GIL (switch interval 5 ms).
"""
from __future__ import annotations

import argparse
import os
import shutil
import signal
import sys
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, TextIO

from cvj_ros.errors import CvjError

PROG = 'driveline_composed'
# Creation order: the recorder first (subscribed before anything publishes), the coupling node
# last (it makes the peers talk), as in cvj_ros.orchestrate.NODE_ORDER.
HOSTED_NODES = ('engine_node', 'load_node', 'monitor_node', 'coupling_node')
EXECUTORS = ('auto', 'events', 'single')
#: ``--executor auto`` takes the EventsExecutor for runs of at most this many exchanges and
#: the SingleThreadedExecutor for longer ones: the EventsExecutor needs less CPU per exchange,
#: but the process grows with every exchange on it, up to ~300 bytes (the side-by-side
#: measurement in docs/robustness.md, "Long runs"): at most ~28 MiB over 1e5 exchanges
AUTO_EVENTS_MAX_EXCHANGES = 100_000
# wall s between checks of the signal flag by the container's timer (a loop that is running
# stops at its next exchange anyway: CouplingNode.stop_signal)
SIGNAL_POLL_S = 0.02


def node_class(name: str) -> type:
    """The rclpy Node class of hosted node ``name`` (imported on demand)."""
    if name == 'engine_node':
        from cvj_ros.nodes.engine_node import EngineNode
        return EngineNode
    if name == 'load_node':
        from cvj_ros.nodes.load_node import LoadNode
        return LoadNode
    if name == 'monitor_node':
        from cvj_ros.nodes.monitor_node import MonitorNode
        return MonitorNode
    if name == 'coupling_node':
        from cvj_ros.nodes.coupling_node import CouplingNode
        return CouplingNode
    if name == 'driver_node':
        from cvj_ros.nodes.driver_node import DriverNode
        return DriverNode
    raise CvjError(f'node: must be one of {", ".join(HOSTED_NODES)}, got {name!r}')


def resolve_executor(kind: str, exchanges: int | None) -> tuple[str, str | None]:
    """``(events | single, note or None)`` for ``--executor kind`` and a run of
    ``exchanges`` exchange steps (None: until stopped). ``auto``: ``events`` up to
    :data:`AUTO_EVENTS_MAX_EXCHANGES`, else ``single`` (flat memory), with a note saying so."""
    if kind != 'auto':
        return kind, None
    if exchanges is not None and exchanges <= AUTO_EVENTS_MAX_EXCHANGES:
        return 'events', None
    length = 'a run without an end' if exchanges is None else f'{exchanges} exchanges'
    return 'single', (f'SingleThreadedExecutor for {length} (--executor auto: the '
                      f'EventsExecutor is faster but its memory grows with every exchange; '
                      f'it is used up to {AUTO_EVENTS_MAX_EXCHANGES} exchanges)')


def make_composed_executor(kind: str, context: Any) -> tuple[Any, str, str | None]:
    """``(executor, kind used, fallback reason or None)``.

    ``'events'``: ``rclpy.experimental.EventsExecutor`` (measured in-process round trip 19 us
    against ~150 us with the SingleThreadedExecutor, docs/benchmark.md); if it cannot be
    created (an rclpy without it), the SingleThreadedExecutor and the reason.
    """
    from rclpy.executors import SingleThreadedExecutor
    if kind == 'events':
        try:
            from rclpy.experimental import EventsExecutor
            return EventsExecutor(context=context), 'events', None
        except Exception as exc:  # noqa: BLE001 (ImportError, or a failing C extension)
            return (SingleThreadedExecutor(context=context), 'single',
                    f'EventsExecutor unavailable ({type(exc).__name__}: {exc}); '
                    'using the SingleThreadedExecutor')
    if kind != 'single':
        raise CvjError(f'--executor: must be one of {", ".join(EXECUTORS)}, got {kind!r}')
    return SingleThreadedExecutor(context=context), 'single', None


class ComposedDriveline:
    """Hosts cvj_ros nodes (and optionally the recorder) on one context and one executor.

    Args:
        context: an initialised rclpy Context (the caller shuts it down).
        executor: ``'events'`` (default) or ``'single'`` (``'auto'``: see
            :func:`resolve_executor`; here, without a known length, ``'single'``).
        hosted: the node names that will be added (:data:`HOSTED_NODES` or fewer): with
            ``intra_process`` their loop topics go through an
            :class:`cvj_ros.nodes.intra.IntraProcessBus` between the hosted nodes and the
            recorder (DDS still carries them to outside subscribers).
        intra_process: False = every message through DDS, also inside the process.
    """

    def __init__(self, context: Any, *, executor: str = 'events',
                 hosted: Sequence[str] = (), intra_process: bool = True) -> None:
        import rclpy
        self.context = context
        kind, auto_note = resolve_executor(executor, None)
        self.executor, self.executor_kind, self.executor_note = make_composed_executor(kind, context)
        self.executor_note = self.executor_note or auto_note
        self.nodes: dict[str, Any] = {}
        self.recorder: Any = None
        self.batching: Any = None      # cvj_ros.bag.BatchingWriter once the recorder is added
        self._recorder_node: Any = None
        self._wake: Any = None
        self._spin_timer: tuple[Any, float] = (None, 0.0)   # (timer, wall period) of _spin
        # the container's own node (as rclcpp's component manager has one): its timers end
        # the timed spins, see _spin
        self._container = rclpy.create_node(PROG, context=context)
        # a signal handler may not complete a Future (its lock may be held by the code it
        # interrupted), and the EventsExecutor has no guard conditions: the handler sets a
        # flag that this timer turns into a wake every SIGNAL_POLL_S
        self._signalled = False
        self._signal_timer = self._container.create_timer(SIGNAL_POLL_S, self._wake_if_signalled)
        self.executor.add_node(self._container)
        self.bus: Any = None
        if intra_process and hosted:
            from cvj_ros.nodes import intra
            topics, wrenches = intra.carried_topics(hosted)
            self.bus = intra.IntraProcessBus(self._container, topics, coupling_wrenches=wrenches)
            intra.attach(context, self.bus)

    def add_node(self, name: str, *, cli_args: Sequence[str] | None = None) -> Any:
        """Create hosted node ``name`` with its own ``--ros-args`` (``cli_args``, e.g. ``-p
        scene:=...``) and add it to the executor. Raises CvjError (ParameterError) for a bad
        parameter, naming it, as the node's own process would."""
        cls = node_class(name)
        kwargs: dict[str, Any] = {'context': self.context}
        if cli_args:
            kwargs['cli_args'] = list(cli_args)
        node = cls(**kwargs)
        self.nodes[name] = node
        if self.bus is not None:
            self.bus.register(node)
        if self.recorder is not None:
            # record the node's contract topics from its first message: subscribed before the
            # executor runs the node (the recorder's graph scan every 0.2 s would miss the
            # first reaction wrenches of /coupling/<joint>/wrench)
            from cvj_ros.bag import topic_type
            for pub in node.publishers:
                if topic_type(pub.topic_name) is not None:
                    self.recorder.subscribe(pub.topic_name)
        self._trust_hosted()
        node.done.add_done_callback(lambda _f: self.wake())   # finished or failed: stop spinning
        self.executor.add_node(node)
        return node

    def add_recorder(self, writer: Any, topics: Sequence[str] = (), *,
                     hold: Sequence[str] = (), run_only: bool = True) -> Any:
        """A ``cvj_recorder`` node with a :class:`cvj_ros.bag.BagRecorder` writing to ``writer``
        (subscribes to every contract topic plus ``topics``); its callbacks run on the shared
        executor. ``hold``: topics dropped (counted) until :attr:`recorder.hold` is cleared."""
        import rclpy

        from cvj_ros import bag as bagmod
        self._recorder_node = rclpy.create_node('cvj_recorder', context=self.context)
        if self.bus is not None:
            self.bus.register(self._recorder_node)
        # the loop waits for the writer rather than run ahead of the disk (hard-kill bound)
        self.batching = bagmod.BatchingWriter(writer, max_lag_s=bagmod.MAX_LAG_S)
        self.recorder = bagmod.BagRecorder(self._recorder_node, self.batching, topics=topics,
                                           run_only=run_only)
        self.recorder.hold = frozenset(hold)
        self._trust_hosted()
        self.executor.add_node(self._recorder_node)
        return self.recorder

    def _trust_hosted(self) -> None:
        """The recorder takes the hosted loop messages (from the in-process bus) without an
        identity check: they are this run's by construction."""
        if self.recorder is not None:
            self.recorder.trust_local = self.bus is not None

    def publisher_count(self, topic: str) -> int:
        """Publishers matched by the recorder's subscription of ``topic`` (0 without
        recorder); for a topic of the in-process bus, the publishers in the ROS graph."""
        sub = None if self.recorder is None else self.recorder._subs.get(topic)
        return 0 if sub is None else sub.get_publisher_count()

    def wake_from_signal(self) -> None:
        """End the current spin within :data:`SIGNAL_POLL_S`: safe in a signal handler (sets
        a flag; a timer on the executor runs :meth:`wake`)."""
        self._signalled = True

    def _wake_if_signalled(self) -> None:
        if self._signalled:
            self.wake()

    def wake(self) -> None:
        """End the current spin (from callbacks; a signal handler calls :meth:`wake_from_signal`)."""
        wake = self._wake
        if wake is not None and not wake.done():
            wake.set_result(True)

    def _spin(self, seconds: float) -> None:
        """Run callbacks for ``seconds`` (wall s) or until :meth:`wake`.

        The end is a timer on the container node, not the executor's timeout: measured here,
        ``EventsExecutor.spin_until_future_complete(timeout_sec=...)`` does not return while
        events keep arriving (a lockstep loop never pauses), so a timeout alone would never
        give control back for Ctrl-C or progress until the run ends."""
        from rclpy.task import Future
        self._wake = Future()
        period = max(seconds, 1e-4)
        # one timer per period, re-armed for every spin: a timer created and destroyed per
        # spin keeps memory in rclpy (a weak reference in the callback group per timer, ~150
        # bytes, and ~250 bytes of native memory) and, on the EventsExecutor, spins of a
        # busy loop end early, many times a second (docs/robustness.md "Long runs")
        timer, timer_period = self._spin_timer
        if timer is None or timer_period != period:
            if timer is not None:
                self._container.destroy_timer(timer)
            timer = self._container.create_timer(period, self.wake)
            self._spin_timer = (timer, period)
        else:
            timer.reset()
        try:
            self.executor.spin_until_future_complete(self._wake, timeout_sec=period + 1.0)
        finally:
            timer.cancel()
            self._wake = None
            self.flush()

    def spin_for(self, seconds: float) -> None:
        """Run callbacks for ``seconds`` (wall s), or until :meth:`wake` / a hosted node ends."""
        self._spin(seconds)

    def flush(self) -> None:
        """Handle the recorder's collected loop messages and hand them to the bag writer thread."""
        if self.recorder is not None:
            self.recorder.take_local()
        if self.batching is not None:
            self.batching.flush()

    def spin_until_done(self, node: Any, *, stop: Callable[[], bool] = lambda: False,
                        on_tick: Callable[[], None] | None = None, tick: float = 0.25) -> None:
        """Spin until ``node.exit_code`` is set, any hosted node failed, ``stop()`` (call
        :meth:`wake` with it from the signal handler) or the context shut down; ``on_tick``
        runs every ``tick`` s (progress)."""
        while node.exit_code is None and self.context.ok() and not stop() and self.failed() is None:
            self._spin(tick)
            if on_tick is not None:
                on_tick()

    def failed(self) -> str | None:
        """``'<node>: <error>'`` of the first hosted node that ended with an error, else None."""
        for name, node in self.nodes.items():
            if node.exit_code not in (None, 0):
                return f'{name}: {node.error_message or f"exit status {node.exit_code}"}'
        return None

    def settle(self) -> None:
        """Run what the in-process bus still holds (the nodes are alive: e.g. the coupling
        node's final diagnostics, queued for the recorder behind the last answers), then
        :meth:`flush`. Without it a drain cut by its budget when the loop ended left those
        deliveries to be dropped by :meth:`destroy` (a bag one /diagnostics short, once in
        a CI run)."""
        if self.bus is not None:
            self.bus.drain(1.0)
        self.flush()

    def destroy(self) -> None:
        """Remove every node and the recorder's subscriptions; shut the executor down."""
        try:
            self.settle()
        except Exception:  # noqa: BLE001 (a node failing now: its own error line is out already)
            pass
        try:
            self.executor.shutdown()
        except Exception:  # noqa: BLE001 (context already shut down)
            pass
        if self.bus is not None:
            from cvj_ros.nodes import intra
            intra.detach(self.context)
            self.bus.destroy()
        for node in reversed(list(self.nodes.values())):
            node.destroy_node()
        self.nodes.clear()
        self._container.destroy_node()
        if self.recorder is not None:
            self.recorder.destroy()
            self.flush()
        if self._recorder_node is not None:
            self._recorder_node.destroy_node()
            self._recorder_node = None


# --- cvj-sim run --composed ------------------------------------------------------------------

def _wait_for_peers(comp: ComposedDriveline, stop: Callable[[], bool], *, timeout: float,
                    mode: str, domain: int, external: Sequence[str],
                    external_timeout: float,
                    peers: tuple[dict[str, str], dict[str, str]] | None = None) -> str | None:
    """Spin until the recorder sees one engine and one load publisher (ours or the outside
    node's) and no other run's publishers for DISCOVERY_SETTLE_S (both modes); an error line
    otherwise (same rules and wording as cvj_ros.orchestrate._wait_for_peers)."""
    from cvj_ros import bag as bagmod
    from cvj_ros.orchestrate import DISCOVERY_SETTLE_S, EXTERNAL_PEERS, PEER_TOPICS
    t0 = time.monotonic()
    # a vehicle scene with --external load: its engine and per-wheel peers (orchestrate.vehicle)
    topics, outside = peers if peers is not None else (
        PEER_TOPICS, {EXTERNAL_PEERS[e][0]: e for e in external if e in EXTERNAL_PEERS})
    settled_since: float | None = None
    while not stop():
        comp.spin_for(0.02)
        n_js = comp.publisher_count(bagmod.JOINT_STATES_TOPIC)
        extra = ([f'{bagmod.JOINT_STATES_TOPIC} has {n_js} publishers'] if n_js > 0 else []) + \
            [f'{topic} has {n} publishers' for topic in topics.values()
             if (n := comp.publisher_count(topic)) > 1]
        if extra:
            return (f'{mode}: {", ".join(extra)} (expected {0 if n_js else 1}) on ROS_DOMAIN_ID='
                    f'{domain} before the loop started: another run or node shares this domain; '
                    'give each run its own ROS_DOMAIN_ID')
        missing = [n for n, topic in topics.items() if comp.publisher_count(topic) < 1]
        now = time.monotonic()
        if not missing:
            settled_since = now if settled_since is None else settled_since
            if now - settled_since >= DISCOVERY_SETTLE_S:
                return None
            continue
        settled_since = None
        for name in missing:
            if name in outside and now > t0 + external_timeout:
                from cvj_ros.nodes.peers import wrong_type_reason
                wrong = wrong_type_reason(getattr(comp.recorder, 'node', None), outside[name],
                                          topics[name], domain, external_timeout)
                if wrong:
                    return wrong
                return (f'--external {outside[name]}: no outside node published {topics[name]} '
                        f'on ROS_DOMAIN_ID={domain} within --external-timeout={external_timeout:g} s')
        if now > t0 + timeout and any(n not in outside for n in missing):
            name = next(n for n in missing if n not in outside)
            return f'{name}: {topics[name]} not connected within {timeout:g} s'
    return None


def _drain(comp: ComposedDriveline, *, expected: dict[str, int], idle: float, bound: float) -> None:
    """Spin until the recorder has ``expected`` counts, or no message for ``idle`` s; <= ``bound`` s."""
    start = time.monotonic()
    deadline = start + bound
    rec = comp.recorder
    while time.monotonic() < deadline:
        counts = rec.counts
        if expected and all(counts.get(t, 0) >= n for t, n in expected.items()):
            return
        if time.monotonic() - max(rec.last_message_wall, start) > idle:
            return
        comp.spin_for(0.02)


def run_composed(options: Any, *, stream: TextIO | None = None) -> Any:
    """``cvj-sim run --composed``: the run of :func:`cvj_ros.orchestrate.run` with every node
    and the recorder inside this process on one executor; returns the RunResult (also in
    ``OUT/report.json``, with ``settings.process = composed`` and the executor used).

    The DDS settings of the node processes (:func:`cvj_ros.nodes.qos.dds_environment`:
    synchronous publication, the 20 ms heartbeat profile, localhost discovery) and
    ``ROS_LOG_DIR=OUT/logs/ros`` (the nodes' log files; nothing on the console) are put
    into this process's environment for the run and restored after it.
    """
    from cvj_ros import bag as bagmod
    from cvj_ros import orchestrate as orch
    stream = sys.stdout if stream is None else stream
    prep = orch.prepare(options)
    compiled_s = orch.prepare_kernel(prep, options)   # a cold kernel: both halves at once
    env, domain = orch._domain_env()
    out = Path(options.out)
    for entry in orch.RUN_ENTRIES:   # --overwrite removes the previous run's files, nothing else
        path = out / entry
        if path.is_dir():
            shutil.rmtree(path)
        elif path.exists():
            path.unlink()
    logs = out / 'logs'
    logs.mkdir(parents=True, exist_ok=True)
    env['ROS_LOG_DIR'] = str(logs / 'ros')
    from cvj_ros.nodes.qos import dds_environment
    dds_environment(env, profile_dir=str(out))
    load_override = None
    if prep.load_series is not None:
        import numpy as np
        load_override = out / 'load_override.npz'
        np.savez(load_override, t=prep.load_series[0], torque=prep.load_series[1])

    saved_env = {k: os.environ.get(k) for k in env}
    os.environ.update(env)
    stop_signal: list[int] = []
    previous: dict[int, Any] = {}
    comp: ComposedDriveline | None = None

    def on_signal(signum: int, _frame: Any) -> None:
        # only flags here: the coupling node reads stop_signal at every exchange and stops at
        # the one in progress (CouplingNode.stop_signal); the container's timer ends a spin that
        # no exchange would end (peers not connected yet, a stalled loop)
        stop_signal.append(signum)
        if comp is not None:
            comp.wake_from_signal()
    in_main = threading.current_thread() is threading.main_thread()
    if in_main:
        for sig in (signal.SIGINT, signal.SIGTERM):
            previous[sig] = signal.signal(sig, on_signal)

    wall0 = time.monotonic() if options.started is None else options.started
    phases: dict[str, float] = {}

    def mark(name: str) -> None:
        phases[name] = round(time.monotonic() - wall0, 4)
    if compiled_s:
        phases['kernel_compile_s'] = compiled_s
    writer = orch.open_run_bag(options, prep, out, extra=(('cvj_ros.process', 'composed'),))
    foreign_dropped: dict[str, int] = {}
    malformed_dropped: dict[str, int] = {}
    steps = int(round(prep.duration / prep.exchange_step))
    executor_kind, executor_note = resolve_executor(options.executor, steps)
    error: str | None = None
    stopped_by: str | None = None
    ctx = None
    exit_codes: dict[str, int | None] = {}
    rec_state = None
    from cvj_ros.progress import Progress
    progress = Progress(prep.duration, label='cvj-sim run')
    import rclpy
    from rclpy.context import Context
    from rclpy.signals import SignalHandlerOptions
    try:
        ctx = Context()
        # console logs off (they would interleave with the report); the log files stay in
        # ROS_LOG_DIR; rcl logging is set up once per process, so this holds for the first run
        rclpy.init(args=['--ros-args', '--disable-stdout-logs'], context=ctx, domain_id=domain,
                   signal_handler_options=SignalHandlerOptions.NO)
        comp = ComposedDriveline(ctx, executor=executor_kind, hosted=prep.nodes,
                                 intra_process=getattr(options, 'intra_process', True))
        comp.add_recorder(writer, prep.coupling_topics,
                          hold=tuple(orch.LOOP_TOPICS) + tuple(prep.coupling_topics))
        comp.recorder.set_command_stamps(orch.command_record_stamps(prep))
        for name in prep.nodes:
            if stop_signal or error is not None:
                break
            if name == 'coupling_node':
                if options.external:
                    progress.clear()
                    print(orch.external_wait_line(options.external, domain, options.external_timeout,
                                                  prep.peers),
                          file=stream, flush=True)
                error = _wait_for_peers(comp, lambda: bool(stop_signal), timeout=options.start_timeout,
                                        mode=options.mode, domain=domain,
                                        external=options.external,
                                        external_timeout=options.external_timeout, peers=prep.peers)
                mark('peers_connected')
                if error is not None or stop_signal:
                    break
                comp.recorder.hold = frozenset()
            params = orch.node_parameters(prep, name, load_override=load_override)
            try:
                node = comp.add_node(name, cli_args=orch._ros_args(params))
            except CvjError as exc:   # bad parameter: the line the node's own process prints
                error = f'{name}: error: {exc}'
            else:
                if name == 'coupling_node':   # stop at the exchange in progress on a signal
                    node.stop_signal = lambda: stop_signal[0] if stop_signal else 0
        coupling = comp.nodes.get('coupling_node')
        js = bagmod.JOINT_STATES_TOPIC

        def loop_started() -> None:
            # step 0 is out (the hosted recorder takes it through the in-process bus): the
            # loop's start, marked when it happens rather than at the next progress tick
            mark('loop_started')
            print(f'cvj-sim run: loop running in one process (domain {domain}, '
                  f'{comp.executor_kind} executor), recording to {out / "bag"}',
                  file=stream, flush=True)
        if coupling is not None:
            coupling.on_started = loop_started

        def on_tick() -> None:
            states = comp.recorder.counts.get(js, 0)
            if states:
                progress.update((states - 1) * prep.exchange_step)
        for note in (executor_note, comp.executor_note):
            if note:
                print(f'cvj-sim run: {note}', file=stream, flush=True)
        if coupling is not None and error is None:
            from cvj_ros.nodes.executor import freeze_heap
            freeze_heap()
            comp.spin_until_done(coupling, stop=lambda: bool(stop_signal), on_tick=on_tick)
        progress.close()
        mark('coupling_exited')
        if 'loop_started' in phases:
            print(orch.loop_ended_line(phases), file=stream, flush=True)
        if comp.recorder is not None:   # later /clock beyond our last state: another run's
            comp.recorder.loop_ended = True
        if error is None:
            error = comp.failed()
        if stop_signal or error is not None or coupling is None:
            if stop_signal:
                stopped_by = {signal.SIGINT: 'SIGINT', signal.SIGTERM: 'SIGTERM'}.get(
                    stop_signal[0], str(stop_signal[0]))
            # the loop has stopped: the answers to its last state and its /clock, in flight
            n_js = comp.recorder.counts.get(js, 0)
            _drain(comp, expected={t: n_js for t in (bagmod.CLOCK_TOPIC, *orch.PEER_TOPICS.values())}
                   if n_js and options.mode == 'lockstep' and coupling is not None
                   and coupling.exit_code is not None else {}, idle=0.3, bound=1.0)
        else:
            lockstep_ok = coupling.exit_code == 0 and options.mode == 'lockstep'
            # lockstep: N+1 states and clocks, and the peers' answers to the final state
            _drain(comp, expected={t: steps + 1 for t in (bagmod.CLOCK_TOPIC, js,
                                                          *orch.PEER_TOPICS.values())}
                   if lockstep_ok else {}, idle=2.0 if lockstep_ok else 0.5, bound=5.0)
        mark('drained')
    finally:
        progress.close()
        try:
            if comp is not None:
                exit_codes = {n: node.exit_code for n, node in comp.nodes.items()}
                if comp.recorder is not None:
                    comp.settle()
                    rec_state = (dict(comp.recorder.first_wall), dict(comp.recorder.last_wall))
                    foreign_dropped = dict(comp.recorder.foreign)
                    malformed_dropped = comp.recorder.malformed
                comp.destroy()
        finally:
            if ctx is not None and ctx.ok():
                rclpy.shutdown(context=ctx)
            writer.close()
            for k, v in saved_env.items():
                if v is None:
                    os.environ.pop(k, None)
                else:
                    os.environ[k] = v
            if in_main:
                for sig, handler in previous.items():
                    signal.signal(sig, handler)
    mark('bag_closed')
    if stop_signal:
        code = 130 if stop_signal[0] == signal.SIGINT else 128 + int(stop_signal[0])
    elif error is not None:
        code = 1
    else:
        code = 0
    return _finish(orch, options, prep, out, domain, code=code, error=error, stopped_by=stopped_by,
                   counts=dict(writer.counts), rec_state=rec_state, exit_codes=exit_codes,
                   phases=phases, wall=time.monotonic() - wall0, steps=steps, stream=stream,
                   executor=comp.executor_kind if comp is not None else executor_kind,
                   foreign_dropped=foreign_dropped, malformed_dropped=malformed_dropped)


def _finish(orch: Any, options: Any, prep: Any, out: Path, domain: int, *, code: int,
            error: str | None, stopped_by: str | None, counts: dict[str, int],
            rec_state: Any, exit_codes: dict[str, int | None], phases: dict[str, float],
            wall: float, steps: int, stream: TextIO, executor: str,
            foreign_dropped: dict[str, int], malformed_dropped: dict[str, int]) -> Any:
    """RunResult, metrics, report.json and the printed report (as the tail of orchestrate.run)."""
    result = orch.result_from_recording(
        options, prep, out, domain, code=code, error=error, stopped_by=stopped_by, counts=counts,
        rec_state=rec_state, exit_codes=exit_codes, phases=phases, wall=wall, steps=steps)
    return orch.finish_result(result, options, prep, stream=stream,
                              foreign_dropped=foreign_dropped, malformed_dropped=malformed_dropped,
                              settings={'process': 'composed', 'executor': executor})


# --- driveline_composed console script -------------------------------------------------------

def _parse_args(argv: Sequence[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        prog=PROG, description='Host engine_node, load_node, monitor_node and coupling_node in one '
        'process on one executor (composed mode). ROS parameters after --ros-args (-p NAME:=VALUE '
        'or --params-file) go to every hosted node; each node takes the parameters it declares.',
        epilog='example: driveline_composed --ros-args -p scene:=kavz685_lever -p exchange_step:=0.001')
    parser.add_argument('--without', action='append', default=[], choices=HOSTED_NODES,
                        metavar='NODE', help='leave NODE out (it runs alone or an outside node '
                        'answers instead); repeatable')
    parser.add_argument('--record', type=Path, default=None, metavar='DIR',
                        help='also record a bag to DIR (must not exist) from inside the process')
    parser.add_argument('--storage', choices=('mcap', 'sqlite3'), default='mcap')
    parser.add_argument('--executor', choices=EXECUTORS, default='events',
                        help='events (default; falls back to single if unavailable), single, or '
                             'auto (here: single, flat memory for a container that runs until stopped)')
    parser.add_argument('--no-intra-process', dest='intra_process', action='store_false',
                        help='hand the loop topics to the hosted nodes through DDS too, instead '
                             'of in-process (slower; for comparison)')
    return parser.parse_args(list(argv))


def _user_sets(argv: Sequence[str], param: str) -> bool:
    """Whether ``argv``'s ROS arguments set ``param`` (``-p``/``--param NAME:=V`` or a
    ``--params-file`` that names it)."""
    tokens = list(argv)
    for i, tok in enumerate(tokens[:-1]):
        nxt = tokens[i + 1]
        if tok in ('-p', '--param') and nxt.split(':=', 1)[0].rsplit(':', 1)[-1] == param:
            return True
        if tok == '--params-file':
            try:
                if param in Path(nxt).read_text(errors='replace'):
                    return True
            except OSError:
                pass
    return False


def _default_min_subscribers(argv: Sequence[str], opts: argparse.Namespace) -> list[str] | None:
    """The hosted coupling node's ``min_subscribers`` when the user gives none: engine and
    load (hosted or outside), the hosted monitor and the ``--record`` recorder, instead of
    the node's hand-start default (which counts a monitor and a recorder of their own)."""
    if _user_sets(argv, 'min_subscribers'):
        return None
    n = 2 + ('monitor_node' not in opts.without) + (opts.record is not None)
    return ['--ros-args', '-p', f'min_subscribers:={n}']


def _main(args: Sequence[str] | None) -> int:
    import rclpy
    from rclpy.context import Context
    from rclpy.signals import SignalHandlerOptions
    from rclpy.utilities import remove_ros_args

    from cvj_ros.nodes.parameters import EXIT_OK, EXIT_PARAMETER
    argv = list(sys.argv if args is None else [PROG, *args])
    opts = _parse_args(remove_ros_args(argv)[1:])
    if opts.record is not None and opts.record.exists():
        raise CvjError(f'--record: {opts.record} exists')
    from cvj_ros.nodes.qos import domain_id
    domain_id()             # a bad ROS_DOMAIN_ID: one line, before DDS logs its own
    ctx = Context()
    rclpy.init(args=argv, context=ctx, signal_handler_options=SignalHandlerOptions.NO)
    stop: list[int] = []
    comp = ComposedDriveline(ctx, executor=opts.executor,
                             hosted=[n for n in HOSTED_NODES if n not in opts.without],
                             intra_process=opts.intra_process)

    def on_signal(signum: int, _frame: Any) -> None:
        stop.append(signum)              # flags only, as in run_composed
        comp.wake_from_signal()
    previous = {sig: signal.signal(sig, on_signal) for sig in (signal.SIGINT, signal.SIGTERM)}
    writer = None
    try:
        if comp.executor_note:
            print(f'{PROG}: {comp.executor_note}', file=sys.stderr)
        if opts.record is not None:
            from cvj_ros import bag as bagmod
            writer = bagmod.BagWriter(opts.record, storage=opts.storage)
            comp.add_recorder(writer)
        for name in HOSTED_NODES:
            if name in opts.without:
                continue
            try:
                node = comp.add_node(name, cli_args=_default_min_subscribers(argv, opts)
                              if name == 'coupling_node' else None)
            except CvjError as exc:
                print(f'{PROG}: error: {name}: {exc}', file=sys.stderr)
                return EXIT_PARAMETER
            if name == 'coupling_node':       # stop at the exchange in progress on a signal
                node.stop_signal = lambda: stop[0] if stop else 0
        done = comp.nodes.get('coupling_node')
        if done is None:   # no loop owner here: serve until Ctrl-C or a node fails
            while ctx.ok() and not stop and comp.failed() is None:
                comp.spin_for(0.25)
        else:
            from cvj_ros.nodes.executor import freeze_heap
            freeze_heap()
            comp.spin_until_done(done, stop=lambda: bool(stop))
            if comp.recorder is not None:
                _drain(comp, expected={}, idle=0.5, bound=5.0)
        failed = comp.failed()
        if failed is not None and not stop:
            return next(n.exit_code for n in comp.nodes.values() if n.exit_code not in (None, 0))
        return EXIT_OK
    finally:
        comp.destroy()
        if ctx.ok():
            rclpy.shutdown(context=ctx)
        if writer is not None:
            writer.close()
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def main(args: Sequence[str] | None = None) -> None:
    """Console script ``driveline_composed`` (exit 0 finished or stopped by Ctrl-C/SIGTERM,
    1 runtime error, 2 bad parameter: one line on stderr, no traceback)."""
    from cvj_ros.guard import guarded
    sys.exit(int(guarded(PROG, lambda: _main(args))))


if __name__ == '__main__':
    main()
