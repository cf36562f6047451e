"""cvj-sim record --until-idle: idle time counts only while the recorder runs, so a process
starved of the CPU for seconds does not take its own pause for the end of the run."""
from __future__ import annotations

import pytest

from cvj_ros.commands.record import IDLE_TICK_MAX_S, IdleClock


def test_idle_counts_polls_not_wall_gaps() -> None:
    clock = IdleClock()
    assert clock.tick(0.0, 0.0) == 0.0          # no message yet: never idle
    assert clock.tick(5.0, 0.0) == 0.0
    clock.tick(5.0, 4.9)                        # first message
    t = 5.0
    for _ in range(10):                         # 10 polls of 20 ms: 0.2 s idle
        t += 0.02
        idle = clock.tick(t, 4.9)
    assert idle == pytest.approx(0.2)
    assert clock.tick(t + 3.0, 4.9) == pytest.approx(0.2 + IDLE_TICK_MAX_S)   # starved 3 s
    assert clock.tick(t + 3.02, 8.0) == 0.0    # a new message resets it
