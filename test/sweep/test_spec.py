"""Sweep definitions: --set parsing, field paths (names for indices), expansion order,
seeded random sampling, and spec errors naming the --set and the field (no simulation)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from cvj_ros.commands.sweep import load_scene_data
from cvj_ros.physics.scene import find_scene, parse_scene
from cvj_ros.sweep.spec import SweepError, build_sweep, parse_path, parse_spec, parse_value


@pytest.fixture(scope='module')
def lever() -> dict:
    return load_scene_data(find_scene('kavz685_lever'))


def test_values_and_specs() -> None:
    assert parse_value('3') == 3 and isinstance(parse_value('3'), int)
    assert parse_value('1e-6') == 1e-6          # YAML 1.1 would read a string
    assert parse_value('dopri5') == 'dopri5'
    assert parse_spec('5:25:5', 'w', random=False) == ((5.0, 10.0, 15.0, 20.0, 25.0), None, False)
    vals, rng, log = parse_spec('1:100:3:log', 'w', random=False)
    assert vals == pytest.approx((1.0, 10.0, 100.0), rel=1e-15) and log and rng is None
    assert parse_spec('a,b', 'w', random=False) == (('a', 'b'), None, False)
    assert parse_spec('7', 'w', random=False) == ((7,), None, False)
    assert parse_spec('1:2', 'w', random=True) == ((), (1.0, 2.0), False)


@pytest.mark.parametrize('spec, needle', [
    ('1:2', 'needs --samples'), ('1:2:0', 'n must be an integer >= 1'), ('1:2:x', 'n must be'),
    ('a:2:3', 'expected a finite number'), ('1:2:3:4', 'expected start:stop:n'),
    ('1,,2', 'empty item'), ('', 'empty value'), ('0:1:3:log', 'log grid needs'),
    ('inf', 'not finite')])
def test_bad_specs(spec: str, needle: str) -> None:
    with pytest.raises(SweepError, match=needle) as exc:
        parse_spec(spec, '--set x', random=False)
    assert str(exc.value).startswith('--set x: ')


def test_paths(lever: dict) -> None:
    assert parse_path('driveline[coupling].params.alpha_deg', 'w') == [
        'driveline', ('coupling',), 'params', 'alpha_deg']
    sw = build_sweep(lever, ['driveline[coupling].params.alpha_deg=10,20',
                             'driveline[1].stiffness=500:700:3'])
    assert [a.field for a in sw.axes] == ['driveline[2].params.alpha_deg', 'driveline[1].stiffness']
    # first --set varies slowest (nested loops in the order given)
    assert sw.variants == ((10, 500.0), (10, 600.0), (10, 700.0), (20, 500.0), (20, 600.0),
                           (20, 700.0))
    d = sw.scene_dict(4)
    assert d['driveline'][2]['params']['alpha_deg'] == 20 and d['driveline'][1]['stiffness'] == 600.0
    assert lever['driveline'][1]['stiffness'] == 715.4     # the base is not modified
    # a key the scene does not write yet but the format has (solver.max_step) is fine
    sw2 = build_sweep(lever, ['solver.max_step=0.01', 'initial.speed_rad_s=30:50:3'])
    assert parse_scene(sw2.scene_dict(2)).solver.max_step == 0.01


@pytest.mark.parametrize('sets, needle', [
    (['driveline[nope].J=1'], "--set driveline[nope].J: driveline has no element named 'nope'"),
    (['driveline[7].J=1'], '--set driveline[7].J: driveline[7] out of range'),
    (['driveline[coupling].params.alpha=1'],
     "--set driveline[coupling].params.alpha: driveline[2].params.alpha: unknown parameter; "
     "did you mean 'alpha_deg'?"),   # a bare angle: the degree form first
    (['driveline[0].mass=1'], '--set driveline[0].mass: driveline[0].mass: unknown key'),
    (['initial.speed_rad_s'], 'expected PATH=SPEC'),
    (['initial..speed=1'], 'empty key'),
    (['engine[0]=1'], 'engine is not a list'),
    (['initial.speed_rad_s=1', 'initial.speed_rad_s=2'], 'already set'),
    (['driveline[bushings].stiffness=1', 'driveline[1].stiffness=2'],
     'driveline[1].stiffness is already set by --set driveline[bushings].stiffness'),
    ([], 'give at least one'),
    (['initial.speed_rpm=300:600:4'], '--set initial.speed_rpm: every value tried (300.0, 600.0) makes '
     'the scene invalid: initial.speed_rpm: give either speed_rad_s or speed_rpm, not both'),
    (['driveline[coupling].params.alpha_deg=95,120'], 'every value tried (95, 120)'),
])
def test_spec_errors_name_the_set_and_field(lever: dict, sets: list[str], needle: str) -> None:
    with pytest.raises(SweepError) as exc:
        build_sweep(lever, sets)
    assert needle in str(exc.value)
    assert '\n' not in str(exc.value)


def test_random_sampling_is_seeded_and_in_range(lever: dict) -> None:
    sets = ['driveline[bushings].stiffness=300:3000:log', 'initial.speed_rad_s=30:50',
            'solver.method=dopri5,dop853', 'engine.m1=623']
    a = build_sweep(lever, sets, samples=200, seed=7)
    b = build_sweep(lever, sets, samples=200, seed=7)
    c = build_sweep(lever, sets, samples=200, seed=8)
    assert a.variants == b.variants and a.variants != c.variants and len(a) == 200
    k = np.array([v[0] for v in a.variants])
    w = np.array([v[1] for v in a.variants])
    assert k.min() >= 300 and k.max() <= 3000 and w.min() >= 30 and w.max() <= 50
    # log-uniform: about half the draws below the geometric mean sqrt(300 * 3000) = 949;
    # binomial(200, 0.5) has sd 7.1, so 100 +- 40 is a 5.6-sigma band
    assert 60 < int(np.sum(k < math.sqrt(300 * 3000))) < 140
    assert {v[2] for v in a.variants} == {'dopri5', 'dop853'}
    assert {v[3] for v in a.variants} == {623}
    assert a.definition['seed'] == 7 and a.definition['samples'] == 200


def test_too_many_variants(lever: dict) -> None:
    with pytest.raises(SweepError, match='more than'):
        build_sweep(lever, ['initial.speed_rad_s=1:2:5000', 'engine.m1=1:2:5000'])


def test_readme_and_docs_examples_build() -> None:
    """The sweep commands shown in README.md, docs/sweeps.md and `cvj-sim sweep --help` parse
    and expand (no run)."""
    import re
    import shlex
    from pathlib import Path

    from cvj_ros.cli import build_parser
    from cvj_ros.commands.sweep import DESCRIPTION
    root = Path(__file__).resolve().parents[2]
    seen = 0
    for text in ((root / 'README.md').read_text(), (root / 'docs/sweeps.md').read_text(), DESCRIPTION):
        text = text.replace('\\\n', ' ')
        for line in re.findall(r'^\s*(cvj-sim sweep [^\n]+)$', text, flags=re.M):
            args = build_parser().parse_args(shlex.split(line)[1:])
            if args.replot:
                continue
            base = load_scene_data(find_scene(args.scene))
            sweep = build_sweep(base, args.sets, samples=args.samples, seed=args.seed)
            assert len(sweep) >= 2, line
            seen += 1
    assert seen >= 6
