"""A real `cvj-sim run` killed hard (SIGKILL to its process group and to every node) mid-run,
with separate node processes and composed (`--composed`, one process), mcap and sqlite3:
`cvj-sim reindex` recovers the bag, and the simulated time lost is at most 0.25 s composed,
1 s with separate processes (bounds below).

How the loss is measured. Separate processes: the test follows /clock from its own process;
once it has seen t >= T_KILL_S it stops every process of the run (SIGSTOP: nothing runs or
writes any more, which leaves on disk what a SIGKILL at that instant leaves), takes the
/clock samples still in flight for SETTLE_S, then SIGKILLs them all; the loss is ``t_seen -
t_last``, the newest /clock the run published against the last joint state in the recovered
bag. Composed: an outside /clock view lags a loop 10x faster than real time by up to 0.4 s
of simulated time under load (samples dropped on the way), so the run kills itself instead:
its coupling node (patched by SELF_KILL) SIGKILLs the process right after publishing the
state at t >= T_KILL_S, and the loss is T_KILL_S - ``t_last``, exact to one step.

Bound: the writer flushes when the pending messages span ``FLUSH_SIM_SPAN_S`` = 0.1 s of
record time (cvj_ros/bag.py); in composed mode the loop waits for the writer rather than run
more than ``MAX_LAG_S`` = 0.15 s ahead of the disk, and the recorder hands its messages over
every ``HANDOFF_SPAN_S`` = 0.05 s: asserted loss <= 0.25 s. With separate processes the
recorder can lag the loop under load and nothing holds the loop back: asserted <= 1 s
(MAX_LOSS_SEPARATE_S). Measured (2026-11, this 2-core machine): see docs/robustness.md,
"Hard kill".
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from cvj_ros import bag
from cvj_ros.cli import main as cli_main

pytestmark = pytest.mark.e2e

CVJ_SIM = str(Path(sys.executable).with_name('cvj-sim'))
T_KILL_S = 1.62         # simulated time of the kill (not a multiple of the flush span)
MAX_LOSS_S = 0.25       # composed: at most 0.25 s of simulated time (module docstring)
# separate processes: nothing holds the loop back when the recorder (another process) lags,
# so the loss is the flush span plus the recorder's lag behind the loop: measured 0.002-0.09 s
# at load average <= 12, 0.76 s once at ~14 (docs/robustness.md); asserted: DESIGN.md
# section 9's 1 s
MAX_LOSS_SEPARATE_S = 1.0
SETTLE_S = 0.5          # wall s to take the /clock samples in flight after the SIGSTOP


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


def follow_clock_until(t_sim: float, timeout: float, alive: subprocess.Popen,
                       on_reached: Callable[[], None] | None = None, settle: float = 0.0) -> float:
    """Subscribe /clock in this process until it shows t >= t_sim; then call ``on_reached``
    (e.g. SIGSTOP the run) and keep taking /clock for ``settle`` s of wall time (what was
    published before the stop and was still in flight). Returns the largest simulated time
    seen."""
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from rosgraph_msgs.msg import Clock

    from cvj_ros.nodes.qos import CLOCK_TOPIC, DATA_QOS
    ctx = Context()
    rclpy.init(context=ctx)
    seen = {'t': -1.0}

    def on_clock(m: Clock) -> None:
        seen['t'] = max(seen['t'], m.clock.sec + 1e-9 * m.clock.nanosec)
    try:
        node = rclpy.create_node('hard_kill_clock', context=ctx)
        node.create_subscription(Clock, CLOCK_TOPIC, on_clock, DATA_QOS)
        ex = SingleThreadedExecutor(context=ctx)
        ex.add_node(node)
        deadline = time.monotonic() + timeout
        while seen['t'] < t_sim:
            assert time.monotonic() < deadline, f'/clock did not reach {t_sim} s in {timeout} s'
            assert alive.poll() is None, f'cvj-sim run ended early ({alive.returncode})'
            ex.spin_once(timeout_sec=0.05)
        if on_reached is not None:
            on_reached()
        end = time.monotonic() + settle
        while time.monotonic() < end:
            ex.spin_once(timeout_sec=0.02)
        ex.shutdown()
        node.destroy_node()
    finally:
        rclpy.shutdown(context=ctx)
    return seen['t']


# `cvj-sim run ... --composed` whose coupling node SIGKILLs the whole process right after it
# published its state at t >= argv[1] s (a composed run is one process: that is the whole run)
SELF_KILL = '''
import os, signal, sys
from cvj_ros.nodes import coupling_node
kill_ns = round(float(sys.argv[1]) * 1e9)
publish = coupling_node.CouplingNode._publish_state
def publish_then_die(self):
    publish(self)
    if self.t_ns >= kill_ns:
        os.kill(os.getpid(), signal.SIGKILL)
coupling_node.CouplingNode._publish_state = publish_then_die
from cvj_ros.cli import main
sys.exit(main(sys.argv[2:]))
'''


def hard_kill_run(out: str | Path, scene: str, t_kill: float, *, storage: str = 'mcap',
                  env: dict[str, str] | None = None, composed: bool = False) -> dict[str, float]:
    """Start `cvj-sim run` (``--composed`` if ``composed``), SIGKILL it and all its nodes at
    simulated t >= t_kill.

    Returns ``t_seen`` (simulated time seen on /clock at the kill, s) and ``pid``."""
    env = dict(os.environ if env is None else env)
    args = ['run', scene, '--out', str(out), '--duration', '1000', '--storage', storage]
    if composed:     # the process kills itself at t_kill: the loss is exact (module docstring)
        proc = subprocess.Popen([sys.executable, '-c', SELF_KILL, repr(t_kill), *args, '--composed'],
                                env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                start_new_session=True)
        try:
            out_text, err_text = proc.communicate(timeout=180)
        finally:
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()
        assert 'loop running' in out_text and proc.returncode == -signal.SIGKILL, out_text + err_text
        return {'t_seen': t_kill}
    proc = subprocess.Popen([CVJ_SIM, *args], env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        line = proc.stdout.readline()        # bounded: printed once the loop records, or EOF
        assert 'loop running' in line, line + proc.stderr.read()
        victims: list[int] = []

        def freeze() -> None:
            # SIGSTOP first: nothing runs or writes any more, which is what SIGKILL leaves
            # on disk, while the /clock samples already published still reach this process
            victims.extend(_children(proc.pid))   # the nodes run in sessions of their own
            os.killpg(proc.pid, signal.SIGSTOP)
            for pid in victims:
                try:
                    os.kill(pid, signal.SIGSTOP)
                except ProcessLookupError:
                    pass
        t_seen = follow_clock_until(t_kill, 120.0, proc, on_reached=freeze, settle=SETTLE_S)
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


@pytest.mark.parametrize('composed', [False, True], ids=['separate', 'composed'])
@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_sigkill_of_the_whole_run_loses_at_most_a_quarter_second_and_reindex_recovers(
        tmp_path: Path, storage: str, composed: bool, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / 'run'
    r = hard_kill_run(out, 'fwd_halfshaft', T_KILL_S, storage=storage, composed=composed)
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
        print(f'\nhard kill ({"composed" if composed else "separate"}, {storage}): killed at '
              f't >= {r["t_seen"]:.3f} s, recovered up to '
              f'{js.t[-1]:.3f} s: lost {lost:.3f} s of simulated time')
    assert lost <= (MAX_LOSS_S if composed else MAX_LOSS_SEPARATE_S)
    assert cli_main(['analyze', str(bag_dir), '--json']) == 0
    capsys.readouterr()
    # reindexing again is harmless (the first original stays, the clean copy is kept too)
    assert cli_main(['reindex', str(bag_dir)]) == 0
    capsys.readouterr()
    assert bag.bag_info(bag_dir).counts == info.counts


if __name__ == '__main__':
    # measurement: python test_hard_kill.py OUT [T_KILL] [STORAGE] [SCENE] [composed]
    res = hard_kill_run(sys.argv[1], sys.argv[4] if len(sys.argv) > 4 else 'fwd_halfshaft',
                        float(sys.argv[2]) if len(sys.argv) > 2 else T_KILL_S,
                        storage=sys.argv[3] if len(sys.argv) > 3 else 'mcap',
                        composed=len(sys.argv) > 5 and sys.argv[5] == 'composed')
    js = None
    from cvj_ros.reindex import reindex
    reindex(Path(sys.argv[1]) / 'bag')
    js = bag.read_bag(Path(sys.argv[1]) / 'bag', ['/driveline/joint_states'])['/driveline/joint_states']
    print(res, 'last state', js.t[-1], 'lost', res['t_seen'] - js.t[-1])
