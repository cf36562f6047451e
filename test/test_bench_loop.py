"""Loop-overhead part of cvj_ros.bench: overhead / round-trip ratios per reference."""
from __future__ import annotations

import math

import pytest

from cvj_ros.bench import ROUND_TRIP_LABELS, overhead_ratios


def test_ratios_divide_overhead_by_each_measured_round_trip() -> None:
    rt = {'events': {'us_mean': 50.0}, 'single': {'note': 'RuntimeError: x'},
          'events_ipc': {'us_mean': 400.0}, 'events_ipc2': {'us_mean': 500.0}}
    r = overhead_ratios({'overhead_us_mean': 1000.0}, rt)
    assert r == pytest.approx({'events': 20.0, 'events_ipc': 2.5, 'events_ipc2': 2.0})
    assert set(r) <= set(ROUND_TRIP_LABELS)


def test_no_ratio_without_overhead_or_round_trip() -> None:
    assert overhead_ratios({'note': 'cvj-sim run failed'}, {'events': {'us_mean': 50.0}}) == {}
    assert overhead_ratios({'overhead_us_mean': 1000.0}, {'note': 'skipped'}) == {}
    assert overhead_ratios({'overhead_us_mean': 1000.0}, {'events': {'us_mean': 0.0}}) == {}
    assert not math.isnan(sum(overhead_ratios({'overhead_us_mean': 1.0}, {'x': {'us_mean': 3.0}}).values()))
