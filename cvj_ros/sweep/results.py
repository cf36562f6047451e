"""Sweep output directory: finished rows, results.csv, timing.csv, sweep.json.

Files in ``--out DIR``:

* ``rows.jsonl`` - one JSON line per finished variant, appended as chunks finish (the
  record that makes Ctrl-C keep finished work and a rerun skip it). JSON writes floats
  with ``repr``, which round-trips exactly;
* ``results.csv`` - the table: ``variant``, one column per ``--set`` (the path as given),
  ``status`` (ok | invalid | failed), the metrics (energy residual, solver counters,
  backend, ``SHAFT.METRIC`` per shaft) and ``error`` last. Rows in variant order, floats
  written with ``repr`` (shortest text that reads back to the same double), so the file
  is the same bytes whichever executor, worker count or resume history produced it;
* ``timing.csv`` - ``variant,wall_s``: wall time of each variant (varies run to run,
  hence not in results.csv);
* ``sweep.json`` - the definition (scene, its data and SHA-256, the --set specs, samples,
  seed, run options), software versions and one entry per invocation (executor, workers,
  variants run, wall time, rate).
"""
from __future__ import annotations

import csv
import hashlib
import io
import json
import math
import os
import platform
import sys
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

FORMAT = 'cvj_ros.sweep/1'
RESULTS = 'results.csv'
TIMING = 'timing.csv'
ROWS = 'rows.jsonl'
MANIFEST = 'sweep.json'


def fmt(value: Any) -> str:
    """CSV text of a cell: floats by ``repr`` (exact round trip; 'nan', 'inf'), ints by
    ``str``, None as empty; numpy scalars as their Python values."""
    if value is None:
        return ''
    if isinstance(value, np.generic):
        value = value.item()        # its Python value: repr(np.float64(0.3)) is 'np.float64(0.3)'
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, float):
        return repr(value)
    return str(value)


def _true_false(value: bool) -> str:
    return 'true' if value else 'false'


def _empty(_value: None) -> str:
    return ''


# fmt for the exact types a row holds (a subclass - np.float64, ... - takes fmt itself)
_FMT = {float: float.__repr__, int: int.__str__, str: str.__str__, bool: _true_false,
        type(None): _empty}


def cells(values: Iterable[Any]) -> list[str]:
    """``[fmt(v) for v in values]``, the same texts, with one dict look-up per cell for
    the types rows hold instead of fmt's chain of tests."""
    get = _FMT.get
    return [(get(type(v)) or fmt)(v) for v in values]


_NONFINITE_JSON = {'nan': 'NaN', 'inf': 'Infinity', '-inf': '-Infinity'}
_JSON_KEYS: dict[str, str] = {}     # json.dumps(key) + ': ' of a row key (rows share them)


def row_texts(row: Mapping[str, Any]) -> tuple[str, tuple[str, ...], str | None] | None:
    """``row`` formatted once: (its JSON text, as ``json.dumps(row)`` writes it; the keys
    other than status and error, in order; the csv text of their cells, ``cells`` joined by
    commas, or None when a cell holds a comma, quote or line break). JSON and csv share the
    text of a float (``repr``; JSON writes NaN and Infinity for the non-finite), an int and
    a bool; None is ``null`` and empty. None when a key is not a str or a value's type is
    not exactly float, int, bool, str or None (json.dumps and fmt then make the texts)."""
    parts = []
    keys = []
    cell_texts = []
    prefixes = _JSON_KEYS
    nonfinite = _NONFINITE_JSON
    for k, v in row.items():
        prefix = prefixes.get(k)
        if prefix is None:
            if type(k) is not str:
                return None
            if len(prefixes) >= 4096:
                prefixes.clear()
            prefix = prefixes[k] = json.dumps(k) + ': '
        t = type(v)
        if t is float:
            c = repr(v)
            parts.append(prefix + nonfinite.get(c, c))
        elif t is int:
            c = repr(v)
            parts.append(prefix + c)
        elif t is str:
            c = v
            parts.append(prefix + json.dumps(v))
        elif t is bool:
            c = 'true' if v else 'false'
            parts.append(prefix + c)
        elif v is None:
            c = ''
            parts.append(prefix + 'null')
        else:
            return None
        if k != 'status' and k != 'error':
            keys.append(k)
            cell_texts.append(c)
    text = ','.join(cell_texts)
    plain = text.count(',') == max(0, len(cell_texts) - 1) and '"' not in text \
        and '\n' not in text and '\r' not in text
    return '{' + ', '.join(parts) + '}', tuple(keys), text if plain else None


_WRITER_BUF = io.StringIO()
_WRITER = csv.writer(_WRITER_BUF, lineterminator='\n')


def csv_line(fields: list[str]) -> str:
    """The line ``csv.writer(f, lineterminator='\\n').writerow(fields)`` writes for text
    fields: joined by commas when no field holds a comma, quote or line break (the writer's
    minimal quoting then quotes none), else the writer's own line."""
    line = ','.join(fields)
    if len(fields) > 1 and line.count(',') == len(fields) - 1 and '"' not in line \
            and '\n' not in line and '\r' not in line:
        return line + '\n'
    _WRITER_BUF.seek(0)
    _WRITER_BUF.truncate()
    _WRITER.writerow(fields)
    return _WRITER_BUF.getvalue()


def scene_digest(data: Mapping[str, Any]) -> str:
    """SHA-256 of the scene dict in canonical JSON (sorted keys): names the base scene."""
    text = json.dumps(data, sort_keys=True, separators=(',', ':'), default=str)
    return hashlib.sha256(text.encode()).hexdigest()


def versions() -> dict[str, str]:
    """Versions of what computed the rows (python, cvj_ros and the numeric stack)."""
    from importlib import metadata

    import cvj_ros
    out = {'python': platform.python_version(), 'cvj_ros': cvj_ros.__version__,
           'platform': platform.platform()}
    for pkg in ('numpy', 'scipy', 'numba', 'llvmlite', 'dask', 'distributed'):
        try:
            out[pkg] = metadata.version(pkg)
        except metadata.PackageNotFoundError:
            pass
    return out


class ResultStore:
    """The files of one sweep directory (created on first write)."""

    def __init__(self, out_dir: str | os.PathLike[str]) -> None:
        self.dir = Path(out_dir)
        # rows appended here: index -> (row, its metric keys, their csv text); one tuple
        # object per distinct key sequence, so write_tables compares them by identity
        self._texts: dict[int, tuple[Mapping[str, Any], tuple[str, ...], str]] = {}
        self._keysets: dict[tuple[str, ...], tuple[str, ...]] = {}

    def path(self, name: str) -> Path:
        return self.dir / name

    # --- manifest ---
    def read_manifest(self) -> dict[str, Any] | None:
        p = self.path(MANIFEST)
        if not p.is_file():
            return None
        try:
            data = json.loads(p.read_text())
        except (OSError, ValueError):
            return None
        return data if isinstance(data, dict) else None

    def write_manifest(self, manifest: Mapping[str, Any]) -> None:
        self.dir.mkdir(parents=True, exist_ok=True)
        tmp = self.path(MANIFEST + '.tmp')
        tmp.write_text(json.dumps(manifest, indent=1, default=str) + '\n')
        tmp.replace(self.path(MANIFEST))

    def clear(self) -> None:
        """Remove this sweep's files (``--fresh``); other files in the directory stay."""
        for name in (ROWS, RESULTS, TIMING, MANIFEST):
            self.path(name).unlink(missing_ok=True)
        plots = self.dir / 'plots'
        if plots.is_dir():
            for f in plots.glob('*.png'):
                f.unlink()

    # --- finished rows ---
    def load_done(self) -> dict[int, tuple[dict[str, Any], float]]:
        """Finished variants: index -> (row, wall s). A line cut short by a kill is skipped
        (its variant runs again)."""
        p = self.path(ROWS)
        done: dict[int, tuple[dict[str, Any], float]] = {}
        if not p.is_file():
            return done
        with p.open() as f:
            for line in f:
                try:
                    rec = json.loads(line)
                    done[int(rec['variant'])] = (dict(rec['row']), float(rec['wall_s']))
                except (ValueError, KeyError, TypeError):
                    continue
        return done

    def append(self, outcomes: Iterable[Any]) -> None:
        """Append finished variants (objects with index, row, wall) to rows.jsonl, flushed.
        Each row's cells are formatted once (:func:`row_texts`): its JSON line, and the csv
        text of its metrics kept for :meth:`write_tables` (by index, with the row itself)."""
        self.dir.mkdir(parents=True, exist_ok=True)
        lines = []
        kept = self._texts
        for o in outcomes:
            texts = row_texts(o.row)
            if texts is None or type(o.index) is not int:
                lines.append(json.dumps({'variant': o.index, 'row': o.row, 'wall_s': o.wall}))
                continue
            row_json, keys, csv_text = texts
            lines.append(f'{{"variant": {o.index}, "row": {row_json}, "wall_s": '
                         f'{json.dumps(o.wall)}}}')
            if csv_text is not None:
                kept[o.index] = (o.row, self._keysets.setdefault(keys, keys), csv_text)
        text = '\n'.join(lines) + '\n' if lines else ''
        with self.path(ROWS).open('a') as f:
            f.write(text)
            f.flush()

    # --- tables ---
    def write_tables(self, axis_columns: Sequence[str], variants: Sequence[Sequence[Any]],
                     done: Mapping[int, tuple[Mapping[str, Any], float]]) -> int:
        """Write results.csv and timing.csv from the finished rows (variant order); returns
        the number of rows written."""
        order = sorted(i for i in done if 0 <= i < len(variants))
        metric_cols: dict[str, None] = {}
        last: Any = None
        for i in order:
            keys = done[i][0].keys()
            if keys == last:        # the same keys as the row before: none new
                continue
            last = keys
            for k in keys:
                if k not in ('status', 'error'):
                    metric_cols.setdefault(k, None)
        header = ['variant', *axis_columns, 'status', *metric_cols, 'error']
        buf = io.StringIO()
        w = csv.writer(buf, lineterminator='\n')
        w.writerow(header)
        lines = [buf.getvalue()]
        cols = tuple(metric_cols)
        canon = self._keysets.get(cols)
        kept = self._texts if canon is not None else {}
        n_fields = 3 + len(axis_columns) + len(cols)
        for i in order:
            row = done[i][0]
            k = kept.get(i)
            if k is not None and k[0] is row and k[1] is canon:
                # the metrics' text from append; the line is csv_line's where it quotes
                # nothing, which the count of commas and the absence of quotes and line
                # breaks show (the metrics' text has none of its own)
                status, error = row.get('status', ''), row.get('error', '')
                if type(status) is str and type(error) is str:
                    head = ','.join([str(i), *cells(variants[i]), status])
                    line = f'{head},{k[2]},{error}' if cols else f'{head},{error}'
                    if line.count(',') == n_fields - 1 and '"' not in line \
                            and '\n' not in line and '\r' not in line:
                        lines.append(line + '\n')
                        continue
            lines.append(csv_line([str(i), *cells(variants[i]), row.get('status', ''),
                                   *cells(map(row.get, cols)), row.get('error', '')]))
        self.dir.mkdir(parents=True, exist_ok=True)
        _atomic_write(self.path(RESULTS), ''.join(lines))
        _atomic_write(self.path(TIMING), 'variant,wall_s\n' + ''.join(
            f'{i},{done[i][1]!r}\n' for i in order))
        return len(order)


def _atomic_write(path: Path, text: str) -> None:
    tmp = path.with_name(path.name + '.tmp')
    tmp.write_text(text)
    tmp.replace(path)


def read_results(path: str | os.PathLike[str]) -> tuple[list[str], list[dict[str, str]]]:
    """(header, rows as dicts of text) of a results.csv."""
    with open(path, newline='') as f:
        r = csv.DictReader(f)
        rows = list(r)
        return list(r.fieldnames or []), rows


def as_float(text: str) -> float:
    """A cell as float (NaN for empty or non-numeric)."""
    try:
        return float(text)
    except (TypeError, ValueError):
        return math.nan


def command_line() -> str:
    """The command that made this sweep (for sweep.json)."""
    return ' '.join(sys.argv)
