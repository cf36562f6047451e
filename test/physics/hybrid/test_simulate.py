"""HybridSimulation's settle at one instant (cvj_ros/physics/hybrid/simulate.py): which
elements stick and which slip when several decide at once."""
from __future__ import annotations

import numpy as np

from cvj_ros.physics.engine import LinearEngine
from cvj_ros.physics.hybrid import (Brake, Clutch, CommandSchedule, CoulombPack, HybridChain,
                                    HybridSimulation)
from cvj_ros.physics.hybrid.chain import Mode, SectionState
from cvj_ros.physics.hybrid.friction import FORWARD, STUCK
from cvj_ros.physics.load import ConstantLoad
from cvj_ros.physics.scene import Inertia

CLUTCH = CoulombPack(mu_s=0.4, mu_k=0.3, cgeo=0.2, fn_max=1875.0)     # 150 / 112.5 N m
BRAKE = CoulombPack(mu_s=0.5, mu_k=0.4, cgeo=0.25, fn_max=40000.0)    # x 0.16: 800 / 640 N m


def test_an_element_released_first_sticks_again_when_the_other_lets_go() -> None:
    """Clutch and brake stuck at rest; engine 200 N m on 0.15 kg m^2, output 0.15 kg m^2
    driven by the load with 900 N m. The clutch must carry 200 > 150 N m: released; with it
    slipping (112.5 N m) the brake must hold 1012.5 > 800: released; with the brake slipping
    (640 N m) the clutch needs 200 - 0.15 (200 + 900 - 640) / 0.3 = -30 N m, within its
    capacity: it sticks again (a mode not passed through yet), while the brake would need
    1100 N m with the clutch stuck: it slips. Leaving the clutch slipping forwards would be
    inconsistent (the engine side at 583 rad/s^2, the disc at 2483)."""
    chain = HybridChain([Inertia('engine_crank', 0.1), Clutch('clutch', 0.05, 0.01, CLUTCH),
                         Inertia('output_shaft', 0.14), Brake('brake', BRAKE)])
    sched = CommandSchedule([(0.0, {'clutch': 0.0, 'brake': 0.16, 'throttle': 1.0})])
    sim = HybridSimulation(chain, engine=LinearEngine(m1=200.0, k1=0.0),
                           load=ConstantLoad(torque=-900.0), schedule=sched, duration=0.1)
    b = chain.clutches['clutch'][1]
    st = SectionState(np.zeros(chain.n_sections), np.zeros(chain.n_sections), np.zeros(4))
    mode = Mode(clutch={'clutch': STUCK}, gear={}, brake=STUCK)
    mode.offsets[b] = chain.lock_offset(mode, b, st)
    mode, _st = sim._settle(0.0, mode, st)
    assert mode.clutch['clutch'] == STUCK and mode.brake == FORWARD
    assert [(e.element, e.after) for e in sim.events] == [
        ('clutch', 'slip+'), ('brake', 'slip+'), ('clutch', 'stuck')]
