"""The fidelity chooser on vehicle scenes (cvj_ros.physics.fidelity_tree through
choose_fidelity): a spring next to an open differential against the closed form of the
apparent inertia, the rigid / elastic decision as for chains (test_fidelity.py), rigid and
elastic runs agreeing within the target, and the tyre relaxation reported and kept.

Closed form (symmetric axle, open differential of ratio i, side gear J_s and wheel J_w per
side, carrier J_c, spring between the crank J_a and the shaft J_b): with u = (q_b, delta)
the two sides' rows are (1/i, +1) and (1/i, -1), so M is diagonal and the spring's right
shaft sees J_r = J_b + (J_c + 2 (J_s + J_w))/i^2 (tyres slipping freely), plus the
vehicle's m r^2/i^2 with gripping tyres (v = r (omega_L + omega_R)/2); the spiders move
only delta and do not enter.
"""
from __future__ import annotations

import math
import re
from typing import Any

import numpy as np
import pytest

from cvj_ros.physics.fidelity import choose_fidelity
from cvj_ros.physics.fidelity_tree import tree_spring_inertias
from cvj_ros.physics.scene import load_scene, parse_scene, shipped_scenes
from cvj_ros.physics.simulate import Simulation

I_DIFF, J_A, J_B, J_C, J_S, J_W, R, M = 4.0, 0.2, 0.01, 0.02, 0.005, 1.0, 0.3, 1500.0


def _wheel(name: str) -> dict[str, Any]:
    return {'type': 'wheel', 'name': name, 'J': J_W, 'radius': R, 'mu': 0.9, 'load_share': 0.3}


def axle(stiffness: float, **extra: Any) -> dict[str, Any]:
    return {'name': 'axle_spring', 'duration': 0.5, 'engine': {'model': 'linear', 'm1': 200.0, 'k1': 0.5},
            'vehicle': {'mass': M, 'initial_speed_kmh': 20},
            'driveline': [{'type': 'inertia', 'name': 'crank', 'J': J_A},
                          {'type': 'spring', 'name': 'k', 'stiffness': stiffness, 'damping': 2.0},
                          {'type': 'inertia', 'name': 'b', 'J': J_B},
                          {'type': 'differential', 'name': 'diff', 'kind': 'open', 'ratio': I_DIFF,
                           'J_carrier': J_C, 'J_side': J_S, 'J_spider': 0.001, 'spider_ratio': 1.6,
                           'left': [_wheel('wheel_left')], 'right': [_wheel('wheel_right')]}],
            **extra}


def test_apparent_inertias_across_an_open_differential_are_the_closed_form() -> None:
    j = tree_spring_inertias(parse_scene(axle(1e4)), {})['k']
    free = J_B + (J_C + 2.0 * (J_S + J_W)) / I_DIFF ** 2
    assert j['j_left'] == pytest.approx(J_A, rel=1e-12)
    assert j['j_left_grip'] == pytest.approx(J_A, rel=1e-12)      # no wheel on the crank side
    assert j['j_right'] == pytest.approx(free, rel=1e-12)
    assert j['j_right_grip'] == pytest.approx(free + M * R * R / I_DIFF ** 2, rel=1e-12)


def test_stiff_spring_next_to_a_differential_becomes_rigid_within_the_target() -> None:
    rep = choose_fidelity(parse_scene(axle(1e6, accuracy_target=0.01)))
    ch = {c.name: c for c in rep.choices}['k']
    j_r = J_B + (J_C + 2.0 * (J_S + J_W) + M * R * R) / I_DIFF ** 2
    omega_n = math.sqrt(1e6 * (1.0 / J_A + 1.0 / j_r))
    assert ch.chosen == 'rigid'
    assert ch.candidates['rigid']['omega_n'] == pytest.approx(omega_n, rel=1e-12)
    # the operating speed is the rolling start's engine speed: 20 km/h on 0.3 m through i = 4
    assert rep.operating_speed == pytest.approx(20 / 3.6 / R * I_DIFF, rel=1e-12)
    r = rep.excitation_band / omega_n
    assert ch.candidates['rigid']['speed_error'] == pytest.approx(r * r / (1 - r * r), rel=1e-12)
    assert ch.candidates['rigid']['speed_error'] <= 0.01
    # the free-tyre frequency is higher (less inertia): the grip limit decides, conservatively
    assert ch.candidates['rigid']['omega_n_free_tyres'] > omega_n
    # soft: elastic; no target: elastic; forced: as forced
    assert choose_fidelity(parse_scene(axle(50.0, accuracy_target=0.01))).levels['k'] == 'elastic'
    assert choose_fidelity(parse_scene(axle(1e6))).levels['k'] == 'elastic'
    assert choose_fidelity(parse_scene(axle(1e6, accuracy_target=0.01)),
                           overrides={'k': 'elastic'}).levels['k'] == 'elastic'


def test_rigid_and_elastic_runs_agree_within_the_target() -> None:
    sc = parse_scene(axle(1e6, accuracy_target=0.01))
    rigid = Simulation(sc, method='dopri5', rtol=1e-8)
    assert rigid.fidelity_report.levels['k'] == 'rigid'
    r = rigid.run(0.3, sample_dt=1e-3)
    e = Simulation(sc, method='rosenbrock', rtol=1e-8, fidelity={'k': 'elastic'}).run(0.3, sample_dt=1e-3)
    i = r.column('wheel_left')
    err = np.max(np.abs(r.velocity[:, i] - e.velocity[:, i]) / np.abs(e.velocity[:, i]))
    assert err < 0.01


@pytest.mark.parametrize('name', ['fwd_axle', 'rwd_propshaft', 'awd_4x4'])
def test_shipped_vehicle_scenes_report_springs_with_their_frequency_and_keep_the_tyres(name: str) -> None:
    import dataclasses
    sc = dataclasses.replace(load_scene(shipped_scenes()[name]), accuracy_target=0.01)
    rep = choose_fidelity(sc)
    springs = [c for c in rep.choices if c.element == 'spring']
    tyres = [c for c in rep.choices if c.element == 'tyre']
    assert springs and all(c.candidates['rigid']['omega_n'] > 0 for c in springs)
    assert tyres and all(c.chosen == 'relaxed' for c in tyres)
    for c in tyres:
        b = c.candidates['instant']
        tau = b['time_constant_s']
        assert b['lag_error'] == pytest.approx(1 - 1 / math.sqrt(1 + (rep.excitation_band * tau) ** 2))
    assert not {c.name for c in tyres} & set(rep.levels)     # levels: joints and springs only
    assert 'tyre' in str(rep) and 'lag e=' in str(rep)


def test_standstill_start_keeps_springs_elastic_and_the_lag_error_is_one() -> None:
    raw = axle(1e6, accuracy_target=0.01)
    raw['vehicle'] = {'mass': M, 'initial_speed_kmh': 0}
    rep = choose_fidelity(parse_scene(raw))
    assert rep.operating_speed == 0.0 and rep.levels['k'] == 'elastic'
    assert all(c.candidates['instant']['lag_error'] == 1.0 for c in rep.choices if c.element == 'tyre')


J_GI, J_GO = 0.004, 0.03        # kg m^2, gearbox input / output of the mode axle below


def mode_axle(stiffness: float) -> dict[str, Any]:
    """The closed-form axle with a gearbox (ratios 3 and 1, reverse -2.5) between ``b`` and
    the differential: a vehicle scene with modes (cvj_ros.physics.hybrid.tree)."""
    raw = axle(stiffness)
    raw['driveline'].insert(3, {'type': 'gearbox', 'name': 'gb', 'J_input': J_GI, 'J_output': J_GO,
                                'ratios': [3.0, 1.0], 'reverse_ratio': -2.5,
                                'max_input_rpm': 6500.0})
    return raw


def test_mode_tree_spring_gets_the_lowest_frequency_of_its_locked_modes() -> None:
    """A vehicle scene with modes (was: no omega_n, so the explicit-step check missed it):
    the spring sees J_r = J_b + J_gi + (J_go + (J_c + 2 (J_s + J_w) + m r^2)/i^2)/i_g^2 with
    the gear engaged (the closed form above, reflected through the gear), largest in the
    gear of smallest |i_g| = 1, so the reported omega_n is that gear's."""
    rep = choose_fidelity(parse_scene(mode_axle(1e4)))
    ch = {c.name: c for c in rep.choices}['k']
    j_r = J_B + J_GI + J_GO + (J_C + 2.0 * (J_S + J_W) + M * R * R) / I_DIFF ** 2
    assert ch.chosen == 'elastic'
    assert ch.candidates['elastic']['omega_n'] == pytest.approx(
        math.sqrt(1e4 * (1.0 / J_A + 1.0 / j_r)), rel=1e-12)


@pytest.mark.parametrize('name, spring, path', [
    ('fwd_axle', 'midshaft_left_twist', 'driveline[4].left[2]'),
    ('launch_clutch', 'midshaft_left_twist', 'driveline[5].left[2]'),
    ('launch_clutch', 'clutch_damper', 'driveline[2]'),
])
def test_explicit_step_check_refuses_a_vehicle_spring_of_1e300_naming_its_path(
        name: str, spring: str, path: str) -> None:
    """stiffness 1e300 on a vehicle scene's spring: refused naming the scene path of the
    spring (a branch's too; was `driveline[midshaft_left_twist]`, and nothing at all for a
    scene with modes); the shipped values pass over the scene's duration."""
    import dataclasses

    from cvj_ros.errors import SceneError
    from cvj_ros.physics.scene import iter_elements
    from cvj_ros.physics.simulate import scene_explicit_step_check
    sc = load_scene(shipped_scenes()[name])
    scene_explicit_step_check(sc, 'dopri5', sc.duration)

    def stiffen(chain: tuple[Any, ...]) -> tuple[Any, ...]:
        out = []
        for el in chain:
            if getattr(el, 'name', None) == spring:
                el = dataclasses.replace(el, stiffness=1e300)
            for side in ('left', 'right'):
                if isinstance(getattr(el, side, None), tuple):
                    el = dataclasses.replace(el, **{side: stiffen(getattr(el, side))})
            out.append(el)
        return tuple(out)

    bad = dataclasses.replace(sc, driveline=stiffen(sc.driveline))
    assert any(getattr(el, 'stiffness', 0) == 1e300 for el in iter_elements(bad.driveline))
    with pytest.raises(SceneError, match=rf'^{re.escape(path)}\.stiffness: spring {spring!r} .* '
                                         r'dopri5 would need ~\S+e\+1\d\d steps for 0\.1 s'):
        scene_explicit_step_check(bad, 'dopri5', 0.1)
    scene_explicit_step_check(bad, 'rosenbrock', 0.1)
