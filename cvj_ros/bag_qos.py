"""What a bag's metadata says about its topics and its ROS version, as ``ros2 bag record``
writes it on ROS 2 Jazzy (rosbag2 format version 9).

* ``offered_qos_profiles`` of each topic: the QoS profile its publisher offers (the topic
  contract, :mod:`cvj_ros.nodes.qos`): ``/driveline/scene`` reliable, transient local,
  keep last 1 - so ``ros2 bag play`` offers it latched again and a late subscriber still
  gets the scene - and every other topic reliable, volatile, keep last
  :data:`DATA_DEPTH`. Deadline, lifespan and liveliness lease are infinite (rmw's
  ``RMW_DURATION_INFINITE``, written by rosbag2 as ``sec: 9223372036, nsec: 854775807``),
  liveliness automatic.
* ``ros_distro: jazzy`` (``rosbags`` writes ``rosbags`` there): :func:`patch_ros_distro`.

rclpy-free (the writer runs without ROS); test/test_bag_metadata.py checks these profiles
against the nodes' rclpy ones.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

__all__ = ['ROS_DISTRO', 'DATA_DEPTH', 'offered_qos', 'patch_ros_distro', 'fix_metadata_file']

ROS_DISTRO = 'jazzy'
#: keep-last depth of the data topics' publishers (cvj_ros.nodes.qos.DATA_DEPTH)
DATA_DEPTH = 10000
#: rmw's RMW_DURATION_INFINITE (INT64_MAX ns) as rosbag2 writes it
INFINITE = (9223372036, 854775807)
LATCHED_TOPICS = frozenset({'/driveline/scene'})


def offered_qos(topic: str) -> Any:
    """The rosbags ``Qos`` the publisher of ``topic`` offers (see the module docstring)."""
    from rosbags.interfaces import (Qos, QosDurability, QosHistory, QosLiveliness,
                                    QosReliability, QosTime)
    inf = QosTime(*INFINITE)
    latched = topic in LATCHED_TOPICS
    return Qos(history=QosHistory.KEEP_LAST, depth=1 if latched else DATA_DEPTH,
               reliability=QosReliability.RELIABLE,
               durability=QosDurability.TRANSIENT_LOCAL if latched else QosDurability.VOLATILE,
               deadline=inf, lifespan=inf, liveliness=QosLiveliness.AUTOMATIC,
               liveliness_lease_duration=inf, avoid_ros_namespace_conventions=False)


_ROSBAGS_DISTRO = 'ros_distro: rosbags'


def patch_ros_distro(writer: Any) -> None:
    """Make an open rosbags ``Writer`` record ``ros_distro: jazzy``: in the metadata its
    storage embeds at close (mcap metadata record, sqlite3 metadata table) and, through
    :func:`fix_metadata_file` after ``close()``, in metadata.yaml."""
    storage = writer.storage
    close = storage.close

    def close_with_distro(version: int, metadata: str) -> None:
        close(version, metadata.replace(_ROSBAGS_DISTRO, f'ros_distro: {ROS_DISTRO}'))
    storage.close = close_with_distro


def fix_metadata_file(bag: Path) -> None:
    """Rewrite ``bag/metadata.yaml``'s ``ros_distro: rosbags`` (rosbags' value) as jazzy
    (write to a temporary file, then rename, as rosbags does)."""
    meta = Path(bag) / 'metadata.yaml'
    text = meta.read_text(encoding='utf-8')
    if _ROSBAGS_DISTRO in text:
        tmp = meta.with_suffix('.yaml.tmp')
        tmp.write_text(text.replace(_ROSBAGS_DISTRO, f'ros_distro: {ROS_DISTRO}'), encoding='utf-8')
        tmp.replace(meta)
