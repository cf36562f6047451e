"""Automated shift schedule: the sequence's envelope, gears and breakpoints, and the schedule's
validation (gear hunting, field paths)."""
from __future__ import annotations

import math

import pytest

from cvj_ros.errors import SceneError
from cvj_ros.physics.hybrid.commands import CommandSchedule
from cvj_ros.physics.hybrid.elements import Gearbox
from cvj_ros.physics.hybrid.shift import AutoShift, parse_shift_schedule

GB = Gearbox('gearbox', 0.005, 0.02, (3.5, 2.1, 1.3, 1.0), -3.3, 6500 * math.pi / 30)
SPEC = {'upshift_rpm': 2500.0, 'downshift_rpm': [1200.0, 1400.0, 1600.0],
        'open_s': 0.1, 'neutral_s': 0.2, 'close_s': 0.4}


def test_sequence_open_neutral_gear_close() -> None:
    """Pedal p + (1 - p) e and throttle x (1 - e) with the envelope e of the module
    docstring, written out at hand-picked times; neutral and the new gear at their instants."""
    base = CommandSchedule([(0.0, {'clutch': 0.2, 'throttle': 0.6})])
    a = AutoShift(base, parse_shift_schedule(SPEC, GB))
    assert a.gear(0.0) == 1 and a.next_breakpoint(0.0) == math.inf
    a.start(1.0, 2)
    assert a.busy(1.5) and not a.busy(1.701) and a.busy(1.0)
    assert a.value('clutch', 1.05) == pytest.approx(0.2 + 0.8 * 0.5)
    assert a.value('throttle', 1.05) == pytest.approx(0.6 * 0.5)
    assert a.value('clutch', 1.2) == 1.0 and a.value('throttle', 1.2) == 0.0
    assert a.value('clutch', 1.5) == pytest.approx(0.2 + 0.8 * 0.5)     # halfway closing
    assert a.value('clutch', 2.0) == 0.2 and a.value('throttle', 2.0) == 0.6
    # the instants are t_s + open_s and t_s + open_s + neutral_s as floats (1.1, 1.3000000000000003)
    assert [a.gear(t) for t in (1.0, 1.0999, 1.1, 1.2999, 1.0 + 0.1 + 0.2, 5.0)] == [1, 1, 0, 0, 2, 2]
    assert a.next_breakpoint(1.0) == pytest.approx(1.1)
    assert a.next_breakpoint(1.105) == pytest.approx(1.3)
    assert a.next_breakpoint(1.305) == pytest.approx(1.7)
    assert a.next_breakpoint(1.705) == math.inf


def test_thresholds_per_gear() -> None:
    s = parse_shift_schedule(SPEC, GB)
    rpm = math.pi / 30
    assert [s.up(g) for g in (1, 2, 3, 4)] == [2500 * rpm] * 3 + [None]
    assert [s.down(g) for g in (1, 2, 3, 4)] == [None, 1200 * rpm, 1400 * rpm, 1600 * rpm]
    assert s.duration == pytest.approx(0.7)


@pytest.mark.parametrize('change, field', [
    ({'downshift_rpm': 1600.0}, 'shift_schedule.downshift_rpm'),   # 2500 * 1.3/2.1 = 1548 < 1600
    ({'upshift_rpm': [2500.0, 2200.0, 3000.0]}, 'shift_schedule.downshift_rpm'),  # 2200*1.3/2.1 < 1400
    ({'upshift_rpm': [2500.0, 3000.0]}, 'shift_schedule.upshift_rpm'),   # one per gear 1..N-1
    ({'upshift_rpm': 7000.0}, 'shift_schedule.upshift_rpm'),       # above max_input_rpm
    ({'start_gear': 5}, 'shift_schedule.start_gear'),
    ({'close_s': -1.0}, 'shift_schedule.close_s'),
    ({'bogus': 1}, 'shift_schedule.bogus'),
])
def test_bad_schedules_name_the_field(change: dict, field: str) -> None:
    with pytest.raises(SceneError) as exc:
        parse_shift_schedule({**SPEC, **change}, GB)
    assert exc.value.field == field
