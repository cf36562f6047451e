"""The README's hand-start recipe, run as written with real processes, in several start
orders, each shell started once the previous one is up: every order gives a complete bag.

The recipe: ``coupling_node``, ``engine_node``, ``load_node``, ``monitor_node`` (each
``--ros-args -p scene:=...``) and ``cvj-sim record OUT --until-idle 2``, no other
parameter. The coupling node's defaults make it wait, without deadline, for 4 subscribers
of the joint states (engine, load, monitor, recorder) before step 0.

Each shell is started once the previous shell's node is up: the test waits until its
node name is in the ROS graph (:func:`_wait_for_node`), which stands for a person's 20 s or
more between shells. Equivalent because before step 0 nothing in these processes depends
on how long the wait lasts: the coupling node has no start deadline by default and only
polls the graph (every 10 ms) and logs who is missing every START_REPORT_S; engine, load
and monitor wait for joint states without any timer; the recorder's --until-idle clock
starts at the run's first message (not at the latched scene message the coupling node
sends while it waits). A wait longer than START_REPORT_S (5 s) in total before the last
peer also shows the waiting line. What the wait's length changes is only the number of
those lines. (The waits replace fixed 3 s pauses, 12 s per order, which did not make the
order sure where a start takes longer; measured waits: docs/benchmark.md "Test suite time".)
"""
from __future__ import annotations

import importlib.util
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

pytestmark = [pytest.mark.e2e, pytest.mark.ros]

# the complete-bag check, the process start/stop and the scene of the launch-equivalent run
_spec = importlib.util.spec_from_file_location(
    '_launch_processes', Path(__file__).parents[1] / 'launch' / 'test_launch_processes.py')
_launch = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(_launch)
check_complete_bag = _launch.check_complete_bag

BIN = Path(sys.executable).parent
# the node name each shell's process creates (the recorder: cvj_ros/orchestrate/recorder.py)
NODE_NAME = {'coupling_node': 'coupling_node', 'engine_node': 'engine_node',
             'load_node': 'load_node', 'monitor_node': 'monitor_node', 'record': 'cvj_recorder'}
# bound on one process's start up to its node in the graph: a hung start, not a timing
# budget (the test prints the waits; docs/benchmark.md "Test suite time")
START_BOUND_S = 120.0
N = _launch.N       # exchange steps of the shared scene (0.3 s at 1 ms)
SCENE = {**_launch.SCENE, 'name': 'hand_start', 'description': 'hand-started nodes', 'seed': 4}


README_ORDER = ('coupling_node', 'engine_node', 'load_node', 'monitor_node', 'record')


def _recipe(scene: Path, out: Path) -> dict[str, list[str]]:
    """The README recipe's command lines (venv console scripts)."""
    cmds = {n: [str(BIN / n), '--ros-args', '-p', f'scene:={scene}']
            for n in ('coupling_node', 'engine_node', 'load_node', 'monitor_node')}
    cmds['record'] = [str(BIN / 'cvj-sim'), 'record', str(out), '--until-idle', '2']
    return cmds


def _wait_for_node(observer, name: str, proc: subprocess.Popen, log: Path) -> float:
    """Return the seconds waited until node ``name`` is in the ROS graph seen by
    ``observer`` (polled every 20 ms); fail with the process's log if it exits first or
    START_BOUND_S passes."""
    t0 = time.monotonic()
    while name not in observer.get_node_names():
        assert proc.poll() is None, (name, proc.returncode, log.read_text()[-3000:])
        assert time.monotonic() - t0 < START_BOUND_S, (name, 'not in the graph',
                                                       log.read_text()[-3000:])
        time.sleep(0.02)
    return time.monotonic() - t0


@pytest.mark.parametrize('order', [
    README_ORDER,                                                  # coupling first, recorder last
    tuple(reversed(README_ORDER)),                                 # recorder first, coupling last
    ('engine_node', 'record', 'coupling_node', 'monitor_node', 'load_node'),
], ids=['readme', 'reversed', 'mixed'])
def test_recipe_in_any_order_records_a_complete_bag(tmp_path: Path, order: tuple[str, ...],
                                                    ctx) -> None:
    import rclpy
    scene = tmp_path / 'scene.yaml'
    scene.write_text(yaml.safe_dump(SCENE, sort_keys=False))
    cmds = _recipe(scene, tmp_path / 'out')
    procs: dict[str, subprocess.Popen] = {}
    waited: list[float] = []
    observer = rclpy.create_node('hand_start_observer', context=ctx)   # reads the graph only
    try:
        for i, name in enumerate(order):
            if i:
                prev = order[i - 1]
                waited.append(_wait_for_node(observer, NODE_NAME[prev], procs[prev],
                                             tmp_path / f'{prev}.log'))
            procs[name] = _launch._start(cmds[name], tmp_path / f'{name}.log')
        deadline = time.monotonic() + 300
        for name in ('coupling_node', 'record'):
            rc = procs[name].wait(timeout=max(1.0, deadline - time.monotonic()))
            assert rc == 0, (name, (tmp_path / f'{name}.log').read_text()[-3000:])
    finally:
        observer.destroy_node()
        _launch._stop_all(procs)
    counts = check_complete_bag(tmp_path / 'out' / 'bag', N)
    print(f'{"/".join(order)}: {counts}; waited for each start (s): '
          f'{", ".join(f"{w:.2f}" for w in waited)}')
    # the waiting line (when the wait outlasted START_REPORT_S) names who was missing
    for line in (tmp_path / 'coupling_node.log').read_text().splitlines():
        if 'waiting for peers (' in line:
            assert '/driveline/joint_states (' in line and 'min_subscribers=4' in line, line
