"""Intra-process delivery of the loop topics between nodes hosted in one process (composed mode).

rclcpp's answer to "nodes in one process pay for DDS" is intra-process communication: a
publisher hands its message straight to the subscriptions in the same process and DDS
carries it only to the others. rclpy has none, and without it every lockstep exchange in
composed mode went through Fast DDS to up to four in-process readers (profiled at 1 ms
exchange steps on kavz685_lever: ~430 of the ~540 us per exchange were the wait for the
answers, most of it delivery inside rclpy/Fast DDS; docs/nodes.md, "Composed mode"). This
module is the rclpy equivalent for the cvj_ros nodes:

* :class:`IntraProcessBus` - one per rclpy Context, attached by the composed container
  (:func:`attach`) before it creates the nodes. It *carries* a fixed set of topics: the
  high-rate loop topics whose publisher is hosted in this process (``/clock``,
  ``/driveline/joint_states``, ``/coupling/<joint>/wrench`` with the coupling node,
  ``/engine/wrench`` with the engine node, ``/load/wrench`` with the load node).
* A node asks :func:`loop_publisher` / :func:`loop_subscription` instead of
  ``create_publisher`` / ``create_subscription(raw=True)``; without a bus (one node per
  process, ``ros2 run``) these ARE the rclpy calls, so separate-process mode is unchanged.
* A carried topic's publisher (:class:`IntraPublisher`) still publishes every message to
  DDS while an outside subscriber is matched (``ros2 topic echo``, rosbag2, a vehicle
  stack: they see the same topics, message for message); the hosted subscribers of a
  carried topic have no DDS subscription and get the same CDR bytes from the bus.
* Delivery is queued, never re-entrant: :meth:`IntraProcessBus.deliver` appends
  ``(callback, bytes)`` per subscriber; a zero-period timer of the bus's node drains the
  queue first in, first out, so a callback never runs inside the publish call that fed
  it (the coupling node publishes its state and only then waits for the answers). A drain
  gives the executor back after ``budget_s`` (timers, /engine/throttle, Ctrl-C) and re-arms
  the timer. The loop is deterministic either way: the answers carry the stamp they answer.

The same "bus" interface serves `cvj-sim run`'s separate-process mode once more:
:class:`RecorderFeed` hands an observer node hosted beside the recorder (the monitor) the
samples the recorder takes, instead of DDS readers of its own.

What an outside node cannot do in composed mode: publish on a carried topic and be heard by
the hosted nodes (the hosted ones have no DDS subscription there). That is a second engine or
load answerer, or another run - what the lockstep loop refuses anyway (docs/ros.md, "Run
identity"). Leave the node out instead (``--external load``, ``driveline_composed --without
load_node``): its topic is then not carried and goes through DDS.
"""
from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable, Iterable
from typing import Any

from cvj_ros.nodes.qos import (BRAKE_TOPIC, CLOCK_TOPIC, CLUTCH_TOPIC, DIAGNOSTICS_TOPIC,
                               ENGINE_THROTTLE_SCALE_TOPIC, ENGINE_THROTTLE_TOPIC,
                               ENGINE_WRENCH_TOPIC, GEAR_TOPIC,
                               JOINT_STATES_TOPIC, LOAD_WRENCH_TOPIC, SCENE_TOPIC)

#: the loop topics each hosted node publishes at the exchange rate
LOOP_TOPICS_OF = {
    # + /coupling/<joint>/wrench; the throttle scale of a shift schedule before each state
    'coupling_node': (CLOCK_TOPIC, JOINT_STATES_TOPIC, ENGINE_THROTTLE_SCALE_TOPIC),
    'engine_node': (ENGINE_WRENCH_TOPIC,),
    'load_node': (LOAD_WRENCH_TOPIC,),
    # the commands: in order with /clock, on which the driver plays them (command_plan.py)
    'driver_node': (ENGINE_THROTTLE_TOPIC, CLUTCH_TOPIC, GEAR_TOPIC, BRAKE_TOPIC),
}
#: topics that hosted AND outside nodes publish (every node's /diagnostics; the latched
#: /driveline/scene, which a late joiner gets from DDS): the hosted subscribers get the hosted
#: publications from the bus, in order with the loop topics, and the outside ones from DDS;
#: the DDS copies of hosted publications are recognised by their bytes and dropped
MIXED_TOPICS = frozenset({DIAGNOSTICS_TOPIC, SCENE_TOPIC})
#: hosted publications of mixed topics remembered for that (per bus)
RECENT_HOSTED = 512
#: a drain gives the executor back after this many wall seconds (2 ms: a watchdog or
#: progress timer is served within one drain; the timer round trip costs ~4 us)
DRAIN_BUDGET_S = 0.002
#: an IntraPublisher asks DDS for its outside subscribers at most this often (s); a call
#: costs ~2.4 us, a publish to no reader ~4.7 us, both per message otherwise
OUTSIDE_REFRESH_S = 0.05

_BUSES: dict[int, 'IntraProcessBus'] = {}


def carried_topics(hosted: Iterable[str]) -> tuple[frozenset[str], bool]:
    """``(topics, coupling wrenches)`` a bus carries for the hosted node names: the loop
    topics of :data:`LOOP_TOPICS_OF`, and whether ``/coupling/<joint>/wrench`` is carried
    (the coupling node is hosted)."""
    hosted = set(hosted)
    topics = frozenset(t for name in hosted for t in LOOP_TOPICS_OF.get(name, ()))
    return topics, 'coupling_node' in hosted


def is_coupling_wrench(topic: str) -> bool:
    """``/coupling/<joint>/wrench`` (one path segment for the joint)."""
    return topic.startswith('/coupling/') and topic.endswith('/wrench') and topic.count('/') == 3


class _Route:
    """What a publication of one topic reaches in this process: the taps (called with
    ``(topic, data)`` at publish time) and the subscriber callbacks (queued). One object per
    topic, changed in place, so a publisher holds its topic's route."""
    __slots__ = ('taps', 'callbacks')

    def __init__(self) -> None:
        self.taps: list[Callable[[str, bytes], None]] = []
        self.callbacks: list[Callable[[bytes], None]] = []


class _BusEndpoint:
    """A hosted reader of a carried topic, as rclpy would count it: the topic's publishers
    in the ROS graph (the hosted one included); ``destroy`` leaves the bus."""

    def __init__(self, bus: 'IntraProcessBus', node: Any, topic: str) -> None:
        self.bus = bus
        self.node = node
        self.topic_name = topic

    def get_publisher_count(self) -> int:
        return self.node.count_publishers(self.topic_name)

    def destroy(self) -> None:
        raise NotImplementedError


class IntraSubscription(_BusEndpoint):
    """A hosted subscriber of a carried topic (no DDS subscription): ``callback(bytes)``,
    run from the bus's drain."""

    def __init__(self, bus: 'IntraProcessBus', node: Any, topic: str,
                 callback: Callable[[bytes], None]) -> None:
        super().__init__(bus, node, topic)
        self.callback = callback

    def destroy(self) -> None:
        self.bus.unsubscribe(self)


class IntraTap(_BusEndpoint):
    """Handle of :meth:`IntraProcessBus.tap`: ``fn(topic, data)`` inside every publish."""

    def __init__(self, bus: 'IntraProcessBus', node: Any, topic: str,
                 fn: Callable[[str, bytes], None]) -> None:
        super().__init__(bus, node, topic)
        self.fn = fn

    def destroy(self) -> None:
        self.bus.untap(self)


class IntraPublisher:
    """Publisher of a carried (or mixed) topic: the hosted subscribers get the CDR bytes
    through the bus; DDS gets the message while an outside subscriber is matched (a mixed
    topic's always: /diagnostics and the latched /driveline/scene reach outside readers and
    late joiners).

    ``publish`` takes the pre-serialised CDR bytes the cvj_ros encoders make, or a message
    object (serialised once with ``rclpy.serialization``)."""

    def __init__(self, bus: 'IntraProcessBus', publisher: Any) -> None:
        self.bus = bus
        self.publisher = publisher
        self.topic_name = publisher.topic_name
        self.mixed = bus.is_mixed(self.topic_name)
        self._route = bus.route(self.topic_name)
        self._outside = 0
        self._checked = -1.0
        self.published = 0

    def get_subscription_count(self) -> int:
        """Hosted (bus) subscribers plus matched DDS subscribers (outside this process)."""
        self._outside = self.publisher.get_subscription_count()
        self._checked = time.monotonic()
        return self._outside + self.bus.subscriber_count(self.topic_name)

    def publish(self, msg: Any) -> None:
        if msg.__class__ is bytes:
            data = msg
        else:
            from rclpy.serialization import serialize_message
            data = serialize_message(msg)
        if self.mixed:
            self.bus.note_hosted(data)
            self.publisher.publish(data)
        else:
            now = time.monotonic()
            if now - self._checked > OUTSIDE_REFRESH_S:
                self._outside = self.publisher.get_subscription_count()
                self._checked = now
            if self._outside:
                self.publisher.publish(data)
        self.published += 1
        self.bus.deliver_route(self.topic_name, self._route, data)

    def wait_for_all_acked(self, timeout: Any) -> bool:
        return self.publisher.wait_for_all_acked(timeout)

    def __getattr__(self, name: str) -> Any:    # handle, qos_profile, ... of the rclpy publisher
        return getattr(self.publisher, name)


class IntraProcessBus:
    """In-process delivery of carried topics (module docstring).

    Args:
        node: the node owning the drain timer (the composed container's own node).
        topics: carried topic names.
        coupling_wrenches: also carry every ``/coupling/<joint>/wrench``.
        budget_s: wall seconds per drain before the executor gets control back.
    """

    def __init__(self, node: Any, topics: Iterable[str] = (), *, coupling_wrenches: bool = False,
                 budget_s: float = DRAIN_BUDGET_S) -> None:
        self.node = node
        self.topics = frozenset(topics)
        self.coupling_wrenches = coupling_wrenches
        self.budget_s = budget_s
        self._subs: dict[str, list[IntraSubscription]] = {}
        # per topic: the taps (called at publish time with (topic, data) - for a consumer that
        # only collects, the recorder; they must not publish or call back into a node) and
        # the subscriber callbacks (queued)
        self._routes: dict[str, _Route] = {}
        self.after_drain: list[Callable[[], None]] = []     # run at the end of every drain
        self._queue: deque[tuple[Callable[[bytes], None], bytes]] = deque()
        self._draining = False
        self._armed = False
        self.nodes: list[Any] = []       # hosted nodes (register), for dds_unmatched
        self._recent: dict[bytes, None] = {}   # hosted publications of mixed topics (keys)
        self.dropped_copies = 0                # DDS copies of hosted publications dropped
        self.delivered = 0
        self.drains = 0
        self._timer = node.create_timer(0.0, self._on_timer)
        self._timer.cancel()

    def register(self, node: Any) -> None:
        """A node hosted in this process (its DDS endpoints count in :meth:`dds_unmatched`)."""
        if node not in self.nodes:
            self.nodes.append(node)

    def dds_unmatched(self) -> list[str]:
        """The hosted DDS publishers (topics the bus does not carry: /diagnostics, the latched
        /driveline/scene) not yet matched by every hosted DDS subscription of their topic, as
        ``'<topic> (<node>: m of n in-process subscribers)'``. With the loop topics on the bus
        the coupling node's start no longer waits for DDS discovery; it waits for this list
        to be empty instead, so the recorder and the monitor get its first diagnostics."""
        wanted: dict[str, int] = {}
        for node in self.nodes:
            for sub in node.subscriptions:
                wanted[sub.topic_name] = wanted.get(sub.topic_name, 0) + 1
        out = []
        for node in self.nodes:
            for pub in node.publishers:
                want = wanted.get(pub.topic_name, 0)
                if want and (have := pub.get_subscription_count()) < want:
                    out.append(f'{pub.topic_name} ({node.get_name()}: {have} of {want} '
                               'in-process subscribers)')
        return out

    def carries(self, topic: str) -> bool:
        """A loop topic: hosted subscribers get it from the bus only."""
        return topic in self.topics or (self.coupling_wrenches and is_coupling_wrench(topic))

    @staticmethod
    def is_mixed(topic: str) -> bool:
        """A topic of :data:`MIXED_TOPICS`: hosted publications from the bus, outside ones
        from DDS."""
        return topic in MIXED_TOPICS

    @staticmethod
    def _key(data: bytes) -> bytes:
        # DDS may append alignment padding to a sample (zero bytes): not part of the message
        return bytes(data).rstrip(b'\x00')

    def note_hosted(self, data: bytes) -> None:
        """Remember a hosted publication of a mixed topic (before it goes to DDS)."""
        recent = self._recent
        recent[self._key(data)] = None
        if len(recent) > RECENT_HOSTED:
            del recent[next(iter(recent))]

    def is_hosted_copy(self, data: bytes) -> bool:
        """True (counted) for the DDS copy of a hosted publication of a mixed topic."""
        if self._key(data) in self._recent:
            self.dropped_copies += 1
            return True
        return False

    def subscribe_mixed(self, node: Any, msg_type: Any, topic: str,
                        callback: Callable[[bytes], None], qos: Any) -> tuple[IntraSubscription, Any]:
        """A raw subscription of a mixed topic: the bus for hosted publications and a DDS
        subscription that drops the copies of hosted ones; returns both."""
        def outside(data: bytes) -> None:
            if not self.is_hosted_copy(data):
                callback(data)
        return (self.subscribe(topic, callback, node=node),
                node.create_subscription(msg_type, topic, outside, qos, raw=True))

    def route(self, topic: str) -> _Route:
        """The (live) route of ``topic``."""
        route = self._routes.get(topic)
        if route is None:
            route = self._routes[topic] = _Route()
        return route

    def subscribe(self, topic: str, callback: Callable[[bytes], None], *, node: Any) -> IntraSubscription:
        sub = IntraSubscription(self, node, topic, callback)
        self._subs.setdefault(topic, []).append(sub)
        self.route(topic).callbacks.append(callback)
        return sub

    def tap(self, topic: str, fn: Callable[[str, bytes], None], *, node: Any) -> IntraTap:
        """Call ``fn(topic, data)`` inside every publish of ``topic`` (no queue: for a consumer
        that only collects, such as the recorder, which then handles its collection in bulk
        from :attr:`after_drain`; ordered as published)."""
        self.route(topic).taps.append(fn)
        return IntraTap(self, node, topic, fn)

    def untap(self, tap: IntraTap) -> None:
        taps = self.route(tap.topic_name).taps
        if tap.fn in taps:
            taps.remove(tap.fn)

    def unsubscribe(self, sub: IntraSubscription) -> None:
        subs = self._subs.get(sub.topic_name, [])
        if sub in subs:
            subs.remove(sub)
            self.route(sub.topic_name).callbacks[:] = [s.callback for s in subs]

    def subscriber_count(self, topic: str) -> int:
        route = self._routes.get(topic)
        return 0 if route is None else len(route.callbacks) + len(route.taps)

    def wrap(self, publisher: Any) -> IntraPublisher:
        return IntraPublisher(self, publisher)

    @property
    def pending(self) -> int:
        """Deliveries queued and not yet run."""
        return len(self._queue)

    def deliver(self, topic: str, data: bytes) -> None:
        """Queue ``data`` for every hosted subscriber of ``topic``; they run from the drain."""
        route = self._routes.get(topic)
        if route is not None:
            self.deliver_route(topic, route, data)

    def deliver_route(self, topic: str, route: _Route, data: bytes) -> None:
        """:meth:`deliver` with the topic's route at hand (what a publisher holds)."""
        for fn in route.taps:
            fn(topic, data)
        callbacks = route.callbacks
        if not callbacks:
            return
        if len(callbacks) == 1:
            self._queue.append((callbacks[0], data))
        else:
            self._queue.extend([(cb, data) for cb in callbacks])
        if not self._draining and not self._armed:
            self._armed = True
            self._timer.reset()

    def _on_timer(self) -> None:
        self._timer.cancel()
        self._armed = False
        self.drain(self.budget_s)

    def drain(self, budget_s: float | None = None) -> int:
        """Run queued deliveries first in, first out (also those they queue) until the queue
        is empty or ``budget_s`` wall seconds passed (then the timer is re-armed); returns
        how many ran. A callback's exception propagates (as from a subscription callback)."""
        if self._draining:
            return 0
        self.drains += 1
        queue = self._queue
        clock = time.perf_counter
        deadline = None if budget_s is None else clock() + budget_s
        ran = 0
        self._draining = True
        try:
            while queue:
                cb, data = queue.popleft()
                ran += 1
                cb(data)
                if deadline is not None and clock() > deadline:
                    break
        finally:
            self._draining = False
            self.delivered += ran
            if queue and not self._armed:
                self._armed = True
                self._timer.reset()
        for hook in self.after_drain:
            hook()
        return ran

    def destroy(self) -> None:
        """Drop every subscription and queued delivery; remove the timer."""
        self._subs.clear()
        for route in self._routes.values():     # publishers hold the routes: empty them
            route.taps.clear()
            route.callbacks.clear()
        self.after_drain.clear()
        self._queue.clear()
        try:
            self.node.destroy_timer(self._timer)
        except Exception:  # noqa: BLE001 (node already destroyed)
            pass


class FedSubscription(_BusEndpoint):
    """A hosted node's subscription fed by a recorder (:class:`RecorderFeed`): ``fn(bytes)``
    among the recorder's observers of the topic until ``destroy``."""

    def __init__(self, feed: 'RecorderFeed', node: Any, topic: str,
                 fn: Callable[[bytes], None]) -> None:
        super().__init__(feed, node, topic)   # type: ignore[arg-type]  (a bus's endpoint)
        self.fn = fn

    def destroy(self) -> None:
        fns = self.bus.recorder.observers.get(self.topic_name, [])
        if self.fn in fns:
            fns.remove(self.fn)


class RecorderFeed:
    """In-process delivery from a recorder to an observer node hosted beside it
    (``cvj-sim run``'s monitor, cvj_ros.orchestrate.recorder.HOSTED_IN_RUN): while the node
    is created, :func:`attach` makes this the "bus" of the recorder's context, so
    ``loop_subscription`` of a topic the recorder subscribes to creates no DDS reader and
    adds the callback to :attr:`cvj_ros.bag.BagRecorder.observers` instead; the recorder
    thread calls it with each sample's CDR bytes after each wake, in loop order (the samples
    it keeps: malformed ones and those not of the run's publishers are left out;
    :meth:`cvj_ros.bag.BagRecorder._take_queued`). Publishers (the monitor's /diagnostics)
    stay plain DDS publishers.

    A callback that raises ends the node's feed (as the exception would end its process):
    ``on_error(name, exc)`` is called once and its callbacks are dropped."""

    def __init__(self, recorder: Any, name: str, topics: Any, on_error: Any) -> None:
        self.recorder = recorder
        self.name = name
        self.topics = frozenset(topics)
        self.on_error = on_error
        self.failed = False
        self.subscriptions: list[FedSubscription] = []

    def carries(self, topic: str) -> bool:
        return topic in self.topics

    def stop(self) -> None:
        """Feed the node nothing more (its subscriptions leave the recorder's observers)."""
        self.failed = True
        for sub in self.subscriptions:
            sub.destroy()

    @staticmethod
    def is_mixed(topic: str) -> bool:
        return False

    @staticmethod
    def wrap(publisher: Any) -> Any:
        return publisher

    def subscribe(self, topic: str, callback: Callable[[bytes], None], *,
                  node: Any) -> FedSubscription:
        def fed(data: bytes) -> None:
            if self.failed:
                return
            try:
                callback(data)
            except Exception as exc:  # noqa: BLE001 (the node's callback: its process would exit 1)
                self.stop()
                self.on_error(self.name, exc)
        sub = FedSubscription(self, node, topic, fed)
        self.recorder.observers.setdefault(topic, []).append(fed)
        self.subscriptions.append(sub)
        return sub


def attach(context: Any, bus: 'IntraProcessBus | RecorderFeed') -> None:
    """Make ``bus`` the bus of the nodes created on ``context`` from now on."""
    _BUSES[id(context)] = bus


def detach(context: Any) -> None:
    _BUSES.pop(id(context), None)


def bus_for(context: Any) -> IntraProcessBus | None:
    """The bus attached to ``context``, or None (one node per process)."""
    return _BUSES.get(id(context)) if _BUSES else None


def loop_publisher(node: Any, msg_type: Any, topic: str, qos: Any) -> Any:
    """``node.create_publisher(msg_type, topic, qos)``, wrapped in an :class:`IntraPublisher`
    when the node's context has a bus that carries ``topic`` or has it as a mixed topic."""
    pub = node.create_publisher(msg_type, topic, qos)
    bus = bus_for(node.context)
    return bus.wrap(pub) if bus is not None and (bus.carries(topic) or bus.is_mixed(topic)) else pub


def loop_subscription(node: Any, msg_type: Any, topic: str, callback: Callable[[Any], None],
                      qos: Any, *, raw: bool = True) -> Any:
    """A subscription from the bus when the node's context has one that carries ``topic``
    (for a mixed topic: the bus and a DDS subscription for outside publishers), else
    ``node.create_subscription``. ``raw``: the callback takes CDR bytes, else the message
    (deserialised with ``rclpy.serialization``)."""
    bus = bus_for(node.context)
    if bus is None or not (bus.carries(topic) or bus.is_mixed(topic)):
        return node.create_subscription(msg_type, topic, callback, qos, raw=raw)
    if raw:
        cb = callback
    else:
        from rclpy.serialization import deserialize_message

        def cb(data: bytes) -> None:
            callback(deserialize_message(data, msg_type))
    if bus.carries(topic):
        return bus.subscribe(topic, cb, node=node)
    return bus.subscribe_mixed(node, msg_type, topic, cb, qos)[0]
