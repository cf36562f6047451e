"""The default demo scene (fwd_halfshaft) shows the exact joint kinematics over a steady
window, and `simulate`, `analyze` and the run report give the same numbers on one record.

One offline run of the shipped scene (4 s, ~2 s wall with the compiled kernel) is written
as a bag with :func:`cvj_ros.trace_bag.write_trace_bag`; then

* simulate's summary, ``analyze`` and the run report's :func:`bag_metrics` on that bag
  must agree exactly (same window, same numbers: float64 round trip, one window module);
* the tripod's output-minus-input angle must swing with the exact model's third-order
  amplitude (closed form below), the Rzeppa's not at all (homokinetic cage);
* the window must be steady by the criterion (physics/steady.py).
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from cvj_ros import analysis
from cvj_ros.orchestrate import bag_metrics
from cvj_ros.physics.scene import find_scene, load_scene
from cvj_ros.physics.simulate import Simulation
from cvj_ros.trace_bag import scene_message, write_trace_bag


@pytest.fixture(scope='module')
def demo(tmp_path_factory: pytest.TempPathFactory) -> tuple[Simulation, dict, Path]:
    scene = load_scene(find_scene('fwd_halfshaft'))
    sim = Simulation(scene)
    trace = sim.run()
    summary = sim.summary()
    path = tmp_path_factory.mktemp('demo') / 'bag'
    text = scene_message(scene, sim.fidelity_report.to_dict(), solver=summary['solver'],
                         duration=float(trace.t[-1]), sample_dt=scene.exchange_step, names=trace.names)
    write_trace_bag(trace, path, scene_yaml=text)
    return sim, summary, path


def test_demo_runs_both_joints_exact_and_steady(demo) -> None:
    sim, summary, _ = demo
    chosen = {c['name']: c['chosen'] for c in summary['fidelity']['choices']}
    assert chosen['tripod'] == 'exact' and chosen['rzeppa'] == 'exact'
    assert summary['solver']['backend'] == 'kernel' and not summary['solver'].get('backend_fallback')
    win = summary['window']
    assert win['steady'] is True and win['source'] == 'criterion', summary['window_text']
    # measured: drift 8e-7, steady from 1.6 s of 4 s; require >= 3 slices (1.2 s) of margin
    assert win['start_s'] <= 2.8 and win['drift'] < 2e-3 and win['amplitude_change'] <= 0.05


def test_tripod_swings_with_exact_third_order_amplitude(demo) -> None:
    """Closed form (seed 002 eq. 19 as corrected in DESIGN.md section 5; tripod.py
    docstring): phi_out - phi_in = -A sin(3 phi_in), A = (r / 2l) tan(beta) tan^2(beta/2)
    = 2.5545e-4 rad at beta 15 deg, r/l = 0.0264/0.24 = 0.11. Bound 1.5e-6 rad: the closed
    form differs from the exact model by <= 9.4e-7 rad (the fidelity report's phi_error of
    'closed' against 'exact', 9.34e-7), plus sampling: 1 ms samples of a swing at 3 x 39.6
    rad/s miss its peak by <= A (1 - cos(119 x 0.5e-3)) = 4.6e-7 rad. Measured 2.5545236e-4
    (|diff| ~ 2e-10: the record holds ~45 swings, one lands on the peak). The ideal
    fidelity (0 swing) would fail by 170x the bound."""
    sim, _, path = demo
    sig = analysis.read_bag_signals(path)
    beta, r, l = math.radians(15.0), 0.0264, 0.24
    amp = r / (2 * l) * math.tan(beta) * math.tan(beta / 2) ** 2
    assert amp == pytest.approx(2.5545e-4, rel=1e-4)
    rep = analysis.analyze_signals(sig)
    tri = rep['joints']['tripod']
    assert tri['geometric_amplitude_rad'] == pytest.approx(amp, abs=1.5e-6)
    # the swing is third order: its phase-average over the input angle is A sin(3 phi) (sign: lag)
    i, o = sig.column('tripod_input'), sig.column('tripod_output')
    m = sig.t >= rep['window']['start_s']
    dev = sig.position[m, o] - sig.position[m, i]
    phi = sig.position[m, i]
    b3 = 2 * np.mean(dev * np.sin(3 * phi))        # Fourier sine coefficient over many swings
    assert b3 == pytest.approx(-amp, abs=0.05 * amp)  # uneven angle sampling over 2.4 s: ~1 % measured
    rz = rep['joints']['rzeppa']
    # alpha = delta/2: homokinetic, K = 1 (seed 003 eq. 12): the swing is rounding only
    assert rz['geometric_amplitude_rad'] < 1e-12


def test_simulate_analyze_and_run_report_agree_on_one_record(demo) -> None:
    """Same record -> same window -> same numbers (float64 in the bag: exact equality up to
    the order of summation, rel 1e-12), except the acceleration: the bag's stamps are whole
    ns, so a 1 ms sample step may differ from the trace's by <= 1 ns: rel 1e-6 (measured
    1.5e-10)."""
    _, summary, path = demo
    rep = analysis.analyze_bag(path)
    run_m = bag_metrics(path)
    assert run_m['window_s'] == pytest.approx([summary['window']['start_s'], summary['window']['end_s']], abs=0)
    assert rep['window']['start_s'] == summary['window']['start_s']
    assert rep['window']['steady'] is run_m['window']['steady'] is summary['window']['steady'] is True
    assert rep['window']['text'] == run_m['window_text'] == summary['window_text']
    for name, s in summary['shafts'].items():
        a, r = rep['shafts'][name], run_m['shafts'][name]
        for key_sim, key_an in (('mean_speed', 'mean_speed_rad_s'), ('delta', 'speed_nonuniformity'),
                                ('speed_amplitude', 'speed_amplitude_rad_s'),
                                ('acceleration_amplitude', 'acceleration_amplitude_rad_s2'),
                                ('mean_torque', 'mean_torque_Nm'), ('torque_amplitude', 'torque_amplitude_Nm')):
            rel = 1e-6 if key_sim == 'acceleration_amplitude' else 1e-12
            assert r[key_sim] == pytest.approx(s[key_sim], rel=rel, abs=1e-12), (name, key_sim)
            assert a[key_an] == pytest.approx(r[key_sim], rel=1e-12, abs=1e-12), (name, key_an)
