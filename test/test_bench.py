"""Work-precision benchmark on a reduced in-test configuration through the same code path
as `cvj-sim bench` (run_bench and the CLI), checking outputs, NaN-freedom and convergence.

The scene is a small lever-like unit (seed 004 parameters: I1 = 0.128, I2 = 0.161 kg m^2,
c = 715.4 N m/rad, b = 6.35 N m s/rad) with a Hooke joint at 15 deg, so the ideal
fidelity has a model error of order 1 - cos(beta) that no tolerance can remove.
"""
from __future__ import annotations

import csv
import math
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

from cvj_ros import bench
from cvj_ros.cli import main
from cvj_ros.physics.scene import parse_scene

SCENE = {'name': 'mini_lever', 'duration': 1.0, 'engine': {'model': 'linear'},
         'load': {'model': 'constant', 'torque': 107.5}, 'initial': {'speed_rad_s': 30.0},
         'driveline': [{'type': 'inertia', 'name': 'engine_crank', 'J': 0.128},
                       {'type': 'joint', 'name': 'hooke', 'kind': 'hooke', 'params': {'beta_deg': 15}},
                       {'type': 'spring', 'name': 'bush', 'stiffness': 715.4, 'damping': 6.35},
                       {'type': 'inertia', 'name': 'wheel', 'J': 0.161}]}
TOLS = (1e-3, 1e-6, 1e-9)


@pytest.fixture(scope='module')
def result(tmp_path_factory: pytest.TempPathFactory) -> tuple[dict, Path]:
    out = tmp_path_factory.mktemp('bench')
    cfg = bench.BenchConfig(scenes=[parse_scene(SCENE)], solvers=('dopri5', 'dop853', 'rk4'),
                            tolerances=TOLS, rk4_steps=(2e-3, 5e-4), fidelities=('ideal', 'exact', 'auto'),
                            energy=('on',), baselines=('RK45', 'LSODA'), horizon=0.2, samples=20, repeats=2,
                            min_timed_s=0.0, exchange_steps=(1e-3, 4e-3), lockstep_scenes=None, round_trip_n=0)
    return bench.run_bench(cfg, out, log=lambda m: None), out


def _rows(res: dict, **match: object) -> list[dict]:
    return [r for r in res['rows'] if all(r.get(k) == v for k, v in match.items())]


def test_outputs_written_without_nan(result: tuple[dict, Path]) -> None:
    res, out = result
    for name in ('bench.csv', 'lockstep.csv', 'bench.md', 'wp_mini_lever.png', 'lockstep.png'):
        assert (out / name).stat().st_size > 200, name
    with (out / 'bench.csv').open() as fh:
        rows = list(csv.DictReader(fh))
    # 'auto' resolves to the exact model here (no accuracy target): not rerun
    # project: 2 fidelities x (2 adaptive x 3 tol x (landing, dense) + 2 rk4 steps);
    # baselines: 2 methods x 3 tol, once with the Python rhs and once with the compiled rhs;
    # numbalsoda's lsoda and dop853 x 3 tol where it is installed (no breakpoints: no restarts)
    experts = len(bench.expert_methods_run(bench.BenchConfig()))
    assert len(rows) == 2 * (2 * 3 * 2 + 2) + 2 * 2 * 3 + experts * 3
    assert sum(r['sampling'] == 'dense' for r in rows) == 2 * 2 * 3
    assert all(r['label'].endswith(' dense') for r in rows if r['sampling'] == 'dense')
    assert sum(r['family'] == 'baseline_compiled' for r in rows) == 2 * 3
    assert res['rows'] and all(r['fidelity'] != 'auto' for r in res['rows'])
    for r in rows:
        assert r['ok'] == 'True', r
        for key in ('wall_s', 'wall_per_sim_s', 'err_speed_rel', 'err_angle_rad', 'nfev'):
            v = float(r[key])
            assert math.isfinite(v) and v >= 0, (key, r)
    md = (out / 'bench.md').read_text()
    assert '| 1e-03 |' in md and 'Pareto front' in md and '## Machine' in md and 'cores' in md
    assert 'best solve_ivp (compiled rhs)' in md and 'ns per call from a compiled loop' in md
    assert 'nan' not in md.lower()
    assert "Fidelity chooser's pick (hooke=exact bush=elastic, the same model as exact)" in md
    # the per-level summary rebuilt from the CSV (`cvj-sim bench --report`) is the run's own
    from cvj_ros import bench_report
    rebuilt = bench_report.summary_lines(bench_report.read_bench_csv(out / 'bench.csv'),
                                         bench_report.read_rhs_ns(out))
    assert '\n'.join(rebuilt) in md and len(rebuilt) > 2 + len(bench.ERROR_LEVELS)


def test_errors_shrink_as_tolerances_tighten(result: tuple[dict, Path]) -> None:
    res, _ = result
    for family, solver in (('project', 'dopri5'), ('project', 'dop853'), ('baseline', 'RK45'),
                           ('baseline', 'LSODA')):
        errs = [_rows(res, family=family, solver=solver, fidelity='exact', tol=t)[0]['err_speed_rel']
                for t in TOLS]
        assert errs[1] < errs[0] / 10 and errs[2] < errs[1] / 10 or errs[2] < 1e-9, (solver, errs)
    rk4 = sorted(_rows(res, solver='rk4', fidelity='exact'), key=lambda r: -r['h'])
    # fourth order: a 4x smaller step cuts the error by ~256
    assert rk4[1]['err_speed_rel'] < rk4[0]['err_speed_rel'] / 50
    cost = [_rows(res, solver='dop853', fidelity='exact', tol=t)[0]['nfev'] for t in TOLS]
    assert cost[0] < cost[1] < cost[2]


def test_dense_sampling_reaches_the_landing_runs_accuracy(result: tuple[dict, Path]) -> None:
    """Dense rows read the samples from the method's dense output (as solve_ivp's t_eval):
    at the same tolerance the error stays of the landing run's order (the dense order is
    the method's: dopri5 4th, dop853 7th); dopri5's free dense output adds no evaluations
    (dop853's costs three per step that holds a sample)."""
    res, _ = result
    for solver in ('dopri5', 'dop853'):
        for t in TOLS:
            land = _rows(res, solver=solver, fidelity='exact', tol=t, sampling='land')[0]
            dense = _rows(res, solver=solver, fidelity='exact', tol=t, sampling='dense')[0]
            assert solver != 'dopri5' or dense['nfev'] <= land['nfev'], t
            assert dense['err_speed_rel'] < max(100 * land['err_speed_rel'], 10 * t), (solver, t)


def test_ideal_fidelity_has_a_model_error_floor(result: tuple[dict, Path]) -> None:
    res, _ = result
    ideal = [r['err_speed_rel'] for r in _rows(res, fidelity='ideal', family='project')]
    exact_best = min(r['err_speed_rel'] for r in _rows(res, fidelity='exact', family='project'))
    # Hooke at 15 deg: the output speed swings by 1/cos b - cos b ~ 7 %; ideal misses it.
    assert min(ideal) > 1e-3 and exact_best < 1e-7


def test_pareto_front_and_levels_table(result: tuple[dict, Path]) -> None:
    res, _ = result
    rows = _rows(res, scene='mini_lever')
    front = bench.pareto_front(rows)
    for r in rows:       # nothing on the front is dominated by any row
        for f in front:
            assert not (r['err_speed_rel'] < f['err_speed_rel'] and r['wall_per_sim_s'] < f['wall_per_sim_s'])
    errs = [f['err_speed_rel'] for f in front]
    costs = [f['wall_per_sim_s'] for f in front]
    assert errs == sorted(errs) and costs == sorted(costs, reverse=True)
    table = res['tables']['mini_lever']
    assert [e['level'] for e in table] == list(bench.ERROR_LEVELS)
    for e in table:
        if e['project'] and e['baseline']:
            assert e['speedup'] == pytest.approx(e['baseline']['wall_per_sim_s'] / e['project']['wall_per_sim_s'])


def test_lockstep_error_shrinks_with_exchange_step(result: tuple[dict, Path]) -> None:
    res, _ = result
    lock = res['lockstep']
    if not lock:
        pytest.skip('cvj_ros.physics.cosim not available')
    assert {r['scheme'] for r in lock} == set(bench.COUPLING_SCHEMES)
    for scheme in bench.COUPLING_SCHEMES:
        by_h = {r['exchange_step']: r for r in lock if r['scheme'] == scheme}
        assert all(r['ok'] and r['rtf'] > 0 for r in by_h.values())
        assert by_h[1e-3]['err_speed_rel'] < by_h[4e-3]['err_speed_rel'], scheme
    zoh = {r['exchange_step']: r['err_speed_rel'] for r in lock if r['scheme'] == 'zoh'}
    # ZOH is first order in the exchange step: 4x smaller step, about 4x smaller error
    assert 2.0 < zoh[4e-3] / zoh[1e-3] < 8.0


def test_pareto_front_unit() -> None:
    rows = [{'ok': True, 'err_speed_rel': e, 'wall_per_sim_s': c, 'family': 'project'}
            for e, c in ((1e-3, 1.0), (1e-4, 2.0), (1e-4, 3.0), (1e-5, 1.5), (1e-6, 5.0))]
    assert [(r['err_speed_rel'], r['wall_per_sim_s']) for r in bench.pareto_front(rows)] == \
        [(1e-6, 5.0), (1e-5, 1.5), (1e-3, 1.0)]


def test_cli_bench_reduced(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    scene_file = tmp_path / 'mini_lever.yaml'
    scene_file.write_text(yaml.safe_dump(SCENE))
    out = tmp_path / 'out'
    rc = main(['bench', '--scenes', str(scene_file), '--solvers', 'dopri5', '--fidelities', 'exact',
               '--baselines', 'RK45', '--tolerances', '1e-4,1e-8', '--horizon', '0.1', '--samples', '10',
               '--repeats', '1', '--exchange-steps', '1e-3', '--no-ros', '--out', str(out)])
    assert rc == 0
    text = capsys.readouterr().out
    assert '# cvj_ros work-precision benchmark' in text and 'mini_lever' in text
    assert sorted(p.name for p in out.iterdir()) == ['bench.csv', 'bench.md', 'lockstep.csv', 'lockstep.png',
                                                     'rhs.csv', 'wp_mini_lever.png']
    assert '## Speedups per error level against each baseline family' in text
    data = np.genfromtxt(out / 'bench.csv', delimiter=',', names=True, dtype=None, encoding='utf-8')
    assert np.all(np.isfinite(data['err_speed_rel']))


def test_cli_bad_scene_and_option(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(['bench', '--scenes', 'no_such_scene_xyz', '--no-ros']) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith('cvj-sim: error: scene: ')
    assert main(['bench', '--tolerances', '2', '--no-ros']) == 2
    assert capsys.readouterr().err.startswith('cvj-sim: error: --tolerances:')
    assert main(['bench', '--passes', '0', '--no-ros']) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ['cvj-sim: error: --passes: must be >= 1, got 0']


def test_rigid_fidelity_and_no_energy_rows(tmp_path: Path) -> None:
    """The 'rigid' fidelity (exact joints, every spring rigid) and the runs without the work
    integrals (energy 'off') are extra project rows, labelled in the CSV and the report; the
    default runs ('on') keep their labels; a scene without a spring runs 'rigid' as 'exact'
    (the same model: not rerun)."""
    no_spring = dict(SCENE, name='mini_rigid', driveline=[d for d in SCENE['driveline']
                                                          if d['type'] != 'spring'])
    cfg = bench.BenchConfig(scenes=[parse_scene(SCENE), parse_scene(no_spring)], solvers=('dopri5',),
                            tolerances=(1e-4, 1e-7), fidelities=('exact', 'rigid'), energy=('on', 'off'),
                            baselines=('RK45',), compiled_baselines=False, expert_methods=(), horizon=0.2,
                            samples=10, repeats=1, min_timed_s=0.0, exchange_steps=(), lockstep_scenes=(),
                            round_trip_n=0)
    res = bench.run_bench(cfg, tmp_path, log=lambda m: None)
    assert len(res['rows']) <= bench.planned_runs(cfg)
    with (tmp_path / 'bench.csv').open() as fh:
        rows = [r for r in csv.DictReader(fh) if r['family'] == 'project']
    # mini_lever: 2 fidelities x 2 tol x (land, dense) x (on, off); mini_rigid: exact only
    assert len(rows) == 16 + 8
    for r in rows:
        assert r['ok'] == 'True', r
        assert r['energy'] in ('on', 'off')
        assert r['label'].endswith(' no-energy') == (r['energy'] == 'off'), r
        assert (r['levels'] == 'hooke=exact bush=rigid') == (r['fidelity'] == 'rigid'), r
    assert {r['fidelity'] for r in rows if r['scene'] == 'mini_rigid'} == {'exact'}
    from cvj_ros.bench_report import read_bench_csv   # the report's labels, from the CSV
    for r in read_bench_csv(tmp_path / 'bench.csv'):
        if r['family'] == 'project':
            assert bench._config_label(r).endswith(' no-energy') == (r['energy'] == 'off')
    # the rigid model loses the spring's twist: its error is the model's, not the tolerance's
    lever = [r for r in rows if r['scene'] == 'mini_lever']
    rigid = min(float(r['err_speed_rel']) for r in lever if r['fidelity'] == 'rigid')
    exact = min(float(r['err_speed_rel']) for r in lever if r['fidelity'] == 'exact')
    assert rigid > 100 * exact
    md = (tmp_path / 'bench.md').read_text()
    assert 'no-energy' in md and 'rigid' in md


def test_run_without_work_integrals_keeps_the_speeds() -> None:
    """``Simulation(track_energy=False)`` (the bench's energy 'off' rows) integrates 2 n_dof
    states instead of 2 n_dof + 3; the work integrals' absence changes the error norm (its
    RMS over fewer components) and so the steps, not the equations: the speeds stay within
    the tolerance (relative to the largest speed) of the default run's. Measured up to
    0.49 tol over dopri5, dop853, vern6 and rosenbrock at 1e-3, 1e-6 and 1e-9."""
    from cvj_ros.physics.simulate import Simulation
    sc = parse_scene(SCENE)
    for method in ('dopri5', 'dop853', 'vern6', 'rosenbrock'):
        for tol in (1e-3, 1e-6, 1e-9):
            on, off = (Simulation(sc, method=method, rtol=tol, atol=tol, track_energy=te)
                       for te in (True, False))
            assert off.driveline.x0.size == on.driveline.x0.size - 3 == 2 * on.driveline.n_dof
            a, b = on.run(1.0, sample_dt=0.05), off.run(1.0, sample_dt=0.05)
            scale = float(np.max(np.abs(a.velocity)))
            assert float(np.max(np.abs(a.velocity - b.velocity))) <= tol * scale, (method, tol)
            assert np.all(np.isnan(b.energy_residual)) and np.all(np.isfinite(a.energy_residual))


def test_energy_option_checked(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(['bench', '--energy', 'maybe', '--no-ros']) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["cvj-sim: error: --energy: unknown value 'maybe'; one of on, off"]
    assert main(['bench', '--fidelities', 'stiff', '--no-ros']) == 2
    assert capsys.readouterr().err.startswith("cvj-sim: error: --fidelities: unknown fidelity 'stiff'")


def test_budget_exceeded_is_recorded_not_fatal(tmp_path: Path) -> None:
    """Explicit dopri5 on a 1e6 N m/rad spring between small inertias is stability-limited
    (h < ~2.8/omega_n): with a small rhs budget the run is recorded as failed, the
    linearly implicit solver still succeeds, and the report lists the failure."""
    stiff = dict(SCENE, name='mini_stiff', driveline=[
        {'type': 'inertia', 'name': 'a', 'J': 0.01},
        {'type': 'spring', 'name': 's', 'stiffness': 1e6, 'damping': 5.0},
        {'type': 'inertia', 'name': 'b', 'J': 0.01}], load={'model': 'constant', 'torque': 10.0})
    cfg = bench.BenchConfig(scenes=[parse_scene(stiff)], solvers=('dopri5', 'rosenbrock'), tolerances=(1e-3,),
                            fidelities=('exact',), baselines=('RK45',), horizon=0.2, samples=4, repeats=1,
                            max_rhs_evals=3000, exchange_steps=(), lockstep_scenes=(), round_trip_n=0)
    res = bench.run_bench(cfg, tmp_path, log=lambda m: None)
    by = {(r['family'], r['solver']): r for r in res['rows']}
    assert not by[('project', 'dopri5')]['ok'] and 'rhs evaluations' in by[('project', 'dopri5')]['note']
    assert not by[('baseline', 'RK45')]['ok']
    assert by[('project', 'rosenbrock')]['ok'] and by[('project', 'rosenbrock')]['err_speed_rel'] < 1e-2
    assert 'runs failed or exceeded the budget' in (tmp_path / 'bench.md').read_text()


def test_repeats_are_spread_over_passes_and_rows_keep_no_private_keys(
        result: tuple[dict, Path]) -> None:
    """repeats=2 over the default 2 passes: every ok row was timed once per pass (2 runs),
    and the closures kept for the second pass are gone from the rows (and the CSV)."""
    res, out = result
    ok = [r for r in res['rows'] if r['ok']]
    assert ok and all(r['repeats'] == 2 for r in ok)
    assert not any(k.startswith('_') for r in res['rows'] for k in r)
    with open(out / 'bench.csv', newline='') as f:
        assert not any(k.startswith('_') for k in next(csv.DictReader(f)))


def test_retime_passes_takes_the_min_over_all_passes() -> None:
    """Unit: a configuration slow in its first pass and fast in the second reports the fast
    time; one that fails in a later pass keeps its first-pass figures."""
    cfg = bench.BenchConfig(repeats=5, passes=3, min_timed_s=0.0)
    assert bench._first_pass_repeats(cfg) == 2
    calls = {'a': 0, 'b': 0}

    def fast_later() -> tuple[None, int, int]:
        calls['a'] += 1
        return None, 1, 0

    def fails_later() -> tuple[None, int, int]:
        calls['b'] += 1
        raise ArithmeticError('boom')

    rows = [{'ok': True, '_once': fast_later, '_walls': [0.5, 0.4], 'wall_s': 0.4},
            {'ok': True, '_once': fails_later, '_walls': [0.3], 'wall_s': 0.3, 'repeats': 1},
            {'ok': False, 'note': 'failed'}]
    bench.retime_passes(rows, cfg, horizon=2.0)
    assert calls['a'] == 3                      # 5 repeats: 2 in the first pass, 2 + 1 later
    assert rows[0]['repeats'] == 5 and rows[0]['wall_s'] < 0.4
    assert rows[0]['wall_per_sim_s'] == rows[0]['wall_s'] / 2.0
    assert rows[1]['wall_s'] == 0.3 and rows[1]['repeats'] == 1
    assert all('_once' not in r and '_walls' not in r for r in rows)


def test_report_gives_the_rhs_of_the_hand_written_reference_model(result: tuple[dict, Path]) -> None:
    """Issue 9's 25 ns figure is for a 2-DOF engine-spring-Hooke-load rhs: the bench times
    the kernel's rhs of that model (exact Hooke, compiled, not the Python fallback) and
    bench.md says so beside the aim."""
    res, out = result
    ref = res['rhs_reference']
    assert ref['compiled_ns'] > 0 and ref['python_us'] > 0
    from cvj_ros.physics.simulate import Simulation
    sim = Simulation(bench.hooke_2dof_scene())
    assert sim.backend == 'kernel' and sim.driveline.n_dof == 2
    md = (out / 'bench.md').read_text()
    assert "reference: a hand-written compiled rhs at 25 ns" in md
    # the three hand-written models, timed as an integrator's stage calls them (CPU time)
    assert set(ref['hand']) == set(bench.HAND_WRITTEN)
    assert all(h['loop'] == 'chain' and h['clock'] == 'cpu' for h in ref['hand'].values())
    assert md.count('CPU time per integrator-like call') == len(bench.HAND_WRITTEN)


def test_short_runs_repeat_until_they_fill_the_minimum_time() -> None:
    """Unit (timeit's autorange): a run far shorter than min_total_s is repeated beyond
    ``repeats`` until the walls fill it, never past max_repeats; a run that fills it alone
    is called ``repeats`` times; the per-pass share splits cfg.min_timed_s and max_repeats."""
    calls = {'n': 0}

    def quick() -> tuple[None, int, int]:
        calls['n'] += 1
        return None, 1, 0

    t = bench._time_runs(quick, 3, min_total_s=0.05, max_repeats=40)
    assert t['repeats'] == calls['n'] == 40          # 40 no-op calls fill far less than 50 ms
    calls['n'] = 0

    def slow() -> tuple[None, int, int]:
        calls['n'] += 1
        time.sleep(0.01)
        return None, 1, 0

    t = bench._time_runs(slow, 2, min_total_s=0.015, max_repeats=40)
    assert t['repeats'] == 2                         # 2 x 10 ms fill 15 ms
    assert bench._autorange(bench.BenchConfig(min_timed_s=0.02, max_repeats=200, passes=2)) == \
        {'min_total_s': 0.01, 'max_repeats': 100}


def test_real_lockstep_reports_both_scenes_and_modes_against_their_targets(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """--real-lockstep times `cvj-sim run` one process per node and --composed on both of
    issue 10's scenes, in rounds that run every scene and mode once (issue 10); bench.md
    gives each run with its target and the overhead against the round trip of the same
    topology, then the median per scene and mode (ROS runs replaced by fixed figures here:
    the real ones are the e2e tests' job)."""
    calls = []
    walls = {('kavz685_lever', False): [600.0, 450.0], ('kavz685_lever', True): [100.0, 80.0],
             ('fwd_halfshaft', False): [700.0, 650.0], ('fwd_halfshaft', True): [110.0, 120.0]}

    def fake_run(scene_name: str, *, duration: float, composed: bool = False, timeout: float = 300.0):
        calls.append((scene_name, duration, composed))
        wall = walls[(scene_name, composed)].pop(0)
        return {'scene': scene_name, 'exchanges': 5000, 'mode': 'composed' if composed else 'separate',
                'exchange_wall_us_mean': wall, 'integration_us_mean': 10.0, 'overhead_us_mean': wall - 10.0,
                'lockstep_wait_us_mean': wall / 2, 'state_us_mean': 5.0, 'real_time_factor': 1e3 / wall}
    monkeypatch.setattr(bench, 'real_lockstep_run', fake_run)
    monkeypatch.setattr(bench, 'measure_rclpy_round_trip', lambda n: {
        'events': {'us_mean': 20.0}, 'events2': {'us_mean': 60.0}, 'events_ipc2': {'us_mean': 400.0}})
    cfg = bench.BenchConfig(scenes=[parse_scene(SCENE)], solvers=('dopri5',), tolerances=(1e-4,),
                            fidelities=('exact',), baselines=('RK45',), repeats=1, passes=1,
                            horizon=0.05, samples=20, exchange_steps=(1e-3,), real_lockstep=True,
                            lockstep_scenes=('kavz685_lever', 'fwd_halfshaft'))
    res = bench.run_bench(cfg, tmp_path, log=lambda m: None)
    one_round = [('kavz685_lever', 5.0, False), ('kavz685_lever', 5.0, True),
                 ('fwd_halfshaft', 5.0, False), ('fwd_halfshaft', 5.0, True)]
    assert calls == one_round * 2                    # alternating: round 1, then round 2
    assert [(r['round'], r['mode']) for r in res['real_lockstep']][:2] == [(1, 'separate'), (1, 'composed')]
    md = (tmp_path / 'bench.md').read_text()
    # one row per run: (600 - 10) / 400 = 1.48x inter-process; (100 - 10) / 60 = 1.50x in-process
    assert '| 1 | kavz685_lever | separate | 600 | 10 | 300 | 5 | 590 | 1.48x (400 us) | 1.67 (>= 2) |' in md
    assert '| 1 | kavz685_lever | composed | 100 | 10 | 50 | 5 | 90 | 1.50x (60 us) | 10 (>= 10) |' in md
    assert '| 2 | fwd_halfshaft | composed | 120 |' in md
    # medians: kavz separate 1.67 and 2.22 -> 1.94, below 2 in one run
    assert ('kavz685_lever, separate: real-time factor median 1.94 (range 1.67-2.22 over 2 runs), '
            'target >= 2: not met') in md
    assert 'kavz685_lever, composed: real-time factor median 11.2 (range 10-12.5 over 2 runs), target >= 10: met' in md
    assert 'fwd_halfshaft, composed: real-time factor median 8.71' in md and 'not met' in md


def test_real_lockstep_median_notes_runs_that_did_not_finish() -> None:
    real = [{'scene': 's', 'mode': 'separate', 'note': 'cvj-sim run exited 2: x', 'round': 1},
            {'scene': 's', 'mode': 'separate', 'real_time_factor': 2.5, 'overhead_us_mean': 390.0,
             'round': 2}]
    (m,) = bench.real_lockstep_medians(real)
    assert (m['runs'], m['finished'], m['rtf_median']) == (2, 1, 2.5)
    lines = '\n'.join(bench._real_lockstep_lines(real, {}))
    assert '| 1 | s | separate | cvj-sim run exited 2: x |' in lines
    assert 'n/a (round trip not measured)' in lines


def test_startup_times_a_cold_compile_in_an_empty_cache_then_warm_commands(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """--startup (issue 9): the warm-up runs once with NUMBA_CACHE_DIR pointing at an empty
    directory, then `cvj-sim simulate kavz685_lever --duration 2` three times on that same
    cache; bench.md gives both with the 1.5 s target (subprocesses faked here: the real cold
    compile takes ~100 s; test/commands/test_simulate_startup.py covers the warm command)."""
    seen = []

    class Done:
        returncode = 0
        stdout = stderr = ''

    real_run = bench.subprocess.run

    def fake_run(cmd, *args, env=None, **kw):
        if env is None:      # not kernel_startup's (platform.processor() runs uname once)
            return real_run(cmd, *args, **kw)
        seen.append((cmd, env['NUMBA_CACHE_DIR']))
        if 'warmup' in cmd[-1]:
            done = Done()
            done.stdout = 'kernel dopri5: compiled in 9.0 s\nkernel ready: 71.2 s (two processes)\n'
            return done
        assert not any(Path(env['NUMBA_CACHE_DIR']).glob('*'))   # nothing cached by the fakes
        return Done()
    monkeypatch.setattr(bench.subprocess, 'run', fake_run)
    st = bench.kernel_startup(warm_runs=3)
    assert seen[0][0][1:] == ['-m', 'cvj_ros.physics.kernel.warmup']
    assert [c[0][1:] for c in seen[1:]] == [['simulate', 'kavz685_lever', '--duration', '2']] * 3
    assert len({d for _c, d in seen}) == 1                      # one cache: cold, then warm
    assert st['warm_runs'] == 3 and st['cold_compile_s'] >= 0.0
    assert st['cold_compile_how'] == 'two processes'
    monkeypatch.setattr(bench, 'kernel_startup', lambda: {
        'cold_compile_s': 98.7, 'cold_compile_how': 'two processes',
        'warm_simulate_s_median': 1.04, 'warm_simulate_s_min': 0.97, 'warm_runs': 3})
    monkeypatch.setattr(bench, 'measure_rclpy_round_trip', lambda n: {})
    cfg = bench.BenchConfig(scenes=[parse_scene(SCENE)], solvers=('dopri5',), tolerances=(1e-4,),
                            fidelities=('exact',), baselines=('RK45',), repeats=1, passes=1,
                            horizon=0.05, samples=20, exchange_steps=(1e-3,), startup=True)
    bench.run_bench(cfg, tmp_path, log=lambda m: None)
    md = (tmp_path / 'bench.md').read_text()
    assert 'cold compile' in md and ': 98.7 s (two processes)' in md
    assert '1.04 s median, 0.97 s min of 3 (target <= 1.5 s)' in md


def test_real_lockstep_run_reads_the_runs_report(monkeypatch: pytest.MonkeyPatch) -> None:
    """The figures of a real run come from its report.json - the loop timing and the
    real-time factor `cvj-sim run` prints - so the bench and the run's report agree; a run
    without loop timing or with an unreadable report gives a note (subprocess faked: the
    real runs are the e2e tests' job)."""
    import json
    import subprocess

    timing = {'exchange_wall_us_mean': 450.0, 'integration_us_mean': 25.0, 'overhead_us_mean': 425.0,
              'lockstep_wait_us_mean': 300.0, 'state_us_mean': 80.0}
    reports: list = [{'real_time_factor': 2.2, 'counts': {'/driveline/joint_states': 5001},
                      'metrics': {'loop_timing': timing}},
                     {'real_time_factor': 2.2, 'counts': {}, 'metrics': {}}, None]
    seen = []

    def fake_run(cmd, **_kw):
        seen.append(cmd)
        out = Path(cmd[cmd.index('--out') + 1])
        out.mkdir(parents=True)
        rep = reports.pop(0)
        (out / 'report.json').write_text('{' if rep is None else json.dumps(rep))
        return subprocess.CompletedProcess(cmd, 0, '', '')
    monkeypatch.setattr(subprocess, 'run', fake_run)
    r = bench.real_lockstep_run('kavz685_lever', duration=5.0, composed=True)
    assert seen[0][1:3] == ['run', 'kavz685_lever'] and '--composed' in seen[0]
    assert r == {'scene': 'kavz685_lever', 'exchanges': 5000, 'process_wall_s': r['process_wall_s'],
                 'mode': 'composed', **timing, 'real_time_factor': 2.2}
    assert 'no coupling-node loop diagnostics' in bench.real_lockstep_run('s', duration=1.0)['note']
    assert bench.real_lockstep_run('s', duration=1.0)['note'].startswith('report.json unreadable')


def test_compiled_baselines_pack_the_model_over_the_bench_horizon(monkeypatch: pytest.MonkeyPatch) -> None:
    """The compiled-rhs solve_ivp baseline and the numbalsoda expert pack the kernel model
    over the bench's horizon (kavz685_lever's random load: floor(0.5 / 0.01) + 6 = 56 knots,
    not the 206 of the scene's 2 s), as Simulation does over a run's duration; their results
    (errors, nfev, njev) are those of the model packed over the scene's duration, bit for bit
    (each knot is a function of its index)."""
    from cvj_ros.physics.kernel import layout
    from cvj_ros.physics.kernel.layout import H_LOAD_F
    from cvj_ros.physics.scene import load_scene, shipped_scenes
    scene = load_scene(shipped_scenes()['kavz685_lever'])
    cfg = bench.BenchConfig(horizon=0.5, samples=10, repeats=1, min_timed_s=0.0, passes=1)
    prob = bench.prepare(scene, cfg, reference_tol=1e-9)
    assert prob.horizon == 0.5 < scene.duration
    build = layout.build_model
    packed: list[tuple[float, int]] = []

    def record(*args, horizon=None, **kw):
        model = build(*args, horizon=horizon, **kw)
        packed.append((horizon, int(model.fp[int(model.ip[H_LOAD_F]) + 4])))
        return model

    def whole(*args, horizon=None, **kw):       # the packing before: max(horizon, duration)
        return build(*args, horizon=max(horizon, float(scene.duration)), **kw)

    def rows() -> list[dict]:
        out = [bench.run_baseline(prob, method='RK45', tol=1e-6, cfg=cfg, compiled=True)]
        out += [bench.run_expert(prob, method=m, tol=1e-6, cfg=cfg)
                for m in bench.expert_methods_run(bench.BenchConfig())]
        return out

    monkeypatch.setattr(layout, 'build_model', record)
    now = rows()
    # (Simulation itself packs over a zero horizon once: its test whether the kernel covers
    # the scene)
    assert packed.count((0.5, 56)) == len(now) and set(packed) == {(0.0, 6), (0.5, 56)}, packed
    monkeypatch.setattr(layout, 'build_model', whole)
    before = rows()
    keys = ('ok', 'err_speed_rel', 'err_angle_rad', 'nfev', 'njev')
    assert [[r.get(k) for k in keys] for r in now] == [[r.get(k) for k in keys] for r in before]
    assert all(r['ok'] for r in now), [r.get('note') for r in now]
