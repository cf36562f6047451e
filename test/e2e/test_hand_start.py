"""The README's hand-start recipe, run as written with real processes, in several start
orders with pauses between the shells: every order gives a complete bag.

The recipe: ``coupling_node``, ``engine_node``, ``load_node``, ``monitor_node`` (each
``--ros-args -p scene:=...``) and ``cvj-sim record OUT --until-idle 2``, no other
parameter. The coupling node's defaults make it wait, without deadline, for 4 subscribers
of the joint states (engine, load, monitor, recorder) before step 0.

Pauses of PAUSE_S (3 s) stand for a person's 20 s or more between shells. Equivalent
because before step 0 nothing in these processes depends on how long the wait lasts: the
coupling node has no start deadline by default and only polls the graph (every 10 ms) and
logs who is missing every START_REPORT_S; engine, load and monitor wait for joint states
without any timer; the recorder's --until-idle clock starts at the run's first message
(not at the latched scene message the coupling node sends while it waits). A pause longer
than START_REPORT_S (5 s) in total before the last peer also shows the waiting line. What
the pause length changes is only the number of those lines.
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

pytestmark = pytest.mark.e2e

BIN = Path(sys.executable).parent
PAUSE_S = 3.0
H = 1e-3
DURATION = 0.3
N = int(round(DURATION / H))
SCENE = {
    'name': 'hand_start', 'description': 'hand-started nodes', 'seed': 4,
    'duration': DURATION, 'exchange_step': H,
    'solver': {'method': 'dopri5', 'rtol': 1e-8, 'atol': 1e-10},
    'engine': {'model': 'linear'}, 'load': {'model': 'constant', 'torque': 20.0},
    'initial': {'speed_rpm': 300.0},
    'driveline': [
        {'type': 'inertia', 'name': 'crank', 'J': 0.128},
        {'type': 'spring', 'name': 'bush', 'stiffness': 715.4, 'damping': 6.35},
        {'type': 'joint', 'name': 'cpl', 'kind': 'hooke', 'params': {'beta_deg': 15.0}},
        {'type': 'inertia', 'name': 'wheel', 'J': 0.5},
    ],
}
def check_complete_bag(bag_path: Path, n_steps: int) -> dict[str, int]:
    """Every exchange is in the bag: n_steps + 1 joint states and clocks from t = 0,
    n_steps engine and load answers, the scene message; returns counts per topic."""
    from cvj_ros import bag
    data = bag.read_bag(bag_path)
    js = data[bag.JOINT_STATES_TOPIC]
    assert len(js.t) == n_steps + 1, f'{len(js.t)} of {n_steps + 1} joint states'
    assert js.t[0] == 0.0
    counts = {topic: len(getattr(series, 't', ())) for topic, series in data.items()}
    assert counts.get('/clock', 0) >= n_steps + 1, counts
    assert counts['/engine/wrench'] >= n_steps and counts['/load/wrench'] >= n_steps, counts
    assert bag.SCENE_TOPIC in data
    return counts


README_ORDER = ('coupling_node', 'engine_node', 'load_node', 'monitor_node', 'record')


def _recipe(scene: Path, out: Path) -> dict[str, list[str]]:
    """The README recipe's command lines (venv console scripts)."""
    cmds = {n: [str(BIN / n), '--ros-args', '-p', f'scene:={scene}']
            for n in ('coupling_node', 'engine_node', 'load_node', 'monitor_node')}
    cmds['record'] = [str(BIN / 'cvj-sim'), 'record', str(out), '--until-idle', '2']
    return cmds


@pytest.mark.parametrize('order', [
    README_ORDER,                                                  # coupling first, recorder last
    tuple(reversed(README_ORDER)),                                 # recorder first, coupling last
    ('engine_node', 'record', 'coupling_node', 'monitor_node', 'load_node'),
], ids=['readme', 'reversed', 'mixed'])
def test_recipe_in_any_order_records_a_complete_bag(tmp_path: Path, order: tuple[str, ...]) -> None:
    scene = tmp_path / 'scene.yaml'
    scene.write_text(yaml.safe_dump(SCENE, sort_keys=False))
    cmds = _recipe(scene, tmp_path / 'out')
    procs: dict[str, subprocess.Popen] = {}
    try:
        for i, name in enumerate(order):
            if i:
                time.sleep(PAUSE_S)
            procs[name] = subprocess.Popen(
                cmds[name], stdout=open(tmp_path / f'{name}.log', 'wb'), stderr=subprocess.STDOUT,
                stdin=subprocess.DEVNULL, env=dict(os.environ), start_new_session=True)
        deadline = time.monotonic() + 300
        for name in ('coupling_node', 'record'):
            rc = procs[name].wait(timeout=max(1.0, deadline - time.monotonic()))
            assert rc == 0, (name, (tmp_path / f'{name}.log').read_text()[-3000:])
    finally:
        for p in procs.values():
            if p.poll() is None:
                os.killpg(p.pid, signal.SIGINT)
        for p in procs.values():
            try:
                p.wait(timeout=15)
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, signal.SIGKILL)
                p.wait()
    counts = check_complete_bag(tmp_path / 'out' / 'bag', N)
    print(f'{"/".join(order)}: {counts}')
    # the waiting line (when the wait outlasted START_REPORT_S) names who was missing
    for line in (tmp_path / 'coupling_node.log').read_text().splitlines():
        if 'waiting for peers (' in line:
            assert '/driveline/joint_states (' in line and 'min_subscribers=4' in line, line
