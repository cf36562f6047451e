"""End to end: the `make demo` run (fwd_halfshaft, 4 s in the lockstep loop) shows the exact
kinematics over a steady window, and its report matches `analyze` and `simulate`.

One `cvj-sim run --composed` of the shipped scene at its own duration (4000 exchange
steps), as `make demo` runs it.

* The report's window is steady by the criterion (cvj_ros/physics/steady.py).
* In the bag, the tripod's output-minus-input angle swings with the third-order amplitude
  A = (r / 2l) tan(beta) tan^2(beta/2) = 2.5545e-4 rad (beta 15 deg, r/l 0.11; seed 002
  eq. 19 as corrected in DESIGN.md section 5). Bound 1.5e-6 rad: closed form vs exact
  model <= 9.4e-7 (fidelity report) + sampling of the peak at 1 ms <= 4.6e-7
  (test/test_demo_scene.py). Measured in the run's bag: 2.5545233e-4. The Rzeppa (cage at
  delta/2, homokinetic) swings by rounding only.
* analyze of the bag = the run report (same window module, same arrays: rel 1e-12).
* The offline `simulate` of the same scene (monolithic, no exchange) agrees with the run
  within the window's stated amplitude error, AMPLITUDE_TOL = 5 % (the run's amplitudes
  carry the ZOH exchange error too, first order in H = 1 ms); mean speeds within
  DRIFT_TOL = 2e-3. Measured: amplitudes and nonuniformities within 1.3 %, mean speeds
  within 1e-5. Compared only where the quantity is resolved: nonuniformity >= 1e-3 and
  torque amplitude >= 0.1 % of the largest (the criterion's floor); below that (Rzeppa
  side nonuniformity ~1e-5, wheel torque ripple 2e-4 N m) run and simulate differ in
  relative terms by tens of percent of a negligible number.
"""
from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from cvj_ros import analysis
from cvj_ros.physics import steady
from cvj_ros.physics.scene import find_scene, load_scene
from cvj_ros.physics.simulate import Simulation

pytestmark = pytest.mark.e2e
CVJ_SIM = str(Path(sys.executable).with_name('cvj-sim'))


@pytest.fixture(scope='module')
def demo_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[subprocess.CompletedProcess, Path]:
    out = tmp_path_factory.mktemp('demo') / 'run'
    # the command `make demo` runs (Makefile DEMO_MODE = --composed; DEMO_DURATION = the scene's 4 s)
    r = subprocess.run([CVJ_SIM, 'run', 'fwd_halfshaft', '--out', str(out), '--composed'],
                       capture_output=True, text=True, timeout=600)
    return r, out


@pytest.mark.ros
def test_demo_report_steady_exact_kinematics_and_tools_agree(demo_run) -> None:
    r, out = demo_run
    assert r.returncode == 0, r.stdout + r.stderr
    metrics = yaml.safe_load((out / 'report.json').read_text())['metrics']
    assert metrics['window']['steady'] is True, metrics['window_text']
    assert 'steady window ' + metrics['window_text'] in r.stdout
    assert 'tripod=exact rzeppa=exact' in r.stdout

    rep = analysis.analyze_bag(out / 'bag')
    beta, ratio = math.radians(15.0), 0.0264 / 0.24
    amp = ratio / 2 * math.tan(beta) * math.tan(beta / 2) ** 2
    assert rep['joints']['tripod']['geometric_amplitude_rad'] == pytest.approx(amp, abs=1.5e-6)
    assert rep['joints']['rzeppa']['geometric_amplitude_rad'] < 1e-12
    assert rep['window']['text'] == metrics['window_text']
    for name, m in metrics['shafts'].items():
        assert rep['shafts'][name]['speed_nonuniformity'] == pytest.approx(m['delta'], rel=1e-12, abs=1e-15)
        assert rep['shafts'][name]['torque_amplitude_Nm'] == pytest.approx(m['torque_amplitude'], rel=1e-12,
                                                                           abs=1e-15)

    sim = Simulation(load_scene(find_scene('fwd_halfshaft')))
    sim.run()
    offline = sim.summary()
    assert offline['window']['steady'] is True
    torque_floor = steady.TORQUE_FLOOR * max(s['torque_amplitude'] for s in offline['shafts'].values())
    for name, s in offline['shafts'].items():
        m = metrics['shafts'][name]
        assert m['mean_speed'] == pytest.approx(s['mean_speed'], rel=steady.DRIFT_TOL), name
        if s['delta'] >= 1e-3:
            assert m['delta'] == pytest.approx(s['delta'], rel=steady.AMPLITUDE_TOL), name
        if s['torque_amplitude'] >= torque_floor:
            assert m['torque_amplitude'] == pytest.approx(s['torque_amplitude'], rel=steady.AMPLITUDE_TOL), name
