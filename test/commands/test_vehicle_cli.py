"""cvj-sim on vehicle scenes: simulate runs them (compiled kernel, no fallback note) and
prints the vehicle table; run refuses the options that replace a chain's load torque in one
line, exit 2, nothing started (the runs themselves: test/e2e/test_run_vehicle.py)."""
from __future__ import annotations

from pathlib import Path

import pytest

from cvj_ros.cli import main


def test_run_refuses_a_recorded_load_on_a_vehicle_scene(tmp_path: Path,
                                                        capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / 'run'
    assert main(['run', 'fwd_axle', '--out', str(out), '--load-from-bag', 'nowhere']) == 2
    err = capsys.readouterr().err
    assert err.count('\n') == 1
    assert err.startswith('cvj-sim: error: --load-from-bag: fwd_axle.yaml is a vehicle scene')
    assert 'tyres' in err and '--external load' in err
    assert not out.exists()


def test_external_load_on_a_vehicle_scene_waits_for_every_wheel(tmp_path: Path) -> None:
    """--external load: no load_node, coupling_node wheel_load:=external, the start wait and
    the recorder on one /load/<wheel>/wrench per wheel (validated only, nothing started)."""
    from cvj_ros.orchestrate.options import RunOptions, prepare
    from cvj_ros.orchestrate.processes import node_parameters
    prep = prepare(RunOptions(scene='awd_4x4', out=tmp_path / 'a', external=('load',)))
    wheels = ['wheel_front_left', 'wheel_front_right', 'wheel_rear_left', 'wheel_rear_right']
    assert 'load_node' not in prep.nodes
    # the recorder's extra topics: every branch's reaction wrenches, then the wheels' loads
    reactions = [f'/coupling/{j}/wrench' for j in ('gearbox', 'tripod_fl', 'rzeppa_fl', 'tripod_fr',
                                                    'rzeppa_fr')]
    assert prep.coupling_topics == reactions + [f'/load/{w}/wrench' for w in wheels]
    topics, outside = prep.peers
    assert topics['engine_node'] == '/engine/wrench' and 'engine_node' not in outside
    assert [t for n, t in topics.items() if outside.get(n) == 'load'] == prep.coupling_topics[len(reactions):]
    assert node_parameters(prep, 'coupling_node', load_override=None)['wheel_load'] == 'external'
    chain = prepare(RunOptions(scene='fwd_halfshaft', out=tmp_path / 'b', external=('load',)))
    assert chain.peers is None and 'wheel_load' not in node_parameters(chain, 'coupling_node',
                                                                        load_override=None)


def test_simulate_prints_vehicle_and_wheels(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(['simulate', 'fwd_axle_split_mu', '--duration', '0.1', '--sample-dt', '0.01']) == 0
    cap = capsys.readouterr()
    assert 'compiled kernel' not in cap.err and 'backend kernel' in cap.out
    assert 'vehicle speed 20 -> ' in cap.out
    assert 'wheel_left' in cap.out and 'no-load samples' in cap.out
