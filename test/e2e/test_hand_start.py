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

The same recipe in free-run (``-p mode:=free-run``), the recorder last and its readers
other than the joint states' made late: the bag still starts at t = 0 on every loop topic.
"""
from __future__ import annotations

import importlib.util
import os
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


# test-only, in the recorder's process (PYTHONPATH): its readers of every topic but the
# joint states and the scene exist only LATE_S after its first one (the recorder's discovery
# timer then subscribes them), so they match the coupling node's and the peers' writers that
# much later than its joint-state reader - what a busy machine does to discovery (seen: a
# hand-started recorder's /clock reader matched 12 and 290 steps after step 0)
LATE_READERS = '''
import os, time
from cvj_ros import bag
_subscribe = bag.BagRecorder.subscribe
_t0 = []

def subscribe(self, topic, msgtype=None):
    if not _t0:
        _t0.append(time.monotonic())
    if (topic not in (bag.JOINT_STATES_TOPIC, bag.SCENE_TOPIC)
            and time.monotonic() - _t0[0] < float(os.environ['CVJ_TEST_LATE_READERS'])):
        return
    return _subscribe(self, topic, msgtype)
bag.BagRecorder.subscribe = subscribe
'''
# after the joint-state reader: beyond the free run's 0.3 s START_SETTLE_S (without the
# observers' wait the run would be over before the other readers exist: 0.3 s simulated on
# wall time) and within its OBSERVER_SETTLE_S + UNMATCHED_WAIT_S (2 + 10 s), after which it
# would start anyway
LATE_S = 3.0


def test_hand_started_free_run_with_the_recorder_last_records_from_t0(tmp_path: Path, ctx) -> None:
    """The README recipe with ``-p mode:=free-run``, the recorder started last and its
    readers other than the joint states' late (LATE_READERS): the coupling node waits for the
    recorder's report on /driveline/recorder_ready before state 0, so the bag holds /clock,
    the joint states and both answers from t = 0. Counts: every state the node published
    (N + 1 less the ticks its catch-up skipped, from its log), as many /clock messages and
    one answer of each peer and one reaction wrench of the scene's joint per state (free-run:
    each peer echoes every state's stamp)."""
    import re

    import numpy as np
    import rclpy

    from cvj_ros import bag
    scene = tmp_path / 'scene.yaml'
    scene.write_text(yaml.safe_dump(SCENE, sort_keys=False))
    site = tmp_path / 'site'
    site.mkdir()
    (site / 'sitecustomize.py').write_text(LATE_READERS)
    cmds = _recipe(scene, tmp_path / 'out')
    cmds['coupling_node'] += ['-p', 'mode:=free-run']
    rec_env = dict(os.environ, CVJ_TEST_LATE_READERS=str(LATE_S),
                   PYTHONPATH=os.pathsep.join([str(site), *filter(None, [os.environ.get('PYTHONPATH')])]))
    procs: dict[str, subprocess.Popen] = {}
    observer = rclpy.create_node('hand_start_observer', context=ctx)   # reads the graph only
    try:
        for i, name in enumerate(README_ORDER):
            if i:
                prev = README_ORDER[i - 1]
                _wait_for_node(observer, NODE_NAME[prev], procs[prev], tmp_path / f'{prev}.log')
            procs[name] = subprocess.Popen(
                cmds[name], stdout=open(tmp_path / f'{name}.log', 'wb'), stderr=subprocess.STDOUT,
                stdin=subprocess.DEVNULL, start_new_session=True,
                env=rec_env if name == 'record' else dict(os.environ))
        deadline = time.monotonic() + 300       # a hung run, not a timing budget (as above)
        for name in ('coupling_node', 'record'):
            rc = procs[name].wait(timeout=max(1.0, deadline - time.monotonic()))
            assert rc == 0, (name, (tmp_path / f'{name}.log').read_text()[-3000:])
    finally:
        observer.destroy_node()
        _launch._stop_all(procs)
    log = (tmp_path / 'coupling_node.log').read_text()
    assert 'starting: those subscribers may miss the first states' not in log, log[-3000:]
    skipped = int(re.search(r'(\d+) ticks run, (\d+) skipped', log).group(2))
    h_ns = int(round(_launch.H * 1e9))
    data = bag.read_bag(tmp_path / 'out' / 'bag', ['/driveline/joint_states', '/clock', '/engine/wrench',
                                                   '/load/wrench', '/coupling/cpl/wrench'])
    stamps = {topic: np.rint(s.t * 1e9).astype(np.int64) for topic, s in data.items()}
    js = stamps['/driveline/joint_states']
    print(f'free-run hand start: {skipped} ticks skipped; messages '
          f'{ {t: int(s.size) for t, s in stamps.items()} }')
    assert js.size == N + 1 - skipped and js[-1] == N * h_ns
    for topic, st in stamps.items():
        assert list(st[:2]) == [0, h_ns], (topic, st[:5])     # t_0, t_1: before the clock starts
        assert st.size == js.size, (topic, st.size, js.size)
