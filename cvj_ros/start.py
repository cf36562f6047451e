"""The Python end of the installed executables (``cvj-sim``, ``driveline_composed``, the nodes).

Each executable is a two-line POSIX-sh launcher that setup.py writes (``launcher_text``
there)::

    #!/bin/sh
    exec /usr/bin/env --block-signal=INT /path/to/python -P -c 'from cvj_ros.start import run; run("cvj_ros.cli:main")' "$0" "$@"

Python thus starts with SIGINT *blocked* (a signal mask survives ``exec``): a Ctrl-C during the
interpreter's start-up (``site``, the encodings, this module's import) stays pending instead
of raising KeyboardInterrupt where no cvj_ros code can catch it. :func:`run` unblocks it first
thing inside a ``try``: a pending Ctrl-C is delivered there and the program exits
quietly with the status it gives an interrupted run (``cvj-sim``: the line ``cvj-sim:
interrupted``, 130; the nodes and ``driveline_composed``: 0, as when they are stopped while
running). A Ctrl-C that Python can only report as "unraisable" (its KeyboardInterrupt raised
inside a weakref callback or a finaliser) is sent again, so it still stops the program. Once
the entry point returns, a Ctrl-C during the interpreter's teardown ends the process with
the entry's status and no output. The process is named after the executable (ps, top).
Imports next to nothing (``collections.abc`` while SIGINT is still blocked), the entry's
module after the unblock.
"""
from __future__ import annotations

import _thread
import os
import signal
import sys
from collections.abc import Callable   # ~1 ms, imported while SIGINT is still blocked

__all__ = ['INTERRUPTED', 'run']

#: exit status and stderr line of an entry interrupted before it handles SIGINT itself
INTERRUPTED: dict[str, tuple[int, str]] = {'cvj_ros.cli': (130, 'cvj-sim: interrupted')}


def run(target: str) -> None:
    """Run ``target`` (``'module:function'``) as the program: ``sys.argv`` is the launcher's
    ``"$0" "$@"``; exits with the function's return value (see module doc for SIGINT)."""
    module, _, function = target.partition(':')
    status, line = INTERRUPTED.get(module, (0, ''))
    del sys.argv[0]                      # '-c': argv[0] is the launcher's path, as for a script
    _name_process(os.path.basename(sys.argv[0]))
    sys.unraisablehook = _redeliver_interrupt(sys.unraisablehook)
    try:
        # a Ctrl-C pending since exec is delivered here, as KeyboardInterrupt
        signal.pthread_sigmask(signal.SIG_UNBLOCK, (signal.SIGINT,))
        import importlib
        status = getattr(importlib.import_module(module), function)()
    except KeyboardInterrupt:
        if line:
            print(line, file=sys.stderr)
    except SystemExit as done:
        status = done.code
    except Exception as exc:   # a SIGINT inside a C extension's import surfaces as its cause
        from cvj_ros.guard import caused_by_sigint
        if not caused_by_sigint(exc):
            raise
        if line:
            print(line, file=sys.stderr)
    _exit_quietly_on_sigint(status)
    sys.exit(status)


def _name_process(name: str) -> None:
    """Show ``name`` (not ``python``) as the process name in ps/top, as when a script runs
    from its own ``#!`` line (Linux: /proc/self/comm, 15 characters)."""
    try:
        with open('/proc/self/comm', 'w') as comm:
            comm.write(name[:15])
    except OSError:
        pass


def _redeliver_interrupt(previous: Callable[[object], object]) -> Callable[[object], object]:
    """An unraisable-exception hook that sends SIGINT again, from a new thread, when the
    exception is a KeyboardInterrupt: a Ctrl-C whose handler ran inside a weakref callback
    or a finaliser (the import system's module-lock callback, measured once in 200 early
    Ctrl-C) is otherwise printed as ``Exception ignored in ...`` with a traceback and lost.
    Other exceptions go to ``previous``."""
    def hook(unraisable: object) -> None:
        if isinstance(getattr(unraisable, 'exc_value', None), KeyboardInterrupt):
            _thread.start_new_thread(os.kill, (os.getpid(), signal.SIGINT))
            return
        previous(unraisable)
    return hook


def _exit_quietly_on_sigint(status: object) -> None:
    """From here on a SIGINT ends the process at once with ``status`` (the teardown left)."""
    code = status if isinstance(status, int) else (0 if status is None else 1)

    def handler(_signum: int, _frame: object) -> None:
        for stream in (sys.stdout, sys.stderr):
            try:
                stream.flush()
            except (OSError, ValueError):
                pass
        os._exit(code)
    if signal.getsignal(signal.SIGINT) is not signal.SIG_IGN:
        signal.signal(signal.SIGINT, handler)
