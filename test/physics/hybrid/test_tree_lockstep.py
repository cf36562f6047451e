"""HybridTreeLockstep: the vehicle mode model stepped per exchange. With inputs that are
constant over each exchange interval anyway (a constant engine torque, step commands at
exchange times) the held-input problem is the offline one, so the lockstep must reproduce
the offline reference (HybridTreeSimulation, an independent event loop over the whole run)
to the solvers' tolerance: the same mode events at the same times, the same speeds."""
from __future__ import annotations

import numpy as np
import pytest

from cvj_ros.physics.hybrid.commands import CommandSchedule
from cvj_ros.physics.hybrid.lockstep import Commands, hybrid_lockstep
from cvj_ros.physics.hybrid.shift import AutoShift
from cvj_ros.physics.hybrid.tree_lockstep import HybridTreeLockstep
from cvj_ros.physics.hybrid.tree_sim import HybridTreeSimulation
from cvj_ros.physics.scene import find_scene, load_scene

T_ENGINE = 150.0      # N m, constant: the ZOH of the loop is exact for it


class ConstEngine:
    def torque(self, t: float, omega: float, phi: float) -> float:
        return T_ENGINE

    def set_throttle(self, x: float) -> None:
        return None


ROWS = [(0.0, {'clutch': 1.0, 'brake': 1.0}), (0.05, {'brake': 0.0}), (0.1, {'clutch': 0.5})]
# the same as steps for the offline schedule (two rows at one time make a step)
STEPS = [(0.0, {'clutch': 1.0, 'brake': 1.0}), (0.05, {'brake': 1.0}), (0.05, {'brake': 0.0}),
         (0.1, {'clutch': 1.0}), (0.1, {'clutch': 0.5})]


def _scene():
    return load_scene(find_scene('launch_clutch'))


def _lockstep_run(duration: float, h: float) -> HybridTreeLockstep:
    scene = _scene()
    hl = HybridTreeLockstep(scene, {}, commands=Commands(1.0, 1.0, 0), shift=scene.shift_schedule,
                            stall_speed=None)
    n = int(round(duration / h))
    assert hl.cuts_throttle and hl.throttle_scale() == 1.0
    scales = []
    for k in range(n):
        t = k * h
        for tr, vals in ROWS:
            if abs(tr - t) < 1e-12:
                hl.set_commands(clutch=vals.get('clutch'), brake=vals.get('brake'))
        hl.advance((k + 1) * h, T_ENGINE, 0.0)
        assert abs(hl.energy_residual()) < 1e-8, (t, hl.energy_residual())   # rtol 1e-8
        scales.append(hl.throttle_scale())
    hl.scales = scales          # the throttle scale at t_1 .. t_n
    return hl


@pytest.fixture(scope='module')
def pair():
    duration = 2.6
    hl = _lockstep_run(duration, 0.01)
    scene = _scene()
    off = HybridTreeSimulation(scene, {}, engine=ConstEngine(),
                               schedule=AutoShift(CommandSchedule(STEPS), scene.shift_schedule),
                               duration=duration, sample_dt=0.01, stall_speed=None)
    return hl, off.run()


def test_events_and_speeds_equal_the_offline_reference(pair) -> None:
    """Brakes released at 0.05 s (the car rolls back in 1st behind the open clutch), the
    pedal to 0.5 at 0.1 s (the clutch slips, the car climbs, the clutch locks), the up-shift
    1 -> 2 by the shift schedule inside the model (neutral and the new gear at the
    sequence's breakpoints): the same events, times within 1e-6 s, final speeds within 1e-6
    relative."""
    hl, r = pair
    got = [(e.element, e.before, e.after) for e in hl.events]
    want = [(e.element, e.before, e.after) for e in r.events]
    assert got == want
    assert ('gearbox', 'gear 0', 'gear 2') in got          # the schedule shifted inside
    for a, b in zip(hl.events, r.events):
        assert a.t == pytest.approx(b.t, abs=1e-6), (a, b)
    mt = hl.tree(hl.mode)
    vel = mt.shaft_speeds(mt.from_state(hl.st, False)[0])   # the reference's convention:
    for i, name in enumerate(hl.shaft_names):               # mid members as their input
        ref = r.column(name)[-1]
        assert vel[i] == pytest.approx(ref, rel=1e-6, abs=1e-6), name
    _pos, js_vel, _eff = hl.joint_states()
    mid = {'tripod_left_spider', 'tripod_right_spider', 'rzeppa_left_cage', 'rzeppa_right_cage'}
    for i, name in enumerate(hl.shaft_names):
        if name not in mid:
            assert js_vel[i] == vel[i], name
    assert hl.mode_values()['vehicle_speed_m_s'] == pytest.approx(r.vehicle_speed[-1], rel=1e-6)


def test_throttle_scale_is_one_minus_the_shift_envelope(pair) -> None:
    """The stepper's output for the engine: 1 - e(t_k) at every exchange time, e built here
    from the up-shift's event time and the schedule's open/neutral/close times (a ramp
    0 -> 1, a hold, a ramp 1 -> 0; docs/clutch_gearbox.md), 1 outside the shift."""
    hl, _r = pair
    s = _scene().shift_schedule
    (ts,) = [e.t for e in hl.events if e.after == 'shift to 2']
    h = 0.01
    inside = 0
    for k, got in enumerate(hl.scales, start=1):
        tau = k * h - ts
        if tau <= 0.0 or tau >= s.open_time + s.neutral_time + s.close_time:
            e = 0.0
        elif tau < s.open_time:
            e = tau / s.open_time
        elif tau <= s.open_time + s.neutral_time:
            e = 1.0
        else:
            e = (s.open_time + s.neutral_time + s.close_time - tau) / s.close_time
        inside += 0.0 < e
        assert got == pytest.approx(1.0 - e, abs=1e-12), (k * h, got, 1.0 - e)
    assert inside >= 50            # 0.6 s of sequence at 10 ms: the cut was exercised


def test_a_chain_or_a_scene_without_schedule_does_not_cut() -> None:
    scene = load_scene(find_scene('fwd_axle_manual'))
    hl = hybrid_lockstep(scene)
    assert not hl.cuts_throttle and hl.throttle_scale() == 1.0
    chain = hybrid_lockstep(load_scene(find_scene('launch_clutch_chain')))
    assert not getattr(chain, 'cuts_throttle', False)


def test_runs_are_bit_identical() -> None:
    a, b = _lockstep_run(0.4, 0.01), _lockstep_run(0.4, 0.01)
    for x, y in zip(a.joint_states(), b.joint_states()):
        np.testing.assert_array_equal(x, y)
    assert [(e.t, e.element, e.after) for e in a.events] == [(e.t, e.element, e.after)
                                                              for e in b.events]


def test_held_brake_keeps_the_wheels_exactly_at_rest() -> None:
    """launch_clutch as the coupling node builds it: at rest on the 10 % grade, both brakes
    stuck, the wheels' speeds stay exactly 0.0 over 0.2 s of 1 ms exchanges."""
    hl = hybrid_lockstep(_scene())
    assert isinstance(hl, HybridTreeLockstep)
    names = hl.shaft_names
    for k in range(200):
        hl.advance((k + 1) * 1e-3, 20.0, 0.0)
        _p, vel, _e = hl.joint_states()
        assert vel[names.index('wheel_left')] == 0.0 and vel[names.index('wheel_right')] == 0.0
    mv = hl.mode_values()
    assert mv['brake_state.brake_left'] == mv['brake_state.brake_right'] == 'stuck'
    assert mv['gear.gearbox'] == 1 and mv['clutch_state.clutch'] == 'slip+'
    assert mv['vehicle_speed_m_s'] == 0.0 and mv['stall'] == ''
    assert hl.gear_count() == 4


def test_a_stall_stops_the_stepper_with_one_line() -> None:
    """Clutch open, a held engine torque of -50 N m: the crank (J 0.25 kg m^2 with the
    clutch's input side) falls from 800 rpm below the stall speed (500 rpm) after
    (83.78 - 52.36) 0.25 / 50 = 0.157 s; the stepper stops there and says so."""
    hl = hybrid_lockstep(_scene())
    k = 0
    while hl.stall is None and k < 400:
        hl.advance((k + 1) * 1e-3, -50.0, 0.0)
        k += 1
    assert hl.stall is not None and hl.stall.startswith('engine stalled at t=')
    t_stall = float(hl.stall.split('t=')[1].split(' ')[0])
    assert t_stall == pytest.approx((800 - 500) * np.pi / 30 * 0.25 / 50, abs=1e-5)
    assert hl.mode_values()['stall'] == hl.stall
    t_end = hl.t
    hl.advance(t_end + 1e-3, -50.0, 0.0)         # stalled: nothing moves on
    assert hl.t == t_end


def test_a_gear_command_under_a_shift_schedule_is_refused_with_a_status() -> None:
    hl = hybrid_lockstep(_scene())
    hl.set_commands(gear=3)
    hl.advance(1e-3, 20.0, 0.0)
    assert hl.gear() == 1
    mv = hl.mode_values()
    assert mv['refused_commands'] == 1 and 'shift_schedule chooses' in mv['last_refused']
