"""Run identity by publisher: which endpoints publish a topic, named for one error line.

A run knows its peers by the publishers its subscriptions matched, never by anything a
message carries (a header can be copied). Jazzy's rclpy gives no per-message publisher GID
(its message info holds timestamps and sequence numbers only, checked by introspection),
so the loop holds the rule on the matched endpoints instead: a loop topic has exactly one
publisher, the one matched when the run started; a second one makes whatever arrives on
that topic unattributable, and the run stops with one line naming it (docs/ros.md,
"Run identity"). This module reads the ROS graph for those lines.
"""
from __future__ import annotations

from typing import Any, NamedTuple

__all__ = ['UNKNOWN_NODE', 'WRENCH_TYPE', 'Endpoint', 'describe', 'named_publisher_endpoints',
           'other_type_publishers', 'publisher_endpoints', 'strangers', 'wrong_type_reason']

#: the type of every peer answer topic (/engine/wrench, /load/wrench, /load/<wheel>/wrench)
WRENCH_TYPE = 'geometry_msgs/msg/WrenchStamped'


class Endpoint(NamedTuple):
    """One publisher in the ROS graph: ``node`` as ``/<namespace>/<name>``, ``gid`` hex."""
    node: str
    gid: str


#: what rmw reports for an endpoint whose node is not known yet (DDS discovered the endpoint,
#: the node-to-endpoint mapping has not arrived)
UNKNOWN_NODE = '_NODE_NAME_UNKNOWN_'


def _node_path(namespace: str, name: str) -> str:
    if name == UNKNOWN_NODE:
        return 'a node not yet named in the ROS graph'
    return f'{namespace.rstrip("/")}/{name}'


def named_publisher_endpoints(node: Any, topic: str, wait_s: float = 0.2) -> list[Endpoint]:
    """:func:`publisher_endpoints`, waiting up to ``wait_s`` (polling every 10 ms) while
    an endpoint's node is not named yet (for an error line, once)."""
    import time
    deadline = time.monotonic() + wait_s
    while True:
        endpoints = publisher_endpoints(node, topic)
        if all(not e.node.startswith('a node not yet') for e in endpoints) or time.monotonic() > deadline:
            return endpoints
        time.sleep(0.01)


def publisher_endpoints(node: Any, topic: str) -> list[Endpoint]:
    """The publishers of ``topic`` in ``node``'s view of the ROS graph (sorted by GID)."""
    out = []
    for info in node.get_publishers_info_by_topic(topic):
        gid = bytes(info.endpoint_gid).hex()
        out.append(Endpoint(_node_path(info.node_namespace, info.node_name), gid))
    return sorted(out, key=lambda e: e.gid)


def strangers(endpoints: list[Endpoint], known: frozenset[str]) -> list[Endpoint]:
    """The endpoints whose GID is not in ``known``."""
    return [e for e in endpoints if e.gid not in known]


def describe(endpoints: list[Endpoint]) -> str:
    """``/engine_node (gid 01.., ), /intruder (gid ..)``: node names with their GIDs."""
    return ', '.join(f'{e.node} (gid {e.gid})' for e in endpoints) or 'none in the ROS graph yet'


def other_type_publishers(node: Any, topic: str, expected: str = WRENCH_TYPE) -> str:
    """``/my_stack as std_msgs/msg/String``: the publishers of ``topic`` in ``node``'s view of
    the ROS graph whose type is not ``expected`` ('' when none, or without a node). A
    subscription never matches them, so a wait for its publisher count cannot see them."""
    if node is None:
        return ''
    return ', '.join(f'{_node_path(i.node_namespace, i.node_name)} as {i.topic_type}'
                     for i in node.get_publishers_info_by_topic(topic) if i.topic_type != expected)


def wrong_type_reason(node: Any, option: str, topic: str, domain: Any, timeout: float) -> str:
    """The ``--external`` line for an awaited wrench ``topic`` that only publishers of another
    type answered (:func:`other_type_publishers`), or '' when there are none."""
    wrong = other_type_publishers(node, topic)
    if not wrong:
        return ''
    return (f'--external {option}: {topic} is published by {wrong}, not {WRENCH_TYPE}, on '
            f'ROS_DOMAIN_ID={domain} (no {WRENCH_TYPE} publisher within '
            f'--external-timeout={timeout:g} s)')
