"""The installed executables (setup.py's sh launchers, cvj_ros/start.py): a Ctrl-C at any
moment of a command's start-up - inside Python's own start-up included - ends it without a
traceback: ``cvj-sim`` with ``cvj-sim: interrupted`` and status 130, a node with status 0."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from cvj_ros import start

REPO = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent
# a SIGINT before Python runs (in the launcher's sh or env, ~1 ms) kills the process: a shell
# shows that as 130 too, with nothing printed
KILLED = -signal.SIGINT


def _installed(name: str) -> str:
    path = BIN / name
    text = path.read_text(errors='replace') if path.exists() else ''
    if 'cvj_ros.start' not in text:
        pytest.fail(f'{path} is not the cvj_ros launcher (an install older than setup.py: make setup)')
    return str(path)


def _setup_module():
    import importlib.util
    import unittest.mock
    spec = importlib.util.spec_from_file_location('cvj_setup', REPO / 'setup.py')
    mod = importlib.util.module_from_spec(spec)
    with unittest.mock.patch('setuptools.setup'), unittest.mock.patch.object(sys, 'argv', ['setup.py']):
        spec.loader.exec_module(mod)
    return mod


def test_launcher_text_blocks_sigint_and_runs_the_entry() -> None:
    setup = _setup_module()
    text = setup.launcher_text('cvj_ros.cli:main', '/opt/my venv/bin/python')
    assert text.startswith('#!/bin/sh\n')          # not a python shebang: installers keep it
    assert ("exec /usr/bin/env --block-signal=INT '/opt/my venv/bin/python' -P -c "
            "'from cvj_ros.start import run; run(\"cvj_ros.cli:main\")' \"$0\" \"$@\"\n") in text
    # an env without --block-signal: Python directly (the old start-up window, said at install)
    assert setup.launcher_text('cvj_ros.cli:main', '/usr/bin/python3', block=False).endswith(
        "\nexec /usr/bin/python3 -P -c 'from cvj_ros.start import run; run(\"cvj_ros.cli:main\")' \"$0\" \"$@\"\n")
    assert setup.env_blocks_signals()      # GNU coreutils >= 8.31 (Ubuntu 22.04+, Debian 11+)
    assert setup.EXECUTABLES['cvj-sim'] == 'cvj_ros.cli:main'
    assert all(setup.EXECUTABLES[n] == f'cvj_ros.nodes.entry:{n}' for n in setup.NODES)


def test_installed_executables_are_the_launchers() -> None:
    setup = _setup_module()
    for name, target in setup.EXECUTABLES.items():
        text = Path(_installed(name)).read_text()
        assert f'run("{target}")' in text and '--block-signal=INT' in text, name


def test_a_running_executable_is_named_after_itself() -> None:
    """ps and top show ``cvj-sim``, not ``python`` (/proc/PID/comm, which run() sets)."""
    code = 'import cvj_ros.start as s; s._name_process("cvj-sim"); print(open("/proc/self/comm").read())'
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True, timeout=60).stdout
    assert out.strip() == 'cvj-sim'


def _run_interrupted(cmd: list[str], delay: float | None, env: dict[str, str] | None = None
                     ) -> tuple[int, str]:
    """Status and stderr of ``cmd`` sent SIGINT ``delay`` s after it started (None: not sent)."""
    # SIGINT at its default, as for a terminal's foreground job (also when pytest itself was
    # started with SIGINT ignored, in a script's background: children inherit that)
    cmd = ['/usr/bin/env', '--default-signal=INT', *cmd]
    proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, env=env, start_new_session=True)
    try:
        time.sleep(delay or 0.0)
        if delay is not None and proc.poll() is None:
            os.killpg(proc.pid, signal.SIGINT)    # what a terminal's Ctrl-C does
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    return proc.returncode, err.decode(errors='replace')


def _sigint_inside_site(tmp_path: Path) -> dict[str, str]:
    """An environment whose Python start-up (``site`` importing ``sitecustomize``) sends
    itself SIGINT: the moment no cvj_ros code could catch it before the launcher."""
    (tmp_path / 'sitecustomize.py').write_text(
        'import os, signal, time\nos.kill(os.getpid(), signal.SIGINT)\ntime.sleep(0.05)\n')
    env = dict(os.environ)
    env['PYTHONPATH'] = os.pathsep.join(p for p in (str(tmp_path), env.get('PYTHONPATH')) if p)
    return env


@pytest.mark.parametrize('name, status, line', [('cvj-sim', 130, 'cvj-sim: interrupted\n'),
                                                ('monitor_node', 0, '')])
def test_sigint_during_python_start_up(tmp_path: Path, name: str, status: int, line: str) -> None:
    """Deterministic: the SIGINT arrives inside ``site``; it waits, blocked, for
    cvj_ros.start, which ends the program with the interrupted status and no traceback."""
    rc, err = _run_interrupted([_installed(name), 'scenes'] if name == 'cvj-sim' else [_installed(name)],
                               None, env=_sigint_inside_site(tmp_path))
    assert (rc, err) == (status, line)


@pytest.mark.parametrize('delay', [0.0, 0.03, 0.08, 0.15, 0.3])
def test_cvj_sim_interrupted_early_prints_no_traceback(delay: float) -> None:
    """Ctrl-C 0-0.3 s into ``cvj-sim scenes`` (Python's start-up, the imports, the listing):
    status 130 (or killed before Python ran), at most the one line, never a traceback."""
    rc, err = _run_interrupted([_installed('cvj-sim'), 'scenes'], delay)
    assert rc in (130, KILLED, 0), (rc, err)       # 0: it had finished
    assert err in ('', 'cvj-sim: interrupted\n'), err


@pytest.mark.ros
@pytest.mark.parametrize('delay', [0.0, 0.1, 0.3])
def test_node_interrupted_early_prints_no_traceback(delay: float) -> None:
    """A node (monitor_node, which starts without peers) interrupted 0-0.3 s after exec:
    status 0 as when it is stopped while spinning (or killed before Python ran), no output."""
    rc, err = _run_interrupted([_installed('monitor_node')], delay)
    assert rc in (0, KILLED), (rc, err)
    assert 'Traceback' not in err and 'KeyboardInterrupt' not in err, err


def test_run_exit_statuses(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                           capsys: pytest.CaptureFixture[str]) -> None:
    """run(): the entry's return value is the status; a KeyboardInterrupt before the entry
    handles it gives the program's interrupted status (and line); SIGINT is unblocked."""
    (tmp_path / 'fake_entry.py').write_text(
        'def ok():\n    return 3\n'
        'def interrupted():\n    raise KeyboardInterrupt\n')
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setitem(start.INTERRUPTED, 'fake_entry', (130, 'fake: interrupted'))
    monkeypatch.setattr(sys, 'unraisablehook', sys.unraisablehook)   # restored after
    named = []
    monkeypatch.setattr(start, '_name_process', named.append)
    previous = signal.getsignal(signal.SIGINT)
    try:
        for function, status, err in (('ok', 3, ''), ('interrupted', 130, 'fake: interrupted\n')):
            monkeypatch.setattr(sys, 'argv', ['-c', '/bin/fake', '--flag'])
            signal.pthread_sigmask(signal.SIG_BLOCK, (signal.SIGINT,))
            with pytest.raises(SystemExit) as done:
                start.run(f'fake_entry:{function}')
            assert done.value.code == status
            assert sys.argv == ['/bin/fake', '--flag']
            assert signal.SIGINT not in signal.pthread_sigmask(signal.SIG_BLOCK, ())
            assert capsys.readouterr().err == err
        assert named == ['fake', 'fake']
    finally:
        signal.signal(signal.SIGINT, previous)


def test_an_interrupt_python_reports_as_unraisable_is_sent_again(tmp_path: Path) -> None:
    """A KeyboardInterrupt raised inside a weakref callback (where Python prints "Exception
    ignored in ..." and goes on; a Ctrl-C landed in the import system's module-lock callback
    that way once in 200 tries) is sent again as SIGINT: the program stops, quietly."""
    (tmp_path / 'fake_entry.py').write_text(
        'import time, weakref\n'
        'class A:\n    pass\n'
        'def interrupt(_ref):\n    raise KeyboardInterrupt\n'
        'def main():\n'
        '    a = A()\n    ref = weakref.ref(a, interrupt)\n    del a\n'
        '    time.sleep(30)\n    return 7\n')
    code = (f'import sys; sys.path.insert(0, {str(tmp_path)!r}); '
            'from cvj_ros.start import run; run("fake_entry:main")')
    env = dict(os.environ, PYTHONPATH=str(REPO))
    t0 = time.monotonic()
    r = subprocess.run([sys.executable, '-P', '-c', code, 'fake'], capture_output=True,
                       text=True, timeout=60, env=env)
    assert (r.returncode, r.stderr) == (0, '')
    assert time.monotonic() - t0 < 25     # stopped, not slept out
