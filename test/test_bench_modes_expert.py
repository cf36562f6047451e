"""The expert baseline of the mode scenes (family baseline_expert in cvj_ros.bench_modes):
numbalsoda on the kernel's compiled mode right-hand side, each mode segment ending at the
oracle run's event (oracle events). The numbalsoda tests skip where it is not installed
(`make test` does not install it; `make bench` does); the skip-line and table tests run
everywhere."""
from __future__ import annotations

import ctypes
import math
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip('numba')
from cvj_ros import bench_expert, bench_modes  # noqa: E402
from cvj_ros.physics.hybrid.from_scene import hybrid_simulation  # noqa: E402
from cvj_ros.physics.scene import load_scene, shipped_scenes  # noqa: E402


def _chain():
    return load_scene(shipped_scenes()['launch_clutch_chain'])


def _expert_run(scene, method: str, tol: float, oracle, duration: float, sample_dt: float):
    sim = hybrid_simulation(scene, method='dopri5', rtol=tol, atol=tol * 1e-2,
                            sample_dt=sample_dt, duration=duration)
    cls = bench_modes.ExpertHybridTreeSimulation if scene.is_tree else bench_modes.ExpertHybridSimulation
    return cls.expert(sim, method, oracle).run()


@pytest.mark.parametrize('name, kind', [('launch_clutch_chain', 0), ('launch_clutch', 1)])
def test_mode_cfunc_is_the_kernels_mode_rhs(name: str, kind: int, monkeypatch) -> None:
    """The cfunc numbalsoda calls gives the mode right-hand side the kernel's segments
    integrate (modes_nb.mode_eval / tree_modes_nb.tm_eval) bit for bit, on the arrays of a
    run's first mode at a perturbed state, and counts each call."""
    pytest.importorskip('numbalsoda')
    from cvj_ros.physics.kernel.modes_nb import mode_eval
    from cvj_ros.physics.kernel.tree_modes_nb import tm_eval
    seen = []
    real = bench_modes._expert_segment

    def spy(sim, kind_, ip, fp, *rest):
        seen.append((kind_, ip.copy(), fp.copy(), np.array(rest[4], dtype=float)))
        return real(sim, kind_, ip, fp, *rest)
    monkeypatch.setattr(bench_modes, '_expert_segment', spy)
    scene = load_scene(shipped_scenes()[name])
    oracle = bench_modes.oracle_run(scene, 0.2, 0.1)[1]
    _expert_run(scene, 'lsoda', 1e-6, oracle, 0.2, 0.1)
    k, ip, fp, y0 = seen[0]
    assert k == kind
    y = y0 + np.linspace(0.01, 0.07, y0.size)
    want = np.empty_like(y)
    sc = np.zeros(256)
    fp_want = fp.copy()
    (mode_eval if kind == 0 else tm_eval)(0.013, y, ip, fp_want, want, sc, False)
    f = bench_expert.mode_expert_cfunc()
    data = bench_expert.mode_expert_data(kind, ip, fp, y.size, sc)
    got = np.full_like(y, np.nan)
    dptr = ctypes.POINTER(ctypes.c_double)
    for _ in range(3):
        f.ctypes(0.013, y.ctypes.data_as(dptr), got.ctypes.data_as(dptr), data.ctypes.data_as(dptr))
    assert np.array_equal(got, want)
    assert data[bench_expert.P_COUNT] == 3.0


def test_expert_segments_agree_with_the_reference_on_launch_clutch_chain() -> None:
    """launch_clutch_chain's first 2 s (the brake sticks at 1.77 s, a located event, and is
    released by the command at 1.8 s; six segments): both numbalsoda methods at rtol 1e-8 take the oracle's events (the kernel's,
    the same as the Python reference's: element and mode), end their segments at its times,
    and land within 1e-6 of the Python reference's samples (relative to the largest speed).
    Measured: lsoda 5.6e-9, dop853 8.0e-8 (DOP853's error per tolerance is larger on this
    scene); 1e-6 is 100x rtol, the tolerance-proportional bound of the continuous scenes'
    expert test."""
    pytest.importorskip('numbalsoda')
    scene = _chain()
    ref = bench_modes.reference_run(scene, 2.0, 0.05, 'python')
    orc_res, oracle = bench_modes.oracle_run(scene, 2.0, 0.05)
    assert [(e.element, e.after) for e in orc_res.events] == [(e.element, e.after) for e in ref.events]
    assert len(oracle) == 6 and sum(1 for o in oracle if o[2] is not None) == 1
    for method in ('lsoda', 'dop853'):
        r = _expert_run(scene, method, 1e-8, oracle, 2.0, 0.05)
        assert [(e.element, e.after) for e in r.events] == [(e.element, e.after) for e in ref.events]
        assert [e.t for e in r.events] == [e.t for e in orc_res.events]
        assert r.speed.shape == ref.speed.shape
        err = bench_modes._speed_error(r, ref)
        assert err < 1e-6, (method, err)
        assert r.stats['nfev'] > 100


def test_witness_bisection_expert_finds_the_references_events() -> None:
    """The expert with its own event location (witnesses on the 1 ms grid, refinement to
    1e-12 s) on launch_clutch_chain's first 2 s: the reference's events, their times within
    1e-6 s, samples within 1e-6 (as the oracle expert) at rtol 1e-8; it does not read the
    oracle (an empty one is fine)."""
    pytest.importorskip('numbalsoda')
    scene = _chain()
    ref = bench_modes.reference_run(scene, 2.0, 0.05, 'python')
    for method in ('lsoda-bisect', 'dop853-bisect'):
        r = _expert_run(scene, method, 1e-8, [], 2.0, 0.05)
        assert [(e.element, e.after) for e in r.events] == [(e.element, e.after) for e in ref.events]
        assert max(abs(a.t - b.t) for a, b in zip(r.events, ref.events)) < 1e-6
        assert bench_modes._speed_error(r, ref) < 1e-6, method


def test_first_crossing_takes_the_earliest_row_in_the_witness_direction() -> None:
    W = np.array([[1.0, -1.0], [0.5, -0.5], [0.0, 0.2], [-1.0, 0.3]])
    assert bench_modes._first_crossing(W, np.array([-1, 1])) == (2, 0)      # both in row 2
    assert bench_modes._first_crossing(W, np.array([1, 1])) == (2, 1)       # only witness 1 rises
    assert bench_modes._first_crossing(W, np.array([1, -1])) == (-1, -1)
    assert bench_modes._first_crossing(W[:, :0], np.array([], dtype=int)) == (-1, -1)


def test_expert_stops_when_it_leaves_the_oracles_sequence() -> None:
    """An oracle that does not fit the run (its first segment starts elsewhere, or its event
    is no witness of the mode) stops the run with OracleMismatch: the expert never integrates
    a mode the oracle did not."""
    pytest.importorskip('numbalsoda')
    scene = _chain()
    oracle = bench_modes.oracle_run(scene, 2.0, 0.1)[1]
    with pytest.raises(bench_modes.OracleMismatch, match='oracle'):
        _expert_run(scene, 'lsoda', 1e-6, [(0.5, 1.0, None)] + oracle[1:], 2.0, 0.1)
    bad = [(t0, t1, ('clutch', 'nonexistent', 0) if key else None) for t0, t1, key in oracle]
    with pytest.raises(bench_modes.OracleMismatch, match='not a witness'):
        _expert_run(scene, 'lsoda', 1e-6, bad, 2.0, 0.1)


def test_mode_study_expert_rows_csv_and_report(tmp_path: Path) -> None:
    """mode_study with both numbalsoda methods: baseline_expert rows for every method and
    tolerance (ok, finite error, the reference's events), the levels' expert speedups, the
    rows in modes.csv and the expert table with its verdict in modes.md."""
    pytest.importorskip('numbalsoda')
    lines: list[str] = []
    s = bench_modes.mode_study('launch_clutch_chain', tolerances=(1e-5, 1e-7), samples=10,
                               repeats=1, duration=2.0, expert_methods=('lsoda', 'dop853'),
                               baseline=False, log=lines.append)
    ex = [r for r in s['rows'] if r['family'] == 'baseline_expert']
    assert [(r['label'], r['tol']) for r in ex] == [
        ('numbalsoda lsoda (oracle events)', 1e-5), ('numbalsoda lsoda (oracle events)', 1e-7),
        ('numbalsoda dop853 (oracle events)', 1e-5), ('numbalsoda dop853 (oracle events)', 1e-7)]
    assert all(r['ok'] and math.isfinite(r['err_speed_rel']) and r['events'] == 2 for r in ex)
    assert all(r['repeats'] == 10 and r['steps'] is None for r in ex)
    assert s['oracle'] == {'segments': 6, 'events': 1}
    lv = {e['level']: e for e in s['levels']}
    e = lv[1e-3]
    assert e['baseline_expert'] is not None
    assert e['speedup_expert'] == pytest.approx(e['baseline_expert']['wall_s'] / e['project']['wall_s'])
    assert any('oracle events' in ln for ln in lines)
    csv_path, md_path = bench_modes.write_mode_outputs([s], tmp_path)
    text = csv_path.read_text()
    assert text.count('baseline_expert') == 4 and text.count('\nlaunch_clutch_chain,project,') == 2
    md = md_path.read_text()
    assert 'kernel vs numbalsoda on the same compiled mode rhs (oracle events)' in md
    assert '| 0.001 | ' in md.split('oracle events)')[1]
    assert '>= 2x against baseline_expert (CPU time and wall): ' in md


def test_mode_study_refuses_an_unknown_expert_method() -> None:
    with pytest.raises(ValueError, match="expert_methods: 'lsoda', 'dop853', 'lsoda-bisect', "
                                         "'dop853-bisect', not 'rk45'"):
        bench_modes.mode_study('launch_clutch_chain', expert_methods=('rk45',), log=lambda m: None)


def _row(family: str, label: str, tol: float, wall: float, cpu: float, err: float = 1e-9) -> dict:
    return {'scene': 'launch_clutch_chain', 'family': family, 'label': label, 'tol': tol,
            'ok': True, 'err_speed_rel': err, 'wall_s': wall, 'cpu_s': cpu,
            'wall_per_sim_s': wall / 10, 'repeats': 10, 'steps': None, 'nfev': 7, 'events': 14,
            'energy_residual': 1e-9, 'load': (1.0, 2.0)}


def test_expert_table_verdict_per_level() -> None:
    """The expert table takes the cheapest run of each family at each level; the verdict is
    'yes' only where the expert costs >= 2x the kernel in CPU time and in wall."""
    rows = [_row('project', 'kernel dopri5', 1e-6, 0.010, 0.008),
            _row('project', 'kernel vern7', 1e-6, 0.012, 0.009),   # dearer: not the best
            _row('baseline_expert', 'numbalsoda lsoda (oracle events)', 1e-6, 0.030, 0.024),
            _row('baseline_expert', 'numbalsoda dop853 (oracle events)', 1e-7, 0.015, 0.020,
                 err=2e-7)]
    s = {'scene': 'launch_clutch_chain', 'duration': 10.0, 'reference': {}, 'rows': rows,
         'levels': bench_modes.mode_levels(rows), 'oracle': {'segments': 26, 'events': 14}}
    table = bench_modes.format_expert_table(s)
    assert ('| 1e-06 | dopri5 | 1e-06 | 8.0 | 10.0 | numbalsoda dop853 | 1e-07 | 20.0 | 15.0 | 2.50x | 1.50x '
            '| no | 1.0-2.0 |') in table
    assert ('| 1e-07 | dopri5 | 1e-06 | 8.0 | 10.0 | numbalsoda lsoda | 1e-06 | 24.0 | 30.0 | 3.00x | 3.00x '
            '| yes | 1.0-2.0 |') in table
    assert '26 segments, 14 located events' in table
    assert table.rstrip().endswith('held at 1e-07, 1e-08; not at 0.001, 0.0001, 1e-05, 1e-06.')
    assert bench_modes.format_expert_table(dict(s, rows=rows[:2])) == ''
    assert bench_modes.format_expert_table(s, 'baseline_expert_bisect') == ''
    rows.append(_row('baseline_expert_bisect', 'numbalsoda lsoda (witness bisection, 1 ms grid)',
                     1e-6, 0.025, 0.020))
    s = dict(s, rows=rows, levels=bench_modes.mode_levels(rows))
    bis = bench_modes.format_expert_table(s, 'baseline_expert_bisect')
    assert 'on a 1 ms grid' in bis and '| numbalsoda lsoda | 1e-06 | 20.0 | 25.0 | 2.50x | 2.50x | yes |' in bis
    assert bis.rstrip().endswith('>= 2x against baseline_expert_bisect (CPU time and wall): held at '
                                 'every level.')
    assert bench_modes.format_expert_table(s) == table       # the oracle's table is its own


def test_expert_skip_line_when_numbalsoda_is_missing(monkeypatch, tmp_path: Path) -> None:
    """Without numbalsoda the mode study goes on without the family, logs why in one line and
    modes.md carries that line instead of the expert table."""
    monkeypatch.setattr(bench_expert, 'unavailable_reason', lambda: 'numbalsoda not importable (test)')
    lines: list[str] = []
    s = bench_modes.mode_study('launch_clutch_chain', tolerances=(1e-5,), samples=5, repeats=1,
                               duration=0.5, expert_methods=('lsoda', 'dop853'), baseline=False,
                               log=lines.append)
    assert [r['family'] for r in s['rows']] == ['project']
    assert [ln for ln in lines if 'skipped' in ln] == [
        '[bench] launch_clutch_chain: baseline_expert skipped: numbalsoda not importable (test)']
    md = bench_modes.write_mode_outputs([s], tmp_path)[1].read_text()
    assert 'baseline_expert skipped: numbalsoda not importable (test)\n' in md
    assert 'oracle events' not in md


def test_run_bench_hands_the_expert_methods_to_the_mode_study(tmp_path, monkeypatch) -> None:
    """run_bench asks the mode study for the configured numbalsoda methods; its log and
    modes.md show the expert ratio per level, bench.md the verdict line per mode scene."""
    from cvj_ros import bench
    from cvj_ros.physics.scene import parse_scene
    rows = [_row('project', 'kernel dopri5', 1e-6, 0.010, 0.008),
            _row('baseline', 'solve_ivp RK45 + events', 1e-6, 0.5, 0.4),
            _row('baseline_expert', 'numbalsoda lsoda (oracle events)', 1e-6, 0.030, 0.024)]
    calls = []

    def study(name, **kw):
        calls.append(kw['expert_methods'])
        return {'scene': name, 'duration': 10.0, 'reference': {}, 'rows': rows,
                'levels': bench_modes.mode_levels(rows), 'oracle': {'segments': 26, 'events': 14}}
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
                            expert_methods=('lsoda',), mode_scenes=('launch_clutch_chain',))
    lines: list[str] = []
    bench.run_bench(cfg, tmp_path, log=lines.append)
    assert calls == [('lsoda', 'lsoda-bisect')]
    assert any('vs numbalsoda (oracle events) 3.00x' in ln for ln in lines)
    md = (tmp_path / 'modes.md').read_text()
    assert '| numbalsoda lsoda | 1e-06 | 24.0 | 30.0 | 3.00x | 3.00x | yes |' in md
    assert 'launch_clutch_chain,baseline_expert,numbalsoda lsoda (oracle events)' in \
        (tmp_path / 'modes.csv').read_text()
    assert ('- launch_clutch_chain: >= 2x against baseline_expert (CPU time and wall): held at '
            'every level.') in (tmp_path / 'bench.md').read_text()
