"""cvj_ros.rosargs: ROS argument blocks are removed as rclpy removes them, and `cvj-sim`
accepts the command lines launch_ros builds."""
from __future__ import annotations

import pytest

from cvj_ros.rosargs import remove_ros_args

CASES = [
    ['p', 'a', '--ros-args'],
    ['p', 'a', '--ros-args', '-r', '__node:=x', '--', 'b'],
    ['p', 'a', '--', 'b'],
    ['p', '--ros-args', '--', '--', 'c'],
    ['p', '-a', '--ros-args', '--disable-stdout-logs', '--', '--ros-args'],
    ['p', 'record', 'out', '--until-idle', '2.0', '--ros-args', '-r', '__node:=rec',
     '--log-level', 'debug', '-e', '/enc'],
    ['p', '--ros-args', '-p', 'x:=1', '--ros-args', '-r', 'a:=b'],
]


@pytest.mark.parametrize('argv', CASES)
def test_same_as_rclpy(argv: list[str]) -> None:
    utilities = pytest.importorskip('rclpy.utilities')
    assert remove_ros_args(argv) == utilities.remove_ros_args(argv)


def test_params_file_block_is_dropped_without_reading_it() -> None:
    # rclpy opens the file (and fails on a missing one); here it is only dropped
    assert remove_ros_args(['record', 'o', '--ros-args', '--params-file', '/nonexistent']) == ['record', 'o']


def test_cvj_sim_ignores_ros_args(capsys: pytest.CaptureFixture[str]) -> None:
    from cvj_ros.cli import main
    assert main(['scenes', '--ros-args', '-r', '__node:=scenes', '--params-file', '/nonexistent']) == 0
    out, err = capsys.readouterr()
    assert 'fwd_halfshaft' in out and 'unrecognized' not in err
