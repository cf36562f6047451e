"""The shipped vehicle launch scene `launch_clutch` (hill start of a FWD car, wheel brakes,
clutch engagement, scheduled shifts 1 -> 2 -> 3) and its sibling `fwd_axle_manual`
(commanded step-by-step up-shift), through the Python reference and `cvj-sim simulate`."""
from __future__ import annotations

import json

import numpy as np
import pytest

from cvj_ros.cli import main
from cvj_ros.physics.hybrid.from_scene import run_hybrid
from cvj_ros.physics.scene import load_scene, shipped_scenes

RPM = np.pi / 30.0


@pytest.fixture(scope='module')
def launch():
    scene = load_scene(shipped_scenes()['launch_clutch'])
    return scene, run_hybrid(scene)


def test_hill_start_shifts_and_end_state(launch) -> None:
    scene, (_sim, r, _wall) = launch
    assert r.stall is None and r.statuses == [] and r.t_end == scene.duration
    for b, w in (('brake_left', 'wheel_left'), ('brake_right', 'wheel_right')):
        ev = [(e.t, e.after) for e in r.events if e.element == b]
        assert ev[0] == (0.0, 'stuck')
        assert ev[1][1] == 'slip+' and 1.5 < ev[1][0] < 1.8    # released while the brake ramps out
        assert np.all(r.column(w)[r.t < ev[1][0]] == 0.0)       # held exactly, no creep
    gears = [e.after for e in r.events if e.element == 'gearbox']
    assert gears == ['shift to 2', 'gear 0', 'gear 2', 'shift to 3', 'gear 0', 'gear 3']
    # the last second in 3rd with the clutch locked: both sides at the same speed
    last = r.t >= scene.duration - 1.0
    assert np.all(r.gear[last] == 3)
    np.testing.assert_array_equal(r.column('clutch_input')[last], r.column('clutch_output')[last])
    assert r.final_mode.clutch['clutch'] == 0 and r.final_mode.gear['gearbox'] == 3
    assert r.vehicle_speed[-1] > 8.0                      # ~33 km/h up the 10 % grade
    assert r.max_energy_residual < 1e-9                   # rtol 1e-8; measured 1.4e-11


def test_shift_times_follow_the_schedule_rule(launch) -> None:
    """Each shift starts with the clutch locked, when the synchronous input speed
    i_g omega_gearbox_output reaches the up-shift speed (bracketed by the samples around it
    and, for the first, from an independent run stopped at that time: a different last step
    of the stepper), neutral follows open_s later and the new gear neutral_s after that."""
    scene, (_sim, r, _wall) = launch
    sched = scene.shift_schedule
    gb = scene.element('gearbox')
    starts = [(e.t, int(e.after.split()[-1])) for e in r.events if e.after.startswith('shift to')]
    assert [g for _t, g in starts] == [2, 3]
    out = r.column('gearbox_output')
    for t_s, g_new in starts:
        g = g_new - 1
        clutch_before = [e.after for e in r.events if e.element == 'clutch' and e.t < t_s]
        assert clutch_before[-1] == 'stuck'
        neutral = next(e.t for e in r.events if e.after == 'gear 0' and e.t > t_s)
        engaged = next(e.t for e in r.events if e.after == f'gear {g_new}' and e.t > t_s)
        assert neutral == pytest.approx(t_s + sched.open_time, abs=1e-12)
        assert engaged == pytest.approx(t_s + sched.open_time + sched.neutral_time, abs=1e-12)
        k = np.searchsorted(r.t, t_s)                     # samples r.t[k-1] < t_s <= r.t[k]
        sync = gb.ratio(g) * out[k - 1:k + 1]
        assert sync[0] < sched.up(g) <= sync[1] + 1e-9
        lin = sync[0] + (sync[1] - sync[0]) * (t_s - r.t[k - 1]) / (r.t[k] - r.t[k - 1])
        assert lin == pytest.approx(sched.up(g), rel=1e-4)     # speed ~linear over 10 ms
    t1 = starts[0][0]
    sim2, r2, _w = run_hybrid(scene, duration=t1)
    right = sim2.probe.links[sim2.probe.gearbox_link['gearbox']].right
    assert gb.ratio(1) * r2.final.qd[right] == pytest.approx(sched.up(1), rel=1e-6)
    assert sched.up(1) == pytest.approx(2500 * RPM)


def test_cli_simulate_reports_events_per_element(capsys) -> None:
    assert main(['simulate', 'launch_clutch', '--duration', '2', '--json']) == 0
    cap = capsys.readouterr()
    s = json.loads(cap.out)
    assert s['events']['brake_left'] == {'stuck': 1, 'slip+': 1}
    assert s['events']['brake_right'] == {'stuck': 1, 'slip+': 1}
    assert s['final_modes']['clutch'] == 'slip+' and s['final_modes']['gearbox'] == 'gear 1'
    assert s['energy_residual'] < 1e-9
    assert s['final_vehicle_speed_m_s'] > 0.0


def test_ros_runs_are_prepared_on_the_tree_lockstep(tmp_path) -> None:
    """`cvj-sim run` takes the scene (no refusal; the runs themselves:
    test/e2e/test_run_launch_clutch.py): the coupling node's backend is the vehicle mode
    model stepped per exchange, and the event-free models still refuse it naming the
    clutch."""
    from cvj_ros.errors import SceneError
    from cvj_ros.orchestrate.options import RunOptions, prepare
    from cvj_ros.physics.hybrid.lockstep import hybrid_lockstep
    from cvj_ros.physics.hybrid.tree_lockstep import HybridTreeLockstep
    from cvj_ros.physics.tree import TreeDriveline
    scene = load_scene(shipped_scenes()['launch_clutch'])
    assert isinstance(hybrid_lockstep(scene), HybridTreeLockstep)
    with pytest.raises(SceneError, match=r"driveline\[1\].*clutch 'clutch'"):
        TreeDriveline.from_scene(scene)
    nodes = prepare(RunOptions('launch_clutch', tmp_path / 'run')).nodes
    assert 'driver_node' in nodes and 'coupling_node' in nodes
    from cvj_ros.errors import CvjError
    with pytest.raises(CvjError, match='^--external load: a vehicle scene with clutch'):
        prepare(RunOptions('launch_clutch', tmp_path / 'run2', external=('load',)))


def test_fwd_axle_manual_commanded_upshift() -> None:
    """fwd_axle with clutch and gearbox: rolling at 50 km/h in 3rd with the clutch locked;
    the commanded shift 3 -> 4 opens the clutch (slip), goes through neutral at 1.55 s,
    engages 4th at 1.65 s and the clutch locks again; the wheels then turn at the engine
    speed over the 4th-gear ratio and the final drive (the differential's carrier)."""
    scene = load_scene(shipped_scenes()['fwd_axle_manual'])
    _sim, r, _w = run_hybrid(scene, duration=2.4)
    gb = [(e.t, e.after) for e in r.events if e.element == 'gearbox']
    assert gb == [(1.55, 'gear 0'), (1.65, 'gear 4')]
    cl = [e.after for e in r.events if e.element == 'clutch']
    assert cl[0] in ('slip+', 'slip-') and cl[-1] == 'stuck'
    assert r.final_mode.clutch['clutch'] == 0 and r.final_mode.gear['gearbox'] == 4
    w_e, w_c = r.column('clutch_output')[-1], r.column('differential_carrier')[-1]
    w_in = r.column('gearbox_input')[-1]
    assert r.column('gearbox_output')[-1] == pytest.approx(w_in / 1.0, rel=1e-12)
    assert w_c == pytest.approx(r.column('gearbox_output')[-1] / 4.06, rel=1e-12)
    assert abs(w_e - w_in) < 0.05 * w_e                  # only the damper's twist rate between
    assert r.max_energy_residual < 1e-9
