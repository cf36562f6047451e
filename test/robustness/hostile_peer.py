"""A hostile rclpy peer for the boundary tests (test_hostile_peers.py, test_hostile_runs.py).

:class:`HostilePeer` is one rclpy node on the run's ROS domain that does what a buggy or
hostile vehicle stack could: answer every joint state on /engine/wrench or /load/wrench with
a plausible torque and the joint state's whole header copied (a forged echo), flood a topic
at 10 kHz, send malformed CDR on any topic, publish foreign JointStates (wrong names, 1e5
entries) and a /clock running backwards. Its publishers are created when an attack starts,
so an attack can begin in the middle of a run. :func:`malformed_samples` lists the
malformed byte strings sent on each input topic.

Run as a script (``python hostile_peer.py ATTACK SECONDS``) it attacks a run started by
``cvj-sim run`` on the same ROS_DOMAIN_ID for that many wall seconds.
"""
from __future__ import annotations

import random
import struct
import sys
from typing import Any

import rclpy
from geometry_msgs.msg import WrenchStamped
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState

from cvj_ros.nodes.qos import DATA_QOS, LATCHED_QOS

FORGED_TORQUE = 50.0      # N m: plausible for kavz685_lever (M_c = 107.5 N m)


def malformed_samples(kind: str, seed: int = 0) -> list[bytes]:
    """Malformed CDR for a topic of message ``kind`` ('wrench', 'joint_states', 'float64',
    'string', 'diagnostics'): empty, one byte, not CDR, a header cut short, length fields
    pointing far past the end (0xffffffff), 1e5 names or values announced, big-endian
    garbage, random bytes (seeded) and an oversized message (1 MiB + 68 bytes)."""
    rng = random.Random(seed)
    le = b'\x00\x01\x00\x00'
    stamp = struct.pack('<iI', 0, 1_000_000)
    out = [b'', b'\x00', b'\xff' * 40, le, le + stamp, le + stamp + struct.pack('<I', 0xFFFFFFFF),
           le + stamp + struct.pack('<I', 10) + b'driveline\x00' + struct.pack('<I', 100_000) + b'x' * 64,
           b'\x00\x00\x00\x00' + bytes(rng.randrange(256) for _ in range(60)),
           le + bytes(rng.randrange(256) for _ in range(120)),
           le + b'\x00' * ((1 << 20) + 64)]
    if kind == 'joint_states':
        # names fine, then an array announced with 1e5 values
        out.append(le + stamp + struct.pack('<I', 10) + b'driveline\x00\x00\x00'
                   + struct.pack('<I', 1) + struct.pack('<I', 2) + b'a\x00\x00\x00'
                   + struct.pack('<I', 100_000) + b'\x00' * 64)
    if kind == 'float64':
        out.append(le + b'\x00\x00')
    return out


class HostilePeer:
    """A hostile node named ``name`` on ``ctx``'s domain (module docstring). Attacks start
    with their method and run from the executor the node is added to (``self.node``)."""

    def __init__(self, ctx: Any, name: str = 'hostile') -> None:
        self.node = rclpy.create_node(name, context=ctx)
        self.pubs: dict[str, Any] = {}
        self.sent: dict[str, int] = {}
        self.last_js: JointState | None = None
        self._js_sub = None
        self._forge: dict[str, tuple[float, int]] = {}
        self.timers: list[Any] = []

    def publisher(self, topic: str, msg_type: Any) -> Any:
        if topic not in self.pubs:
            qos = LATCHED_QOS if topic == '/driveline/scene' else DATA_QOS
            self.pubs[topic] = self.node.create_publisher(msg_type, topic, qos)
        return self.pubs[topic]

    def send(self, topic: str, msg_type: Any, msg: Any) -> bool:
        """Publish ``msg`` (a message, or raw CDR bytes) on ``topic``; False (not counted)
        when the middleware refused it."""
        try:
            self.publisher(topic, msg_type).publish(msg)
        except Exception:  # noqa: BLE001 (rclpy's RCLError: e.g. a reliable writer's history full)
            return False
        self.sent[topic] = self.sent.get(topic, 0) + 1
        return True

    def _watch_joint_states(self) -> None:
        if self._js_sub is None:
            self._js_sub = self.node.create_subscription(JointState, '/driveline/joint_states',
                                                         self._on_js, DATA_QOS)

    def _on_js(self, msg: JointState) -> None:
        self.last_js = msg
        for topic, (torque, from_ns) in self._forge.items():
            stamp_ns = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
            if stamp_ns >= from_ns:
                self.send(topic, WrenchStamped, self.forged(msg, torque))

    @staticmethod
    def forged(js: JointState, torque: float) -> WrenchStamped:
        """An answer to ``js`` with its whole header copied (stamp and frame_id)."""
        w = WrenchStamped()
        w.header = js.header
        w.wrench.torque.z = torque
        return w

    def forge_echo(self, topic: str, torque: float = FORGED_TORQUE, from_s: float = 0.0) -> None:
        """Answer every joint state stamped >= ``from_s`` on ``topic`` with ``torque``, the
        joint state's header copied (publisher created at the first forged answer)."""
        self._forge[topic] = (torque, int(round(from_s * 1e9)))
        self._watch_joint_states()

    def flood(self, topic: str, hz: float = 10_000.0, torque: float = FORGED_TORQUE) -> None:
        """Send answers stamped like the latest joint state on ``topic`` at ``hz`` (as fast
        as the executor allows)."""
        self._watch_joint_states()
        self.publisher(topic, WrenchStamped)

        def tick() -> None:
            if self.last_js is not None:
                self.send(topic, WrenchStamped, self.forged(self.last_js, torque))
        self.timers.append(self.node.create_timer(1.0 / hz, tick))

    def foreign_joint_states(self, count: int = 14) -> None:
        """Publish ``count`` JointStates that are not the run's: wrong names, wrong sizes,
        1e5 entries."""
        for i in range(count):
            js = JointState()
            js.header.frame_id = 'driveline'
            js.header.stamp.nanosec = i * 1_000_000
            n = 100_000 if i % 2 else 3
            js.name = [f'intruder_{j}' for j in range(n)]
            js.position = [0.0] * n
            js.velocity = [1.0] * (n - 1)
            self.send('/driveline/joint_states', JointState, js)

    def backwards_clock(self, start_s: float = 100.0, hz: float = 1000.0) -> None:
        """Publish /clock from ``start_s`` going backwards by 1 ms per message at ``hz``."""
        value = [int(start_s * 1e9)]

        def tick() -> None:
            value[0] = max(value[0] - 1_000_000, 0)
            c = Clock()
            c.clock.sec, c.clock.nanosec = divmod(value[0], 1_000_000_000)
            self.send('/clock', Clock, c)
        self.timers.append(self.node.create_timer(1.0 / hz, tick))

    def destroy(self) -> None:
        self.node.destroy_node()


ATTACKS = ('forge_engine', 'forge_load', 'flood_engine', 'malformed_engine', 'malformed_load',
           'foreign_js', 'clock_back')


def main(argv: list[str]) -> None:
    """``hostile_peer.py ATTACK FROM_S``: one of :data:`ATTACKS` against the run on
    ROS_DOMAIN_ID, from its first joint state stamped >= FROM_S simulated seconds (the
    backwards /clock from the start) until EOF on standard input. Prints ``ready`` once its
    node exists and ``sent {...}`` at the end. Like another run, it subscribes to the joint
    states only once the run's /clock shows up (a subscriber there before would count toward
    the coupling node's ``min_subscribers``)."""
    import select
    import threading

    from rosgraph_msgs.msg import Clock as ClockMsg

    from cvj_ros.nodes.executor import make_executor
    attack, from_s = argv[0], float(argv[1])
    if attack not in ATTACKS:
        raise SystemExit(f'hostile_peer.py: ATTACK must be one of {", ".join(ATTACKS)}')
    rclpy.init()
    peer = HostilePeer(None)
    ex = make_executor('events', None)
    ex.add_node(peer.node)
    from_ns = int(round(from_s * 1e9))
    started = threading.Event()

    def on_state(msg: JointState) -> None:
        peer._on_js(msg)                 # the attacks already started (forged answers)
        if started.is_set() or msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec < from_ns:
            return
        started.set()
        if attack.startswith('forge_'):
            topic = '/engine/wrench' if attack == 'forge_engine' else '/load/wrench'
            peer.forge_echo(topic, from_s=from_s)
            peer.send(topic, WrenchStamped, peer.forged(msg, FORGED_TORQUE))
        elif attack == 'flood_engine':
            peer.flood('/engine/wrench')
        elif attack.startswith('malformed_'):
            topic = '/engine/wrench' if attack == 'malformed_engine' else '/load/wrench'
            for data in malformed_samples('wrench'):
                peer.send(topic, WrenchStamped, data)
        elif attack == 'foreign_js':
            peer.foreign_joint_states(14)

    def on_clock(_msg: Any) -> None:
        if peer._js_sub is None:
            peer._js_sub = peer.node.create_subscription(JointState, '/driveline/joint_states',
                                                         on_state, DATA_QOS)

    peer.node.create_subscription(ClockMsg, '/clock', on_clock, DATA_QOS)
    if attack == 'clock_back':
        peer.backwards_clock()
    print('ready', flush=True)
    try:
        while not select.select([sys.stdin], [], [], 0)[0]:
            ex.spin_once(timeout_sec=0.02)
    finally:
        print(f'sent {peer.sent}', flush=True)
        ex.shutdown()
        peer.destroy()
        rclpy.shutdown()


if __name__ == '__main__':
    main(sys.argv[1:])
