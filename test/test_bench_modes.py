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


def test_solve_ivp_baseline_of_a_vehicle_finds_the_kernels_events() -> None:
    """launch_clutch's first 2 s (brake hold and release) by solve_ivp with the tree
    reference's witnesses as event functions and by the tree kernel."""
    scene = load_scene(shipped_scenes()['launch_clutch'])
    kw = dict(duration=2.0, rtol=1e-8, atol=1e-10, sample_dt=0.1)
    rb = bench_modes.SolveIvpHybridTreeSimulation.from_reference(hybrid_simulation(scene, **kw)).run()
    rk = bench_modes.KernelHybridTreeSimulation.from_reference(hybrid_simulation(scene, **kw)).run()
    assert [(e.element, e.after) for e in rb.events] == [(e.element, e.after) for e in rk.events]
    assert [e.after for e in rk.events] == ['stuck', 'stuck', 'slip+', 'slip+']
    assert max(abs(a.t - b.t) for a, b in zip(rb.events, rk.events)) < 1e-6
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


def test_run_bench_writes_the_mode_tables(tmp_path, monkeypatch) -> None:
    """run_bench with mode scenes: their study (here a stub with two rows) goes to modes.csv
    and modes.md and into the result; the report stays the last path."""
    from cvj_ros import bench
    from cvj_ros.physics.scene import parse_scene
    rows = [{'scene': 'launch_clutch_chain', 'family': f, 'label': f, 'tol': 1e-6, 'ok': True,
             'err_speed_rel': 1e-5, 'wall_s': w, 'wall_per_sim_s': w / 10, 'repeats': 1,
             'steps': 1, 'nfev': 7, 'events': 14, 'energy_residual': 1e-9}
            for f, w in (('project', 0.01), ('baseline', 0.5))]
    calls = []

    def study(name, **kw):
        calls.append((name, kw['tolerances']))
        return {'scene': name, 'duration': 10.0, 'reference': {}, 'rows': rows,
                'levels': bench_modes.mode_levels(rows)}
    monkeypatch.setattr(bench_modes, 'mode_study', study)
    scene = {'name': 'mini', 'duration': 1.0, 'engine': {'model': 'linear'},
             'load': {'model': 'constant', 'torque': 10.0}, 'initial': {'speed_rad_s': 30.0},
             'driveline': [{'type': 'inertia', 'name': 'engine_crank', 'J': 0.1},
                           {'type': 'spring', 'name': 'bush', 'stiffness': 700.0, 'damping': 6.0},
                           {'type': 'inertia', 'name': 'wheel', 'J': 0.2}]}
    cfg = bench.BenchConfig(scenes=[parse_scene(scene)], solvers=('dopri5',), tolerances=(1e-4,),
                            fidelities=('exact',), baselines=('RK45',), horizon=0.1, samples=5,
                            repeats=1, min_timed_s=0.0, exchange_steps=(1e-3,),
                            lockstep_scenes=None, round_trip_n=0, compiled_baselines=False,
                            expert_methods=(), mode_scenes=('launch_clutch_chain',))
    res = bench.run_bench(cfg, tmp_path, log=lambda m: None)
    assert calls == [('launch_clutch_chain', (1e-4, 1e-11))]
    assert res['modes'][0]['levels'][0]['speedup'] == 50.0
    assert (tmp_path / 'modes.csv').read_text().count('\n') == 3
    assert '| 0.001 | 1e-06 | - | 10.0 | 1e-06 | - | 500.0 | - | 50.0x | - |' in \
        (tmp_path / 'modes.md').read_text()
    assert res['paths'][-1].name == 'bench.md'


def test_cli_mode_scene_selection() -> None:
    """`cvj-sim bench` times launch_clutch_chain and launch_clutch by default, not with --quick or --scenes
    (unless --mode-scenes names it); --mode-scenes refuses a scene without modes."""
    import argparse

    from cvj_ros.commands import bench as cli_bench
    from cvj_ros.errors import SceneError
    p = argparse.ArgumentParser()
    cli_bench.add_arguments(p)

    def modes(*argv: str) -> tuple:
        return tuple(cli_bench.config_from_args(p.parse_args(list(argv))).mode_scenes)
    assert modes() == ('launch_clutch_chain', 'launch_clutch')
    assert modes('--quick') == () and modes('--scenes', 'cardan_truck') == ()
    assert modes('--mode-scenes') == ()
    assert modes('--scenes', 'cardan_truck', '--mode-scenes', 'launch_clutch_chain') == \
        ('launch_clutch_chain',)
    with pytest.raises(SceneError, match='--mode-scenes'):
        modes('--mode-scenes', 'cardan_truck')


@pytest.mark.slow
def test_kernel_reference_of_a_vehicle_is_the_python_reference() -> None:
    """The bench's reference of a vehicle scene (the kernel, dopri5 at rtol 1e-13) against
    the Python reference (dop853 at rtol 1e-12) on launch_clutch's first 3 s (brake hold,
    release, clutch lock): the same events, times and samples within 1e-10 (relative; the
    bench's finest level is 1e-8). Measured: 3.3e-12 s, 3.0e-11."""
    scene = load_scene(shipped_scenes()['launch_clutch'])
    rk = bench_modes.reference_run(scene, 3.0, 0.1, 'kernel')
    rp = bench_modes.reference_run(scene, 3.0, 0.1, 'python')
    assert [(e.element, e.after) for e in rk.events] == [(e.element, e.after) for e in rp.events]
    assert ('clutch', 'stuck') in [(e.element, e.after) for e in rk.events]
    assert max(abs(a.t - b.t) for a, b in zip(rk.events, rp.events)) < 1e-10 * 3.0
    assert abs(rk.speed - rp.speed).max() < 1e-10 * abs(rp.speed).max()


def test_mode_study_of_a_vehicle_takes_the_kernel_reference() -> None:
    """launch_clutch's first 0.5 s (the brakes hold): the reference is the kernel's, both
    families reach the same 2 events, the table says which reference and the load."""
    s = bench_modes.mode_study('launch_clutch', tolerances=(1e-6,), samples=5, repeats=1,
                               duration=0.5, log=lambda m: None)
    assert s['reference']['backend'] == 'kernel' and s['reference']['rtol'] == 1e-13
    assert [r['events'] for r in s['rows']] == [2, 2]
    assert all(len(r['load']) == 2 for r in s['rows'])
    table = bench_modes.format_mode_table(s)
    assert 'Reference: kernel dopri5 at rtol 1e-13' in table and '| load |' in table
