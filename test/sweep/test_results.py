"""results.csv cells (cvj_ros/sweep/results.py: fmt): numpy scalars are written as their Python values."""
from __future__ import annotations

import math

import numpy as np
import pytest

from cvj_ros.sweep.results import fmt


@pytest.mark.parametrize('value, text', [
    (0.3, '0.3'), (np.float64(0.3), '0.3'), (np.float32(0.5), '0.5'), (float('nan'), 'nan'),
    (np.float64('-inf'), '-inf'), (7, '7'), (np.int64(7), '7'), (True, 'true'),
    (np.bool_(False), 'false'), (None, ''), ('kernel', 'kernel')])
def test_cell_text(value: object, text: str) -> None:
    assert fmt(value) == text


def test_floats_round_trip_exactly() -> None:
    for x in (0.1 + 0.2, 1e-300, math.pi, np.nextafter(1.0, 2.0)):
        assert float(fmt(x)) == x and float(fmt(np.float64(x))) == x
