"""Flat memory of a composed `cvj-sim run` (slow: 5-10 minutes of wall time on this machine).

Two runs of kavz685_lever at 1 ms, 120 s and 360 s of simulated time, measured as
``scripts/run_rss.py`` does (peak VmRSS of the one process, every 20 ms, during the loop and
after it). Bound on the growth per simulated second, from the promise that a 1-hour run stays
within PEAK_1H_MIB: whatever the 60 s run peaks at, the remaining 3540 s may add at most
``PEAK_1H_MIB - peak(120 s)``, so the slope between the two runs must stay below that divided
by 3480 s (~0.08 MiB per simulated second from a ~210 MiB start). The growth slows down with
the run's length (docs/robustness.md "Long runs": 0.068 / 0.078 MiB per simulated second in
and after the loop from 60 to 240 s, 0.029 / 0.048 over the whole 1-hour run, which peaked at
309 / 397 MiB), so the first minute, where caches and histories fill, is left out of the
slope. A leak of 100 bytes per exchange (0.095 MiB per simulated second) fails it.

Measured (load average 10-15): loop 0.061 MiB per simulated second (allowed 0.084), after the
loop 0.0767 (allowed 0.0776) - passed, with almost no margin after the loop; the same test
with 60 s and 240 s runs failed by as little (0.0777 against 0.0771). A linear extrapolation
from minutes overestimates the hour (0.048 measured over it), so this test is at its edge
while the hour itself holds: the loop's growth must come down for it to pass with a margin.
"""
from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

pytestmark = [pytest.mark.e2e, pytest.mark.slow]

PEAK_1H_MIB = 500.0
SHORT_S, LONG_S, HOUR_S = 120.0, 360.0, 3600.0

_spec = importlib.util.spec_from_file_location(
    '_run_rss', Path(__file__).parents[2] / 'scripts' / 'run_rss.py')
_rss = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(_rss)


def test_composed_run_memory_is_flat_enough_for_an_hour(tmp_path: Path) -> None:
    # a first run after a code change compiles kernels and peaks ~90 MiB higher: not measured
    assert _rss.measure(tmp_path / 'warm', 'kavz685_lever', 1.0, ['--composed'])['exit'] == 0
    short = _rss.measure(tmp_path / 'short', 'kavz685_lever', SHORT_S, ['--composed'])
    long = _rss.measure(tmp_path / 'long', 'kavz685_lever', LONG_S, ['--composed'])
    assert short['exit'] == 0 and long['exit'] == 0
    for key in ('loop_peak', 'after_peak'):
        allowed = (PEAK_1H_MIB - short[key]) / (HOUR_S - SHORT_S)      # MiB per simulated s
        slope = (long[key] - short[key]) / (LONG_S - SHORT_S)
        print(f'{key}: {short[key]:.0f} MiB at {SHORT_S:g} s, {long[key]:.0f} MiB at {LONG_S:g} s: '
              f'{slope:.4f} MiB per simulated s (allowed {allowed:.4f})')
        assert slope <= allowed, (key, short, long)
