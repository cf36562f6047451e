"""A bag's metadata.yaml has the fields and values `ros2 bag record` writes on ROS 2 Jazzy
(rosbag2 format version 9: rosbag2_storage's yaml.hpp and rosbag2_transport's qos.cpp),
for both storages: each topic's real offered QoS profile (so `ros2 bag play` re-latches
/driveline/scene) and ``ros_distro: jazzy``, in metadata.yaml and in the metadata the
storage file embeds."""
from __future__ import annotations

import sqlite3
from pathlib import Path

import pytest
import yaml

from cvj_ros import bag
from cvj_ros.bag_qos import DATA_DEPTH, INFINITE

# rosbag2 (Jazzy) metadata version 9, rosbag2_bagfile_information
BAGFILE_FIELDS = {'version', 'storage_identifier', 'duration', 'starting_time', 'message_count',
                  'topics_with_message_count', 'compression_format', 'compression_mode',
                  'relative_file_paths', 'files', 'custom_data', 'ros_distro'}
TOPIC_FIELDS = {'name', 'type', 'serialization_format', 'offered_qos_profiles', 'type_description_hash'}
QOS_FIELDS = {'history', 'depth', 'reliability', 'durability', 'deadline', 'lifespan', 'liveliness',
              'liveliness_lease_duration', 'avoid_ros_namespace_conventions'}
FILE_FIELDS = {'path', 'starting_time', 'duration', 'message_count'}


def _write_bag(path: Path, storage: str) -> None:
    ts = bag.typestore()
    String = ts.types['std_msgs/msg/String']
    Clock = ts.types['rosgraph_msgs/msg/Clock']
    Time = ts.types['builtin_interfaces/msg/Time']
    with bag.BagWriter(path, storage=storage) as w:
        w.add_topic(bag.SCENE_TOPIC)
        w.add_topic(bag.CLOCK_TOPIC)
        w.set_custom_data('cvj_ros.seed', '3')
        w.write(bag.SCENE_TOPIC, 0, ts.serialize_cdr(String(data='scene: {}'), 'std_msgs/msg/String'))
        for k in range(3):
            w.write(bag.CLOCK_TOPIC, k * 10**6,
                    ts.serialize_cdr(Clock(clock=Time(sec=0, nanosec=k * 10**6)), 'rosgraph_msgs/msg/Clock'))


def _qos_dict(durability: str, depth: int) -> dict:
    inf = {'sec': INFINITE[0], 'nsec': INFINITE[1]}
    return {'history': 'keep_last', 'depth': depth, 'reliability': 'reliable', 'durability': durability,
            'deadline': inf, 'lifespan': inf, 'liveliness': 'automatic',
            'liveliness_lease_duration': inf, 'avoid_ros_namespace_conventions': False}


@pytest.mark.parametrize('storage', bag.STORAGES)
def test_metadata_has_rosbag2_jazzy_fields(tmp_path: Path, storage: str) -> None:
    path = tmp_path / 'bag'
    _write_bag(path, storage)
    meta = yaml.safe_load((path / 'metadata.yaml').read_text())
    info = meta['rosbag2_bagfile_information']
    assert set(meta) == {'rosbag2_bagfile_information'}
    assert set(info) == BAGFILE_FIELDS
    assert info['version'] == 9 and info['ros_distro'] == 'jazzy'
    assert info['storage_identifier'] == storage and info['message_count'] == 4
    assert set(info['duration']) == {'nanoseconds'}
    assert set(info['starting_time']) == {'nanoseconds_since_epoch'}
    assert info['custom_data'] == {'cvj_ros.seed': '3'}
    assert all(set(f) == FILE_FIELDS for f in info['files'])
    topics = {t['topic_metadata']['name']: t for t in info['topics_with_message_count']}
    assert set(topics) == {bag.SCENE_TOPIC, bag.CLOCK_TOPIC}
    for name, entry in topics.items():
        md = entry['topic_metadata']
        assert set(md) == TOPIC_FIELDS and md['serialization_format'] == 'cdr'
        assert md['type_description_hash'].startswith('RIHS01_')
        (qos,) = md['offered_qos_profiles']          # a list of profiles, not a string
        assert set(qos) == QOS_FIELDS
    assert topics[bag.SCENE_TOPIC]['topic_metadata']['offered_qos_profiles'] == [_qos_dict('transient_local', 1)]
    assert topics[bag.CLOCK_TOPIC]['topic_metadata']['offered_qos_profiles'] == [_qos_dict('volatile', DATA_DEPTH)]
    assert topics[bag.CLOCK_TOPIC]['message_count'] == 3


@pytest.mark.parametrize('storage', bag.STORAGES)
def test_storage_file_embeds_the_same_distro_and_profiles(tmp_path: Path, storage: str) -> None:
    path = tmp_path / 'bag'
    _write_bag(path, storage)
    (data_file,) = [f for f in path.iterdir() if f.suffix in ('.mcap', '.db3')]
    if storage == 'sqlite3':
        con = sqlite3.connect(data_file)
        (embedded,) = con.execute('SELECT metadata FROM metadata').fetchone()
        qos = dict(con.execute('SELECT name, offered_qos_profiles FROM topics').fetchall())
        con.close()
        assert 'transient_local' in qos[bag.SCENE_TOPIC] and 'volatile' in qos[bag.CLOCK_TOPIC]
    else:
        embedded = data_file.read_bytes().decode('latin-1')
    assert 'ros_distro: jazzy' in embedded and 'ros_distro: rosbags' not in embedded
    # rosbags reads the profiles back
    from rosbags.interfaces import QosDurability
    from rosbags.rosbag2 import Reader
    with Reader(path) as reader:
        assert reader.ros_distro == 'jazzy'
        by_topic = {c.topic: c.ext.offered_qos_profiles for c in reader.connections}
    assert by_topic[bag.SCENE_TOPIC][0].durability == QosDurability.TRANSIENT_LOCAL
    assert by_topic[bag.SCENE_TOPIC][0].depth == 1


def test_profiles_are_the_publishers_profiles() -> None:
    """bag_qos (rclpy-free) states the profiles cvj_ros.nodes.qos gives the publishers."""
    qos = pytest.importorskip('cvj_ros.nodes.qos')
    from cvj_ros.bag_qos import offered_qos
    for topic, profile in ((bag.SCENE_TOPIC, qos.LATCHED_QOS), (bag.JOINT_STATES_TOPIC, qos.DATA_QOS),
                           ('/coupling/cv/wrench', qos.DATA_QOS)):
        got = offered_qos(topic)
        assert got.depth == profile.depth
        assert got.reliability.name == profile.reliability.name
        assert got.durability.name == profile.durability.name
        assert got.history.name == profile.history.name


@pytest.mark.parametrize('storage', bag.STORAGES)
def test_reindexed_bag_keeps_distro_and_profiles(tmp_path: Path, storage: str) -> None:
    from cvj_ros.reindex import reindex
    path = tmp_path / 'bag'
    _write_bag(path, storage)
    (path / 'metadata.yaml').unlink()            # as after a hard kill
    reindex(path)
    info = yaml.safe_load((path / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert info['ros_distro'] == 'jazzy'
    topics = {t['topic_metadata']['name']: t['topic_metadata'] for t in info['topics_with_message_count']}
    assert topics[bag.SCENE_TOPIC]['offered_qos_profiles'] == [_qos_dict('transient_local', 1)]
