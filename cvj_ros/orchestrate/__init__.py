"""`cvj-sim run`: launch a driveline run as ROS processes and record it to a bag.

Like a launch file: the loop nodes engine_node, load_node and coupling_node each run as
their own process (the console scripts, ``--ros-args -p ...``); the recorder
(:class:`cvj_ros.bag.BagRecorder`) runs inside the ``cvj-sim`` process, and beside it the
observer monitor_node (:data:`HOSTED_IN_RUN`: its own rclpy node, parameters and
executor thread, its subscriptions fed from the recorder's, so a loop message crosses into
this process once for both). Why there: the bag's lifetime then belongs to the process
that handles Ctrl-C/SIGTERM and decides the shutdown order, so the bag is finalised on
every exit path without inter-process signalling, and the message counts/wall times feed
the report directly; the orchestrator itself only sleeps.

Sequence: validate everything (scene, options, load bag) -> create the run directory
``OUT`` (``OUT/bag`` the rosbag2 bag, ``OUT/logs/<node>.log`` the node outputs,
``OUT/report.json``) -> start the recorder and the hosted monitor (subscribed before any
node exists, so the coupling node sees them matched before step 0) -> start engine, load and
coupling processes together, the coupling node gated (``start_gate=stdin``: it imports and
loads its compiled physics meanwhile, but creates no topic endpoint) -> wait until the
recorder sees the peers' publishers and no other run's -> say "go" on its standard input
-> wait for the coupling node to exit -> wait until the recorder is drained -> SIGINT the
other nodes (SIGTERM, then SIGKILL after a grace period) -> close the bag -> report. The
recorder's participant gets the run's Fast DDS profile (0.25 s discovery announcements,
cvj_ros.nodes.qos): with Fast DDS's 3 s the peers, started after it, found it only at its
next announcement. Measured on kavz685_lever 0.5 s: the whole command 7.2-9.1 s before the
gate, 6.1-6.7 s with it, 5.0-5.2 s with both.

Domain: all processes share the caller's ``ROS_DOMAIN_ID``; when it is unset the run
picks ``1 + pid % 100`` (stated in the report) instead of the crowded default 0.
``ROS_AUTOMATIC_DISCOVERY_RANGE`` defaults to ``LOCALHOST``.

Exit status: 0 finished; 1 runtime error (the coupling node's ERROR line is printed, e.g.
a peer that stopped answering); 2 bad scene/option (before any process starts);
130/143 stopped by SIGINT/SIGTERM (bag complete and readable).

Modules: ``options`` (RunOptions, RunResult, prepare), ``processes`` (node command lines,
parameters, stop order, error lines), ``recorder`` (bag, recorder, start-up handshake), ``report``
(metrics, report.json, printed report); this module holds :func:`run`, the sequence above.
"""
from __future__ import annotations

import shutil
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, TextIO

import numpy as np

from cvj_ros import bag as bagmod
from cvj_ros.errors import CvjError
from cvj_ros.orchestrate.options import (  # noqa: F401  (re-exported)
    MODES, NODE_ORDER, RUN_ENTRIES, SCHEMES, RunOptions, RunResult, _domain_env, _Prepared, prepare,
    prepare_kernel)
from cvj_ros.orchestrate.recorder import (  # noqa: F401  (re-exported)
    DISCOVERY_SETTLE_S, EXTERNAL_PEERS, HOSTED_IN_RUN, LOOP_TOPICS, PEER_TOPICS, _Recorder,
    _wait_for_peers,
    command_record_stamps, external_wait_line, open_run_bag)
from cvj_ros.orchestrate.processes import (  # noqa: F401  (re-exported)
    _die_with_parent, _ros_args, _signal_name, _stop_processes, close_stdin, error_line,
    node_command, node_parameters, start_gated)
from cvj_ros.orchestrate.report import (  # noqa: F401  (re-exported)
    FREE_RUN_KEYS, IDENTITY_COUNTERS, LOOP_COUNTERS, _jsonable, _recorded_fidelity, bag_metrics,
    finish_result, free_run_timing, loop_counters, loop_ended_line, monitor_statuses, print_report,
    result_from_recording)


def run(options: RunOptions, *, stream: TextIO | None = None,
        on_started: Callable[[dict[str, subprocess.Popen[bytes]]], None] | None = None) -> RunResult:
    """Run a scene as ROS processes, record the bag, print the report to ``stream``.

    Args:
        options: the run options.
        stream: where the report goes (default stdout).
        on_started: called with the node processes once all are started (tests use it to
            kill a peer).

    Returns:
        The :class:`RunResult` (also written to ``out/report.json``).

    Raises:
        CvjError: bad scene or option, before any process starts.
    """
    if options.composed:   # one process, one executor: cvj_ros.composed
        from cvj_ros.composed import run_composed
        return run_composed(options, stream=stream)
    stream = sys.stdout if stream is None else stream
    prep = prepare(options)
    # a cold kernel compiles here, both halves at once, on the user's terminal: the nodes load
    compiled_s = prepare_kernel(prep, options)
    env, domain = _domain_env()
    out = Path(options.out)
    for entry in RUN_ENTRIES:  # --overwrite removes the previous run's files, nothing else
        path = out / entry
        if path.is_dir():
            shutil.rmtree(path)
        elif path.exists():
            path.unlink()
    logs = out / 'logs'
    logs.mkdir(parents=True, exist_ok=True)
    env['ROS_LOG_DIR'] = str(logs / 'ros')
    from cvj_ros.nodes.qos import dds_environment, process_dds_profile
    dds_environment(env, profile_dir=str(out))   # writes out/fastdds_profile.xml unless the user set one
    load_override = None
    if prep.load_series is not None:
        load_override = out / 'load_override.npz'
        np.savez(load_override, t=prep.load_series[0], torque=prep.load_series[1])

    stop_signal: list[int] = []
    previous = {}

    def on_signal(signum: int, _frame: Any) -> None:
        stop_signal.append(signum)
    in_main = threading.current_thread() is threading.main_thread()
    if in_main:
        for sig in (signal.SIGINT, signal.SIGTERM):
            previous[sig] = signal.signal(sig, on_signal)

    wall0 = time.monotonic() if options.started is None else options.started
    phases: dict[str, float] = {}

    def mark(name: str) -> None:
        phases[name] = round(time.monotonic() - wall0, 4)
    if compiled_s:
        phases['kernel_compile_s'] = compiled_s
    writer = open_run_bag(options, prep, out)
    procs: dict[str, subprocess.Popen[bytes]] = {}
    log_files: list[Any] = []
    recorder: _Recorder | None = None
    error: str | None = None
    stopped_by: str | None = None
    steps = int(round(prep.duration / prep.exchange_step))
    from cvj_ros.progress import Progress
    # simulated time, real-time factor, ETA on stderr at most once a second, only on a terminal
    progress = Progress(prep.duration, label='cvj-sim run')
    try:
        # nothing of ours flows on the loop topics before our coupling node starts (both
        # modes): held until then, a refused run's bag gets none of another run's messages
        with process_dds_profile(env):   # the recorder announces itself every 0.25 s too
            recorder = _Recorder(writer, prep.coupling_topics, domain,
                                 hold=tuple(LOOP_TOPICS) + tuple(prep.coupling_topics))
            # the driver's samples at their step's time, whenever they arrive (docs/ros.md "Commands")
            recorder.recorder.set_command_stamps(command_record_stamps(prep))
        # the observers run in this process, subscribed before any loop node starts
        for name in (n for n in prep.nodes if n in HOSTED_IN_RUN):
            try:
                recorder.host(name, _ros_args(node_parameters(
                    prep, name, load_override=load_override)),
                    log=logs / f'{name}.log')
            except CvjError as exc:   # bad parameter: the line the node's own process prints
                error = f'{name}: error: {exc}'
        # every node process starts now, the coupling node gated (start_gate=stdin): its imports
        # and compiled physics load while the peers start, but it creates no topic endpoint
        # before "go" - volatile topics lose what is published before a match, and the
        # other-run check below needs it to have no joint-state publisher yet
        for name in prep.nodes:
            if stop_signal or error is not None:
                break
            if name in recorder.hosted:
                continue
            params = node_parameters(prep, name, load_override=load_override)
            gated = name == 'coupling_node'
            if gated:
                params['start_gate'] = 'stdin'
                if options.mode == 'lockstep':
                    # the loop runs at most MAX_LAG_S ahead of what the bag holds on disk, as
                    # composed mode's writer does (docs/robustness.md "Hard kill")
                    params['record_lag_max'] = bagmod.MAX_LAG_S
                # a fed hosted node has no joint-state reader of its own
                params['min_subscribers'] -= sum(
                    1 for feed in recorder.feeds.values() if feed.carries(bagmod.JOINT_STATES_TOPIC))
            fh = open(logs / f'{name}.log', 'wb')
            log_files.append(fh)
            procs[name] = subprocess.Popen(
                node_command(name) + _ros_args(params), stdout=fh, stderr=subprocess.STDOUT,
                stdin=subprocess.PIPE if gated else subprocess.DEVNULL, env=env,
                start_new_session=True, preexec_fn=_die_with_parent)
        if 'coupling_node' in procs and not stop_signal and error is None:
            # the coupling node (which makes the peers talk) goes once the recorder sees the
            # peers' publishers and no other run's
            if options.external:
                progress.clear()
                print(external_wait_line(options.external, domain, options.external_timeout, prep.peers),
                      file=stream, flush=True)
            error = _wait_for_peers(recorder, procs, logs, stop_signal, options.start_timeout,
                                    mode=options.mode, domain=domain,
                                    external=options.external,
                                    external_timeout=options.external_timeout, peers=prep.peers)
            mark('peers_connected')
            if error is None and not stop_signal:
                recorder.recorder.hold = frozenset()
                error = start_gated(procs['coupling_node'], logs / 'coupling_node.log')
        for proc in procs.values():   # no "go" said yet: EOF, the gated node exits 0 unstarted
            close_stdin(proc)
        if on_started is not None and not stop_signal and error is None:
            on_started(procs)
        coupling = procs.get('coupling_node')
        while coupling is not None and coupling.poll() is None and not stop_signal:
            for name, p in procs.items():  # a peer rejected its parameters: no point waiting
                if name != 'coupling_node' and p.poll() == 2 and error is None:
                    error = f'{name}: ' + (error_line(logs / f'{name}.log') or 'bad parameter (exit 2)')
            if error is not None:
                break
            states = recorder.recorder.counts.get(bagmod.JOINT_STATES_TOPIC, 0)
            if 'loop_started' not in phases and states:
                mark('loop_started')
                print(f'cvj-sim run: loop running (domain {domain}), recording to {out / "bag"}',
                      file=stream, flush=True)
            if states:
                progress.update((states - 1) * prep.exchange_step)
            time.sleep(0.02)
        progress.close()
        mark('coupling_exited')
        if 'loop_started' in phases:
            progress.clear()
            print(loop_ended_line(phases), file=stream, flush=True)
        if recorder is not None:
            recorder.recorder.loop_ended = True   # later /clock beyond our last state: not ours
        if stop_signal or error is not None:
            stopped_by = {signal.SIGINT: 'SIGINT', signal.SIGTERM: 'SIGTERM'}.get(
                stop_signal[0], str(stop_signal[0])) if stop_signal else None
            if 'coupling_node' in procs:
                _stop_processes(procs, ['coupling_node'], options.grace)
            # the loop stopped at its last state: that state's answers and /clock are in flight
            n_js = recorder.recorder.counts.get(bagmod.JOINT_STATES_TOPIC, 0) if recorder else 0
            recorder.drain(expected={t: n_js for t in (bagmod.CLOCK_TOPIC, *PEER_TOPICS.values())}
                           if n_js and options.mode == 'lockstep' and not options.external else {},
                           idle=0.3, bound=1.0)
        else:
            rc = procs['coupling_node'].returncode
            lockstep_ok = rc == 0 and options.mode == 'lockstep'
            # lockstep: N+1 states and clocks are in flight when the coupling node exits
            recorder.drain(expected={t: steps + 1 for t in (bagmod.CLOCK_TOPIC, bagmod.JOINT_STATES_TOPIC)}
                           if lockstep_ok else {}, idle=2.0 if lockstep_ok else 0.5, bound=5.0)
            # the peers answer the final state too (no one waits for those answers)
            recorder.drain(expected={t: steps + 1 for t in PEER_TOPICS.values()} if lockstep_ok else {},
                           idle=0.5, bound=2.0)
            if rc is not None and rc < 0:  # killed by a signal: its log holds no error line
                error = f'coupling_node: killed by {_signal_name(-rc)} (exit status {rc})'
            elif rc != 0:
                line = error_line(logs / 'coupling_node.log')
                error = f'coupling_node: {line}' if line else f'coupling_node: exited with status {rc}'
        mark('drained')
        _stop_processes(procs, [n for n in procs if n != 'coupling_node'] + ['coupling_node']
                        if 'coupling_node' in procs else list(procs), options.grace)
    finally:
        progress.close()   # erase the progress line (idempotent) before any other output
        # the bag is finalised on every path (errors, signals): everything recorded stays readable
        try:
            if procs:
                _stop_processes(procs, list(procs), options.grace)
        finally:
            rec_state = None
            foreign_dropped: dict[str, int] = {}
            malformed_dropped: dict[str, int] = {}
            hosted_codes: dict[str, int] = {}
            if recorder is not None:
                hosted_codes = recorder.hosted_exit_codes()
                rec_state = (dict(recorder.recorder.first_wall), dict(recorder.recorder.last_wall))
                foreign_dropped = dict(recorder.recorder.foreign)
                malformed_dropped = recorder.recorder.malformed
                recorder.close()
            writer.close()
            for fh in log_files:
                fh.close()
            if in_main:
                for sig, handler in previous.items():
                    signal.signal(sig, handler)
    mark('bag_closed')
    wall = time.monotonic() - wall0
    if stop_signal:
        code = 130 if stop_signal[0] == signal.SIGINT else 128 + int(stop_signal[0])
    elif error is not None:
        code = 1
    else:
        code = 0
    result = result_from_recording(
        options, prep, out, domain, code=code, error=error, stopped_by=stopped_by,
        counts=dict(writer.counts), rec_state=rec_state,
        exit_codes={**{n: p.returncode for n, p in procs.items()}, **hosted_codes},
        phases=phases, wall=wall, steps=steps)
    return finish_result(result, options, prep, stream=stream,
                         foreign_dropped=foreign_dropped, malformed_dropped=malformed_dropped,
                         settings={'process': 'separate'} | (
                             {'hosted': ','.join(hosted_codes)} if hosted_codes else {}))
