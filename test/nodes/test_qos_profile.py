"""The Fast DDS profile a run's processes get (cvj_ros/nodes/qos.py): well-formed, with the
20 ms writer heartbeat and the 0.25 s participant announcement, written only when the user set
no profile file; process_dds_profile sets the file for one block of this process and restores."""
from __future__ import annotations

import os
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from cvj_ros.nodes import qos

NS = {'p': 'http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles'}
KEY = 'FASTRTPS_DEFAULT_PROFILES_FILE'


def _ns(elem: ET.Element | None) -> float:
    assert elem is not None
    return float(elem.findtext('p:sec', namespaces=NS)) + float(elem.findtext('p:nanosec', namespaces=NS)) * 1e-9


def test_profile_is_wellformed_with_heartbeat_and_announcement_period() -> None:
    root = ET.fromstring(qos.FASTDDS_PROFILE.encode())
    part = root.find('p:participant', NS)
    assert part is not None and part.get('is_default_profile') == 'true'
    lease = part.find('p:rtps/p:builtin/p:discovery_config/p:leaseAnnouncement', NS)
    assert _ns(lease) == pytest.approx(0.25)           # Fast DDS default: 3 s
    pub = root.find('p:publisher', NS)
    assert pub is not None and pub.get('is_default_profile') == 'true'
    assert _ns(pub.find('p:times/p:heartbeatPeriod', NS)) == pytest.approx(0.02)


def test_dds_environment_writes_the_profile_unless_the_user_set_one(tmp_path: Path) -> None:
    env: dict[str, str] = {'RMW_IMPLEMENTATION': 'rmw_fastrtps_cpp'}
    qos.dds_environment(env, profile_dir=str(tmp_path))
    assert Path(env[KEY]).read_text() == qos.FASTDDS_PROFILE
    assert env['RMW_FASTRTPS_PUBLICATION_MODE'] == 'SYNCHRONOUS'
    mine = {'RMW_IMPLEMENTATION': 'rmw_fastrtps_cpp', KEY: '/elsewhere.xml'}
    qos.dds_environment(mine, profile_dir=str(tmp_path / 'x'))
    assert mine[KEY] == '/elsewhere.xml' and not (tmp_path / 'x').exists()


def test_process_dds_profile_sets_and_restores(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv(KEY, raising=False)
    with qos.process_dds_profile({KEY: '/run/fastdds_profile.xml'}):
        assert os.environ[KEY] == '/run/fastdds_profile.xml'
    assert KEY not in os.environ
    monkeypatch.setenv(KEY, '/user.xml')                  # the user's file wins
    with qos.process_dds_profile({KEY: '/run/fastdds_profile.xml'}):
        assert os.environ[KEY] == '/user.xml'
    assert os.environ[KEY] == '/user.xml'
    monkeypatch.delenv(KEY)
    with qos.process_dds_profile({}):                     # no profile (not Fast DDS)
        assert KEY not in os.environ


def test_a_hand_started_node_takes_the_runs_delivery_settings_unless_the_user_set_them(
        tmp_path: Path, monkeypatch) -> None:
    """node_dds_defaults (called before a node process's or `cvj-sim record`'s first
    participant): synchronous publication and the 20 ms heartbeat profile where unset; the
    RMW and the discovery range untouched; the user's values win; another RMW gets nothing."""
    import tempfile
    for key in ('RMW_FASTRTPS_PUBLICATION_MODE', 'FASTRTPS_DEFAULT_PROFILES_FILE',
                'FASTDDS_DEFAULT_PROFILES_FILE', 'RMW_IMPLEMENTATION', 'ROS_AUTOMATIC_DISCOVERY_RANGE'):
        monkeypatch.delenv(key, raising=False)
    monkeypatch.setattr(tempfile, 'gettempdir', lambda: str(tmp_path))
    qos.node_dds_defaults()
    assert os.environ['RMW_FASTRTPS_PUBLICATION_MODE'] == 'SYNCHRONOUS'
    path = Path(os.environ['FASTRTPS_DEFAULT_PROFILES_FILE'])
    assert path.parent.parent == tmp_path and path.read_text() == qos.FASTDDS_PROFILE
    assert 'RMW_IMPLEMENTATION' not in os.environ and 'ROS_AUTOMATIC_DISCOVERY_RANGE' not in os.environ
    assert [p.name for p in path.parent.iterdir()] == [path.name]     # no temporary left behind

    monkeypatch.setenv('RMW_FASTRTPS_PUBLICATION_MODE', 'ASYNCHRONOUS')
    monkeypatch.setenv('FASTRTPS_DEFAULT_PROFILES_FILE', '/mine.xml')
    qos.node_dds_defaults()
    assert os.environ['RMW_FASTRTPS_PUBLICATION_MODE'] == 'ASYNCHRONOUS'
    assert os.environ['FASTRTPS_DEFAULT_PROFILES_FILE'] == '/mine.xml'

    for key in ('RMW_FASTRTPS_PUBLICATION_MODE', 'FASTRTPS_DEFAULT_PROFILES_FILE'):
        monkeypatch.delenv(key)
    monkeypatch.setenv('RMW_IMPLEMENTATION', 'rmw_cyclonedds_cpp')
    qos.node_dds_defaults()
    assert 'RMW_FASTRTPS_PUBLICATION_MODE' not in os.environ
    assert 'FASTRTPS_DEFAULT_PROFILES_FILE' not in os.environ
