"""Thin rclpy adapters around :mod:`cvj_ros.physics`; one node class per module."""
