"""Every ```python block of README.md and docs/*.md runs as pasted: each is executed in a
fresh interpreter (the project's, ``sys.executable``) with the repository on PYTHONPATH and
an empty temporary directory as the working directory, so a block may not lean on files
other than the shipped scenes it names, and exits 0.

A block that reads a bag a reader records with ROS first (``make demo``, ``cvj-sim run ...
--out``) is listed in :data:`NEEDS_RECORDED_BAG` with the run that writes it; it is only
compiled and checked for names it reads without defining or importing them (every block is). A block deliberately a fragment or a signature summary is fenced with
another language tag (``text``) in the docs and is not collected. :data:`HEAVY` blocks
run with ``-m slow``.
"""
from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = [ROOT / 'README.md', *sorted((ROOT / 'docs').glob('*.md'))]

# Hang guard per block, not a speed bound: on a cold numba cache a block that reaches the
# compiled kernel (docs/solvers.md's CoupledStepper) compiles it in the subprocess, which
# took 234 s (dopri5) under a load of 12-20 on 2 cores; warm, every block takes < 15 s.
TIMEOUT_S = 600.0

# (file, text only that block contains) -> the run that writes the bag it reads
NEEDS_RECORDED_BAG = {
    ('docs/analysis.md', "read_bag_signals('runs/kavz/bag')"):
        'cvj-sim run kavz685_lever --out runs/kavz (a ROS run) writes runs/kavz/bag',
    ('docs/ros.md', "read_bag('runs/demo/bag')"):
        "the README's make demo (a ROS run) writes runs/demo/bag",
}
# (file, text only that block contains) -> why it is slow
HEAVY = {
    ('docs/clutch_gearbox.md', "run_hybrid(load_scene(find_scene('launch_clutch')))"):
        'the full launch_clutch hybrid run: 51 s under load here',
}


def python_blocks() -> list[tuple[str, str]]:
    """(``file:line`` of the opening fence, code) of every ```python block of the docs."""
    out = []
    for path in DOCS:
        lines = path.read_text(encoding='utf-8').splitlines()
        start = None
        for no, line in enumerate(lines, 1):
            if start is None and re.fullmatch(r'\s*```python\s*', line):
                start = no
            elif start is not None and re.fullmatch(r'\s*```\s*', line):
                out.append((f'{path.relative_to(ROOT)}:{start}', '\n'.join(lines[start:no - 1]) + '\n'))
                start = None
        assert start is None, f'{path.relative_to(ROOT)}:{start}: ```python block never closed'
    return out


BLOCKS = python_blocks()


def _listed(where: str, code: str, table: dict[tuple[str, str], str]) -> str | None:
    doc = where.rsplit(':', 1)[0]
    return next((why for (f, key), why in table.items() if f == doc and key in code), None)


def _params() -> list:
    params = []
    for where, code in BLOCKS:
        marks = [pytest.mark.slow] if _listed(where, code, HEAVY) else []
        params.append(pytest.param(where, code, marks=marks, id=where))
    return params


def test_every_listed_block_exists_once() -> None:
    """The skip and slow lists name blocks that are in the docs (one each), so a moved or
    rewritten block does not silently leave a list entry that skips nothing."""
    for table in (NEEDS_RECORDED_BAG, HEAVY):
        for doc, key in table:
            hits = [w for w, code in BLOCKS if w.rsplit(':', 1)[0] == doc and key in code]
            assert len(hits) == 1, (doc, key, hits)


def test_blocks_found() -> None:
    """The collector sees the docs' blocks (README's joint example, the solvers' steppers)."""
    files = {w.rsplit(':', 1)[0] for w, _ in BLOCKS}
    assert {'README.md', 'docs/solvers.md', 'docs/kinematics.md', 'docs/engine_load.md'} <= files


def undefined_names(code: str, where: str = '<block>') -> set[str]:
    """Global names the block reads but neither assigns, imports nor finds in builtins
    (its module scope and every function in it, by :mod:`symtable`)."""
    import builtins
    import symtable
    top = symtable.symtable(code, where, 'exec')
    defined = {s.get_name() for s in top.get_symbols() if s.is_assigned() or s.is_imported()}
    defined |= set(dir(builtins))
    used: set[str] = set()
    tables = [top]
    while tables:
        table = tables.pop()
        tables.extend(table.get_children())
        used |= {s.get_name() for s in table.get_symbols() if s.is_referenced()
                 and (table is top or s.is_global())}
    return used - defined


@pytest.mark.parametrize('where,code', [pytest.param(w, c, id=w) for w, c in BLOCKS])
def test_block_compiles_and_defines_what_it_reads(where: str, code: str) -> None:
    """Every block, the skipped ones too, is valid Python and reads no name it does not
    define or import (the NameError a reader would get: ``ev = j.evaluate(phi)`` with no
    ``phi``)."""
    compile(code, where, 'exec')
    assert not undefined_names(code, where), where


def test_undefined_names_finds_what_a_reader_would_miss() -> None:
    assert undefined_names('import numpy as np\nev = j.evaluate(phi)\n') == {'j', 'phi'}
    assert undefined_names('def f(t, y):\n    return k * y\nk = 2\nprint(f(0, 1))\n') == set()
    assert undefined_names('def f(t):\n    return g(t)\n') == {'g'}


@pytest.mark.parametrize('where,code', _params())
def test_block_runs(where: str, code: str, tmp_path: Path) -> None:
    why = _listed(where, code, NEEDS_RECORDED_BAG)
    if why:
        pytest.skip(f'needs a recorded bag: {why}')
    path = os.pathsep.join(p for p in (str(ROOT), os.environ.get('PYTHONPATH', '')) if p)
    env = dict(os.environ, PYTHONPATH=path, MPLBACKEND='Agg')
    proc = subprocess.run([sys.executable, '-c', code], cwd=tmp_path, env=env,
                          capture_output=True, text=True, timeout=TIMEOUT_S)
    assert proc.returncode == 0, f'{where}: exit {proc.returncode}\n{proc.stderr[-3000:]}'
