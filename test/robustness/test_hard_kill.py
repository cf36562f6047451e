"""A real `cvj-sim run` killed hard (SIGKILL to its process group and to every node) mid-run,
with separate node processes and composed (`--composed`, one process), mcap and sqlite3:
`cvj-sim reindex` recovers the bag, and the simulated time lost is at most 0.25 s in every
mode and storage (bound below).

How the loss is measured: the run kills itself, so the loss is exact to one step. An outside
/clock view is not used: under load it lagged the loop by more than 0.5 s of simulated time
(a separate run's test saw t = 2.50 s while its bag already held 3.006 s). Composed: the
coupling node (patched by SELF_KILL) SIGKILLs the process right after publishing the state at
t >= T_KILL_S. Separate processes: the coupling node process (patched through the
sitecustomize SEPARATE_KILL, which only acts in a process running a CouplingNode) stops
cvj-sim's process group and every other node process (SIGSTOP: nothing runs or writes any
more), SIGKILLs them all, then itself, right after publishing the state at t >= T_KILL_S.
The loss is ``t_kill - t_last``: the newest /clock the run published against the last joint
state in the recovered bag.

Bound: the writer flushes when the pending messages span ``FLUSH_SIM_SPAN_S`` = 0.1 s of
record time (cvj_ros/bag.py); in composed mode the loop waits for the writer rather than run
more than ``MAX_LAG_S`` = 0.15 s ahead of the disk, and the recorder hands its messages over
every ``HANDOFF_SPAN_S`` = 0.05 s. With separate processes the recorder (a thread of
cvj-sim) publishes on /driveline/recorded the record time its bag holds on disk, and the
coupling node does not go past it by more than ``record_lag_max`` = ``MAX_LAG_S`` (it sends
/clock t_(k+1) only then): the loss is at most 0.15 s plus a step. Asserted: 0.25 s, the
issue's promise, in both modes. Measured (2026-11, this 2-core machine): see
docs/robustness.md, "Hard kill".
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from cvj_ros import bag
from cvj_ros.cli import main as cli_main

pytestmark = pytest.mark.e2e

CVJ_SIM = str(Path(sys.executable).with_name('cvj-sim'))
T_KILL_S = 1.62         # simulated time of the kill (not a multiple of the flush span)
MAX_LOSS_S = 0.25       # at most 0.25 s of simulated time, both modes (module docstring)


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


# sitecustomize for separate processes: the coupling node, right after it published its state at
# t >= CVJ_TEST_KILL_AT_S, writes that t (ns) to CVJ_TEST_KILL_REPORT, SIGSTOPs cvj-sim's
# process group (its parent, started in a session of its own) and the other node processes
# (cvj-sim's children), then SIGKILLs all of them and itself: the whole run, killed at once
SEPARATE_KILL = '''
import os
if os.environ.get('CVJ_TEST_KILL_AT_S'):
    import signal
    from cvj_ros.nodes import coupling_node
    _kill_ns = round(float(os.environ['CVJ_TEST_KILL_AT_S']) * 1e9)
    _publish = coupling_node.CouplingNode._publish_state

    def _children(pid):
        out = []
        for tid in os.listdir(f'/proc/{pid}/task'):
            with open(f'/proc/{pid}/task/{tid}/children') as fh:
                out += [int(x) for x in fh.read().split()]
        return out

    def _publish_then_die(self):
        _publish(self)
        if self.t_ns >= _kill_ns:
            parent, me = os.getppid(), os.getpid()
            others = [p for p in _children(parent) if p != me]
            os.killpg(parent, signal.SIGSTOP)
            for p in others:
                os.kill(p, signal.SIGSTOP)
            with open(os.environ['CVJ_TEST_KILL_REPORT'], 'w') as fh:
                fh.write(str(self.t_ns))
            os.killpg(parent, signal.SIGKILL)
            for p in others:
                os.kill(p, signal.SIGKILL)
            os.kill(me, signal.SIGKILL)
    coupling_node.CouplingNode._publish_state = _publish_then_die
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
    hook = Path(out).parent / f'{Path(out).name}_hook'
    hook.mkdir(parents=True, exist_ok=True)
    (hook / 'sitecustomize.py').write_text(SEPARATE_KILL)
    report = hook / 'killed_at_ns'
    env['PYTHONPATH'] = os.pathsep.join([str(hook)] + [p for p in [env.get('PYTHONPATH')] if p])
    env['CVJ_TEST_KILL_AT_S'] = repr(t_kill)
    env['CVJ_TEST_KILL_REPORT'] = str(report)
    proc = subprocess.Popen([CVJ_SIM, *args], env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        out_text, err_text = proc.communicate(timeout=180)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    assert 'loop running' in out_text and report.exists(), out_text + err_text
    t_seen = int(report.read_text()) * 1e-9
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
    assert lost <= MAX_LOSS_S
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
