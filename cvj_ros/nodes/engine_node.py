"""engine_node: answers each /driveline/joint_states sample with /engine/wrench.

``torque.z`` = engine torque on the crank (N m, positive along positive rotation) from
:func:`cvj_ros.physics.engine.engine_from_spec` at the crank shaft's speed (rad/s) and
unwrapped angle (rad); the stamp echoes the joint-state stamp, frame_id = the crank
shaft name (the scene's first inertia, e.g. ``engine_crank``). /engine/throttle
(std_msgs/Float64, 0..1) sets the pedal; NaN/inf/out-of-range values are rejected with an
ERROR diagnostic and not applied.

Run alone: ``engine_node --ros-args -p scene:=kavz685_lever`` (waits for joint states).
"""
from __future__ import annotations

import math
import sys
from collections.abc import Sequence
from typing import Any

from std_msgs.msg import Float64

from cvj_ros.errors import CvjError
from cvj_ros.nodes.cdr import CdrError, decode_float64
from cvj_ros.nodes.common import (ERROR, OK, ParameterError, ParamSpec, TorqueResponder,
                                  declare_parameters, inertia_names, load_scene_param,
                                  load_yaml_mapping, run_node, scene_dict)
from cvj_ros.nodes.intra import loop_subscription
from cvj_ros.nodes.qos import DATA_QOS, ENGINE_THROTTLE_TOPIC, ENGINE_WRENCH_TOPIC

#: a throttle change this large (or the first sample) is said on /diagnostics
THROTTLE_REPORT_STEP = 0.05

PARAMS = (
    ParamSpec('scene', '', 'scene name (e.g. kavz685_lever) or scene YAML path'),
    ParamSpec('seed', -1, 'random seed; -1 = the scene seed (the engine models are deterministic)',
              lo=-1, hi=2**31 - 1),
    ParamSpec('throttle', -1.0, 'initial pedal position [0..1]; -1 keeps the engine spec setting',
              lo=-1.0, hi=1.0),
    ParamSpec('engine_spec', '', 'YAML mapping replacing the scene engine spec '
              '(e.g. "{model: linear, m1: 600, k1: 12}"); empty = the scene engine'),
    ParamSpec('crank_shaft', '', 'JointState name of the crank shaft; empty = the scene first inertia'),
)


def answering_source(engine: Any) -> Any:
    """What the node evaluates per answer: a map engine through the compiled formula
    (:class:`cvj_ros.physics.kernel.sources_nb.CompiledMapEngineTorque`), any other engine
    as it is."""
    from cvj_ros.physics.engine import MapEngine
    if type(engine) is MapEngine:
        try:
            from cvj_ros.physics.kernel.sources_nb import CompiledMapEngineTorque
            return CompiledMapEngineTorque(engine)
        except ImportError:      # no numba: the Python formula
            return engine
    return engine


class EngineNode(TorqueResponder):
    """Engine torque responder (see module docstring). Parameters: :data:`PARAMS`."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__('engine_node', **kwargs)
        p = self.params = declare_parameters(self, PARAMS)
        scene = load_scene_param(p['scene'])
        if p['throttle'] != -1.0 and not 0.0 <= p['throttle'] <= 1.0:
            raise ParameterError('throttle', f'must be in 0..1 (or -1 = scene), got {p["throttle"]}')
        spec = load_yaml_mapping('engine_spec', p['engine_spec']) or dict(scene_dict(scene)['engine'])
        from cvj_ros.physics.engine import engine_from_spec
        try:
            engine = engine_from_spec(spec, field='engine_spec' if p['engine_spec'] else 'engine')
        except CvjError as exc:
            raise ParameterError('engine_spec' if p['engine_spec'] else 'scene', str(exc)) from None
        if p['throttle'] >= 0.0:
            engine.set_throttle(p['throttle'])
        shaft = p['crank_shaft'] or inertia_names(scene)[0]
        self.scene = scene
        self.engine = engine
        self.throttle = p['throttle'] if p['throttle'] >= 0.0 else float('nan')
        self.throttle_rejected = 0
        self._throttle_said = float('nan')      # the throttle last said on /diagnostics
        self.start_answering(source=answering_source(engine), shaft=shaft, wrench_topic=ENGINE_WRENCH_TOPIC)
        # raw: a malformed sample is dropped by the checked decoder, not by rclpy's
        # deserialisation inside the executor (which raised out of spin())
        # (composed with driver_node: from the in-process bus, in order with the joint states)
        self.throttle_sub = loop_subscription(self, Float64, ENGINE_THROTTLE_TOPIC,
                                              self._on_throttle_raw, DATA_QOS)
        describe = getattr(engine, 'describe', None)
        self.get_logger().info(f'engine {describe() if describe else type(engine).__name__} on shaft '
                               f'{shaft!r}; waiting for /driveline/joint_states')

    def _on_throttle_raw(self, data: bytes) -> None:
        """A serialised /engine/throttle sample: checked (:func:`decode_float64`), applied."""
        try:
            x = decode_float64(data)
        except CdrError as exc:
            self._drop(str(exc), ENGINE_THROTTLE_TOPIC)
            return
        self._on_throttle(Float64(data=x))

    def _on_throttle(self, msg: Float64) -> None:
        x = float(msg.data)
        if not math.isfinite(x) or not 0.0 <= x <= 1.0:
            self.throttle_rejected += 1
            self.report(ERROR, f'/engine/throttle: must be a finite value in 0..1, got {x}; not applied',
                        {'rejected': self.throttle_rejected})
            return
        try:
            self.engine.set_throttle(x)
        except CvjError as exc:   # the model's own validation
            self.throttle_rejected += 1
            self.report(ERROR, f'/engine/throttle: {exc}; not applied', {'rejected': self.throttle_rejected})
            return
        self.throttle = x
        # a driver plays ramps as one sample per exchange step: say a change of >= 0.05 (and
        # the first), not every sample (1000 OK statuses a second swamped /diagnostics)
        if not abs(x - self._throttle_said) < THROTTLE_REPORT_STEP:
            self._throttle_said = x
            self.report(OK, f'throttle set to {x:g}', {'throttle': x})


def main(args: Sequence[str] | None = None) -> None:
    sys.exit(run_node(EngineNode, args, prog='engine_node'))


if __name__ == '__main__':
    main()
