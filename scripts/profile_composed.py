"""Where the microseconds of one lockstep exchange go in composed mode (docs/nodes.md).

Runs ``cvj-sim run SCENE --composed`` in this process (a warm-up run first, so imports and
the compiled kernel are loaded) with wall-clock timers (time.perf_counter) around every
callback of the hosted nodes, and prints the mean time per exchange step of each:

* coupling: integrate (``CoupledStepper.advance``), publish state (/clock, joint states,
  reaction wrenches: ``_publish_state``), take answers (the two wrench callbacks minus the
  step they trigger);
* engine / load answer (deserialised JointState in, torque, CDR WrenchStamped out);
* monitor (joint states, both wrenches, /diagnostics, deserialised);
* recorder callbacks (``BagRecorder._on_message``, incl. the hand-off to the writer queue)
  and the writer thread's ``rosbags`` write (runs on its own thread, competing for the GIL);
* the rest = exchange wall time minus the callbacks: executor dispatch, DDS delivery,
  Python-object conversion of deserialised messages, GIL hand-offs, other processes.

Usage: ``python scripts/profile_composed.py [SCENE] [--duration S] [--exchange-step S]
[--runs N] [--separate] [--cprofile N]`` (``--separate`` times the one-process-per-node mode instead:
only the exchange wall time and the coupling node's own split are available then).
"""
from __future__ import annotations

import argparse
import functools
import io
import sys
import tempfile
import threading
import time
from collections import defaultdict
from pathlib import Path
from typing import Any, Callable

TIMES: dict[str, list[float]] = defaultdict(lambda: [0, 0.0])
OWN: dict[str, float] = defaultdict(float)   # the same time less the timed calls nested inside
_LOCAL = threading.local()                   # .nested: per open timed call of this thread,
                                             # the time of its timed callees
CLOCK = time.perf_counter     # --clock cpu: time.thread_time (CPU of the calling thread)


def timed(key: str | Callable[[Any], str], fn: Callable[..., Any]) -> Callable[..., Any]:
    """``fn`` wrapped to add its wall time (s) and a call to ``TIMES[key]``, and its time
    less that of the timed calls inside it to ``OWN[key]``."""
    @functools.wraps(fn)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        t0 = CLOCK()
        nested = _LOCAL.__dict__.setdefault('nested', [])
        nested.append(0.0)
        try:
            return fn(*args, **kwargs)
        finally:
            k = key(args[0]) if callable(key) else key
            dt = CLOCK() - t0
            slot = TIMES[k]
            slot[0] += 1
            slot[1] += dt
            OWN[k] += dt - nested.pop()
            if nested:
                nested[-1] += dt
    return wrapper


def instrument() -> None:
    """Wrap the callbacks (before any node exists: subscriptions bind the wrapped methods)."""
    from rosbags.rosbag2 import Writer

    from cvj_ros import bag
    from cvj_ros.nodes.coupling_node import CouplingNode
    from cvj_ros.nodes.monitor_node import MonitorNode
    from cvj_ros.nodes.torque_responder import TorqueResponder
    from cvj_ros.physics.cosim import CoupledStepper
    from cvj_ros.nodes.driver_node import DriverNode
    from cvj_ros.nodes.hybrid_backend import HybridOutputs, HybridStepper
    from cvj_ros.physics import state_outputs
    from cvj_ros.physics.kernel.tree_modes_lockstep import KernelHybridTreeLockstep
    CoupledStepper.advance = timed('coupling integrate', CoupledStepper.advance)
    # mode scenes (clutch, gearbox, brake): the mode lockstep, its compiled segments inside
    HybridStepper.advance = timed('coupling integrate', HybridStepper.advance)
    KernelHybridTreeLockstep._run_segment = timed('compiled segments',
                                                  KernelHybridTreeLockstep._run_segment)
    # the physics of "publish state": joint state and reaction wrenches
    for cls in (HybridOutputs, state_outputs.TreeKernelStateOutputs,
                state_outputs.KernelStateOutputs, state_outputs.PythonStateOutputs):
        cls.joint_states = timed('joint state', cls.joint_states)
        cls.wrenches = timed('reaction wrenches', cls.wrenches)
    CouplingNode._apply_commands = timed('commands', CouplingNode._apply_commands)
    CouplingNode._on_command = timed('command callbacks', CouplingNode._on_command)
    DriverNode._on_clock = timed('driver', DriverNode._on_clock)
    CouplingNode._publish_state = timed('coupling publish state', CouplingNode._publish_state)
    CouplingNode._step = timed('coupling step (integrate + publish)', CouplingNode._step)
    CouplingNode._on_engine = timed('coupling wrench callbacks (incl. step)', CouplingNode._on_engine)
    CouplingNode._on_load = timed('coupling wrench callbacks (incl. step)', CouplingNode._on_load)
    # the loop subscriptions take CDR bytes (``_raw``); the message variants serve ros2 run
    for name in ('_on_joint_states', '_on_joint_states_raw'):
        setattr(TorqueResponder, name, timed(lambda self: f'{self.get_name()} answer',
                                             getattr(TorqueResponder, name)))
    for name in ('_on_joint_states', '_on_joint_states_raw', '_on_torque_raw',
                 '_on_diagnostics', '_on_diagnostics_raw'):
        setattr(MonitorNode, name, timed('monitor', getattr(MonitorNode, name)))
    bag.BagRecorder._on_message = timed('recorder callbacks', bag.BagRecorder._on_message)
    Writer.write = timed('writer thread (rosbags write)', Writer.write)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('scene', nargs='?', default='kavz685_lever')
    ap.add_argument('--duration', type=float, default=5.0)
    ap.add_argument('--exchange-step', type=float, default=1e-3)
    ap.add_argument('--runs', type=int, default=1)
    ap.add_argument('--separate', action='store_true')
    ap.add_argument('--clock', choices=('wall', 'cpu'), default='wall',
                    help='wall: time.perf_counter; cpu: time.thread_time (less disturbed by other '
                         'processes; the rest is then process CPU - callbacks)')
    ap.add_argument('--without', action='append', default=[], choices=('monitor_node',),
                    help='leave the monitor out (its share of the exchange = the difference)')
    ap.add_argument('--cprofile', type=int, default=0, metavar='N',
                    help='instead of the timers: cProfile the loop thread and print the N '
                         'functions with the most own time (us per exchange)')
    a = ap.parse_args()
    if a.without:
        import cvj_ros.orchestrate as orch
        orch.NODE_ORDER = tuple(n for n in orch.NODE_ORDER if n not in a.without)
    global CLOCK
    CLOCK = time.thread_time if a.clock == 'cpu' else time.perf_counter
    from cvj_ros.orchestrate import RunOptions, run
    out = Path(tempfile.mkdtemp(prefix='cvj_profile_'))
    opts = dict(scene=a.scene, out=out, exchange_step=a.exchange_step, overwrite=True,
                composed=not a.separate)
    run(RunOptions(duration=0.2, **opts), stream=io.StringIO())     # warm-up: imports, kernel
    if not a.separate and not a.cprofile:
        instrument()
    for i in range(a.runs):
        TIMES.clear()
        OWN.clear()
        if a.cprofile:
            import cProfile
            import pstats
            prof = cProfile.Profile()
            prof.enable()
            r = run(RunOptions(duration=a.duration, **opts), stream=io.StringIO())
            prof.disable()
            steps = max(1, r.counts.get('/driveline/joint_states', 1) - 1)
            print(f'{a.scene} run {i + 1} (cProfile): {steps} exchanges, real-time factor '
                  f'{r.real_time_factor:.3g}')
            st = pstats.Stats(prof)
            rows = sorted(st.stats.items(), key=lambda kv: -kv[1][2])[:a.cprofile]
            print(f'  {"own us/exch":>11s} {"cum us/exch":>11s} {"calls/exch":>10s}  function')
            for (file, line, fn), (_cc, nc, tt, ct, _callers) in rows:
                print(f'  {tt / steps * 1e6:11.1f} {ct / steps * 1e6:11.1f} {nc / steps:10.2f}  '
                      f'{Path(file).name}:{line} {fn}')
            continue
        r = run(RunOptions(duration=a.duration, **opts), stream=io.StringIO())
        steps = max(1, r.counts.get('/driveline/joint_states', 1) - 1)
        per = r.wall_per_step * 1e6
        print(f'{a.scene} {"separate" if a.separate else "composed"} run {i + 1}: {steps} exchanges, '
              f'real-time factor {r.real_time_factor:.3g}, {per:.0f} us per exchange (exit {r.exit_code})')
        if a.separate:
            continue
        us = {k: v[1] / steps * 1e6 for k, v in TIMES.items()}
        if a.clock == 'cpu':   # the coupling node's process CPU per exchange (diagnostics)
            from cvj_ros.orchestrate import loop_counters  # noqa: F401 (bag helpers loaded)
            from cvj_ros import bag as bagmod
            diags = bagmod.read_bag(r.bag, ['/diagnostics'])['/diagnostics']
            per = next(float(st['values']['process_cpu_us_mean']) for sts in reversed(diags.statuses)
                       for st in sts if st['name'] == 'coupling_node: loop')
            print(f'  process CPU per exchange {per:.0f} us (all threads)')
        own = {k: v / steps * 1e6 for k, v in OWN.items()}
        # integrate and publish state with what they call (joint state, wrenches, segments);
        # the callbacks without the step, publication or commands they trigger
        exclusive = {
            'coupling integrate': us.get('coupling integrate', 0.0),
            'coupling publish state': us.get('coupling publish state', 0.0),
            'coupling take answers': own.get('coupling wrench callbacks (incl. step)', 0.0),
            'engine answer': us.get('engine_node answer', 0.0),
            'load answer': us.get('load_node answer', 0.0),
            'monitor': us.get('monitor', 0.0),
            'recorder callbacks': us.get('recorder callbacks', 0.0),
            'coupling step bookkeeping': own.get('coupling step (integrate + publish)', 0.0),
            'coupling commands (step k in force)': us.get('commands', 0.0),
            'coupling command callbacks': own.get('command callbacks', 0.0),
            'driver': us.get('driver', 0.0),
        }
        in_callbacks = sum(exclusive.values())
        for k, v in exclusive.items():
            print(f'  {k:34s} {v:8.1f} us')
        rest = 'executor, DDS, writer thread (rest)' if a.clock == 'cpu' else 'executor, DDS, GIL, other (rest)'
        print(f'  {rest:34s} {per - in_callbacks:8.1f} us')
        for k in ('compiled segments', 'joint state', 'reaction wrenches'):
            if k in us:      # inside integrate / publish state above
                print(f'  {"  of which " + k:34s} {us[k]:8.1f} us')
        print(f'  {"writer thread (parallel, GIL)":34s} {us.get("writer thread (rosbags write)", 0.0):8.1f} us')
    sys.stdout.flush()


if __name__ == '__main__':
    main()
