"""Topic glob patterns read per name segment (cvj_ros/topic_pattern.py): ``*`` stays inside
one segment, a ``**`` segment spans any number of them; a selection also takes the topics
under a namespace it matches. Every pattern the docs show keeps selecting what it did."""
from __future__ import annotations

from pathlib import Path

import pytest

from cvj_ros import bag
from cvj_ros.errors import BagError
from cvj_ros.topic_pattern import topic_match, topic_selected


def test_star_stays_inside_one_segment() -> None:
    assert topic_match('/coupling/tripod/wrench', '/coupling/*/wrench')
    assert not topic_match('/coupling/a/b/wrench', '/coupling/*/wrench')    # fnmatch: True
    assert not topic_match('/driveline/a/b/wrench', '/driveline/*/wrench')
    assert not topic_match('/load/wrench', '/load/*/wrench')
    assert topic_match('/load/front_left/wrench', '/load/*/wrench')
    assert topic_match('/coupling/rzeppa_2/wrench', '/coupling/rzeppa_?/wrench')
    assert topic_match('/coupling/rzeppa_2/wrench', '/coupling/[rt]*/wrench')
    assert not topic_match('/coupling/a/b', '/coupling/a?b')                # ? is not /
    assert not topic_match('/clock', '/CLOCK')                             # case matters


def test_double_star_spans_segments() -> None:
    for topic in ('/coupling/wrench', '/coupling/a/wrench', '/coupling/a/b/wrench'):
        assert topic_match(topic, '/coupling/**/wrench')
    assert topic_match('/load/front_left/wrench', '/load/**')
    assert topic_match('/a/b/c', '**') and topic_match('/a/b/c', '**/c')
    assert not topic_match('/coupling/a/b/torque', '/coupling/**/wrench')


def test_selection_takes_the_topics_under_a_matched_namespace() -> None:
    """``/coupling/*`` and ``/load/*`` (the docs' examples) select the wrenches one level
    deeper, as before; ``/driveline/*/wrench`` still selects nothing two levels deeper."""
    assert topic_selected('/coupling/tripod/wrench', '/coupling/*')
    assert topic_selected('/load/wrench', '/load/*') and topic_selected('/load/front_left/wrench', '/load/*')
    assert not topic_selected('/driveline/a/b/wrench', '/driveline/*/wrench')
    assert topic_selected('/driveline/a/wrench', '/driveline/*/wrench')
    assert topic_selected('/clock', '/clock') and not topic_selected('/clockwork', '/clock')
    assert not topic_selected('/driveline/joint_states', '/drive')          # a segment, not a prefix


def test_contract_pattern_topics_are_one_level_deep() -> None:
    """The recorder subscribes to a graph topic when it has a contract type: a deeper topic
    is not a joint's or a wheel's wrench (fnmatch took /coupling/a/b/wrench for one)."""
    assert bag.topic_type('/coupling/tripod/wrench') == 'geometry_msgs/msg/WrenchStamped'
    assert bag.topic_type('/load/front_left/wrench') == 'geometry_msgs/msg/WrenchStamped'
    assert bag.topic_type('/coupling/a/b/wrench') is None
    assert bag.topic_type('/load/a/b/wrench') is None
    assert not bag.exchange_wrench_topic('/coupling/a/b/wrench')
    assert bag.exchange_wrench_topic('/coupling/tripod/wrench')


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_bag_reading_selects_per_segment(tmp_path: Path, storage: str) -> None:
    """read_raw / read_bag with patterns on a bag that also holds a deeper wrench topic."""
    ts = bag.typestore()
    W = ts.types['geometry_msgs/msg/WrenchStamped']
    H = ts.types['std_msgs/msg/Header']
    T = ts.types['builtin_interfaces/msg/Time']
    V = ts.types['geometry_msgs/msg/Vector3']
    Wr = ts.types['geometry_msgs/msg/Wrench']
    data = bytes(ts.serialize_cdr(W(header=H(stamp=T(sec=0, nanosec=0), frame_id='x'),
                                    wrench=Wr(force=V(x=0.0, y=0.0, z=0.0),
                                              torque=V(x=0.0, y=0.0, z=1.0))),
                                  'geometry_msgs/msg/WrenchStamped'))
    topics = ['/coupling/tripod/wrench', '/coupling/a/b/wrench', '/load/wrench', '/load/front_left/wrench']
    path = tmp_path / 'b'
    with bag.BagWriter(path, storage=storage) as w:
        for topic in topics:
            w.add_topic(topic, 'geometry_msgs/msg/WrenchStamped')
        for topic in topics:
            w.write(topic, 0, data)

    def chosen(patterns: list[str]) -> set[str]:
        return {t for t, _ty, _ts, _d in bag.read_raw(path, patterns)}

    assert chosen(['/coupling/*/wrench']) == {'/coupling/tripod/wrench'}
    assert chosen(['/coupling/**/wrench']) == {'/coupling/tripod/wrench', '/coupling/a/b/wrench'}
    assert chosen(['/coupling/*']) == {'/coupling/tripod/wrench', '/coupling/a/b/wrench'}
    assert chosen(['/load/*']) == {'/load/wrench', '/load/front_left/wrench'}
    assert set(bag.read_bag(path, ['/coupling/*/wrench'])) == {'/coupling/tripod/wrench'}
    with pytest.raises(BagError, match=r'^/load/\*/x: topic not in bag'):
        bag.read_raw(path, ['/load/*/x'])
