"""End to end: free-run holds its deadline (issue 10 item 3).

`cvj-sim run --mode free-run --catch-up skip|burst --external load` for 6 s simulated at h = 5 ms, with an
outside load answerer (load_node started by the test, as a vehicle stack would be) and a
throttle publisher in the test process. Once /clock passes 2 s (and the test has followed it
for 0.5 s) the coupling node is frozen (SIGSTOP) for 0.2 s. Checked against the bag, independently of the node's own counters:

* every tick is accounted: with ``catch_up=skip`` each missed tick shows as a gap in the
  recorded joint-state stamps (stamps stay on the grid k h), and the sum of (gap - 1) over
  the bag equals the reported ``ticks_skipped``; the recorded states equal ``ticks_run`` + 1;
  every skipped tick is an overrun (late by >= h);
* the freeze's ticks are all counted as overruns (at least floor((S_lo - 2h)/h); the test
  brackets the freeze S_lo <= S <= S_hi by clock readings between and around its kill()
  calls, as it may be descheduled itself); with skip it shows as one gap g with
  S_lo - 2h <= g h <= S_hi + lateness_max + 2h (the two wake-ups around the freeze are at
  most one step before its start and one lateness after its end); with burst (bound 10)
  as a jump after the burst;
* simulated time tracks wall time: the final drift (wall since step 0 - simulated time at
  the last publication) is between 0 and the worst lateness + the time of one step, and
  the offset (DDS source timestamp of /clock - simulated time) seen by the test process
  does not move by more than the node's largest drift + 20 ms;
* the throttle publisher drove the engine: each recorded engine answer equals the linear
  law x M1 - K1 omega at the crank speed of the joint state it answers, with x one of the
  published pedal values (so the pedal changed during the run, 1e-9 relative: the
  answer is that arithmetic in double precision).

Bounds hold under CI load because they are stated in the node's own measured lateness,
not in a fixed timing budget (a loaded machine raises lateness_max and the bounds with it).
"""
from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import yaml

from cvj_ros import bag

pytestmark = [pytest.mark.e2e, pytest.mark.ros]

BIN = Path(sys.executable).parent
H = 0.005                      # s, exchange step
DURATION = 6.0                 # s simulated (>= 5 s, issue 10 item 3)
N = int(round(DURATION / H))
FREEZE_AT = 2.0                # s simulated time at which the coupling node is stopped (or later:
FOLLOW_BEFORE_FREEZE = 0.5     # s of /clock the test's driver must have seen before it)
FREEZE = 0.2                   # s wall, SIGSTOP .. SIGCONT
M1 = 623.0                     # N m, linear engine (seed 004 eq. 3.23 defaults, given explicitly)
K1 = 13.2                      # N m s/rad
LOAD = 107.5                   # N m
PEDAL = (1.0, 0.9, 0.95)       # published in turn every 0.3 s wall
SCENE = {
    'name': 'free_run_deadline', 'seed': 3, 'duration': DURATION, 'exchange_step': H,
    'solver': {'method': 'dopri5', 'rtol': 1e-8, 'atol': 1e-10},
    'engine': {'model': 'linear', 'm1': M1, 'k1': K1},
    'load': {'model': 'constant', 'torque': LOAD},
    # the steady speed (M1 - LOAD) / K1 = 39 rad/s: the held torques of the 0.2 s skip
    # stay near equilibrium (a jump of n h multiplies a speed error by ~ 1 - K1 n h / J)
    'initial': {'speed_rad_s': (M1 - LOAD) / K1},
    'driveline': [{'type': 'inertia', 'name': 'crank', 'J': 0.128},
                  {'type': 'spring', 'name': 'shaft', 'stiffness': 715.4, 'damping': 6.35},
                  {'type': 'inertia', 'name': 'wheel', 'J': 0.161}],
}


class ThrottleAndClock:
    """Test-side node: publishes /engine/throttle (PEDAL in turn every 0.3 s wall) and
    follows /clock; spun in a background thread."""

    def __init__(self) -> None:
        import rclpy
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor
        from rosgraph_msgs.msg import Clock
        from std_msgs.msg import Float64

        from cvj_ros.nodes.qos import CLOCK_TOPIC, DATA_QOS, ENGINE_THROTTLE_TOPIC
        self.ctx = Context()
        rclpy.init(context=self.ctx)
        self.node = rclpy.create_node('free_run_test_driver', context=self.ctx)
        self.t = -1.0
        # (DDS source timestamp = the coupling node's wall clock when it wrote the sample, s;
        #  /clock s): unlike the receipt time, free of this process's own backlog under load
        self.received: list[tuple[float, float]] = []
        self.sent: list[float] = []
        self._float64 = Float64
        self.node.create_subscription(Clock, CLOCK_TOPIC, self._on_clock, DATA_QOS)
        self.pub = self.node.create_publisher(Float64, ENGINE_THROTTLE_TOPIC, DATA_QOS)
        self.node.create_timer(0.3, self._send)
        self.ex = SingleThreadedExecutor(context=self.ctx)
        self.ex.add_node(self.node)
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()

    def _spin(self) -> None:
        try:
            while self.ctx.ok():
                self.ex.spin_once(timeout_sec=0.05)
        except Exception:  # noqa: BLE001 (context shut down while spinning)
            pass

    def _on_clock(self, msg, info) -> None:
        self.t = msg.clock.sec + 1e-9 * msg.clock.nanosec
        source_ns = info['source_timestamp'] if isinstance(info, dict) else info.source_timestamp
        self.received.append((source_ns * 1e-9, self.t))

    def _send(self) -> None:
        if self.t < 0 or self.pub.get_subscription_count() == 0:
            return
        x = PEDAL[len(self.sent) % len(PEDAL)]
        self.pub.publish(self._float64(data=x))
        self.sent.append(x)

    def wait_until(self, t_sim: float, timeout: float) -> float:
        deadline = time.monotonic() + timeout
        while self.t < t_sim:
            assert time.monotonic() < deadline, f'/clock did not reach {t_sim} s (at {self.t})'
            time.sleep(0.002)
        return self.t

    def close(self) -> None:
        import rclpy
        rclpy.shutdown(context=self.ctx)
        self.thread.join(timeout=5)
        self.node.destroy_node()


def child_pid(process_table: Callable[[], dict[int, tuple[int, str]]], parent: int, name: str,
              timeout: float) -> int:
    """Pid of the child process of ``parent`` whose command line contains ``name``
    (``process_table``: the conftest fixture)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        for pid, (ppid, cmd) in process_table().items():
            if ppid == parent and name in cmd:
                return pid
        time.sleep(0.05)
    raise AssertionError(f'no child {name!r} of pid {parent} within {timeout} s')


def _stop(p: subprocess.Popen | None) -> None:
    if p is not None and p.poll() is None:
        os.killpg(p.pid, signal.SIGINT)
        try:
            p.wait(timeout=10)
        except subprocess.TimeoutExpired:
            os.killpg(p.pid, signal.SIGKILL)
            p.wait(timeout=10)


@pytest.mark.parametrize('catch_up', ['skip', 'burst'])
def test_free_run_counts_every_late_tick_and_tracks_wall_time(tmp_path: Path, catch_up: str,
                                                              process_table) -> None:
    scene = tmp_path / 'scene.yaml'
    scene.write_text(yaml.safe_dump(SCENE, sort_keys=False))
    out = tmp_path / 'run'
    run = subprocess.Popen([str(BIN / 'cvj-sim'), 'run', str(scene), '--out', str(out),
                            '--mode', 'free-run', '--catch-up', catch_up, '--external', 'load'],
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                           stdin=subprocess.DEVNULL, env=dict(os.environ), start_new_session=True)
    load = driver = None
    try:
        first = run.stdout.readline()
        assert first.startswith('cvj-sim run: waiting up to'), first + run.stderr.read()
        # the driver before the load node (the loop starts only once the load is there): its
        # DDS participant then has the load node's start-up to be discovered; created after
        # it, one CI run's driver got its first /clock only at 2.035 s simulated (a missed
        # initial discovery announcement waits for the periodic one)
        driver = ThrottleAndClock()
        load = subprocess.Popen([str(BIN / 'load_node'), '--ros-args', '-p', f'scene:={scene}'],
                                stdout=open(tmp_path / 'load.log', 'wb'), stderr=subprocess.STDOUT,
                                stdin=subprocess.DEVNULL, env=dict(os.environ), start_new_session=True)
        coupling = child_pid(process_table, run.pid, 'coupling_node', 60.0)
        driver.wait_until(FREEZE_AT, 120.0)
        # the freeze once the driver has followed /clock for FOLLOW_BEFORE_FREEZE s of it, so
        # its series brackets the freeze: even so created first, a CI run's driver got its
        # first /clock only at 2.18 s (its participant found by the coupling node's only at
        # a later announcement; the free-run loop waits for its loop peers, not for it)
        driver.wait_until(driver.received[0][1] + FOLLOW_BEFORE_FREEZE, 120.0)
        freeze_sim = driver.t
        # the freeze is at least [after SIGSTOP, before SIGCONT] and at most [before SIGSTOP,
        # after SIGCONT]: this process may itself be descheduled around its kill() calls
        t_before = time.monotonic()
        os.kill(coupling, signal.SIGSTOP)
        t_stopped = time.monotonic()
        time.sleep(FREEZE)        # the freeze itself, not a wait for discovery
        t_cont = time.monotonic()
        os.kill(coupling, signal.SIGCONT)
        t_after = time.monotonic()
        freeze_lo, freeze_hi = t_cont - t_stopped, t_after - t_before
        stdout, stderr = run.communicate(timeout=180)
    finally:
        if driver is not None:
            driver.close()
        _stop(run)
        _stop(load)
    assert run.returncode == 0, first + stdout + stderr
    report = json.loads((out / 'report.json').read_text())
    fr = report['metrics']['free_run']
    assert fr['catch_up'] == catch_up and fr['ticks_handled'] == N
    assert report['sim_duration'] == pytest.approx(DURATION)     # skipped ticks included
    assert f'free-run (catch-up {catch_up}):' in stdout and 'overruns' in stdout

    data = bag.read_bag(out / 'bag')
    js = data[bag.JOINT_STATES_TOPIC]
    k = np.round(js.t / H).astype(np.int64)
    np.testing.assert_allclose(js.t, k * H, rtol=0, atol=1e-9)     # stamps on the grid
    assert k[0] == 0 and k[-1] == N                                 # ran to the end, 6 s
    gaps = np.diff(k)
    assert np.all(gaps >= 1)
    # every tick accounted, from the bag: states = ticks run + 1, missed = sum(gap - 1)
    assert js.t.size == fr['ticks_run'] + 1
    assert int(np.sum(gaps - 1)) == fr['ticks_skipped']
    assert fr['ticks_run'] + fr['ticks_skipped'] == N
    assert fr['overruns'] >= fr['ticks_skipped']     # a skipped tick is late by >= h
    # the freeze: the ticks due while the node was stopped are late by >= h when handled
    # (run in a burst or skipped): at least floor((S - 2 h) / h) of them (the wake-ups
    # around the freeze are at most one step before its start and after its end)
    assert fr['overruns'] >= math.floor((freeze_lo - 2 * H) / H)
    late_max = fr['lateness_us_max'] * 1e-6
    after = k[1:] > round(FREEZE_AT / H)
    if catch_up == 'skip':
        # one gap g after the freeze time with S - 2h <= g h <= S + lateness_max + 2h
        i_freeze = int(np.argmax(gaps * after))
        g = int(gaps[i_freeze])
        assert freeze_lo - 2 * H <= g * H <= freeze_hi + late_max + 2 * H, (g, freeze_lo, freeze_hi, late_max)
    else:
        # burst_max = 10 (default): at most 10 steps in a wake-up, so a freeze of ~40 ticks
        # ends in a jump over the rest of the backlog
        g = int(np.max(gaps[after]))
        assert g > 1 and (freeze_lo - 2 * H) / H - 10 <= g, (g, freeze_lo)
    print(f'free-run e2e ({catch_up}): freeze {freeze_lo * 1e3:.1f}..{freeze_hi * 1e3:.1f} ms -> '
          f'largest gap after it {g} '
          f'ticks; {fr}')
    # simulated time tracks wall time
    step_wall = 0.05        # s, bound on one step's wall time (measured 0.2-1 ms here: 50x)
    assert 0.0 <= fr['drift_s'] <= late_max + step_wall, fr
    # ... seen from outside: the DDS source timestamp of each /clock sample (the node's wall
    # clock when it wrote it; system clock, independent of the node's monotonic bookkeeping
    # and of this process's receive backlog) - simulated time; its median over the first
    # and the last fifth of the run differ by at most the node's drift range (<= drift_max)
    # + 20 ms for CLOCK_REALTIME vs CLOCK_MONOTONIC rate difference over 6 s (NTP slews at
    # most 500 ppm: 3 ms) and the /clock publication before the joint state (< one step)
    recv = np.array(driver.received)
    offset = recv[:, 0] - recv[:, 1]
    fifth = max(recv.shape[0] // 5, 1)
    shift = float(np.median(offset[-fifth:]) - np.median(offset[:fifth]))
    print(f'free-run e2e: /clock source time - sim offset: spread {np.ptp(offset) * 1e3:.1f} ms, median '
          f'shift first -> last fifth {shift * 1e3:.2f} ms over {recv[-1, 1] - recv[0, 1]:.3f} s simulated')
    assert recv[-1, 1] == pytest.approx(DURATION)
    assert recv[0, 1] <= freeze_sim - FOLLOW_BEFORE_FREEZE + H, (recv[0, 1], freeze_sim)
    assert abs(shift) <= fr['drift_max_s'] + 0.02, (shift, fr)
    # the throttle publisher drove the engine (linear law at the answered crank speed)
    eng = data['/engine/wrench']
    crank = dict(zip(np.round(js.t / H).astype(np.int64), js.velocity[:, js.shaft('crank')]))
    ke = np.round(eng.t / H).astype(np.int64)
    x = np.array([(tz + K1 * crank[kk]) / M1 for kk, tz in zip(ke, eng.torque_z) if kk in crank])
    assert x.size >= fr['ticks_run']
    dist = np.min(np.abs(x[:, None] - np.array(PEDAL)[None, :]), axis=1)
    assert np.all(dist <= 1e-9), np.unique(np.round(x, 6))
    assert len(set(np.round(x, 6))) >= 2          # the pedal changed during the run
    assert all(math.isfinite(v) for v in js.velocity.ravel())


def test_free_run_rt_priority_is_applied_or_refused_with_one_warning(tmp_path: Path) -> None:
    """`--rt-priority 5`: the coupling node's threads run under SCHED_FIFO 5 when the process
    may (CAP_SYS_NICE) - the report and report.json say so - else one WARN line in its log
    and realtime_priority 0; the run finishes either way."""
    scene = tmp_path / 'scene.yaml'
    scene.write_text(yaml.safe_dump(dict(SCENE, duration=0.5), sort_keys=False))
    out = tmp_path / 'run'
    proc = subprocess.run([str(BIN / 'cvj-sim'), 'run', str(scene), '--out', str(out), '--mode',
                           'free-run', '--rt-priority', '5'], capture_output=True, text=True,
                          timeout=180, stdin=subprocess.DEVNULL, env=dict(os.environ))
    assert proc.returncode == 0, proc.stdout + proc.stderr
    fr = json.loads((out / 'report.json').read_text())['metrics']['free_run']
    log = (out / 'logs' / 'coupling_node.log').read_text()
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(5))   # may this machine?
        allowed = True
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    except PermissionError:
        allowed = False
    if allowed:
        assert fr['realtime_priority'] == 5 and 'SCHED_FIFO 5' in proc.stdout
        assert 'SCHED_FIFO refused' not in log
    else:
        assert fr['realtime_priority'] == 0 and log.count('SCHED_FIFO refused') == 1
    assert fr['ticks_handled'] == 100


def test_bad_rt_priority_is_one_line_exit_2(tmp_path: Path) -> None:
    proc = subprocess.run([str(BIN / 'cvj-sim'), 'run', 'kavz685_lever', '--out', str(tmp_path / 'r'),
                           '--mode', 'free-run', '--rt-priority', '100'], capture_output=True,
                          text=True, timeout=60, stdin=subprocess.DEVNULL, env=dict(os.environ))
    assert proc.returncode == 2, proc.stdout + proc.stderr
    assert '--rt-priority: must be an integer in 0..99, got 100' in proc.stderr
    assert 'Traceback' not in proc.stderr
