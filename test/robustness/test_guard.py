"""The top-level guard (cvj_ros.guard) of `cvj-sim` and the node mains: one line, non-zero
exit, the traceback only with --debug / CVJ_DEBUG=1; Ctrl-C keeps its exit codes."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from cvj_ros import guard
from cvj_ros.cli import main as cli_main
from cvj_ros.errors import SceneError


def _boom() -> int:
    with guard.reading('DIR/scene.yaml'):
        raise ZeroDivisionError('float division by zero')


def test_unexpected_exception_is_one_line_naming_what_was_read(capsys: pytest.CaptureFixture[str],
                                                                monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv('CVJ_DEBUG', raising=False)
    assert guard.guarded('cvj-sim', _boom) == guard.EXIT_UNEXPECTED
    err = capsys.readouterr().err
    assert err == ('cvj-sim: error: DIR/scene.yaml: ZeroDivisionError: float division by zero '
                   '(unexpected; run with --debug or CVJ_DEBUG=1 for the traceback)\n')


@pytest.mark.parametrize('switch', ['flag', 'env'])
def test_debug_prints_the_traceback_before_the_line(switch: str, capsys: pytest.CaptureFixture[str],
                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv('CVJ_DEBUG', raising=False)
    if switch == 'env':
        monkeypatch.setenv('CVJ_DEBUG', '1')
    assert guard.guarded('cvj-sim', _boom, debug=switch == 'flag') == guard.EXIT_UNEXPECTED
    err = capsys.readouterr().err
    assert err.startswith('Traceback') and 'ZeroDivisionError' in err
    assert err.splitlines()[-1].startswith('cvj-sim: error: DIR/scene.yaml: ZeroDivisionError')


def test_user_error_exit_2_and_multiline_message_joined(capsys: pytest.CaptureFixture[str]) -> None:
    def bad() -> int:
        raise SceneError('driveline[1].J', 'must be > 0,\ngot 0')
    assert guard.guarded('cvj-sim', bad) == guard.EXIT_USER
    assert capsys.readouterr().err == 'cvj-sim: error: driveline[1].J: must be > 0, got 0\n'


def test_keyboard_interrupt_and_system_exit_pass_through() -> None:
    def interrupt() -> int:
        raise KeyboardInterrupt
    with pytest.raises(KeyboardInterrupt):
        guard.guarded('cvj-sim', interrupt)
    with pytest.raises(SystemExit):
        guard.guarded('cvj-sim', sys.exit, 3)


def test_an_exception_a_sigint_caused_is_a_keyboard_interrupt(capsys: pytest.CaptureFixture[str]) -> None:
    """A SIGINT inside a C extension's initialisation surfaces as an ImportError caused by the
    KeyboardInterrupt (seen in CI under a node launcher): the guard gives it to the entry
    point's Ctrl-C path (cvj-sim: 130), not an "unexpected" error line."""
    def interrupted_import() -> None:
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt as exc:
            raise ImportError('initialization failed') from exc
    with pytest.raises(KeyboardInterrupt):
        guard.guarded('prog', interrupted_import)
    assert capsys.readouterr().err == ''
    assert guard.caused_by_sigint(ImportError('x')) is False


def test_cli_debug_flag_through_the_executable(tmp_path: Path) -> None:
    scene = tmp_path / 'latin1.yaml'
    scene.write_bytes('name: Gelenkwelle_\u00e4\n'.encode('latin-1'))
    exe = [sys.executable, '-m', 'cvj_ros.cli']
    r = subprocess.run([*exe, 'simulate', str(scene)], capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and r.stdout == ''
    assert r.stderr == (f'cvj-sim: error: {scene}:1: not UTF-8 text: byte 0xe4 at column 19 '
                        '(latin-1 or another encoding? save the file as UTF-8)\n')
    r = subprocess.run([*exe, '--debug', 'simulate', str(scene)], capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and r.stderr.startswith('Traceback')


def test_broken_stdout_pipe_is_silent() -> None:
    exe = [sys.executable, '-m', 'cvj_ros.cli', 'scenes']
    p = subprocess.Popen(exe, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    p.stdout.close()                        # the reader went away (`cvj-sim scenes | head -0`)
    err = p.stderr.read().decode()
    p.wait(timeout=120)
    assert 'Traceback' not in err


def test_cli_in_process_unexpected_error_names_the_scene(monkeypatch: pytest.MonkeyPatch,
                                                         capsys: pytest.CaptureFixture[str]) -> None:
    from cvj_ros.commands import simulate
    monkeypatch.delenv('CVJ_DEBUG', raising=False)

    def broken(args) -> int:
        raise RuntimeError('internal state lost')
    monkeypatch.setattr(simulate, 'run', broken)
    assert cli_main(['simulate', 'stiff']) == guard.EXIT_UNEXPECTED
    assert capsys.readouterr().err.startswith('cvj-sim: error: stiff: RuntimeError: internal state lost')


_BOMB = b'\n'.join([b'a0: &a0 [lol, lol, lol, lol, lol, lol, lol, lol, lol]']
                   + [f'a{i}: &a{i} [{", ".join([f"*a{i - 1}"] * 9)}]'.encode() for i in range(1, 10)])


@pytest.mark.parametrize(('content', 'line'), [
    ('name: x\n'.encode('utf-16'), '{f}: UTF-16 text; cvj_ros reads UTF-8: save the file as UTF-8'),
    (b'name: x\n\x00\x01', '{f}: binary data (NUL byte at offset 8), not a UTF-8 text file'),
    (b'#' * ((1 << 20) + 1), '{f}: scene file larger than 1024 KiB; not a scene file?'),
    (b'name: x\nextra: ' + b'[' * 10_000 + b']' * 10_000, '{f}:2: YAML nested deeper than 64 levels'),
    (_BOMB, '{f}: YAML aliases expand to more than 100000 values (alias bomb?)'),
    (b'name: x\nduration: 1' + b'0' * 400, 'duration: must be a finite number, got an integer of 401 '
                                           'digits (beyond the float range)'),
])
def test_scene_file_rejections_are_one_exact_line(tmp_path: Path, content: bytes, line: str,
                                                  capsys: pytest.CaptureFixture[str]) -> None:
    """docs/robustness.md, table "Bad input": scene files that are not small UTF-8 YAML."""
    f = tmp_path / 'scene.yaml'
    f.write_bytes(content)
    assert cli_main(['simulate', str(f)]) == 2
    out, err = capsys.readouterr()
    assert out == '' and err == f'cvj-sim: error: {line.format(f=f)}\n'
