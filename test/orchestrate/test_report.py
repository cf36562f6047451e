"""The run report's per-exchange loop line (issue 10: the real-time targets shown in
`cvj-sim run`'s report), on fabricated results; the e2e tests check it in real runs."""
from __future__ import annotations

import io
from pathlib import Path

import pytest

from cvj_ros.orchestrate.options import RunResult
from cvj_ros.orchestrate.report import REAL_TIME_TARGETS, loop_line, print_report


def _result(*, process: str, rtf: float, h: float = 1e-3, mode: str = 'lockstep') -> RunResult:
    return RunResult(
        exit_code=0, out=Path('o'), bag=Path('o/bag'), scene_path='s.yaml', domain_id=7,
        sim_duration=5.0, exchange_step=h, steps_expected=5000, wall_time=7.0,
        loop_wall_time=5.0 / rtf, wall_per_step=1e-3 / rtf, real_time_factor=rtf,
        counts={'/driveline/joint_states': 5001}, node_exit_codes={},
        metrics={'loop_timing': {'exchange_wall_us_mean': 1e3 / rtf, 'integration_us_mean': 11.0,
                                 'overhead_us_mean': 1e3 / rtf - 11.0,
                                 'lockstep_wait_us_mean': 60.0, 'state_us_mean': 9.0}},
        settings={'mode': mode, 'process': process})


@pytest.mark.parametrize(('process', 'rtf', 'verdict'), [
    ('composed', 12.5, 'against the composed target >= 10: met'),
    ('composed', 8.0, 'against the composed target >= 10: not met'),
    ('separate, hosted monitor_node', 2.2, 'against the separate target >= 2: met'),
    ('separate, hosted monitor_node', 1.6, 'against the separate target >= 2: not met'),
])
def test_loop_line_gives_the_split_and_the_target_of_the_layout(process: str, rtf: float,
                                                                 verdict: str) -> None:
    line = loop_line(_result(process=process, rtf=rtf))
    assert line is not None and line.endswith(verdict)
    assert f'wall {1e3 / rtf:.0f} us = integration 11 us + overhead {1e3 / rtf - 11:.0f} us' in line
    assert '(lockstep wait 60 us, state evaluation + publication 9 us)' in line
    assert REAL_TIME_TARGETS == {'composed': 10.0, 'separate': 2.0}


def test_loop_line_only_states_a_target_for_1_ms_steps_and_only_for_lockstep() -> None:
    line = loop_line(_result(process='composed', rtf=30.0, h=5e-3))
    assert line is not None and 'target' not in line
    assert loop_line(_result(process='composed', rtf=1.0, mode='free-run')) is None
    r = _result(process='composed', rtf=12.0)
    r.metrics = {}
    assert loop_line(r) is None


def test_print_report_puts_the_loop_line_under_the_wall_time() -> None:
    out = io.StringIO()
    print_report(_result(process='composed', rtf=12.5), out)
    lines = out.getvalue().splitlines()
    i = next(k for k, ln in enumerate(lines) if ln.startswith('  wall time'))
    assert lines[i + 1].startswith('  loop per exchange: wall 80 us')
