#!/usr/bin/env python3
"""An outside vehicle stack hooked into the cvj_ros driveline, written against standard
ROS 2 messages only (no cvj_ros import): what an integrator writes.

It plays two roles a vehicle software stack plays against a driveline:

* **driver**: publishes the pedal on ``/engine/throttle`` (std_msgs/Float64, 0..1) as a
  ramp over simulated time, from ``throttle_start`` to ``throttle_end`` in ``ramp_s``;
* **vehicle**: answers every ``/driveline/joint_states`` message with the road load on
  ``/load/wrench`` (geometry_msgs/WrenchStamped), in place of cvj_ros's ``load_node``.

What an answerer must echo (docs/ros.md, "Outside nodes"): the answer's ``header.stamp``
is the joint-state ``header.stamp`` it answers (copying the whole header does it; the
run knows its peers by their publishers, not by the frame_id). ``torque.z``
is the resisting torque on the output shaft in N m (positive opposes positive rotation).
Do not stamp the answer with ``get_clock().now()``: under ``use_sim_time`` it can lag the
joint state by a step; echoing is always right.

Road load at the wheel (SI units): wheel speed omega (rad/s) -> vehicle speed
v = omega r_w (m/s), force F = m g c_r + 1/2 rho c_d A v |v| + m g sin(grade) (N),
torque T = F r_w (N m); the rolling term is smoothed through zero speed
(tanh(v / 0.1 m/s)) so a standstill start is not a step.

Run it next to the driveline, e.g. ``cvj-sim run fwd_halfshaft --out runs/stack --external
load`` and in another shell ``python3 examples/vehicle_stack.py --ros-args -p
use_sim_time:=true``. Parameters: ``output_shaft`` (JointState name of the wheel,
default ``wheel``), ``mass`` (kg), ``wheel_radius`` (m), ``rolling_coeff``,
``drag_coeff``, ``frontal_area`` (m^2), ``air_density`` (kg/m^3), ``grade`` (rad),
``throttle_start``, ``throttle_end``, ``ramp_s`` (s), ``max_answers`` (stop after that
many answers; 0 = run until Ctrl-C).
"""
from __future__ import annotations

import math
import sys

import rclpy
from rclpy.executors import ExternalShutdownException
from geometry_msgs.msg import WrenchStamped
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64

G = 9.80665  # m/s^2


class VehicleStack(Node):
    """Throttle ramp out, road load answered on every joint state."""

    def __init__(self) -> None:
        super().__init__('vehicle_stack')
        p = {
            'output_shaft': 'wheel', 'mass': 1300.0, 'wheel_radius': 0.3, 'rolling_coeff': 0.012,
            'drag_coeff': 0.3, 'frontal_area': 2.2, 'air_density': 1.2, 'grade': 0.0,
            'throttle_start': 0.2, 'throttle_end': 0.6, 'ramp_s': 2.0, 'max_answers': 0,
        }
        for name, default in p.items():
            self.declare_parameter(name, default)
        self.prm = {name: self.get_parameter(name).value for name in p}
        qos = QoSProfile(depth=100, history=HistoryPolicy.KEEP_LAST,
                         reliability=ReliabilityPolicy.RELIABLE)
        self.load_pub = self.create_publisher(WrenchStamped, '/load/wrench', qos)
        self.throttle_pub = self.create_publisher(Float64, '/engine/throttle', qos)
        self.create_subscription(JointState, '/driveline/joint_states', self.on_joint_states, qos)
        self.index: int | None = None
        self.answers = 0
        self.last_throttle: float | None = None
        self.done = False

    def road_torque(self, omega: float) -> float:
        """Resisting torque at the wheel (N m) for wheel speed ``omega`` (rad/s)."""
        p = self.prm
        r = p['wheel_radius']
        v = omega * r
        rolling = p['mass'] * G * p['rolling_coeff'] * math.tanh(v / 0.1)
        drag = 0.5 * p['air_density'] * p['drag_coeff'] * p['frontal_area'] * v * abs(v)
        climb = p['mass'] * G * math.sin(p['grade'])
        return (rolling + drag + climb) * r

    def throttle_at(self, t: float) -> float:
        """Pedal ramp over simulated time ``t`` (s), 0..1."""
        p = self.prm
        u = 1.0 if p['ramp_s'] <= 0 else min(max(t / p['ramp_s'], 0.0), 1.0)
        return min(max(p['throttle_start'] + u * (p['throttle_end'] - p['throttle_start']), 0.0), 1.0)

    def on_joint_states(self, msg: JointState) -> None:
        if self.done:
            return
        if self.index is None:
            try:
                self.index = list(msg.name).index(self.prm['output_shaft'])
            except ValueError:
                self.get_logger().error(
                    f"output_shaft: {self.prm['output_shaft']!r} is not in /driveline/joint_states "
                    f"(names: {', '.join(msg.name)})")
                self.done = True
                return
        t = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec
        throttle = round(self.throttle_at(t), 3)   # publish only when the pedal moved
        if throttle != self.last_throttle:
            self.throttle_pub.publish(Float64(data=throttle))
            self.last_throttle = throttle
        answer = WrenchStamped()
        answer.header.stamp = msg.header.stamp          # echo the stamp ...
        answer.header.frame_id = msg.header.frame_id    # ... and the frame_id
        answer.wrench.torque.z = self.road_torque(float(msg.velocity[self.index]))
        self.load_pub.publish(answer)
        self.answers += 1
        if self.prm['max_answers'] and self.answers >= self.prm['max_answers']:
            self.done = True


def main(args: list[str] | None = None) -> int:
    rclpy.init(args=args)
    node = VehicleStack()
    try:
        while rclpy.ok() and not node.done:
            rclpy.spin_once(node, timeout_sec=0.1)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass   # Ctrl-C / SIGTERM: rclpy's handler may shut the context down mid-spin
    finally:
        answered = node.answers
        node.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()
    print(f'vehicle_stack: answered {answered} joint states', file=sys.stderr)
    return 0


if __name__ == '__main__':
    sys.exit(main())
