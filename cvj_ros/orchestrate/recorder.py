"""The run's bag (:func:`open_run_bag`), the in-process recorder and the start-up handshake: which peers must be up before the
coupling node starts, and when another run on the domain refuses this one."""
from __future__ import annotations

import os
import subprocess
import threading
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from cvj_ros import bag as bagmod
from cvj_ros.orchestrate.options import EXTERNAL_PEERS  # noqa: F401  (re-exported)
from cvj_ros.orchestrate.processes import error_line


# The recorder's take loop sleeps this long after each wake that took messages (s): one wake
# then takes the messages of many exchange steps instead of one message, and the recorder's
# process (which also hosts the monitor) competes less with the loop's processes for the
# cores. Measured (separate processes, kavz685_lever 5 s, 3 alternating pairs, /proc
# per-thread CPU): 0 -> 2 ms took the recorder thread from 149-164 to 79-108 us CPU per
# exchange step; 2 -> 20 ms (fwd_halfshaft 5 s, 3 alternating pairs, 2026-11-24): real-time
# factor 2.05-2.30 -> 2.32 (all three), state publication 97-114 -> 79-90 us per exchange.
# The bag is then up to ~20 ms behind the loop (stamps are the messages' own, not arrival
# times); RECORDER_QOS's depth holds 10 s; a stop takes what is queued (the last take of
# BagRecorder.spin).
RECORDER_COALESCE_S = 0.02

# Nodes `cvj-sim run` hosts in its own process, beside the recorder, instead of one process
# each: the observers, which read every loop message the recorder reads. As a process of its
# own the monitor took three more inter-process deliveries per exchange and a fifth process
# on two cores. Hosted, its subscriptions of the topics the recorder records are fed from the
# recorder's (intra.RecorderFeed): every sample is taken from DDS once, in the recorder thread.
# Measured (kavz685_lever 5 s, h = 1 ms, alternating pairs, /proc CPU): docs/nodes.md,
# "Separate processes: the monitor beside the recorder". The loop nodes keep their processes.
HOSTED_IN_RUN = ('monitor_node',)


# The topics whose flushed record time /driveline/recorded reports (the oldest of them): the
# loop's own, one message per exchange each.
GATE_TOPICS = frozenset({bagmod.JOINT_STATES_TOPIC, bagmod.CLOCK_TOPIC, '/engine/wrench',
                         '/load/wrench'})


# The recorder asks its writer to flush at a hand-off whose newest loop message is this far
# (s of record time) past what is on disk: 0 = at every hand-off, i.e. once per wake of the
# take loop. The gate (record_lag_max = MAX_LAG_S) holds the loop while it is more than
# 0.15 s past the disk; between two flushes the disk falls behind by this lead plus one
# wake's worth of loop (RECORDER_COALESCE_S of wall time = 0.05 s of record time at 2.5x
# real time) plus the take and the flush. With the lead at 0.1 s that reached 0.15 s at
# about 2x real time on an idle machine, so the gate held an unloaded loop every few wakes
# (docs/benchmark.md, "Lockstep in separate processes: the recorder gate (2026-11-28)").
# A flush closes the mcap chunk (fsync still at most every FLUSH_WALL_S) or commits the
# sqlite3 transaction: writer thread CPU per exchange unchanged within the spread.
RECORDER_FLUSH_LAG_S = 0.0


def recorder_front(writer: bagmod.BagWriter) -> bagmod.BatchingWriter:
    """The recorder's front of ``writer``: one hand-off per wake of the take loop, and a flush
    requested at each hand-off that is :data:`RECORDER_FLUSH_LAG_S` past the disk (measured
    on the loop topics, :data:`GATE_TOPICS`)."""
    return bagmod.BatchingWriter(writer, flush_lag_s=RECORDER_FLUSH_LAG_S, lag_topics=GATE_TOPICS)


class _Recorder:
    """BagRecorder on its own rclpy context, taking messages in a background thread of this process."""

    def __init__(self, writer: bagmod.BagWriter, topics: Sequence[str], domain_id: int, *,
                 hold: Sequence[str] = (), run_only: bool = True) -> None:
        import rclpy
        from rclpy.signals import SignalHandlerOptions
        self.ctx = rclpy.context.Context()
        rclpy.init(context=self.ctx, domain_id=domain_id,
                   signal_handler_options=SignalHandlerOptions.NO)
        self.node = rclpy.create_node('cvj_recorder', context=self.ctx)
        # one hand-off to the writer thread per wake of the take loop, not one per message
        self.batching = recorder_front(writer)
        self.recorder = bagmod.BagRecorder(self.node, self.batching, topics=topics, run_only=run_only)
        self.recorder.hold = frozenset(hold)     # before the first message can arrive
        self._stop = threading.Event()
        # what the bag holds on disk, for the coupling node's recorder gate (record_lag_max)
        from rosgraph_msgs.msg import Clock

        from cvj_ros.nodes.qos import LATCHED_QOS, RECORDED_TOPIC
        self.writer = writer
        self.recorded_pub = self.node.create_publisher(Clock, RECORDED_TOPIC, LATCHED_QOS)
        self.recorded_thread = threading.Thread(target=self._report_recorded, name='recorded',
                                                daemon=True)
        self.recorded_thread.start()
        self.hosted: dict[str, tuple[Any, Any]] = {}     # name -> (node, executor): see host()
        self.host_errors: dict[str, str] = {}
        self.feeds: dict[str, Any] = {}       # name -> its subscriptions' intra.RecorderFeed
        self._hosted_threads: list[threading.Thread] = []
        self.thread = threading.Thread(target=self._spin, name='recorder', daemon=True)
        self.thread.start()

    def _spin(self) -> None:
        # BagRecorder.spin takes every queued sample per wake. Executors were measured too slow
        # or lossy here: SingleThreadedExecutor fell ~0.7 s behind a 200-step run, and
        # rclpy.experimental.EventsExecutor left samples unread (24 of 101 joint states).
        self.recorder.spin(self._stop, coalesce=RECORDER_COALESCE_S)

    def _report_recorded(self) -> None:
        """Publish on ``/driveline/recorded`` the record time (ns, as a Clock) up to which the
        bag is on the OS side, each time it advances: the coupling node's recorder gate
        (``record_lag_max``) waits for it. The time is the oldest of the loop topics' newest
        flushed stamps (:data:`GATE_TOPICS`, :attr:`BagWriter.durable_topics`): a topic whose
        samples reach the recorder late (a repaired joint state) holds it back, not the
        newest /clock. Woken by the writer thread's flush (no polling delay on the loop's
        critical path). It waits for the writer's next flush (:meth:`BagWriter.wait_flush`),
        not for a newer stamp of any topic: that one is usually in already (/clock t_(k+1) is
        ahead of the answers for t_k), and waiting for it made this loop spin (measured,
        kavz685_lever 5 s at load 4-6: 160-300 us of CPU per exchange beside the loop)."""
        from rosgraph_msgs.msg import Clock
        sent = -1
        flushes = 0
        msg = Clock()
        while not self._stop.is_set() and self.ctx.ok():
            flushes = self.writer.wait_flush(flushes, 0.1)
            if not self.writer._thread.is_alive():
                return             # closed
            now = self.writer.durable_ns
            if now >= 2**63 - 1:
                return             # the writer failed: nothing more reaches the disk
            loop = [v for t, v in self.writer.durable_topics.items() if t in GATE_TOPICS]
            now = min(loop) if loop else -1
            if now <= sent:
                continue
            msg.clock.sec, msg.clock.nanosec = divmod(now, 1_000_000_000)
            try:
                self.recorded_pub.publish(msg)
            except Exception:  # noqa: BLE001 (context shut down while closing)
                return
            sent = now

    def host(self, name: str, cli_args: Sequence[str], *, log: Path | None = None) -> None:
        """Create node ``name`` (:func:`cvj_ros.composed.node_class`, its own ``--ros-args``)
        on the recorder's context and spin it on its own EventsExecutor in a thread of this
        process (:data:`HOSTED_IN_RUN`). Its subscriptions of topics the recorder subscribes
        to are fed by the recorder (:class:`cvj_ros.nodes.intra.RecorderFeed`: no DDS reader
        of its own, the callbacks run in the recorder thread); its other subscriptions, its publishers,
        parameters and services are its own, served by its executor.

        Raises CvjError (a bad parameter, naming it) as the node's own process would exit 2.
        A callback's exception (in either thread) ends the node: :attr:`host_errors` holds
        the line (also written to ``log``), the run goes on as it would without that process."""
        from cvj_ros.composed import make_composed_executor, node_class
        from cvj_ros.nodes import intra
        feed = intra.RecorderFeed(self.recorder, name, self.recorder._subs,
                            on_error=lambda n, exc: self._host_failed(n, exc, log))
        intra.attach(self.ctx, feed)      # its subscriptions of recorded topics: fed, no DDS reader
        try:
            node = node_class(name)(context=self.ctx, cli_args=list(cli_args))
        finally:
            intra.detach(self.ctx)
        self.feeds[name] = feed
        executor, _kind, _note = make_composed_executor('events', self.ctx)
        executor.add_node(node)
        self.hosted[name] = (node, executor)
        thread = threading.Thread(target=self._spin_hosted, args=(name, node, executor, log),
                                  name=name[:15], daemon=True)
        self._hosted_threads.append(thread)
        thread.start()

    def _spin_hosted(self, name: str, node: Any, executor: Any, log: Path | None) -> None:
        from rclpy.task import Future
        never = Future()      # spin inside the executor (no per-event Python loop), 0.1 s wakes
        try:
            while not self._stop.is_set() and self.ctx.ok():
                executor.spin_until_future_complete(never, timeout_sec=0.1)
        except Exception as exc:  # noqa: BLE001 (the node's callback failed: its process would exit 1)
            if self._stop.is_set() or not self.ctx.ok():
                return          # shutting down
            self._host_failed(name, exc, log)

    def _host_failed(self, name: str, exc: BaseException, log: Path | None) -> None:
        """A hosted node's callback raised (in its executor thread or, fed, in the recorder
        thread): the line in :attr:`host_errors` and its log; the node gets nothing more."""
        line = f'{name}: {type(exc).__name__}: {exc}'
        self.host_errors.setdefault(name, line)
        feed = self.feeds.get(name)
        if feed is not None:
            feed.stop()
        if log is not None:
            try:
                with open(log, 'a', encoding='utf-8') as fh:
                    fh.write(line + '\n')
            except OSError:
                pass

    def hosted_exit_codes(self) -> dict[str, int]:
        """What the hosted nodes' processes would have exited with: 1 after an error, else 0."""
        return {name: 1 if name in self.host_errors else 0 for name in self.hosted}

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
        for thread in self._hosted_threads:
            thread.join(2.0)
        self.thread.join(2.0)
        self.recorded_thread.join(2.0)
        for (node, executor), thread in zip(self.hosted.values(), self._hosted_threads):
            # bounded: a CI run (OPENBLAS_CORETYPE=Haswell, two refused runs started together)
            # left one cvj-sim hanging after the refusal, where is not known; this wait and
            # the spin thread's are the unbounded ones the hosted node added
            try:
                if not thread.is_alive():
                    executor.remove_node(node)
                executor.shutdown(timeout_sec=1.0)
            finally:
                node.destroy_node()
        try:
            self.recorder.destroy()
            self.node.destroy_node()
        finally:
            self.batching.flush()      # what the last wake (or destroy) collected
            if self.ctx.ok():
                rclpy.shutdown(context=self.ctx)


PEER_TOPICS = {'engine_node': '/engine/wrench', 'load_node': '/load/wrench'}
# How long "our peers are up, nobody else is" must hold before the loop starts (s), both modes.
# The recorder's participant exists from before the peers were started (>= ~1 s of process
# start), so another run's endpoints have usually been discovered already; this covers a
# slow discovery under load at the cost of 0.3 s per run.
DISCOVERY_SETTLE_S = 0.3
LOOP_TOPICS = (bagmod.JOINT_STATES_TOPIC, bagmod.CLOCK_TOPIC, bagmod.SCENE_TOPIC,
               '/engine/wrench', '/load/wrench', '/engine/throttle_scale')
def command_record_stamps(prep: Any) -> dict[str, list[int]]:
    """Record times (ns) of the command samples the run's driver_node plays, per topic
    (:meth:`cvj_ros.bag.BagRecorder.set_command_stamps`): each at the time t_k of its step,
    the same in composed and separate processes; none when no driver plays (an outside
    stack's samples are recorded at the latest /clock). In lockstep the coupling node's
    /engine/throttle_scale (a shift schedule's) has one sample per step, the n-th at t_n."""
    from cvj_ros.nodes.command_plan import NS_PER_S, CommandPlan, throttle_scale_stamps
    h_ns = int(round(prep.exchange_step * NS_PER_S))
    n_steps = int(round(prep.duration * NS_PER_S / h_ns))
    out = (CommandPlan.from_scene(prep.scene, h_ns, n_steps).record_stamps()
           if 'driver_node' in prep.nodes else {})
    if prep.options.mode == 'lockstep':
        out.update(throttle_scale_stamps(prep.scene, h_ns, n_steps))
    return out


# --external NAME: (the node it replaces, what the outside node must publish)


def external_wait_line(external: Sequence[str], domain: int, timeout: float,
                       peers: tuple[dict[str, str], dict[str, str]] | None = None) -> str:
    """The one line printed while a run waits for outside peers: which topic, what to publish
    (``peers``: a vehicle scene's, orchestrate.vehicle.vehicle_peers)."""
    parts = [f'{PEER_TOPICS[EXTERNAL_PEERS[e][0]]} ({EXTERNAL_PEERS[e][1]})' for e in external
             if e in EXTERNAL_PEERS and (peers is None or e != 'load')]
    if peers is not None:
        parts.append(f'{", ".join(t for n, t in peers[0].items() if peers[1].get(n) == "load")} '
                     '(each wheel\'s resisting torque, torque.z in N m (positive opposes positive rotation))')
    if any(e not in EXTERNAL_PEERS for e in external):   # --external driver: not awaited
        parts.append('(when it likes) /engine/throttle, /driveline/clutch, /driveline/gear, '
                     '/driveline/brake (the commands; docs/ros.md, "Commands")')
    return (f'cvj-sim run: waiting up to {timeout:g} s for an outside node on ROS_DOMAIN_ID={domain} '
            f'to publish {" and ".join(parts)}: subscribe to /driveline/joint_states and answer '
            f'every message with a geometry_msgs/WrenchStamped whose header.stamp '
            f'echoes the joint state\'s (docs/ros.md, "Outside nodes")')


def _wait_for_peers(recorder: _Recorder, procs: dict[str, subprocess.Popen[bytes]], logs: Path,
                    stop_signal: list[int], timeout: float, *, mode: str = 'lockstep',
                    domain: int | None = None, external: Sequence[str] = (),
                    external_timeout: float = 30.0,
                    peers: tuple[dict[str, str], dict[str, str]] | None = None) -> str | None:
    """Wait until the recorder matched engine/load publishers (``peers``: a vehicle scene's
    engine and per-wheel outside loads, orchestrate.vehicle.vehicle_peers); an error line if a
    peer died or ``timeout`` (s; ``external_timeout`` for outside peers) passed, else None."""
    t0 = time.monotonic()
    deadline = t0 + timeout
    topics, outside = peers if peers is not None else (
        PEER_TOPICS, {EXTERNAL_PEERS[e][0]: e for e in external if e in EXTERNAL_PEERS})
    settled_since: float | None = None
    dom = domain if domain is not None else os.environ.get('ROS_DOMAIN_ID', '0')
    while not stop_signal:
        for name, proc in procs.items():   # any node (the gated coupling node too) that died
            rc = proc.poll()
            if rc is not None:
                return f'{name}: ' + (error_line(logs / f'{name}.log') or f'exited with status {rc}')
        # another run on this domain: stop before our coupling node publishes a single state
        # into the other run's bag (its own watchdog can take 0.25 s and more under load).
        # Our coupling node waits at its start gate (no endpoints), so any joint-state publisher is another run's;
        # engine/load counts alone cannot tell: the other run's peers, discovered before ours
        # start, made a count of 1 look like "our peer is up" (measured: the second run then
        # started and mixed into the first one's bag).
        n_js = recorder.publisher_count(bagmod.JOINT_STATES_TOPIC)
        extra = ([f'{bagmod.JOINT_STATES_TOPIC} has {n_js} publishers'] if n_js > 0 else []) + \
            [f'{topic} has {n} publishers' for topic in topics.values()
             if (n := recorder.publisher_count(topic)) > 1]
        if extra:
            return (f'{mode}: {", ".join(extra)} (expected {0 if n_js else 1}) on ROS_DOMAIN_ID='
                    f'{dom} before the loop started: another run or '
                    'node shares this domain; give each run its own ROS_DOMAIN_ID')
        missing = [n for n, topic in topics.items() if recorder.publisher_count(topic) < 1]
        if not missing:
            # hold the all-clear for DISCOVERY_SETTLE_S: endpoints of another run on the
            # domain may still be arriving
            now = time.monotonic()
            settled_since = now if settled_since is None else settled_since
            if now - settled_since >= DISCOVERY_SETTLE_S:
                return None
            time.sleep(0.02)
            continue
        settled_since = None
        now = time.monotonic()
        for name in missing:
            if name in outside and now > t0 + external_timeout:
                from cvj_ros.nodes.peers import wrong_type_reason
                wrong = wrong_type_reason(getattr(recorder.recorder, 'node', None), outside[name],
                                          topics[name], domain, external_timeout)
                if wrong:
                    return wrong
                return (f'--external {outside[name]}: no outside node published {topics[name]} '
                        f'on ROS_DOMAIN_ID={domain} within --external-timeout={external_timeout:g} s; '
                        f'start it on that domain (e.g. ROS_DOMAIN_ID={domain} .venv/bin/python '
                        f'examples/vehicle_stack.py --ros-args -p use_sim_time:=true)')
        if now > deadline and any(name not in outside for name in missing):
            name = next(n for n in missing if n not in outside)
            return f'{name}: {topics[name]} not connected within {timeout:g} s'
        time.sleep(0.02)
    return None


def open_run_bag(options: Any, prep: Any, out: Path, *,
                 extra: Sequence[tuple[str, str]] = ()) -> bagmod.BagWriter:
    """The run's bag writer at ``out/bag`` with the run's metadata (scene, mode, scheme, seed,
    duration, exchange step, outside nodes, ``extra`` pairs): nothing random, so two runs of
    one scene and seed write the same bytes."""
    writer = bagmod.BagWriter(out / 'bag', storage=options.storage)
    for key, value in (('cvj_ros.scene_path', str(prep.scene_path)), ('cvj_ros.mode', options.mode),
                       ('cvj_ros.coupling_scheme', options.scheme),
                       ('cvj_ros.seed', '' if prep.seed is None else str(prep.seed)),
                       ('cvj_ros.duration', repr(prep.duration)),
                       ('cvj_ros.exchange_step', repr(prep.exchange_step)),
                       ('cvj_ros.external', ','.join(options.external)), *extra):
        writer.set_custom_data(key, value)
    return writer
