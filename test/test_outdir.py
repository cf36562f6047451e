"""cvj_ros.outdir and cvj-sim: an output directory that cannot be written stops the command
at once with one line naming the option; the check leaves nothing behind."""
from __future__ import annotations

from pathlib import Path

import pytest

from cvj_ros.errors import CvjError
from cvj_ros.outdir import check_out_dir


def test_writable_new_directory_passes_and_is_not_left_behind(tmp_path: Path) -> None:
    check_out_dir(tmp_path / 'a' / 'b')
    assert not (tmp_path / 'a').exists()
    check_out_dir(tmp_path)            # existing and writable
    assert list(tmp_path.iterdir()) == []


def test_unusable_directories_name_the_option(tmp_path: Path) -> None:
    (tmp_path / 'file').write_text('x')
    with pytest.raises(CvjError, match=r'^--out: cannot write to .*/file/x: Not a directory$'):
        check_out_dir(tmp_path / 'file' / 'x')
    with pytest.raises(CvjError, match=r'^OUT: .*/file exists and is not a directory$'):
        check_out_dir(tmp_path / 'file', 'OUT')
    with pytest.raises(CvjError, match=r'^--out: cannot write to /proc/cvj_out_test: '):
        check_out_dir('/proc/cvj_out_test')


@pytest.mark.parametrize('argv, option', [
    (['run', 'kavz685_lever', '--out', '/proc/cvj_out_test'], '--out'),
    (['sweep', 'kavz685_lever', '--set', 'engine.m1=600,610', '--out', '/proc/cvj_out_test'], '--out'),
    (['record', '/proc/cvj_out_test'], 'OUT'),
])
def test_cvj_sim_names_the_option_not_the_scene(argv: list[str], option: str,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    from cvj_ros.cli import main
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith(f'cvj-sim: error: {option}: cannot write to /proc/cvj_out_test'), err
    assert 'kavz685_lever' not in err and 'unexpected' not in err
