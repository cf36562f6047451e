"""Hard cases of stick and slip (DESIGN.md section 8): every event time against an
independent closed form, the energy balance through every transition, the brake hold.

Solver: dopri5 at rtol 1e-10 unless stated. Event times come from Brent's method on the
dense output (xtol 4 eps); their error is the dense output's, so the bounds below are a few
times the tolerance, with the stated extra where the closed form idealises the scene.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from cvj_ros.physics.engine import LinearEngine
from cvj_ros.physics.hybrid import (Brake, Clutch, CommandSchedule, CoulombPack, Gearbox,
                                    HybridChain, HybridSimulation)
from cvj_ros.physics.load import ConstantLoad, RoadLoad
from cvj_ros.physics.scene import Inertia, Spring

pytestmark = pytest.mark.hard

CLUTCH = CoulombPack(mu_s=0.4, mu_k=0.3, cgeo=0.2, fn_max=4000.0)     # 240 N m kinetic
BRAKE = CoulombPack(mu_s=0.5, mu_k=0.4, cgeo=0.25, fn_max=40000.0)    # 4000 N m kinetic
ENERGY_BOUND = 1e-8      # relative energy residual; rtol 1e-10 with ~1e3 steps


def _const_engine(torque: float) -> LinearEngine:
    return LinearEngine(m1=torque, k1=0.0)     # M = throttle * M1: constant at throttle 1


def test_engagement_at_large_speed_difference_locks_at_the_closed_form_time() -> None:
    """Engine at 300 rad/s, disc at rest, clutch fully closed at t = 0, constant torques:
    slip s' = (T_e - T_k)/J_1 - (T_k - T_l)/J_2 is constant, lock-up at s_0 / -s'."""
    j1a, j1b, j2a, j2b = 0.15, 0.05, 0.02, 0.5
    t_e, t_l = 150.0, 40.0
    chain = HybridChain([Inertia('engine_crank', j1a), Clutch('clutch', j1b, j2a, CLUTCH),
                         Inertia('wheel', j2b)])
    sim = HybridSimulation(chain, engine=_const_engine(t_e), load=ConstantLoad(torque=t_l),
                           schedule=CommandSchedule([(0.0, {'clutch': 0.0, 'throttle': 1.0})]),
                           duration=1.0, initial_speed=300.0,
                           initial_speeds={'clutch_output': 0.0}, rtol=1e-10, atol=1e-12)
    r = sim.run()
    t_k = CLUTCH.kinetic(1.0)
    j1, j2 = j1a + j1b, j2a + j2b
    t_lock = 300.0 / -((t_e - t_k) / j1 - (t_k - t_l) / j2)
    locks = [e for e in r.events if e.after == 'stuck' and e.t > 0]
    assert len(locks) == 1 and len(r.events) == 1
    assert locks[0].t == pytest.approx(t_lock, rel=1e-12, abs=1e-12)
    # after the lock both shafts turn at exactly the same speed, accelerating together
    i = r.t > t_lock + 1e-3
    np.testing.assert_array_equal(r.column('clutch_input')[i], r.column('clutch_output')[i])
    w_lock = 300.0 + (t_e - t_k) / j1 * t_lock
    assert r.column('wheel')[-1] == pytest.approx(w_lock + (t_e - t_l) / (j1 + j2) * (1.0 - t_lock),
                                                  rel=1e-10)
    # the energy dissipated in slip is booked: the balance closes
    assert r.max_energy_residual < ENERGY_BOUND
    dissipated = float(r.final.work[3])
    assert dissipated == pytest.approx(t_k * 300.0 * t_lock / 2.0, rel=1e-9)


def _judder_times(n: int, *, v0: float, c: float, j: float, t_s: float, t_k: float) -> list[float]:
    """Closed form of stick-slip of a disc (inertia j, spring c to the ground) on a surface
    moving at v0: stick until c theta = T_s, then slip as theta = theta_k + A cos(wt) +
    (v0/w) sin(wt) (w^2 = c/j, A = (T_s - T_k)/c) until the disc speed is v0 again after
    w t = 2 pi - 2 atan(A w / v0); stick again until c theta = T_s."""
    w = math.sqrt(c / j)
    th_s, th_k = t_s / c, t_k / c
    a = th_s - th_k
    x = 2 * math.pi - 2 * math.atan(a * w / v0)
    th_end = th_k + a * math.cos(x) + v0 / w * math.sin(x)
    t_slip, t_stick = x / w, (th_s - th_end) / v0
    out, t = [], th_s / v0
    for k in range(n):
        out.append(t)                  # stuck -> slip
        t += t_slip
        out.append(t)                  # slip -> stuck
        t += t_stick
    return out


def test_judder_locates_every_transition() -> None:
    """Engine of 1e9 kg m^2 at 10 rad/s (its speed changes by < 1e-8 relative in the run),
    half-open clutch, friction disc 0.01 kg m^2 on an undamped 2000 N m/rad spring to a braked
    wheel: 67 stick-slip cycles in 1 s, each transition within 1e-8 s of the closed form
    (bound: the engine's relative speed change times the run, plus the tolerance)."""
    chain = HybridChain([Inertia('engine_crank', 1e9), Clutch('clutch', 1.0, 0.01, CLUTCH),
                         Spring('damper', 2000.0, 0.0), Inertia('wheel', 1.0),
                         Brake('brake', BRAKE)])
    sched = CommandSchedule([(0.0, {'clutch': 0.5, 'brake': 1.0, 'throttle': 0.0})])
    sim = HybridSimulation(chain, engine=_const_engine(0.0), load=ConstantLoad(torque=0.0),
                           schedule=sched, duration=1.0, initial_speed=10.0,
                           initial_speeds={'wheel': 0.0}, rtol=1e-10, atol=1e-12)
    r = sim.run()
    ev = [e for e in r.events if e.element == 'clutch' and e.t > 0]
    assert [e.after for e in ev[:4]] == ['slip+', 'stuck', 'slip+', 'stuck']
    ref = _judder_times(len(ev) // 2 + 1, v0=10.0, c=2000.0, j=0.01,
                        t_s=CLUTCH.static(0.5), t_k=CLUTCH.kinetic(0.5))
    assert len(ev) == len([t for t in ref if t <= 1.0]) >= 130
    np.testing.assert_allclose([e.t for e in ev], ref[:len(ev)], rtol=0, atol=1e-8)
    # the braked wheel never moves, the spring's work comes back: no net loss but friction
    assert np.all(r.column('wheel') == 0.0)
    assert r.max_energy_residual < ENERGY_BOUND


def _car(grade: float) -> tuple[HybridChain, RoadLoad]:
    gb = Gearbox('gearbox', 0.01, 0.02, (3.5, 2.1, 1.4), -3.3, max_input_speed=650.0)
    chain = HybridChain([Inertia('engine_crank', 0.2), Clutch('clutch', 0.05, 0.02, CLUTCH), gb,
                         Spring('halfshaft', 8000.0, 5.0), Inertia('wheel', 140.0),
                         Brake('brake', BRAKE)])
    road = RoadLoad(mass=1500.0, wheel_radius=0.3, final_drive_ratio=4.0, grade_percent=grade)
    return chain, road


def test_brake_holds_on_a_grade_for_10_s_with_speed_exactly_zero() -> None:
    """10 % grade: 109.8 N m at the wheel shaft (m g sin(atan 0.1) r / i_final) against a
    brake of 5000 N m static capacity: the wheel stays at exactly 0 rad/s, no event, no creep."""
    chain, road = _car(10.0)
    sched = CommandSchedule([(0.0, {'clutch': 1.0, 'brake': 1.0, 'gear': 1, 'throttle': 0.0})])
    sim = HybridSimulation(chain, engine=LinearEngine(m1=20.0, k1=0.25), load=road,
                           schedule=sched, duration=10.0, sample_dt=0.01, initial_speed=80.0,
                           initial_speeds={'clutch_output': 0.0}, rtol=1e-10, atol=1e-12)
    r = sim.run()
    assert r.t[-1] == pytest.approx(10.0)
    assert np.all(r.column('wheel') == 0.0)
    assert r.final.q[-1] == 0.0
    assert [e.element for e in r.events if e.t > 0] == []
    assert r.final_mode.brake == 0
    assert r.max_energy_residual < ENERGY_BOUND


def test_brake_release_on_a_grade_rolls_back_when_the_ramp_crosses_the_hold_torque() -> None:
    """Brake released linearly from 1 at t = 1 s to 0 at t = 2 s, clutch open: the brake slips
    backwards when its static capacity 5000 (2 - t) N m falls to the holding torque
    (the grade's 109.81 N m at rest, plus the halfshaft's twist torque, which rings out by then)."""
    chain, road = _car(10.0)
    sched = CommandSchedule([(0.0, {'clutch': 1.0, 'brake': 1.0, 'gear': 1}),
                             (1.0, {'brake': 1.0}), (2.0, {'brake': 0.0})])
    sim = HybridSimulation(chain, engine=LinearEngine(m1=20.0, k1=0.25), load=road,
                           schedule=sched, duration=2.5, initial_speed=80.0,
                           initial_speeds={'clutch_output': 0.0}, rtol=1e-10, atol=1e-12)
    r = sim.run()
    rel = [e for e in r.events if e.element == 'brake' and e.t > 0]
    assert rel[0].after == 'slip-'
    hold = road.torque(0.0, 0.0)
    # the halfshaft still carries a small twist torque: compare with a 1 N m allowance
    cap = BRAKE.static(1.0)
    assert rel[0].t == pytest.approx(2.0 - hold / cap, abs=1.0 / cap)
    assert r.column('wheel')[-1] < 0.0
    assert r.max_energy_residual < ENERGY_BOUND


def test_stall_is_reported_at_the_closed_form_time() -> None:
    """Brake held, engine at 80 rad/s with 60 N m on 0.25 kg m^2 (104 rad/s at 0.1 s), clutch
    snapped shut at t = 0.1 s: it slips with 240 N m, the engine decelerates at
    (60 - 240)/0.25 rad/s^2 and falls below the stall speed 50 rad/s at
    t = 0.1 + 54 * 0.25 / 180 s; the run stops there."""
    chain = HybridChain([Inertia('engine_crank', 0.2), Clutch('clutch', 0.05, 0.02, CLUTCH),
                         Inertia('wheel', 50.0), Brake('brake', BRAKE)])
    sched = CommandSchedule([(0.0, {'clutch': 1.0, 'brake': 1.0, 'throttle': 1.0}),
                             (0.1, {'clutch': 1.0}), (0.1, {'clutch': 0.0})])
    sim = HybridSimulation(chain, engine=_const_engine(60.0), load=ConstantLoad(torque=500.0),
                           schedule=sched, duration=1.0, initial_speed=80.0,
                           initial_speeds={'clutch_output': 0.0}, stall_speed=50.0,
                           rtol=1e-10, atol=1e-12)
    r = sim.run()
    w_close = 80.0 + 60.0 / 0.25 * 0.1
    t_stall = 0.1 + (w_close - 50.0) * 0.25 / (CLUTCH.kinetic(1.0) - 60.0)
    assert r.stall is not None and r.stall.startswith('engine stalled at t=')
    assert '\n' not in r.stall
    assert r.t_end == pytest.approx(t_stall, abs=1e-12)
    assert r.t[-1] <= r.t_end
    assert r.max_energy_residual < ENERGY_BOUND


def test_shift_under_load_matches_the_closed_form() -> None:
    """Rigid car in 1st, clutch stuck, constant 150 N m against 300 N m at the wheel:
    t1 = 0.5 s pedal snaps open (the clutch slips at zero capacity), 0.55 s neutral, 0.6 s
    2nd gear (ideal synchroniser: momentum-conserving lock of disc + gearbox input to the
    output), pedal closes linearly over 0.3 s (slip s(tau) = s0 + alpha tau - beta tau^2 / 2),
    then the slip falls linearly to the lock. Each phase is a constant
    acceleration (or a ramp), so every speed and the lock time are closed forms."""
    je, jci, jco, jgi, jgo, jw = 0.2, 0.05, 0.02, 0.01, 0.02, 60.0
    i1, i2 = 3.5, 2.1
    t_e, t_l = 150.0, 300.0
    gb = Gearbox('gearbox', jgi, jgo, (i1, i2, 1.4), -3.3, max_input_speed=650.0)
    chain = HybridChain([Inertia('engine_crank', je), Clutch('clutch', jci, jco, CLUTCH), gb,
                         Inertia('wheel', jw)])
    sched = CommandSchedule([(0.0, {'clutch': 0.0, 'gear': 1, 'throttle': 1.0}),
                             (0.5, {'clutch': 0.0}), (0.5, {'clutch': 1.0}),
                             (0.55, {'gear': 0}), (0.6, {'gear': 2, 'clutch': 1.0}),
                             (0.9, {'clutch': 0.0})])
    w0 = 100.0
    sim = HybridSimulation(chain, engine=_const_engine(t_e), load=ConstantLoad(torque=t_l),
                           schedule=sched, duration=1.5, initial_speed=w0, rtol=1e-10,
                           atol=1e-12)
    r = sim.run()
    # phase 1 (0..0.5): one rigid body in engine coordinates
    j_in = jco + jgi                      # disc + gearbox input
    j_out = jgo + jw
    m1 = je + jci + j_in + j_out / i1 ** 2
    a1 = (t_e - t_l / i1) / m1
    we = w0 + a1 * 0.5                    # engine and disc at 0.5 s
    wd = we
    wo = we / i1                          # gearbox output
    # 0.5..0.55: engine alone; disc side in gear 1 (rigid with the output)
    m_side = j_in + j_out / i1 ** 2
    we += t_e / (je + jci) * 0.1          # the engine is free until the pedal closes
    wd += (-t_l / i1) / m_side * 0.05
    wo = wd / i1
    # 0.55..0.6: neutral: the disc side coasts, the output decelerates under the load
    wo += -t_l / j_out * 0.05
    # 0.6: synchroniser lock in 2nd, momentum conserving in disc coordinates
    wd = (j_in * wd + (1.0 / i2) * j_out * wo) / (j_in + j_out / i2 ** 2)
    # 0.6..: clutch ramp: capacity K tau / 0.3 on slip s = w_e - w_d
    j1, j2 = je + jci, j_in + j_out / i2 ** 2
    k = CLUTCH.kinetic(1.0) / 0.3
    s0 = we - wd
    alpha = t_e / j1 + (t_l / i2) / j2
    beta = k / j1 + k / j2
    s1 = s0 + alpha * 0.3 - beta * 0.3 ** 2 / 2      # slip when the pedal is closed
    assert s1 > 0.0                                    # this scene locks after the ramp
    t_k = CLUTCH.kinetic(1.0)
    slope = (t_e - t_k) / j1 - (t_k - t_l / i2) / j2
    tau = 0.3 + s1 / -slope
    names = [(e.element, e.after) for e in r.events if e.t > 0]
    assert names == [('clutch', 'slip+'), ('gearbox', 'gear 0'), ('gearbox', 'gear 2'),
                     ('clutch', 'stuck')]
    lock = r.events[-1]
    assert lock.t == pytest.approx(0.6 + tau, abs=1e-10)
    assert r.statuses == []
    assert r.max_energy_residual < ENERGY_BOUND
    assert r.final.lock_loss > 0.0        # the synchroniser's loss is booked


def test_gear_that_would_over_speed_the_engine_is_refused() -> None:
    """At 300 rad/s of gearbox output, 1st (3.5) would need 1050 rad/s > 650: refused, the
    gearbox stays in neutral, one status line; 3rd (1.4 -> 420 rad/s) is then taken."""
    gb = Gearbox('gearbox', 0.01, 0.02, (3.5, 2.1, 1.4), -3.3, max_input_speed=650.0)
    chain = HybridChain([Inertia('engine_crank', 0.2), Clutch('clutch', 0.05, 0.02, CLUTCH), gb,
                         Inertia('wheel', 60.0)])
    sched = CommandSchedule([(0.0, {'clutch': 1.0, 'gear': 0}), (0.1, {'gear': 1}),
                             (0.2, {'gear': 3})])
    sim = HybridSimulation(chain, engine=_const_engine(0.0), load=ConstantLoad(torque=0.0),
                           schedule=sched, duration=0.3, initial_speed=100.0,
                           initial_speeds={'gearbox_output': 300.0})
    r = sim.run()
    assert len(r.statuses) == 1 and 'gear 1 refused' in r.statuses[0]
    assert '1050.0 rad/s would exceed 650.0 rad/s' in r.statuses[0]
    assert [e.after for e in r.events if e.element == 'gearbox'] == ['gear 3']
    assert r.final_mode.gear['gearbox'] == 3
    assert r.max_energy_residual < ENERGY_BOUND


def test_a_refused_gear_is_not_retried_until_commanded_anew() -> None:
    """Neutral, output at 250 rad/s slowed by 200 N m on 1.02 kg m^2 (196.1 rad/s^2). 1st
    (3.5, limit 650 rad/s) commanded at 0.1 s needs 806 rad/s: refused; a later row of another
    channel at 0.35 s, when 1st would need 635 rad/s, does not retry it; neutral at 0.4 s and
    1st again at 0.45 s (566 rad/s) engage it."""
    gb = Gearbox('gearbox', 0.01, 0.02, (3.5, 2.1, 1.4), -3.3, max_input_speed=650.0)
    chain = HybridChain([Inertia('engine_crank', 0.2), Clutch('clutch', 0.05, 0.02, CLUTCH), gb,
                         Inertia('wheel', 1.0)])
    sched = CommandSchedule([(0.0, {'clutch': 1.0, 'gear': 0}), (0.1, {'gear': 1}),
                             (0.35, {'throttle': 0.0}), (0.4, {'gear': 0}), (0.45, {'gear': 1})])
    sim = HybridSimulation(chain, engine=_const_engine(0.0), load=ConstantLoad(torque=200.0),
                           schedule=sched, duration=0.5, initial_speed=100.0,
                           initial_speeds={'gearbox_output': 250.0})
    r = sim.run()
    assert len(r.statuses) == 1 and r.statuses[0].startswith('t=0.100000 s: gear 1 refused')
    gears = [(round(e.t, 12), e.after) for e in r.events if e.element == 'gearbox']
    assert gears == [(0.45, 'gear 1')]
    assert r.max_energy_residual < ENERGY_BOUND


def _damped_judder_times(n: int, *, v0: float, c: float, d: float, j: float, t_s: float,
                         t_k: float) -> list[float]:
    """Closed form of stick-slip with a damped spring: stick until c theta + d v0 = T_s; slip
    as x = theta - T_k/c = e^(-z w t) (A cos(w_d t) + B sin(w_d t)) with A = x_0,
    B = (v0 + z w x_0) / w_d, until theta' = v0 again (first root after 0 of the closed-form
    derivative, bracketed on a grid of w_d t / 200 and refined by Brent); stick again at v0."""
    from scipy.optimize import brentq
    w = math.sqrt(c / j)
    z = d / (2.0 * math.sqrt(c * j))
    wd = w * math.sqrt(1.0 - z * z)
    th_rel = (t_s - d * v0) / c
    x0 = th_rel - t_k / c
    a, b = x0, (v0 + z * w * x0) / wd

    def x(t: float) -> float:
        return math.exp(-z * w * t) * (a * math.cos(wd * t) + b * math.sin(wd * t))

    def dx(t: float) -> float:
        e = math.exp(-z * w * t)
        return e * ((-z * w * a + wd * b) * math.cos(wd * t) + (-z * w * b - wd * a) * math.sin(wd * t))

    h = 2 * math.pi / wd / 200
    k = next(k for k in range(1, 400)                  # within two periods, else no re-stick
             if dx(k * h) - v0 < 0.0 <= dx((k + 1) * h) - v0)
    t_slip = brentq(lambda t: dx(t) - v0, k * h, (k + 1) * h, xtol=1e-15, rtol=8.9e-16)
    th_end = t_k / c + x(t_slip)
    t_stick = (th_rel - th_end) / v0
    out, t = [], th_rel / v0
    for _ in range(n):
        out.append(t)
        t += t_slip
        out.append(t)
        t += t_stick
    return out


def test_judder_with_low_damping_locates_every_transition() -> None:
    """As the undamped judder with 1 % damping in the disc's spring (d = 2 zeta sqrt(c J) =
    0.089 N m s/rad; from ~4 % on the disc no longer catches up with the drive within a swing,
    it slips on and settles): every transition within 1e-8 s of the damped closed form."""
    c, j = 2000.0, 0.01
    d = 2 * 0.01 * math.sqrt(c * j)
    chain = HybridChain([Inertia('engine_crank', 1e9), Clutch('clutch', 1.0, j, CLUTCH),
                         Spring('damper', c, d), Inertia('wheel', 1.0), Brake('brake', BRAKE)])
    sched = CommandSchedule([(0.0, {'clutch': 0.5, 'brake': 1.0, 'throttle': 0.0})])
    sim = HybridSimulation(chain, engine=_const_engine(0.0), load=ConstantLoad(torque=0.0),
                           schedule=sched, duration=0.5, initial_speed=10.0,
                           initial_speeds={'wheel': 0.0}, rtol=1e-10, atol=1e-12)
    r = sim.run()
    ev = [e for e in r.events if e.element == 'clutch' and e.t > 0]
    ref = _damped_judder_times(len(ev) // 2 + 1, v0=10.0, c=c, d=d, j=j,
                               t_s=CLUTCH.static(0.5), t_k=CLUTCH.kinetic(0.5))
    assert len(ev) == len([t for t in ref if t <= 0.5]) >= 60
    np.testing.assert_allclose([e.t for e in ev], ref[:len(ev)], rtol=0, atol=1e-8)
    assert r.max_energy_residual < ENERGY_BOUND
    assert float(r.final.work[2]) > 0.0          # the damper dissipated


def test_command_rows_at_the_exchange_step_do_not_move_the_lock() -> None:
    """The constant-torque engagement with a throttle row every 1 ms (the exchange step's
    resolution, 1000 breakpoints the stepper lands on): the lock-up time is still the closed
    form to 1e-12 s, and the run lands on every row."""
    j1a, j1b, j2a, j2b = 0.15, 0.05, 0.02, 0.5
    t_e, t_l = 150.0, 40.0
    chain = HybridChain([Inertia('engine_crank', j1a), Clutch('clutch', j1b, j2a, CLUTCH),
                         Inertia('wheel', j2b)])
    rows = [(0.0, {'clutch': 0.0, 'throttle': 1.0})] + [(k * 1e-3, {'throttle': 1.0})
                                                       for k in range(1, 1000)]
    sim = HybridSimulation(chain, engine=_const_engine(t_e), load=ConstantLoad(torque=t_l),
                           schedule=CommandSchedule(rows), duration=1.0, initial_speed=300.0,
                           initial_speeds={'clutch_output': 0.0}, rtol=1e-10, atol=1e-12)
    r = sim.run()
    t_k = CLUTCH.kinetic(1.0)
    t_lock = 300.0 / -((t_e - t_k) / (j1a + j1b) - (t_k - t_l) / (j2a + j2b))
    (lock,) = [e for e in r.events if e.after == 'stuck']
    assert lock.t == pytest.approx(t_lock, abs=1e-12)
    assert r.stats['steps'] >= 1000


@pytest.mark.parametrize('seed', range(8))
def test_random_command_schedules_keep_the_invariants(seed: int) -> None:
    """Fuzz: 25 random rows (clutch, brake, throttle anywhere in 0..1, any gear) over 3 s on a
    car with a map engine on a 6 % grade. Every run ends (or stalls in one line), the energy
    balance closes, the wheel is exactly still whenever the brake is stuck, a rerun is
    identical, and the events stay few (no chattering: < 60 per simulated second)."""
    from cvj_ros.physics.engine import engine_from_spec
    rng = np.random.default_rng(seed)
    rows: list[tuple[float, dict]] = [(0.0, {'clutch': 1.0, 'brake': 1.0, 'gear': 1, 'throttle': 0.0})]
    for t in np.sort(rng.uniform(0.05, 3.0, 25)):
        ch = rng.choice(['clutch', 'brake', 'throttle', 'gear'])
        rows.append((float(t), {ch: int(rng.integers(-1, 4)) if ch == 'gear'
                                else float(rng.choice([0.0, 1.0, rng.uniform()]))}))
    chain, road = _car(6.0)

    def run():
        return HybridSimulation(chain, engine=engine_from_spec({'model': 'map', 'throttle': 0.0,
                                                                 'stall_rpm': 400.0}),
                                load=road, schedule=CommandSchedule(rows), duration=3.0,
                                sample_dt=0.005, initial_speed=85.0, stall_speed=400 * math.pi / 30,
                                rtol=1e-8, atol=1e-10).run()
    r = run()
    assert r.stall is None or r.stall.startswith('engine stalled at t=')
    assert r.stall is not None or r.t_end == 3.0
    assert r.max_energy_residual < 1e-6
    assert len(r.events) < 60 * 3.0
    brake = [e for e in r.events if e.element == 'brake']
    for k, e in enumerate(brake):
        if e.after == 'stuck':
            t_end = brake[k + 1].t if k + 1 < len(brake) else r.t_end
            held = (r.t > e.t) & (r.t < t_end)
            assert np.all(r.column('wheel')[held] == 0.0)
    r2 = run()
    assert r2.events == r.events
    np.testing.assert_array_equal(r2.speed, r.speed)


def test_an_event_on_a_command_row_still_applies_the_row() -> None:
    """Brake stepped from 1 to 0 at 0.5 s on the grade, with 1st commanded in the same row:
    the stuck-brake witness jumps at the row, so the release is located on it (to Brent's
    4 eps); the row's gear command must act all the same (it has no later row to wait for)."""
    chain, road = _car(10.0)
    sched = CommandSchedule([(0.0, {'clutch': 1.0, 'brake': 1.0, 'gear': 0}),
                             (0.5, {'brake': 1.0}), (0.5, {'brake': 0.0, 'gear': 1})])
    sim = HybridSimulation(chain, engine=LinearEngine(m1=20.0, k1=0.25), load=road,
                           schedule=sched, duration=1.0, initial_speed=80.0, rtol=1e-10,
                           atol=1e-12)
    r = sim.run()
    rel = [e for e in r.events if e.element == 'brake' and e.t > 0]
    assert rel[0].after == 'slip-' and rel[0].t == pytest.approx(0.5, abs=1e-12)
    gears = [(e.t, e.after) for e in r.events if e.element == 'gearbox']
    assert len(gears) == 1 and gears[0][1] == 'gear 1' and gears[0][0] == pytest.approx(0.5, abs=1e-12)
    assert r.final_mode.gear['gearbox'] == 1 and r.column('wheel')[-1] < 0.0   # rolls back
    assert r.max_energy_residual < ENERGY_BOUND


def test_clutch_and_brake_that_each_need_the_other_stuck_both_slip() -> None:
    """Everything at rest, clutch closed (150 N m static, 112.5 kinetic), an engine of
    100 N m on 0.25 kg m^2, a light output side (0.05 kg m^2) that the load drives with
    900 N m against a brake of 800 N m static (640 kinetic). Both stuck, the brake must hold
    1000 N m: it slips; then the clutch must hold 100 - 0.25 (1000 - 640)/0.3 = -200 N m: it
    slips backwards; with it slipping the brake would hold 900 - 112.5 = 787.5 N m, and
    with the brake stuck the clutch 100 N m. Sticking either again at t = 0 (before: the
    settle's 8 rounds ended with the clutch stuck carrying 200 N m, its witness already
    below zero, for the whole run) is wrong: both slip, each side at constant acceleration,
    engine (100 + 112.5) / 0.25 = 850 rad/s^2, output (900 - 112.5 - 640) / 0.05 =
    2950 rad/s^2 (closed form), and nothing changes after t = 0."""
    clutch = CoulombPack(mu_s=0.4, mu_k=0.3, cgeo=0.2, fn_max=1875.0)
    chain = HybridChain([Inertia('engine_crank', 0.2), Clutch('clutch', 0.05, 0.01, clutch),
                         Inertia('output_shaft', 0.04), Brake('brake', BRAKE)])
    sched = CommandSchedule([(0.0, {'clutch': 0.0, 'brake': 0.16, 'throttle': 1.0})])
    sim = HybridSimulation(chain, engine=_const_engine(100.0), load=ConstantLoad(torque=-900.0),
                           schedule=sched, duration=0.2, sample_dt=0.01, rtol=1e-10, atol=1e-12)
    r = sim.run()
    assert r.final_mode.clutch['clutch'] == -1 and r.final_mode.brake == 1
    assert all(e.t == 0.0 for e in r.events)
    assert [(e.element, e.after) for e in r.events[-2:]] == [('brake', 'slip+'), ('clutch', 'slip-')]
    np.testing.assert_allclose(r.column('engine_crank'), 850.0 * r.t, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(r.column('output_shaft'), 2950.0 * r.t, rtol=1e-12, atol=1e-12)
    assert r.max_energy_residual < ENERGY_BOUND
