"""cvj-sim on vehicle scenes: simulate runs them (compiled kernel, no fallback note) and
prints the vehicle table; run refuses them in one line, exit 2, nothing started."""
from __future__ import annotations

from pathlib import Path

import pytest

from cvj_ros.cli import main


def test_run_refuses_a_vehicle_scene(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / 'run'
    assert main(['run', 'fwd_axle', '--out', str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count('\n') == 1
    assert err.startswith('cvj-sim: error: fwd_axle.yaml: a vehicle scene') and 'simulate' in err
    assert not out.exists()


def test_simulate_prints_vehicle_and_wheels(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(['simulate', 'fwd_axle_split_mu', '--duration', '0.1', '--sample-dt', '0.01']) == 0
    cap = capsys.readouterr()
    assert 'compiled kernel' not in cap.err and 'backend kernel' in cap.out
    assert 'vehicle speed 20 -> ' in cap.out
    assert 'wheel_left' in cap.out and 'no-load samples' in cap.out
