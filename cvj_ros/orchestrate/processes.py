"""How a node process starts and stops: its command line and ROS parameters, the parent-death
signal, the stop order (SIGINT, SIGTERM, SIGKILL) and the error line read from its log."""
from __future__ import annotations

import re
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from cvj_ros.orchestrate.options import _Prepared


def node_command(name: str) -> list[str]:
    """How to start node ``name``: the console script next to this Python, else on PATH,
    else ``python -c 'from cvj_ros.nodes.<name> import main; main()'``. Every node flushes
    its publishers before it exits (cvj_ros.nodes.common.flush_publishers)."""
    exe = Path(sys.executable).with_name(name)
    if exe.exists():
        return [str(exe)]
    found = shutil.which(name)
    if found:
        return [found]
    return [sys.executable, '-c', f'from cvj_ros.nodes.{name} import main; main()']


def node_parameters(prep: _Prepared, name: str, *, load_override: Path | None) -> dict[str, Any]:
    """ROS parameters given to node ``name`` (see docs/ros.md and each node's PARAMS)."""
    o = prep.options
    params: dict[str, Any] = {'scene': str(prep.scene_path)}
    if prep.seed is not None:
        params['seed'] = int(prep.seed)
    if name == 'coupling_node':
        params.update(mode=o.mode, coupling_scheme=o.scheme, exchange_step=float(prep.exchange_step),
                      duration=float(prep.duration), peer_timeout=float(o.peer_timeout),
                      nonfinite_torque=o.nonfinite_torque,
                      **({'catch_up': o.catch_up, 'burst_max': int(o.burst_max),
                          'realtime_priority': int(o.rt_priority)} if o.mode == 'free-run' else {}),
                      # engine, load, the recorder (and monitor) see /driveline/joint_states before step 0
                      min_subscribers=3 + ('monitor_node' in prep.nodes),
                      # after "go" the peers are there: a bounded wait, as the run's own
                      start_timeout=float(o.start_timeout))
        if getattr(prep, 'peers', None) is not None:      # a vehicle scene, --external load
            params['wheel_load'] = 'external'
    if name == 'coupling_node' and prep.scene.has_modes:
        # the driver's samples gate each state (lockstep), or an outside stack's are taken as they come
        params['commands'] = 'external' if 'driver' in o.external else 'driver'
        params['mode_backend'] = o.mode_backend
    if name == 'driver_node':
        params.update(exchange_step=float(prep.exchange_step), duration=float(prep.duration))
    if name == 'engine_node' and 'driver_node' in prep.nodes and o.mode == 'lockstep':
        # the state t_k is answered with the driver's throttle of step k (counted)
        params.update(commands='driver', exchange_step=float(prep.exchange_step),
                      duration=float(prep.duration))
    if name == 'engine_node' and getattr(prep.scene, 'shift_schedule', None) is not None:
        # the shift schedule's throttle scale with its joint state (lockstep), or as it comes
        params['throttle_scale'] = 'lockstep' if o.mode == 'lockstep' else 'on_arrival'
    if load_override is not None and name in ('coupling_node', 'load_node'):
        params['load_override'] = str(load_override)
    return params


def _ros_args(params: dict[str, Any]) -> list[str]:
    args = ['--ros-args']
    for k, v in params.items():
        if isinstance(v, bool):
            v = str(v).lower()
        elif isinstance(v, float):
            v = repr(v)
        args += ['-p', f'{k}:={v}']
    return args


try:  # loaded in the parent: the child between fork and exec must not import anything
    import ctypes
    _LIBC: Any = ctypes.CDLL('libc.so.6', use_errno=True)
except OSError:  # not glibc Linux
    _LIBC = None


def _die_with_parent() -> None:
    """In the child: get SIGTERM if cvj-sim dies (Linux PR_SET_PDEATHSIG = 1), so no node is orphaned."""
    if _LIBC is not None:
        _LIBC.prctl(1, int(signal.SIGTERM))


def close_stdin(proc: subprocess.Popen[bytes]) -> None:
    """Close our end of ``proc``'s standard input, if it has one (idempotent): a node still
    waiting at its start gate reads EOF and exits 0 without starting."""
    if proc.stdin is not None and not proc.stdin.closed:
        try:
            proc.stdin.close()
        except OSError:      # it exited: a broken pipe on the flush
            pass


def start_gated(proc: subprocess.Popen[bytes], log: Path) -> str | None:
    """Say ``go`` to a node waiting at its start gate (coupling_node ``start_gate=stdin``);
    None, or the error line when the process exited before it could hear it."""
    rc = proc.poll()
    if rc is None and proc.stdin is not None:
        try:
            proc.stdin.write(b'go\n')
            proc.stdin.flush()
            return None
        except OSError:      # BrokenPipeError: it exited meanwhile
            rc = proc.wait()
        finally:
            close_stdin(proc)
    return f'coupling_node: {error_line(log) or f"exited with status {rc}"} (before the loop started)'


def _stop_processes(procs: dict[str, subprocess.Popen[bytes]], names: Sequence[str], grace: float) -> None:
    """SIGINT ``names``; after ``grace`` s SIGTERM the survivors; after another ``grace`` SIGKILL.
    Their standard input is closed first (a node at its start gate then exits at once)."""
    for n in names:
        close_stdin(procs[n])
    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGKILL):
        alive = [n for n in names if procs[n].poll() is None]
        if not alive:
            return
        for n in alive:
            try:
                procs[n].send_signal(sig)
            except ProcessLookupError:
                pass
        deadline = time.monotonic() + grace
        while time.monotonic() < deadline and any(procs[n].poll() is None for n in alive):
            time.sleep(0.02)
    for n in names:
        procs[n].wait()


_LOG_LEVEL = re.compile(r'\[(ERROR|FATAL)\]')
# rclpy's console format: "[ERROR] [1795891544.977407028] [coupling_node]: message"
_ROS_LOG_PREFIX = re.compile(r'^\[(ERROR|FATAL)\] \[[0-9.]+\] \[[^\]]*\]: ')


def error_line(log_path: Path) -> str | None:
    """The last ERROR/FATAL line (rclpy logging, its level, stamp and logger name taken off:
    the caller names the node) or ``<prog>: error:`` line of a node log."""
    try:
        lines = log_path.read_text(errors='replace').splitlines()
    except OSError:
        return None
    for line in reversed(lines):
        if _LOG_LEVEL.search(line) or ': error:' in line:
            return _ROS_LOG_PREFIX.sub('', line.strip())
    rest = [line.strip() for line in lines if line.strip()]
    return rest[-1] if rest else None  # e.g. the last line of a traceback


def _signal_name(signum: int) -> str:
    try:
        return signal.Signals(signum).name
    except ValueError:
        return f'signal {signum}'
