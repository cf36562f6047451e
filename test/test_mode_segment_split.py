"""scripts/mode_segment_split.py: its variants of segment_nb.py change only the piece they
double or cut, and bad arguments give one line and a non-zero exit."""
from __future__ import annotations

import difflib
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / 'scripts'))
import mode_segment_split as mss  # noqa: E402

SRC = (ROOT / 'cvj_ros' / 'physics' / 'kernel' / 'segment_nb.py').read_text()


def _added_removed(text: str) -> tuple[list[str], list[str]]:
    diff = list(difflib.ndiff(SRC.splitlines(), text.splitlines()))
    return ([d[2:].strip() for d in diff if d.startswith('+ ')],
            [d[2:].strip() for d in diff if d.startswith('- ')])


def test_variants_change_only_their_piece() -> None:
    v = mss.variants(SRC)
    assert v['A'] == SRC
    added, removed = _added_removed(v['B'])
    assert removed == [] and added == ['mode_eval(t, y, ip, fp, dy, sc, want)',
                                       'tm_eval(t, y, ip, fp, dy, sc, want)']
    added, removed = _added_removed(v['C'])
    assert removed == [] and added == ['_witness_from(kind, t_new, y, ip, fp, K[fsal], sc, g_new)']
    added, removed = _added_removed(v['G'])
    assert removed == [] and added == ['_f(kind, t, y, ip, fp, work[3], sc, False)']
    added, removed = _added_removed(v['Z'])
    assert removed == [] and added == ['if t0 < t_stop:', 'return']
    for k in 'DEF':          # a doubled block: the source's lines, each once more
        added, removed = _added_removed(v[k])
        assert added and all(line in SRC for line in added if line != 'ss = (ss + ss2) / 2'
                             and 'ss2' not in line and 't_i2' not in line)
    assert len(v['D']) - len(SRC) == len(mss._ARG)


def test_changed_source_is_one_line() -> None:
    with pytest.raises(SystemExit, match='segment_nb.py changed'):
        mss.variants(SRC.replace(mss._WIT, ''))


@pytest.mark.parametrize('args', [[], ['x'], ['2'], ['1e-5', '0']])
def test_bad_arguments_one_line(args: list[str]) -> None:
    out = subprocess.run([sys.executable, str(ROOT / 'scripts' / 'mode_segment_split.py'), *args],
                         capture_output=True, text=True, cwd=ROOT, timeout=300)
    assert out.returncode != 0
    assert out.stderr.strip().splitlines() == [
        'mode_segment_split: usage: mode_segment_split.py TOL (0 < TOL < 1) [ROUNDS > 0] '
        '[SCRATCH_DIR]']


def test_base_variant_imports_that_revisions_tree_rhs(tmp_path: Path) -> None:
    """--base REV: segment_nb.py of REV importing REV's tree_modes_nb.py (written beside it);
    an unknown revision is one line."""
    text = mss.base_variant('HEAD', tmp_path)
    head = subprocess.run(['git', 'show', 'HEAD:cvj_ros/physics/kernel/segment_nb.py'],
                          cwd=ROOT, capture_output=True, text=True, check=True).stdout
    assert text == head.replace('from cvj_ros.physics.kernel.tree_modes_nb import',
                                'from segvar_O_tm import')
    assert 'from segvar_O_tm import' in text
    tm = subprocess.run(['git', 'show', 'HEAD:cvj_ros/physics/kernel/tree_modes_nb.py'],
                        cwd=ROOT, capture_output=True, text=True, check=True).stdout
    assert (tmp_path / 'segvar_O_tm.py').read_text() == tm
    with pytest.raises(SystemExit, match="no segment_nb.py at revision 'no-such-rev'"):
        mss.base_variant('no-such-rev', tmp_path)
