"""Run options and peers of a vehicle scene (wheels, differentials, tyres).

By default a vehicle scene's load is its tyres and vehicle body, integrated by coupling_node
as part of the tree's equations (cvj_ros.physics.tree); load_node answers /load/wrench with
0 N m so the lockstep protocol stays the chains' one. ``--external load`` instead leaves
load_node out and has outside nodes answer one ``/load/<wheel>/wrench`` per wheel
(coupling_node ``wheel_load:=external``, cvj_ros.nodes.wheel_loads); the run waits for, and
records, every wheel's topic. ``--load-from-bag`` is refused before anything starts: a
vehicle bag's /load/wrench is 0 N m (the tyres are inside), and replaying its per-wheel
answers would need load_node to answer every wheel topic from a series (not written).
"""
from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

from cvj_ros.errors import CvjError

__all__ = ['check_vehicle_options', 'wheel_names', 'vehicle_peers']


def check_vehicle_options(scene_path: Path, options: Any) -> None:
    """Refuse, in one line naming the option, what a vehicle scene cannot use.

    Raises:
        CvjError: ``--load-from-bag`` with a vehicle scene.
    """
    if options.load_from_bag is not None:
        raise CvjError(f'--load-from-bag: {scene_path.name} is a vehicle scene: its road load is '
                       'the tyres and vehicle body inside coupling_node (a vehicle bag\'s /load/wrench '
                       'is 0 N m), and replaying a bag\'s per-wheel /load/<wheel>/wrench is not '
                       'supported yet; outside wheel loads: --external load')


def wheel_names(scene: Any) -> list[str]:
    """The scene's wheels, depth first (their JointState shaft names)."""
    from cvj_ros.physics.scene import Wheel, iter_elements
    return [el.name for el in iter_elements(scene.driveline) if isinstance(el, Wheel)]


def vehicle_peers(scene: Any, external: Sequence[str]) -> tuple[dict[str, str], dict[str, str]] | None:
    """With ``--external load`` on a vehicle scene: (peer -> the topic it publishes, peer ->
    the --external value it stands for) for the run's start wait, one peer per wheel
    (``<wheel> load`` on ``/load/<wheel>/wrench``) instead of load_node; None otherwise
    (the chains' peers)."""
    if not getattr(scene, 'is_tree', False) or 'load' not in external:
        return None
    from cvj_ros.nodes.wheel_loads import wheel_wrench_topic
    topics = {'engine_node': '/engine/wrench'}
    outside = {'engine_node': 'engine'} if 'engine' in external else {}
    for w in wheel_names(scene):
        topics[f'{w} load'] = wheel_wrench_topic(w)
        outside[f'{w} load'] = 'load'
    return topics, outside
