"""Vehicle scenes: the branching format's round trip and its errors' field paths."""
from __future__ import annotations

import copy
from typing import Any

import pytest

from cvj_ros.errors import SceneError
from cvj_ros.physics.scene import Differential, Wheel, iter_elements, parse_scene

WHEEL = {'type': 'wheel', 'name': 'wheel_left', 'J': 1.0, 'radius': 0.3, 'mu': 0.9, 'load_share': 0.3}


def scene() -> dict[str, Any]:
    return {'name': 'axle', 'duration': 1.0, 'engine': {'model': 'linear', 'm1': 100.0},
            'vehicle': {'mass': 1500, 'initial_speed_kmh': 20},
            'driveline': [
                {'type': 'inertia', 'name': 'crank', 'J': 0.2},
                {'type': 'differential', 'name': 'diff', 'kind': 'open', 'ratio': 4.0,
                 'J_carrier': 0.02, 'J_side': 0.005,
                 'left': [{'type': 'spring', 'name': 'hs_l', 'stiffness': 8000},
                          {'type': 'joint', 'name': 'tri_l', 'kind': 'tripod', 'params': {'beta_deg': 6}},
                          dict(WHEEL)],
                 'right': [dict(WHEEL, name='wheel_right')]}]}


def test_round_trip_and_iteration() -> None:
    sc = parse_scene(scene())
    assert sc.is_tree
    assert parse_scene(sc.to_dict()) == sc
    names = [el.name for el in iter_elements(sc.driveline)]
    assert names == ['crank', 'diff', 'hs_l', 'tri_l', 'wheel_left', 'wheel_right']
    assert isinstance(sc.element('wheel_right'), Wheel)
    assert isinstance(sc.element('diff'), Differential)
    assert 'load' not in sc.to_dict()


def error(d: dict[str, Any]) -> str:
    with pytest.raises(SceneError) as exc:
        parse_scene(d)
    return str(exc.value)


@pytest.mark.parametrize('edit, expect', [
    (lambda d: d['driveline'][1]['left'][1]['params'].update(beta_deg=95),
     'driveline[1].left[1].params.beta_deg'),
    (lambda d: d['driveline'][1]['left'][2].update(mu=-1), 'driveline[1].left[2].mu: must be > 0'),
    (lambda d: d['driveline'][1]['right'][0].pop('radius'), 'driveline[1].right[0].radius: missing'),
    (lambda d: d['driveline'][1]['right'][0].update(tyre={'B': 10, 'D': 1}),
     "driveline[1].right[0].tyre.D: unknown key"),
    (lambda d: d['driveline'][1].update(kind='planetary'), 'driveline[1].kind: must be one of'),
    (lambda d: d['driveline'][1].update(kind='clutch_pack'), 'driveline[1].preload_nm: missing'),
    (lambda d: d['driveline'][1].update(viscous=3.0), "driveline[1].viscous: only for kind 'viscous'"),
    (lambda d: d['driveline'][1].update(kind='viscous'), 'driveline[1].viscous: missing'),
    (lambda d: d['driveline'][1].pop('J_side'), 'driveline[1].J_side: missing'),
    (lambda d: d['driveline'][1].update(right=[]), 'driveline[1].right: must be a non-empty list'),
    (lambda d: d['driveline'][1]['right'].append({'type': 'inertia', 'name': 'x', 'J': 1}),
     'driveline[1].right[0].type: a wheel must be the last element'),
    (lambda d: d['driveline'][1]['left'].pop(), 'driveline[1].left[1].type: a vehicle driveline ends'),
    (lambda d: d['driveline'][1]['right'][0].update(name='tri_l'),
     "driveline[1].right[0].name: duplicate name 'tri_l' (also driveline[1].left[1])"),
    (lambda d: d['driveline'][1]['right'][0].update(load_share=0.8),
     'driveline[1].right[0].load_share: the wheels\' static load shares sum to 1.1 > 1'),
    (lambda d: d.update(load={'model': 'constant'}), "vehicle: give either 'load'"),
    (lambda d: d['vehicle'].update(cg_height=0.5), 'vehicle.wheelbase: load transfer needs'),
    (lambda d: d['vehicle'].update(cg_height=0.5, wheelbase=2.6, front_share=0.6),
     'driveline[1].left[2].axle: missing (front or rear)'),
    (lambda d: d['vehicle'].update(mass=0), 'vehicle.mass: must be > 0'),
    (lambda d: d['vehicle'].update(initial_speed_m_s=3), 'vehicle.initial_speed_m_s: give either'),
    (lambda d: d.update(initial={'speed_rpm': 1000}), 'initial.speed_rpm: the vehicle'),
])
def test_errors_name_the_field(edit: Any, expect: str) -> None:
    d = copy.deepcopy(scene())
    edit(d)
    assert error(d).startswith(expect)


def test_chain_scene_refuses_wheels_and_vehicle_needs_no_load() -> None:
    d = scene()
    chain = {'name': 'c', 'duration': 1.0, 'engine': {'model': 'linear'}, 'load': {'model': 'constant'},
             'driveline': [{'type': 'inertia', 'name': 'a', 'J': 1.0}, dict(WHEEL)]}
    assert error(chain).startswith("driveline[1].type: 'wheel' needs a vehicle scene")
    d.pop('vehicle')
    assert error(d).startswith("load: missing (or a 'vehicle' block")
