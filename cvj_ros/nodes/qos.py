"""QoS profiles shared by every cvj_ros node, the recorder and replay.

* :data:`DATA_QOS` - data topics (/clock, /driveline/joint_states, /engine/wrench,
  /load/wrench, /coupling/<joint>/wrench, /diagnostics, /engine/throttle):
  reliable, volatile, keep_last depth 1000, so a lockstep run loses no sample even
  when a subscriber lags by many exchange steps.
* :data:`LATCHED_QOS` - /driveline/scene: reliable, transient_local, depth 1, so a
  late subscriber (recorder, monitor) still receives the one scene message.
"""
from __future__ import annotations

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

DATA_DEPTH = 1000

DATA_QOS = QoSProfile(
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
    history=HistoryPolicy.KEEP_LAST,
    depth=DATA_DEPTH,
)

LATCHED_QOS = QoSProfile(
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
    history=HistoryPolicy.KEEP_LAST,
    depth=1,
)

# Topic names (DESIGN.md section 2).
CLOCK_TOPIC = '/clock'
JOINT_STATES_TOPIC = '/driveline/joint_states'
ENGINE_WRENCH_TOPIC = '/engine/wrench'
ENGINE_THROTTLE_TOPIC = '/engine/throttle'
LOAD_WRENCH_TOPIC = '/load/wrench'
SCENE_TOPIC = '/driveline/scene'
DIAGNOSTICS_TOPIC = '/diagnostics'


def coupling_wrench_topic(joint: str) -> str:
    """Topic of the reaction wrench of scene joint ``joint``: ``/coupling/<joint>/wrench``."""
    return f'/coupling/{joint}/wrench'
