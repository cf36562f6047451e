"""The per-level summary rebuilt from a bench.csv (cvj_ros/bench_report.py, `cvj-sim bench
--report`), on a small synthetic CSV whose speedups are worked out by hand below."""
from __future__ import annotations

import csv
from pathlib import Path

import pytest

from cvj_ros import bench, bench_report
from cvj_ros.cli import main


def _row(family: str, solver: str, tol: float, err: float, cost: float, nfev: int = 100,
         ok: bool = True, scene: str = 'mini') -> dict[str, object]:
    return {'scene': scene, 'family': family, 'solver': solver, 'fidelity': 'exact' if family == 'project' else '',
            'tol': tol, 'h': '', 'label': '', 'ok': ok, 'wall_s': cost, 'wall_spread': 0.0, 'repeats': 3,
            'wall_per_sim_s': cost, 'nfev': nfev, 'njev': 0, 'err_speed_rel': err, 'err_angle_rad': err,
            'levels': '', 'breakpoints': family != 'baseline_expert', 'sampling': 'land', 'note': ''}


# Levels 1e-3..1e-8. Project: dopri5 reaches 1e-3 at 1e-4 s/s, dop853 reaches 1e-7 at 3e-4.
# Plain solve_ivp: RK45 1e-3 at 5e-3 (50x), RK45 1e-8 reaches 1e-8 at 6e-3 (20x where the
# project needs dop853; the project does not reach 1e-8). Compiled rhs: LSODA 1e-3 at 1e-3 (10x).
# Expert: lsoda reaches 1e-3 at 3e-4 (3x), dop853 reaches 1e-8 at 4.5e-4 (1.5x from 1e-4 on).
ROWS = [_row('project', 'dopri5', 1e-3, 5e-4, 1e-4, 416),
        _row('project', 'dop853', 1e-6, 5e-8, 3e-4, 1226),
        _row('project', 'rk4', 1e-9, 1e-12, 1e-6, ok=False),          # failed: never counted
        _row('baseline', 'RK45', 1e-3, 5e-4, 5e-3),
        _row('baseline', 'RK45', 1e-8, 5e-9, 6e-3),
        _row('baseline_compiled', 'LSODA', 1e-3, 6e-4, 1e-3),
        _row('baseline_expert', 'lsoda', 1e-3, 4e-4, 3e-4),
        _row('baseline_expert', 'dop853', 1e-6, 1e-8, 4.5e-4)]


def _write(out: Path, rows: list[dict[str, object]]) -> None:
    out.mkdir(parents=True, exist_ok=True)
    with (out / 'bench.csv').open('w', newline='') as fh:
        w = csv.DictWriter(fh, fieldnames=bench.CSV_FIELDS)
        w.writeheader()
        w.writerows(rows)


def test_read_bench_csv_restores_types(tmp_path: Path) -> None:
    _write(tmp_path, ROWS)
    rows = bench_report.read_bench_csv(tmp_path / 'bench.csv')
    assert [r['ok'] for r in rows] == [True, True, False, True, True, True, True, True]
    assert rows[1]['wall_per_sim_s'] == 3e-4 and rows[1]['nfev'] == 1226 and rows[0]['h'] is None


def test_target_misses_by_hand(tmp_path: Path) -> None:
    _write(tmp_path, ROWS)
    misses = bench_report.target_misses(bench_report.read_bench_csv(tmp_path / 'bench.csv'))
    got = {(m['level'], m['target'].split()[2]): m for m in misses}
    # expert: 1.5x at 1e-4..1e-7, project unreachable at 1e-8; plain: 20x at 1e-4..1e-7, unreachable at 1e-8
    assert sorted(got) == sorted((lv, fam) for lv in (1e-4, 1e-5, 1e-6, 1e-7, 1e-8)
                                 for fam in ('baseline_expert', 'plain'))
    assert got[(1e-5, 'baseline_expert')]['speedup'] == pytest.approx(1.5)
    assert got[(1e-5, 'plain')]['speedup'] == pytest.approx(20.0)
    assert 'does not reach' in got[(1e-8, 'plain')]['text']


def test_cli_report_rebuilds_summary_from_csv(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    _write(tmp_path, ROWS)
    bench_report.write_rhs_csv(tmp_path / 'rhs.csv', {'mini': {'compiled_ns': 71.6, 'compiled_from_python_us': 1.0,
                                                               'python_us': 30.0}})
    assert main(['bench', '--report', str(tmp_path)]) == 0
    text = capsys.readouterr().out
    assert text == (tmp_path / 'summary.md').read_text()
    line_1e3 = next(ln for ln in text.splitlines() if ln.startswith('| mini | 1e-03 |'))
    cells = [c.strip() for c in line_1e3.split('|')[1:-1]]
    assert cells[2:] == ['dopri5 exact tol=1e-03', '0.0001', '416', '50.00x', '10.00x', '3.00x',
                         'numbalsoda lsoda tol=1e-03', '72']
    assert 'not met at 10 (scene, level, target):' in text


def test_rhs_ns_read_back_from_bench_md(tmp_path: Path) -> None:
    (tmp_path / 'bench.md').write_text(
        '## mini\n\nRight-hand side (exact fidelity, engine and load inside): compiled 65 ns per call '
        'from a compiled loop; 1.10 us per call from Python (the solve_ivp wrapper); Python reference '
        '30.1 us per call.\n\n## stiff\n\nRight-hand side cost: not measured (no kernel).\n')
    assert bench_report.read_rhs_ns(tmp_path) == {'mini': 65.0}


def test_cli_report_bad_dir_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(['bench', '--report', str(tmp_path / 'nothing')]) == 2
    assert capsys.readouterr().err.strip().splitlines() == [
        f'cvj-sim: error: --report: no bench.csv in {tmp_path / "nothing"}']
    (tmp_path / 'bench.csv').write_text('a,b\n1,2\n')
    assert main(['bench', '--report', str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith('cvj-sim: error: --report: ') and 'not a bench.csv' in err[0]
