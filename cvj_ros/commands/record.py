"""`cvj-sim record OUT`: the run recorder standalone, for nodes started by hand or by a launch file.

The same recorder ``cvj-sim run`` uses (:class:`cvj_ros.bag.BagRecorder`: raw CDR, record
time = the message's simulated stamp, every contract topic plus ``/coupling/*/wrench`` and
``/load/*/wrench`` as they appear, the latched ``/driveline/scene`` message stored in the bag and in its
metadata). It records on the current ``ROS_DOMAIN_ID`` until Ctrl-C / SIGTERM, until
``--duration`` wall seconds have passed, or (``--until-idle S``) until nothing arrived for
S seconds after the first message and the run's coupling node (``--coupling-node``, by its
fully qualified node name) no longer publishes joint states on the graph (up to
BEHIND_WAIT_S more while the joint states, /clock or an answer topic end before the others:
their last messages are still on the way); on every one
of these paths the bag is finalised
(metadata.yaml written), so everything recorded stays readable.
"""
from __future__ import annotations

import argparse
import math
import os
import re
import signal
import sys
import time
from pathlib import Path
from typing import Any

from cvj_ros.errors import CvjError

NAME = 'record'
HELP = 'record the driveline topics of nodes started elsewhere to a bag'
DESCRIPTION = """Record every cvj_ros topic on this ROS domain to a rosbag2 bag (mcap or sqlite3),
for nodes started by hand (`ros2 run` / console scripts) or by launch/driveline.launch.py.
Stops on Ctrl-C or SIGTERM (bag finalised, exit 0), after --duration wall seconds, or
with --until-idle S once no message arrived for S seconds and the run's coupling node
(--coupling-node, default /coupling_node) has left the graph (a loop that pauses - a coupling
node compiling or starved of the CPU - is waited for; another node's joint-state publisher
is not).

examples:
  cvj-sim record runs/manual                      # Ctrl-C to stop
  cvj-sim record runs/manual --storage sqlite3 --until-idle 2
"""


# The coupling node's fully qualified name in every run the project starts: cvj-sim run
# (separate processes and composed), the launch file (Node(name='coupling_node'), no
# namespace) and the hand-started `ros2 run cvj_ros coupling_node` of the README.
COUPLING_NODE = '/coupling_node'
_NODE_NAME = re.compile(r'(/[A-Za-z_][A-Za-z0-9_]*)+')


def node_name(text: str) -> str:
    """A fully qualified ROS node name (``/coupling_node``, ``/car/coupling_node``; a bare
    ``coupling_node`` is taken in the root namespace). Raises CvjError naming
    --coupling-node otherwise."""
    name = text if text.startswith('/') else '/' + text
    if not _NODE_NAME.fullmatch(name):
        raise CvjError(f'--coupling-node: not a ROS node name (/NAME or /NS/NAME of letters, '
                       f'digits, _): {text!r}')
    return name


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('out', help='output directory; the bag is written to OUT/bag')
    parser.add_argument('--storage', choices=('mcap', 'sqlite3'), default='mcap',
                        help='bag storage (default mcap)')
    parser.add_argument('--overwrite', action='store_true', help='replace an existing OUT/bag')
    parser.add_argument('--duration', type=float, default=None, metavar='S',
                        help='stop after S wall seconds (default: until Ctrl-C)')
    parser.add_argument('--until-idle', type=float, default=None, metavar='S',
                        help='stop once no message arrived for S wall seconds (after the run\'s '
                             'first one; the latched scene message, sent while the coupling node '
                             'still waits for its peers, does not count) and the run\'s coupling '
                             'node (--coupling-node) publishes /driveline/joint_states no more (a '
                             'paused loop is waited for, other publishers are not); up to '
                             '15 s more while the joint states, /clock or an answer topic end '
                             'before the others')
    parser.add_argument('--coupling-node', default=COUPLING_NODE, metavar='NAME',
                        help='fully qualified node name of the run\'s coupling node, which '
                             '--until-idle waits for (default %(default)s: as cvj-sim run, the '
                             'launch file and `ros2 run cvj_ros coupling_node` name it; '
                             '/NS/NAME after -r __ns:=/NS -r __node:=NAME)')
    parser.add_argument('--run-only', action='store_true',
                        help='record one run\'s publishers only: a loop topic\'s messages while it has '
                             'one publisher, /clock attributed by value (docs/ros.md "Run identity"); '
                             'default: every well-formed message')
    parser.add_argument('--topics', nargs='+', default=[], metavar='T',
                        help='extra topics to record at once (contract types); '
                             '/coupling/*/wrench and /load/*/wrench (outside wheel loads) are '
                             'found by themselves')


def _check(args: argparse.Namespace) -> None:
    for opt, value in (('--duration', args.duration), ('--until-idle', args.until_idle)):
        if value is not None and not (math.isfinite(value) and value > 0):
            raise CvjError(f'{opt}: must be a finite number > 0, got {value}')
    args.coupling_node = node_name(args.coupling_node)


# Most wall time one poll of the --until-idle loop counts as idle: a process starved of the
# CPU (seconds, on a loaded machine) has not been able to receive either, so its own pause
# is not silence of the run (a recorder woken after 2 s would otherwise stop before its
# executor took the messages already waiting for it).
IDLE_TICK_MAX_S = 0.1


class IdleClock:
    """Seconds without a new run message, counted only while this process ran: each poll
    adds at most IDLE_TICK_MAX_S; a new message (its wall time changed) resets it; nothing
    counts before the first message."""

    def __init__(self) -> None:
        self.idle = 0.0
        self._seen = 0.0
        self._prev: float | None = None

    def tick(self, now: float, last_message: float) -> float:
        if last_message != self._seen:
            self._seen, self.idle = last_message, 0.0
        elif last_message and self._prev is not None:
            self.idle += min(max(now - self._prev, 0.0), IDLE_TICK_MAX_S)
        self._prev = now
        return self.idle


# --until-idle: how long past S the recorder still waits while the joint states' or a loop
# topic's newest stamp is behind the others'. A reliable DDS writer repairs a lost sample when its reader
# answers the writer's heartbeat, and the reader hands later samples over only in order, so a
# sample lost late in the run (a full receive buffer on a busy machine) holds back the rest of
# its topic until the next heartbeat: Fast DDS sends one every 3 s by default, more than S = 2 s
# (seen: a hand-started run whose bag ended 60 engine, load and coupling answers short, all
# joint states in). Several heartbeat periods, so a repair that is itself lost is waited for.
BEHIND_WAIT_S = 15.0


def loop_topic(topic: str) -> bool:
    """A topic with one message per exchange stamped like the joint state it belongs to:
    /clock and the exchange wrenches (:func:`cvj_ros.bag.exchange_wrench_topic`). Not the
    recorder's one-publisher set (``bag._one_publisher_topic``): that one adds the scene and
    /engine/throttle_scale (one publisher, not one message per exchange) and leaves out
    /clock (attributed by value)."""
    from cvj_ros.bag import exchange_wrench_topic
    return topic == '/clock' or exchange_wrench_topic(topic)


def run_end(last_stamp: dict[str, int]) -> tuple[int, dict[str, int]]:
    """(newest, behind): the newest recorded stamp (ns) of the joint states and the loop
    topics, and those of them whose newest stamp is older, with that stamp: their last
    messages are still on the way (or their publisher stopped). Every exchange t_k has a
    joint state, a /clock and the answers stamped t_k. (0, {}) before the first joint state."""
    stamps = {t: v for t, v in list(last_stamp.items()) if t == '/driveline/joint_states' or loop_topic(t)}
    if '/driveline/joint_states' not in stamps:
        return 0, {}
    newest = max(stamps.values())
    return newest, {t: v for t, v in stamps.items() if v < newest}


def behind_topics(last_stamp: dict[str, int]) -> list[str]:
    """The joint states and loop topics behind the newest of them (:func:`run_end`), sorted."""
    return sorted(run_end(last_stamp)[1])


def idle_stop(idle: float, until_idle: float, behind: list[str], loop_alive: bool = False) -> bool:
    """--until-idle: stop after ``until_idle`` s without a message, unless a topic is
    :func:`behind_topics`; then after ``until_idle`` + BEHIND_WAIT_S. Never while
    ``loop_alive`` (the run's coupling node is still on the graph): the loop has paused - a
    coupling node compiling, swapped out or starved of the CPU -, not ended, and what it
    sends next belongs in the bag."""
    if loop_alive:
        return False
    return idle >= until_idle and (not behind or idle >= until_idle + BEHIND_WAIT_S)


def loop_alive(node: Any, coupling_node: str = COUPLING_NODE) -> bool:
    """The run's coupling node (fully qualified name ``coupling_node``) publishes
    /driveline/joint_states on the graph. Other publishers of that topic (a stack's, a
    replay, a finished run's lingering node) do not count: they would hold the recorder
    forever."""
    from cvj_ros.nodes.qos import JOINT_STATES_TOPIC
    return any(_qualified(info.node_namespace, info.node_name) == coupling_node
               for info in node.get_publishers_info_by_topic(JOINT_STATES_TOPIC))


def _qualified(namespace: str, name: str) -> str:
    return f'{namespace.rstrip("/")}/{name}'


class ReadyAnnouncer:
    """Reports on /driveline/recorder_ready (latched std_msgs/String, JSON ``{"recorder":
    "<node> pid <pid>", "matched": {topic: publishers}}``) how many publishers each of the
    recorder's readers has matched, whenever that changes: the reader's side of a match,
    which a hand-started coupling node compares with the publishers it sees before step 0
    (CouplingNode.recorders_not_ready)."""

    def __init__(self, recorder: Any) -> None:
        from std_msgs.msg import String

        from cvj_ros.nodes.qos import LATCHED_QOS, RECORDER_READY_TOPIC
        self.recorder = recorder
        self.token = f'{recorder.node.get_fully_qualified_name()} pid {os.getpid()}'
        self.sent: dict[str, int] | None = None
        self._string = String
        self._pub = recorder.node.create_publisher(String, RECORDER_READY_TOPIC, LATCHED_QOS)

    def poll(self) -> None:
        import json
        matched = self.recorder.recorder.matched_publishers()
        if matched != self.sent:
            self._pub.publish(self._string(data=json.dumps({'recorder': self.token, 'matched': matched})))
            self.sent = matched


def _last_run_message(rec: Any) -> float:
    """Wall time (monotonic s) of the newest message recorded on any topic but the latched
    /driveline/scene (0 before the first): the coupling node publishes the scene as it
    starts, possibly long before step 0 while it waits for its peers, so --until-idle counts
    from the run's first message instead."""
    from cvj_ros.bag import SCENE_TOPIC
    return max((w for topic, w in list(rec.last_wall.items()) if topic != SCENE_TOPIC), default=0.0)


def run(args: argparse.Namespace) -> int:
    from cvj_ros import bag as bagmod
    from cvj_ros.nodes.qos import domain_id, node_dds_defaults
    _check(args)
    domain = domain_id()
    node_dds_defaults()     # before the recorder's participant: 20 ms heartbeats (repairs)
    out = Path(args.out)
    writer = bagmod.BagWriter(out / 'bag', storage=args.storage, overwrite=args.overwrite)
    writer.set_custom_data('cvj_ros.recorded_by', 'cvj-sim record')
    stop: list[int] = []
    previous: dict[int, Any] = {}

    def on_signal(signum: int, _frame: Any) -> None:
        stop.append(signum)
    for sig in (signal.SIGINT, signal.SIGTERM):
        previous[sig] = signal.signal(sig, on_signal)
    recorder = None
    wall0 = time.monotonic()
    try:
        from cvj_ros.orchestrate import _Recorder
        recorder = _Recorder(writer, list(args.topics), domain, run_only=args.run_only)
        print(f'cvj-sim record: recording domain {domain} to {out / "bag"} '
              f'({args.storage}); Ctrl-C to stop', file=sys.stderr, flush=True)
        ready = ReadyAnnouncer(recorder)
        idle = IdleClock()
        while not stop:
            ready.poll()
            now = time.monotonic()
            if args.duration is not None and now - wall0 >= args.duration:
                break
            if args.until_idle is not None:
                quiet = idle.tick(now, _last_run_message(recorder.recorder))
                if quiet >= args.until_idle and idle_stop(
                        quiet, args.until_idle, behind_topics(recorder.recorder.last_stamp),
                        loop_alive(recorder.node, args.coupling_node)):
                    break
            time.sleep(0.02)
    finally:
        try:
            if recorder is not None:
                recorder.close()
        finally:
            writer.close()
            for sig, handler in previous.items():
                signal.signal(sig, handler)
    counts = dict(writer.counts)
    total = sum(counts.values())
    print(f'cvj-sim record: {total} messages on {len(counts)} topics in {out / "bag"}'
          + (f' (stopped by {signal.Signals(stop[0]).name})' if stop else ''), file=sys.stderr)
    for topic in sorted(counts):
        print(f'  {topic:32s} {counts[topic]:8d}', file=sys.stderr)
    newest, behind = run_end(recorder.recorder.last_stamp) if recorder is not None else (0, {})
    if behind:
        print('cvj-sim record: note: '
              + ', '.join(f'{t} ends at t={behind[t] / 1e9:.9g} s' for t in sorted(behind))
              + f', the run at t={newest / 1e9:.9g} s '
              '(their publisher stopped early, or their last messages never arrived)', file=sys.stderr)
    foreign = dict(recorder.recorder.foreign) if recorder is not None else {}
    if foreign:
        print(f'cvj-sim record: dropped {sum(foreign.values())} messages of publishers outside '
              'the run: ' + ', '.join(f'{t} {n}' for t, n in sorted(foreign.items())), file=sys.stderr)
    malformed = recorder.recorder.malformed if recorder is not None else {}
    if malformed:
        print(f'cvj-sim record: dropped {sum(malformed.values())} malformed messages: '
              + ', '.join(f'{t} {n}' for t, n in sorted(malformed.items())), file=sys.stderr)
    if recorder is not None and recorder.recorder.scene_text is None and total:
        print('cvj-sim record: note: no /driveline/scene message was received '
              '(start the recorder before coupling_node to store the scene)', file=sys.stderr)
    return 0
