"""Compile what a ROS run calls before it starts, in two processes when both halves are cold.

A lockstep run calls, in its coupling node, the scene method's stepper (``<method>_advance``
of kernel/steppers_nb.py) and the per-exchange outputs (``joint_state_one``, ``wrenches_one``
of kernel/outputs_nb.py); its engine node the map engine (a ``model: map`` scene), its monitor
the window statistics (kernel/window_nb.py). Cold, the stepper half (stepper, engine map,
windows) and the outputs half take about the same compile time (docs/solvers.md "First run").

numba compiles under one process-wide lock (``numba.core.compiler_lock.global_compiler_lock``,
taken around every compilation), so two threads compile one function after the other: the
halves compile in parallel only in two processes. :func:`prepare_run` probes numba's cache
index of each entry point (no compile, no load); when both halves miss it starts
``python -m cvj_ros.physics.kernel.prepare SCENE`` for the outputs half and compiles the
stepper half itself, each from the run's own scene (the same argument types as the run's
calls, so the run then only loads). numba writes a cache file through a temporary file and
a rename; the halves share no entry point, only callees both may save (``rhs``), where the
worst case of the race is a lost index entry, recompiled at that function's first call from
Python, never a wrong result (kernel/warmup.py runs two processes on one cache the same
way). One half cold: compiled here. Nothing cold: nothing happens (a few index reads).

What the user sees (stderr): one line naming what is compiled where, on a terminal a progress
line with the elapsed time rewritten every second, and one line with the times. In the
one-process-per-node run this happens in ``cvj-sim run`` before any node starts, so the nodes
only load and the compile lines are on the user's terminal, not in the node logs.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any, NamedTuple, TextIO

__all__ = ['Half', 'halves', 'is_cold', 'prepare_run', 'compile_half', 'child_command', 'main']

#: seconds between two rewrites of the progress line (terminal only)
TICK_S = 1.0


class Half(NamedTuple):
    """One compile unit of a run: its name, the numba dispatchers the run calls from it
    (probed by :func:`is_cold`), the user's words for what of it is cold."""
    name: str
    dispatchers: Sequence[Any]
    words: str


def _advance(method: str) -> Any:
    from cvj_ros.physics.kernel import steppers_nb as nb
    from cvj_ros.physics.kernel.stepper import _ROSENBROCK
    if method == 'ros2':
        return nb.ros2_advance
    if method in _ROSENBROCK:
        return nb.ros_advance
    return getattr(nb, f'{method}_advance')


def _uses_map_engine(scene: Any) -> bool:
    from cvj_ros.physics.engine import MapEngine, engine_from_spec
    try:
        return type(engine_from_spec(scene.engine)) is MapEngine
    except Exception:   # noqa: BLE001 (the engine node reports a bad engine, not this probe)
        return False


def _words(dispatchers: Sequence[Any], method: str) -> str:
    """The user's words for the cold ones of ``dispatchers``."""
    names = {'map_engine_eval': 'the engine map', 'ring_push': 'the monitor windows',
             'ring_window_stats': 'the monitor windows', 'cdr_rows': 'the monitor windows',
             'joint_state_one': 'the joint states and wrenches'}
    out = [names.get(getattr(getattr(d, 'py_func', None), '__name__', ''), f'the {method} stepper')
           for d in dispatchers if is_cold(d)]
    return ', '.join(dict.fromkeys(out))


def halves(scene: Any, method: str) -> tuple[Half, Half]:
    """(stepper half, outputs half) of a ROS run of ``scene`` with ``method``: the entry
    points every such run calls from Python (``wrenches_one`` only runs for joints with
    compiled reactions, so it does not decide whether the outputs are cold; it compiles with
    them)."""
    from cvj_ros.physics.kernel import outputs_nb, sources_nb, window_nb
    if getattr(scene, 'has_modes', False):    # the mode model (Python reference) steps it
        stepper = [sources_nb.map_engine_nb] if _uses_map_engine(scene) else []
        stepper += [window_nb.ring_push, window_nb.ring_window_stats, window_nb.cdr_rows]
        return (Half('stepper', stepper, _words(stepper, method)), Half('outputs', [], ''))
    stepper = [_advance(method)]
    if _uses_map_engine(scene):
        stepper.append(sources_nb.map_engine_nb)
    stepper += [window_nb.ring_push, window_nb.ring_window_stats, window_nb.cdr_rows]
    outputs = [outputs_nb.joint_state_one]
    return (Half('stepper', stepper, _words(stepper, method)),
            Half('outputs', outputs, _words(outputs, method)))


def is_cold(dispatcher: Any) -> bool:
    """True when numba's disk cache holds no entry for ``dispatcher`` (its index is missing,
    empty, or stale against the source file: numba's own check). Reads the index only."""
    try:
        return not dispatcher._cache._cache_file._load_index()
    except Exception:   # noqa: BLE001 (no cache, caching off, other numba internals)
        return False   # unknown: the run compiles or loads it as before


def _kernel_covers(scene: Any) -> bool:
    """Whether the run's driveline packs into kernel data (else the run integrates on the
    Python reference and compiles nothing: its entry points stay cold for good)."""
    try:
        from cvj_ros.physics.driveline import Driveline
        from cvj_ros.physics.kernel.layout import build_model
        build_model(Driveline.from_scene(scene))
    except Exception:   # noqa: BLE001 (NotImplementedError, or a bad scene the run reports)
        return False
    return True


def _scene_method(scene: Any) -> str:
    return scene.solver.method


def compile_half(name: str, scene: Any, *, scheme: str = 'zoh',
                 exchange_step: float | None = None) -> None:
    """Compile (or load) one half from the run's scene as the run calls it: the coupling
    node's stepper (:class:`cvj_ros.physics.cosim.CoupledStepper`, which advances a throwaway
    copy), the engine node's map engine and the monitor's windows; or the coupling node's
    per-exchange outputs (:func:`cvj_ros.physics.state_outputs.make_state_outputs`)."""
    from cvj_ros.physics.driveline import Driveline
    if getattr(scene, 'has_modes', False):    # no kernel stepper or outputs: engine, monitor
        if name != 'outputs':
            _compile_sources(scene)
        return
    driveline = Driveline.from_scene(scene)
    if name == 'outputs':
        from cvj_ros.physics.state_outputs import make_state_outputs
        joints = [j for j, m in driveline.joint_models.items() if hasattr(m, 'reactions')]
        make_state_outputs(driveline, joints, compiled=True)
        return
    from cvj_ros.physics.cosim import CoupledStepper
    method = _scene_method(scene)
    h_fixed = scene.solver.h or exchange_step or scene.exchange_step
    CoupledStepper(driveline, scheme=scheme, method=method, rtol=scene.solver.rtol,
                   atol=scene.solver.atol, h=h_fixed if method in ('rk4', 'ros2') else scene.solver.h,
                   slope='estimate' if scheme == 'linear_implicit' else 'reported')
    _compile_sources(scene)


def _compile_sources(scene: Any) -> None:
    """The engine node's map engine and the monitor's windows."""
    if _uses_map_engine(scene):
        from cvj_ros.physics.engine import engine_from_spec
        from cvj_ros.physics.kernel.sources_nb import CompiledMapEngineTorque
        CompiledMapEngineTorque(engine_from_spec(scene.engine))
    from cvj_ros.physics.kernel import window_nb
    window_nb.warm()


@contextmanager
def _quiet_notices() -> Iterator[None]:
    """The per-function compile lines off (this module says it in one line instead)."""
    old = os.environ.pop('CVJ_COMPILE_NOTICE', None)
    try:
        yield
    finally:
        if old is not None:
            os.environ['CVJ_COMPILE_NOTICE'] = old


def _ticker(stream: TextIO, text: str, t0: float, stop: threading.Event) -> None:
    """On a terminal: ``text`` with the elapsed seconds, rewritten in place every
    :data:`TICK_S` (numba's compiler releases the GIL often enough for this thread)."""
    while not stop.wait(TICK_S):
        stream.write(f'\r{text} {time.monotonic() - t0:.0f} s ')
        stream.flush()


def child_command(scene_path: Path, *, scheme: str, exchange_step: float | None) -> list[str]:
    """The second process's command line: this module's :func:`main` on the outputs half."""
    cmd = [sys.executable, '-m', 'cvj_ros.physics.kernel.prepare', str(scene_path),
           '--half', 'outputs', '--scheme', scheme]
    if exchange_step is not None:
        cmd += ['--exchange-step', repr(float(exchange_step))]
    return cmd


def prepare_run(scene_path: Path, scene: Any, *, scheme: str = 'zoh',
                exchange_step: float | None = None, stream: TextIO | None = None,
                parallel: bool | None = None) -> dict[str, float]:
    """Compile the cold halves of a ROS run of ``scene`` (file ``scene_path``) before it
    starts; returns the wall seconds per compiled half (empty when nothing was cold).

    Args:
        parallel: both halves cold: the outputs half in a second process (default: when the
            machine has >= 2 cores and ``CVJ_PREPARE_SERIAL`` is not ``1``).
    """
    stream = sys.stderr if stream is None else stream
    try:
        pair = halves(scene, _scene_method(scene))
    except Exception:   # noqa: BLE001 (no numba, a method without a kernel: the run decides)
        return {}
    cold = [h for h in pair if any(is_cold(d) for d in h.dispatchers)]
    if not cold or not _kernel_covers(scene):
        return {}
    if parallel is None:
        parallel = (os.cpu_count() or 1) >= 2 and os.environ.get('CVJ_PREPARE_SERIAL', '') != '1'
    child = None
    here = cold
    t0 = time.monotonic()
    if parallel and len(cold) == 2:
        here = [cold[0]]
        env = {k: v for k, v in os.environ.items() if k != 'CVJ_COMPILE_NOTICE'}
        cmd = child_command(scene_path, scheme=scheme, exchange_step=exchange_step)
        child = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env)
        where = (f'{cold[0].words} in this process, {cold[1].words} in a second process '
                 f'(in parallel)')
    else:
        where = ' and '.join(h.words for h in cold)
    print(f'cvj_ros: compiling the physics kernel for this run: {where} '
          f'(first use; cached afterwards)', file=stream, flush=True)
    from cvj_ros.progress import is_terminal
    stop = threading.Event()
    ticker = None
    if is_terminal(stream):
        ticker = threading.Thread(target=_ticker, daemon=True,
                                  args=(stream, 'cvj_ros: compiling the physics kernel...', t0, stop))
        ticker.start()
    times: dict[str, float] = {}
    try:
        with _quiet_notices():
            for h in here:
                compile_half(h.name, scene, scheme=scheme, exchange_step=exchange_step)
                times[h.name] = time.monotonic() - t0
        if child is not None:
            out, err = child.communicate()
            if child.returncode == 0:
                try:
                    times['outputs'] = float(json.loads(out.decode().strip().splitlines()[-1])['seconds'])
                except (ValueError, KeyError, IndexError):
                    times['outputs'] = time.monotonic() - t0
            else:   # the run compiles the outputs itself (and reports any real error)
                last = (err.decode(errors='replace').strip().splitlines() or ['no output'])[-1]
                print(f'cvj_ros: the second compile process exited {child.returncode} ({last}); '
                      f'the run compiles the rest itself', file=stream, flush=True)
    finally:
        if child is not None and child.poll() is None:
            child.kill()
            child.wait()
        stop.set()
        if ticker is not None:
            ticker.join()
            stream.write('\r\033[K')
    total = time.monotonic() - t0
    split = ', '.join(f'{n} {s:.1f} s' for n, s in times.items())
    print(f'cvj_ros: compiled the physics kernel for this run in {total:.1f} s ({split})',
          file=stream, flush=True)
    return times


def main(argv: list[str] | None = None) -> int:
    """``python -m cvj_ros.physics.kernel.prepare SCENE --half outputs|stepper [--scheme S]
    [--exchange-step H]``: compile one half (the second process of :func:`prepare_run`);
    prints ``{"seconds": ...}`` on stdout."""
    import argparse
    p = argparse.ArgumentParser(prog='python -m cvj_ros.physics.kernel.prepare')
    p.add_argument('scene', type=Path)
    p.add_argument('--half', choices=('stepper', 'outputs'), required=True)
    p.add_argument('--scheme', default='zoh')
    p.add_argument('--exchange-step', type=float, default=None)
    args = p.parse_args(argv)
    from cvj_ros.physics.scene import load_scene
    t0 = time.monotonic()
    compile_half(args.half, load_scene(args.scene), scheme=args.scheme,
                 exchange_step=args.exchange_step)
    print(json.dumps({'seconds': round(time.monotonic() - t0, 3)}), flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
