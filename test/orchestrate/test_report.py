"""The run report's wall-time, real-time factor and per-exchange lines on fabricated results
(facts: what the time went to and what the factor is computed on; no development targets,
those are `cvj-sim bench`'s); the e2e tests check them in real runs."""
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


@pytest.mark.parametrize(('process', 'rtf'), [('composed', 12.5), ('composed', 8.0),
                                             ('separate, hosted monitor_node', 1.6)])
def test_loop_line_gives_the_split_and_no_development_target(process: str, rtf: float) -> None:
    line = loop_line(_result(process=process, rtf=rtf))
    assert line is not None
    assert f'wall {1e3 / rtf:.0f} us = integration 11 us + overhead {1e3 / rtf - 11:.0f} us' in line
    assert line.endswith('(lockstep wait 60 us, state evaluation + publication 9 us)')
    assert 'target' not in line and 'met' not in line
    assert REAL_TIME_TARGETS == {'composed': 10.0, 'separate': 2.0}   # cvj-sim bench's


def test_loop_line_only_for_lockstep_with_loop_diagnostics() -> None:
    assert loop_line(_result(process='composed', rtf=1.0, mode='free-run')) is None
    r = _result(process='composed', rtf=12.0)
    r.metrics = {}
    assert loop_line(r) is None


def test_print_report_states_the_whole_command_and_the_rate_basis() -> None:
    """Wall time of the whole command split into start-up, loop and the phases after it; the
    real-time factor with the simulated span and the loop wall time it is computed on."""
    r = _result(process='composed', rtf=12.5)
    r.wall_time = 9.0
    r.phases = {'loop_started': 1.5, 'coupling_exited': 1.9, 'drained': 2.2, 'bag_closed': 2.4,
                'report_done': 9.0}
    out = io.StringIO()
    print_report(r, out)
    lines = out.getvalue().splitlines()
    i = next(k for k, ln in enumerate(lines) if ln.startswith('  wall time'))
    assert lines[i] == ('  wall time 9.00 s: start-up 1.50 s, loop 0.400 s, after the loop 7.10 s '
                        '(last messages 0.30 s, closing the bag 0.20 s, report 6.60 s)')
    assert lines[i + 1] == ('  real-time factor 12.5 = 5 s simulated / 0.400 s of loop (first to '
                            'last joint state recorded); 0.556 over the whole command; wall per '
                            'exchange step 80 us')
    assert lines[i + 2].startswith('  loop per exchange: wall 80 us')
    assert 'target' not in out.getvalue()


def test_wall_line_says_how_much_of_the_start_up_was_compiling() -> None:
    """A run that compiled its kernel first (kernel/prepare.py) says so inside the start-up."""
    from cvj_ros.orchestrate.report import wall_line
    r = _result(process='separate', rtf=2.0)
    r.wall_time = 50.0
    r.phases = {'kernel_compile_s': 40.0, 'loop_started': 45.0}
    assert wall_line(r) == ('  wall time 50.00 s: start-up 45.00 s (compiling the physics kernel '
                            '40.00 s), loop 2.500 s')


def test_run_notes_name_a_speed_trend_unless_the_line_stalled() -> None:
    """`cvj-sim run`'s notes after the report carry the report's speed trend (computed from
    the bag, test_report_stream.py) as `simulate` does; a stall line replaces it (the trend
    of a stalled line is not the point)."""
    from cvj_ros.commands.run import degenerate_notes
    from cvj_ros.physics.scene import find_scene
    trend = ('speed trend: wheel accelerates by +8 rad/s over the window (+8 rad/s^2), 100% of '
             'its max - min speed: the speed nonuniformity there measures that trend, not a fluctuation')
    r = _result(process='composed', rtf=10.0)
    r.scene_path = str(find_scene('kavz685_lever'))
    r.metrics = {'shafts': {'engine_crank': {'mean_speed': 150.0}, 'wheel': {'mean_speed': 150.0}},
                 'speed_trend': trend}
    assert degenerate_notes(r) == [trend]
    r.metrics['speed_trend'] = None
    assert degenerate_notes(r) == []
    r.metrics.update(speed_trend=trend, shafts={'engine_crank': {'mean_speed': 1e-3}})
    notes = degenerate_notes(r)
    assert len(notes) == 1 and notes[0].startswith('stall: ')


@pytest.mark.parametrize('scene', ['launch_clutch', 'fwd_axle', 'launch_clutch_chain'])
def test_run_notes_name_the_trend_on_vehicle_and_mode_scenes(scene) -> None:
    """A vehicle tree or a mode scene has no serial Driveline for the fastest-mode check; the
    speed trend is still named (a launch from rest is all trend)."""
    from cvj_ros.commands.run import degenerate_notes
    from cvj_ros.physics.scene import find_scene
    trend = 'speed trend: wheel_left accelerates ...'
    r = _result(process='composed', rtf=1.0)
    r.scene_path = str(find_scene(scene))
    r.metrics = {'shafts': {'engine_crank': {'mean_speed': 150.0}}, 'speed_trend': trend}
    assert degenerate_notes(r) == [trend]


def test_free_run_line_states_the_skipped_share() -> None:
    """One line; the skipped ticks with their share of all ticks, none when nothing was
    skipped (the numbers of a launch_clutch free run that fell behind at 1 ms)."""
    from cvj_ros.orchestrate.report import free_run_line
    fr = {'catch_up': 'skip', 'ticks_run': 1328, 'ticks_skipped': 8672, 'overruns': 8673,
          'lateness_us_p50': 13803.8, 'lateness_us_p99': 758578.0, 'lateness_us_max': 844091.0,
          'drift_s': 0.0187685, 'drift_max_s': 0.845076}
    line = free_run_line(fr)
    assert '\n' not in line
    assert '1328 ticks run, 8672 skipped (86.7 % of the ticks), 8673 overruns' in line
    kept = free_run_line({**fr, 'ticks_run': 10000, 'ticks_skipped': 0, 'overruns': 0})
    assert '10000 ticks run, 0 skipped, 0 overruns' in kept
