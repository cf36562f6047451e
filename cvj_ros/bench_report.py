"""The per-level summary of a `cvj-sim bench` run, from its rows or from its bench.csv.

Per scene and error level 1e-3..1e-8 (max relative output-speed error): the cheapest project
configuration reaching the level, and its speedup (family cost / project cost, wall seconds
per simulated second) against the cheapest configuration of each baseline family that reaches
it - plain ``solve_ivp`` on the Python rhs, ``solve_ivp`` on the compiled rhs, and
``baseline_expert`` (numbalsoda on the compiled rhs) - with the compiled rhs's ns per call.
Then every (scene, level) where a target does not hold: >= 2x against the best
``baseline_expert`` and >= 30x against the best plain ``solve_ivp``.

``cvj-sim bench --report DIR`` rebuilds it from ``DIR/bench.csv`` without re-running: the ns
per rhs call come from ``DIR/rhs.csv`` (written by runs since it exists) or else from the
"Right-hand side" lines of ``DIR/bench.md``.
"""
from __future__ import annotations

import csv
import math
import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from cvj_ros.bench import ERROR_LEVELS, _config_label, _g, best_at_levels

__all__ = ['EXPERT_TARGET', 'PLAIN_TARGET', 'RHS_FIELDS', 'read_bench_csv', 'read_rhs_ns',
           'summary_lines', 'target_misses', 'write_rhs_csv', 'write_summary']

EXPERT_TARGET = 2.0     # best project config >= 2x cheaper than the best baseline_expert config
PLAIN_TARGET = 30.0     # ... and >= 30x cheaper than the best plain solve_ivp
RHS_FIELDS = ('scene', 'compiled_ns', 'compiled_from_python_us', 'python_us')

_FLOATS = ('tol', 'h', 'wall_s', 'wall_spread', 'wall_per_sim_s', 'err_speed_rel', 'err_angle_rad')
_INTS = ('repeats', 'nfev', 'njev')
_RHS_LINE = re.compile(r'^Right-hand side \(exact fidelity[^)]*\): compiled ([0-9.eE+-]+) ns per call')


def _number(text: str, kind: type) -> Any:
    if text in ('', 'None'):
        return None
    return kind(float(text)) if kind is int else kind(text)


def read_bench_csv(path: str | Path) -> list[dict[str, Any]]:
    """The rows of a bench.csv with their types back (numbers as float/int, ``ok`` as bool,
    empty cells as None); ``breakpoints`` and ``sampling`` stay strings, as the report's
    labels read them. Raises ValueError naming the file and line on a malformed row."""
    p = Path(path)
    rows: list[dict[str, Any]] = []
    with p.open(newline='') as fh:
        reader = csv.DictReader(fh)
        missing = {'scene', 'family', 'ok', 'wall_per_sim_s', 'err_speed_rel'} - set(reader.fieldnames or ())
        if missing:
            raise ValueError(f'{p}: not a bench.csv (no column {", ".join(sorted(missing))})')
        for i, raw in enumerate(reader, start=2):
            r: dict[str, Any] = dict(raw)
            try:
                for k in _FLOATS:
                    if k in r:
                        r[k] = _number(r[k] or '', float)
                for k in _INTS:
                    if k in r:
                        r[k] = _number(r[k] or '', int)
            except ValueError as exc:
                raise ValueError(f'{p}, line {i}: {exc}') from None
            r['ok'] = r.get('ok') == 'True'
            if r['ok'] and (r['wall_per_sim_s'] is None or r['err_speed_rel'] is None):
                raise ValueError(f'{p}, line {i}: ok row without wall_per_sim_s or err_speed_rel')
            rows.append(r)
    return rows


def write_rhs_csv(path: str | Path, rhs: Mapping[str, Mapping[str, Any]]) -> Path:
    """``rhs.csv``: per scene the costs of :func:`cvj_ros.bench.rhs_cost` (scenes without
    them are left out)."""
    p = Path(path)
    with p.open('w', newline='') as fh:
        w = csv.DictWriter(fh, fieldnames=RHS_FIELDS, extrasaction='ignore')
        w.writeheader()
        for scene, rc in rhs.items():
            if 'compiled_ns' in rc:
                w.writerow({'scene': scene, **{k: rc.get(k, '') for k in RHS_FIELDS[1:]}})
    return p


def read_rhs_ns(out_dir: str | Path) -> dict[str, float]:
    """Compiled rhs ns per call per scene of a bench output directory: from ``rhs.csv``, or
    else from the "Right-hand side" line under each scene's heading in ``bench.md``; {} when
    neither is there."""
    d = Path(out_dir)
    if (d / 'rhs.csv').is_file():
        with (d / 'rhs.csv').open(newline='') as fh:
            return {r['scene']: float(r['compiled_ns']) for r in csv.DictReader(fh) if r.get('compiled_ns')}
    out: dict[str, float] = {}
    if (d / 'bench.md').is_file():
        scene = None
        for line in (d / 'bench.md').read_text().splitlines():
            if line.startswith('## '):
                scene = line[3:].strip()
            m = _RHS_LINE.match(line)
            if m and scene:
                out[scene] = float(m.group(1))
    return out


def _speedup(x: float | None) -> str:
    return f'{x:.2f}x' if x else '-'


def summary_lines(rows: Sequence[Mapping[str, Any]], rhs_ns: Mapping[str, float] | None = None, *,
                  levels: Sequence[float] = ERROR_LEVELS) -> list[str]:
    """Markdown: one table row per (scene, level) with the best project configuration, its
    cost and rhs evaluations, the speedup against the best of each baseline family (and
    the expert family's configuration), and the scene's compiled rhs ns per call; then
    the target misses (:func:`target_misses`)."""
    rhs_ns = rhs_ns or {}
    md = ['| scene | error level | best project config | s/s | rhs evals | vs solve_ivp | '
          'vs solve_ivp + compiled rhs | vs baseline_expert | best baseline_expert config | rhs ns/call |',
          '| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |']
    scenes = list(dict.fromkeys(r['scene'] for r in rows))
    for name in scenes:
        for e in best_at_levels([r for r in rows if r['scene'] == name], levels=levels):
            pr = e['project']
            ns = rhs_ns.get(name)
            md.append(f'| {name} | {e["level"]:.0e} | {_config_label(pr)} | '
                      f'{_g(pr and pr["wall_per_sim_s"])} | {pr["nfev"] if pr else "-"} | '
                      f'{_speedup(e["speedup"])} | {_speedup(e["speedup_compiled"])} | '
                      f'{_speedup(e["speedup_expert"])} | {_config_label(e["baseline_expert"])} | '
                      f'{f"{ns:.0f}" if ns is not None else "-"} |')
    misses = target_misses(rows, levels=levels)
    md += ['', f'Targets (>= {EXPERT_TARGET:g}x the best baseline_expert, >= {PLAIN_TARGET:g}x the best '
           f'plain solve_ivp): ' + ('met at every scene and level.' if not misses else
                                   f'not met at {len(misses)} (scene, level, target):'), '']
    md += [f'- {m["scene"]} {m["level"]:.0e}, {m["target"]}: {m["text"]}' for m in misses]
    return md


def target_misses(rows: Sequence[Mapping[str, Any]], *, levels: Sequence[float] = ERROR_LEVELS,
                  expert_target: float = EXPERT_TARGET,
                  plain_target: float = PLAIN_TARGET) -> list[dict[str, Any]]:
    """Every (scene, level, target) that does not hold: the speedup against the family's
    best is below the target, or the family reaches the level and the project does not.
    A level no configuration of the family reaches is not a miss (the project is cheaper
    without bound); a family with no row on the scene (not run) is not judged."""
    out = []
    for name in dict.fromkeys(r['scene'] for r in rows):
        srows = [r for r in rows if r['scene'] == name]
        fams = {r['family'] for r in srows}
        for e in best_at_levels(srows, levels=levels):
            for fam, key, target in (('baseline_expert', 'speedup_expert', expert_target),
                                     ('baseline', 'speedup', plain_target)):
                if fam not in fams:
                    continue
                sp, base = e[key], e[fam]
                label = f'>= {target:g}x {"baseline_expert" if fam == "baseline_expert" else "plain solve_ivp"}'
                if e['project'] is None and base is not None:
                    text = f'the project does not reach the level ({_config_label(base)} does)'
                elif sp is not None and sp < target:
                    text = f'{sp:.2f}x ({_config_label(e["project"])} against {_config_label(base)})'
                else:
                    continue
                out.append({'scene': name, 'level': e['level'], 'target': label,
                            'speedup': sp if sp is not None else math.nan, 'text': text})
    return out


def write_summary(out_dir: str | Path) -> Path:
    """Rebuild ``summary.md`` of a bench output directory from its ``bench.csv`` (and the rhs
    figures, :func:`read_rhs_ns`); returns its path."""
    d = Path(out_dir)
    rows = read_bench_csv(d / 'bench.csv')
    md = ['# cvj_ros benchmark: speedups per error level', '',
          f'From {d / "bench.csv"} ({len(rows)} rows). Speedup = cost of the best configuration of '
          'the family reaching the level / cost of the best project configuration (wall s per '
          'simulated s); rhs ns/call: the compiled rhs from a compiled loop.', '']
    md += summary_lines(rows, read_rhs_ns(d))
    p = d / 'summary.md'
    p.write_text('\n'.join(md) + '\n')
    return p
