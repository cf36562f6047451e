"""`cvj-sim run launch_clutch` (a vehicle tree: clutch, gearbox, two wheel brakes, a shift
schedule) as real processes, separate and composed: every shaft of both branches, every
engine answer and every throttle scale are the offline exchange loop's bit for bit
(KernelHybridTreeLockstep with the scene's command plan and the engine model answering each t_k
at pedal x throttle_scale(), the shift's throttle cut), the separate and the composed run
give the same bag, and the run follows `cvj-sim simulate` within a stated bound.

Runs are shortened to 4.6 s, over the first shift: both brakes hold the car on the 10 %
grade exactly at rest, the brakes release at ~1.74 s, the clutch locks at ~2.69 s in 1st,
the schedule shifts 1 -> 2 at ~3.88 s with the throttle cut and the clutch locks again in
2nd at ~4.31 s (docs/clutch_gearbox.md)."""
from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from cvj_ros import bag

pytestmark = pytest.mark.e2e

_spec = importlib.util.spec_from_file_location(
    'e2e_run_composed', Path(__file__).with_name('test_run_composed.py'))
_composed = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(_composed)
raw_messages = _composed.raw_messages          # canonical (stamp, CDR) per topic

DURATION = 4.6
N = 4600
H_NS = 1_000_000
CVJ_SIM = str(Path(sys.executable).parent / 'cvj-sim')
COMMAND_TOPICS = ('/engine/throttle', '/driveline/clutch', '/driveline/brake',
                  '/engine/throttle_scale')


@pytest.fixture(scope='module')
def runs(tmp_path_factory) -> dict[str, tuple[subprocess.CompletedProcess, Path]]:
    work = tmp_path_factory.mktemp('e2e_launch_clutch')
    out = {}
    for name, extra in (('separate', []), ('composed', ['--composed'])):
        r = subprocess.run([CVJ_SIM, 'run', 'launch_clutch', '--out', str(work / name),
                            '--duration', str(DURATION), *extra],
                           capture_output=True, text=True, timeout=900)
        out[name] = (r, work / name / 'bag')
    return out


def _scene():
    from cvj_ros.physics.scene import find_scene, load_scene
    return load_scene(find_scene('launch_clutch'))


def offline_exchange_loop(scene, h_ns: int, n: int) -> dict:
    """The loop's physics without ROS: the scene's stepper (hybrid_lockstep on the compiled
    tree kernel, as the coupling node's default), the commands
    of step k (CommandPlan), and the engine node's model (answering_source) answering the
    state t_k at pedal x throttle_scale() (the shift's cut), integrated t_k -> t_(k+1) with
    that torque held. Returns every step's joint states, torques, scales and the events."""
    from cvj_ros.nodes.command_plan import CommandPlan
    from cvj_ros.nodes.common import scene_dict
    from cvj_ros.nodes.engine_node import answering_source
    from cvj_ros.nodes.parameters import inertia_names
    from cvj_ros.physics.engine import engine_from_spec
    from cvj_ros.physics.hybrid.lockstep import hybrid_lockstep
    plan = CommandPlan.from_scene(scene, h_ns, n)
    hl = hybrid_lockstep(scene, backend='auto')     # the coupling node's default --mode-backend
    assert hl.backend == 'kernel'
    engine = engine_from_spec(dict(scene_dict(scene)['engine']), field='engine')
    source = answering_source(engine)
    pedal = float(engine.throttle)
    crank = hl.shaft_names.index(inertia_names(scene)[0])
    out: dict = {'pos': [], 'vel': [], 'eff': [], 'torque': [], 'scale': []}
    for k in range(n + 1):
        # the state t_k goes out with the commands of step k in force (their capacities in
        # the efforts) and the scale of step k; the engine answers it at pedal x scale
        vals = dict(plan.at(k))
        hl.set_commands(clutch=vals.get('clutch'), brake=vals.get('brake'))
        pedal = vals.get('throttle', pedal)
        scale = hl.throttle_scale()
        engine.set_throttle(pedal * scale)
        pos, vel, eff = hl.joint_states()
        torque = float(source.torque(k * h_ns / 1e9, vel[crank], pos[crank]))
        for key, v in (('pos', pos), ('vel', vel), ('eff', eff), ('torque', torque),
                       ('scale', scale)):
            out[key].append(v)
        if k < n:
            hl.advance((k + 1) * h_ns / 1e9, torque, 0.0)
    out['hybrid'] = hl
    return out


@pytest.fixture(scope='module')
def offline():
    return offline_exchange_loop(_scene(), H_NS, N)


def test_runs_finish_in_second_gear_with_the_clutch_locked(runs) -> None:
    for name, (r, _bag) in runs.items():
        assert r.returncode == 0, (name, r.stdout[-2000:], r.stderr[-2000:])
        assert ('modes at the end: clutch stuck, gearbox gear 2, brake_left slip+, '
                'brake_right slip+') in r.stdout, r.stdout


def test_separate_and_composed_runs_give_the_same_bag(runs) -> None:
    """Two runs, one process per node and all in one process, record the same messages
    (record stamp and canonical CDR) on every loop and command topic: the run does not
    depend on the layout nor on anything a second run could change."""
    a, b = raw_messages(runs['separate'][1]), raw_messages(runs['composed'][1])
    for topic in ('/clock', '/driveline/joint_states', '/driveline/scene', '/engine/wrench',
                  '/load/wrench', *COMMAND_TOPICS):
        ma, mb = a[topic], b[topic]
        if topic in ('/engine/wrench', '/load/wrench') and {len(ma), len(mb)} == {N, N + 1}:
            ma, mb = ma[:N], mb[:N]   # separate mode may lose the unawaited answer to t_N
        assert ma == mb, topic
        assert ma, topic


@pytest.mark.parametrize('name', ['separate', 'composed'])
def test_the_run_is_the_offline_exchange_loop_bit_for_bit(runs, offline, name) -> None:
    """The coupling node's physics is hybrid_lockstep(scene) stepped per exchange and the
    engine node's the engine model at pedal x scale: the offline loop (no ROS) gives every
    shaft's position, speed and effort, every engine torque and every throttle scale of the
    run bit for bit, through the shift with its throttle cut, and the same mode events."""
    data = bag.read_bag(runs[name][1], ['/driveline/joint_states', '/engine/wrench',
                                         '/engine/throttle_scale'])
    js, ew = data['/driveline/joint_states'], data['/engine/wrench']
    sc = data['/engine/throttle_scale']
    assert js.t.size == N + 1 and np.asarray(ew.t).size == N + 1
    assert list(js.names) == offline['hybrid'].shaft_names
    np.testing.assert_array_equal(js.position, np.array(offline['pos']))
    np.testing.assert_array_equal(js.velocity, np.array(offline['vel']))
    np.testing.assert_array_equal(js.effort, np.array(offline['eff']))
    order = np.argsort(np.asarray(ew.t), kind='stable')
    np.testing.assert_array_equal(np.asarray(ew.torque_z)[order], np.array(offline['torque']))
    # one scale per step, recorded at t_n; the cut ran (scale < 1 over the shift)
    np.testing.assert_array_equal(np.round(np.asarray(sc.t) * 1e9).astype(np.int64),
                                  np.arange(N + 1, dtype=np.int64) * H_NS)
    np.testing.assert_array_equal(np.asarray(sc.value), np.array(offline['scale']))
    assert min(offline['scale']) == 0.0
    hl = offline['hybrid']
    assert ('gearbox', 'gear 0', 'gear 2') in [(e.element, e.before, e.after) for e in hl.events]
    assert abs(hl.energy_residual()) < 1e-9


def test_the_run_follows_the_offline_reference(runs, offline) -> None:
    """Against `cvj-sim simulate` (engine torque, commands and the shift's throttle cut
    continuous) the loop holds them over each 1 ms step. Measured over these 4.6 s
    (docs/ros.md "Vehicle mode scenes"): the clutch and gearbox events are the reference's,
    in order, within EVENT_TOL (largest 1.1 ms, the re-lock in 2nd); outside the shift
    sequence every shaft's speed is within BOUND (largest error 31 % of it); inside it
    (trigger to re-lock) the same bound holds with the loop's curve allowed a time offset
    of one exchange step (its events are located on its own trajectory: largest 71 % of
    the bound), where the pointwise error at the gear engagement, a speed jump 0.9 ms
    later in the loop, reaches 42 % of a shaft's largest speed. The brakes hold both wheels
    at exactly 0 until their release; the clutch's two sides turn at one speed once it is
    locked in 2nd."""
    from cvj_ros.physics.hybrid.from_scene import hybrid_simulation
    off = hybrid_simulation(_scene(), duration=DURATION, sample_dt=0.001).run()
    key = lambda evs: [(e.element, e.before, e.after) for e in evs  # noqa: E731
                       if e.element in ('clutch', 'gearbox')]
    loop_events = offline['hybrid'].events
    assert key(loop_events) == key(off.events)
    assert ('gearbox', 'gear 0', 'gear 2') in key(off.events)
    for a, b in zip([e for e in loop_events if e.element in ('clutch', 'gearbox')],
                    [e for e in off.events if e.element in ('clutch', 'gearbox')]):
        assert abs(a.t - b.t) <= EVENT_TOL, (a, b)
    (t_shift,) = [e.t for e in off.events if e.after == 'shift to 2']
    t_lock = max(e.t for e in off.events if e.element == 'clutch' and e.after == 'stuck')
    js = bag.read_bag(runs['composed'][1], ['/driveline/joint_states'])['/driveline/joint_states']
    t = np.asarray(js.t)
    names = list(js.names)
    inside = (off.t >= t_shift) & (off.t <= t_lock)
    offsets = np.linspace(-H_NS / 1e9, H_NS / 1e9, 21)
    for name in off.shafts:
        v = js.velocity[:, names.index(name)]
        ref = off.column(name)
        bound = BOUND_REL * np.max(np.abs(ref)) + BOUND_ABS
        err = np.abs(np.interp(off.t, t, v) - ref)
        assert np.max(err[~inside]) <= bound, (name, np.max(err[~inside]))
        tube = np.min([np.abs(np.interp(off.t[inside] + s, t, v) - ref[inside])
                       for s in offsets], axis=0)
        assert np.max(tube) <= bound, (name, np.max(tube))
    for wheel in ('wheel_left', 'wheel_right'):
        assert np.all(js.velocity[t < 1.7, names.index(wheel)] == 0.0)
    late = t > 4.35
    np.testing.assert_array_equal(js.velocity[late, names.index('clutch_input')],
                                  js.velocity[late, names.index('clutch_output')])


BOUND_REL = 0.01
BOUND_ABS = 0.05
EVENT_TOL = 2e-3     # s, two exchange steps


def test_diagnostics_carry_the_modes_and_the_vehicle(runs, offline) -> None:
    """The coupling node's last loop status: gear, clutch and both brakes' modes, the mode
    events, the vehicle speed and per-wheel tyre values, the energy residual."""
    d = bag.read_bag(runs['composed'][1], ['/diagnostics'])['/diagnostics']
    last = [s for ss in d.statuses for s in ss if s['name'] == 'coupling_node: loop'][-1]
    v = last['values']
    assert (v['clutch_state.clutch'], v['gear.gearbox']) == ('stuck', '2')
    assert v['brake_state.brake_left'] == v['brake_state.brake_right'] == 'slip+'
    assert v['shifting'] == '0' and v['stall'] == '' and v['refused_commands'] == '0'
    assert int(v['mode_events']) == len(offline['hybrid'].events)
    assert float(v['vehicle_speed_m_s']) > 2.0
    for wheel in ('wheel_left', 'wheel_right'):
        assert float(v[f'{wheel}.fx_N']) > 0.0 and v[f'{wheel}.status'] == '0'
    assert abs(float(v['energy_residual'])) < 1e-9


def test_the_monitor_reports_the_standing_start_and_the_shift_as_states(runs) -> None:
    """The monitor's nonuniformity limits are for steady running: the launch from rest, the
    wheelspin on the grade and the shift are reported as states (`monitor: modes`), so the
    run has no ERROR status of the monitor (before: 44 in these windows)."""
    for name, (r, _bag) in runs.items():
        assert ' ERROR and ' not in r.stdout, (name, r.stdout[-3000:])
    d = bag.read_bag(runs['composed'][1], ['/diagnostics'])['/diagnostics']
    states = {s['message'] for ss in d.statuses for s in ss if s['name'] == 'monitor: modes'}
    assert 'steady running' in states
    assert any('slipping' in m for m in states) and any('shift running' in m for m in states)


def test_the_offline_bag_has_the_run_bags_joint_states(runs, tmp_path, capsys) -> None:
    """`cvj-sim simulate launch_clutch --bag` writes what the ROS run's bag carries for the
    same scene: its topics are the run's (the run adds /clock, /load/wrench, the throttle
    scale and its nodes' statuses), the joint states name the same shafts and fill position,
    velocity and effort, and at every offline sample (on the loop's 1 ms grid) the values
    agree within bounds set by the loop's 1 ms hold of torques and commands (measured in
    docs/clutch_gearbox.md "Bag and figure of an offline run": angles within
    POSITION_TOL_REL of each shaft's travel, torques within EFFORT_TOL_REL of each
    shaft's largest more than EVENT_WINDOW from a located event, where one held step moves
    a torque step by a whole exchange); `cvj-sim analyze` reads both."""
    from cvj_ros.cli import main
    assert main(['simulate', 'launch_clutch', '--duration', str(DURATION),
                 '--bag', str(tmp_path / 'off')]) == 0
    capsys.readouterr()
    ros_bag = runs['composed'][1]
    ros_topics = set(bag.bag_info(ros_bag).counts)
    off_topics = set(bag.bag_info(tmp_path / 'off').counts)
    assert off_topics <= ros_topics, off_topics - ros_topics
    assert {'/driveline/joint_states', '/engine/wrench', '/diagnostics', '/driveline/scene',
            '/driveline/clutch', '/driveline/brake', '/engine/throttle'} <= off_topics
    off = bag.read_bag(tmp_path / 'off', ['/driveline/joint_states'])['/driveline/joint_states']
    ros = bag.read_bag(ros_bag, ['/driveline/joint_states'])['/driveline/joint_states']
    assert list(off.names) == list(ros.names)
    k = np.round(np.asarray(off.t) * 1e9 / H_NS).astype(np.int64)
    np.testing.assert_array_equal(np.round(np.asarray(ros.t)[k] * 1e9).astype(np.int64), k * H_NS)
    travel = np.max(np.abs(ros.position - ros.position[0]), axis=0)
    d_pos = np.max(np.abs(off.position - ros.position[k]), axis=0)
    assert np.all(d_pos <= POSITION_TOL_REL * travel + 1e-9), dict(zip(off.names, d_pos / travel))
    ev = [e.t for e in runs_events(tmp_path / 'off')]
    near = np.zeros(k.size, dtype=bool)
    for te in ev:
        near |= np.abs(np.asarray(off.t) - te) <= EVENT_WINDOW
    big = np.max(np.abs(ros.effort), axis=0)
    d_eff = np.max(np.abs(off.effort[~near] - ros.effort[k][~near]), axis=0)
    assert np.all(d_eff <= EFFORT_TOL_REL * big), dict(zip(off.names, d_eff / big))
    for b in (tmp_path / 'off', ros_bag):
        assert main(['analyze', str(b), '--json']) == 0
        capsys.readouterr()


def runs_events(bag_dir: Path) -> list:
    """The located events of an offline bag (their /diagnostics statuses), with ``t``."""
    from types import SimpleNamespace

    from cvj_ros.mode_outputs import EVENT_STATUS
    d = bag.read_bag(bag_dir, ['/diagnostics'])['/diagnostics']
    return [SimpleNamespace(t=float(s['values']['t_s'])) for ss in d.statuses for s in ss
            if s['name'] == EVENT_STATUS]


# measured 2026-11-28 over these 4.6 s (composed run against the kernel's offline run):
# angles within 7e-4 of each shaft's travel; torques within 3.3 % of each shaft's largest
# more than EVENT_WINDOW from a located event (27 % at the events themselves, where the
# loop's held commands move a torque step by up to one exchange); the engine torque 0.97 %
POSITION_TOL_REL = 2e-3
EFFORT_TOL_REL = 0.05
EVENT_WINDOW = 0.05   # s: the loop's clutch re-lock lags the reference's by up to 1.1 ms, its
#                       torques settle within ~30 ms of an event (measured above)
