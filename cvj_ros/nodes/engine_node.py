"""engine_node: answers each /driveline/joint_states sample with /engine/wrench.

``torque.z`` = engine torque on the crank (N m, positive along positive rotation) from
:func:`cvj_ros.physics.engine.engine_from_spec` at the crank shaft's speed (rad/s) and
unwrapped angle (rad); the stamp echoes the joint-state stamp, frame_id = the crank
shaft name (the scene's first inertia, e.g. ``engine_crank``). /engine/throttle
(std_msgs/Float64, 0..1) sets the pedal; NaN/inf/out-of-range values are rejected with an
ERROR diagnostic and not applied. With ``commands:=driver`` (a driver_node plays the scene's
schedule in lockstep) the n-th throttle sample belongs to the step of the schedule's n-th
throttle change, and the joint state t_k is answered only once the samples of the steps up to
k are in and applied (docs/ros.md, "Commands"). /engine/throttle_scale (std_msgs/Float64,
0..1, from the coupling node under a shift schedule) is the transmission's torque
intervention: the engine runs at pedal x scale; with ``throttle_scale:=lockstep`` the n-th
sample is the scale of the n-th joint state (the coupling node publishes one right before
each state: step n in lockstep) and that state is answered only once it is in.

Run alone: ``engine_node --ros-args -p scene:=kavz685_lever`` (waits for joint states).
"""
from __future__ import annotations

import math
import sys
from bisect import bisect_right
from collections import deque
from collections.abc import Sequence
from typing import Any

from std_msgs.msg import Float64

from cvj_ros.errors import CvjError
from cvj_ros.nodes.cdr import CdrError, decode_float64
from cvj_ros.nodes.common import (ERROR, NS_PER_S, OK, ParameterError, ParamSpec, TorqueResponder,
                                  declare_parameters, inertia_names, load_scene_param,
                                  load_yaml_mapping, run_node, scene_dict)
from cvj_ros.nodes.intra import loop_subscription
from cvj_ros.nodes.qos import (DATA_QOS, ENGINE_THROTTLE_SCALE_TOPIC, ENGINE_THROTTLE_TOPIC,
                               ENGINE_WRENCH_TOPIC)

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
    ParamSpec('commands', 'none', 'driver: a driver_node plays the scene\'s commands: schedule in '
              'lockstep; the joint state t_k is answered once the throttle samples of steps <= k '
              'are in (counted from the schedule); none: each sample applies on arrival',
              choices=('none', 'driver')),
    ParamSpec('throttle_scale', 'auto', 'lockstep: the coupling node\'s n-th /engine/throttle_scale '
              'sample is the factor on the pedal for the n-th joint state, which is answered once '
              'it is in; on_arrival: each sample applies when it arrives (free-run); auto: lockstep '
              'when the scene has a shift_schedule, else on_arrival',
              choices=('auto', 'lockstep', 'on_arrival')),
    ParamSpec('exchange_step', 0.0, 'exchange step of the loop [s] (commands:=driver); 0 = the '
              'scene exchange_step', lo=0.0, hi=3600.0),
    ParamSpec('duration', 0.0, 'simulated time of the run [s] (commands:=driver); 0 = the scene '
              'duration', lo=0.0, hi=1e9),
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
        # commands:=driver: step times (ns) of the driver's throttle samples, in order; the
        # samples taken (step ns, value or None when undecodable) not yet applied; the joint
        # states waiting for them
        self.throttle_steps: list[int] | None = None
        self._throttle_taken = 0
        self._throttle_queue: deque[tuple[int, float | None]] = deque()
        self._held_states: deque[tuple[int, tuple[int, int, str, float, float]]] = deque()
        self.throttle_waits = 0        # joint states answered only after their throttle came
        if p['commands'] == 'driver':
            self.throttle_steps = self._throttle_schedule(scene, p)
        # the shift schedule's torque intervention: the pedal (commanded, or the engine spec's)
        # times the scale in force; throttle_scale lockstep: the scales taken, in the order of
        # the joint states they go with
        self.pedal = float(engine.throttle)
        self.scale = 1.0
        self.scale_lockstep = (p['throttle_scale'] == 'lockstep' or (
            p['throttle_scale'] == 'auto' and getattr(scene, 'shift_schedule', None) is not None))
        self._scales: deque[float | None] = deque()
        self._scale_taken = 0          # samples received (index of the state of the next one)
        self._scale_state = -1         # index of the state whose scale is in force
        self._states_seen = 0          # joint states of the shaft taken so far
        self.start_answering(source=answering_source(engine), shaft=shaft, wrench_topic=ENGINE_WRENCH_TOPIC)
        # raw: a malformed sample is dropped by the checked decoder, not by rclpy's
        # deserialisation inside the executor (which raised out of spin())
        # (composed with driver_node: from the in-process bus, in order with the joint states)
        self.throttle_sub = loop_subscription(self, Float64, ENGINE_THROTTLE_TOPIC,
                                              self._on_throttle_raw, DATA_QOS)
        self.scale_sub = loop_subscription(self, Float64, ENGINE_THROTTLE_SCALE_TOPIC,
                                           self._on_scale_raw, DATA_QOS)
        describe = getattr(engine, 'describe', None)
        self.get_logger().info(f'engine {describe() if describe else type(engine).__name__} on shaft '
                               f'{shaft!r}; waiting for /driveline/joint_states')

    @staticmethod
    def _throttle_schedule(scene: Any, p: dict[str, Any]) -> list[int]:
        """Step times (ns) of the throttle samples a driver plays (commands:=driver)."""
        from cvj_ros.nodes.command_plan import CommandPlan
        if not scene.commands:
            raise ParameterError('commands', f'driver: {scene.name} has no commands: schedule')
        h_ns = int(round((p['exchange_step'] or scene.exchange_step) * NS_PER_S))
        if h_ns <= 0:
            raise ParameterError('exchange_step', f'must be >= 1 ns, got {p["exchange_step"]}')
        n_steps = int(round((p['duration'] or scene.duration) * NS_PER_S / h_ns))
        return CommandPlan.from_scene(scene, h_ns, n_steps).stamps('throttle')

    def _on_throttle_raw(self, data: bytes) -> None:
        """A serialised /engine/throttle sample: checked (:func:`decode_float64`), applied
        (commands:=driver: queued with its step, applied when the joint state of that step
        is answered, and a joint state held for it answered now)."""
        try:
            x: float | None = decode_float64(data)
        except CdrError as exc:
            self._drop(str(exc), ENGINE_THROTTLE_TOPIC)
            x = None
        if self.throttle_steps is None:
            if x is not None:
                self._on_throttle(Float64(data=x))
            return
        n = self._throttle_taken
        self._throttle_taken += 1       # the driver's n-th sample, even one that did not decode
        step = self.throttle_steps[n] if n < len(self.throttle_steps) else -1   # beyond: now
        self._throttle_queue.append((step, x))
        self._release_held()

    def _release_held(self) -> None:
        """Answer the held joint states whose throttle and scale are in, in order."""
        while self._held_states:
            n, state = self._held_states[0]
            if not self._due(state[0] * NS_PER_S + state[1], n):
                return
            self._held_states.popleft()
            super()._answer_state(*state)

    def _due(self, t_ns: int, n: int) -> bool:
        """The throttle samples (commands:=driver) of the step at t_ns and the scale
        (throttle_scale lockstep) of the n-th joint state are in: applied, True."""
        if self.scale_lockstep and not self._scale_due(n):
            return False
        return self.throttle_steps is None or self._throttle_due(t_ns)

    def _on_scale_raw(self, data: bytes) -> None:
        """A serialised /engine/throttle_scale sample: checked (:func:`decode_float64`, 0..1);
        applied now, or (lockstep) queued as the scale of the next step and applied when the
        joint state of that step is answered."""
        try:
            x: float | None = decode_float64(data)
        except CdrError as exc:
            self._drop(str(exc), ENGINE_THROTTLE_SCALE_TOPIC)
            x = None
        if x is not None and not (math.isfinite(x) and 0.0 <= x <= 1.0):
            self.throttle_rejected += 1
            self.report(ERROR, f'{ENGINE_THROTTLE_SCALE_TOPIC}: must be a finite value in 0..1, got '
                               f'{x}; not applied', {'rejected': self.throttle_rejected})
            x = None
        if not self.scale_lockstep:
            if x is not None:
                self._set_scale(x)
            return
        self._scales.append(x)          # the scale of state _scale_taken, even a bad one
        self._scale_taken += 1
        self._release_held()

    def _scale_due(self, n: int) -> bool:
        """The scale of the n-th joint state is in (lockstep): applied, True."""
        if n >= self._scale_taken:
            return False
        while self._scale_state < n:
            x = self._scales.popleft()
            self._scale_state += 1
            if x is not None:
                self._set_scale(x)
        return True

    def _set_scale(self, x: float) -> None:
        self.scale = x
        self.engine.set_throttle(self.pedal * x)

    def _throttle_due(self, t_ns: int) -> bool:
        """Every throttle sample of the steps up to t_ns is in: applied, True."""
        if bisect_right(self.throttle_steps, t_ns) > self._throttle_taken:
            return False
        queue = self._throttle_queue
        while queue and queue[0][0] <= t_ns:
            x = queue.popleft()[1]
            if x is not None:
                self._on_throttle(Float64(data=x))
        return True

    def _answer_state(self, sec: int, nanosec: int, frame: str, phi: float, omega: float) -> None:
        """Answer the joint state at (sec, nanosec); commands:=driver: once the throttle of
        its step is in force (the throttle of step k travels from the driver's process, the
        state t_k from the coupling node's: two publishers, no order between them)."""
        n = self._states_seen
        self._states_seen += 1
        if (self.throttle_steps is not None or self.scale_lockstep) and (
                self._held_states or not self._due(sec * NS_PER_S + nanosec, n)):
            self._held_states.append((n, (sec, nanosec, frame, phi, omega)))
            self.throttle_waits += 1
            return
        super()._answer_state(sec, nanosec, frame, phi, omega)

    def _on_throttle(self, msg: Float64) -> None:
        x = float(msg.data)
        if not math.isfinite(x) or not 0.0 <= x <= 1.0:
            self.throttle_rejected += 1
            self.report(ERROR, f'/engine/throttle: must be a finite value in 0..1, got {x}; not applied',
                        {'rejected': self.throttle_rejected})
            return
        try:
            self.engine.set_throttle(x * self.scale)
        except CvjError as exc:   # the model's own validation
            self.throttle_rejected += 1
            self.report(ERROR, f'/engine/throttle: {exc}; not applied', {'rejected': self.throttle_rejected})
            return
        self.throttle = self.pedal = x
        # a driver plays ramps as one sample per exchange step: say a change of >= 0.05 (and
        # the first), not every sample (1000 OK statuses a second swamped /diagnostics)
        if not abs(x - self._throttle_said) < THROTTLE_REPORT_STEP:
            self._throttle_said = x
            self.report(OK, f'throttle set to {x:g}', {'throttle': x})


def main(args: Sequence[str] | None = None) -> None:
    sys.exit(run_node(EngineNode, args, prog='engine_node'))


if __name__ == '__main__':
    main()
