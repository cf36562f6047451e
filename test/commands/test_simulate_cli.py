"""`cvj-sim simulate` and `cvj-sim scenes` through the CLI entry point."""
from __future__ import annotations

import json

import numpy as np
import pytest

from cvj_ros.cli import main


def test_scenes_lists_shipped(capsys) -> None:
    assert main(['scenes']) == 0
    out = capsys.readouterr().out
    for name in ('kavz685_lever', 'fwd_halfshaft', 'cardan_truck', 'tripod_xiu2024', 'stiff'):
        assert name in out


def test_simulate_text_summary(capsys) -> None:
    assert main(['simulate', 'kavz685_lever', '--duration', '0.3']) == 0
    out = capsys.readouterr().out
    assert 'drive_shaft' in out and 'energy balance residual' in out
    assert 'per simulated s' in out and 'fidelity' in out


def test_first_run_summary_says_the_compile_is_in_its_wall_time(capsys, monkeypatch) -> None:
    """On a cold cache the kernel compiles inside the run's wall time (131.5 s of 131.54 s in
    a fresh clone): the first line says how much of it was the compile."""
    from cvj_ros.physics.simulate import Simulation
    finish = Simulation._finish

    def cold(self, *args, **kwargs):
        trace = finish(self, *args, **kwargs)
        self.compile_seconds = 12.34
        return trace
    monkeypatch.setattr(Simulation, '_finish', cold)
    assert main(['simulate', 'kavz685_lever', '--duration', '0.05']) == 0
    first = capsys.readouterr().out.splitlines()[0]
    assert first.endswith('s per simulated s), including 12.3 s compiling the kernel (first run)'), first


def test_simulate_json_and_csv(tmp_path, capsys) -> None:
    csv = tmp_path / 'run.csv'
    assert main(['simulate', 'stiff', '--duration', '0.1', '--json', '--csv', str(csv),
                 '--method', 'rosenbrock', '--rtol', '1e-7', '--dense']) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary['solver']['method'] == 'rosenbrock'
    assert summary['solver']['rtol'] == 1e-7
    assert set(summary['shafts']) == {'drive', 'driven'}
    data = np.loadtxt(csv, delimiter=',', skiprows=1)
    header = csv.read_text().splitlines()[0].split(',')
    assert header[0] == 't_s' and 'driven_velocity_rad_s' in header
    assert data[-1, 0] == 0.1


@pytest.mark.parametrize('method', ['rodas4', 'rodas3'])
def test_simulate_takes_every_offline_solver(method, capsys) -> None:
    """--method takes every solver Simulation runs (solvers.METHODS), the loose-tolerance
    RODAS methods included (their --help names them); a name outside is one line, exit 2."""
    from cvj_ros.physics.scene import OFFLINE_METHODS
    from cvj_ros.physics.solvers import METHODS
    assert set(OFFLINE_METHODS) == set(METHODS)
    assert main(['simulate', 'stiff', '--duration', '0.1', '--json', '--method', method,
                 '--rtol', '1e-3']) == 0
    assert json.loads(capsys.readouterr().out)['solver']['method'] == method
    assert main(['simulate', 'stiff', '--method', 'nope']) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith('cvj-sim: error: --method: must be one of')
    assert 'rodas3' in err[0]


def test_simulate_fidelity_override(capsys) -> None:
    assert main(['simulate', 'fwd_halfshaft', '--duration', '0.05', '--json',
                 '--fidelity', 'tripod=exact', 'midshaft_twist=rigid']) == 0
    levels = {c['name']: c['chosen'] for c in json.loads(capsys.readouterr().out)['fidelity']['choices']}
    assert levels['tripod'] == 'exact' and levels['midshaft_twist'] == 'rigid'


def test_user_errors_one_line_exit_2(tmp_path, capsys) -> None:
    assert main(['simulate', 'stif']) == 2
    assert capsys.readouterr().err.startswith("cvj-sim: error: scene: no scene file or shipped scene 'stif'")
    assert main(['simulate', 'stiff', '--fidelity', 'stiff_spring=soft']) == 2
    assert 'fidelity.stiff_spring: must be one of' in capsys.readouterr().err
    assert main(['simulate', 'stiff', '--fidelity', 'oops']) == 2
    assert 'expected NAME=LEVEL' in capsys.readouterr().err
    bad = tmp_path / 'bad.yaml'
    bad.write_text('name: b\nduration: 1\nengine: {model: linear}\nload: {model: constant}\n'
                   'driveline:\n  - {type: inertia, name: a, J: 1}\n'
                   '  - {type: joint, name: h, kind: hooke, params: {beta_deg: 95}}\n'
                   '  - {type: inertia, name: b, J: 1}\n')
    assert main(['simulate', str(bad)]) == 2
    err = capsys.readouterr().err
    assert err.startswith('cvj-sim: error: driveline[1].params.beta_deg:') and 'Traceback' not in err
    assert main(['simulate', 'stiff', '--duration', '-1']) == 2


def test_simulate_bag_is_read_by_analyze_with_the_same_window(tmp_path, capsys) -> None:
    """--bag writes the trace; analyze prints the same window line; an existing bag
    without --overwrite is one error line, exit 2."""
    bag = tmp_path / 'bag'
    assert main(['simulate', 'tripod_xiu2024', '--duration', '0.3', '--bag', str(bag)]) == 0
    cap = capsys.readouterr()
    window = next(line for line in cap.out.splitlines() if line.startswith('steady window '))
    assert 'wrote 301 samples to bag' in cap.err
    assert main(['analyze', str(bag)]) == 0
    out = capsys.readouterr().out
    assert '  ' + window[len('steady window '):] in out.splitlines()
    assert main(['simulate', 'tripod_xiu2024', '--duration', '0.3', '--bag', str(bag)]) == 2
    err = capsys.readouterr().err
    assert err.startswith('cvj-sim: error: ') and 'Traceback' not in err and err.count('\n') == 1
    assert main(['simulate', 'tripod_xiu2024', '--duration', '0.3', '--bag', str(bag), '--overwrite']) == 0


def test_simulate_says_what_makes_a_run_degenerate(tmp_path, capsys) -> None:
    """One line each: a joint beyond its angle limit (as the ROS monitor), a sample step
    too coarse for the fastest mode; a sound run has none."""
    import yaml
    scene = {'name': 'degenerate', 'duration': 0.2, 'exchange_step': 1e-3,
             'engine': {'model': 'linear'}, 'load': {'model': 'constant', 'torque': 50.0},
             'initial': {'speed_rpm': 300.0},
             'driveline': [{'type': 'inertia', 'name': 'a', 'J': 0.128},
                           {'type': 'spring', 'name': 's', 'stiffness': 715.4, 'damping': 6.35},
                           {'type': 'joint', 'name': 'tj', 'kind': 'tripod', 'params': {'beta_deg': 40.0}},
                           {'type': 'inertia', 'name': 'b', 'J': 0.161}]}
    path = tmp_path / 'degenerate.yaml'
    path.write_text(yaml.safe_dump(scene))
    assert main(['simulate', str(path), '--sample-dt', '0.05', '--json']) == 0
    notes = json.loads(capsys.readouterr().out)['notes']
    assert notes[0] == ('limit exceeded: joint tj bent 40 deg, above the recommended limit for a '
                        'tripod joint 25 deg')
    assert notes[1].startswith("sample step 0.05 s is too coarse for the scene's fastest mode")
    # (0.2 s of a start-up: the speeds still fall, which is named too)
    assert all(n.startswith('speed trend: ') for n in notes[2:]) and len(notes) <= 3
    assert main(['simulate', 'kavz685_lever', '--duration', '2']) == 0   # steady by then
    assert 'note:' not in capsys.readouterr().out
