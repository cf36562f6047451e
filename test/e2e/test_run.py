"""End to end: `cvj-sim run` starts the node processes, records a bag, reports; faults and signals.

Runs are short (0.2 s simulated at 1 ms exchange = 200 steps) and shared between tests
through module fixtures, so the whole file stays well under two minutes on 2 cores.

Lockstep against offline: the bound on |omega_lockstep - omega_simulate| is the
exchange-coupling error of ZOH, which is first order in the exchange step H
(cvj_ros.physics.cosim: the held torque is an explicit Euler feedback). Its size at H is
estimated without the reference by Richardson extrapolation of the offline coupled
stepper: E(H) ~= 2 |w_cosim(H) - w_cosim(H/2)| (for e = C H + O(H^2)). The test checks
(1) first order (E(H)/E(H/2) in 1.6..2.4 against the offline Simulation),
(2) the ROS lockstep run equals the offline coupled stepper at the same H (same
arithmetic; only the solver tolerance and the stamp rounding remain: 1e-6 relative), and
(3) |lockstep - simulate| <= 1.25 E(H) + 1e-9.
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

from cvj_ros import bag

pytestmark = pytest.mark.e2e

H = 1e-3
DURATION = 0.2
N = int(round(DURATION / H))
CVJ_SIM = str(Path(sys.executable).with_name('cvj-sim'))

# Scene A: the KAVZ-685 machine unit of seed 004 shortened to a Hooke coupling with an elastic
# bushing (linear engine characteristic, constant load).
SCENE_A = {
    'name': 'e2e_hooke', 'description': 'e2e: engine, bushing, Hooke 15 deg, driven', 'seed': 3,
    'duration': 1.0, 'exchange_step': H,
    'solver': {'method': 'dopri5', 'rtol': 1e-9, 'atol': 1e-11},
    'engine': {'model': 'linear'}, 'load': {'model': 'constant', 'torque': 100.0},
    'initial': {'speed_rpm': 300.0},
    'driveline': [
        {'type': 'inertia', 'name': 'crank', 'J': 0.128},
        {'type': 'spring', 'name': 'bush', 'stiffness': 715.4, 'damping': 6.35},
        {'type': 'joint', 'name': 'cpl', 'kind': 'hooke', 'fidelity': 'exact', 'params': {'beta_deg': 15.0}},
        {'type': 'inertia', 'name': 'driven', 'J': 0.161},
    ],
}
# Scene B: seeded random load (seed 004 eq. 3.30) through two joints and a midshaft spring.
SCENE_B = {
    'name': 'e2e_random', 'description': 'e2e: seeded random load, two joints', 'seed': 11,
    'duration': 1.0, 'exchange_step': H,
    'solver': {'method': 'dopri5', 'rtol': 1e-8, 'atol': 1e-10},
    'engine': {'model': 'linear'},
    'load': {'model': 'random', 'mean': 107.5, 'amplitude': 8.8, 'sample_interval': 0.01},
    'initial': {'speed_rpm': 350.0},
    'driveline': [
        {'type': 'inertia', 'name': 'crank', 'J': 0.128},
        {'type': 'joint', 'name': 'inner', 'kind': 'hooke', 'fidelity': 'exact', 'params': {'beta_deg': 10.0}},
        {'type': 'inertia', 'name': 'mid', 'J': 0.02},
        {'type': 'spring', 'name': 'midshaft', 'stiffness': 2000.0, 'damping': 2.0},
        {'type': 'joint', 'name': 'outer', 'kind': 'hooke', 'fidelity': 'exact',
         'params': {'beta_deg': 10.0, 'phase_deg': 0.0}},     # yokes 90 deg out of phase
        {'type': 'inertia', 'name': 'wheel', 'J': 0.161},
    ],
}


def _write_scene(path: Path, scene: dict) -> Path:
    path.write_text(yaml.safe_dump(scene, sort_keys=False))
    return path


def _cli(args: list[str], **kw) -> subprocess.CompletedProcess:
    return subprocess.run([CVJ_SIM, *args], capture_output=True, text=True, timeout=120, **kw)


@pytest.fixture(scope='module')
def work(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp('e2e_run')
    _write_scene(d / 'a.yaml', SCENE_A)
    _write_scene(d / 'b.yaml', SCENE_B)
    return d


@pytest.fixture(scope='module')
def run_a(work: Path) -> tuple[subprocess.CompletedProcess, Path]:
    r = _cli(['run', str(work / 'a.yaml'), '--out', str(work / 'run_a'), '--duration', str(DURATION),
              '--exchange-step', str(H)])
    return r, work / 'run_a' / 'bag'


@pytest.fixture(scope='module')
def runs_b(work: Path) -> list[tuple[subprocess.CompletedProcess, Path]]:
    out = []
    for i, storage in enumerate(('mcap', 'sqlite3')):
        r = _cli(['run', str(work / 'b.yaml'), '--out', str(work / f'run_b{i}'), '--duration', str(DURATION),
                  '--seed', '7', '--storage', storage])
        out.append((r, work / f'run_b{i}' / 'bag'))
    return out


def _check_bag_layout(bag_path: Path, shafts: list[str], joints: list[str]) -> bag.JointStateSeries:
    info = bag.bag_info(bag_path)
    expected = {'/clock', '/driveline/joint_states', '/driveline/scene', '/engine/wrench', '/load/wrench',
                '/diagnostics'} | {f'/coupling/{j}/wrench' for j in joints}
    assert set(info.counts) == expected, info.counts
    for topic in ('/clock', '/driveline/joint_states'):
        assert info.counts[topic] == N + 1, (topic, info.counts)
    assert info.counts['/driveline/scene'] == 1
    data = bag.read_bag(bag_path)
    js = data['/driveline/joint_states']
    assert js.names == shafts
    np.testing.assert_array_equal(np.round(js.t * 1e9).astype(np.int64), np.arange(N + 1) * 1_000_000)
    assert np.all(np.diff(js.record_t) > 0)                       # record time = stamp, monotonic
    np.testing.assert_array_equal(js.record_t, js.t)
    for topic in ('/engine/wrench', '/load/wrench'):
        # every exchange the loop waited for was answered once, stamp echoed; the answer to the
        # final state t_N is not waited for and may be lost when the coupling node exits
        # before its last sample reached the peer (known: coupling_node does not wait for acks)
        stamps = np.sort(data[topic].t)
        np.testing.assert_array_equal(stamps[:N], js.t[:N])
        assert stamps.size in (N, N + 1) and (stamps.size == N or stamps[-1] == js.t[-1])
    np.testing.assert_array_equal(data['/clock'].value, js.t)
    # plain frame names (REP-103): no run token (the run knows its peers by publisher)
    assert 'cvj_ros.run_token' not in info.custom_data
    assert data['/engine/wrench'].frame_id == shafts[0]
    assert data['/load/wrench'].frame_id == shafts[-1]
    assert np.all(np.isfinite(js.position)) and np.all(np.isfinite(js.velocity))
    return js


def test_run_writes_documented_bag_and_report(run_a) -> None:
    r, bag_path = run_a
    assert r.returncode == 0, r.stdout + r.stderr
    _check_bag_layout(bag_path, ['crank', 'cpl_input', 'cpl_output', 'driven'], ['cpl'])
    for text in ('finished', 'real-time factor', 'nonuniformity', '/driveline/joint_states 201', str(bag_path),
                 'loop per exchange: wall ', 's of loop (first to last joint state recorded)',
                 'after the loop'):
        assert text in r.stdout, r.stdout
    scene_msg = bag.read_scene_message(bag_path)
    assert scene_msg['scene']['name'] == 'e2e_hooke'
    assert scene_msg['mode'] == 'lockstep' and scene_msg['coupling_scheme'] == 'zoh'
    assert 'fidelity' in scene_msg
    info = bag.bag_info(bag_path)
    assert info.custom_data['cvj_ros.mode'] == 'lockstep'
    assert yaml.safe_load(info.custom_data['cvj_ros.scene'])['scene']['name'] == 'e2e_hooke'
    report = yaml.safe_load((bag_path.parent / 'report.json').read_text())
    assert report['exit_code'] == 0 and report['wall_per_step'] > 0
    print(f"\nwall time per exchange step: {report['wall_per_step'] * 1e6:.0f} us "
          f"(loop {report['loop_wall_time']:.3f} s for {N} steps)")


def test_run_report_and_analyze_agree_on_the_bag(run_a) -> None:
    """One window definition (cvj_ros.physics.steady): the run's report (report.json and
    its printed window line with the criterion) and `analyze` of the same bag give the same
    window and the same numbers (same arrays, same functions: rel 1e-12)."""
    from cvj_ros import analysis
    r, bag_path = run_a
    assert r.returncode == 0, r.stdout + r.stderr
    metrics = yaml.safe_load((bag_path.parent / 'report.json').read_text())['metrics']
    rep = analysis.analyze_bag(bag_path)
    assert 'steady window ' + metrics['window_text'] in r.stdout, r.stdout
    assert metrics['window']['criterion'] in r.stdout
    assert rep['window']['text'] == metrics['window_text']
    assert [rep['window']['start_s'], rep['window']['end_s']] == metrics['window_s']
    for name, m in metrics['shafts'].items():
        a = rep['shafts'][name]
        for key_run, key_an in (('mean_speed', 'mean_speed_rad_s'), ('delta', 'speed_nonuniformity'),
                                ('acceleration_amplitude', 'acceleration_amplitude_rad_s2'),
                                ('torque_amplitude', 'torque_amplitude_Nm')):
            assert a[key_an] == pytest.approx(m[key_run], rel=1e-12, abs=1e-12), (name, key_run)


def _offline_coupled(scene, h: float) -> np.ndarray:
    """Velocities at t_k of the offline exchange loop (what the nodes compute, without ROS)."""
    from cvj_ros.physics.cosim import CoupledStepper
    from cvj_ros.physics.driveline import Driveline
    from cvj_ros.physics.engine import engine_from_spec
    from cvj_ros.physics.load import load_from_spec
    dl = Driveline.from_scene(scene, track_energy=True)
    eng = engine_from_spec(dict(scene.engine))
    load = load_from_spec(dict(scene.load), seed=scene.seed)
    st = CoupledStepper(dl, scheme='zoh', method=scene.solver.method, rtol=scene.solver.rtol,
                        atol=scene.solver.atol, h=scene.solver.h)
    x = np.array(dl.x0, dtype=float)
    n = int(round(DURATION / h))
    out = []
    for k in range(n + 1):
        t = k * h
        te = eng.torque(t, dl.engine_omega(x), dl.engine_phi(x))
        tl = load.torque(t, dl.load_omega(x), dl.load_phi(x))
        out.append(np.asarray(dl.joint_states(x, te, tl)[2], dtype=float))
        if k < n:
            x = st.advance((k + 1) * h, te, tl)
    return np.array(out)


def test_lockstep_matches_offline_within_exchange_error(run_a, work: Path) -> None:
    from cvj_ros.physics.scene import load_scene
    from cvj_ros.physics.simulate import Simulation
    r, bag_path = run_a
    assert r.returncode == 0, r.stderr
    js = bag.read_bag(bag_path, ['/driveline/joint_states'])['/driveline/joint_states']
    scene = load_scene(work / 'a.yaml')
    ref = Simulation(scene).run(DURATION, sample_dt=H)
    ref_w = np.array([ref.velocity[:, ref.column(n)] for n in js.names]).T
    assert ref_w.shape == js.velocity.shape
    w_h, w_h2 = _offline_coupled(scene, H), _offline_coupled(scene, H / 2)[::2]
    scale = np.max(np.abs(ref_w))
    # (2) the ROS run is the offline exchange loop
    assert np.max(np.abs(js.velocity - w_h)) <= 1e-6 * scale
    # (1) ZOH coupling error is first order in H
    e_h, e_h2 = np.max(np.abs(w_h - ref_w)), np.max(np.abs(w_h2 - ref_w))
    assert 1.6 < e_h / e_h2 < 2.4, (e_h, e_h2)
    # (3) bound from the exchange step alone (Richardson), checked against the reference
    bound = 2 * np.max(np.abs(w_h - w_h2))
    err = np.max(np.abs(js.velocity - ref_w))
    assert err <= 1.25 * bound + 1e-9, (err, bound)
    print(f'\nlockstep vs simulate: max |dw| = {err:.3e} rad/s, Richardson bound {bound:.3e} rad/s')


def test_same_seed_gives_identical_messages_across_storages(runs_b) -> None:
    (r0, b0), (r1, b1) = runs_b
    assert r0.returncode == 0, r0.stdout + r0.stderr
    assert r1.returncode == 0, r1.stdout + r1.stderr
    assert bag.bag_info(b0).storage == 'mcap' and bag.bag_info(b1).storage == 'sqlite3'
    _check_bag_layout(b0, ['crank', 'inner_input', 'inner_output', 'mid', 'outer_input', 'outer_output',
                           'wheel'], ['inner', 'outer'])
    # /diagnostics carry wall-clock metrics (real-time factor, wait times): excluded. Every
    # other message is byte-identical, record times too (no run token anywhere), and so is
    # the bag's metadata besides the storage
    def messages(b: Path) -> list[tuple[str, int, bytes]]:
        return [(t, ts, bytes(d)) for t, _, ts, d in bag.read_raw(b) if t != '/diagnostics']
    m0, m1 = messages(b0), messages(b1)
    assert len(m0) == len(m1) > 5 * N
    assert sorted(m0) == sorted(m1)
    assert bag.bag_info(b0).custom_data == bag.bag_info(b1).custom_data
    t, tz = bag.load_torque_series(b0)
    assert np.std(tz) > 1.0  # the random load is really random (seeded)
    assert bag.read_scene_message(b0)['seed'] == 7


def test_load_from_bag_reproduces_recorded_load(runs_b, work: Path) -> None:
    (_, b0), _ = runs_b
    (work / 'run_lb').mkdir()
    (work / 'run_lb' / 'notes.txt').write_text('mine')
    (work / 'run_lb' / 'report.json').write_text('{}')     # a previous run
    args = ['run', str(work / 'a.yaml'), '--out', str(work / 'run_lb'), '--duration', '0.1',
            '--load-from-bag', str(b0)]
    r = _cli(args)
    assert r.returncode == 2 and '--out:' in r.stderr and 'use --overwrite' in r.stderr
    r = _cli(args + ['--overwrite'])
    assert r.returncode == 0, r.stdout + r.stderr
    assert (work / 'run_lb' / 'notes.txt').read_text() == 'mine'   # --overwrite removes only run files
    t0, tz0 = bag.load_torque_series(b0)
    t1, tz1 = bag.load_torque_series(work / 'run_lb' / 'bag')
    assert t1.size in (100, 101)  # see _check_bag_layout on the answer to the final state
    np.testing.assert_allclose(tz1, np.interp(t1, t0, tz0), rtol=1e-9, atol=1e-9)


def test_bad_scene_exits_2_before_any_process(work: Path) -> None:
    bad = dict(SCENE_A, driveline=[dict(SCENE_A['driveline'][0], J=-1.0)] + SCENE_A['driveline'][1:])
    path = _write_scene(work / 'bad.yaml', bad)
    r = _cli(['run', str(path), '--out', str(work / 'run_bad')])
    assert r.returncode == 2
    assert r.stderr.strip().splitlines() == [r.stderr.strip()]  # one line
    assert 'driveline[0].J' in r.stderr and 'Traceback' not in r.stderr
    assert not (work / 'run_bad').exists()
    r = _cli(['run', 'no_such_scene', '--out', str(work / 'run_bad')])
    assert r.returncode == 2 and 'scene' in r.stderr
    r = _cli(['run', str(work / 'a.yaml'), '--out', str(work / 'run_bad'), '--duration', '-1'])
    assert r.returncode == 2 and r.stderr.startswith('cvj-sim: error: --duration')
    r = _cli(['run', str(work / 'a.yaml'), '--out', str(work / 'run_bad'), '--load-from-bag',
              str(work / 'no_bag')])
    assert r.returncode == 2 and r.stderr.startswith('cvj-sim: error: --load-from-bag:')
    assert 'no such bag' in r.stderr
    assert not (work / 'run_bad').exists()


def _wait_for(path: Path, text: str, timeout: float) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if path.exists() and text in path.read_text(errors='replace'):
            return
        time.sleep(0.05)
    raise AssertionError(f'{text!r} not in {path} after {timeout} s')


@pytest.mark.parametrize('sig', [signal.SIGINT, signal.SIGTERM])
def test_signal_leaves_readable_bag(work: Path, sig: int) -> None:
    out = work / f'run_sig{int(sig)}'
    p = subprocess.Popen([CVJ_SIM, 'run', str(work / 'a.yaml'), '--out', str(out), '--duration', '1000'],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        first = p.stdout.readline()  # printed once the first exchange is recorded
        assert 'loop running' in first, first
        time.sleep(0.3)   # not a discovery wait: let the loop record ~0.3 s of states before the signal
        p.send_signal(sig)
        stdout, stderr = p.communicate(timeout=30)
    finally:
        if p.poll() is None:
            p.kill()
    assert p.returncode == 128 + int(sig), stdout + stderr
    assert f'stopped by {signal.Signals(sig).name}' in stdout
    report = yaml.safe_load((out / 'report.json').read_text())
    assert all(code is not None for code in report['node_exit_codes'].values())  # no process left
    js = bag.read_bag(out / 'bag', ['/driveline/joint_states'])['/driveline/joint_states']
    assert js.t.size > 10 and np.all(np.diff(js.t) > 0)
    assert bag.bag_info(out / 'bag').counts['/driveline/scene'] == 1


@pytest.mark.ros
def test_killed_engine_stops_run_with_clear_error(work: Path) -> None:
    from cvj_ros.orchestrate import RunOptions, run
    out = work / 'run_kill'
    killed = []

    import io
    stream = io.StringIO()

    def kill_engine_later(procs) -> None:
        def killer() -> None:
            deadline = time.monotonic() + 60
            while 'loop running' not in stream.getvalue() and time.monotonic() < deadline:
                time.sleep(0.02)
            time.sleep(0.3)   # not a discovery wait: the loop runs ~0.3 s before the kill
            os.kill(procs['engine_node'].pid, signal.SIGKILL)
            killed.append(time.monotonic())
        threading.Thread(target=killer, daemon=True).start()

    result = run(RunOptions(scene=str(work / 'a.yaml'), out=out, duration=1000.0, peer_timeout=1.0),
                 stream=stream, on_started=kill_engine_later)
    assert killed
    assert result.exit_code == 1
    assert result.error is not None and result.error.startswith('coupling_node:')
    assert '/engine/wrench' in result.error, result.error
    print(f'\nkilled engine -> {result.error}')
    assert result.node_exit_codes['coupling_node'] not in (0, None)
    assert 'FAILED' in stream.getvalue()
    js = bag.read_bag(out / 'bag', ['/driveline/joint_states'])['/driveline/joint_states']
    assert js.t.size > 10 and np.all(np.diff(js.t) > 0)  # finalized, readable
