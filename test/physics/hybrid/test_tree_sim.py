"""HybridTreeSimulation's settle at one instant (cvj_ros/physics/hybrid/tree_sim.py): which
elements stick and which slip when several decide at once. Checked by the consistency of the
mode it ends in, computed apart from the settle: every stuck element within its static
capacity, every slipping element at zero slip slipping the way its friction assumes (the
slip one short step along the mode's own derivative has the sign of its mode)."""
from __future__ import annotations

import itertools
import math

import pytest

from cvj_ros.physics.engine import LinearEngine
from cvj_ros.physics.hybrid import CommandSchedule
from cvj_ros.physics.hybrid.chain import Mode
from cvj_ros.physics.hybrid.events import same_instant
from cvj_ros.physics.hybrid.friction import BACKWARD, FORWARD, STUCK
from cvj_ros.physics.hybrid.tree import TreeState
from cvj_ros.physics.hybrid.tree_sim import HybridTreeSimulation
from cvj_ros.physics.scene import parse_scene
from cvj_ros.physics.vehicle import GRAVITY

#: clutch: mu_s cgeo fn = 0.5 x 0.2 m x 1000 N = 100 N m static, 90 N m kinetic
CLUTCH = {'type': 'clutch', 'name': 'clutch', 'J_input': 0.01, 'J_output': 0.015,
          'mu_static': 0.5, 'mu_kinetic': 0.45, 'cgeo_m': 0.2, 'normal_force_max': 1000.0}


def _side(s: str, J: float, twist_deg: float) -> list[dict]:
    """Midshaft, halfshaft spring (twisted at the start), wheel, wheel brake."""
    return [{'type': 'inertia', 'name': f'midshaft_{s}', 'J': J},
            {'type': 'spring', 'name': f'halfshaft_{s}', 'stiffness': 5000.0, 'damping': 0.0,
             'initial_twist_deg': twist_deg},
            {'type': 'wheel', 'name': f'wheel_{s}', 'J': 1.0, 'radius': 0.3, 'mu': 0.9,
             'load_share': 0.3, 'axle': 'front',
             'tyre': {'B': 10.0, 'C': 1.9, 'E': 0.97, 'relaxation_length': 0.2}},
            {'type': 'brake', 'name': f'brake_{s}', 'mu_static': 0.45, 'mu_kinetic': 0.40,
             'cgeo_m': 0.22, 'normal_force_max': 15000.0}]


def _scene(diff: dict, left: list[dict], right: list[dict], grade: float = 0.0,
           clutch: dict = CLUTCH) -> dict:
    """Engine, clutch, 1:1 gearbox (no spring between), a 1:1 differential, two sides."""
    return {'name': 'settle_case', 'duration': 0.5,
            'solver': {'method': 'dopri5', 'rtol': 1e-8, 'atol': 1e-10},
            'engine': {'model': 'map', 'throttle': 0.0},
            'vehicle': {'mass': 1500.0, 'rolling_coeff': 0.0, 'drag_coeff': 0.0,
                        'frontal_area': 2.2, 'grade_percent': grade},
            'driveline': [
                {'type': 'inertia', 'name': 'engine_crank', 'J': 0.2}, clutch,
                {'type': 'gearbox', 'name': 'gearbox', 'J_input': 0.001, 'J_output': 0.001,
                 'ratios': [1.0], 'reverse_ratio': -1.0, 'max_input_rpm': 9000.0},
                dict(diff, type='differential', name='differential', ratio=1.0, J_carrier=0.01,
                     J_side=0.001, J_spider=0.001, spider_ratio=1.0, left=left, right=right)]}


def _pack_sim(preload: float, *, bias: float = 0.5, static_ratio: float = 1.7,
              left: tuple[float, float] = (0.25, 0.0), right: tuple[float, float] = (0.07, -1.0),
              engine_torque: float = 240.0, clutch: dict = CLUTCH) -> HybridTreeSimulation:
    """Clutch and clutch-pack differential (capacity static_ratio (preload + bias
    |T_carrier|)) with sides of (J kg m^2, halfshaft twist deg), by default unequal (0.25 and
    0.07 kg m^2, the right halfshaft twisted -1 deg), 240 N m on the engine, everything at
    rest, clutch closed in 1st, brakes off."""
    d = _scene({'kind': 'clutch_pack', 'preload_nm': preload, 'torque_bias': bias,
                'static_ratio': static_ratio}, _side('left', *left), _side('right', *right),
               clutch=clutch)
    sched = CommandSchedule([(0.0, {'clutch': 0.0, 'brake': 0.0, 'throttle': 1.0, 'gear': 1})])
    return HybridTreeSimulation(parse_scene(d), {}, engine=LinearEngine(m1=engine_torque, k1=0.0),
                                schedule=sched, duration=0.1)


def _with(sim: HybridTreeSimulation, mode: Mode, st: TreeState, clutch: int, pack: int
          ) -> tuple[Mode, TreeState]:
    """``mode`` with the clutch and the pack in the given modes (locked at the state st)."""
    m = mode.copy()
    i, d = sim.probe.clutch_link['clutch'], sim.probe.packs['differential'][1]
    m.clutch['clutch'], m.packs['differential'] = clutch, pack
    m.offsets.pop(i, None)
    m.offsets.pop(-(d + 1), None)
    if clutch == STUCK:
        m.offsets[i] = sim.tree(mode).lock_offset(i, st, 1.0)
    if pack == STUCK:
        m.offsets[-(d + 1)] = st.delta[d]
    _mt, _x, st = sim._apply(m, st, True)
    return m, st


def _start(sim: HybridTreeSimulation) -> tuple[Mode, TreeState]:
    """Clutch and pack stuck at the start (at rest: every slip exactly 0)."""
    mode, mt, x = sim._initial()
    return _with(sim, mode, mt.to_state(x, 0.0), STUCK, STUCK)


def _inconsistent(sim: HybridTreeSimulation, mode: Mode, st: TreeState, t: float = 0.0,
                  h: float = 1e-7) -> list[str]:
    """What is wrong with ``mode`` at ``st`` (empty: consistent). The slip rate's sign is
    read one step h (s) along the mode's derivative (a slip at exactly 0 becomes h sdot);
    an open clutch (no capacity) has no direction to check."""
    mt, x, st = sim._apply(mode, st, False)
    ev = sim._eval(mt, t, x)
    ev_h = sim._eval(mt, t, x + h * ev.ydot)
    ck, cs, _bk, bs = sim._capacities(t)
    out = []
    for name, m in mode.clutch.items():
        if m == STUCK and abs(ev.stuck_torque[name]) > cs:
            out.append(f'{name} stuck with {ev.stuck_torque[name]:.3f} N m > {cs:.3f} N m')
        if m != STUCK and ck > 0.0 and ev.slip[name] == 0.0 and ev_h.slip[name] * m <= 0.0:
            out.append(f'{name} slipping {m:+d} with slip {ev_h.slip[name]:.3g} after {h} s')
    for name, m in mode.packs.items():
        if m == STUCK and abs(ev.pack_stuck[name]) > ev.pack_static[name]:
            out.append(f'{name} stuck with {ev.pack_stuck[name]:.3f} N m > '
                       f'{ev.pack_static[name]:.3f} N m')
        if m != STUCK and ev.pack_slip[name] == 0.0 and ev_h.pack_slip[name] * m <= 0.0:
            out.append(f'{name} slipping {m:+d} with slip {ev_h.pack_slip[name]:.3g} after {h} s')
    for name, m in mode.brakes.items():
        if m == STUCK and abs(ev.hold[name]) > bs[name]:
            out.append(f'{name} stuck with {ev.hold[name]:.3f} N m > {bs[name]:.3f} N m')
    return out


def _consistent_modes(sim: HybridTreeSimulation) -> set[tuple[int, int]]:
    """(clutch, pack) modes of the nine that are consistent at the start."""
    mode, st = _start(sim)
    return {(c, p) for c, p in itertools.product((STUCK, FORWARD, BACKWARD), repeat=2)
            if not _inconsistent(sim, *_with(sim, mode, st, c, p))}


def test_clutch_and_pack_that_would_cycle_end_consistent() -> None:
    """Preload 10 N m: the chain's first case on the tree. Both stuck, the clutch must carry
    117.06 N m > 100: released (slip+); with it slipping (90 N m) the pack needs 89.35 N m
    against a capacity fallen with the carrier torque to 81.84: released (slip-); with the
    pack slipping the clutch needs 91.47 N m: stuck again; with the clutch stuck the pack
    would hold again (96.32 <= 103.06 N m) - back to both stuck, where the clutch cannot
    hold. Sticking the pack there returns to a mode passed through at this instant:
    refused, the pack slips backwards. The tree's former rule (only elements released in an
    earlier settle at the instant were not stuck again) cycled for its 16 rounds and left
    both stuck, the clutch carrying 117.06 N m over its 100 N m capacity. Consistent here:
    the pack slipping backwards with the clutch stuck or (91.47 N m above its 90 N m kinetic
    capacity) slipping forwards; the settle ends in the first (a stick at zero slip that
    holds is taken)."""
    sim = _pack_sim(preload=10.0)
    assert _consistent_modes(sim) == {(STUCK, BACKWARD), (FORWARD, BACKWARD)}
    mode, st = _start(sim)
    assert _inconsistent(sim, mode, st) == ['clutch stuck with 117.056 N m > 100.000 N m']
    mode, st = sim._settle(0.0, mode, st)
    assert [(e.element, e.after) for e in sim.events] == [
        ('clutch', 'slip+'), ('differential', 'slip-'), ('clutch', 'stuck')]
    assert mode.clutch['clutch'] == STUCK and mode.packs['differential'] == BACKWARD
    assert _inconsistent(sim, mode, st) == []


def test_clutch_released_first_sticks_again_when_the_pack_lets_go() -> None:
    """No preload: the chain's second case on the tree. Both stuck, both are over their
    capacity (clutch 117.06 > 100 N m, pack 96.32 > 86.06); the clutch is released first,
    then the pack (89.35 N m against 64.84 with the clutch slipping); with the pack slipping
    the clutch needs 84.31 N m: it holds again (a mode not passed through yet), while the
    pack, over its capacity also with the clutch stuck, keeps slipping. That is the one
    consistent mode of the nine: leaving the clutch slipping forwards (90 N m kinetic, more
    than the 84.31 it has to pass) would turn its slip negative with the friction still
    pushing it forwards. The tree's former rule ended there too: the re-stick happens inside
    one settle, and only a release in an earlier settle at the instant blocked it."""
    sim = _pack_sim(preload=0.0)
    assert _consistent_modes(sim) == {(STUCK, BACKWARD)}
    mode, st = sim._settle(0.0, *_start(sim))
    assert [(e.element, e.after) for e in sim.events] == [
        ('clutch', 'slip+'), ('differential', 'slip-'), ('clutch', 'stuck')]
    assert mode.clutch['clutch'] == STUCK and mode.packs['differential'] == BACKWARD
    assert _inconsistent(sim, mode, st) == []


def test_pack_stuck_again_beside_a_clutch_slipping_the_wrong_way() -> None:
    """Clutch 0.24 / 0.234 (48 / 46.8 N m), pack 1.8 (27 + 0.6 |T_carrier|), sides 0.013
    kg m^2 twisted -1.4 deg and 0.078 kg m^2 twisted 0.47 deg, 70 N m on the engine. The one
    consistent mode: clutch slip-, pack slip+. From both stuck the pack is released, then the
    clutch, which reaches that mode; the pack then holds again (its capacity rises with the
    clutch slipping backwards), and with the pack stuck no clutch mode is consistent (stuck it
    is over its capacity, slipping either way its slip turns against its friction), while the
    clutch's stick is refused (a mode passed through). The one-at-a-time settle ends there
    (clutch slipping backwards while its slip rises; the settle never turns a slip's
    direction), so the two elements' modes are chosen together: of the nine only clutch
    slip-, pack slip+ is consistent, the pack is released again. The same pattern ended 2 of
    5400 random settles of such trees (docs/clutch_gearbox.md); this scene, found the same
    way, is rounded."""
    sim = _pack_sim(27.0, bias=0.6, static_ratio=1.8, left=(0.013, -1.4), right=(0.078, 0.47),
                    engine_torque=70.0, clutch=dict(CLUTCH, mu_static=0.24, mu_kinetic=0.234))
    assert _consistent_modes(sim) == {(BACKWARD, FORWARD)}
    mode, st = sim._settle(0.0, *_start(sim))
    assert [(e.element, e.after, e.cause) for e in sim.events] == [
        ('differential', 'slip+', 'capacity below torque'),
        ('clutch', 'slip-', 'capacity below torque'),
        ('differential', 'stuck', 'zero slip'),
        ('differential', 'slip+', 'modes chosen together')]
    assert mode.clutch['clutch'] == BACKWARD and mode.packs['differential'] == FORWARD
    assert _inconsistent(sim, mode, st) == []
    assert sim.statuses == []


@pytest.mark.parametrize('start, fresh, chosen', [
    # the clutch kept slipping forwards (one element kept beats one more stuck)
    ((FORWARD, STUCK), (), (FORWARD, BACKWARD)),
    ((FORWARD, FORWARD), (), (FORWARD, BACKWARD)),
    # the clutch kept stuck
    ((STUCK, STUCK), (), (STUCK, BACKWARD)),
    # nothing can be kept: the most stuck
    ((BACKWARD, FORWARD), (), (STUCK, BACKWARD)),
    # the clutch the event's (in ``fresh``): it is not stuck, it only slips
    ((BACKWARD, FORWARD), ('clutch',), (FORWARD, BACKWARD)),
])
def test_modes_chosen_together_keep_the_most_then_stick_the_most(
        start: tuple[int, int], fresh: tuple[str, ...], chosen: tuple[int, int]) -> None:
    """The fallback's preference (HybridTreeSimulation._joint) where two modes are consistent:
    preload 10 N m, {clutch stuck or slip+, pack slip-} (test above: the clutch's 91.47 N m
    lies between its 90 N m kinetic and 100 N m static capacity). From an inconsistent start
    it takes the consistent mode keeping the most elements as they were, then the one with
    the most stuck (maximal sticking); a ``fresh`` element is not stuck. The consistent set
    and each result are judged apart from the settle (_inconsistent)."""
    sim = _pack_sim(preload=10.0)
    assert _consistent_modes(sim) == {(STUCK, BACKWARD), (FORWARD, BACKWARD)}
    mode, st = _with(sim, *_start(sim), *start)
    assert _inconsistent(sim, mode, st) != []
    mode, st = sim._joint(0.0, mode, st, fresh)
    assert (mode.clutch['clutch'], mode.packs['differential']) == chosen
    assert _inconsistent(sim, mode, st) == []
    changed = {n for n, before, now in (('clutch', start[0], chosen[0]),
                                        ('differential', start[1], chosen[1])) if before != now}
    assert {e.element for e in sim.events} == changed
    assert all(e.cause == 'modes chosen together' for e in sim.events)


def test_two_brakes_behind_an_open_differential_released_together_both_slip() -> None:
    """Equal sides behind an open differential on a 10 % grade, clutch open in neutral, the
    brakes (1485 N m static each at full command) released from 0.05 s to 0.25 s: both
    holding torques (m g sin(atan 0.1) r / 2 = 219.63 N m each, the tyres carrying the grade
    force at rest) reach the falling capacity at one instant, the closed form
    t = 0.05 + 0.2 (1 - 219.63 / 1485) s. The first witness releases its brake; the second
    brake's witness fires at the same instant. Both slip from there (rolling back: slip-),
    and neither is stuck again at that instant: with the chain's rule alone the first brake,
    its hold equal to its capacity to rounding (1.4e-13 N m below it), was stuck again when
    the second let go ({left stuck, right slipping} had not been passed through) and
    released by its witness at once, two more events at the same instant."""
    d = _scene({'kind': 'open'}, _side('left', 0.05, 0.0), _side('right', 0.05, 0.0), grade=10.0)
    sched = CommandSchedule([(0.0, {'clutch': 1.0, 'brake': 1.0, 'throttle': 0.0, 'gear': 0}),
                             (0.05, {'brake': 1.0}), (0.25, {'brake': 0.0})])
    sim = HybridTreeSimulation(parse_scene(d), {}, engine=LinearEngine(m1=0.0, k1=0.0),
                               schedule=sched, duration=0.24, sample_dt=0.01)
    r = sim.run()
    assert r.t_end == pytest.approx(0.24)
    hold = 1500.0 * GRAVITY * math.sin(math.atan(0.1)) * 0.3 / 2.0
    t_release = 0.05 + 0.2 * (1.0 - hold / (0.45 * 0.22 * 15000.0))
    ev = sorted((e.element, e.before, e.after) for e in r.events[:2])
    assert ev == [('brake_left', 'slip+', 'stuck'), ('brake_right', 'slip+', 'stuck')]
    assert [e.t for e in r.events[:2]] == [0.0, 0.0]
    rest = r.events[2:]
    assert sorted((e.element, e.before, e.after) for e in rest) == [
        ('brake_left', 'stuck', 'slip-'), ('brake_right', 'stuck', 'slip-')]
    assert same_instant(rest[0].t, rest[1].t)
    # located by Brent on the dense output (4 eps); the hold is constant while pinned
    assert rest[0].t == pytest.approx(t_release, abs=1e-9)
    assert r.final_mode.brakes == {'brake_left': BACKWARD, 'brake_right': BACKWARD}
    assert r.column('wheel_left')[-1] < 0.0 and r.column('wheel_right')[-1] < 0.0
    assert _inconsistent(sim, r.final_mode, r.final, r.t_end) == []
    assert r.max_energy_residual < 1e-8


def test_more_elements_deciding_than_chosen_together_is_said() -> None:
    """Beyond JOINT_MAX elements deciding at once (3**n modes) the one-at-a-time result
    stands and a status line says which elements it leaves inconsistent (here the bound
    lowered to 1 on the wrong-way scene above, two elements deciding)."""
    sim = _pack_sim(27.0, bias=0.6, static_ratio=1.8, left=(0.013, -1.4), right=(0.078, 0.47),
                    engine_torque=70.0, clutch=dict(CLUTCH, mu_static=0.24, mu_kinetic=0.234))
    sim.JOINT_MAX = 1
    mode, st = sim._settle(0.0, *_start(sim))
    assert mode.clutch['clutch'] == BACKWARD and mode.packs['differential'] == STUCK
    assert sim.statuses == ['t=0.000000 s: 2 friction elements decide at once (at most 1 are '
                            'chosen together): clutch left inconsistent']
    assert _inconsistent(sim, mode, st) != []
