"""Unique JointState shaft names by construction (issue 14 item 1): a joint names its
shafts <name>_input, <name>_output and <name>_<member>; a generated name that collides with
another element's is a SceneError naming both elements."""
from __future__ import annotations

import random

import pytest

from cvj_ros.errors import SceneError
from cvj_ros.physics.driveline import Driveline, build_driveline
from cvj_ros.physics.scene import load_scene, parse_scene, shipped_scenes


@pytest.mark.parametrize('name', sorted(shipped_scenes()))
def test_shipped_scenes_have_unique_shaft_names(name: str) -> None:
    sc = load_scene(shipped_scenes()[name])
    if sc.has_modes and sc.is_tree:   # clutch, gearbox, brakes on a vehicle: the mode-aware tree
        from cvj_ros.physics.hybrid.from_scene import hybrid_simulation
        names = hybrid_simulation(sc).shaft_names
    elif sc.has_modes:   # clutch, gearbox, brake: the mode-aware chain names the shafts
        from cvj_ros.physics.hybrid import HybridChain
        names = list(HybridChain(sc.driveline).shafts)
    else:
        names = build_driveline(sc).shaft_names
    assert len(set(names)) == len(names), names


def _scene(elements: list[dict]) -> dict:
    return {'name': 'names', 'duration': 0.1, 'exchange_step': 0.001,
            'engine': {'model': 'linear'}, 'load': {'model': 'constant', 'torque': 10.0},
            'driveline': elements}


def test_generated_name_colliding_with_an_inertia_names_both() -> None:
    sc = parse_scene(_scene([
        {'type': 'inertia', 'name': 'gearbox_input', 'J': 0.1},
        {'type': 'joint', 'name': 'gearbox', 'kind': 'gear', 'params': {'gear_ratio': 3.0}},
        {'type': 'inertia', 'name': 'out', 'J': 0.2}]))
    with pytest.raises(SceneError) as exc:
        Driveline.from_scene(sc)
    assert str(exc.value) == (
        "driveline[1].name: shaft name 'gearbox_input' is made by both driveline[0] "
        "('gearbox_input') and driveline[1] ('gearbox'; a joint names its shafts <name>_input, "
        "<name>_output and <name>_<member>); rename one of them")


def test_fuzzed_name_sets_are_unique_or_rejected_naming_both() -> None:
    """300 seeded random chains whose names are drawn from a pool built to collide
    (a, a_input, a_output, a_cage, a_spider ...): each either builds with unique names or
    is rejected with the line above; both outcomes occur."""
    pool = ['a', 'b', 'a_input', 'a_output', 'a_cage', 'a_spider', 'b_input', 'b_output', 'c']
    kinds = [('gear', {'gear_ratio': 2.0}), ('rzeppa', {'delta_deg': 20.0}),
             ('tripod', {'beta_deg': 10.0, 'r_m': 0.02, 'l_m': 0.2}),
             ('hooke', {'beta_deg': 10.0, 'phase_deg': 0.0})]   # two in a row must state it
    outcomes = {'built': 0, 'rejected': 0}
    for case in range(300):
        rng = random.Random(case)
        names = rng.sample(pool, 5)
        elements = []
        for k, nm in enumerate(names):
            if k % 2 == 0:
                elements.append({'type': 'inertia', 'name': nm, 'J': 0.1})
            else:
                kind, params = rng.choice(kinds)
                elements.append({'type': 'joint', 'name': nm, 'kind': kind, 'params': params})
        try:
            shaft_names = Driveline.from_scene(parse_scene(_scene(elements))).shaft_names
        except SceneError as exc:
            msg = str(exc)
            assert 'is made by both driveline[' in msg and '\n' not in msg, msg
            outcomes['rejected'] += 1
            continue
        assert len(set(shaft_names)) == len(shaft_names), shaft_names
        outcomes['built'] += 1
    assert outcomes['built'] > 20 and outcomes['rejected'] > 20, outcomes
