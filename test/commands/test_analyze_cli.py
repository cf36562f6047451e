"""`cvj-sim analyze` end to end on a synthetic bag (text, JSON, PNGs) and on a missing bag."""
from __future__ import annotations

import importlib.util
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from cvj_ros.cli import main

_spec = importlib.util.spec_from_file_location('_synthetic_bag', Path(__file__).parents[1] / 'test_analysis.py')
_synth = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(_synth)


@pytest.fixture(scope='module')
def bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return _synth.write_synthetic_bag(tmp_path_factory.mktemp('cli') / 'bag', duration=2.0)


def test_analyze_json_and_plots(bag: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(['analyze', str(bag), '--json', '--plots', str(tmp_path / 'png')]) == 0
    rep = json.loads(capsys.readouterr().out)
    assert rep['shafts']['engine_crank']['speed_amplitude_rad_s'] == pytest.approx(_synth.A_SPEED, rel=1e-3)
    assert rep['shafts']['engine_crank']['torque_harmonics']['amplitude'][0] == pytest.approx(8.0, abs=0.03)
    names = sorted(Path(p).name for p in rep['plots'])
    assert names == ['harmonics.png', 'nonuniformity.png', 'speeds_torques.png']
    for p in rep['plots']:
        data = Path(p).read_bytes()
        assert data[:8] == b'\x89PNG\r\n\x1a\n' and len(data) > 20_000


def test_analyze_text(bag: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(['analyze', str(bag), '--skip', '0.5']) == 0
    out = capsys.readouterr().out
    assert 'engine_crank' in out and 'hooke' in out and 'lockstep: 2001 steps' in out
    assert 'start transient 0.5 s skipped' in out


def test_missing_bag_exits_2_with_one_line(tmp_path: Path) -> None:
    exe = Path(sys.executable).with_name('cvj-sim')
    cmd = [str(exe)] if exe.exists() else [sys.executable, '-m', 'cvj_ros.cli']
    r = subprocess.run(cmd + ['analyze', str(tmp_path / 'missing')], capture_output=True, text=True,
                       timeout=60, env=dict(os.environ))
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith('cvj-sim: error: ') and 'missing: no such bag' in lines[0]


def test_bad_option_exits_2(bag: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(['analyze', str(bag), '--skip', '-1']) == 2
    assert capsys.readouterr().err.startswith('cvj-sim: error: --skip:')


def test_analyze_leaves_out_another_publishers_joint_states(bag: Path, tmp_path: Path,
                                                            capsys: pytest.CaptureFixture[str]) -> None:
    """Joint states of another layout interleaved in the run's topic (a `cvj-sim record` on a
    busy domain): analyze reports the run's own figures, the same as without them, and names
    the rest in one line."""
    mixed = _synth.write_synthetic_bag(tmp_path / 'mixed', duration=2.0, foreign_every=100)
    assert main(['analyze', str(mixed), '--json']) == 0
    got = json.loads(capsys.readouterr().out)
    assert main(['analyze', str(bag), '--json']) == 0
    want = json.loads(capsys.readouterr().out)
    assert got['shafts'] == want['shafts'] and got['joints'] == want['joints']
    assert got['foreign_messages'] == {'/driveline/joint_states': 20} and not want['foreign_messages']
    assert main(['analyze', str(mixed)]) == 0
    out = capsys.readouterr().out.splitlines()
    assert [line for line in out if 'not the run' in line] == [
        "left out as not the run's (other joint names, undecodable): 20 on /driveline/joint_states "
        '(20 messages)']


def test_analyze_text_names_gaps(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The gaps line of `cvj-sim run`'s report, printed by `analyze` for a free run's bag
    lacking 20 sample times (t = 0.5 .. 0.519 s, 20 ticks skipped)."""
    bag = _synth.write_synthetic_bag(tmp_path / 'bag', duration=2.0, scene=_synth.FREE_RUN_SCENE,
                                     missing=range(500, 520), ticks_skipped=20)
    assert main(['analyze', str(bag)]) == 0
    assert ('  gaps: all 3 loop topics miss 20 of 2001 sample times (longest run 0.02 s from '
            't = 0.5 s); 20 ticks skipped by free-run catch-up') in capsys.readouterr().out.splitlines()
