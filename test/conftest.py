"""Test-wide settings: keep all DDS traffic on this machine, one ROS domain per test run."""
from __future__ import annotations

import os

os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
if 'ROS_DOMAIN_ID' not in os.environ or os.environ.get('CVJ_TEST_FRESH_DOMAIN'):
    # Domain ids 0..101 are safe for any participant count; derive one from the pid.
    os.environ['ROS_DOMAIN_ID'] = str(1 + os.getpid() % 100)
os.environ.setdefault('RMW_IMPLEMENTATION', 'rmw_fastrtps_cpp')


import pytest  # noqa: E402


@pytest.fixture
def ctx():
    """A fresh rclpy Context per test (initialised, shut down afterwards). rclpy is imported
    here, not at module level, so physics-only test runs do not need it."""
    import rclpy
    from rclpy.context import Context
    context = Context()
    rclpy.init(context=context)
    yield context
    if context.ok():
        rclpy.shutdown(context=context)
