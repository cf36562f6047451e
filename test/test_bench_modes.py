"""Mode scenes in the benchmark: the compiled kernel against plain solve_ivp with event
functions on launch_clutch_chain (brake hold and release: its first 2 s)."""
from __future__ import annotations

import math

import pytest

pytest.importorskip('numba')
from cvj_ros import bench_modes  # noqa: E402
from cvj_ros.physics.hybrid.from_scene import hybrid_simulation  # noqa: E402
from cvj_ros.physics.scene import load_scene, shipped_scenes  # noqa: E402


def test_solve_ivp_baseline_finds_the_kernels_events() -> None:
    scene = load_scene(shipped_scenes()['launch_clutch_chain'])
    kw = dict(duration=2.0, rtol=1e-8, atol=1e-10, sample_dt=0.1)
    rb = bench_modes.SolveIvpHybridSimulation.from_reference(hybrid_simulation(scene, **kw)).run()
    rk = bench_modes.KernelHybridSimulation.from_reference(hybrid_simulation(scene, **kw)).run()
    assert [(e.element, e.after) for e in rb.events] == [(e.element, e.after) for e in rk.events]
    assert [e.after for e in rk.events] == ['stuck', 'slip+']         # brake hold, release
    assert max(abs(a.t - b.t) for a, b in zip(rb.events, rk.events)) < 1e-6
    assert rb.speed.shape == rk.speed.shape
    assert abs(rb.speed - rk.speed).max() < 1e-5 * abs(rk.speed).max()


def test_mode_study_rows_and_levels() -> None:
    lines: list[str] = []
    s = bench_modes.mode_study('launch_clutch_chain', tolerances=(1e-5, 1e-7), samples=10,
                               repeats=1, duration=2.0, log=lines.append)
    assert [(r['family'], r['tol']) for r in s['rows']] == [
        ('project', 1e-5), ('project', 1e-7), ('baseline', 1e-5), ('baseline', 1e-7)]
    assert all(r['ok'] and math.isfinite(r['err_speed_rel']) for r in s['rows'])
    # the error follows the tolerance in both families
    for fam in ('project', 'baseline'):
        e5, e7 = (r['err_speed_rel'] for r in s['rows'] if r['family'] == fam)
        assert e7 < e5 < 1e-2
    lv = {e['level']: e for e in s['levels']}
    assert lv[1e-3]['speedup'] is not None and lv[1e-3]['speedup'] > 1.0
    table = bench_modes.format_mode_table(s)
    assert '| 0.001 |' in table and 'solve_ivp RK45 + events' in table
    assert any('mode reference' in line for line in lines)
