"""``python -m cvj_ros.physics.kernel.warmup`` (``make kernel``): every method is compiled once,
split over two processes on a machine with two or more cores (the real cold compile takes
~70-120 s: test_bench.py and the CI's ``make kernel`` run it; here the compiling is faked)."""
from __future__ import annotations

import pytest

from cvj_ros.physics.kernel import warmup
from cvj_ros.physics.kernel.stepper import KERNEL_METHODS


class FakeChild:
    def __init__(self, status: int) -> None:
        self.status = status

    def wait(self) -> int:
        return self.status


@pytest.fixture
def fake(monkeypatch: pytest.MonkeyPatch):
    calls: dict[str, list] = {'warm': [], 'outputs': [], 'spawned': []}
    monkeypatch.setattr(warmup, 'warm', lambda methods=KERNEL_METHODS, **kw: calls['warm'].append(
        tuple(methods)) or 0.0)
    monkeypatch.setattr(warmup, 'warm_outputs', lambda **kw: calls['outputs'].append(1) or 0.0)
    monkeypatch.setattr(warmup, 'warm_modes', lambda **kw: calls['outputs'].append(2) or 0.0)
    monkeypatch.delenv('CVJ_WARMUP_SERIAL', raising=False)
    monkeypatch.setattr(warmup.os, 'cpu_count', lambda: 2)

    def spawn(status: int = 0):
        def popen(cmd, **kw):
            calls['spawned'].append(cmd)
            return FakeChild(status)
        monkeypatch.setattr(warmup.subprocess, 'Popen', popen)
    calls['spawn'] = spawn
    return calls


def test_two_cores_split_every_method_between_this_process_and_one_child(fake, capsys) -> None:
    fake['spawn']()
    assert warmup.main([]) == 0
    (cmd,) = fake['spawned']
    assert cmd[1:] == ['-m', 'cvj_ros.physics.kernel.warmup', '--methods', ','.join(warmup.CHILD_METHODS)]
    (mine,) = fake['warm']
    child = tuple(m for m in warmup.CHILD_METHODS if m in KERNEL_METHODS)
    assert sorted(mine + child) == sorted(KERNEL_METHODS)   # each once, all
    assert not set(mine) & set(child)
    assert 'outputs' in warmup.CHILD_METHODS
    assert fake['outputs'] == [2]                             # the mode segment here, outputs there
    assert 'kernel ready' in capsys.readouterr().out


def test_a_failing_child_fails_the_warm_up(fake, capsys) -> None:
    fake['spawn'](status=3)
    assert warmup.main([]) == 1
    assert 'exited 3' in capsys.readouterr().err


def test_one_core_or_the_serial_switch_compiles_everything_here(fake, monkeypatch) -> None:
    fake['spawn']()
    monkeypatch.setattr(warmup.os, 'cpu_count', lambda: 1)
    assert warmup.main([]) == 0
    monkeypatch.setattr(warmup.os, 'cpu_count', lambda: 8)
    monkeypatch.setenv('CVJ_WARMUP_SERIAL', '1')
    assert warmup.main([]) == 0
    assert fake['spawned'] == [] and fake['warm'] == [KERNEL_METHODS, KERNEL_METHODS]
    assert fake['outputs'] == [1, 2, 1, 2]                    # outputs and modes, both runs


def test_child_mode_and_bad_arguments(fake, capsys) -> None:
    assert warmup.main(['--methods', 'ros2,rodas4']) == 0
    assert fake['warm'] == [('ros2', 'rodas4')] and fake['outputs'] == []
    assert warmup.main(['--methods', 'tsit5,outputs']) == 0
    assert fake['warm'][-1] == ('tsit5',) and fake['outputs'] == [1]
    assert warmup.main(['--methods', 'ros2,euler']) == 2
    assert 'unknown euler' in capsys.readouterr().err
    assert warmup.main(['--fast']) == 2
