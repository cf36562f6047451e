"""The local process pool's fork server, started without importing the sweep machinery.

:func:`start_fork_server` sets the ``forkserver`` preload to :mod:`cvj_ros.sweep.preload`
and starts the server: a fresh interpreter that imports numba and loads the compiled
kernel (~0.55 s CPU), which every pool worker then forks from. ``cvj-sim sweep`` calls it
before it imports numpy, the scene parser and the sweep's own modules, so the server's
kernel load runs beside the command's start-up on the other core; the
:class:`~cvj_ros.sweep.run.ProcessExecutor` calls it again (a no-op once running).
:func:`stop_fork_server` (run at this process's exit) ends the server and waits for it, so
a command that stops early (a mistyped scene name, a bad ``--set``) leaves no process
loading the kernel behind it.
"""
from __future__ import annotations

import os

PRELOAD = ['cvj_ros.sweep.preload']


def start_fork_server() -> None:
    """Start (once per process) the fork server that loads the kernel for the pool."""
    import multiprocessing as mp
    from multiprocessing import forkserver
    # a threaded BLAS in every worker would oversubscribe the cores (see Makefile); the
    # server inherits this environment, and the workers the server's
    os.environ.setdefault('OPENBLAS_NUM_THREADS', '1')
    mp.get_context('forkserver').set_forkserver_preload(PRELOAD)
    before = getattr(forkserver._forkserver, '_forkserver_pid', None)
    forkserver.ensure_running()
    global _AT_EXIT, _SERVED
    if getattr(forkserver._forkserver, '_forkserver_pid', None) != before:
        _SERVED = False     # a new server (the first, or one after a dead one)
    if not _AT_EXIT:
        import atexit
        atexit.register(stop_fork_server)
        _AT_EXIT = True


_AT_EXIT = False
_SERVED = False     # the server has forked a worker: its preload is done


def mark_served() -> None:
    """Note that the fork server has forked a worker (so it has loaded its preload and
    ends by itself, at once, when this process exits)."""
    global _SERVED
    _SERVED = True


def stop_fork_server() -> None:
    """End this process's fork server, if it started one and it has not served a worker
    yet, and wait for it. A server still importing its preload would otherwise run on after
    its parent exits: it stops only when its preload is done and it finds the parent's pipe
    closed (a server that has served is past its preload and is left to do so). Called at
    exit (after the pool's workers are gone); a later :func:`start_fork_server` starts a
    new one."""
    import signal
    from multiprocessing import forkserver
    server = forkserver._forkserver        # the module's ForkServer (no public handle)
    pid = getattr(server, '_forkserver_pid', None)
    if pid is None or _SERVED:
        return
    try:
        os.kill(pid, signal.SIGTERM)
    except ProcessLookupError:
        pass
    try:
        server._stop()      # closes its pipe, waits for the pid, removes its socket
    except OSError:         # reaped already: forget it as _stop would
        server._forkserver_pid = server._forkserver_address = None


def usable_cores() -> int:
    """Cores this process may run on (sched_getaffinity), else os.cpu_count()."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)
