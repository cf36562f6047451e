"""Scene messages a user meets first: every solver `--method` takes is a scene method, and
the suggestions name what the user most likely meant."""
from __future__ import annotations

import copy

import pytest

from cvj_ros.errors import SceneError
from cvj_ros.physics.scene import OFFLINE_METHODS, SOLVER_METHODS, parse_scene

BASE = {
    'name': 'messages', 'duration': 0.1, 'exchange_step': 1e-3,
    'engine': {'model': 'linear'}, 'load': {'model': 'constant', 'torque': 10.0},
    'driveline': [
        {'type': 'inertia', 'name': 'a', 'J': 0.1},
        {'type': 'joint', 'name': 'j', 'kind': 'hooke', 'params': {'beta_deg': 15.0}},
        {'type': 'inertia', 'name': 'b', 'J': 0.1},
    ],
}


def _scene(**joint: object) -> dict:
    d = copy.deepcopy(BASE)
    d['driveline'][1].update(joint)
    return d


@pytest.mark.parametrize('method', ['rodas4', 'rodas3', 'dopri5', 'ros2'])
def test_scene_takes_every_offline_method(method: str) -> None:
    d = copy.deepcopy(BASE)
    d['solver'] = {'method': method, 'h': 1e-4}
    assert parse_scene(d).solver.method == method


def test_scene_methods_are_the_methods_simulate_takes() -> None:
    from cvj_ros.physics.solvers import METHODS
    assert set(SOLVER_METHODS) == set(OFFLINE_METHODS) == set(METHODS)


def test_coupling_node_takes_every_scene_method() -> None:
    pytest.importorskip('rclpy')
    from cvj_ros.nodes.coupling_node import SOLVERS
    assert set(SOLVERS) - {''} == set(SOLVER_METHODS)


@pytest.mark.parametrize('kind', ['cardan', 'universal'])
def test_a_single_cardan_suggests_hooke(kind: str) -> None:
    with pytest.raises(SceneError, match=r"^driveline\[1\]\.kind: must be one of .*, got '" + kind
                       + r"'; did you mean 'hooke'\?$"):
        parse_scene(_scene(kind=kind))


def test_a_bare_angle_suggests_degrees() -> None:
    with pytest.raises(SceneError, match=r"^driveline\[1\]\.params\.beta: unknown parameter; "
                                         r"did you mean 'beta_deg'\?$"):
        parse_scene(_scene(params={'beta': 15.0}))


def test_lever_hinge_sum_out_of_range_names_the_sum() -> None:
    with pytest.raises(SceneError) as err:
        parse_scene(_scene(kind='lever_hinge', params={'alpha_deg': 89.0, 'delta_alpha_deg': 1.72}))
    assert str(err.value) == ('driveline[1].params.alpha_deg: the sum alpha + delta_alpha must be '
                              'in [0, 90) deg, got 89 + 1.72 = 90.72 deg')
