"""Hard cases (DESIGN.md section 8) through the lockstep coupling at a 1 ms exchange:
start from standstill, engine stall under a friction-like load, load reversal.

The offline runs (engine and load inside the right-hand side) are covered by
test/physics/test_simulate.py (test_standstill_start_and_stall, test_load_reversal) and
test/physics/test_engine.py (test_engine_stall_under_excess_friction_load). Here the same
driveline (KAVZ-685 unit of seed 004: I1 = 0.128, c_y = 715.4, b_y = 6.35, Hooke 15 deg,
I2 = 0.161) runs as coupling_node runs it: CoupledStepper, torques from the engine/load
models evaluated only at the exchange points t_k, slopes reported. Reference: the offline
Simulation at rtol 1e-9. Criteria (max speed error over all shafts, rad/s; measured values
in docs/robustness.md):

* standstill start (0 -> 39 rad/s, constant 107.5 N m load, 1 s): zoh < 1.0,
  extrapolate < 0.4, linear_implicit < 1e-6 (exact up to the solver tolerance: the linear
  engine M1 - K1 w, seed 004 eq. 3.23, is what its slope model assumes);
* stall (throttle 0, friction load 107.5 tanh(w / 0.5) N m, 0.3 s): zoh and
  linear_implicit come to rest (|w| < 1e-3 rad/s at the end), errors < 0.8 / 0.15;
  extrapolate at H = 1 ms does NOT: the friction slope K = 215 N m s/rad on J2 = 0.161
  gives J/K = 0.75 ms < H and the extrapolated torque keeps a limit cycle (> 0.5 rad/s
  peak to peak) - a limit of the scheme (DESIGN.md section 3), asserted so it stays
  documented; at H = 0.5 ms it comes to rest;
* load reversal (load steps from +107.5 to -192.5 N m at 0.5 s, backlash 1 deg, 1 s):
  zoh < 1.2, extrapolate < 0.2, linear_implicit < 1.2 (the step is a jump in time, which
  the speed slope of linear_implicit does not capture); after the step the load drives:
  the speeds rise.
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np
import pytest

from cvj_ros.physics.cosim import CoupledStepper
from cvj_ros.physics.driveline import Driveline
from cvj_ros.physics.engine import engine_from_spec
from cvj_ros.physics.load import load_from_spec
from cvj_ros.physics.scene import Scene, parse_scene
from cvj_ros.physics.simulate import Simulation

CASES = {
    'standstill': ({'model': 'linear'}, {'model': 'constant', 'torque': 107.5}, 0.0, 1.0, False),
    'stall': ({'model': 'linear', 'throttle': 0.0},
              {'model': 'constant', 'torque': 107.5, 'speed_scale': 0.5}, 39.0, 0.3, False),
    'reversal': ({'model': 'linear'}, [{'model': 'constant', 'torque': 107.5},
                                       {'model': 'brake_steps', 'steps': [[0.5, -300.0]]}],
                 39.0, 1.0, True),
}


def case_scene(name: str) -> Scene:
    engine, load, w0, duration, backlash = CASES[name]
    spring = {'type': 'spring', 'name': 's', 'stiffness': 715.4, 'damping': 6.35}
    if backlash:
        spring['backlash_deg'] = 1.0
    return parse_scene({
        'name': name, 'duration': duration, 'engine': engine, 'load': load,
        'initial': {'speed_rad_s': w0},
        'driveline': [{'type': 'inertia', 'name': 'a', 'J': 0.128}, spring,
                      {'type': 'joint', 'name': 'h', 'kind': 'hooke', 'params': {'beta_deg': 15.0}},
                      {'type': 'inertia', 'name': 'b', 'J': 0.161}]})


@lru_cache(maxsize=None)
def reference(name: str) -> np.ndarray:
    """Shaft speeds (rad/s) every 1 ms, offline, rtol 1e-9."""
    sc = case_scene(name)
    return Simulation(sc, rtol=1e-9, atol=1e-11).run(sc.duration, sample_dt=1e-3).velocity


def lockstep(name: str, scheme: str, h: float = 1e-3) -> np.ndarray:
    """Shaft speeds at every exchange point of a CoupledStepper run with exchange step h."""
    sc = case_scene(name)
    engine, load = engine_from_spec(sc.engine), load_from_spec(sc.load, seed=sc.seed)
    dl = Driveline.from_scene(sc)
    cs = CoupledStepper(dl, scheme=scheme, rtol=1e-8, atol=1e-10)
    x = dl.x0.copy()
    out = [dl.joint_states(x, 0.0, 0.0)[2]]
    for k in range(int(round(sc.duration / h))):
        t = k * h
        we, wl = dl.engine_omega(x), dl.load_omega(x)
        x = cs.advance((k + 1) * h, engine.torque(t, we, dl.engine_phi(x)),
                       load.torque(t, wl, dl.load_phi(x)),
                       slope_engine=engine.slope(t, we), slope_load=load.slope(t, wl))
        out.append(dl.joint_states(x, 0.0, 0.0)[2])
    return np.asarray(out)


@pytest.mark.hard
@pytest.mark.parametrize('name,scheme,bound', [
    ('standstill', 'zoh', 1.0), ('standstill', 'extrapolate', 0.4),
    ('standstill', 'linear_implicit', 1e-6),
    ('stall', 'zoh', 0.8), ('stall', 'linear_implicit', 0.15),
    ('reversal', 'zoh', 1.2), ('reversal', 'extrapolate', 0.2),
    ('reversal', 'linear_implicit', 1.2),
])
def test_lockstep_1ms_against_offline(name: str, scheme: str, bound: float) -> None:
    w = lockstep(name, scheme)
    ref = reference(name)
    err = float(np.max(np.abs(w - ref)))
    print(f'\n{name} {scheme} H = 1 ms: max speed error {err:.3g} rad/s')
    assert np.all(np.isfinite(w))
    assert err < bound
    if name == 'standstill':
        assert np.all(w[0] == 0.0) and w[-1, 0] > 30.0
    if name == 'stall':
        assert np.max(np.abs(w[-1])) < 1e-3 and np.max(np.abs(ref[-1])) < 1e-3
    if name == 'reversal':
        i_step = 500
        assert w[-1, -1] > w[i_step, -1] + 10.0        # the reversed load drives the shafts


@pytest.mark.hard
def test_extrapolate_limit_cycle_at_standstill_needs_h_below_j_over_k() -> None:
    coarse = lockstep('stall', 'extrapolate', 1e-3)
    tail = coarse[-100:]                                # last 0.1 s
    print(f'\nstall extrapolate H = 1 ms: limit cycle {np.ptp(tail[:, -1]):.3g} rad/s p-p')
    assert np.ptp(tail[:, -1]) > 0.5
    fine = lockstep('stall', 'extrapolate', 5e-4)
    assert np.max(np.abs(fine[-1])) < 1e-3
