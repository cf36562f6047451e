"""kernel.prepare: a run's cold entry points are found from numba's cache index without
compiling; both halves cold: the outputs half in a second process while this one compiles
the stepper half, one line before (what compiles where) and one after (the times); one half
cold: compiled here; nothing cold: nothing said, nothing started."""
from __future__ import annotations

import importlib.util
import io
import sys
from pathlib import Path

import pytest

from cvj_ros.physics.kernel import prepare


def _cached_module(tmp_path: Path):
    pytest.importorskip('numba')
    src = tmp_path / 'cvj_probe_mod.py'
    src.write_text('from numba import njit\n\n\n@njit(cache=True)\ndef twice(x):\n    return 2.0 * x\n')
    spec = importlib.util.spec_from_file_location('cvj_probe_mod', src)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_is_cold_reads_the_index_only(tmp_path: Path) -> None:
    mod = _cached_module(tmp_path)
    assert prepare.is_cold(mod.twice)
    assert not mod.twice.overloads            # the probe compiled nothing
    assert mod.twice(1.5) == 3.0              # compiles and writes the cache
    assert not prepare.is_cold(mod.twice)
    fresh = _cached_module(tmp_path)          # a new process would see the same
    assert not prepare.is_cold(fresh.twice)
    assert prepare.is_cold(object()) is False  # not a cached dispatcher: unknown, not cold


class _Fake:
    def __init__(self, cold: bool) -> None:
        self.cold = cold


@pytest.fixture
def fake_run(monkeypatch: pytest.MonkeyPatch):
    """halves() with two fake dispatchers, compile_half recording, the child command a
    Python that prints what the real child prints."""
    state = {'cold': {'stepper': True, 'outputs': True}, 'here': [], 'covers': True}

    def halves(scene, method):
        return (prepare.Half('stepper', [_Fake(state['cold']['stepper'])], 'the rk4 stepper'),
                prepare.Half('outputs', [_Fake(state['cold']['outputs'])], 'the joint states'))
    monkeypatch.setattr(prepare, 'halves', halves)
    monkeypatch.setattr(prepare, 'is_cold', lambda d: d.cold)
    monkeypatch.setattr(prepare, '_kernel_covers', lambda scene: state['covers'])
    monkeypatch.setattr(prepare, 'compile_half',
                        lambda name, scene, **kw: state['here'].append(name))
    monkeypatch.setattr(prepare, 'child_command', lambda *a, **kw: [
        sys.executable, '-c', 'print("{\\"seconds\\": 0.25}")'])
    return state


class _Scene:
    class solver:
        method = 'rk4'


def test_both_halves_cold_compile_in_two_processes(fake_run) -> None:
    err = io.StringIO()
    times = prepare.prepare_run(Path('s.yaml'), _Scene(), stream=err, parallel=True)
    assert fake_run['here'] == ['stepper']                 # the outputs went to the child
    assert times['outputs'] == 0.25 and set(times) == {'stepper', 'outputs'}
    lines = err.getvalue().splitlines()
    assert lines[0] == ('cvj_ros: compiling the physics kernel for this run: the rk4 stepper in '
                        'this process, the joint states in a second process (in parallel) '
                        '(first use; cached afterwards)')
    assert lines[1].startswith('cvj_ros: compiled the physics kernel for this run in ')
    assert 'outputs 0.2 s' in lines[1] or 'outputs 0.3 s' in lines[1]
    assert len(lines) == 2                                 # not a terminal: no progress line


def test_serial_or_one_half_cold_compiles_here(fake_run) -> None:
    err = io.StringIO()
    prepare.prepare_run(Path('s.yaml'), _Scene(), stream=err, parallel=False)
    assert fake_run['here'] == ['stepper', 'outputs']
    assert 'the rk4 stepper and the joint states (first use' in err.getvalue()
    fake_run['here'].clear()
    fake_run['cold']['stepper'] = False
    prepare.prepare_run(Path('s.yaml'), _Scene(), stream=io.StringIO(), parallel=True)
    assert fake_run['here'] == ['outputs']


def test_nothing_cold_says_nothing(fake_run) -> None:
    fake_run['cold'].update(stepper=False, outputs=False)
    err = io.StringIO()
    assert prepare.prepare_run(Path('s.yaml'), _Scene(), stream=err) == {}
    assert err.getvalue() == '' and fake_run['here'] == []


def test_progress_line_on_a_terminal(fake_run, monkeypatch: pytest.MonkeyPatch) -> None:
    """On a terminal the elapsed time is rewritten in place (carriage return) while it
    compiles, and erased before the closing line."""
    import time

    class Tty(io.StringIO):
        def isatty(self) -> bool:
            return True
    monkeypatch.setattr(prepare, 'TICK_S', 0.05)
    monkeypatch.setattr(prepare, 'compile_half', lambda name, scene, **kw: time.sleep(0.3))
    err = Tty()
    prepare.prepare_run(Path('s.yaml'), _Scene(), stream=err, parallel=False)
    text = err.getvalue()
    assert '\rcvj_ros: compiling the physics kernel... 0 s' in text and text.count('\r') >= 2
    assert '\r\033[K' in text and text.endswith(' s)\n')


def test_a_scene_on_the_python_reference_compiles_nothing(fake_run) -> None:
    """A driveline the kernel does not cover runs on Python: its entry points stay cold for
    good, and every run would otherwise say it compiles."""
    fake_run['covers'] = False
    err = io.StringIO()
    assert prepare.prepare_run(Path('s.yaml'), _Scene(), stream=err) == {}
    assert err.getvalue() == '' and fake_run['here'] == []


def test_kernel_covers_a_shipped_chain_scene() -> None:
    from cvj_ros.physics.scene import find_scene, load_scene
    assert prepare._kernel_covers(load_scene(find_scene('fwd_halfshaft')))
    assert not prepare._kernel_covers(object())
