"""Monitor statuses reach the user of `cvj-sim run` (issue 14 item 3): counts, first and
worst in the report, `--fail-on error|warn|never` sets the exit status, and the report names
seed, mode, scheme, storage and fidelity."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

pytestmark = pytest.mark.e2e

CVJ_SIM = str(Path(sys.executable).with_name('cvj-sim'))
SCENE = {
    'name': 'monitor_limits', 'seed': 5, 'duration': 0.3, 'exchange_step': 0.001,
    'solver': {'method': 'dopri5', 'rtol': 1e-8, 'atol': 1e-10},
    'engine': {'model': 'linear'}, 'load': {'model': 'constant', 'torque': 100.0},
    'initial': {'speed_rpm': 300.0},
    'driveline': [
        {'type': 'inertia', 'name': 'crank', 'J': 0.128},
        {'type': 'spring', 'name': 'bush', 'stiffness': 715.4, 'damping': 6.35},
        # a Hooke joint at 25 deg makes ~0.2 nonuniformity: the 0.001 limit is violated
        {'type': 'joint', 'name': 'cpl', 'kind': 'hooke', 'fidelity': 'exact',
         'params': {'beta_deg': 25.0}, 'limits': {'max_nonuniformity': 0.001}},
        {'type': 'inertia', 'name': 'driven', 'J': 0.161}],
}


def _run(tmp_path: Path, name: str, *extra: str) -> subprocess.CompletedProcess[str]:
    scene = tmp_path / 'scene.yaml'
    scene.write_text(yaml.safe_dump(SCENE, sort_keys=False))
    return subprocess.run([CVJ_SIM, 'run', str(scene), '--out', str(tmp_path / name), *extra],
                          capture_output=True, text=True, timeout=180)


def test_fail_on_error_fails_the_run_and_reports(tmp_path: Path) -> None:
    r = _run(tmp_path, 'default', '--fail-on', 'error')
    assert r.returncode == 1, r.stdout + r.stderr
    err = r.stderr.strip().splitlines()
    assert len(err) == 1 and err[0].startswith('cvj-sim: error: monitor: '), r.stderr
    assert 'ERROR and' in err[0] and '(--fail-on error); worst: ERROR t = ' in err[0]
    assert 'nonuniformity' in err[0]
    assert '  monitor: ' in r.stdout and 'first ERROR: t = ' in r.stdout
    assert '  settings: seed 5, mode lockstep, scheme zoh, storage mcap, process separate, hosted monitor_node, fidelity cpl=exact' in r.stdout
    report = json.loads((tmp_path / 'default' / 'report.json').read_text())
    assert report['metrics']['monitor']['error'] >= 1 and report['exit_code'] == 1


def test_default_never_keeps_exit_0_and_still_reports(tmp_path: Path) -> None:
    r = _run(tmp_path, 'never', '--storage', 'sqlite3')
    assert r.returncode == 0, r.stdout + r.stderr
    assert r.stdout.startswith('cvj-sim run: loop running') and 'cvj-sim run: finished' in r.stdout
    assert '  monitor: ' in r.stdout and 'worst: ERROR' in r.stdout
    assert 'storage sqlite3' in r.stdout
