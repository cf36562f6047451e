"""A real `cvj-sim run` killed hard (SIGKILL to its process group and to every node) mid-run:
`cvj-sim reindex` recovers the bag, and the simulated time lost is at most 1 s.

How the loss is measured: the test follows /clock from its own process and kills everything
once it has seen t >= T_KILL_S. The loss is ``t_seen - t_last`` where ``t_last`` is the last
joint state in the recovered bag. The test's /clock view lags the loop by the DDS delivery
time (well under 10 ms of wall time), so the true loss can exceed the measured one by that
many exchange steps; the bound below has a margin far larger than that.

Bound: the writer flushes when the pending messages span ``FLUSH_SIM_SPAN_S`` = 0.25 s of
record time (cvj_ros/bag.py), so what is on disk lags the newest received message by at most
0.25 s plus the messages in flight in the writer queue and the recorder (ms). Asserted:
loss <= 1.0 s (the issue's requirement, 4x the flush span). Measured (2026-11, this 2-core
machine): see docs/robustness.md, "Hard kill".
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from cvj_ros import bag
from cvj_ros.cli import main as cli_main

pytestmark = pytest.mark.e2e

CVJ_SIM = str(Path(sys.executable).with_name('cvj-sim'))
T_KILL_S = 1.62         # simulated time of the kill (not a multiple of the flush span)
MAX_LOSS_S = 1.0        # issue 11: a hard kill loses at most 1 s of simulated time


def _children(pid: int) -> list[int]:
    """Direct children of ``pid`` (Linux /proc)."""
    out: list[int] = []
    try:
        for tid in os.listdir(f'/proc/{pid}/task'):
            with open(f'/proc/{pid}/task/{tid}/children') as fh:
                out += [int(x) for x in fh.read().split()]
    except OSError:
        pass
    return out


def follow_clock_until(t_sim: float, timeout: float, alive: subprocess.Popen) -> float:
    """Subscribe /clock in this process; return the first simulated time >= t_sim seen."""
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from rosgraph_msgs.msg import Clock

    from cvj_ros.nodes.qos import CLOCK_TOPIC, DATA_QOS
    ctx = Context()
    rclpy.init(context=ctx)
    seen = {'t': -1.0}
    try:
        node = rclpy.create_node('hard_kill_clock', context=ctx)
        node.create_subscription(Clock, CLOCK_TOPIC,
                                 lambda m: seen.__setitem__('t', m.clock.sec + 1e-9 * m.clock.nanosec),
                                 DATA_QOS)
        ex = SingleThreadedExecutor(context=ctx)
        ex.add_node(node)
        deadline = time.monotonic() + timeout
        while seen['t'] < t_sim:
            assert time.monotonic() < deadline, f'/clock did not reach {t_sim} s in {timeout} s'
            assert alive.poll() is None, f'cvj-sim run ended early ({alive.returncode})'
            ex.spin_once(timeout_sec=0.05)
        ex.shutdown()
        node.destroy_node()
    finally:
        rclpy.shutdown(context=ctx)
    return seen['t']


def hard_kill_run(out: str | Path, scene: str, t_kill: float, *, storage: str = 'mcap',
                  env: dict[str, str] | None = None) -> dict[str, float]:
    """Start `cvj-sim run`, SIGKILL it and all its nodes at simulated t >= t_kill.

    Returns ``t_seen`` (simulated time seen on /clock at the kill, s) and ``pid``."""
    env = dict(os.environ if env is None else env)
    proc = subprocess.Popen([CVJ_SIM, 'run', scene, '--out', str(out), '--duration', '1000',
                             '--storage', storage], env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        line = proc.stdout.readline()        # bounded: printed once the loop records, or EOF
        assert 'loop running' in line, line + proc.stderr.read()
        t_seen = follow_clock_until(t_kill, 120.0, proc)
        victims = _children(proc.pid)        # the nodes run in sessions of their own
        os.killpg(proc.pid, signal.SIGKILL)
        for pid in victims:
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        proc.wait(timeout=30)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
        proc.stdout.close()
        proc.stderr.close()
    assert proc.returncode == -signal.SIGKILL
    return {'t_seen': t_seen}


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_sigkill_of_the_whole_run_loses_at_most_1s_and_reindex_recovers(
        tmp_path: Path, storage: str, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / 'run'
    r = hard_kill_run(out, 'fwd_halfshaft', T_KILL_S, storage=storage)
    bag_dir = out / 'bag'
    assert not (bag_dir / 'metadata.yaml').exists()          # what a hard kill leaves
    # analyze says how to repair it
    assert cli_main(['analyze', str(bag_dir)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f'cvj-sim reindex {bag_dir}' in err[0], err
    # reindex, then the bag is complete up to the flush point
    assert cli_main(['reindex', str(bag_dir)]) == 0
    report = capsys.readouterr().out
    assert 'reindexed' in report and (bag_dir / 'metadata.yaml').exists()
    info = bag.bag_info(bag_dir)
    assert info.storage == storage
    assert info.counts['/driveline/scene'] == 1 and 'cvj_ros.scene' in info.custom_data
    js = bag.read_bag(bag_dir, ['/driveline/joint_states'])['/driveline/joint_states']
    h = 0.001                                                # fwd_halfshaft exchange step, s
    k = np.round(js.t / h).astype(np.int64)
    np.testing.assert_array_equal(k, np.arange(k.size))      # consecutive from t = 0, no hole
    lost = r['t_seen'] - js.t[-1]
    with capsys.disabled():
        print(f'\nhard kill ({storage}): killed at t >= {r["t_seen"]:.3f} s, recovered up to '
              f'{js.t[-1]:.3f} s: lost {lost:.3f} s of simulated time')
    assert lost <= MAX_LOSS_S
    assert cli_main(['analyze', str(bag_dir), '--json']) == 0
    capsys.readouterr()
    # reindexing again is harmless (the first original stays, the clean copy is kept too)
    assert cli_main(['reindex', str(bag_dir)]) == 0
    capsys.readouterr()
    assert bag.bag_info(bag_dir).counts == info.counts


if __name__ == '__main__':   # measurement: python test_hard_kill.py OUT [T_KILL] [STORAGE] [SCENE]
    res = hard_kill_run(sys.argv[1], sys.argv[4] if len(sys.argv) > 4 else 'fwd_halfshaft', float(sys.argv[2]) if len(sys.argv) > 2 else T_KILL_S,
                        storage=sys.argv[3] if len(sys.argv) > 3 else 'mcap')
    print(res)
