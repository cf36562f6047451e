"""The expert baseline of `cvj-sim bench` (family baseline_expert: numbalsoda on the compiled
rhs through one cfunc). The plumbing tests skip cleanly where numbalsoda is not installed
(`make test` does not install it; `make bench` does); the skip-line tests run everywhere."""
from __future__ import annotations

import ctypes
import re
from pathlib import Path

import numpy as np
import pytest

from cvj_ros import bench, bench_expert
from cvj_ros.physics.scene import parse_scene

# a small lever-like unit (as test_bench.py): Hooke joint at 15 deg, elastic bushing
SCENE = {'name': 'mini_lever', 'duration': 1.0, 'engine': {'model': 'linear'},
         'load': {'model': 'constant', 'torque': 107.5}, 'initial': {'speed_rad_s': 30.0},
         'driveline': [{'type': 'inertia', 'name': 'engine_crank', 'J': 0.128},
                       {'type': 'joint', 'name': 'hooke', 'kind': 'hooke', 'params': {'beta_deg': 15}},
                       {'type': 'spring', 'name': 'bush', 'stiffness': 715.4, 'damping': 6.35},
                       {'type': 'inertia', 'name': 'wheel', 'J': 0.161}]}


def _cfg(**kw: object) -> bench.BenchConfig:
    base = dict(scenes=[parse_scene(SCENE)], solvers=('dop853',), tolerances=(1e-4, 1e-8),
                fidelities=('exact',), baselines=('RK45',), compiled_baselines=False, horizon=0.2,
                samples=10, repeats=1, passes=1, min_timed_s=0.0, exchange_steps=(), energy=('on',),
                lockstep_scenes=(), round_trip_n=0)
    base.update(kw)
    return bench.BenchConfig(**base)


def test_skip_line_is_printed_and_written_when_numbalsoda_is_missing(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Without numbalsoda the run goes on without the family and says why in one line."""
    monkeypatch.setattr(bench_expert, 'unavailable_reason', lambda: 'numbalsoda not importable (test)')
    lines: list[str] = []
    res = bench.run_bench(_cfg(), tmp_path, log=lines.append)
    skip = [ln for ln in lines if 'baseline_expert skipped' in ln]
    assert skip == ['[bench] baseline_expert skipped: numbalsoda not importable (test); `make bench` '
                    'installs it (pip install -r requirements-bench.txt: builds from source, needs '
                    'gfortran and cmake)']
    assert not [r for r in res['rows'] if r['family'] == 'baseline_expert']
    assert 'baseline_expert skipped: numbalsoda not importable (test)' in (tmp_path / 'bench.md').read_text()
    assert bench.planned_runs(_cfg()) == 2 + 2 * 1 + 2     # no expert runs planned either


def test_no_skip_line_when_the_family_is_not_asked_for(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(bench_expert, 'unavailable_reason', lambda: 'numbalsoda not importable (test)')
    lines: list[str] = []
    bench.run_bench(_cfg(expert_methods=()), tmp_path, log=lines.append)
    assert not [ln for ln in lines if 'baseline_expert' in ln]


def test_unavailable_reason_is_one_line() -> None:
    reason = bench_expert.unavailable_reason()
    try:
        import numbalsoda  # noqa: F401
    except Exception:
        assert reason and '\n' not in reason and reason.startswith('numbalsoda not importable')
    else:
        assert reason is None


# ------------------------------------------------------------------ with numbalsoda installed


def _model(scene_dict: dict) -> tuple:
    from cvj_ros.physics.kernel.layout import build_model
    from cvj_ros.physics.simulate import Simulation
    scene = parse_scene(scene_dict)
    sim = Simulation(scene, fidelity=bench.forced_levels(scene, 'exact'))
    return sim, build_model(sim.driveline, engine=sim.engine, load=sim.load, horizon=1.0)


def test_cfunc_is_the_compiled_rhs_and_counts_its_calls() -> None:
    """The cfunc numbalsoda calls gives kernel/rhs_nb.rhs's derivative bit for bit at an
    arbitrary state, reading the scene from the parameter block, and counts each call."""
    pytest.importorskip('numbalsoda')
    from cvj_ros.physics.kernel.rhs_nb import rhs
    sim, model = _model(SCENE)
    y = sim.driveline.x0.copy() + np.linspace(0.1, 0.7, sim.driveline.x0.size)
    want = np.empty_like(y)
    rhs(0.013, y, model.ip, model.fp, want)
    f = bench_expert.expert_cfunc()
    data = bench_expert.expert_data(model.ip, model.fp, y.size)
    got = np.full_like(y, np.nan)
    dptr = ctypes.POINTER(ctypes.c_double)
    for _ in range(3):
        f.ctypes(0.013, y.ctypes.data_as(dptr), got.ctypes.data_as(dptr), data.ctypes.data_as(dptr))
    assert np.array_equal(got, want)
    assert data[bench_expert.P_COUNT] == 3.0


def test_expert_rows_reach_the_reference_and_enter_the_level_table(tmp_path: Path) -> None:
    """Both methods at 1e-8 land within 1e-6 of the dop853 1e-10 reference on the same error
    grid (a tolerance-proportional error; 100x margin over the tolerance for the global error's
    growth over 0.2 s), count their rhs calls, and take part in the per-level speedups."""
    pytest.importorskip('numbalsoda')
    res = bench.run_bench(_cfg(), tmp_path, log=lambda m: None)
    rows = [r for r in res['rows'] if r['family'] == 'baseline_expert']
    assert sorted((r['solver'], r['tol']) for r in rows) == [
        ('dop853', 1e-8), ('dop853', 1e-4), ('lsoda', 1e-8), ('lsoda', 1e-4)]
    for r in rows:
        assert r['ok'], r
        assert r['nfev'] > 10
        if r['tol'] == 1e-8:
            assert r['err_speed_rel'] < 1e-6
    table = res['tables']['mini_lever']
    at = {e['level']: e for e in table}
    e = at[1e-3]
    assert e['baseline_expert'] is not None
    assert e['speedup_expert'] == pytest.approx(e['baseline_expert']['wall_per_sim_s'] / e['project']['wall_per_sim_s'])
    md = (tmp_path / 'bench.md').read_text()
    assert 'best numbalsoda (compiled rhs)' in md
    assert re.search(r'\| numbalsoda (lsoda|dop853) tol=1e-0\d \|', md)


def test_restart_at_breakpoints_matches_one_call() -> None:
    """Restarting at every knot of a random load gives the same samples as one call over the
    horizon to the tolerance (both against the same reference), and lands the rows with the
    breakpoints flag set."""
    pytest.importorskip('numbalsoda')
    scene = dict(SCENE, name='mini_random', load={'model': 'random', 'mean': 100.0, 'amplitude': 10.0,
                                                   'sample_interval': 0.01})
    cfg = _cfg(scenes=[parse_scene(scene)], tolerances=(1e-9,), horizon=0.1)
    prob = bench.prepare(cfg.scenes[0], cfg, reference_tol=1e-11)
    assert prob.has_breakpoints
    for method in bench_expert.EXPERT_METHODS:
        one = bench.run_expert(prob, method=method, tol=1e-9, cfg=cfg, restart=False)
        per = bench.run_expert(prob, method=method, tol=1e-9, cfg=cfg, restart=True)
        assert one['ok'] and per['ok'] and per['breakpoints'] and not one['breakpoints'], (one, per)
        assert per['err_speed_rel'] < 1e-6
        assert per['label'].endswith('restart-at-breaks')


def test_knots_an_ulp_from_a_sample_are_snapped_onto_it() -> None:
    """Knots at k x 10 ms meet the 50 ms samples up to an ulp: such a knot becomes the sample
    (no segment shorter than the span's 1e-12), knots at the span's ends are dropped."""
    t = np.linspace(0.0, 1.0, 21)
    knots = np.arange(0, 101) * 0.01
    s = bench_expert._snapped(knots, t)
    assert s.size == 99 and s[0] == 0.01 and s[-1] == 0.99
    assert np.min(np.diff(np.unique(np.concatenate((s, t))))) > 1e-3
    assert set(t[1:-1]) <= set(s)


def test_quiet_stdout_silences_file_descriptor_1_and_restores_it(capfd: pytest.CaptureFixture[str]) -> None:
    """numbalsoda's C and Fortran diagnostics go to fd 1, past sys.stdout: silenced during the
    family's runs, and the report printed after them still reaches stdout."""
    import os
    with bench_expert.quiet_stdout():
        os.write(1, b'the problem seems to become stiff\n')
    os.write(1, b'after\n')
    assert capfd.readouterr().out == 'after\n'


def test_quiet_stdout_drops_buffered_c_output(capfd: pytest.CaptureFixture[str]) -> None:
    """A C printf inside (buffered by libc, as numbalsoda's are) does not surface later."""
    import ctypes
    libc = ctypes.CDLL(None)
    with bench_expert.quiet_stdout():
        libc.printf(b'more than nmax = 250 steps are needed\n')
    libc.fflush(None)
    assert 'nmax' not in capfd.readouterr().out


def test_a_cfunc_that_does_not_compile_skips_the_family_with_one_line(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    pytest.importorskip('numbalsoda')

    def broken() -> None:
        raise RuntimeError('typing failed\nsecond line')
    monkeypatch.setattr(bench_expert, 'expert_cfunc', broken)
    lines: list[str] = []
    res = bench.run_bench(_cfg(tolerances=(1e-4,)), tmp_path, log=lines.append)
    assert [ln for ln in lines if 'skipped' in ln] == [
        '[bench] baseline_expert skipped: numbalsoda is installed but its cfunc did not compile '
        '(typing failed)']
    assert not [r for r in res['rows'] if r['family'] == 'baseline_expert']


@pytest.mark.parametrize('args, message', [
    ([], 'usage:'),
    (['/nonexistent/bench.csv'], '/nonexistent/bench.csv: cannot read the bench CSV'),
    (['README.md'], 'README.md: not a `cvj-sim bench` CSV'),
])
def test_expert_rounds_bad_input_is_one_line(args: list[str], message: str) -> None:
    """scripts/expert_rounds.py on a missing or wrong CSV: one line naming it, exit != 0."""
    import subprocess
    import sys
    root = Path(__file__).resolve().parents[1]
    out = subprocess.run([sys.executable, str(root / 'scripts' / 'expert_rounds.py'), *args],
                         cwd=root, capture_output=True, text=True, timeout=120)
    assert out.returncode != 0
    assert out.stderr.strip().startswith(message) and len(out.stderr.strip().splitlines()) == 1
    assert 'Traceback' not in out.stderr


def test_expert_cfuncs_are_not_disk_cached() -> None:
    """The cfuncs close over an intrinsic made in each process: numba's cache key would differ
    in every process, so a disk cache would never hit and would grow by a file per process."""
    assert type(bench_expert.expert_cfunc()._cache).__name__ == 'NullCache'
    assert type(bench_expert.mode_expert_cfunc()._cache).__name__ == 'NullCache'
