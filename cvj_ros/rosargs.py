"""ROS arguments on a command line that is not (only) a ROS node's: strip them.

launch_ros's ``Node`` action appends ``--ros-args [-r __node:=NAME] [--params-file FILE]`` to
every command line it starts, also to programs that are no rclpy node (``cvj-sim record``
in launch/driveline.launch.py). :func:`remove_ros_args` drops them as rclpy's
``rclpy.utilities.remove_ros_args`` does (rcl's ``rcl_remove_ros_arguments``): every block
from ``--ros-args`` up to and including the next ``--`` (or the end of the line), without
importing rclpy and without checking what the block holds (ignored, so never an error).
"""
from __future__ import annotations

from collections.abc import Sequence

__all__ = ['ROS_ARGS_FLAG', 'ROS_ARGS_END', 'remove_ros_args']

ROS_ARGS_FLAG = '--ros-args'
ROS_ARGS_END = '--'


def remove_ros_args(argv: Sequence[str]) -> list[str]:
    """``argv`` without its ROS argument blocks (``--ros-args ... [--]``), other tokens in order.

    A ``--`` outside a block stays (it belongs to the program's own parser).
    """
    out: list[str] = []
    inside = False
    for token in argv:
        if inside:
            if token == ROS_ARGS_END:
                inside = False
            continue
        if token == ROS_ARGS_FLAG:
            inside = True
            continue
        out.append(token)
    return out
