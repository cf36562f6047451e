"""HybridChain structure, mode assembly and the lock map (angles continuous, momentum kept)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from cvj_ros.errors import SceneError
from cvj_ros.physics.engine import LinearEngine
from cvj_ros.physics.hybrid import (Brake, Clutch, CommandSchedule, CoulombPack, Gearbox,
                                    HybridChain, HybridSimulation, Mode, SectionState)
from cvj_ros.physics.hybrid.friction import FORWARD, STUCK
from cvj_ros.physics.load import ConstantLoad
from cvj_ros.physics.scene import Inertia, Joint, Spring

PACK = CoulombPack(mu_s=0.4, mu_k=0.3, cgeo=0.2, fn_max=4000.0)


def _chain(with_hooke: bool = False) -> HybridChain:
    hooke = [Joint('hooke', 'hooke', params={'beta': math.radians(30.0)}),
             Inertia('propshaft', 0.03)] if with_hooke else []
    return HybridChain([Inertia('engine_crank', 0.2), Clutch('clutch', 0.05, 0.02, PACK),
                        Spring('damper', 1500.0, 1.0), Inertia('input_shaft', 0.01),
                        Gearbox('gearbox', 0.01, 0.02, (3.0, 2.0), -3.0, 700.0), *hooke,
                        Inertia('wheel', 5.0), Brake('brake', PACK)])


def test_sections_boundaries_and_shaft_names() -> None:
    ch = _chain()
    assert [b.kind for b in ch.boundaries] == ['clutch', 'spring', 'gearbox']
    assert ch.n_sections == 4
    assert {'engine_crank', 'clutch_input', 'clutch_output', 'input_shaft', 'gearbox_input',
            'gearbox_output', 'wheel'} <= set(ch.shafts)
    mode = Mode(clutch={'clutch': STUCK}, gear={'gearbox': 2}, brake=FORWARD,
                offsets={0: 0.0, 2: 0.0})
    asm = ch.assemble(mode)
    assert [g.sections for g in asm.groups] == [(0, 1), (2, 3)]   # split at the damper only
    assert not asm.pinned
    asm2 = ch.assemble(Mode(clutch={'clutch': FORWARD}, gear={'gearbox': 0}, brake=STUCK))
    assert len(asm2.groups) == 4 and asm2.pinned


@pytest.mark.parametrize('elements, field', [
    ([Inertia('a', 1.0), Brake('brake', PACK), Inertia('b', 1.0)], 'driveline[1]'),
    ([Inertia('a', 1.0), Gearbox('g1', 1.0, 1.0, (2.0,), -2.0, 1.0),
      Gearbox('g2', 1.0, 1.0, (2.0,), -2.0, 1.0), Inertia('b', 1.0)], 'driveline'),
    # one clutch command, one capacity: a second clutch would be given the first one's pack
    ([Inertia('a', 1.0), Clutch('c1', 0.05, 0.02, PACK), Inertia('b', 1.0),
      Clutch('c2', 0.05, 0.02, CoulombPack(mu_s=0.4, mu_k=0.3, cgeo=0.1, fn_max=400.0)),
      Inertia('c', 1.0)], 'driveline'),
])
def test_bad_layouts_name_the_field(elements: list, field: str) -> None:
    with pytest.raises(SceneError) as exc:
        HybridChain(elements)
    assert exc.value.field == field


def test_bad_gearbox_names_the_field() -> None:
    with pytest.raises(SceneError, match=r'^gb.reverse_ratio:'):
        Gearbox('gb', 1.0, 1.0, (2.0,), 2.0, 100.0)
    with pytest.raises(SceneError, match=r'^gb.ratios\[1\]:'):
        Gearbox('gb', 1.0, 1.0, (2.0, 0.0), -2.0, 100.0)


def test_lock_keeps_angles_and_momentum_through_a_hooke_joint() -> None:
    """Lock the gearbox at a speed mismatch: every section angle is unchanged (the offset),
    the group speed is the plastic-impact value sum A M v / sum A^2 M computed here by hand,
    and the kinetic energy lost equals the returned loss."""
    ch = _chain(with_hooke=True)
    st = SectionState(q=np.array([0.3, 0.25, 0.2, 1.7]), v=np.array([50.0, 50.0, 48.0, 10.0]),
                      work=np.zeros(4))
    free = Mode(clutch={'clutch': FORWARD}, gear={'gearbox': 0}, brake=FORWARD)
    locked = free.copy()
    locked.gear['gearbox'] = 2
    locked.offsets[2] = ch.lock_offset(locked, 2, st)
    asm = ch.assemble(locked)
    y, loss = ch.to_mode(asm, st, [2])
    back = ch.to_sections(asm, y, st)
    np.testing.assert_allclose(back.q, st.q, rtol=0, atol=1e-15)
    from cvj_ros.physics.sections import section_kinematics
    m2 = section_kinematics(ch.sections[2], 0.2)[3]
    m3 = section_kinematics(ch.sections[3], 1.7)[3]
    a3 = section_kinematics(ch.sections[2], 0.2)[1] / 2.0      # through the gear 1/i
    v = (m2 * 48.0 + a3 * m3 * 10.0) / (m2 + a3 * a3 * m3)
    assert back.v[2] == pytest.approx(v, rel=1e-14)
    assert back.v[3] == pytest.approx(a3 * v, rel=1e-14)
    ke = lambda s: ch.energy(s)[0]                              # noqa: E731
    assert loss == pytest.approx(ke(st) - ke(back), rel=1e-12)
    assert loss > 0.0


def test_energy_closes_with_a_hooke_joint_through_lock_and_slip() -> None:
    """Clutch engagement and a shift with a 30 deg Hooke joint behind the gearbox (its ratio
    swings 0.87..1.15 twice a turn, and its torque pulsation makes the locked clutch judder):
    residual at the solver's tolerance throughout (1.1e-10 measured at rtol 1e-10)."""
    ch = _chain(with_hooke=True)
    sched = CommandSchedule([(0.0, {'clutch': 1.0, 'gear': 1, 'throttle': 1.0}),
                             (0.2, {'clutch': 1.0}), (0.6, {'clutch': 0.0}),
                             (1.0, {'clutch': 0.0}), (1.0, {'clutch': 1.0}),
                             (1.05, {'gear': 2}), (1.1, {'clutch': 1.0}), (1.4, {'clutch': 0.0})])
    sim = HybridSimulation(ch, engine=LinearEngine(m1=120.0, k1=0.3), load=ConstantLoad(torque=30.0),
                           schedule=sched, duration=2.0, initial_speed=90.0,
                           initial_speeds={'clutch_output': 0.0}, rtol=1e-10, atol=1e-12)
    r = sim.run()
    assert r.count('clutch', 'stuck') >= 2
    assert [e.after for e in r.events if e.element == 'gearbox'] == ['gear 2']   # via neutral
    assert r.max_energy_residual < 1e-8


def test_chain_behind_a_clutch_open_at_t0_starts_at_rest() -> None:
    """Engine at 80 rad/s; pedal 1 at t = 0: the disc and everything behind it start at rest
    (a standing start), the engine side at 80 rad/s."""
    ch = _chain()
    sched = CommandSchedule([(0.0, {'clutch': 1.0, 'gear': 1, 'brake': 1.0})])
    sim = HybridSimulation(ch, engine=LinearEngine(m1=0.0, k1=0.0), load=ConstantLoad(torque=0.0),
                           schedule=sched, duration=0.01, sample_dt=0.01, initial_speed=80.0)
    r = sim.run()
    assert r.column('engine_crank')[0] == 80.0 and r.column('clutch_input')[0] == 80.0
    assert r.column('clutch_output')[0] == 0.0 and r.column('wheel')[0] == 0.0
    assert r.final_mode.brake == STUCK
