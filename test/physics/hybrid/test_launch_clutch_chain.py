"""The shipped chain launch scene: hill start, shifts 1 -> 2 -> 3, through `cvj-sim simulate`
(compiled kernel by default, the Python reference with --backend python) and refused by
`cvj-sim run` until the ROS part exists."""
from __future__ import annotations

import json

import numpy as np
import pytest

from cvj_ros.cli import main
from cvj_ros.physics.hybrid.from_scene import run_hybrid
from cvj_ros.physics.scene import load_scene, parse_scene, shipped_scenes


@pytest.fixture(scope='module')
def launch():
    scene = load_scene(shipped_scenes()['launch_clutch_chain'])
    return scene, run_hybrid(scene)


def test_round_trip() -> None:
    sc = load_scene(shipped_scenes()['launch_clutch_chain'])
    assert sc.has_modes
    assert parse_scene(sc.to_dict(), source=sc.source) == sc


def test_hill_start_and_shifts(launch) -> None:
    scene, (sim, r, _wall) = launch
    assert r.stall is None and r.statuses == [] and r.t_end == scene.duration
    brake = [(e.t, e.after) for e in r.events if e.element == 'brake']
    assert brake[0] == (0.0, 'stuck')
    # released (forward: the engine pulls the car up the grade) while the brake ramps out
    assert brake[1][1] == 'slip+' and 1.5 < brake[1][0] < 1.8
    w = r.column('wheel')
    assert np.all(w[r.t < brake[1][0]] == 0.0)          # held: exactly at rest, no creep
    gears = [e.after for e in r.events if e.element == 'gearbox']
    assert gears == ['gear 0', 'gear 2', 'gear 0', 'gear 3']
    assert r.count('clutch', 'stuck') >= 3
    # the last second in 3rd with the clutch locked: both sides at the same speed
    last = r.t >= scene.duration - 1.0
    assert np.all(r.gear[last] == 3)
    np.testing.assert_array_equal(r.column('clutch_input')[last], r.column('clutch_output')[last])
    assert r.final_mode.clutch['clutch'] == 0
    assert w[-1] > 15.0                                 # ~6 m/s up the 10 % grade
    assert r.max_energy_residual < 1e-7                 # rtol 1e-8; measured 3.0e-9


def test_same_scene_same_numbers(launch) -> None:
    """A rerun up to a command row (2.5 s, where the full run's stepper lands too) gives the
    same samples and events to the bit."""
    scene, (_sim, r, _wall) = launch
    _s2, r2, _w2 = run_hybrid(scene, duration=2.5)
    n = r2.t.size
    np.testing.assert_array_equal(r2.speed, r.speed[:n])
    np.testing.assert_array_equal(r2.energy_residual, r.energy_residual[:n])
    assert r2.events == [e for e in r.events if e.t <= 2.5]


def test_cli_simulate_reports_events(capsys) -> None:
    assert main(['simulate', 'launch_clutch_chain', '--duration', '4', '--json']) == 0
    cap = capsys.readouterr()
    s = json.loads(cap.out)
    assert s['events']['brake'] == {'stuck': 1, 'slip+': 1}
    assert s['events']['clutch']['stuck'] >= 1
    assert s['solver']['backend'] == 'kernel' and s['solver']['events'] >= 2
    assert s['solver']['backend_fallback'] == ''
    assert main(['simulate', 'launch_clutch_chain', '--duration', '4', '--json',
                 '--backend', 'python']) == 0
    cap_p = capsys.readouterr()
    s_p = json.loads(cap_p.out)
    assert s_p['solver']['backend'] == 'python' and s_p['events'] == s['events']
    assert cap_p.err == ''
    assert main(['simulate', 'launch_clutch_chain', '--duration', '0.5']) == 0
    out = capsys.readouterr().out
    assert 'events brake: 1 -> stuck' in out and 'final: clutch' in out
    assert 'backend kernel' in out
    # the Rosenbrock methods run compiled too, without a note
    assert main(['simulate', 'launch_clutch_chain', '--duration', '0.5', '--method', 'rodas4']) == 0
    cap = capsys.readouterr()
    assert 'backend kernel' in cap.out and cap.err == ''


def test_cli_refusals(tmp_path, capsys) -> None:
    assert main(['simulate', 'launch_clutch_chain', '--dense']) == 2   # samples are dense already
    assert main(['simulate', 'launch_clutch_chain', '--method', 'rk4']) == 2
    assert main(['run', 'launch_clutch_chain', '--out', str(tmp_path / 'run'),
                 '--scheme', 'extrapolate']) == 2        # the ROS loop runs it with zoh only
    assert main(['sweep', 'launch_clutch_chain', '--set', 'initial.speed_rpm=800,900',
                 '--out', str(tmp_path / 'sweep'), '--workers', '1', '--no-plots',
                 '--orders-shaft', 'wheel']) == 2     # no shaft torques on the reference
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 4 and all(line.startswith('cvj-sim: error: ') for line in err)
    assert '--scheme: a scene with clutch, gearbox, brake or commands runs with zoh' in err[2]
    assert '--orders-shaft: a scene with clutch, gearbox, brake or commands' in err[3]
    assert not (tmp_path / 'run').exists() and not (tmp_path / 'sweep').exists()
