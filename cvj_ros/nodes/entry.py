"""Entry functions of the node executables (setup.py's launchers run them through
:func:`cvj_ros.start.run`): each imports its node module and calls that module's ``main()``.

Why not ``cvj_ros.nodes.<node>:main`` directly: a console script imports the module before it
calls ``main``, so a SIGINT that arrives while the module's imports (rclpy, numpy, numba, the
physics) are still loading - Ctrl-C right after ``ros2 run``, or ``cvj-sim run`` stopping
nodes it has just started - ended the process with the interpreter's KeyboardInterrupt
traceback (in the node's log file under ``cvj-sim run``). Here the import runs inside the
launcher: interrupted, the process exits with status 0 and no output, as a node interrupted
while spinning does (``executor.run_node``). This module imports nothing heavy.
"""
from __future__ import annotations

import importlib
import signal
import sys


def launch(module: str) -> None:
    """Import ``cvj_ros.nodes.<module>`` and run its ``main()`` (exit status 0 if a SIGINT
    interrupts the import, also inside a C extension's initialisation).

    The SIGINT handler during the import records the signal before it raises
    KeyboardInterrupt: raised inside a weakref callback or ``__del__`` (the import system's
    module-lock callbacks run during garbage collection), the interpreter prints "Exception
    ignored in ..." and goes on, and the node then waited at its start gate for good
    (reproduced once in 408 SIGINTs under load). A recorded SIGINT ends the process with
    status 0 after the import as well."""
    got: list[int] = []

    def on_sigint(signum: int, _frame: object) -> None:
        got.append(signum)
        raise KeyboardInterrupt
    previous = signal.signal(signal.SIGINT, on_sigint)
    try:
        try:
            node_module = importlib.import_module(f'cvj_ros.nodes.{module}')
        except KeyboardInterrupt:
            sys.exit(0)
        except BaseException as exc:  # noqa: BLE001 (re-raised unless a SIGINT caused it)
            from cvj_ros.guard import caused_by_sigint   # not at module level: no import before the try
            if caused_by_sigint(exc):
                sys.exit(0)
            raise
        if got:                       # a KeyboardInterrupt the interpreter ignored
            sys.exit(0)
    finally:
        signal.signal(signal.SIGINT, previous)
    node_module.main()


def engine_node() -> None:
    launch('engine_node')


def coupling_node() -> None:
    launch('coupling_node')


def load_node() -> None:
    launch('load_node')


def monitor_node() -> None:
    launch('monitor_node')


def replay_node() -> None:
    launch('replay_node')


def driver_node() -> None:
    launch('driver_node')
