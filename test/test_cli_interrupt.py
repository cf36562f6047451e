"""cvj-sim: a Ctrl-C at any point of main - also while it builds the parser and imports the
subcommand - prints one line and exits 130, never a traceback."""
from __future__ import annotations

import subprocess
import sys

import pytest

from cvj_ros import cli


def _interrupted(_only: object = None) -> None:
    raise KeyboardInterrupt


def _interrupted_import(_only: object = None) -> None:
    try:
        raise KeyboardInterrupt
    except KeyboardInterrupt as exc:   # a SIGINT inside a C extension's initialisation
        raise ImportError('initialization failed') from exc


@pytest.mark.parametrize('where', [_interrupted, _interrupted_import])
def test_interrupt_while_building_the_parser(where, monkeypatch: pytest.MonkeyPatch,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setattr(cli, 'build_parser', where)
    assert cli.main(['scenes']) == 130
    assert capsys.readouterr().err == 'cvj-sim: interrupted\n'


def test_other_errors_still_raise(monkeypatch: pytest.MonkeyPatch) -> None:
    def broken(_only: object = None) -> None:
        raise ImportError('a real import error')
    monkeypatch.setattr(cli, 'build_parser', broken)
    with pytest.raises(ImportError):
        cli.main(['scenes'])


def test_module_imports_nothing_heavy() -> None:
    """Importing cvj_ros.cli (what the console script does before main runs) loads neither
    argparse nor typing: the window a SIGINT could hit outside main stays minimal."""
    code = ('import sys; before = set(sys.modules); import cvj_ros.cli; '
            'print(sorted(m for m in set(sys.modules) - before if not m.startswith("cvj_ros")))')
    out = subprocess.run([sys.executable, '-S', '-c', code], capture_output=True, text=True,
                         timeout=60, env=None).stdout
    assert 'argparse' not in out and "'typing'" not in out, out
