"""Faults with the real node processes (DESIGN.md section 9), each run a few seconds of loop.

* A node that answers late: once /clock shows the loop stepping (t >= 0.1 s), the engine
  process is frozen (SIGSTOP) for 0.5 s, shorter than peer_timeout = 1.5 s: the lockstep loop waits and goes on, and the recorded states
  still equal the offline coupled stepper at the same exchange step (so nothing was
  integrated out of order). Later the load process is frozen for longer than
  peer_timeout: the run stops with exit 1 and one error line naming /load/wrench and
  peer_timeout; the bag is complete up to the stop (readable, consecutive stamps from 0,
  an ERROR status on /diagnostics).
* Bad pedal positions on /engine/throttle (NaN, +-inf, 1.5) sent by the test during the
  same run: the engine node reports them as ERROR diagnostics and does not apply them
  (the states still equal the offline loop).
* The coupling node killed (SIGKILL) mid-run: exit 1, one line naming coupling_node, the
  other nodes stopped, the bag complete up to the kill.
* A second run on the same ROS domain while one runs: the new one is refused with exit 1
  and an error naming the domain; the running one goes on, or stops with one line naming
  the second run's node as an intruder (a run knows its peers by publisher,
  cvj_ros.nodes.peers); neither bag holds the other's messages.

Already covered elsewhere (not repeated): a killed engine node and SIGINT with a readable
bag (test/e2e/test_run.py), duplicate / late / out-of-order stamps and NaN torques from the
peers (test/nodes/test_coupling_node.py, in-process, exact stamps and momentum balance).
"""
from __future__ import annotations

import io
import math
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pytest
import yaml

from cvj_ros import bag

pytestmark = [pytest.mark.e2e, pytest.mark.ros]

CVJ_SIM = str(Path(sys.executable).with_name('cvj-sim'))
H = 1e-3
SCENE = {
    'name': 'faults', 'seed': 5, 'duration': 1000.0, 'exchange_step': H,
    'solver': {'method': 'dopri5', 'rtol': 1e-9, 'atol': 1e-11},
    'engine': {'model': 'linear'}, 'load': {'model': 'constant', 'torque': 100.0},
    'initial': {'speed_rpm': 300.0},
    'driveline': [
        {'type': 'inertia', 'name': 'crank', 'J': 0.128},
        {'type': 'spring', 'name': 'bush', 'stiffness': 715.4, 'damping': 6.35},
        {'type': 'joint', 'name': 'cpl', 'kind': 'hooke', 'fidelity': 'exact',
         'params': {'beta_deg': 15.0}},
        {'type': 'inertia', 'name': 'driven', 'J': 0.161},
    ],
}


def wait_for_text(path: Path, text: str, timeout: float) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if path.exists() and text in path.read_text(errors='replace'):
            return
        time.sleep(0.05)
    raise AssertionError(f'{text!r} not in {path} after {timeout} s')


def check_bag_up_to_stop(bag_path: Path) -> bag.JointStateSeries:
    """Readable bag, joint states consecutive from t = 0 at exactly k * H, all finite."""
    js = bag.read_bag(bag_path, ['/driveline/joint_states'])['/driveline/joint_states']
    k = np.round(js.t / H).astype(np.int64)
    np.testing.assert_array_equal(k, np.arange(k.size))
    assert np.all(np.isfinite(js.position)) and np.all(np.isfinite(js.velocity))
    return js


def offline_lockstep(n_steps: int) -> np.ndarray:
    """Shaft speeds at t_k of the same loop offline: CoupledStepper (zoh) with the engine and
    load torques evaluated at the exchange points, as engine_node / load_node do."""
    from cvj_ros.physics.cosim import CoupledStepper
    from cvj_ros.physics.driveline import Driveline
    from cvj_ros.physics.engine import engine_from_spec
    from cvj_ros.physics.load import load_from_spec
    from cvj_ros.physics.scene import parse_scene
    sc = parse_scene(SCENE)
    engine, load = engine_from_spec(sc.engine), load_from_spec(sc.load, seed=sc.seed)
    dl = Driveline.from_scene(sc)
    cs = CoupledStepper(dl, scheme='zoh', method=sc.solver.method, rtol=sc.solver.rtol,
                        atol=sc.solver.atol)
    x = dl.x0.copy()
    out = [dl.joint_states(x, 0.0, 0.0)[2]]
    for k in range(n_steps):
        t = k * H
        x = cs.advance((k + 1) * H, engine.torque(t, dl.engine_omega(x), dl.engine_phi(x)),
                       load.torque(t, dl.load_omega(x), dl.load_phi(x)))
        out.append(dl.joint_states(x, 0.0, 0.0)[2])
    return np.asarray(out)


class SimClock:
    """Follows /clock from the test process (a subscriber only: no extra publisher)."""

    def __init__(self) -> None:
        import rclpy
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor
        from rosgraph_msgs.msg import Clock

        from cvj_ros.nodes.qos import CLOCK_TOPIC, DATA_QOS
        self.ctx = Context()
        rclpy.init(context=self.ctx)
        self.node = rclpy.create_node('fault_test_clock', context=self.ctx)
        self.t = -1.0
        self.node.create_subscription(Clock, CLOCK_TOPIC, self._on_clock, DATA_QOS)
        from std_msgs.msg import Float64

        from cvj_ros.nodes.qos import ENGINE_THROTTLE_TOPIC
        self._float64 = Float64
        self.throttle_pub = self.node.create_publisher(Float64, ENGINE_THROTTLE_TOPIC, DATA_QOS)
        from diagnostic_msgs.msg import DiagnosticArray
        self.throttle_errors: list[str] = []
        self.node.create_subscription(DiagnosticArray, '/diagnostics', self._on_diagnostics, DATA_QOS)
        self.executor = SingleThreadedExecutor(context=self.ctx)
        self.executor.add_node(self.node)

    def _on_diagnostics(self, msg) -> None:
        self.throttle_errors += [s.message for s in msg.status
                                 if s.message.startswith('/engine/throttle:') and s.level == b'\x02']

    def _on_clock(self, msg) -> None:
        self.t = msg.clock.sec + 1e-9 * msg.clock.nanosec

    def wait_until(self, t_sim: float, timeout: float) -> float:
        """Spin until simulated time >= t_sim (s); return the time seen."""
        deadline = time.monotonic() + timeout
        while self.t < t_sim:
            assert time.monotonic() < deadline, f'/clock did not reach {t_sim} s'
            self.executor.spin_once(timeout_sec=0.05)
        return self.t

    def wait_for_engine(self, timeout: float) -> None:
        """Spin until the engine node's /engine/throttle subscription is matched.

        A volatile topic drops what is published before discovery matched both ends (CI failed
        once: the four bad values were sent 0.05 s into the loop and none reached the engine).
        """
        deadline = time.monotonic() + timeout
        while self.throttle_pub.get_subscription_count() < 1:
            assert time.monotonic() < deadline, 'engine_node never subscribed to /engine/throttle'
            self.executor.spin_once(timeout_sec=0.05)

    def send_bad_throttle_until_rejected(self, values: Sequence[float], timeout: float) -> None:
        """Publish ``values`` on /engine/throttle every 50 ms of wall time until the engine's
        ERROR diagnostic for every one of them came back (bounded). A volatile topic drops
        what is published before both ends matched, and the compiled loop now passes the 25 ms
        of simulated time between two fixed sends in ~10 ms of wall time (CI lost both sends;
        later CI saw the reader match in the middle of a burst: only 1.5 came back)."""
        deadline = time.monotonic() + timeout

        def missing() -> list[float]:
            return [v for v in values
                    if not any(f'got {v!r};' in m for m in self.throttle_errors)]
        while missing():
            assert time.monotonic() < deadline, \
                f'engine_node never rejected /engine/throttle {missing()} ({self.throttle_errors})'
            for bad in values:
                self.send_throttle(bad)
            end = time.monotonic() + 0.05
            while time.monotonic() < end and missing():
                self.executor.spin_once(timeout_sec=0.01)

    def send_throttle(self, value: float) -> None:
        """Publish a pedal position on /engine/throttle (as a vehicle stack would)."""
        self.throttle_pub.publish(self._float64(data=value))
        self.executor.spin_once(timeout_sec=0.01)

    def close(self) -> None:
        import rclpy
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.shutdown(context=self.ctx)


def test_late_engine_recovers_and_frozen_load_stops_with_clear_error(tmp_path: Path) -> None:
    from cvj_ros.orchestrate import RunOptions, run
    scene = tmp_path / 'faults.yaml'
    scene.write_text(yaml.safe_dump(SCENE, sort_keys=False))
    out = tmp_path / 'run'
    log = out / 'logs' / 'coupling_node.log'
    events: dict[str, float] = {}

    def freeze(proc: subprocess.Popen, seconds: float, name: str) -> None:
        os.kill(proc.pid, signal.SIGSTOP)
        events[f'{name}_stop'] = time.monotonic()
        try:
            time.sleep(seconds)
        finally:
            os.kill(proc.pid, signal.SIGCONT)

    # the clock's participant is made and destroyed here, not in the chaos thread while the
    # run's recorder takes messages (see test_coupling_node_killed_mid_run_closes_the_bag)
    clock = SimClock()
    threads: list[threading.Thread] = []

    def on_started(procs: dict[str, subprocess.Popen]) -> None:
        def chaos() -> None:
            clock.wait_until(0.05, 60.0)                       # loop is stepping
            clock.wait_for_engine(30.0)
            # bad pedal inputs, resent until the engine's ERROR for them is seen
            clock.send_bad_throttle_until_rejected((math.nan, math.inf, -math.inf, 1.5), 30.0)
            events['t_engine_freeze'] = clock.wait_until(0.1, 60.0)
            freeze(procs['engine_node'], 0.5, 'engine')   # late, within peer_timeout
            events['t_after_engine'] = clock.wait_until(events['t_engine_freeze'] + 0.1, 30.0)
            freeze(procs['load_node'], 3.0, 'load')       # beyond peer_timeout
        threads.append(threading.Thread(target=chaos, daemon=True))
        threads[0].start()

    try:
        result = run(RunOptions(scene=str(scene), out=out, peer_timeout=1.5), stream=io.StringIO(),
                     on_started=on_started)
    finally:
        for t in threads:
            t.join(30.0)
        clock.close()
    assert 'engine_stop' in events and 'load_stop' in events, events
    assert result.exit_code == 1
    assert result.error is not None and '\n' not in result.error
    assert '/load/wrench' in result.error and 'peer_timeout' in result.error
    assert '/engine/wrench' not in result.error
    js = check_bag_up_to_stop(out / 'bag')
    # the engine froze mid-run (t >= 0.1 s) and the loop went on for >= 0.1 s after it
    assert events['t_engine_freeze'] >= 0.1
    assert js.t[-1] >= events['t_after_engine'] >= events['t_engine_freeze'] + 0.1
    # the 0.5 s engine freeze is inside the recorded run and changed nothing: states equal
    # the offline loop (same arithmetic; solver tolerance and stamp rounding remain)
    ref = offline_lockstep(js.t.size - 1)
    np.testing.assert_allclose(js.velocity, ref, rtol=1e-6, atol=1e-9)
    diag = bag.read_bag(out / 'bag', ['/diagnostics'])['/diagnostics']
    errors = [s['message'] for msg in diag.statuses for s in msg if s['level'] == 2]
    assert any('/load/wrench' in m for m in errors), errors
    # NaN / inf / out-of-range pedal positions: ERROR diagnostics from the engine node, not
    # applied (the states above equal the offline loop at the scene's throttle)
    bad_throttle = [m for m in errors if m.startswith('/engine/throttle:')]
    for v in (math.nan, math.inf, -math.inf, 1.5):   # each one rejected, as the sender saw
        assert any(f'got {v!r};' in m for m in bad_throttle), (v, bad_throttle)


def test_second_run_on_the_same_domain_is_refused_and_mixes_nothing(tmp_path: Path) -> None:
    """A second lockstep run on a domain where one is running: the second is refused before
    its loop starts (one line naming the publishers and the domain) and its bag records
    none of the first run's loop messages; the first goes on (stopped by the test with
    SIGINT) or, once the second run's engine or load node answers its joint states, stops
    with one line naming that node as an intruder (cvj_ros.nodes.peers: answers on a topic
    with two publishers cannot be told apart, so none of them is integrated). Either way
    its bag is consecutive from t = 0 with nothing of the second run in it. If discovery
    is so slow that the second run's loop starts anyway, it is stopped with SIGINT or by
    its own intruder check; the bags are checked the same way."""
    scene = tmp_path / 'faults.yaml'
    scene.write_text(yaml.safe_dump(SCENE, sort_keys=False))
    out_a, out_b = tmp_path / 'a', tmp_path / 'b'
    env = dict(os.environ)
    first = subprocess.Popen([CVJ_SIM, 'run', str(scene), '--out', str(out_a)], env=env,
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    second = None
    try:
        # run A is stepping once it prints 'loop running' (after its first recorded exchange):
        # a bounded wait on the event itself, not a fixed sleep (readline ends at A's exit)
        first_line = first.stdout.readline()
        assert 'loop running' in first_line, first_line
        second = subprocess.Popen([CVJ_SIM, 'run', str(scene), '--out', str(out_b)], env=env,
                                  stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:   # refused: exits after its peers' start-up (~3-10 s here under load)
            b_out, b_err = second.communicate(timeout=60)
        except subprocess.TimeoutExpired:       # it got through: stop it as a user would
            second.send_signal(signal.SIGINT)
            b_out, b_err = second.communicate(timeout=60)
        first.send_signal(signal.SIGINT)
        out, err = first.communicate(timeout=60)
    finally:
        for p in (first, second):
            if p is not None and p.poll() is None:
                p.kill()
    domain = f'ROS_DOMAIN_ID={env["ROS_DOMAIN_ID"]}'
    assert 'Traceback' not in b_err
    b_counts = bag.bag_info(out_b / 'bag').counts if (out_b / 'bag' / 'metadata.yaml').exists() else {}
    if second.returncode == 1:       # refused: one line naming the publishers and the domain
        lines = b_err.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith(('cvj-sim: error: lockstep: ',
                                                        'cvj-sim: error: coupling_node: ')), b_err
        assert domain in lines[0] and 'publishers' in lines[0]
        assert b_counts.get('/driveline/joint_states', 0) == 0, b_counts   # nothing of run A
    else:                            # ran beside A (slow discovery): its own states only
        assert second.returncode in (1, 130), (second.returncode, b_out, b_err)
        if (out_b / 'bag' / 'metadata.yaml').exists():
            check_bag_up_to_stop(out_b / 'bag')
    # A goes on, or stops naming B's node as an intruder (exit 1, or 130 when the test's
    # SIGINT came while it was closing); it never integrates B's answers
    assert 'Traceback' not in err
    # the intruder named by its node, or under load before the graph shows its node:
    # 'intruder a publisher not in the ROS graph yet'
    if ': intruder ' in out + err:
        assert first.returncode in (1, 130), (first.returncode, out, err)
        assert domain in out + err
    else:   # stopped by the test's SIGINT (if it came while an intruder stop was being
        # reported, cvj-sim says only "interrupted")
        assert first.returncode == 130 and ('stopped by SIGINT' in out or 'cvj-sim: interrupted' in err), \
            (first.returncode, out, err)
    js = check_bag_up_to_stop(out_a / 'bag')
    assert js.t.size > 10
    assert np.unique(js.t).size == js.t.size              # no state of run B mixed in
    info = bag.bag_info(out_a / 'bag')
    assert info.counts.get('/driveline/scene') == 1


def test_coupling_node_killed_mid_run_closes_the_bag(tmp_path: Path) -> None:
    """SIGKILL of the process that owns simulated time, once /clock shows t >= 0.1 s: the
    run ends with exit 1 and one line naming coupling_node, every other node is stopped
    and the bag holds every state recorded up to the kill."""
    from cvj_ros.orchestrate import RunOptions, run
    scene = tmp_path / 'faults.yaml'
    scene.write_text(yaml.safe_dump(SCENE, sort_keys=False))
    out = tmp_path / 'run'
    seen: dict[str, float] = {}

    # The clock's participant is made here and destroyed after the run, not in the killer
    # thread: CI twice lost the whole pytest process to SIGSEGV in this test (no Python
    # frame, stops 23 and 24, about 1 in 30 runs, never reproduced locally). Suspected, not
    # shown: the killer thread destroyed its Fast DDS participant right after the kill while
    # the recorder's participant in this process was taking the dead writer's last samples
    # over shared memory; this takes that concurrency away.
    clock = SimClock()
    threads: list[threading.Thread] = []

    def on_started(procs: dict[str, subprocess.Popen]) -> None:
        def killer() -> None:
            seen['t_kill'] = clock.wait_until(0.1, 60.0)
            os.kill(procs['coupling_node'].pid, signal.SIGKILL)
        threads.append(threading.Thread(target=killer, daemon=True))
        threads[0].start()

    try:
        result = run(RunOptions(scene=str(scene), out=out), stream=io.StringIO(), on_started=on_started)
    finally:
        for t in threads:
            t.join(30.0)
        clock.close()
    assert 't_kill' in seen
    assert result.exit_code == 1
    assert result.error is not None and '\n' not in result.error
    assert result.error.startswith('coupling_node:'), result.error
    assert 'killed by SIGKILL' in result.error, result.error
    assert result.node_exit_codes['coupling_node'] == -signal.SIGKILL
    assert all(code is not None for code in result.node_exit_codes.values())   # all stopped
    js = check_bag_up_to_stop(out / 'bag')
    # /clock t_k goes out before the joint state t_k (lockstep: before the integration to
    # t_k), so at the kill the last state may be t_kill - H; and states the coupling node
    # had published but DDS had not yet delivered die with its process (not lost by the
    # recorder: the bag is consecutive from 0 above). Measured with both cores busy
    # (make test-stress): up to 6 undelivered exchanges (last state 0.094 s at a kill seen at
    # 0.1 s); the bound allows 50 (8x).
    assert js.t[-1] >= seen['t_kill'] - 50 * H - 1e-9
