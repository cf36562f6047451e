"""`cvj-sim fit` through the CLI entry point: JSON output, plot, bad input in one line."""
from __future__ import annotations

import json

import pytest

from cvj_ros.cli import main


def test_fit_shipped_table_json_and_plot(tmp_path, capsys):
    png = tmp_path / 'fit.png'
    argv = ['fit', 'kavz685_lever', '--data', 'davidbaev2023/4.3', '--shaft', 'drive_shaft',
            '--fit', 'load.mean=150:300', '--orders', '2', '--duration', '1.0',
            '--plot', str(png), '--json']
    assert main(argv) == 0
    out = json.loads(capsys.readouterr().out)
    assert set(out['fitted']) == {'load.mean'}
    # the mean torque follows the mean load: the measured 215.8 N m within 1 %
    assert out['fitted']['load.mean'] == pytest.approx(215.8, rel=0.01)
    assert [o['order'] for o in out['orders']] == [0, 1, 2]
    assert png.stat().st_size > 0
    assert main(argv) == 0      # deterministic: the same inputs give the same bytes
    assert json.loads(capsys.readouterr().out) == out


def test_fit_text_report(tmp_path, capsys):
    assert main(['fit', 'kavz685_lever', '--data', 'davidbaev2023/4.2', '--fit',
                 'load.mean=150:300', '--orders', '1', '--duration', '1.0',
                 '--plot', 'none']) == 0
    out = capsys.readouterr().out
    assert 'load.mean' in out and '(95 %)' in out and 'residual' in out


@pytest.mark.parametrize('args, msg', [
    ([], '--fit: give at least one'),
    (['--fit', 'load.nothing=1:2'], 'load.nothing'),
    (['--fit', 'load.mean=3'], 'expected a range LO:HI'),
    (['--fit', 'load.mean=1:2', '--fit', 'load.mean=3:4'], 'already fitted'),
    (['--fit', 'driveline[nosuch].stiffness=1:2'], "no element named 'nosuch'"),
    (['--fit', 'load.mean=100:200', '--data', 'davidbaev2023/9.9'], 'no such shipped table'),
    (['--fit', 'load.mean=100:200', '--orders', '0'], '--orders'),
])
def test_bad_input_one_line(capsys, args, msg):
    argv = ['fit', 'kavz685_lever', '--data', 'davidbaev2023/4.2', '--plot', 'none'] + args
    if '--data' in args:
        argv = ['fit', 'kavz685_lever', '--plot', 'none'] + args
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith('cvj-sim: error:') and msg in err


def test_bad_data_file_one_line(tmp_path, capsys):
    p = tmp_path / 'bad.csv'
    p.write_bytes(b'\x00\xff\xfe garbage')
    assert main(['fit', 'kavz685_lever', '--data', str(p), '--fit', 'load.mean=100:200',
                 '--plot', 'none']) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(p) in err


def test_fit_orders_subset(capsys):
    assert main(['fit', 'kavz685_lever', '--data', 'davidbaev2023/4.2', '--fit',
                 'load.mean=150:300', '--orders', '2', '--fit-orders', '0,2', '--duration', '1.0',
                 '--plot', 'none', '--json']) == 0
    out = json.loads(capsys.readouterr().out)
    assert [o['used'] for o in out['orders']] == [True, False, True]
    assert main(['fit', 'kavz685_lever', '--data', 'davidbaev2023/4.2', '--fit',
                 'load.mean=150:300', '--orders', '2', '--fit-orders', '0,3', '--plot', 'none']) == 2
    assert '--fit-orders' in capsys.readouterr().err


def test_fit_recovers_a_stiffness_from_a_recorded_bag(tmp_path, capsys):
    # a bag of the KAVZ-685 unit (random load, seed 685) with 900 N m/rad bushings; the fit
    # analyses the model over the bag's own window, so at the truth the residuals vanish
    import yaml

    from cvj_ros.commands.sweep import load_scene_data
    from cvj_ros.physics.scene import find_scene
    scene = load_scene_data(find_scene('kavz685_lever'))
    scene['driveline'][1]['stiffness'] = 900.0
    scene['duration'] = 1.5
    path = tmp_path / 'unit.yaml'
    path.write_text(yaml.safe_dump(scene))
    bag = tmp_path / 'bag'
    assert main(['simulate', str(path), '--bag', str(bag)]) == 0
    capsys.readouterr()
    assert main(['fit', 'kavz685_lever', '--duration', '1.5', '--data', str(bag), '--skip', '0.75',
                 '--fit', 'driveline[bushings].stiffness=400:1600', '--plot', 'none',
                 '--json']) == 0
    out = json.loads(capsys.readouterr().out)
    assert out['fitted']['driveline[bushings].stiffness'] == pytest.approx(900.0, abs=0.5)
    assert out['rms_residual'] < 1e-3
