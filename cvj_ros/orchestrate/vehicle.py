"""Run options that mean something else for a vehicle scene (wheels, differentials, tyres).

A vehicle scene's load is its tyres and vehicle body, integrated by coupling_node as part of
the tree's equations (cvj_ros.physics.tree); load_node answers /load/wrench with 0 N m so the
lockstep protocol stays the chains' one. Options that replace a chain's load torque have
nothing to act on there: they are refused before anything starts.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

from cvj_ros.errors import CvjError

__all__ = ['check_vehicle_options']


def check_vehicle_options(scene_path: Path, options: Any) -> None:
    """Refuse, in one line naming the option, what a vehicle scene cannot use.

    Raises:
        CvjError: ``--load-from-bag`` or ``--external load`` with a vehicle scene.
    """
    why = ('the road load of a vehicle scene is its tyres and vehicle body, integrated by '
           'coupling_node (cvj-sim simulate gives the same equations offline)')
    if options.load_from_bag is not None:
        raise CvjError(f'--load-from-bag: {scene_path.name} is a vehicle scene: {why}; '
                       'a recorded load torque has no shaft to act on')
    if 'load' in options.external:
        raise CvjError(f'--external: load: {scene_path.name} is a vehicle scene: {why}; '
                       'outside per-wheel loads (/load/<wheel>/wrench) are not wired yet')
