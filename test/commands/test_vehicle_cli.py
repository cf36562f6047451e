"""cvj-sim on vehicle scenes: simulate runs them (compiled kernel, no fallback note) and
prints the vehicle table; run refuses the options that replace a chain's load torque in one
line, exit 2, nothing started (the runs themselves: test/e2e/test_run_vehicle.py)."""
from __future__ import annotations

from pathlib import Path

import pytest

from cvj_ros.cli import main


@pytest.mark.parametrize('option, prefix', [
    (['--external', 'load'], 'cvj-sim: error: --external: load: fwd_axle.yaml is a vehicle scene'),
    (['--load-from-bag', 'nowhere'], 'cvj-sim: error: --load-from-bag: fwd_axle.yaml is a vehicle scene')])
def test_run_refuses_load_options_on_a_vehicle_scene(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                     option: list[str], prefix: str) -> None:
    out = tmp_path / 'run'
    assert main(['run', 'fwd_axle', '--out', str(out), *option]) == 2
    err = capsys.readouterr().err
    assert err.count('\n') == 1
    assert err.startswith(prefix) and 'tyres' in err
    assert not out.exists()


def test_simulate_prints_vehicle_and_wheels(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(['simulate', 'fwd_axle_split_mu', '--duration', '0.1', '--sample-dt', '0.01']) == 0
    cap = capsys.readouterr()
    assert 'compiled kernel' not in cap.err and 'backend kernel' in cap.out
    assert 'vehicle speed 20 -> ' in cap.out
    assert 'wheel_left' in cap.out and 'no-load samples' in cap.out
