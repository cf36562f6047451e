"""`cvj-sim sweep` of a scene with clutch, gearbox, brake and commands (launch_clutch_chain):
each variant runs the mode model on the compiled kernel (or, with backend 'python', its
Python reference), its row equal to that backend's offline result of the same variant."""
from __future__ import annotations

import copy
import csv
from pathlib import Path

import pytest

from cvj_ros.cli import main
from cvj_ros.physics.hybrid.from_scene import run_hybrid
from cvj_ros.physics.scene import find_scene, parse_scene
from cvj_ros.sweep.run import RunOptions, run_variant
from cvj_ros.textfile import load_yaml_bounded, read_text_file


def _base() -> dict:
    path = find_scene('launch_clutch_chain')
    data = load_yaml_bounded(read_text_file(path, what='scene file'), str(path))
    data['duration'] = 2.5        # brake hold, release at ~1.77 s, clutch slipping
    return data


def test_a_mode_variant_row_is_the_offline_kernel_run() -> None:
    from cvj_ros.physics.hybrid.from_scene import hybrid_simulation
    from cvj_ros.physics.kernel.modes import KernelHybridSimulation
    data = _base()
    data['initial'] = {'speed_rpm': 1000.0}
    row, _wall = run_variant(copy.deepcopy(data), RunOptions())
    assert row['status'] == 'ok' and row['error'] == '' and row['backend'] == 'kernel'
    r = KernelHybridSimulation.from_reference(hybrid_simulation(parse_scene(data))).run()
    for i, shaft in enumerate(r.shafts):
        assert row[f'{shaft}.final_speed'] == r.speed[-1, i]
    assert row['energy_residual'] == r.max_energy_residual
    assert row['brake.events'] == r.count('brake') == 2
    assert row['brake.final_mode'] == 'slip+' and row['gearbox.final_gear'] == 1


def test_a_mode_variant_row_is_the_offline_reference() -> None:
    data = _base()
    data['initial'] = {'speed_rpm': 1000.0}
    row, _wall = run_variant(copy.deepcopy(data), RunOptions(backend='python'))
    assert row['status'] == 'ok' and row['error'] == '' and row['backend'] == 'python'
    _sim, r, _w = run_hybrid(parse_scene(data))
    for i, shaft in enumerate(r.shafts):
        assert row[f'{shaft}.final_speed'] == r.speed[-1, i]
    assert row['energy_residual'] == r.max_energy_residual
    assert row['brake.events'] == r.count('brake') == 2
    assert row['brake.final_mode'] == 'slip+' and row['gearbox.final_gear'] == 1
    assert row['stall'] is False and row['t_end'] == 2.5


def test_cli_sweeps_a_mode_scene(tmp_path: Path) -> None:
    assert main(['sweep', 'launch_clutch_chain', '--set', 'duration=2.5',
                 '--set', 'initial.speed_rpm=800,1000', '--out', str(tmp_path / 's'),
                 '--workers', '1', '--no-plots']) == 0
    rows = list(csv.DictReader(open(tmp_path / 's' / 'results.csv')))
    assert [r['status'] for r in rows] == ['ok', 'ok']
    assert all(r['brake.final_mode'] == 'slip+' for r in rows)
    assert float(rows[0]['wheel.final_speed']) > 0.0


def test_an_invalid_mode_variant_names_its_field() -> None:
    """mu_static below mu_kinetic: the variant is invalid, named by its field, not a crash."""
    data = _base()
    data['driveline'][-1]['mu_static'] = 0.1
    row, _wall = run_variant(data, RunOptions())
    assert row['status'] == 'invalid' and row['error'].startswith('driveline[7]')


def test_cli_sweeps_a_vehicle_mode_scene(tmp_path: Path) -> None:
    """launch_clutch (a vehicle tree: clutch, gearbox, two wheel brakes, a shift schedule),
    2 variants of 2 s (brake hold and release at ~1.74 s, clutch slipping): one row per
    variant with columns per element, each the compiled kernel's result (equal to the
    offline reference within the kernel tests' bounds, test_tree_modes_kernel.py)."""
    assert main(['sweep', 'launch_clutch', '--set', 'duration=2.0',
                 '--set', 'vehicle.grade_percent=8,10', '--out', str(tmp_path / 's'),
                 '--workers', '1', '--no-plots']) == 0
    rows = list(csv.DictReader(open(tmp_path / 's' / 'results.csv')))
    assert [r['status'] for r in rows] == ['ok', 'ok'] and rows[0]['backend'] == 'kernel'
    for r in rows:
        assert r['brake_left.final_mode'] == r['brake_right.final_mode'] == 'slip+'
        assert r['clutch.final_mode'] == 'slip+' and r['gearbox.final_gear'] == '1'
        assert float(r['vehicle_speed_m_s']) > 0.0          # rolling up the grade
    by_grade = {float(r['vehicle.grade_percent']): r for r in rows}
    # 10 %: stuck at 0, released once; 8 %: released earlier, stuck again once, released
    assert int(by_grade[10.0]['brake_left.events']) == 2
    assert int(by_grade[8.0]['brake_left.events']) == 4
    path = find_scene('launch_clutch')
    data = load_yaml_bounded(read_text_file(path, what='scene file'), str(path))
    data['duration'] = 2.0
    data['vehicle']['grade_percent'] = 8
    from cvj_ros.physics.hybrid.from_scene import hybrid_simulation
    from cvj_ros.physics.kernel.tree_modes import KernelHybridTreeSimulation
    r = KernelHybridTreeSimulation.from_reference(hybrid_simulation(parse_scene(data))).run()
    _sim, rp, _w = run_hybrid(parse_scene(data))
    row = by_grade[8.0]
    for i, shaft in enumerate(r.shafts):
        assert float(row[f'{shaft}.final_speed']) == r.speed[-1, i]
        assert r.speed[-1, i] == pytest.approx(rp.speed[-1, i], rel=1e-7, abs=1e-7)
    assert float(row['vehicle_speed_m_s']) == float(r.vehicle_speed[-1])
    assert float(row['energy_residual']) == r.max_energy_residual < 1e-9
