"""`cvj-sim bench --sweep N`: the line's arithmetic (efficiency, 10 000-variant figure) on
given rates, and its argument check (the timed run itself is not a test: see
docs/sweeps.md for measured figures)."""
from __future__ import annotations

import pytest

from cvj_ros.bench import format_sweep_rates
from cvj_ros.cli import main


def test_format_sweep_rates() -> None:
    rows = [{'scene': 'kavz685_lever', 'variants': 400, 'workers': 1, 'rate': 60.0,
             'startup_s': 2.0, 'total_wall_s': 9.0, 'efficiency': 1.0},
            {'scene': 'kavz685_lever', 'variants': 400, 'workers': 2, 'rate': 108.0,
             'startup_s': 3.0, 'total_wall_s': 7.0, 'efficiency': 108.0 / 120.0}]
    lines = format_sweep_rates(rows).splitlines()
    assert lines[0].startswith('sweep kavz685_lever: 400 variants, 1 worker: 60.0 variants/s after '
                               '2.0 s start-up (9.0 s wall), scaling efficiency 100 %')
    assert 'scaling efficiency 90 %' in lines[1]
    # start-up + 10 000 / 108 variants/s = 3 + 92.6 s
    assert lines[2].startswith('sweep: 10 000 variants would take ~96 s with 2 workers (target <= 60 s)')


def test_bench_sweep_argument(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(['bench', '--sweep', '0']) == 2
    assert capsys.readouterr().err.strip() == ('cvj-sim: error: --sweep: must be in 1..1000000 '
                                               'variants, got 0')
