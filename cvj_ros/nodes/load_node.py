"""load_node: answers each /driveline/joint_states sample with /load/wrench.

``torque.z`` = resisting torque on the output shaft (N m, positive opposes positive
rotation) from :func:`cvj_ros.physics.load.load_from_spec` (every load model: constant,
random, fourier, road, brake_steps, time_series and their sums) at the output shaft's
speed (rad/s) and unwrapped angle (rad); stamp echoes the joint-state stamp, frame_id =
the output shaft name (the scene's last inertia). ``load_override`` replaces the scene
load by a recorded torque time series (``.npz`` or YAML with ``t`` [s] and ``torque``
[N m]; e.g. the /load/wrench of an earlier bag).

Run alone: ``load_node --ros-args -p scene:=kavz685_lever`` (waits for joint states).
"""
from __future__ import annotations

import sys
from collections.abc import Sequence
from typing import Any

from cvj_ros.errors import CvjError
from cvj_ros.nodes.common import (ParameterError, ParamSpec, TorqueResponder, declare_parameters,
                                  inertia_names, load_scene_param, load_torque_series_file,
                                  run_node, scene_dict, scene_seed)
from cvj_ros.nodes.qos import LOAD_WRENCH_TOPIC

PARAMS = (
    ParamSpec('scene', '', 'scene name (e.g. kavz685_lever) or scene YAML path'),
    ParamSpec('seed', -1, 'random seed of the random load; -1 = the scene seed',
              lo=-1, hi=2**31 - 1),
    ParamSpec('load_spec', '', 'YAML mapping or list replacing the scene load spec '
              '(e.g. "{model: constant, Mc: 100}"); empty = the scene load'),
    ParamSpec('load_override', '', 'path of a load torque time series (.npz or YAML with t [s], '
              'torque [N m]) used instead of the scene load; empty = none'),
    ParamSpec('output_shaft', '', 'JointState name of the output shaft; empty = the scene last inertia'),
)


def build_load(scene: Any, p: dict[str, Any]) -> Any:
    """The load model the parameters ask for (scene load, ``load_spec`` or ``load_override``;
    a vehicle scene without either: 0 N m, :func:`vehicle_scene_load`)."""
    import yaml

    from cvj_ros.physics import load as load_mod
    if getattr(scene, 'is_tree', False) and not (p['load_override'] or p['load_spec'].strip()):
        return vehicle_scene_load()
    seed = scene_seed(scene, p['seed'])
    if p['load_override']:
        t, torque = load_torque_series_file('load_override', p['load_override'])
        try:
            return load_mod.TimeSeriesLoad.from_arrays(t, torque, field='load_override')
        except CvjError as exc:
            raise ParameterError('load_override', f'{p["load_override"]}: {exc}') from None
    field = 'load'
    spec: Any = scene_dict(scene)['load']
    if p['load_spec'].strip():
        field = 'load_spec'
        try:
            spec = yaml.safe_load(p['load_spec'])
        except yaml.YAMLError as exc:
            raise ParameterError('load_spec', f'not valid YAML: {str(exc).splitlines()[0]}') from None
    try:
        return load_mod.load_from_spec(spec, seed=seed, field=field)
    except CvjError as exc:
        raise ParameterError(field if field == 'load_spec' else 'scene', str(exc)) from None


def vehicle_scene_load() -> Any:
    """A vehicle scene's /load/wrench source: 0 N m. Its tyres and vehicle body are part of the
    tree's equations, which coupling_node integrates; the answer keeps the lockstep protocol
    the chains' one (same peers, same gate, a recorded /load/wrench per step)."""
    from cvj_ros.physics.load import ConstantLoad
    return ConstantLoad(torque=0.0)


def output_shaft(scene: Any) -> str:
    """JointState name the load answer reads: a chain's last inertia, a vehicle scene's last
    wheel (cvj_ros.physics.tree names a wheel shaft after its wheel)."""
    if getattr(scene, 'is_tree', False):
        from cvj_ros.physics.scene import Wheel, iter_elements
        return [el.name for el in iter_elements(scene.driveline) if isinstance(el, Wheel)][-1]
    return inertia_names(scene)[-1]


class LoadNode(TorqueResponder):
    """Load torque responder (see module docstring). Parameters: :data:`PARAMS`."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__('load_node', **kwargs)
        p = self.params = declare_parameters(self, PARAMS)
        scene = load_scene_param(p['scene'])
        self.scene = scene
        self.load = build_load(scene, p)
        shaft = p['output_shaft'] or output_shaft(scene)
        self.start_answering(source=self.load, shaft=shaft, wrench_topic=LOAD_WRENCH_TOPIC)
        describe = getattr(self.load, 'describe', None)
        self.get_logger().info(f'load {describe() if describe else type(self.load).__name__} on '
                               f'shaft {shaft!r}; waiting for /driveline/joint_states')


def main(args: Sequence[str] | None = None) -> None:
    sys.exit(run_node(LoadNode, args, prog='load_node'))


if __name__ == '__main__':
    main()
