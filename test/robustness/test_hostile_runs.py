"""Hostile peers against `cvj-sim run` in separate processes (docs/robustness.md, "Hostile peers").

kavz685_lever for 2 s at 1 ms (cvj-sim run, lockstep, one process per node). A hostile
rclpy peer (hostile_peer.py, a process of its own, as another stack or run is) attacks from
the run's first joint state stamped >= 0.1 s: a forged echo on /engine/wrench or
/load/wrench (the whole joint-state header copied, 50 N m), a flood of such answers as fast
as its executor goes, malformed CDR on /engine/wrench, 14 foreign JointStates (wrong
names, wrong sizes, 1e5 entries), and a /clock going backwards from 100 s (from the start).
Oracle: the run either ends normally with joint states byte for byte those of the
undisturbed run, or stops with exactly one line naming the intruder node and the topic,
its joint states byte for byte the undisturbed run's up to the stop; `cvj-sim analyze`
reads the bag (exit 0). `make test` runs the forged echo and the backwards /clock; all of
them, under load, run in `make test-stress` (marker ``stress``).
"""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from cvj_ros import bag

pytestmark = [pytest.mark.e2e, pytest.mark.ros]

CVJ_SIM = str(Path(sys.executable).with_name('cvj-sim'))
HOSTILE = str(Path(__file__).with_name('hostile_peer.py'))
DURATION = '2.0'        # s simulated: long enough for DDS to discover the intruder mid-run
FROM_S = '0.1'          # the attack starts at the first joint state stamped >= this
RUN_TIMEOUT_S = 180.0
H_S = 1e-3              # kavz685_lever's exchange step
# A stopped run's bag holds its states up to the recorder's last one-publisher check before
# the intruder appeared (docs/robustness.md, "Known limitations"); the intruder appears at a
# state >= FROM_S, and the recorder may lag the loop by up to bag.MAX_LAG_S of simulated time
# (the record gate) plus one step, so at least this many of the run's states are in the bag
# (make test-stress, load ~21: 71 of the 100 before the stop, once only 1, which analyze then
# refuses as too short, not for the intruder)
MIN_RECORDED = max(1, round(float(FROM_S) / H_S) - round(bag.MAX_LAG_S / H_S) - 1)


def _run(out: Path) -> subprocess.CompletedProcess:
    return subprocess.run([CVJ_SIM, 'run', 'kavz685_lever', '--out', str(out), '--duration', DURATION],
                          capture_output=True, text=True, timeout=RUN_TIMEOUT_S)


def _raw(bag_path: Path, topic: str) -> list[bytes]:
    """The messages of ``topic`` in stamp order, as recorded (CDR bytes)."""
    return [bytes(d) for _t, _m, _ts, d in sorted(bag.read_raw(bag_path, [topic]), key=lambda r: r[2])]


@pytest.fixture(scope='module')
def reference(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp('hostile') / 'reference'
    r = _run(out)
    assert r.returncode == 0, r.stdout + r.stderr
    return out / 'bag'


def attacked_run(tmp_path: Path, attack: str) -> tuple[subprocess.CompletedProcess, str]:
    env = dict(os.environ)
    peer = subprocess.Popen([sys.executable, HOSTILE, attack, FROM_S], stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, text=True, env=env, start_new_session=True)
    try:
        assert peer.stdout is not None and peer.stdout.readline().strip() == 'ready'
        r = _run(tmp_path / 'run')
    finally:
        out, _ = peer.communicate('', timeout=60)      # EOF on stdin: it stops
    return r, out.strip().splitlines()[-1] if out.strip() else ''


@pytest.mark.parametrize('attack, topic', [
    ('forge_engine', '/engine/wrench'), ('clock_back', None),
    # the same rule on the other topics: in `make test-stress` (each ~15 s here); in-process
    # in test_hostile_peers.py
    pytest.param('forge_load', '/load/wrench', marks=pytest.mark.stress),
    pytest.param('flood_engine', '/engine/wrench', marks=pytest.mark.stress),
    pytest.param('malformed_engine', '/engine/wrench', marks=pytest.mark.stress),
    pytest.param('foreign_js', '/driveline/joint_states', marks=pytest.mark.stress)])
def test_attack_leaves_the_undisturbed_run_or_one_named_line(reference: Path, tmp_path: Path,
                                                             attack: str, topic: str | None) -> None:
    r, sent = attacked_run(tmp_path, attack)
    print(f'{attack}: exit {r.returncode}; {sent}; {r.stderr.strip()[-300:]}')
    assert 'Traceback' not in r.stderr + r.stdout
    run_bag = tmp_path / 'run' / 'bag'
    ours, ref = _raw(run_bag, bag.JOINT_STATES_TOPIC), _raw(reference, bag.JOINT_STATES_TOPIC)
    if r.returncode == 0:          # undisturbed: the same bytes as the undisturbed run
        assert ours == ref
        assert _raw(run_bag, bag.CLOCK_TOPIC) == _raw(reference, bag.CLOCK_TOPIC)
    else:
        assert topic is not None, r.stderr
        lines = [ln for ln in r.stderr.strip().splitlines() if ln.strip()]
        assert len(lines) == 1, r.stderr
        assert f'{topic}: intruder /hostile (gid ' in lines[0], lines[0]
        assert r.returncode == 1 and len(ours) >= MIN_RECORDED and ours == ref[:len(ours)]
    a = subprocess.run([CVJ_SIM, 'analyze', str(run_bag), '--json'], capture_output=True, text=True,
                       timeout=120)
    if len(ours) < 2:      # a stop before the recorder had two states (MIN_RECORDED): too short
        assert a.returncode == 2 and 'need at least 2 messages' in a.stderr, a.stderr
    else:
        assert a.returncode == 0, a.stderr
