"""`cvj-sim run` progress line: on a (fake) terminal stderr gets the line, the report on
stdout is unchanged; the real run, in-process (the nodes are real processes)."""
from __future__ import annotations

import io
from pathlib import Path

import pytest
import yaml

from cvj_ros.orchestrate import RunOptions, run
from cvj_ros.progress import Progress

pytestmark = pytest.mark.e2e

SCENE = {
    'name': 'progress_two_mass', 'duration': 0.2, 'exchange_step': 0.001,
    'solver': {'method': 'dopri5', 'rtol': 1e-8, 'atol': 1e-10},
    'engine': {'model': 'linear'}, 'load': {'model': 'constant', 'torque': 50.0},
    'initial': {'speed_rad_s': 30.0},
    'driveline': [{'type': 'inertia', 'name': 'crank', 'J': 0.128},
                  {'type': 'spring', 'name': 'shaft', 'stiffness': 715.4, 'damping': 6.35},
                  {'type': 'inertia', 'name': 'wheel', 'J': 0.161}],
}


class FakeTTY(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_run_shows_progress_on_a_terminal(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    scene = tmp_path / 'scene.yaml'
    scene.write_text(yaml.safe_dump(SCENE))
    ticks = [0.0]

    def clock() -> float:          # every reading 1 s later: every poll may print a line
        ticks[0] += 1.0
        return ticks[0]
    monkeypatch.setattr(Progress, 'default_clock', staticmethod(clock))
    tty = FakeTTY()
    monkeypatch.setattr('sys.stderr', tty)
    report = io.StringIO()
    result = run(RunOptions(scene=str(scene), out=tmp_path / 'run'), stream=report)
    assert result.exit_code == 0, report.getvalue()
    err = tty.getvalue()
    assert '\rcvj-sim run: t=' in err and ' s simulated (' in err and 'real-time factor' in err, err
    assert err.endswith('\r')               # erased before the report
    assert '\r' not in report.getvalue()    # the report itself has no progress in it
