"""results.csv cells (cvj_ros/sweep/results.py: fmt): numpy scalars are written as their Python
values; the fast cells and lines (cells, csv_line) are fmt's and csv.writer's."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from cvj_ros.sweep.results import cells, csv_line, fmt


@pytest.mark.parametrize('value, text', [
    (0.3, '0.3'), (np.float64(0.3), '0.3'), (np.float32(0.5), '0.5'), (float('nan'), 'nan'),
    (np.float64('-inf'), '-inf'), (7, '7'), (np.int64(7), '7'), (True, 'true'),
    (np.bool_(False), 'false'), (None, ''), ('kernel', 'kernel')])
def test_cell_text(value: object, text: str) -> None:
    assert fmt(value) == text


def test_floats_round_trip_exactly() -> None:
    for x in (0.1 + 0.2, 1e-300, math.pi, np.nextafter(1.0, 2.0)):
        assert float(fmt(x)) == x and float(fmt(np.float64(x))) == x


VALUES = [0.3, np.float64(0.3), np.float32(0.5), float('nan'), np.float64('-inf'), -0.0, 7,
          np.int64(7), True, False, np.bool_(False), None, 'kernel', '', 'a,b', 'say "x"',
          'two\nlines', 'cr\rhere', ' lead', 'tab\there', "it's", 1e300, -7, 2 ** 70]


def test_cells_equal_fmt() -> None:
    assert cells(VALUES) == [fmt(v) for v in VALUES]


@pytest.mark.parametrize('n', [1, 2, 3])
def test_csv_line_is_the_writers_line(n: int) -> None:
    """csv_line writes csv.writer's line (minimal quoting, '\\n') for every n-field row
    of the cells above: plain, commas, quotes, line breaks, empty and one-field rows."""
    import csv
    import io
    import itertools
    texts = [fmt(v) for v in VALUES]
    for fields in itertools.product(texts, repeat=n):
        buf = io.StringIO()
        csv.writer(buf, lineterminator='\n').writerow(list(fields))
        assert csv_line(list(fields)) == buf.getvalue(), fields


def test_tables_are_the_writers_bytes(tmp_path: Path) -> None:
    """write_tables: the same results.csv as csv.writer over fmt of every cell, with rows
    whose keys differ (a failed row without metrics, a new column later)."""
    import csv
    import io

    from cvj_ros.sweep.results import ResultStore
    done = {0: ({'status': 'ok', 'a.x': 0.1, 'n': 3, 'error': ''}, 0.5),
            2: ({'status': 'failed', 'error': 'bad, "quoted"\nvalue'}, 0.25),
            1: ({'status': 'ok', 'a.x': np.float64(0.2), 'n': 4, 'b': True, 'error': ''}, 1.0)}
    variants = [(1.5, 'x'), (2, 'y,z'), (None, '')]
    ResultStore(tmp_path).write_tables(['p', 'q'], variants, done)
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator='\n')
    w.writerow(['variant', 'p', 'q', 'status', 'a.x', 'n', 'b', 'error'])
    for i in (0, 1, 2):
        row = done[i][0]
        w.writerow([str(i), *(fmt(v) for v in variants[i]), row['status'],
                    *(fmt(row.get(c)) for c in ('a.x', 'n', 'b')), row['error']])
    assert (tmp_path / 'results.csv').read_text() == buf.getvalue()
