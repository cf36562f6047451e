"""Fidelity choice: bounds against the exact model, cheap picks stay inside the target."""
from __future__ import annotations

import json
import math
import re

import numpy as np
import pytest

from cvj_ros.physics.fidelity import choose_fidelity, joint_error_bounds, joint_max_order
from cvj_ros.physics.scene import parse_scene
from cvj_ros.physics.simulate import Simulation


class Const:
    def __init__(self, value: float) -> None:
        self.value = value

    def torque(self, t: float, omega: float, phi: float = 0.0) -> float:
        return self.value

    def slope(self, t: float, omega: float, phi: float = 0.0) -> float:
        return 0.0


def tripod_scene(target: float | None, *, beta_deg: float = 15.0) -> object:
    d = {'name': 'f', 'duration': 0.5, 'engine': {'model': 'linear'},
         'load': {'model': 'constant', 'torque': 0.0}, 'initial': {'speed_rad_s': 100.0},
         'driveline': [{'type': 'inertia', 'name': 'big', 'J': 1e6},
                       {'type': 'joint', 'name': 'tj', 'kind': 'tripod',
                        'params': {'beta_deg': beta_deg, 'r_m': 0.0264, 'l_m': 0.24}},
                       {'type': 'inertia', 'name': 'out', 'J': 0.01}]}
    if target is not None:
        d['accuracy_target'] = target
    return parse_scene(d)


def test_hooke_bound_is_closed_form() -> None:
    beta = math.radians(20.0)
    b = joint_error_bounds('hooke', {'beta': beta})
    # ratio swings cos b .. 1/cos b; ideal has ratio 1: max |1 - r| = 1/cos b - 1
    assert b['ideal']['ratio_error'] == pytest.approx(1 / math.cos(beta) - 1, rel=1e-6)
    assert b['exact']['speed_error'] == 0.0
    assert joint_max_order('hooke', {'beta': beta}) >= 2
    assert joint_max_order('ideal_cv', {}) == 0


@pytest.mark.parametrize('target,expected', [(0.01, 'ideal'), (1e-4, 'closed'), (1e-9, 'exact'),
                                             (None, 'exact')])
def test_tripod_choice_by_target(target: float | None, expected: str) -> None:
    rep = choose_fidelity(tripod_scene(target))
    assert rep.levels['tj'] == expected


@pytest.mark.parametrize('target', [0.01, 1e-4])
def test_cheap_choice_measured_error_inside_target(target: float) -> None:
    """Run the chosen (cheap) model and the exact one at constant input speed: the
    measured relative output-speed error stays inside the target."""
    sc = tripod_scene(target)
    cheap = Simulation(sc, method='dop853', rtol=1e-10, atol=1e-12, engine=Const(0.0), load=Const(0.0))
    assert cheap.fidelity_report.levels['tj'] != 'exact'
    exact = Simulation(sc, method='dop853', rtol=1e-10, atol=1e-12, engine=Const(0.0), load=Const(0.0),
                       fidelity={'tj': 'exact'})
    a = cheap.run(0.2, sample_dt=2e-4)
    b = exact.run(0.2, sample_dt=2e-4)
    i = a.column('out')
    err = np.max(np.abs(a.velocity[:, i] - b.velocity[:, i]) / np.abs(b.velocity[:, i]))
    assert err <= target
    assert err > 0.05 * target       # the bound is not vacuous: the cheap model does differ


def test_spring_rigid_when_far_above_band() -> None:
    base = {'name': 's', 'duration': 0.5, 'engine': {'model': 'linear', 'm1': 50.0, 'k1': 0.4},
            'load': {'model': 'constant', 'torque': 10.0}, 'initial': {'speed_rad_s': 100.0},
            'driveline': [{'type': 'inertia', 'name': 'a', 'J': 0.01},
                          {'type': 'spring', 'name': 'k', 'stiffness': 1e6, 'damping': 10.0},
                          {'type': 'inertia', 'name': 'b', 'J': 0.01}]}
    rep = choose_fidelity(parse_scene({**base, 'accuracy_target': 0.01}))
    ch = {c.name: c for c in rep.choices}['k']
    assert ch.chosen == 'rigid'
    assert ch.candidates['rigid']['omega_n'] == pytest.approx(math.sqrt(1e6 * 200.0))
    assert ch.candidates['rigid']['speed_error'] <= 0.01
    soft = dict(base, driveline=[base['driveline'][0], {**base['driveline'][1], 'stiffness': 50.0},
                                 base['driveline'][2]], accuracy_target=0.01)
    assert choose_fidelity(parse_scene(soft)).levels['k'] == 'elastic'
    # without a target the spring stays as written
    assert choose_fidelity(parse_scene(base)).levels['k'] == 'elastic'
    # rigid and elastic runs agree on the speeds (quasi-static)
    sc = parse_scene({**base, 'accuracy_target': 0.01})
    r = Simulation(sc, method='dopri5', rtol=1e-8).run(0.3, sample_dt=1e-3)
    e = Simulation(sc, method='rosenbrock', rtol=1e-8, fidelity={'k': 'elastic'}).run(0.3, sample_dt=1e-3)
    assert np.max(np.abs(r.velocity[:, -1] - e.velocity[:, -1]) / e.velocity[:, -1]) < 0.01


def test_report_printable_and_serialisable() -> None:
    rep = choose_fidelity(tripod_scene(0.01))
    text = str(rep)
    assert 'tj' in text and 'ideal' in text
    d = json.loads(rep.to_json())
    assert d['choices'][0]['chosen'] == 'ideal'
    assert d['accuracy_target'] == 0.01


# launch_clutch_chain's values (config/scenes/launch_clutch_chain.yaml, kg m^2, N m/rad)
LCC_J_IN = 0.15 + 0.10 + 0.01          # crank + clutch input + clutch output (clutch stuck)
LCC_J_MID = 0.01 + 0.005               # input shaft + gearbox input; gearbox output 0.02
LCC_RATIOS = (14.21, 8.526, 5.684, 4.263, -13.398)


def test_mode_chain_spring_gets_the_lowest_frequency_of_its_locked_modes() -> None:
    """A chain with clutch, gearbox and brake (was: no fidelity report at all, so no omega_n
    and no explicit-step check): every clutch stuck, each gear engaged, the brake stuck.
    The damper sees J_l = J_in, J_r = J_mid + 0.02/i^2, lowest in 4th (smallest |i|, largest
    J_r); the halfshaft J_l = J_mid i^2 + 0.02 against the braked wheel (1/J_r = 0), lowest
    in 1st (largest |i|). Both by hand from the scene file."""
    from cvj_ros.physics.scene import load_scene, shipped_scenes
    rep = choose_fidelity(load_scene(shipped_scenes()['launch_clutch_chain']))
    ch = {c.name: c for c in rep.choices}
    damper = min(math.sqrt(1200.0 * (1.0 / LCC_J_IN + 1.0 / (LCC_J_MID + 0.02 / i ** 2)))
                 for i in LCC_RATIOS)
    half = min(math.sqrt(6100.0 / (LCC_J_MID * i ** 2 + 0.02)) for i in LCC_RATIOS)
    assert ch['clutch_damper'].chosen == ch['halfshaft'].chosen == 'elastic'
    assert ch['clutch_damper'].candidates['elastic']['omega_n'] == pytest.approx(damper, rel=1e-12)
    assert ch['halfshaft'].candidates['elastic']['omega_n'] == pytest.approx(half, rel=1e-12)
    assert half == pytest.approx(math.sqrt(6100.0 / (LCC_J_MID * 14.21 ** 2 + 0.02)), rel=1e-15)


@pytest.mark.parametrize('spring, value, path', [('clutch_damper', '1200.0', 'driveline[2]'),
                                                 ('halfshaft', '6100.0', 'driveline[5]')])
def test_explicit_step_check_refuses_a_mode_chain_spring_of_1e300(
        tmp_path, spring: str, value: str, path: str) -> None:
    """launch_clutch_chain with a spring at 1e300 N m/rad: refused for dopri5 over 0.1 s,
    naming the stiffness (was: not checked, the report could not be built); the shipped
    values pass over the scene's 10 s, an implicit solver is not refused."""
    from cvj_ros.errors import SceneError
    from cvj_ros.physics.scene import load_scene, shipped_scenes
    from cvj_ros.physics.simulate import scene_explicit_step_check
    text = shipped_scenes()['launch_clutch_chain'].read_text()
    scene_explicit_step_check(load_scene(shipped_scenes()['launch_clutch_chain']), 'dopri5', 10.0)
    assert text.count(f'stiffness: {value}') == 1
    bad = tmp_path / 'stiff.yaml'
    bad.write_text(text.replace(f'stiffness: {value}', 'stiffness: 1.0e+300'))
    sc = load_scene(str(bad))
    with pytest.raises(SceneError, match=rf'^{re.escape(path)}\.stiffness: spring {spring!r} .* '
                                         r'dopri5 would need ~\S+e\+1\d\d steps for 0\.1 s'):
        scene_explicit_step_check(sc, 'dopri5', 0.1)
    scene_explicit_step_check(sc, 'rosenbrock', 0.1)
    scene_explicit_step_check(sc, 'dopri5', 0.1, overrides={spring: 'rigid'})
