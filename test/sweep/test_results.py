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


class _Outcome:
    def __init__(self, index: object, row: dict, wall: object) -> None:
        self.index, self.row, self.wall = index, row, wall


ROWS = [{'status': 'ok', 'a.x': 0.1, 'a.nan': float('nan'), 'a.inf': float('inf'),
         'a.ninf': float('-inf'), 'z': -0.0, 'n': 3, 'big': 2 ** 70, 'b': True, 'c': False,
         'none': None, 'backend': 'kernel', 'error': ''},
        {'status': 'failed', 'error': 'bad, "quoted"\nvalue \u00e9\u2013'},
        {'status': 'ok', 'a.x': np.float64(0.2), 'n': 4, 'error': ''},     # fallback
        {'status': 'ok', 'a.x': 0.3, 'n': 5, 'b': True, 'note': 'x,y', 'error': ''},
        {'status': 'ok', 1: 2.0, 'error': ''},                               # a non-str key
        {},
        {'status': 'ok', 'a.x': 0.4, 'n': 6, 'error': ''}]


def test_rows_jsonl_lines_are_json_dumps(tmp_path: Path) -> None:
    """append writes json.dumps' line for every row (its own texts where row_texts covers
    the row, json.dumps where not: numpy scalars, non-str keys, a bool index)."""
    import json

    from cvj_ros.sweep.results import ResultStore
    outs = [_Outcome(i, r, 0.25 * i) for i, r in enumerate(ROWS)]
    outs.append(_Outcome(True, ROWS[0], np.float64(0.5)))
    store = ResultStore(tmp_path)
    store.append(outs[:3])
    store.append(outs[3:])
    store.append([])
    want = ''.join(json.dumps({'variant': o.index, 'row': o.row, 'wall_s': o.wall}) + '\n'
                   for o in outs)
    assert (tmp_path / 'rows.jsonl').read_text() == want


def test_tables_from_appended_texts_equal_a_fresh_store(tmp_path: Path,
                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    """write_tables with the texts append kept gives the bytes of a store that appended
    nothing (every cell from the rows), with rows of differing keys, quoted cells, axis
    values that need quoting, a row replaced after its append and rows never appended."""
    from cvj_ros.sweep.results import ResultStore
    variants = [(1.5, 'x'), (2, 'y,z'), (None, ''), (0.5, 'a'), (1, 'b'), (2, 'c'),
                (3, 'd'), (4, 'e'), (5, 'f')]
    same = [ROWS[6], dict(ROWS[6], n=7, **{'a.x': float('nan')}),
            dict(ROWS[6], status='failed', error='x, "y"'), dict(ROWS[6], n=None)]
    sets = [same, ROWS[:1] + ROWS[3:4] + ROWS[6:], ROWS[2:], ROWS]
    import cvj_ros.sweep.results as results
    calls = []
    monkeypatch.setattr(results, 'csv_line', lambda f: calls.append(f) or csv_line(f))
    for k, rows in enumerate(sets):
        store = ResultStore(tmp_path / f'a{k}')
        store.append([_Outcome(i, r, 0.1) for i, r in enumerate(rows)])
        done = {i: (r, 0.1) for i, r in enumerate(rows)}
        done[len(rows)] = ({'status': 'ok', 'a.x': 9.0, 'error': ''}, 0.2)   # not appended
        if k == 3:
            done[0] = (dict(ROWS[0], status='failed'), 0.1)     # replaced after its append
        calls.clear()
        store.write_tables(['p', 'q'], variants, done)
        if k == 0:      # csv_line for the axis value 'y,z', the failed row's error and
            assert [c[0] for c in calls] == ['1', '2', '4']     # the row not appended
        fresh = ResultStore(tmp_path / f'b{k}')
        fresh.write_tables(['p', 'q'], variants, done)
        for name in ('results.csv', 'timing.csv'):
            assert (tmp_path / f'a{k}' / name).read_bytes() == \
                (tmp_path / f'b{k}' / name).read_bytes(), (k, name)


def test_row_texts_cover_the_plain_types() -> None:
    from cvj_ros.sweep.results import row_texts
    text = row_texts(ROWS[6])
    assert text is not None and text[1] == ('a.x', 'n') and text[2] == '0.4,6'
    assert row_texts(ROWS[3])[2] is None        # 'x,y' needs quoting: the row's own line
    assert row_texts(ROWS[2]) is None and row_texts(ROWS[4]) is None
