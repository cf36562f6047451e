"""End to end: `cvj-sim run` on vehicle scenes, composed and one process per node.

fwd_axle runs 0.1 s at its 1 ms exchange step (100 steps) in each mode; the four shipped
vehicle scenes run 0.02 s composed. The bound on |omega_lockstep - omega_simulate| is, as for
chains (test/e2e/test_run.py), the ZOH exchange error of the engine torque, first order in
the exchange step H (cvj_ros.physics.cosim): estimated without the reference by Richardson
extrapolation of the offline exchange loop, E(H) ~= 2 |w(H) - w(H/2)|. Checked: (1) first
order against the offline Simulation (ratio E(H)/E(H/2) in 1.6..2.4); (2) each ROS run equals
the offline exchange loop at the same H (same stepper on the same torques: 1e-9 relative,
far above the 3e-14 seen, for the stamps' rounding); (3) |lockstep - simulate| <= 1.25 E(H)
on every shaft, the wheels included. The tyres and the vehicle body are inside the equations
the coupling node integrates, so they add no exchange error of their own.
"""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from cvj_ros import bag

pytestmark = pytest.mark.e2e

H = 1e-3
DURATION = 0.1
N = int(round(DURATION / H))
CVJ_SIM = str(Path(sys.executable).with_name('cvj-sim'))
VEHICLE_SCENES = ('fwd_axle', 'fwd_axle_split_mu', 'rwd_propshaft', 'awd_4x4')


def _cli(args: list[str]) -> subprocess.CompletedProcess:
    return subprocess.run([CVJ_SIM, *args], capture_output=True, text=True, timeout=600)


@pytest.fixture(scope='module')
def work(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp('e2e_vehicle')


@pytest.fixture(scope='module')
def runs(work: Path) -> dict[str, tuple[subprocess.CompletedProcess, Path]]:
    """fwd_axle twice composed (determinism) and once one process per node."""
    out = {}
    for key, extra in (('composed', ['--composed']), ('composed_again', ['--composed']),
                       ('separate', [])):
        r = _cli(['run', 'fwd_axle', '--out', str(work / key), '--duration', str(DURATION), *extra])
        out[key] = (r, work / key / 'bag')
    return out


def _offline_exchange_loop(scene, h: float) -> np.ndarray:
    """Velocities at t_k of the exchange loop without ROS (what the nodes compute): the
    coupling node's stepper on the TreeDriveline, the engine torque held from t_k."""
    from cvj_ros.physics.cosim import CoupledStepper
    from cvj_ros.physics.engine import engine_from_spec
    from cvj_ros.physics.tree import TreeDriveline
    dl = TreeDriveline.from_scene(scene, track_energy=True)
    eng = engine_from_spec(dict(scene.engine))
    st = CoupledStepper(dl, scheme='zoh', method=scene.solver.method, rtol=scene.solver.rtol,
                        atol=scene.solver.atol, h=scene.solver.h)
    h_ns = int(round(h * 1e9))
    x = np.array(dl.x0, dtype=float)
    n = int(round(DURATION / h))
    out = []
    for k in range(n + 1):
        te = eng.torque(k * h_ns / 1e9, dl.engine_omega(x), dl.engine_phi(x))
        out.append(np.asarray(dl.joint_states(x, te, 0.0)[2], dtype=float))
        if k < n:
            x = st.advance((k + 1) * h_ns / 1e9, te, 0.0)
    return np.array(out)


def _joint_states(bag_path: Path) -> bag.JointStateSeries:
    return bag.read_bag(bag_path, ['/driveline/joint_states'])['/driveline/joint_states']


@pytest.mark.parametrize('mode', ['composed', 'separate'])
def test_vehicle_run_writes_every_branch_and_the_report_shows_the_wheels(runs, mode: str) -> None:
    from cvj_ros.physics.scene import find_scene, load_scene
    from cvj_ros.physics.tree import TreeDriveline
    r, bag_path = runs[mode]
    assert r.returncode == 0, r.stdout + r.stderr
    names = TreeDriveline.from_scene(load_scene(find_scene('fwd_axle'))).shaft_names
    info = bag.bag_info(bag_path)
    # every joint of both branches records its reaction wrench, one per exchange
    joints = ('gearbox', 'tripod_left', 'rzeppa_left', 'tripod_right', 'rzeppa_right')
    assert set(info.counts) == {'/clock', '/driveline/joint_states', '/driveline/scene',
                                '/engine/wrench', '/load/wrench', '/diagnostics',
                                *(f'/coupling/{j}/wrench' for j in joints)}, info.counts
    assert info.counts['/driveline/joint_states'] == N + 1
    data = bag.read_bag(bag_path)
    for j in joints:
        w = data[f'/coupling/{j}/wrench']
        assert info.counts[f'/coupling/{j}/wrench'] == N + 1 and w.frame_id == f'{j}_housing'
        assert np.all(np.isfinite(w.torque))
    js = data['/driveline/joint_states']
    assert js.names == names and {'wheel_left', 'wheel_right'} <= set(names)
    np.testing.assert_array_equal(np.round(js.t * 1e9).astype(np.int64), np.arange(N + 1) * 1_000_000)
    load = data['/load/wrench']
    assert load.frame_id == 'wheel_right' and np.all(load.torque == 0.0)   # tyres inside
    assert np.sort(load.t)[:N].tolist() == js.t[:N].tolist()
    for shaft in ('wheel_left', 'wheel_right', 'differential_left', 'differential_right'):
        assert f'\n    {shaft} ' in r.stdout, r.stdout            # per-wheel row of the report
    # analyze: per shaft (the wheels included) and the vehicle's loop values
    from cvj_ros import analysis
    rep = analysis.analyze_bag(bag_path)
    assert {'wheel_left', 'wheel_right'} <= set(rep['shafts'])
    assert set(rep['reactions']) == set(joints)          # every branch's joints, housing frame
    assert all(rep['reactions'][j]['frame_id'] == f'{j}_housing' for j in joints)
    assert 'reaction wrenches (housing frame)' in analysis.format_report(rep)
    figs = rep['diagnostics']['figures']
    assert 13.0 < figs['coupling_node: loop/vehicle_speed_m_s']['last'] < 14.5   # from 50 km/h
    for w in ('wheel_left', 'wheel_right'):
        assert figs[f'coupling_node: loop/{w}.fz_N']['last'] > 0
        assert figs[f'coupling_node: loop/{w}.status']['max_abs'] == 0


def test_vehicle_lockstep_matches_offline_within_exchange_error(runs) -> None:
    from cvj_ros.physics.scene import find_scene, load_scene
    from cvj_ros.physics.simulate import Simulation
    scene = load_scene(find_scene('fwd_axle'))
    ref = Simulation(scene).run(DURATION, sample_dt=H)
    w_h, w_h2 = _offline_exchange_loop(scene, H), _offline_exchange_loop(scene, H / 2)[::2]
    for mode in ('composed', 'separate'):
        r, bag_path = runs[mode]
        assert r.returncode == 0, r.stdout + r.stderr
        js = _joint_states(bag_path)
        ref_w = np.array([ref.velocity[:, ref.column(n)] for n in js.names]).T
        assert ref_w.shape == js.velocity.shape
        scale = np.max(np.abs(ref_w))
        # (2) the ROS run is the offline exchange loop
        assert np.max(np.abs(js.velocity - w_h)) <= 1e-9 * scale, mode
        # (1) the ZOH engine-torque exchange error is first order in H
        e_h, e_h2 = np.max(np.abs(w_h - ref_w)), np.max(np.abs(w_h2 - ref_w))
        assert 1.6 < e_h / e_h2 < 2.4, (e_h, e_h2)
        # (3) per shaft, the wheels included: within the Richardson bound of that shaft
        bound = 2 * np.max(np.abs(w_h - w_h2), axis=0)
        err = np.max(np.abs(js.velocity - ref_w), axis=0)
        assert np.all(err <= 1.25 * bound + 1e-9), dict(zip(js.names, zip(err, bound)))
        for wheel in ('wheel_left', 'wheel_right'):
            i = js.names.index(wheel)
            print(f'\n{mode} {wheel}: max |dw| = {err[i]:.3e} rad/s, bound {bound[i]:.3e} rad/s')


def test_vehicle_runs_are_byte_identical_and_modes_agree(runs) -> None:
    (r0, b0), (r1, b1) = runs['composed'], runs['composed_again']
    assert r0.returncode == 0 and r1.returncode == 0, r0.stderr + r1.stderr

    def messages(b: Path) -> list[tuple[str, int, bytes]]:
        # /diagnostics carry wall-clock metrics: excluded (as for chains)
        return [(t, ts, bytes(d)) for t, _, ts, d in bag.read_raw(b) if t != '/diagnostics']
    m0 = messages(b0)
    assert m0 == messages(b1) and len(m0) > 3 * N
    # one process per node integrates the same numbers
    rs, bs = runs['separate']
    assert rs.returncode == 0, rs.stderr
    js0, js2 = _joint_states(b0), _joint_states(bs)
    np.testing.assert_array_equal(js0.velocity, js2.velocity)
    np.testing.assert_array_equal(js0.position, js2.position)
    np.testing.assert_array_equal(js0.effort, js2.effort)


@pytest.mark.parametrize('scene', VEHICLE_SCENES)
def test_every_vehicle_scene_runs_briefly(work: Path, scene: str) -> None:
    from cvj_ros.physics.scene import Wheel, find_scene, iter_elements, load_scene
    r = _cli(['run', scene, '--out', str(work / f'brief_{scene}'), '--duration', '0.02', '--composed'])
    assert r.returncode == 0, r.stdout + r.stderr
    js = _joint_states(work / f'brief_{scene}' / 'bag')
    wheels = [el.name for el in iter_elements(load_scene(find_scene(scene)).driveline)
              if isinstance(el, Wheel)]
    assert set(wheels) <= set(js.names) and len(wheels) >= 2
    assert np.all(np.isfinite(js.velocity)) and js.t.size == 21


C_ROAD = 3.0        # N m s/rad: the tiny responder's wheel load T_w = C_ROAD omega_w
N_EXT = 50          # 0.05 s: the outside-wheel mode runs the Python stepper (no kernel input)


def _offline_with_wheel_rule(scene) -> np.ndarray:
    """The exchange loop without ROS with the responder's rule as the wheel loads."""
    from cvj_ros.physics.cosim import CoupledStepper
    from cvj_ros.physics.engine import engine_from_spec
    from cvj_ros.physics.tree import TreeDriveline
    dl = TreeDriveline.from_scene(scene, track_energy=True)
    dl.set_wheel_torques([0.0] * dl.n_wheel)
    eng = engine_from_spec(dict(scene.engine))
    st = CoupledStepper(dl, scheme='zoh', method=scene.solver.method, rtol=scene.solver.rtol,
                        atol=scene.solver.atol, h=scene.solver.h)
    x = np.array(dl.x0, dtype=float)
    out = []
    for k in range(N_EXT + 1):
        te = eng.torque(k * 1_000_000 / 1e9, dl.engine_omega(x), dl.engine_phi(x))
        names, _p, v, _e = dl.joint_states(x, te)
        out.append(v)
        if k < N_EXT:
            dl.set_wheel_torques([C_ROAD * v[names.index(w)] for w in dl.wheel_names])
            x = st.advance((k + 1) * 1_000_000 / 1e9, te, 0.0)
    return np.array(out)


@pytest.mark.parametrize('mode', ['composed', 'separate'])
def test_external_per_wheel_loads_answered_by_a_tiny_responder(work: Path, mode: str) -> None:
    """--external load on a vehicle scene: no load_node, one /load/<wheel>/wrench per wheel
    from an outside process (test/e2e/wheel_responder.py), recorded, integrated."""
    import os
    responder = subprocess.Popen([sys.executable, str(Path(__file__).with_name('wheel_responder.py')),
                                  str(C_ROAD), 'wheel_left', 'wheel_right'], env=dict(os.environ),
                                 stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        out = work / f'ext_{mode}'
        r = _cli(['run', 'fwd_axle', '--out', str(out), '--duration', str(N_EXT * H), '--external', 'load',
                  *(['--composed'] if mode == 'composed' else [])])
    finally:
        responder.terminate()
        responder.wait(timeout=30)
    assert r.returncode == 0, r.stdout + r.stderr
    assert '/load/wheel_left/wrench, /load/wheel_right/wrench (each wheel' in r.stdout
    assert 'external=load' in r.stdout
    data = bag.read_bag(out / 'bag')
    assert '/load/wrench' not in data                    # no load_node
    js = data['/driveline/joint_states']
    assert js.t.size == N_EXT + 1
    for wheel in ('wheel_left', 'wheel_right'):
        answers = data[f'/load/{wheel}/wrench']
        assert answers.frame_id == wheel
        order = np.argsort(answers.t)
        np.testing.assert_array_equal(answers.t[order][:N_EXT], js.t[:N_EXT])   # stamps echoed
        i = js.names.index(wheel)
        np.testing.assert_array_equal(answers.torque_z[order][:N_EXT], C_ROAD * js.velocity[:N_EXT, i])
        assert f'\n    /load/{wheel}/wrench' in r.stdout
    # the run is the offline exchange loop with the same wheel answers (same Python stepper)
    from cvj_ros.physics.scene import find_scene, load_scene
    ref = _offline_with_wheel_rule(load_scene(find_scene('fwd_axle')))
    assert np.max(np.abs(js.velocity - ref)) <= 1e-9 * np.max(np.abs(ref))
