"""kernel.compiling: a compile on first use is announced on stderr (one line before, one
after with its wall time) when CVJ_COMPILE_NOTICE=1, which cvj-sim sets; silent otherwise,
and silent for an entry point already in memory."""
from __future__ import annotations

import pytest

from cvj_ros.physics.kernel import compiling, entry_point


def _fresh():
    numba = pytest.importorskip('numba')

    @numba.njit
    def twice(x):
        return 2.0 * x
    return twice


def test_first_use_is_announced(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setenv('CVJ_COMPILE_NOTICE', '1')
    fn = _fresh()
    assert entry_point(fn, (1.5,))(1.5) == 3.0
    err = capsys.readouterr().err.splitlines()
    assert err[0] == 'cvj_ros: compiling the physics kernel: twice (first use; cached afterwards)'
    assert err[1].startswith('cvj_ros: compiled twice in ') and err[1].endswith(' s')
    entry_point(fn, (2.5,))                   # compiled already: nothing to say
    assert capsys.readouterr().err == ''


def test_silent_without_the_switch(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.delenv('CVJ_COMPILE_NOTICE', raising=False)
    entry_point(_fresh(), (1.0,))
    with compiling(object()):
        pass
    assert capsys.readouterr().err == ''


def test_cvj_sim_switches_it_on_for_itself_and_its_children() -> None:
    import os
    import subprocess
    import sys
    code = ('import os, sys; from cvj_ros import cli; sys.argv = ["cvj-sim", "scenes"]; '
            'cli.main(); print("NOTICE=" + os.environ.get("CVJ_COMPILE_NOTICE", ""), file=sys.stderr)')
    env = {k: v for k, v in os.environ.items() if k != 'CVJ_COMPILE_NOTICE'}
    r = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True, timeout=120, env=env)
    assert 'NOTICE=1' in r.stderr, r.stderr
