"""A tiny outside road for `cvj-sim run VEHICLE_SCENE --external load`: answers every
/driveline/joint_states message with one /load/<wheel>/wrench per wheel, torque.z =
C_ROAD * omega_wheel (N m, a viscous road), the joint-state stamp echoed, frame_id the wheel.

Usage: python wheel_responder.py C_ROAD WHEEL [WHEEL ...]   (exits on SIGTERM/SIGINT)
"""
from __future__ import annotations

import signal
import sys


def main(argv: list[str]) -> int:
    import rclpy
    from geometry_msgs.msg import WrenchStamped
    from sensor_msgs.msg import JointState

    from cvj_ros.nodes.qos import DATA_QOS
    from cvj_ros.nodes.wheel_loads import wheel_wrench_topic
    c_road, wheels = float(argv[0]), argv[1:]
    rclpy.init()
    node = rclpy.create_node('wheel_responder')
    pubs = {w: node.create_publisher(WrenchStamped, wheel_wrench_topic(w), DATA_QOS) for w in wheels}

    def on_js(msg: JointState) -> None:
        names = list(msg.name)
        for w, pub in pubs.items():
            out = WrenchStamped()
            out.header.stamp = msg.header.stamp
            out.header.frame_id = w
            out.wrench.torque.z = c_road * msg.velocity[names.index(w)]
            pub.publish(out)

    node.create_subscription(JointState, '/driveline/joint_states', on_js, DATA_QOS)
    stop: list[int] = []
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda s, _f: stop.append(s))
    while not stop and rclpy.ok():
        rclpy.spin_once(node, timeout_sec=0.05)
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
