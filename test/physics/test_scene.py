"""Scene format: parsing, SI conversion, round trip, validation errors naming the field."""
from __future__ import annotations

import copy
import math

import pytest

from cvj_ros.errors import SceneError
from cvj_ros.physics.scene import Inertia, Joint, Spring, find_scene, load_scene, parse_scene

BASE = {
    'name': 'two_mass', 'description': 'test', 'seed': 3, 'duration': 1.0, 'exchange_step': 1e-3,
    'solver': {'method': 'dopri5', 'rtol': 1e-7, 'atol': 1e-9},
    'engine': {'model': 'linear'}, 'load': {'model': 'constant', 'torque': 100.0},
    'initial': {'speed_rpm': 300.0},
    'driveline': [
        {'type': 'inertia', 'name': 'crank', 'J': 0.128},
        {'type': 'spring', 'name': 'bush', 'stiffness': 715.4, 'damping': 6.35,
         'law': 'progressive', 'k2': 2.0, 'backlash_deg': 1.0},
        {'type': 'joint', 'name': 'cpl', 'kind': 'hooke', 'fidelity': 'exact',
         'params': {'beta_deg': 15.0}, 'limits': {'max_angle_deg': 25.0}},
        {'type': 'inertia', 'name': 'driven', 'J': 0.161},
    ],
}


def scene_with(path: str, value: object) -> dict:
    """Copy of BASE with the dotted/indexed ``path`` set to ``value``."""
    d = copy.deepcopy(BASE)
    node = d
    parts = path.replace('[', '.').replace(']', '').split('.')
    for p in parts[:-1]:
        node = node[int(p)] if p.isdigit() else node[p]
    last = parts[-1]
    node[int(last) if last.isdigit() else last] = value
    return d


def test_parse_converts_units_to_si() -> None:
    sc = parse_scene(BASE)
    assert sc.initial_speed == pytest.approx(300.0 * math.pi / 30.0)
    crank, bush, cpl, driven = sc.driveline
    assert isinstance(crank, Inertia) and isinstance(bush, Spring) and isinstance(cpl, Joint)
    assert cpl.params['beta'] == pytest.approx(math.radians(15.0))
    assert bush.backlash == pytest.approx(math.radians(1.0))
    assert cpl.limits == {'max_angle_deg': 25.0}
    assert driven.J == 0.161


def test_round_trip_to_dict() -> None:
    sc = parse_scene(BASE)
    again = parse_scene(sc.to_dict())
    assert again == sc
    assert parse_scene(__import__('yaml').safe_load(sc.to_yaml())) == sc


def test_scene_is_frozen() -> None:
    sc = parse_scene(BASE)
    with pytest.raises(Exception):
        sc.duration = 3.0  # type: ignore[misc]


@pytest.mark.parametrize('path,value,field,words', [
    ('driveline[2].params.beta_deg', 95.0, 'driveline[2].params.beta_deg', '< 90'),
    ('driveline[2].params.beta_deg', 90.0, 'driveline[2].params.beta_deg', '< 90'),
    ('driveline[0].J', -1.0, 'driveline[0].J', 'must be > 0'),
    ('driveline[0].J', 0.0, 'driveline[0].J', 'must be > 0'),
    ('driveline[1].stiffness', 0.0, 'driveline[1].stiffness', 'must be > 0'),
    ('driveline[1].damping', float('nan'), 'driveline[1].damping', 'finite'),
    ('driveline[3].J', float('inf'), 'driveline[3].J', 'finite'),
    ('driveline[2].kind', 'hoke', 'driveline[2].kind', "did you mean 'hooke'"),
    ('driveline[0].J', 'heavy', 'driveline[0].J', 'must be a number'),
    ('duration', -2.0, 'duration', 'must be > 0'),
    ('solver.method', 'rk45', 'solver.method', 'must be one of'),
    ('driveline[1].law', 'cubic', 'driveline[1].law', 'must be one of'),
    ('driveline[2].fidelity', 'closed', 'driveline[2].fidelity', 'hooke has fidelities'),
    ('driveline[2].params.beta_dge', 10.0, 'driveline[2].params.beta_dge', "did you mean 'beta_deg'"),
    ('driveline[2].limits.max_angle_deg', -3.0, 'driveline[2].limits.max_angle_deg', '> 0'),
    ('seed', 1.5, 'seed', 'non-negative integer'),
    ('engine.m1', float('nan'), 'engine.m1', ''),
    ('load.torqe', 1.0, 'load.torqe', ''),
])
def test_validation_names_field(path: str, value: object, field: str, words: str) -> None:
    with pytest.raises(SceneError) as err:
        parse_scene(scene_with(path, value))
    assert str(err.value).startswith(field + ':'), str(err.value)
    assert words in str(err.value)


def test_unknown_top_level_key_did_you_mean() -> None:
    d = copy.deepcopy(BASE)
    d['duraton'] = 3.0
    with pytest.raises(SceneError, match=r"^duraton: unknown key; did you mean 'duration'"):
        parse_scene(d)


def test_unknown_element_key() -> None:
    d = scene_with('driveline[1].stifness', 3.0)
    with pytest.raises(SceneError, match=r"^driveline\[1\]\.stifness: unknown key; did you mean 'stiffness'"):
        parse_scene(d)


def test_layout_errors() -> None:
    d = copy.deepcopy(BASE)
    d['driveline'] = d['driveline'][1:]
    with pytest.raises(SceneError, match=r'^driveline\[0\]\.type: the first element must be an inertia'):
        parse_scene(d)
    d = copy.deepcopy(BASE)
    d['driveline'].insert(2, {'type': 'spring', 'name': 's2', 'stiffness': 1.0})
    with pytest.raises(SceneError, match=r'^driveline\[2\]: no inertia between'):
        parse_scene(d)
    d = copy.deepcopy(BASE)
    d['driveline'][3]['name'] = 'crank'
    with pytest.raises(SceneError, match=r'^driveline\[3\]\.name: duplicate'):
        parse_scene(d)


def test_malformed_yaml_names_line(tmp_path) -> None:
    p = tmp_path / 'bad.yaml'
    p.write_text('name: x\nduration: 1\ndriveline: [\n  {type: inertia\n')
    with pytest.raises(SceneError) as err:
        load_scene(p)
    assert str(err.value).startswith(f'{p}:'), str(err.value)
    assert 'malformed YAML' in str(err.value)


def test_find_scene_by_path_and_name(tmp_path) -> None:
    p = tmp_path / 'mine.yaml'
    p.write_text('name: x\n')
    assert find_scene(str(p)) == p
    with pytest.raises(SceneError, match='^scene: no scene file'):
        find_scene('definitely_not_a_scene')


def test_deprecated_scene_name_finds_the_renamed_scene_with_one_line(capsys) -> None:
    """tripod_seed000 (a label) was renamed tripod_xiu2024 (its source paper); the old name
    still resolves to the same file and says so in one line on stderr."""
    from cvj_ros.physics.scene import DEPRECATED_SCENES, shipped_scenes
    assert DEPRECATED_SCENES['tripod_seed000'] == 'tripod_xiu2024'
    assert 'tripod_seed000' not in shipped_scenes()
    new = find_scene('tripod_xiu2024')
    assert capsys.readouterr().err == ''
    assert find_scene('tripod_seed000') == new
    assert find_scene('tripod_seed000.yaml') == new
    err = capsys.readouterr().err.splitlines()
    assert err == ["cvj_ros: scene name 'tripod_seed000' is deprecated; it is now 'tripod_xiu2024'"] * 2
    assert load_scene(new).name == 'tripod_xiu2024'


def test_documented_example_is_a_valid_scene() -> None:
    """The annotated example in docs/scenes.md parses (keeps the documentation honest)."""
    import pathlib

    import yaml
    doc = (pathlib.Path(__file__).resolve().parents[2] / 'docs' / 'scenes.md').read_text()
    block = doc.split('```yaml\n', 1)[1].split('```', 1)[0]
    sc = parse_scene(yaml.safe_load(block), source='docs/scenes.md')
    assert [el.type for el in sc.driveline] == ['inertia', 'spring', 'joint', 'inertia']
    assert sc.accuracy_target == 0.01


def test_summed_load_list_round_trip() -> None:
    d = copy.deepcopy(BASE)
    d['load'] = [{'model': 'constant', 'torque': 50.0}, {'model': 'random', 'mean': 0.0, 'amplitude': 5.0}]
    sc = parse_scene(d)
    assert isinstance(sc.load, list) and len(sc.load) == 2
    assert parse_scene(sc.to_dict()) == sc
    d['load'][1]['amplitud'] = 1.0
    with pytest.raises(SceneError, match=r'^load\[1\]\.amplitud'):
        parse_scene(d)


def _propshaft(second: dict, *, between: list | None = None) -> dict:
    """BASE with a second Hooke joint after the first, only shafts between them."""
    d = copy.deepcopy(BASE)
    mid = [{'type': 'inertia', 'name': 'centre', 'J': 0.02}] if between is None else between
    d['driveline'][3:3] = mid + [dict({'type': 'joint', 'name': 'rear', 'kind': 'hooke'}, **second)]
    return d


def test_two_hooke_joints_without_a_phase_name_phase_deg() -> None:
    """A second Hooke joint behind the first with only shafts between must state its yoke
    phase: the error names the field path and the first joint."""
    with pytest.raises(SceneError, match=r'^driveline\[4\]\.params\.phase_deg: missing: .*'
                                         r'driveline\[2\]') as info:
        parse_scene(_propshaft({'params': {'beta_deg': 15.0}}))
    assert info.value.field == 'driveline[4].params.phase_deg'
    # springs and inertias between (a centre bearing, an elastic tube) do not break the pair
    tube = [{'type': 'inertia', 'name': 'tube_front', 'J': 0.02},
            {'type': 'spring', 'name': 'tube', 'stiffness': 2e4},
            {'type': 'inertia', 'name': 'tube_rear', 'J': 0.02}]
    with pytest.raises(SceneError, match=r'^driveline\[6\]\.params\.phase_deg: missing'):
        parse_scene(_propshaft({'params': {'beta_deg': 15.0}, 'fidelity': 'ideal'}, between=tube))


def test_stated_phase_or_a_joint_between_is_accepted() -> None:
    sc = parse_scene(_propshaft({'params': {'beta_deg': 15.0, 'phase_deg': 90.0}}))
    assert sc.element('rear').params['phase'] == pytest.approx(math.pi / 2)
    assert sc.element('rear').params_file == {'beta_deg': 15.0, 'phase_deg': 90.0}
    assert parse_scene(sc.to_dict()) == sc
    parse_scene(_propshaft({'params': {'beta_deg': 15.0, 'phase_rad': 0.0}}))
    gear = [{'type': 'inertia', 'name': 'centre', 'J': 0.02},
            {'type': 'joint', 'name': 'box', 'kind': 'gear', 'params': {'gear_ratio': 2.0}},
            {'type': 'inertia', 'name': 'centre2', 'J': 0.02}]
    parse_scene(_propshaft({'params': {'beta_deg': 15.0}}, between=gear))


def test_two_hooke_stages_of_a_chain_joint_need_a_phase() -> None:
    d = copy.deepcopy(BASE)
    d['driveline'][2] = {'type': 'joint', 'name': 'shaft', 'kind': 'chain',
                         'params': {'joints': [{'kind': 'hooke', 'beta': 0.2},
                                               {'kind': 'hooke', 'beta': 0.2}]}}
    with pytest.raises(SceneError, match=r'^driveline\[2\]\.params\.joints\[1\]\.phase: missing'):
        parse_scene(d)
    d['driveline'][2]['params']['joints'][1]['phase'] = math.pi / 2
    parse_scene(d)


@pytest.mark.parametrize('key, value, words', [
    ('cross_angle_deg', 10.0, 'locks'), ('phase_deg', 400.0, 'out of range'),
    ('bend_plane_deg', float('nan'), 'finite')])
def test_hooke_phase_parameters_validated(key: str, value: float, words: str) -> None:
    with pytest.raises(SceneError, match=rf'^driveline\[2\]\.params\.{key}: .*{words}'):
        parse_scene(scene_with(f'driveline[2].params.{key}', value))


def test_scene_dirs_finds_an_installed_share_directory(tmp_path, monkeypatch) -> None:
    """The ament resource index marks the package's prefix (ament_index_python's lookup,
    read without importing it); a prefix without the marker is not searched."""
    from cvj_ros.physics.scene import scene_dirs
    marked, other = tmp_path / 'marked', tmp_path / 'other'
    for prefix in (marked, other):
        (prefix / 'share' / 'cvj_ros' / 'config' / 'scenes').mkdir(parents=True)
    index = marked / 'share' / 'ament_index' / 'resource_index' / 'packages'
    index.mkdir(parents=True)
    (index / 'cvj_ros').write_text('')
    monkeypatch.setenv('AMENT_PREFIX_PATH', f'{other}:{marked}')
    dirs = scene_dirs()
    assert marked / 'share' / 'cvj_ros' / 'config' / 'scenes' in dirs
    assert other / 'share' / 'cvj_ros' / 'config' / 'scenes' not in dirs
