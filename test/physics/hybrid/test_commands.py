"""Command schedule: ramps, steps, gear steps, validation with field paths."""
from __future__ import annotations

import math

import pytest

from cvj_ros.errors import SceneError
from cvj_ros.physics.hybrid.commands import CommandSchedule


def test_ramps_steps_and_gears() -> None:
    s = CommandSchedule([(0.0, {'clutch': 1.0, 'gear': 1, 'throttle': 0.1}),
                         (1.0, {'clutch': 1.0}),
                         (2.0, {'clutch': 0.0, 'gear': 2}),
                         (3.0, {'throttle': 0.5}), (3.0, {'throttle': 0.2})])
    assert s.value('clutch', 0.5) == 1.0
    assert s.value('clutch', 1.5) == pytest.approx(0.5)
    assert s.value('clutch', 9.0) == 0.0
    assert s.value('throttle', 2.0) == pytest.approx(0.1 + 0.4 * 2.0 / 3.0)
    assert s.value('throttle', 3.0) == 0.2          # two rows at one time: a step
    assert s.value('brake', 1.0) == 0.0             # never set
    assert (s.gear(1.999), s.gear(2.0)) == (1, 2)
    assert s.breakpoints == [0.0, 1.0, 2.0, 3.0]
    assert s.next_breakpoint(2.0) == 3.0 and s.next_breakpoint(3.0) == math.inf


@pytest.mark.parametrize('rows, field', [
    ([(0.0, {'clutch': 1.5})], 'commands[0].clutch'),
    ([(0.0, {'gear': 1.5})], 'commands[0].gear'),
    ([(0.0, {'clutch': 1.0}), (-1.0, {'clutch': 0.0})], 'commands[1].t'),
    ([(1.0, {'clutch': 1.0}), (0.5, {'clutch': 0.0})], 'commands[1].t'),
    ([(0.0, {'clucth': 1.0})], 'commands[0].clucth'),
    ([(0.0, {'brake': float('nan')})], 'commands[0].brake'),
])
def test_bad_rows_name_the_field(rows: list, field: str) -> None:
    with pytest.raises(SceneError) as exc:
        CommandSchedule(rows)
    assert exc.value.field == field


def test_a_segment_that_ends_on_a_step_sees_it_from_the_left() -> None:
    """Inside a segment ending at t_end, a step at t_end (two rows there) is its first row's
    value at and beyond t_end (the last stage of an explicit step lands there); a row
    without a step, times before t_end and a segment ending elsewhere are unchanged."""
    s = CommandSchedule([(0.0, {'clutch': 1.0, 'throttle': 0.1}),
                         (0.1, {'clutch': 1.0}), (0.1, {'clutch': 0.0}),
                         (1.0, {'throttle': 0.5}), (2.0, {'throttle': 0.2})])
    assert s.value('clutch', 0.1) == 0.0                       # the step, from the right
    assert s.value('clutch', 0.1, 0.1) == 1.0                  # from the left
    assert s.value('clutch', math.nextafter(0.1, 1.0), 0.1) == 1.0   # a stage a rounding beyond
    assert s.value('clutch', 0.05, 0.1) == 1.0
    assert s.value('clutch', 0.1, 1.0) == 0.0                  # not the segment's end
    for t in (0.5, 1.0, 1.0 + 2e-16, 1.5):                     # no step at 1.0: as value(t)
        assert s.value('throttle', t, 1.0) == s.value('throttle', t)
    assert s.value('brake', 0.1, 0.1) == 0.0                   # no rows
