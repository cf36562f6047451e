"""Scene-file keys of clutch, gearbox, brake and commands: parse, round trip, field paths,
and every other path (Driveline, ROS run) refusing such a scene in one line."""
from __future__ import annotations

import copy
import random
from typing import Any

import pytest

from cvj_ros.errors import CvjError, SceneError
from cvj_ros.physics.hybrid.elements import Brake, Clutch, Gearbox
from cvj_ros.physics.scene import parse_scene

BASE: dict[str, Any] = {
    'name': 'modes', 'duration': 0.5, 'exchange_step': 0.001,
    'engine': {'model': 'linear', 'm1': 100.0, 'k1': 0.5},
    'load': {'model': 'constant', 'torque': 20.0},
    'initial': {'speed_rad_s': 80.0},
    'driveline': [
        {'type': 'inertia', 'name': 'engine_crank', 'J': 0.2},
        {'type': 'clutch', 'name': 'clutch', 'J_input': 0.05, 'J_output': 0.01,
         'mu_static': 0.35, 'mu_kinetic': 0.3, 'cgeo_m': 0.2, 'normal_force_max': 4000.0},
        {'type': 'spring', 'name': 'damper', 'stiffness': 1200.0, 'damping': 1.0},
        {'type': 'inertia', 'name': 'input_shaft', 'J': 0.01},
        {'type': 'gearbox', 'name': 'gearbox', 'J_input': 0.005, 'J_output': 0.02,
         'ratios': [12.0, 7.0], 'reverse_ratio': -11.0, 'max_input_rpm': 6000.0},
        {'type': 'inertia', 'name': 'wheel', 'J': 50.0},
        {'type': 'brake', 'name': 'brake', 'mu_static': 0.5, 'mu_kinetic': 0.4, 'cgeo_m': 0.5,
         'normal_force_max': 20000.0},
    ],
    'commands': [{'t': 0.0, 'clutch': 1.0, 'gear': 1, 'brake': 1.0},
                 {'t': 0.1, 'brake': 0.0, 'clutch': 0.0, 'throttle': 1.0}],
}


def test_parse_and_round_trip() -> None:
    sc = parse_scene(copy.deepcopy(BASE))
    assert sc.has_modes
    cl, gb, br = sc.driveline[1], sc.driveline[4], sc.driveline[6]
    assert isinstance(cl, Clutch) and cl.pack.kinetic(1.0) == pytest.approx(240.0)
    assert isinstance(gb, Gearbox) and gb.ratios == (12.0, 7.0)
    assert gb.max_input_speed == pytest.approx(6000.0 * 3.141592653589793 / 30.0)
    assert isinstance(br, Brake)
    assert sc.commands[0] == {'t': 0.0, 'clutch': 1.0, 'gear': 1, 'brake': 1.0}
    again = parse_scene(sc.to_dict())
    assert again == sc
    assert not parse_scene({**copy.deepcopy(BASE), 'driveline': BASE['driveline'][:1]
                            + [BASE['driveline'][5]], 'commands': None}).has_modes


def _with(path: list, value: Any) -> dict:
    d = copy.deepcopy(BASE)
    node = d
    for k in path[:-1]:
        node = node[k]
    if value is KeyError:
        del node[path[-1]]
    else:
        node[path[-1]] = value
    return d


@pytest.mark.parametrize('path, value, field', [
    (['driveline', 1, 'mu_static'], 0.2, 'driveline[1].mu_static'),
    (['driveline', 1, 'J_output'], 0.0, 'driveline[1].J_output'),
    (['driveline', 1, 'cgeo_m'], KeyError, 'driveline[1].cgeo_m'),
    (['driveline', 1, 'colour'], 'red', 'driveline[1].colour'),
    (['driveline', 4, 'ratios'], [], 'driveline[4].ratios'),
    (['driveline', 4, 'ratios'], [3.0, -1.0], 'driveline[4].ratios[1]'),
    (['driveline', 4, 'reverse_ratio'], 3.0, 'driveline[4].reverse_ratio'),
    (['driveline', 4, 'max_input_rpm'], float('nan'), 'driveline[4].max_input_rpm'),
    (['driveline', 6, 'normal_force_max'], -1.0, 'driveline[6].normal_force_max'),
    (['commands', 1, 'clutch'], 2.0, 'commands[1].clutch'),
    (['commands', 1, 'gear'], 3, 'commands[1].gear'),
    (['commands', 1, 't'], KeyError, 'commands[1].t'),
    (['commands', 1, 'steer'], 0.1, 'commands[1].steer'),
    (['commands'], {'t': 0}, 'commands'),
    (['solver'], {'method': 'rk4', 'h': 1e-4}, 'solver.method'),
])
def test_bad_fields_are_named(path: list, value: Any, field: str) -> None:
    with pytest.raises(SceneError) as exc:
        parse_scene(_with(path, value))
    assert exc.value.field == field, str(exc.value)
    assert '\n' not in str(exc.value)


def test_layout_rules_name_the_element() -> None:
    d = copy.deepcopy(BASE)
    d['driveline'].insert(3, d['driveline'].pop(6))        # brake in the middle
    with pytest.raises(SceneError) as exc:
        parse_scene(d)
    assert exc.value.field == 'driveline[3].type'
    d = copy.deepcopy(BASE)
    d['driveline'].insert(5, {**d['driveline'][4], 'name': 'gearbox2'})
    with pytest.raises(SceneError) as exc:
        parse_scene(d)
    assert exc.value.field == 'driveline[5].type'
    d = copy.deepcopy(BASE)
    d['driveline'] = d['driveline'][:4] + [d['driveline'][5]]   # no gearbox, yet gear commands
    with pytest.raises(SceneError) as exc:
        parse_scene(d)
    assert exc.value.field == 'commands[0].gear'


def test_other_paths_refuse_a_mode_scene_in_one_line(tmp_path) -> None:
    """Driveline (compiled kernel, sweeps) refuses a scene with mode elements naming the
    element; the ROS run's preparation takes it with --scheme zoh only, before anything
    starts."""
    import yaml

    from cvj_ros.orchestrate.options import RunOptions, prepare
    from cvj_ros.physics.driveline import Driveline
    sc = parse_scene(copy.deepcopy(BASE))
    with pytest.raises(SceneError) as exc:
        Driveline.from_scene(sc)
    assert exc.value.field == 'driveline[1]' and 'cvj-sim simulate' in str(exc.value)
    path = tmp_path / 'modes.yaml'
    path.write_text(yaml.safe_dump(BASE))
    with pytest.raises(CvjError) as exc2:
        prepare(RunOptions(scene=str(path), out=tmp_path / 'run', scheme='extrapolate'))
    assert str(exc2.value).startswith('--scheme: a scene with clutch, gearbox, brake or commands '
                                      'runs with zoh')
    assert not (tmp_path / 'run').exists()
    assert 'driver_node' in prepare(RunOptions(scene=str(path), out=tmp_path / 'run')).nodes


def test_fuzzed_mode_keys_give_a_scene_or_a_field_error() -> None:
    """300 seeded mutations of the mode keys: each parses to a scene whose chain builds, or
    stops with a SceneError whose field starts with driveline, commands or solver."""
    weird: list[Any] = [float('nan'), -1.0, 0, 1e308, True, None, 'x', [], {}, [1, 'a'], 2.5, -1]
    rng = random.Random(31)
    rejected = 0
    for _ in range(300):
        d = copy.deepcopy(BASE)
        target = rng.choice([d['driveline'][1], d['driveline'][4], d['driveline'][6],
                             rng.choice(d['commands'])])
        key = rng.choice(list(target))
        if rng.random() < 0.2:
            del target[key]
        else:
            target[key] = copy.deepcopy(rng.choice(weird))
        try:
            sc = parse_scene(d)
        except SceneError as exc:
            rejected += 1
            assert exc.field.startswith(('driveline', 'commands', 'solver')), str(exc)
            continue
        from cvj_ros.physics.hybrid import HybridChain
        HybridChain(sc.driveline)
    assert rejected > 150


def test_documented_examples_parse_and_run() -> None:
    """docs/clutch_gearbox.md: the scene-keys block parses (with a name, duration, load) and the
    Python example runs to the events its comment states."""
    import re
    from pathlib import Path

    import yaml
    doc = (Path(__file__).resolve().parents[3] / 'docs' / 'clutch_gearbox.md').read_text()
    block = re.search(r'## Scene keys\n\n```yaml\n(.*?)```', doc, flags=re.S).group(1)
    data = yaml.safe_load(block)
    data.update(name='doc', duration=4.0, load={'model': 'road', 'mass': 1500.0,
                                                'wheel_radius': 0.3, 'grade_percent': 10.0})
    sc = parse_scene(data, source='docs/clutch_gearbox.md')
    assert sc.has_modes and len(sc.commands) == 4
    code = re.search(r'## Python\n\n```python\n(.*?)```', doc, flags=re.S).group(1)
    ns: dict[str, Any] = {}
    exec(compile(code, 'docs/clutch_gearbox.md', 'exec'), ns)      # noqa: S102
    r = ns['r']
    got = [(e.element, e.after, round(e.t, 2)) for e in r.events]
    assert got == [('brake', 'stuck', 0.0), ('brake', 'slip+', 1.81), ('clutch', 'stuck', 2.64)]
