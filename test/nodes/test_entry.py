"""The node executables' launchers (cvj_ros/nodes/entry.py): a SIGINT while a node's modules
are still importing ends it with exit status 0 and no traceback, as a SIGINT while it spins
does (`cvj-sim run` stops nodes it has just started that way; Ctrl-C after `ros2 run`)."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from cvj_ros.nodes import entry

pytestmark = pytest.mark.ros

COUPLING = str(Path(sys.executable).with_name('coupling_node'))


def test_every_node_executable_goes_through_its_launcher() -> None:
    """setup.py's executable of each node runs its launcher here, and each launcher names
    the module of the same name."""
    import re
    setup = (Path(__file__).resolve().parents[2] / 'setup.py').read_text()
    nodes = re.search(r"NODES = \[(.*?)\]", setup).group(1)
    names = [n.strip().strip("'") for n in nodes.split(',')]
    assert "**{n: f'cvj_ros.nodes.entry:{n}' for n in NODES}" in setup
    for name in names:
        assert callable(getattr(entry, name))
        assert (Path(entry.__file__).with_name(f'{name}.py')).is_file()
    script = Path(sys.executable).with_name('coupling_node').read_text()
    assert 'cvj_ros.nodes.entry' in script          # the installed executable (make setup)


@pytest.mark.parametrize('delay', [0.15, 0.4, 0.8, 1.5])
def test_sigint_during_start_up_exits_0_without_a_traceback(tmp_path: Path, ros_domain: int,
                                                            delay: float) -> None:
    """The gated coupling node (no topic endpoint until "go": nothing reaches the domain)
    interrupted at increasing times after the interpreter's own start-up: during the
    imports (~1-2 s here: rclpy, numba, the physics), then while it builds or waits at its
    gate. Every time: status 0, no traceback in its output.

    The delay counts from the end of Python's own start-up (the ``site`` import, marked by
    a ``sitecustomize`` on PYTHONPATH that touches a file), not from exec: a SIGINT before
    any cvj_ros code runs is the interpreter's to report (docs/robustness.md, Ctrl-C while
    importing), and under load that start-up alone took more than 0.8 s (make test-stress:
    ``Fatal Python error: init_import_site`` at 0.15 s and 0.8 s after exec)."""
    log, mark, site = tmp_path / 'log', tmp_path / 'site_done', tmp_path / 'site'
    site.mkdir()
    (site / 'sitecustomize.py').write_text(
        f'open({str(mark)!r}, "w").close()   # the interpreter has imported site\n')
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(
        [str(site)] + [p for p in os.environ.get('PYTHONPATH', '').split(os.pathsep) if p]))
    with open(log, 'wb') as out:
        proc = subprocess.Popen([COUPLING, '--ros-args', '-p', 'scene:=kavz685_lever',
                                 '-p', 'start_gate:=stdin'], env=env,
                                stdin=subprocess.PIPE, stdout=out, stderr=subprocess.STDOUT)
        try:
            deadline = time.monotonic() + 60.0
            while not mark.exists() and proc.poll() is None and time.monotonic() < deadline:
                time.sleep(0.002)
            assert mark.exists(), log.read_text(errors='replace')
            time.sleep(delay)
            proc.send_signal(signal.SIGINT)
            rc = proc.wait(timeout=60)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
    text = log.read_text(errors='replace')
    assert rc == 0, text
    assert 'Traceback' not in text and 'KeyboardInterrupt' not in text, text


def test_sigint_inside_a_c_extensions_initialisation_exits_0(monkeypatch: pytest.MonkeyPatch) -> None:
    """A SIGINT while rclpy's C extension initialises surfaces as ``ImportError:
    initialization failed`` caused by the KeyboardInterrupt (seen once in CI at 0.15 s after
    exec): exit 0 as for a plain KeyboardInterrupt. An ImportError of its own still raises."""
    import importlib

    def interrupted_init(name: str):
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt as exc:
            raise ImportError('initialization failed') from exc
    monkeypatch.setattr(importlib, 'import_module', interrupted_init)
    with pytest.raises(SystemExit) as done:
        entry.launch('coupling_node')
    assert done.value.code == 0

    def missing(name: str):
        raise ImportError('No module named x')
    monkeypatch.setattr(importlib, 'import_module', missing)
    with pytest.raises(ImportError, match='No module named x'):
        entry.launch('coupling_node')


def test_sigint_whose_keyboard_interrupt_the_interpreter_ignored_still_exits_0(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """A SIGINT whose KeyboardInterrupt is raised inside a weakref callback during the import
    is printed and ignored by the interpreter ("Exception ignored in"; under load the node
    then waited at its start gate for good): the launcher recorded it and exits 0 without
    running the node, and puts the previous SIGINT handler back."""
    import importlib
    before = signal.getsignal(signal.SIGINT)

    class Node:
        @staticmethod
        def main() -> None:
            raise AssertionError('the node must not run')

    def import_with_ignored_interrupt(name: str):
        try:                          # what the interpreter does with it in a callback
            signal.getsignal(signal.SIGINT)(signal.SIGINT, None)
        except KeyboardInterrupt:
            pass
        return Node
    monkeypatch.setattr(importlib, 'import_module', import_with_ignored_interrupt)
    with pytest.raises(SystemExit) as done:
        entry.launch('coupling_node')
    assert done.value.code == 0
    assert signal.getsignal(signal.SIGINT) is before
