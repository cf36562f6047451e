"""replay_node: publishes a recorded cvj_ros bag (mcap or sqlite3) with its own /clock.

Every selected topic is republished as the raw CDR bytes stored in the bag (no
deserialise/serialise round trip), with the bag's message types and the project QoS
(``cvj_ros.nodes.qos``: DATA_QOS, LATCHED_QOS for /driveline/scene). The bag's own
``/clock`` is not replayed; instead, before the messages of each new record time t the
node publishes ``/clock`` = t (the bag's time axis is simulated time, see
:mod:`cvj_ros.bag`), so subscribers with ``use_sim_time`` follow the replay.

Pacing: a message with record time t goes out at wall time
``start + (t - t_first) / rate``. ``loop`` starts over at the end (the clock jumps back
to the bag start, like ``ros2 bag play --loop``). The node exits 0 after the last
message (no loop) or on Ctrl-C.

Parameters: ``bag`` (path), ``rate`` (playback speed factor, > 0), ``loop`` (bool),
``topics`` (list of topics or glob patterns; empty = all), ``start_delay`` (s of wall
time before the first message, for discovery), ``publish_clock`` (bool).

Only the run's messages are replayed: a joint state whose names are not the run's (the
``shaft_names`` of the bag's scene, else the first joint state's) and any message that does
not decode (:func:`cvj_ros.nodes.cdr.check_message`) are left out - another publisher's,
recorded by ``cvj-sim record`` on a busy domain - and counted in one line at the start.

Run alone: ``replay_node --ros-args -p bag:=runs/demo/bag -p rate:=2.0``.
"""
from __future__ import annotations

import sys
import threading
import time
from collections.abc import Sequence
from typing import Any

from rosgraph_msgs.msg import Clock

from cvj_ros import bag as bagmod
from cvj_ros.errors import BagError
from cvj_ros.nodes.common import CvjNode, ParameterError, ParamSpec, declare_parameters, run_node
from cvj_ros.nodes.qos import CLOCK_TOPIC, DATA_QOS, LATCHED_QOS, SCENE_TOPIC

PARAMS = (
    ParamSpec('bag', '', 'bag directory to replay (mcap or sqlite3)'),
    ParamSpec('rate', 1.0, 'playback speed factor [-] (2.0 = twice real time)', lo=0.0, lo_open=True,
              hi=1e6),
    ParamSpec('loop', False, 'start over at the end of the bag'),
    ParamSpec('topics', [''], 'topics (or glob patterns) to replay; empty = all'),
    ParamSpec('start_delay', 0.5, 'wall time before the first message, for discovery [s]',
              lo=0.0, hi=60.0),
    ParamSpec('publish_clock', True, 'publish /clock from the bag record time'),
)

USAGE = """usage: replay_node [--ros-args -p bag:=PATH [-p rate:=R] [-p loop:=true]
                   [-p topics:="['/driveline/joint_states']"] [-p start_delay:=S]
                   [-p publish_clock:=false]]

Publishes a recorded cvj_ros bag (raw CDR, original types) with its own /clock.
Parameters:
""" + ''.join(f'  {p.name:14s} {p.description} (default {p.default!r})\n' for p in PARAMS)


def run_messages(messages: list[tuple[str, str, int, bytes]], names: Sequence[str] | None
                 ) -> tuple[list[tuple[str, str, int, bytes]], dict[str, int]]:
    """The run's messages of ``(topic, msgtype, record ns, CDR)`` and the count of the others
    per topic: undecodable ones (:func:`~cvj_ros.nodes.cdr.check_message`) and joint states
    whose names are not ``names`` (None: the first decodable joint state's)."""
    from cvj_ros.nodes.cdr import CdrError, JointStateDecoder, checked_length
    dec = JointStateDecoder()
    run_names = list(names) if names else None
    keep: list[tuple[str, str, int, bytes]] = []
    foreign: dict[str, int] = {}
    for item in messages:
        topic, msgtype, _ts, data = item
        try:
            checked_length(msgtype, data, dec)
            ok = True
            if msgtype == 'sensor_msgs/msg/JointState':
                got = list(dec.decode(data).name)
                run_names = got if run_names is None else run_names
                ok = got == run_names
        except CdrError:
            ok = False
        if ok:
            keep.append(item)
        else:
            foreign[topic] = foreign.get(topic, 0) + 1
    return keep, foreign


def foreign_line(foreign: dict[str, int]) -> str:
    """One line naming the messages left out of the replay, per topic."""
    parts = ', '.join(f'{n} on {t}' for t, n in sorted(foreign.items()))
    return (f"replay: left out {sum(foreign.values())} messages not the run's (other joint "
            f'names, undecodable): {parts}')


class ReplayNode(CvjNode):
    """Replays a bag (module docstring). ``messages_published`` counts data messages, ``loops``
    completed passes; :meth:`stop` ends the playback early."""

    def __init__(self, *, context: Any = None, parameter_overrides: Sequence[Any] | None = None,
                 autostart: bool = True) -> None:
        super().__init__('replay_node', context=context, parameter_overrides=list(parameter_overrides or []))
        p = declare_parameters(self, PARAMS)
        if not p['bag']:
            raise ParameterError('bag', 'required: path of the bag to replay')
        self.rate = float(p['rate'])
        self.loop = bool(p['loop'])
        self.start_delay = float(p['start_delay'])
        self.publish_clock = bool(p['publish_clock'])
        wanted = [t for t in p['topics'] if t]
        try:
            info = bagmod.bag_info(p['bag'])
            selected = [t for t in info.types if t != CLOCK_TOPIC]
            if wanted:
                from cvj_ros.topic_pattern import topic_selected
                for w in wanted:
                    if not any(topic_selected(t, w) for t in info.types):
                        raise ParameterError('topics', f'{w}: topic not in bag {p["bag"]}')
                selected = [t for t in selected if any(topic_selected(t, w) for w in wanted)]
            messages = bagmod.read_raw(p['bag'], selected) if selected else []
        except BagError as exc:
            raise ParameterError('bag', str(exc)) from None
        self.messages, self.foreign = run_messages(messages, bagmod.run_joint_names(p['bag']))
        if self.foreign:
            self.get_logger().warning(foreign_line(self.foreign))
        self.publishers_by_topic: dict[str, Any] = {}
        for topic in selected:
            cls = bagmod._msg_class(info.types[topic])
            qos = LATCHED_QOS if topic == SCENE_TOPIC else DATA_QOS
            self.publishers_by_topic[topic] = self.create_publisher(cls, topic, qos)
        self.clock_pub = self.create_publisher(Clock, CLOCK_TOPIC, DATA_QOS) if self.publish_clock else None
        self.messages_published = 0
        self.published_by_topic: dict[str, int] = {}
        self.loops = 0
        self._wall_start: float | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._play, name='replay', daemon=True)
        if autostart:
            self.start()

    def start(self) -> None:
        """Start the playback thread."""
        self._thread.start()

    def stop(self) -> None:
        """End the playback at the next message."""
        self._stop.set()

    def join(self, timeout: float | None = None) -> None:
        self._thread.join(timeout)

    def _play(self) -> None:
        try:
            if self._stop.wait(self.start_delay):
                return
            while not self._stop.is_set():
                self._play_once()
                self.loops += 1
                if not self.loop or not self.messages:
                    break
            self._flush()
            print(self.summary(), flush=True)
            self.finish()
        except Exception as exc:  # report, never a silent dead thread
            self.fail(f'replay: {exc}')

    def summary(self) -> str:
        """What was published: total, topics, bag-time span, wall time, rate; one line per topic."""
        span = (self.messages[-1][2] - self.messages[0][2]) * 1e-9 if self.messages else 0.0
        wall = time.monotonic() - self._wall_start if self._wall_start is not None else 0.0
        head = (f'replay: published {self.messages_published} messages on '
                f'{len(self.published_by_topic)} topics, {self.loops} pass(es) over {span:.6g} s of '
                f'bag time in {wall:.3g} s wall (rate {self.rate:g}x'
                + (', /clock from the bag stamps' if self.publish_clock else '') + ')')
        width = max((len(t) for t in self.published_by_topic), default=0)
        if self.foreign:
            head += '\n' + foreign_line(self.foreign)
        return '\n'.join([head] + [f'  {t:<{width}}  {n}' for t, n in
                                    sorted(self.published_by_topic.items())])

    def _flush(self, timeout: float = 2.0) -> None:
        """Wait until reliable subscribers acknowledged everything sent (``timeout`` s in total)."""
        from rclpy.duration import Duration
        deadline = time.monotonic() + timeout
        for pub in [*self.publishers_by_topic.values(), self.clock_pub]:
            if pub is not None:
                pub.wait_for_all_acked(Duration(seconds=max(0.0, deadline - time.monotonic())))

    def _play_once(self) -> None:
        if not self.messages:
            return
        t_first = self.messages[0][2]
        wall0 = time.monotonic()
        if self._wall_start is None:
            self._wall_start = wall0
        last_clock = None
        for topic, _msgtype, ts, data in self.messages:
            due = wall0 + (ts - t_first) * 1e-9 / self.rate
            delay = due - time.monotonic()
            if delay > 0 and self._stop.wait(delay):
                return
            if self._stop.is_set():
                return
            if self.clock_pub is not None and ts != last_clock:
                clock = Clock()
                clock.clock.sec, clock.clock.nanosec = divmod(ts, 1_000_000_000)
                self.clock_pub.publish(clock)
                last_clock = ts
            self.publishers_by_topic[topic].publish(data)
            self.messages_published += 1
            self.published_by_topic[topic] = self.published_by_topic.get(topic, 0) + 1


def main(args: Sequence[str] | None = None) -> None:
    argv = list(sys.argv[1:] if args is None else args)
    user_args = argv[:argv.index('--ros-args')] if '--ros-args' in argv else argv
    if '-h' in user_args or '--help' in user_args:
        print(USAGE)
        sys.exit(0)
    sys.exit(run_node(ReplayNode, None if args is None else ['replay_node', *argv], prog='replay_node'))


if __name__ == '__main__':
    main()
