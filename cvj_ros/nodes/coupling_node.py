"""coupling_node: owns simulated time, the Driveline and its persistent CoupledStepper.

Publishes ``/clock``, ``/driveline/joint_states`` (names = ``Driveline.shaft_names``;
position rad unwrapped, velocity rad/s, effort N m), ``/coupling/<joint>/wrench`` for
every joint whose model gives reactions (force N / torque N m in the joint's housing
frame, frame_id ``<joint>_housing``), ``/driveline/scene`` (latched, once: YAML with
``scene``, ``seed``, ``fidelity``, ``mode``, ``coupling_scheme``) and its own loop
diagnostics on ``/diagnostics`` (steps, real-time factor, lockstep wait per exchange,
integration time, joint-state evaluation + publication time, overhead per exchange,
process CPU time per exchange, ignored stamps, energy residual).

Publication order per step: /clock for t_k first (lockstep: as soon as both answers for
t_(k-1) are in, before the integration), then the joint states stamped t_k (the peers wait
for them; an outside node under ``use_sim_time`` then sees ``now() == t_k`` in its
callback as far as its executor takes the clock first), then the reaction wrenches
(computed while the peers answer). The loop's messages are published
as pre-serialised CDR bytes (:class:`~cvj_ros.nodes.common.JointStateEncoder` etc.), which
skips rclpy's Python-to-C conversion; the bytes decode to the same messages. The joint state
and the reaction wrenches come from :mod:`cvj_ros.physics.state_outputs`: compiled when the
stepper runs the kernel (a few us per exchange), else the Python reference.

Lockstep (default, deterministic). Simulated time is integer
nanoseconds t_k = k * h_ns. At step k the node publishes /clock and joint states
stamped t_k; /engine/wrench and /load/wrench must answer with exactly that stamp. When
both are in, the stepper integrates to t_{k+1} and the next state goes out - all inside
the subscription callback, so the loop is event driven (no busy waiting). A watchdog
timer ends the run with one ERROR line naming the missing topic when an answer takes
longer than ``peer_timeout``. Answers with another stamp (late, duplicate,
out-of-order) are ignored and counted; the first one per topic while t_k is awaited is
said at once in one WARN line ("answers on /load/wrench are
stamped 0.000 s, expected 0.001 s: echo the joint-state stamp ..."), and a stall with
only wrong stamps from a topic ends after ``WRONG_STAMP_STALL_S`` (1 s, or peer_timeout if
shorter) with that line instead of "is load_node running?". A NaN/inf torque is never
integrated: with ``nonfinite_torque=stop`` (default) ERROR diagnostic and exit 1; with
``hold`` the last finite torque of that topic (0 N m before the first) stands in for it,
counted as ``held_torques`` (diagnostics level WARN, first one logged).

Run identity by publisher (cvj_ros.nodes.peers; frame_ids are plain frame names:
``driveline``, ``<joint>_housing``, ``coupling_node``): the publishers of
/driveline/joint_states, /engine/wrench and /load/wrench when step 0 goes out are the run's
peers. A second publisher on one of them stops the loop with one ERROR line naming every
publisher (before step 0) or the intruder, its topic and the step (after it); an answer that
arrives while its topic has two matched publishers is never integrated. An answer that does
not decode is dropped and counted (``malformed_messages``, first one per topic in one WARN
line). Before step 0 the node waits until ``min_subscribers`` subscribers
see /driveline/joint_states (default 4: engine, load, monitor and the recorder ``cvj-sim
record``) and both wrench topics have a publisher, so no message is lost, and until that
has held for START_SETTLE_S with no other run's publisher discovered, in both modes
(OBSERVER_SETTLE_S when observers such as the recorder are awaited without a gated start:
their matches with the engine's and load's writers are not visible here; then also until
the graph's subscriptions and recorders matched, at most UNMATCHED_WAIT_S). The wait
has no deadline by default (``start_timeout`` 0: nodes started by hand in any order, with
any pause); every START_REPORT_S it logs who is connected and who is missing. After t_N = duration it publishes
the final joint state and exits 0.

Free-run: exchange steps on wall time - tick j is due at w0 + j h (CLOCK_MONOTONIC) and
integrates to t_j = j h with the latest torques held (zero-order hold at the coupling
level); /clock carries the simulated time. The initial state goes out, the first exchange
runs once every answer to it is in (at most ``peer_timeout``), and the clock starts as the
state t_1 goes out (w0 = then - h; docs/ros.md, "Free-run"). The node
re-arms a steady-clock timer for the next due time after each wake-up (an rclpy periodic
timer re-arms from its call time, so its phase slips: measured here 970-990 of 1000
ticks of 2 ms in 2 s). Missed ticks follow ``catch_up`` (``skip``: drop them, one step
jumps to wall time; ``burst``: run them back to back, at most ``burst_max`` per wake-up,
then skip); every tick's lateness (start - due time) goes into p50/p99/max, ticks late by
>= h are counted as ``overruns``, and the drift (wall time since w0 - simulated time at
publication) is reported; all in the loop diagnostics (level WARN once a tick overran).
``realtime_priority`` > 0 puts the threads of this process under SCHED_FIFO (opt-in;
measured p99 lateness here at h = 2 ms under a load average of 9-10: 0.2 ms instead of
12-34 ms, docs/ros.md).
See :mod:`cvj_ros.nodes.freerun`. A non-finite torque is rejected (ERROR diagnostic) and
the previous value is kept.

Effort in a joint state at t_k uses the torques most recently received (zero before the
first answer).

Recorder gate (lockstep, ``record_lag_max`` > 0; `cvj-sim run` sets it for separate
processes): the run's recorder publishes on ``/driveline/recorded`` (rosgraph_msgs/Clock,
latched) the record time up to which its bag is on the OS side; the loop does not integrate
to t_(k+1) while t_(k+1) is more than ``record_lag_max`` ahead of it, so a SIGKILL of the
whole run loses at most that much simulated time (docs/robustness.md "Hard kill"). A held
loop that sees no progress for ``peer_timeout`` stops with one line naming the topic.
"""
from __future__ import annotations

import math
import os
import struct
import sys
import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import yaml
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import WrenchStamped
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64, String

from cvj_ros.errors import CvjError, StartCancelled
from cvj_ros.nodes.cdr import CdrError, checked_length
from cvj_ros.nodes.intra import bus_for, loop_publisher, loop_subscription
from cvj_ros.nodes.malformed import MALFORMED_KEY, MalformedInputs
from cvj_ros.nodes.vehicle_diagnostics import vehicle_values
from cvj_ros.nodes.wheel_loads import WHEEL_LOAD_MODES, WheelAnswers
from cvj_ros.nodes.peers import (describe, named_publisher_endpoints, publisher_endpoints,
                                 strangers)
from cvj_ros.nodes.freerun import CATCH_UP_POLICIES, FreeRunScheduler, Step, run_wakeup
from cvj_ros.nodes.diagnostics import plain_status, publish_statuses
from cvj_ros.nodes.common import (ERROR, NS_PER_S, OK, WARN, ClockEncoder, CvjNode,
                                  JointStateEncoder, ParameterError, ParamSpec,
                                  WrenchStampedEncoder, declare_parameters,
                                  decode_wrench_stamp_torque_z, load_scene_param,
                                  ns_to_stamp, parse_assignments, run_node, scene_dict,
                                  scene_seed)
from cvj_ros.nodes.qos import (CLOCK_TOPIC, DATA_QOS, DIAGNOSTICS_TOPIC,
                               ENGINE_THROTTLE_SCALE_TOPIC, ENGINE_WRENCH_TOPIC, JOINT_STATES_TOPIC,
                               LATCHED_QOS, LOAD_WRENCH_TOPIC, RECORDED_TOPIC, RECORDER_READY_TOPIC,
                               SCENE_TOPIC, coupling_wrench_topic, qos_match, type_name)

_CLOCK_STAMP = struct.Struct('<iI')    # rosgraph_msgs/Clock: int32 sec, uint32 nanosec at byte 4
_CLOCK_STAMP_BE = struct.Struct('>iI')
_FLOAT64_LE = struct.Struct('<4sd')    # std_msgs/Float64 as little-endian CDR
_CDR_LE = b'\x00\x01\x00\x00'
MODES = ('lockstep', 'free-run')
SCHEMES = ('zoh', 'extrapolate', 'linear_implicit')
SOLVERS = ('', 'dopri5', 'dop853', 'rosenbrock', 'rk4', 'ros2', 'rodas4', 'rodas3', 'tsit5',
           'vern6', 'vern7', 'vern8')
NONFINITE_POLICIES = ('stop', 'hold')
#: header.frame_id of /driveline/joint_states (REP-103 frame name; no run token)
JOINT_STATES_FRAME = 'driveline'
# How long the peers must stay connected, with no other run's publisher in sight (both modes),
# before step 0 goes out (s). The subscriber count that says "peers connected" cannot tell
# this run's engine/load from another run's on the same domain, and a state published before
# our own peers matched is lost to them (volatile QoS): the run then waits out peer_timeout
# with no answer (seen in CI: a second run's coupling node started 2 ms after its participant
# saw the first run's subscribers, and discovered the first run's engine publisher 2 ms
# later). Holding the all-clear this long lets foreign_publishers() see the other run first
# and refuse, as the orchestrator does before starting this node (DISCOVERY_SETTLE_S).
START_SETTLE_S = 0.3
# ... and this long when observers beyond engine and load are awaited (min_subscribers > 2)
# and no `cvj-sim run` gated the start: a recorder or monitor also reads /engine/wrench and
# /load/wrench, and whether their readers matched the engine's and load's writers cannot be
# seen from here (other participants' matches). Hand-started under a load average of ~12,
# 1 of 9 runs of test/e2e/test_hand_start.py recorded all 301 joint states but only 128 of
# 300 engine and load answers, most likely because the recorder's wrench readers matched
# after step 0 with the 0.3 s settle; `cvj-sim run` instead waits until its recorder has
# matched the peers' writers before "go", and in composed mode the in-process bus reports
# the hosted nodes' matches (missing_peers): both keep START_SETTLE_S.
OBSERVER_SETTLE_S = 2.0
# After that settle, a hand-started run (either mode) also waits until every subscription the ROS
# graph shows on this node's own data topics (/clock, the joint states, /diagnostics, the
# coupling wrenches, same type, compatible QoS) is matched by its writer, and until every
# `cvj-sim record` in the graph reports on /driveline/recorder_ready that its readers matched
# every publisher this node sees (the reader's side of a match is not visible here; a
# volatile reader that matches late skips what was written before). Seen: a recorder whose /clock and
# coupling-wrench readers matched 12 steps after step 0 (CI), and 290 steps after it
# (launch-equivalent run, load ~25 with two CPU burners). Bounded (this long past the
# settle, then one WARN line naming them and the run starts): an endpoint the graph lists
# can fail to match for reasons not visible here.
UNMATCHED_WAIT_S = 10.0
# A stall during which only wrong-stamped answers came from a topic ends after this many
# seconds (or peer_timeout, if shorter) with the stamp line: a peer that stamps wrongly
# (e.g. with now() under use_sim_time a step behind) never sends the right stamp, while a
# peer that sends junk next to its right answer sends the right one within milliseconds
# (fuzz tests: test/robustness/test_fuzz_wrench_inputs.py).
WRONG_STAMP_STALL_S = 1.0
# The loop looks at the ROS graph (a second /driveline/joint_states publisher, which no
# answer callback sees) at most this often (s): lockstep between two exchanges, besides the
# watchdog; free-run at a wake-up;
# three publisher counts (one from the graph), ~20 us per check: 0.2 % of the wall time.
GRAPH_CHECK_S = 0.01
# Free-run, while the answers to state 0 are awaited: how often the node looks for a stop
# signal, another run's publisher and peer_timeout (s).
PRIME_CHECK_S = 0.02
# While a step waits for the recorder (record_lag_max), SIGINT/SIGTERM is looked for this often (s).
HOLD_SIGNAL_CHECK_S = 0.02
# While waiting for its peers before step 0, the node says who is there and who is missing
# this often (s): a person starting nodes by hand sees what the loop waits for.
START_REPORT_S = 5.0
#: the subscribers of /driveline/joint_states a hand-started run has by default (node names:
#: the node executables and the recorder of `cvj-sim record`), named when they are missing
EXPECTED_SUBSCRIBERS = ('engine_node', 'load_node', 'monitor_node', 'cvj_recorder')

#: coupling_node ``start_gate`` values (:func:`wait_for_go`)
START_GATES = ('', 'stdin')

PARAMS = (
    ParamSpec('scene', '', 'scene name (e.g. kavz685_lever) or scene YAML path'),
    ParamSpec('seed', -1, 'random seed; -1 = the scene seed', lo=-1, hi=2**31 - 1),
    ParamSpec('mode', 'lockstep', 'loop mode', choices=MODES),
    ParamSpec('coupling_scheme', 'zoh', 'how received torques act inside an exchange step',
              choices=SCHEMES),
    ParamSpec('exchange_step', 0.0, 'exchange step h [s]; 0 = the scene exchange_step',
              lo=0.0, hi=10.0),
    ParamSpec('duration', 0.0, 'simulated duration [s]; 0 = the scene duration', lo=0.0, hi=1e7),
    ParamSpec('peer_timeout', 5.0, 'longest wait for an engine/load answer [s] (lockstep: each '
              'one, else the run stops; free-run: the answers to state 0, then the clock starts '
              'without them)',
              lo=0.0, hi=3600.0, lo_open=True),
    ParamSpec('start_timeout', 0.0, 'longest wait for peers to connect before step 0 [s]; '
              '0 = no limit (wait, naming who is missing every few seconds)', lo=0.0, hi=1e6),
    ParamSpec('min_subscribers', 4, 'subscribers /driveline/joint_states must have before step 0 '
              '(engine + load + monitor + recorder = 4; 3 without monitor or recorder; + 1 per '
              'node of yours that must see step 0)', lo=0, hi=64),
    ParamSpec('start_gate', '', 'stdin = build the physics, then wait for a line "go" on '
              'standard input before creating any topic endpoint (EOF: exit 0 without '
              'starting); how `cvj-sim run` starts this process while the peers start; '
              'empty = no wait', choices=START_GATES),
    ParamSpec('solver', '', 'integration method; empty = the scene solver', choices=SOLVERS),
    ParamSpec('mode_backend', 'auto', 'scenes with clutch, gearbox, brake or commands: auto = '
              'the compiled kernel for dopri5/dop853, else the Python reference; kernel; python',
              choices=('auto', 'kernel', 'python')),
    ParamSpec('rtol', 0.0, 'relative tolerance [-]; 0 = the scene rtol', lo=0.0, hi=1.0),
    ParamSpec('atol', 0.0, 'absolute tolerance [rad, rad/s]; 0 = the scene atol', lo=0.0, hi=1.0),
    ParamSpec('fidelity', [''], 'forced fidelities "element=level" (joints ideal|closed|exact, '
              'springs elastic|rigid)'),
    ParamSpec('load_override', '', 'load torque time series file used by load_node instead of '
              'the scene load (recorded in /driveline/scene); empty = scene load'),
    ParamSpec('diagnostics_every', 100, 'publish loop diagnostics every N exchange steps',
              lo=1, hi=10**9),
    ParamSpec('track_energy', True, 'integrate work integrals and report the energy residual'),
    ParamSpec('wheel_load', 'internal', 'vehicle scene: internal = the built-in tyres (load_node '
              'answers /load/wrench, unused); external = outside nodes answer /load/<wheel>/wrench '
              'for every wheel instead of the tyres and load_node', choices=WHEEL_LOAD_MODES),
    ParamSpec('nonfinite_torque', 'stop', 'lockstep: a NaN/inf torque.z answer stops the run '
              '(stop) or is replaced by the last finite torque of that topic, counted as '
              'held_torques with WARN (hold)', choices=NONFINITE_POLICIES),
    ParamSpec('catch_up', 'skip', 'free-run: missed ticks are dropped, one step jumping to wall '
              'time (skip), or run back to back up to burst_max per wake-up, then dropped (burst)',
              choices=CATCH_UP_POLICIES),
    ParamSpec('burst_max', 10, 'free-run, catch_up=burst: most ticks run back to back in one '
              'wake-up', lo=1, hi=10**6),
    ParamSpec('record_lag_max', 0.0, 'lockstep: most simulated time the loop runs ahead of what '
              'the run\'s recorder reports on disk (/driveline/recorded) [s]; 0 = no gate '
              '(no recorder reports; composed mode bounds its writer itself)', lo=0.0, hi=1e6),
    ParamSpec('realtime_priority', 0, 'free-run: SCHED_FIFO priority of the threads of this '
              'process (1..99; '
              'needs CAP_SYS_NICE, else a WARN and normal scheduling); 0 = normal scheduling',
              lo=0, hi=99),
    ParamSpec('commands', 'driver', 'scenes with clutch, gearbox, brake or commands, lockstep: '
              'driver = driver_node plays the scene schedule and each state t_k waits for the '
              'samples of step k (docs/ros.md, "Commands"); external = a vehicle stack sends '
              'them, each in force from the next state published after it arrived',
              choices=('driver', 'external')),
)


def wait_for_go(logger: Any = None, stream: Any = None) -> None:
    """``start_gate=stdin``: block until a line ``go`` on ``stream`` (standard input).

    `cvj-sim run` starts this process together with the peers so that its imports and the
    compiled physics load while they start (~1-3 s per run), and says ``go`` once the
    recorder has matched the peers and no other run shares the domain (the check that needs
    this node to have no /driveline/joint_states publisher yet). Anything else, or EOF (the
    run was stopped, or cvj-sim died), raises :class:`StartCancelled`: the process exits 0
    without having created a topic endpoint. A SIGINT/SIGTERM while it waits (caught by
    :func:`~cvj_ros.nodes.executor.run_node`'s handler, which does not interrupt a blocking
    read) raises it too: standard input is polled every 0.1 s when it is a file or pipe."""
    import select

    from cvj_ros.nodes.executor import stop_requested
    stream = sys.stdin if stream is None else stream
    if logger is not None:
        logger.info('physics ready; waiting for "go" on standard input (start_gate=stdin)')
    try:
        fd = stream.fileno()
    except (AttributeError, OSError, ValueError):   # not a file (a test's StringIO)
        fd = None
    try:
        while fd is not None and not select.select([fd], [], [], 0.1)[0]:
            if stop_requested():
                raise StartCancelled(f'start_gate: stopped by signal {stop_requested()} before '
                                     '"go"; not started')
        line = stream.readline()
    except (OSError, ValueError):       # closed or unreadable: no go
        line = ''
    if line.strip() != 'go':
        raise StartCancelled('start_gate: no "go" on standard input; not started')


class CouplingNode(CvjNode):
    """The lockstep / free-run coupling node (see module docstring). Parameters: :data:`PARAMS`."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__('coupling_node', **kwargs)
        p = self.params = declare_parameters(self, PARAMS)
        scene = self.scene = load_scene_param(p['scene'])
        self.seed = scene_seed(scene, p['seed'])
        # plain frame names (a run is told apart by its publishers: cvj_ros.nodes.peers)
        self.js_frame = JOINT_STATES_FRAME
        self.diag_frame = 'coupling_node'
        self.mode = p['mode']
        self.scheme = p['coupling_scheme']
        h = p['exchange_step'] or scene.exchange_step
        duration = p['duration'] or scene.duration
        self.h_ns = int(round(h * NS_PER_S))
        if self.h_ns <= 0:
            raise ParameterError('exchange_step', f'must be >= 1 ns, got {h}')
        self.n_steps = int(round(duration * NS_PER_S / self.h_ns))
        if self.n_steps < 1:
            raise ParameterError('duration', f'must be >= exchange_step ({h} s), got {duration}')
        if abs(self.n_steps * self.h_ns - duration * NS_PER_S) > 1e-6 * self.h_ns + 1:
            self.get_logger().warning(f'duration {duration} s is not a multiple of the exchange step '
                                      f'{h} s: running {self.n_steps} steps')
        forced = parse_assignments('fidelity', [s for s in p['fidelity'] if s])
        # an explicit solver on a spring too stiff to step: refused before anything is built
        # or compiled, over the duration this node runs (as Simulation.run, physics.simulate)
        from cvj_ros.physics.simulate import scene_explicit_step_check
        scene_explicit_step_check(scene, p['solver'] or scene.solver.method,
                                  self.n_steps * self.h_ns / NS_PER_S, overrides=forced)
        self.driveline, self.stepper = self._build_physics(scene, forced, p)
        self.x = np.array(self.stepper_state(), dtype=float)
        self.names = list(self.driveline.shaft_names)
        self.energy0 = self._energy_total(self.x)
        # every joint with reactions, of a chain or of every branch of a vehicle scene's tree
        self.reaction_joints = [name for name, m in self.driveline.joint_models.items()
                                if hasattr(m, 'reactions')] if hasattr(self.driveline, 'reactions') else []
        if p['start_gate'] == 'stdin':
            wait_for_go(self.get_logger())

        # publishers
        # loop topics: through the in-process bus in composed mode (cvj_ros.nodes.intra)
        self.clock_pub = loop_publisher(self, Clock, CLOCK_TOPIC, DATA_QOS)
        self.js_pub = loop_publisher(self, JointState, JOINT_STATES_TOPIC, DATA_QOS)
        self.diag_pub = loop_publisher(self, DiagnosticArray, DIAGNOSTICS_TOPIC, DATA_QOS)
        self.scene_pub = loop_publisher(self, String, SCENE_TOPIC, LATCHED_QOS)
        self.reaction_pubs = {j: loop_publisher(self, WrenchStamped, coupling_wrench_topic(j), DATA_QOS)
                              for j in self.reaction_joints}
        # raw: the callbacks get the serialised answer and read stamp and torque.z directly
        self.engine_sub = loop_subscription(self, WrenchStamped, ENGINE_WRENCH_TOPIC,
                                            self._on_engine, DATA_QOS)
        self.load_sub = loop_subscription(self, WrenchStamped, LOAD_WRENCH_TOPIC,
                                          self._on_load, DATA_QOS)
        # recorder gate (module docstring): record time (ns) the recorder has on disk
        self.record_lag_ns = int(round(p['record_lag_max'] * NS_PER_S)) if self.mode == 'lockstep' else 0
        self.recorded_ns = 0
        self._record_held = False           # both answers in, the step waits for the recorder
        self._record_hold_start = 0.0       # perf_counter s of the current hold
        self._recorded_mono = 0.0           # monotonic s of the last progress of recorded_ns
        self.record_waits = 0
        self.record_wait_total = 0.0        # s
        self.recorded_sub = (self.create_subscription(Clock, RECORDED_TOPIC, self._on_recorded,
                                                      LATCHED_QOS, raw=True)
                             if self.record_lag_ns > 0 else None)
        # while held: looks for SIGINT/SIGTERM every HOLD_SIGNAL_CHECK_S (the watchdog's period
        # can be 0.25 s; a stop must come within 0.1 s)
        self._hold_timer = (self.create_timer(HOLD_SIGNAL_CHECK_S, self._check_hold)
                            if self.record_lag_ns > 0 else None)
        if self._hold_timer is not None:
            self._hold_timer.cancel()
        # run identity by publisher (cvj_ros.nodes.peers): answers that come through DDS are
        # taken only while their topic has one publisher, the one matched at step 0; from
        # the in-process bus (composed mode) only hosted nodes' answers come at all
        self._dds_engine = not hasattr(self.engine_sub, 'bus')
        self._dds_load = not hasattr(self.load_sub, 'bus')
        # wheel_load=external: one answer per wheel completes the load port (wheel_loads.py)
        self.wheel_answers: WheelAnswers | None = None
        self.wheel_subs: list[Any] = []
        if p['wheel_load'] == 'external':
            self.wheel_answers = WheelAnswers(self.driveline.wheel_names)
            self.wheel_subs = [
                loop_subscription(self, WrenchStamped, topic,
                                  lambda data, i=i: self._on_wheel(data, i), DATA_QOS)
                for i, topic in enumerate(self.wheel_answers.topics)]
        self._peer_gids: dict[str, frozenset[str]] = {}
        self._graph_due = 0.0         # monotonic s of the next graph check inside the loop
        # Reused message objects: one builtin_interfaces/Time shared by every header and
        # /clock, updated in place each step (publish() serialises synchronously, so reuse is
        # safe); WrenchStamped construction alone measured 27 us per message here.
        self._stamp = ns_to_stamp(0)
        self._js_msg = JointState()
        self._js_msg.name = self.names
        self._js_msg.header.stamp = self._stamp
        self._js_msg.header.frame_id = self.js_frame
        self._clock_msg = Clock(clock=self._stamp)
        self._reaction_msgs: dict[str, WrenchStamped] = {}
        for j in self.reaction_joints:
            w = WrenchStamped()
            w.header.stamp = self._stamp
            w.header.frame_id = f'{j}_housing'
            self._reaction_msgs[j] = w
        # pre-serialised publication (bytes): skips rclpy's field-by-field conversion
        self._js_cdr = JointStateEncoder(self.names, self.js_frame)
        self._clock_cdr = ClockEncoder()
        self._reaction_cdr = {j: WrenchStampedEncoder(f'{j}_housing')
                              for j in self.reaction_joints}
        self.raw_publication = (self._js_cdr.ok and self._clock_cdr.ok
                                and all(e.ok for e in self._reaction_cdr.values()))
        # per-exchange joint state (intermediate members filled) and reaction wrenches:
        # compiled when the stepper runs the kernel, else the Python reference; outside
        # wheel loads run the Python stepper (no kernel input) but a compiled joint state
        from cvj_ros.physics.state_outputs import make_state_outputs
        self.outputs = getattr(self.driveline, 'state_outputs', None) or make_state_outputs(
            self.driveline, self.reaction_joints,
            compiled=(getattr(self.stepper, 'backend', 'python') == 'kernel'
                      or getattr(self.driveline, 'wheel_torques', None) is not None))
        # commands (clutch, gear, brake, throttle) of a mode scene: cvj_ros.nodes.command_inbox
        self.hybrid = getattr(self.driveline, 'hybrid', None)
        self.commands: Any = None
        self.command_subs: dict[str, Any] = {}
        self.gated_commands = False
        self._state_pending = False
        if self.hybrid is not None:
            self._subscribe_commands(scene, p)
        # a shift schedule's throttle cut: the factor on the pedal for step k goes out before
        # the state t_k (docs/ros.md "Commands"; the engine node answers t_k with it)
        self.scale_pub = (loop_publisher(self, Float64, ENGINE_THROTTLE_SCALE_TOPIC, DATA_QOS)
                          if getattr(self.hybrid, 'cuts_throttle', False) else None)

        # loop state
        self.k = 0
        self.t_ns = 0
        self.T_engine = 0.0
        self.T_load = 0.0
        self._have_engine = False
        self._have_load = False
        self.waiting = False
        self.started = False
        self.ignored_stamps = 0
        self.rejected_torques = 0
        self.malformed = MalformedInputs(self.get_logger())   # undecodable answers, per topic
        self.held_torques = 0            # nonfinite_torque=hold: NaN/inf answers replaced
        self._last_finite = {ENGINE_WRENCH_TOPIC: 0.0, LOAD_WRENCH_TOPIC: 0.0}   # N m
        # answers with a stamp other than t_k while t_k is awaited: (stamp ns, expected ns)
        # per topic, the first of the run (said at once in one WARN line) and the latest of
        # the current wait (named by the stall error instead of "is load_node running?")
        self.wrong_stamp: dict[str, tuple[int, int]] = {}
        self._wrong_in_wait: dict[str, tuple[int, int]] = {}
        self.joint_states_published = 0
        self._clock_sent_ns = -1          # last /clock time published (ns)
        # timing (wall, perf_counter seconds)
        self._wait_start = 0.0
        self.wait_total = 0.0
        self.integration_total = 0.0
        self.exchange_total = 0.0
        self.state_total = 0.0      # joint-state evaluation + publication (critical path)
        self.exchanges = 0
        self._t_wall0 = 0.0
        self._cpu0 = 0.0

        # hand-started recorders' latest report of their readers' matches (RECORDER_READY_TOPIC):
        # recorder -> {topic: publishers matched}
        self.recorder_matches: dict[str, dict[str, int]] = {}
        self.ready_sub = self.create_subscription(String, RECORDER_READY_TOPIC, self._on_recorder_ready,
                                                  LATCHED_QOS)
        self._publish_scene()
        self._wait_t0 = time.monotonic()
        self._start_deadline = self._wait_t0 + p['start_timeout'] if p['start_timeout'] > 0 else math.inf
        self._next_report = self._wait_t0 + START_REPORT_S
        self._ready_since: float | None = None     # peers connected since (monotonic s)
        self._start_timer = self.create_timer(0.01, self._try_start)
        self._watchdog = None
        self._free_timer = None
        self.scheduler: FreeRunScheduler | None = None   # free-run only
        # free-run start: the answer topics still awaited for state 0 (None: not waiting)
        self._prime_wait: set[str] | None = None
        self._prime_t0 = 0.0
        self._prime_timer = None
        self._first_state_ns = 0          # monotonic ns at which the state t_1 went out
        self.realtime_priority = 0                       # SCHED_FIFO priority in force (free-run)
        self._diag_k = 0                                 # k of the last periodic diagnostics
        # the SIGINT/SIGTERM caught in this process (0: none), read at every exchange:
        # run_node's handler here, the composed container's in `cvj-sim run --composed`
        from cvj_ros.nodes.executor import stop_requested
        self.stop_signal: Callable[[], int] = stop_requested
        # called once, right after step 0 is published (the composed run's "loop running")
        self.on_started: Callable[[], None] | None = None
        self.get_logger().info(
            f'scene {scene.name!r}: {len(self.names)} shafts, {self.driveline.n_dof} DOF, '
            f'{self.n_steps} steps of {self.h_ns / NS_PER_S:g} s, mode {self.mode}, '
            f'scheme {self.scheme}, backend {getattr(self.stepper, "backend", "python")}; '
            f'waiting for peers')

    # --- physics set-up ---------------------------------------------------------------------

    def _build_physics(self, scene: Any, forced: dict[str, str], p: dict[str, Any]) -> tuple[Any, Any]:
        if scene.has_modes:      # clutch, gearbox, brake, commands: cvj_ros.nodes.hybrid_backend
            from cvj_ros.nodes.hybrid_backend import build_hybrid
            if self.scheme != 'zoh':
                raise ParameterError('coupling_scheme', f'a scene with clutch, gearbox, brake or '
                                                        f'commands runs with zoh, got {self.scheme!r}')
            if p['wheel_load'] == 'external':
                raise ParameterError('wheel_load', 'external: not for a scene with clutch, gearbox, '
                                                   'brake or commands (the mode model has its tyres)')
            try:
                driveline, stepper = build_hybrid(scene, method=p['solver'] or None,
                                                  rtol=p['rtol'] or None, atol=p['atol'] or None,
                                                  fidelity=forced or None,
                                                  backend=p['mode_backend'])
            except CvjError as exc:
                if str(exc).startswith('backend: '):
                    raise ParameterError('mode_backend', str(exc)[len('backend: '):]) from None
                raise ParameterError('scene', str(exc)) from None
            h = driveline.hybrid
            self.method, self.rtol, self.atol = h.method, h.rtol, h.atol
            return driveline, stepper
        from cvj_ros.physics.cosim import CoupledStepper
        from cvj_ros.physics.driveline import Driveline
        from cvj_ros.physics.tree import TreeDriveline
        # a vehicle scene: tyres and body inside the equations, /load/wrench unused
        model = TreeDriveline if scene.is_tree else Driveline
        try:
            driveline = model.from_scene(scene, fidelity=forced or None,
                                         track_energy=p['track_energy'])
        except CvjError as exc:
            field = 'fidelity' if forced and str(exc).split(':')[0] in forced else 'scene'
            raise ParameterError(field, str(exc)) from None
        if p['wheel_load'] == 'external':
            if not scene.is_tree:
                raise ParameterError('wheel_load', 'external needs a vehicle scene (wheels); '
                                     'a chain takes its outside load on /load/wrench')
            driveline.set_wheel_torques([0.0] * driveline.n_wheel)   # Python stepper
        rhs_model = driveline
        if p['wheel_load'] == 'external':
            # the Python stepper on the compiled right-hand side with the wheel torques
            from cvj_ros.physics.kernel.tree_wheel_rhs import CompiledWheelLoadRhs
            try:
                rhs_model = CompiledWheelLoadRhs(driveline)
            except NotImplementedError:
                pass
        method = p['solver'] or scene.solver.method
        rtol = p['rtol'] or scene.solver.rtol
        atol = p['atol'] or scene.solver.atol
        # fixed-step methods step at the scene's solver.h, else at the exchange step
        h_fixed = scene.solver.h or self.h_ns / NS_PER_S
        try:
            # Torque messages carry no slope: linear_implicit estimates it by least squares.
            stepper = CoupledStepper(rhs_model, scheme=self.scheme, method=method, rtol=rtol, atol=atol,
                                     h=h_fixed if method in ('rk4', 'ros2') else scene.solver.h,
                                     slope='estimate' if self.scheme == 'linear_implicit' else 'reported')
        except CvjError as exc:
            raise ParameterError('solver', str(exc)) from None
        self.method, self.rtol, self.atol = method, rtol, atol
        return driveline, stepper

    def stepper_state(self) -> np.ndarray:
        x = getattr(self.stepper, 'x', None)
        if x is None:
            x = getattr(self.stepper, 'y', None)
        return np.array(self.driveline.x0 if x is None else x, dtype=float)

    def _energy_total(self, x: np.ndarray) -> float:
        e = self.driveline.energy(x)
        return float(e['kinetic'] + e['elastic'])

    def fidelity_report(self) -> Any:
        report = getattr(self.driveline, 'fidelity_report', None)
        if report is None:
            return dict(getattr(self.driveline, 'levels', {}))
        for attr in ('to_dict', 'as_dict'):
            if hasattr(report, attr):
                return getattr(report, attr)()
        return {'levels': dict(getattr(report, 'levels', {}))}

    # --- commands (mode scenes) ---------------------------------------------------------

    def _subscribe_commands(self, scene: Any, p: dict[str, Any]) -> None:
        """Subscribe the command topics; with ``commands=driver`` in lockstep and a scene
        schedule, each state t_k waits for the driver's samples of step k (CommandPlan)."""
        from std_msgs.msg import Float64, Int8

        from cvj_ros.nodes.command_inbox import CommandInbox
        from cvj_ros.nodes.command_plan import CHANNEL_TOPICS, CommandPlan
        from cvj_ros.nodes.hybrid_backend import gear_count
        plan = None
        if p['commands'] == 'driver' and self.mode == 'lockstep' and scene.commands:
            plan = CommandPlan.from_scene(scene, self.h_ns, self.n_steps)
        self.gated_commands = plan is not None
        # the topics the driver publishes (a channel without rows has no publisher)
        self._played_topics = {CHANNEL_TOPICS[c] for c in plan.channels} if plan else set()
        self.commands = CommandInbox(plan, n_gears=gear_count(self.hybrid))
        self._refused_said: set[str] = set()
        for channel, topic in CHANNEL_TOPICS.items():
            if channel == 'throttle' and (plan is None or 'throttle' not in plan.channels):
                continue           # the engine node applies the throttle; counted only when played
            self.command_subs[topic] = loop_subscription(
                self, Int8 if channel == 'gear' else Float64, topic,
                lambda data, c=channel: self._on_command(c, data), DATA_QOS)

    def _on_command(self, channel: str, data: bytes) -> None:
        """A raw command sample: checked (malformed: dropped, named once per topic; out of
        range: refused, ERROR once per topic), kept; releases a state waiting for it."""
        from cvj_ros.nodes.command_plan import CHANNEL_TOPICS, CommandError
        if self.exit_code is not None:
            return
        topic = CHANNEL_TOPICS[channel]
        sub = self.command_subs[topic]
        if (self.gated_commands and self.started and not hasattr(sub, 'bus')
                and sub.get_publisher_count() > 1):      # a second publisher beside the driver
            self._stop_with_error(self._intruder_line(topic))
            return
        try:
            self.commands.offer(channel, data)
        except CommandError as exc:
            if exc.malformed:
                self._drop_malformed(topic, str(exc))
            elif topic not in self._refused_said:
                self._refused_said.add(topic)
                line = f'{topic}: {exc}; not applied (further ones counted as refused_commands)'
                self.get_logger().error(line)
                self.publish_diagnostics(ERROR, line)
            return
        if self._state_pending and self.commands.ready(self.k):
            self._state_pending = False
            if self._emit_state():
                self._after_state()

    def _apply_commands(self) -> bool:
        """Put the commands of step k in force over [t_k, t_(k+1)]; False when the run stopped."""
        from cvj_ros.nodes.command_plan import CommandError
        try:
            vals = self.commands.take(self.k)
        except CommandError as exc:
            self._stop_with_error(f'lockstep: {exc}')
            return False
        if vals:
            self.hybrid.set_commands(clutch=vals.get('clutch'), brake=vals.get('brake'),
                                     gear=None if 'gear' not in vals else int(vals['gear']))
        return True

    def _emit_state(self) -> bool:
        """Publish the state t_k, once the command samples of step k are in (mode scenes);
        False while they are awaited (/clock t_k is out: the driver plays on it) or when the
        run stopped."""
        if self.commands is not None:
            if not self.commands.ready(self.k):
                self._publish_clock(self.t_ns)
                self._state_pending = True
                self._wait_start = time.perf_counter()
                return False
            if not self._apply_commands():
                return False
        self._publish_state()
        return True

    def _publish_scene(self) -> None:
        scene = scene_dict(self.scene)
        if self.params['load_override']:
            scene['load'] = {'model': 'time_series', 'file': self.params['load_override']}
        text = yaml.safe_dump({
            'scene': scene, 'seed': self.seed, 'fidelity': self.fidelity_report(),
            'mode': self.mode, 'coupling_scheme': self.scheme,
            'exchange_step': self.h_ns / NS_PER_S, 'duration': self.n_steps * self.h_ns / NS_PER_S,
            'solver': {'method': self.method, 'rtol': self.rtol, 'atol': self.atol,
                       'backend': getattr(self.stepper, 'backend', 'python'),
                       'backend_fallback': getattr(self.stepper, 'backend_fallback', None)},
            'shaft_names': self.names,
            # a mode scene: who sends the commands (driver: a driver_node plays the scene's
            # schedule, so a recorder started by hand stamps them by it; bag.scene_command_stamps)
            **({'commands': self.params['commands']} if self.hybrid is not None else {}),
        }, sort_keys=False)
        self.scene_pub.publish(String(data=text))

    # --- start ------------------------------------------------------------------------------

    def missing_peers(self) -> list[str]:
        """Topics whose peers are not connected yet (empty list = ready)."""
        missing = []
        n_sub = self.js_pub.get_subscription_count()
        if n_sub < self.params['min_subscribers']:
            missing.append(f'{JOINT_STATES_TOPIC} ({n_sub} of {self.params["min_subscribers"]} '
                           f'subscribers{self._subscriber_names()})')
        for topic, sub in self._answer_subs():
            if sub.get_publisher_count() < 1:
                missing.append(f'{topic} (no publisher)')
        if self.gated_commands:      # the driver's command publishers (commands=driver)
            missing += [f'{topic} (no publisher: driver_node)' for topic, sub in self.command_subs.items()
                        if topic in self._played_topics and sub.get_publisher_count() < 1]
        if (self.scale_pub is not None and self.scale_pub.get_subscription_count() < 1
                and self._engine_node_listens()):
            missing.append(f'{ENGINE_THROTTLE_SCALE_TOPIC} (no subscriber: engine_node)')
        bus = bus_for(self.context)
        if bus is not None:    # composed: the in-process DDS endpoints matched (intra.py)
            missing += bus.dds_unmatched()
        return missing

    def _own_data_publishers(self) -> list[tuple[str, Any]]:
        """(topic, publisher) of this node's per-exchange data topics."""
        pubs = [(CLOCK_TOPIC, self.clock_pub), (JOINT_STATES_TOPIC, self.js_pub),
                (DIAGNOSTICS_TOPIC, self.diag_pub),
                *((coupling_wrench_topic(j), pub) for j, pub in self.reaction_pubs.items())]
        if self.scale_pub is not None:
            pubs.append((ENGINE_THROTTLE_SCALE_TOPIC, self.scale_pub))
        return pubs

    def unmatched_subscriptions(self) -> list[str]:
        """'topic (n of m)' for each own data topic whose writer has matched fewer readers
        than the ROS graph shows subscriptions of the same type with a compatible QoS."""
        out = []
        for topic, pub in self._own_data_publishers():
            try:
                infos = self.get_subscriptions_info_by_topic(topic)
            except Exception:  # noqa: BLE001 (graph query during shutdown)
                return []
            name = type_name(pub.msg_type)
            shown = sum(1 for i in infos
                        if i.topic_type == name and qos_match(pub.qos_profile, i.qos_profile))
            matched = pub.get_subscription_count()
            if matched < shown:
                out.append(f'{topic} ({matched} of {shown} subscriptions matched)')
        return out

    def _on_recorder_ready(self, msg: String) -> None:
        """A recorder's report (commands/record.ReadyAnnouncer); anything else is ignored."""
        import json
        try:
            report = json.loads(msg.data)
            token, matched = str(report['recorder']), report['matched']
            if not (isinstance(matched, dict) and all(
                    isinstance(t, str) and type(n) is int for t, n in matched.items())):
                return
        except (ValueError, KeyError, TypeError):
            return
        self.recorder_matches[token] = matched

    def recorders_not_ready(self) -> list[str]:
        """What the recorders in the graph (`cvj-sim record`, publishers of
        /driveline/recorder_ready) have not matched yet: a recorder not heard from, a
        recordable topic with more publishers in this node's graph (same type, compatible
        QoS) than the recorder's reader has matched, or one it has not subscribed. Only the
        reader's side knows its matches, and a volatile reader that matches a writer late
        skips what was written before."""
        from cvj_ros.bag import topic_type
        from cvj_ros.nodes.qos import RECORDER_QOS
        n = self.count_publishers(RECORDER_READY_TOPIC)
        if len(self.recorder_matches) < n:
            return [f'{RECORDER_READY_TOPIC} ({len(self.recorder_matches)} of {n} recorders heard)']
        shown: dict[str, int] = {}
        for topic, _types in self.get_topic_names_and_types():
            want = topic_type(topic)
            if want is None:
                continue
            qos = LATCHED_QOS if topic == SCENE_TOPIC else RECORDER_QOS
            shown[topic] = sum(1 for i in self.get_publishers_info_by_topic(topic)
                               if i.topic_type == want and qos_match(i.qos_profile, qos))
        out = []
        for token, matched in sorted(self.recorder_matches.items()):
            out += [f'{topic} ({matched.get(topic, 0)} of {k} publishers matched by recorder {token})'
                    for topic, k in sorted(shown.items()) if matched.get(topic, 0) < k]
        return out

    def _engine_node_listens(self) -> bool:
        """An engine_node (ours: it takes /engine/throttle_scale, and in lockstep waits for
        the scale of step 0) subscribes to the joint states; an outside engine need not."""
        try:
            return any(info.node_name == 'engine_node' for info in
                       self.get_subscriptions_info_by_topic(JOINT_STATES_TOPIC))
        except Exception:  # noqa: BLE001 (graph query during shutdown)
            return False

    def _answer_subs(self) -> list[tuple[str, Any]]:
        """(topic, subscription) of every answer the loop waits for: /engine/wrench and
        /load/wrench, or with wheel_load=external /engine/wrench and each /load/<wheel>/wrench."""
        if self.wheel_answers is None:
            return [(ENGINE_WRENCH_TOPIC, self.engine_sub), (LOAD_WRENCH_TOPIC, self.load_sub)]
        return [(ENGINE_WRENCH_TOPIC, self.engine_sub), *zip(self.wheel_answers.topics, self.wheel_subs)]

    def _subscriber_names(self) -> str:
        """': a, b; not yet: c' - the nodes subscribed to the joint states and the
        :data:`EXPECTED_SUBSCRIBERS` not among them ('' when the graph cannot be read)."""
        try:
            names = sorted(info.node_name for info in
                           self.get_subscriptions_info_by_topic(JOINT_STATES_TOPIC))
        except Exception:  # noqa: BLE001 (graph query during shutdown: say nothing)
            return ''
        absent = [n for n in EXPECTED_SUBSCRIBERS if n not in names]
        return (f': {", ".join(names) or "none"}' + (f'; not yet: {", ".join(absent)}' if absent else ''))

    def foreign_publishers(self) -> str | None:
        """The line naming extra publishers on the loop topics, else None (both modes).

        The loop needs exactly one publisher of /driveline/joint_states (this node), of
        /engine/wrench and of /load/wrench: the peers are the publishers matched when step 0
        goes out (cvj_ros.nodes.peers). More before step 0 is an ambiguity (another run or
        node shares this ROS domain: the line names every publisher); more after it is an
        intruder, named against the peer matched at step 0. Messages on a topic with two
        publishers cannot be told apart (rclpy gives no per-message publisher), so neither
        case integrates anything from that topic any more. Both modes refuse the ambiguity
        before step 0 (free-run would otherwise hold the other run's answers as its torques).
        """
        return self._extra_publishers()

    def _guarded_topics(self) -> list[tuple[str, Any]]:
        """(topic, publisher count function) of the loop topics whose messages reach this
        run through DDS: all three before step 0, and after it those the in-process bus does
        not carry (composed mode hears only its hosted publishers there)."""
        topics: list[tuple[str, Any]] = [
            (JOINT_STATES_TOPIC, lambda: self.count_publishers(JOINT_STATES_TOPIC)),
            *((topic, sub.get_publisher_count) for topic, sub in self._answer_subs())]
        if self.gated_commands:      # the driver's command topics (commands=driver)
            topics += [(t, sub.get_publisher_count) for t, sub in self.command_subs.items()
                       if t in self._played_topics]
        bus = bus_for(self.context)
        if self.started and bus is not None:
            topics = [(t, n) for t, n in topics if not bus.carries(t)]
        return topics

    def _extra_publishers(self) -> str | None:
        """:meth:`foreign_publishers`' line from the publisher counts and the ROS graph."""
        extra = [(topic, n) for topic, count in self._guarded_topics() if (n := count()) > 1]
        if not extra:
            return None
        if self.started:
            return self._intruder_line(extra[0][0])
        named = '; '.join(f'{topic} has {n} publishers: {describe(publisher_endpoints(self, topic))}'
                          for topic, n in extra)
        return (f'{self.mode}: {named} (expected 1) on ROS_DOMAIN_ID='
                f'{os.environ.get("ROS_DOMAIN_ID", "0")}: another run or node shares this domain '
                f'and its messages would mix into this loop; give each run its own ROS_DOMAIN_ID')

    def _note_peers(self) -> None:
        """Step 0: the publishers of the loop topics now are this run's peers."""
        self._peer_gids = {topic: frozenset(e.gid for e in publisher_endpoints(self, topic))
                           for topic, _count in self._guarded_topics()}

    def _intruder_line(self, topic: str) -> str:
        """One line naming the publisher on ``topic`` that is not the peer matched at step 0."""
        known = self._peer_gids.get(topic, frozenset())
        # the run stops on this line: worth up to 0.2 s for the intruder's node name
        endpoints = named_publisher_endpoints(self, topic)
        new = strangers(endpoints, known)
        peers = [e for e in endpoints if e.gid in known]
        who = describe(new) if new else 'a publisher not in the ROS graph yet'
        return (f'{self.mode}: {topic}: intruder {who} besides this run\'s peer '
                f'{describe(peers) if peers else "(gone)"} on ROS_DOMAIN_ID='
                f'{os.environ.get("ROS_DOMAIN_ID", "0")}; stopped at t={self.t_ns / NS_PER_S:.9g} s '
                f'(step {self.k}) without integrating any of its messages: messages on a topic with '
                f'two publishers cannot be told apart; give each run its own ROS_DOMAIN_ID')

    def _try_start(self) -> None:
        if self.started or self.exit_code is not None:
            return
        foreign = self.foreign_publishers()
        if foreign:
            self._stop_with_error(foreign)
            return
        missing = self.missing_peers()
        if missing:
            self._ready_since = None
            now = time.monotonic()
            if now > self._start_deadline:
                self._start_timer.cancel()
                self.fail(f'start: peers not connected within start_timeout='
                          f'{self.params["start_timeout"]} s: {"; ".join(missing)}')
            elif now >= self._next_report:
                self._next_report = now + START_REPORT_S
                self.get_logger().info(
                    f'waiting for peers ({now - self._wait_t0:.0f} s): {"; ".join(missing)} '
                    f'(min_subscribers={self.params["min_subscribers"]})')
            return
        now = time.monotonic()
        if self._ready_since is None:
            self._ready_since = now
        # by hand (both modes): the observers' matches too; cvj-sim run gates the start after
        # its recorder matched, composed the in-process bus reports its DDS matches
        # (missing_peers). Free-run: this is before state 0 and its wall clock (_prime_done)
        by_hand = (self.params['min_subscribers'] > 2 and not self.params['start_gate']
                   and bus_for(self.context) is None)
        settle = OBSERVER_SETTLE_S if by_hand else START_SETTLE_S
        if now - self._ready_since < settle:
            return
        unmatched = self.unmatched_subscriptions() + self.recorders_not_ready() if by_hand else []
        if unmatched:
            if now - self._ready_since < settle + UNMATCHED_WAIT_S:
                return
            self.get_logger().warning(
                f'start: {"; ".join(unmatched)} after {settle + UNMATCHED_WAIT_S:g} s; '
                'starting: those subscribers may miss the first states')
        self._start_timer.cancel()
        self._note_peers()
        self.started = True
        self._t_wall0 = time.perf_counter()
        self._cpu0 = time.process_time()
        self._emit_state()
        if self.on_started is not None:
            self.on_started()
        if self.mode == 'lockstep':
            period = min(max(self.params['peer_timeout'] / 10.0, 0.005), 0.25)
            self._watchdog = self.create_timer(period, self._check_peers)
            self._begin_wait()
        else:
            # the clock starts once state 0 is answered and the first exchange ran (_prime_done)
            self._prime_wait = {topic for topic, _sub in self._answer_subs()}
            self._prime_t0 = time.monotonic()
            self._prime_timer = self.create_timer(PRIME_CHECK_S, self._check_prime)

    # --- free-run start -----------------------------------------------------------------------

    def _prime_answer(self, topic: str) -> None:
        """Free-run, before the clock starts: an answer on ``topic`` ticks it off (only state
        0 is out, so it answers state 0 whatever its stamp: free-run holds every answer), and
        the last one runs the first exchange (:meth:`_prime_done`)."""
        if self._prime_wait is None:
            return
        self._prime_wait.discard(topic)
        if not self._prime_wait:
            self._prime_done()

    def _check_prime(self) -> None:
        """Free-run, waiting for the answers to state 0: a stop signal ends the run; after
        ``peer_timeout`` the clock starts without them (one WARN line naming them)."""
        if self._prime_wait is None or self.exit_code is not None:
            return
        if self.stop_signal():
            self.stop_by_signal(self.stop_signal())
            return
        foreign = self._extra_publishers()
        if foreign:
            self._stop_with_error(foreign)
            return
        waited = time.monotonic() - self._prime_t0
        if waited > self.params['peer_timeout']:
            line = (f'free-run: no answer to state 0 on {" and ".join(sorted(self._prime_wait))} '
                    f'within peer_timeout={self.params["peer_timeout"]:g} s; starting the clock '
                    f'without it (torques held at their last value, 0 N m before the first)')
            self.get_logger().warning(line)
            self.publish_diagnostics(WARN, line)
            self._prime_done()

    def _prime_done(self) -> None:
        """State 0 is answered: run the first exchange t_0 -> t_1 now, with those answers, and
        start the wall clock as its state goes out (tick 1 due then, tick j at + (j - 1) h).
        What a first exchange costs once (compiled code loaded on first use, the peers' and
        the recorder's first callbacks) then delays no tick: started at step 0 instead, a
        slow first step made the next wake-up skip every tick up to
        wall time, so the record lost its start (docs/ros.md, "Free-run")."""
        self._prime_wait = None
        if self._prime_timer is not None:
            self._prime_timer.cancel()
        self.scheduler = FreeRunScheduler(self.h_ns, self.n_steps, catch_up=self.params['catch_up'],
                                          burst_max=self.params['burst_max'])
        self.realtime_priority = self._set_realtime_priority(self.params['realtime_priority'])
        self._run_free_step(Step(ticks=1, lateness_ns=0))
        if self.exit_code is not None:
            return
        self.scheduler.start(self._first_state_ns, ticks_done=1)
        from rclpy.clock import Clock as RosClock, ClockType
        # CLOCK_MONOTONIC, the scheduler's clock; one-shot use: re-armed in _free_tick
        delay_ns = max(self.scheduler.due_ns(2) - time.monotonic_ns(), 1_000)
        self._free_timer = self.create_timer(delay_ns / NS_PER_S, self._free_tick,
                                             clock=RosClock(clock_type=ClockType.STEADY_TIME))

    def _set_realtime_priority(self, priority: int) -> int:
        """Free-run: put every thread of this process under SCHED_FIFO ``priority`` - the loop
        thread, the executor's timer thread that wakes it and the DDS threads that carry its
        publications (setting only the calling thread left p99 lateness at 34 ms at h = 2 ms
        under a load average of 9; all threads: 0.2 ms). Returns the priority in force
        (0 = normal scheduling; a refusal is one WARN line and changes nothing)."""
        if priority <= 0:
            return 0
        try:
            tids = sorted(int(t) for t in os.listdir('/proc/self/task'))
        except OSError:
            tids = [0]
        done: list[int] = []
        try:
            for tid in tids:
                try:
                    os.sched_setscheduler(tid, os.SCHED_FIFO, os.sched_param(priority))
                except ProcessLookupError:      # the thread ended meanwhile
                    continue
                done.append(tid)
        except (OSError, AttributeError) as exc:
            for tid in done:                    # all or nothing
                try:
                    os.sched_setscheduler(tid, os.SCHED_OTHER, os.sched_param(0))
                except OSError:
                    pass
            self.get_logger().warning(
                f'realtime_priority={priority}: SCHED_FIFO refused ({exc}); running with normal '
                f'scheduling (needs CAP_SYS_NICE, e.g. root or setcap)')
            return 0
        return priority

    # --- lockstep ---------------------------------------------------------------------------

    def _begin_wait(self) -> None:
        self._have_engine = self._have_load = False
        self._wrong_in_wait.clear()
        self.waiting = True
        self._wait_start_mono = time.monotonic()

    def _check_peers(self) -> None:
        if self.exit_code is not None:
            return
        foreign = self.foreign_publishers()
        if foreign:
            self._stop_with_error(foreign)
            return
        if self._record_held:
            if self.stop_signal():        # Ctrl-C / SIGTERM while the recorder catches up
                self._record_held = False
                self.stop_by_signal(self.stop_signal())
            elif time.monotonic() - self._recorded_mono > self.params['peer_timeout']:
                self._stop_with_error(
                    f'lockstep: the run\'s recorder reported {self.recorded_ns / NS_PER_S:.9g} s on '
                    f'disk on {RECORDED_TOPIC}, the loop waits to go past '
                    f'{(self.t_ns + self.h_ns) / NS_PER_S:.9g} s (record_lag_max='
                    f'{self.params["record_lag_max"]:g} s): no progress within peer_timeout='
                    f'{self.params["peer_timeout"]} s; is the recorder (cvj-sim) running?')
            return
        if not self.waiting:
            return
        waited = time.monotonic() - self._wait_start_mono
        stall = [t for t, have in ((ENGINE_WRENCH_TOPIC, self._have_engine),
                                   (LOAD_WRENCH_TOPIC, self._have_load))
                 if not have and t in self._wrong_in_wait]
        stall_bound = min(WRONG_STAMP_STALL_S, self.params['peer_timeout'])
        if stall and waited > stall_bound:
            self._stop_with_error(
                f'lockstep: no answer stamped t={self.t_ns / NS_PER_S:.9g} s (step {self.k}) '
                f'on {stall[0]} within {stall_bound:g} s, only wrongly stamped ones; '
                + self.wrong_stamp_line(stall[0], *self._wrong_in_wait[stall[0]]))
            return
        if self._state_pending and waited > self.params['peer_timeout']:
            self._stop_with_error(
                f'lockstep: no command sample on {" and ".join(self.commands.missing(self.k))} for '
                f't={self.t_ns / NS_PER_S:.9g} s (step {self.k}) within peer_timeout='
                f'{self.params["peer_timeout"]} s; is driver_node running?')
            return
        if waited > self.params['peer_timeout']:
            if self.k == 0 and not (self._have_engine or self._have_load):
                # state 0 unanswered by both while another run's publishers are in sight: that
                # run's subscribers made the start look ready before our peers had matched
                # (discovery slower than START_SETTLE_S); say so, not "is engine_node running?"
                foreign = self._extra_publishers()
                if foreign:
                    self._stop_with_error(f'{foreign} (state 0 went unanswered: this run started '
                                          f'before its own peers had matched it)')
                    return
            missing = [t for t, have in ((ENGINE_WRENCH_TOPIC, self._have_engine),
                                         (LOAD_WRENCH_TOPIC, self._have_load)) if not have]
            who = 'engine_node' if ENGINE_WRENCH_TOPIC in missing else 'load_node'
            if self.wheel_answers is not None and LOAD_WRENCH_TOPIC in missing:
                missing = [t for t in missing if t != LOAD_WRENCH_TOPIC] + self.wheel_answers.missing(self.t_ns)
                who = 'engine_node' if ENGINE_WRENCH_TOPIC in missing else 'the outside wheel-load node'
            self._stop_with_error(
                f'lockstep: no answer on {" and ".join(missing)} for t={self.t_ns / NS_PER_S:.9g} s '
                f'(step {self.k}) within peer_timeout={self.params["peer_timeout"]} s; '
                f'is {who} running?')

    def _stop_with_error(self, message: str) -> None:
        self.waiting = False
        self.publish_diagnostics(ERROR, message)
        self.fail(message)
        self._cancel_timers()

    def _cancel_timers(self) -> None:
        for tm in (self._watchdog, self._free_timer, self._start_timer, self._hold_timer,
                   self._prime_timer):
            if tm is not None:
                tm.cancel()

    def wrong_stamp_line(self, topic: str, got: int, expected: int) -> str:
        """The one line saying that answers on ``topic`` are stamped ``got`` ns, not ``expected``."""
        # as many decimals as the exchange step needs (1 ms -> 0.001), at least 3
        decimals = max(3, 9 - (len(str(self.h_ns)) - len(str(self.h_ns).rstrip('0'))))
        return (f'answers on {topic} are stamped {got / NS_PER_S:.{decimals}f} s, expected '
                f'{expected / NS_PER_S:.{decimals}f} s: echo the joint-state stamp (header) in the answer')

    def _note_wrong_stamp(self, topic: str, stamp_ns: int) -> None:
        """A wrong stamp on ``topic`` while t_k is awaited; the first of the run is said at
        once in one WARN line (log and /diagnostics), later ones only counted."""
        self._wrong_in_wait[topic] = (stamp_ns, self.t_ns)
        if topic in self.wrong_stamp:
            return
        self.wrong_stamp[topic] = (stamp_ns, self.t_ns)
        line = self.wrong_stamp_line(topic, stamp_ns, self.t_ns)
        self.get_logger().warning(line)
        self.publish_diagnostics(WARN, line)

    def _hold_nonfinite(self, value: float, stamp_ns: int, topic: str) -> float:
        """nonfinite_torque=hold: the last finite torque of ``topic`` (0 N m before the
        first); counted in ``held_torques`` (WARN); the first one is logged in one line."""
        held = self._last_finite.get(topic, 0.0)
        self.held_torques += 1
        if self.held_torques == 1:
            self.get_logger().warning(
                f'{topic}: torque.z not finite ({value}) at stamp {stamp_ns / NS_PER_S:.9g} s; '
                f'holding the last finite value {held:g} N m (nonfinite_torque=hold; '
                f'further ones are counted as held_torques in /diagnostics)')
        return held

    def _torque_ok(self, value: float, stamp_ns: int, topic: str) -> bool:
        """True when the torque is finite; else reject it (ERROR diagnostic)."""
        if math.isfinite(value):
            return True
        self.rejected_torques += 1
        text = (f'{topic}: torque.z not finite ({value}) at stamp '
                f'{stamp_ns / NS_PER_S:.9g} s; rejected, never integrated')
        if self.mode == 'lockstep':
            self._stop_with_error(text)
        else:
            self.publish_diagnostics(ERROR, text)
        return False

    def _on_engine(self, data: bytes) -> None:
        self._on_answer(data, ENGINE_WRENCH_TOPIC, engine=True)

    def _on_load(self, data: bytes) -> None:
        if self.wheel_answers is not None:      # wheel_load=external: the wheels answer instead
            return
        self._on_answer(data, LOAD_WRENCH_TOPIC, engine=False)

    def _on_wheel(self, data: bytes, i: int) -> None:
        """A raw /load/<wheel>/wrench answer (wheel_load=external), checked as /load/wrench's
        (malformed: dropped and counted; a second publisher once running: stop; non-finite:
        the nonfinite_torque policy). Free-run: the wheel's torque is held from now on.
        Lockstep: taken once per wheel for t_k; the last wheel's answer completes the load
        port, which then goes the /load/wrench way (:meth:`_on_wrench`)."""
        wheels = self.wheel_answers
        topic = wheels.topics[i]
        try:
            stamp_ns, value = decode_wrench_stamp_torque_z(data)
        except CdrError as exc:
            self._drop_malformed(topic, str(exc))
            return
        if self.exit_code is not None:
            return
        sub = self.wheel_subs[i]
        if self.started and not hasattr(sub, 'bus') and sub.get_publisher_count() > 1:
            self._stop_with_error(self._intruder_line(topic))
            return
        if self.mode == 'lockstep' and self.params['nonfinite_torque'] == 'hold':
            if math.isfinite(value):
                self._last_finite[topic] = value
            else:
                value = self._hold_nonfinite(value, stamp_ns, topic)
        if not self._torque_ok(value, stamp_ns, topic):
            return
        if self.mode != 'lockstep':
            wheels.values[i] = value
            self.driveline.set_wheel_torques(wheels.values)
            if self._prime_wait is not None:
                self._prime_answer(topic)
            return
        if not self.waiting or self._have_load or stamp_ns != self.t_ns or wheels.answered(i, stamp_ns):
            self.ignored_stamps += 1     # late, duplicate or out-of-order answer
            if self.waiting and not self._have_load and stamp_ns != self.t_ns:
                self._note_wrong_stamp(topic, stamp_ns)
            return
        if wheels.offer(i, stamp_ns, value):
            self.driveline.set_wheel_torques(wheels.values)
            self._on_wrench(stamp_ns, 0.0, LOAD_WRENCH_TOPIC, engine=False)

    def _on_answer(self, data: bytes, topic: str, *, engine: bool) -> None:
        """A raw wrench answer on ``topic``: checked decode (malformed: dropped and counted),
        a second publisher on the topic once the loop runs stops it naming the intruder, else
        the torque goes to :meth:`_on_wrench`."""
        try:
            stamp_ns, value = decode_wrench_stamp_torque_z(data)
        except CdrError as exc:
            self._drop_malformed(topic, str(exc))
            return
        dds, sub = (self._dds_engine, self.engine_sub) if engine else (self._dds_load, self.load_sub)
        if self.started and dds and sub.get_publisher_count() > 1:
            self._stop_with_error(self._intruder_line(topic))
            return
        self._on_wrench(stamp_ns, value, topic, engine=engine)

    def _drop_malformed(self, topic: str, reason: str) -> None:
        """A message on ``topic`` the checked decoder refused: never integrated, counted
        (``malformed_messages``), the first one per topic in one WARN line (log and
        /diagnostics)."""
        line = self.malformed.drop(topic, reason)
        if line is not None and self.exit_code is None:
            self.publish_diagnostics(WARN, line)

    def _on_wrench(self, stamp_ns: int, value: float, topic: str, *, engine: bool) -> None:
        """One answer: stamp (integer ns) and torque.z (N m) of a WrenchStamped on ``topic``."""
        if self.exit_code is not None:
            return
        if self.mode == 'lockstep' and self.params['nonfinite_torque'] == 'hold':
            if math.isfinite(value):
                self._last_finite[topic] = value
            else:
                value = self._hold_nonfinite(value, stamp_ns, topic)
        if not self._torque_ok(value, stamp_ns, topic):
            return
        if self.mode != 'lockstep':
            if engine:
                self.T_engine = value
            else:
                self.T_load = value
            if self._prime_wait is not None:
                self._prime_answer(ENGINE_WRENCH_TOPIC if engine else LOAD_WRENCH_TOPIC)
            return
        have = self._have_engine if engine else self._have_load
        if not self.waiting or have or stamp_ns != self.t_ns:
            self.ignored_stamps += 1     # late, duplicate or out-of-order answer
            if self.waiting and not have:
                self._note_wrong_stamp(topic, stamp_ns)
            return
        if engine:
            self.T_engine, self._have_engine = value, True
        else:
            self.T_load, self._have_load = value, True
        if self._have_engine and self._have_load:
            if self.stop_signal():           # Ctrl-C / SIGTERM: t_k and its answers are the last
                self.stop_by_signal(self.stop_signal())
                return
            now = time.monotonic()
            if now >= self._graph_due:        # a second joint-state publisher (not an answer)
                self._graph_due = now + GRAPH_CHECK_S
                foreign = self.foreign_publishers()
                if foreign:
                    self._stop_with_error(foreign)
                    return
            self.waiting = False
            self.wait_total += time.perf_counter() - self._wait_start
            if self.record_lag_ns and self.t_ns + self.h_ns - self.recorded_ns > self.record_lag_ns:
                self._record_held = True         # _on_recorded goes on (module docstring)
                self._record_hold_start = time.perf_counter()
                self._recorded_mono = time.monotonic()
                self._hold_timer.reset()
                return
            self._advance()

    def _advance(self) -> None:
        """Both answers for t_k are in: /clock t_(k+1), integrate, publish the state t_(k+1)."""
        sent = self._wait_start
        # /clock t_(k+1) goes out now, before the integration: the longest head start
        # over the joint state t_(k+1) an outside node's executor can get (both answers
        # for t_k are in, so nobody in the loop works at t_k any more)
        self._publish_clock(self.t_ns + self.h_ns)
        self._step()   # publishes the next state: sets _wait_start
        if self.exit_code is None:
            # one exchange = joint-state publication to the next one
            self.exchange_total += self._wait_start - sent
            self.exchanges += 1
            self._begin_wait()

    def _check_hold(self) -> None:
        """While the step waits for the recorder: a SIGINT/SIGTERM ends the loop now."""
        if self._record_held and self.exit_code is None and self.stop_signal():
            self._record_held = False
            self._hold_timer.cancel()
            self.stop_by_signal(self.stop_signal())

    def _on_recorded(self, data: bytes) -> None:
        """``/driveline/recorded``: the record time the run's bag holds on disk (raw Clock);
        a held step goes on once it is within ``record_lag_max``."""
        try:
            checked_length('rosgraph_msgs/msg/Clock', data)
            sec, nanosec = (_CLOCK_STAMP if data[1] == 1 else _CLOCK_STAMP_BE).unpack_from(data, 4)
            stamp_ns = sec * NS_PER_S + nanosec
        except (CdrError, struct.error, IndexError) as exc:
            self._drop_malformed(RECORDED_TOPIC, str(exc))
            return
        if stamp_ns <= self.recorded_ns:
            return
        self.recorded_ns = stamp_ns
        self._recorded_mono = time.monotonic()
        if self._record_held and self.exit_code is None and (
                self.t_ns + self.h_ns - stamp_ns <= self.record_lag_ns):
            self._record_held = False
            self._hold_timer.cancel()
            self.record_waits += 1
            self.record_wait_total += time.perf_counter() - self._record_hold_start
            if self.stop_signal():
                self.stop_by_signal(self.stop_signal())
                return
            self._advance()

    # --- stepping ---------------------------------------------------------------------------

    def _step(self, ticks: int = 1) -> None:
        """Integrate t_k -> t_{k+ticks} with the current torques and publish the new state
        (ticks > 1: free-run skipping missed ticks)."""
        t_next_ns = self.t_ns + ticks * self.h_ns
        c0 = time.perf_counter()
        try:
            x = self.stepper.advance(t_next_ns / NS_PER_S, self.T_engine, self.T_load)
        except CvjError as exc:
            self._stop_with_error(f'integration failed at t={self.t_ns / NS_PER_S:.9g} s: {exc}; '
                                  f'{self._step_torques()}')
            return
        self.integration_total += time.perf_counter() - c0
        self.x = np.asarray(x, dtype=float)
        self.k += ticks
        self.t_ns = t_next_ns
        if self.hybrid is not None and self.hybrid.stall is not None:
            self._publish_state()
            self._end_stalled()
            return
        if self._emit_state():
            self._after_state()

    def _end_stalled(self) -> None:
        """A mode scene's engine stalled: the state at the stall is the last; its line on
        /diagnostics (WARN) and in the log; exit 0 (the run's outcome, not an error)."""
        self.waiting = False
        self._cancel_timers()
        line = self.hybrid.stall
        self.get_logger().warning(line)
        self.publish_diagnostics(WARN, line)
        self.finish()

    def _after_state(self) -> None:
        """After the state t_k went out: periodic diagnostics, the end of the run at t_N."""
        every = self.params['diagnostics_every']
        if self.k // every != self._diag_k // every:
            self._diag_k = self.k
            self.publish_diagnostics(self._level(), 'running')
        if self.k >= self.n_steps:
            self.waiting = False
            self._cancel_timers()
            self.publish_diagnostics(self._level(), 'finished')
            st = self.loop_stats()
            self.get_logger().info(
                f'finished {self.k} steps, t={self.t_ns / NS_PER_S:g} s, real-time factor '
                f'{st["real_time_factor"]:.3g}; per exchange: wall {st["exchange_wall_us_mean"]:.0f} us, '
                f'integration {st["integration_us_mean"]:.0f} us, overhead {st["overhead_us_mean"]:.0f} us, '
                f'wait {st["lockstep_wait_us_mean"]:.0f} us, state {st["state_us_mean"]:.0f} us, '
                f'process CPU {st["process_cpu_us_mean"]:.0f} us')
            if self.scheduler is not None:
                self.get_logger().info(
                    f'free-run (catch_up {st["catch_up"]}): {st["ticks_run"]} ticks run, '
                    f'{st["ticks_skipped"]} skipped, {st["overruns"]} overruns (late by >= h); '
                    f'lateness p50 {st["lateness_us_p50"]:.0f} us, p99 {st["lateness_us_p99"]:.0f} us, '
                    f'max {st["lateness_us_max"]:.0f} us; drift {st["drift_s"] * 1e3:.3f} ms '
                    f'(max {st["drift_max_s"] * 1e3:.3f} ms)')
            self.finish()

    def _step_torques(self) -> str:
        """The torques a failed step integrated, each with the topic it came from, the largest
        magnitude first (names the topic of an absurd torque that broke the step)."""
        pairs = sorted(((ENGINE_WRENCH_TOPIC, float(self.T_engine)), (LOAD_WRENCH_TOPIC, float(self.T_load))),
                       key=lambda tv: -abs(tv[1]) if math.isfinite(tv[1]) else -math.inf)
        return 'torques of the step, largest first: ' + ', '.join(f'{t} {v:.6g} N m' for t, v in pairs)

    def _free_tick(self) -> None:
        """Free-run wake-up: run every due tick (catch-up policy of the scheduler), then
        re-arm the timer for the next due time (a wake-up before it runs nothing)."""
        sched = self.scheduler
        if self.exit_code is not None or sched is None:
            return
        now = time.monotonic()
        if now >= self._graph_due:      # a second publisher on a loop topic (as in lockstep)
            self._graph_due = now + GRAPH_CHECK_S
            foreign = self._extra_publishers()
            if foreign:
                self._stop_with_error(foreign)
                return
        run_wakeup(sched, time.monotonic_ns, self._run_free_step)
        if self.exit_code is not None or sched.finished() or self._free_timer is None:
            return
        delay_ns = sched.due_ns(sched.done + 1) - time.monotonic_ns()
        self._free_timer.timer_period_ns = max(delay_ns, 1_000)
        self._free_timer.reset()

    def stop_by_signal(self, signum: int) -> None:
        """End the loop at the exchange in progress (SIGINT/SIGTERM): the state t_k already
        published and its answers are the run's last; an OK status 'stopped by <signal> at
        step k' on /diagnostics; exit 0 (the signal's exit status is the caller's)."""
        if self.exit_code is not None:
            return
        import signal as _signal
        try:
            name = _signal.Signals(signum).name
        except ValueError:
            name = f'signal {signum}'
        self.waiting = False
        self._cancel_timers()
        line = f'stopped by {name} at step {self.k}, t={self.t_ns / NS_PER_S:.9g} s'
        self.publish_diagnostics(self._level(), line)
        self.get_logger().info(line)
        self.finish()

    def _run_free_step(self, step: Step) -> bool:
        """One free-run exchange step of ``step.ticks`` exchange steps; False when the run ended."""
        if self.stop_signal():
            self.stop_by_signal(self.stop_signal())
            return False
        now = time.perf_counter()
        self._step(step.ticks)
        self.exchange_total += time.perf_counter() - now
        self.exchanges += 1
        return self.exit_code is None

    def _publish_clock(self, t_ns: int) -> None:
        """Publish /clock = ``t_ns`` (once per time: :meth:`_publish_state` skips it then)."""
        if t_ns == self._clock_sent_ns:
            return
        sec, nanosec = divmod(t_ns, NS_PER_S)
        if self.raw_publication:
            self.clock_pub.publish(self._clock_cdr.encode(sec, nanosec))
        else:
            self._stamp.sec, self._stamp.nanosec = sec, nanosec
            self.clock_pub.publish(self._clock_msg)
        self._clock_sent_ns = t_ns

    def _publish_state(self) -> None:
        """Publish the state at t_k: /clock, then /driveline/joint_states (the peers wait for
        it), then the reaction wrenches, which nobody in the loop waits for."""
        c0 = time.perf_counter()
        sec, nanosec = divmod(self.t_ns, NS_PER_S)
        x, t_engine, t_load = self.x, self.T_engine, self.T_load
        raw = self.raw_publication
        if not raw:
            self._stamp.sec, self._stamp.nanosec = sec, nanosec   # shared by /clock and headers
        # /clock for t_k goes out BEFORE the joint state stamped t_k: an outside node under
        # use_sim_time has then (as far as its executor takes the clock first) now() == t_k
        # in its joint-state callback. In lockstep it went out already before the
        # integration (_on_wrench); else here, ahead of the joint-state evaluation.
        self._publish_clock(self.t_ns)
        if self.scale_pub is not None:      # the throttle scale of step k, before the state t_k
            self.scale_pub.publish(_FLOAT64_LE.pack(_CDR_LE, self.hybrid.throttle_scale()))
        pos, vel, eff = self.outputs.joint_states(x, t_engine, t_load)
        if raw:
            self.js_pub.publish(self._js_cdr.encode(sec, nanosec, pos, vel, eff))
        else:
            msg = self._js_msg
            msg.position = pos.tolist()
            msg.velocity = vel.tolist()
            msg.effort = eff.tolist()
            self.js_pub.publish(msg)
        self._wait_start = time.perf_counter()   # the lockstep wait starts here
        if self.scheduler is not None:
            if self.scheduler.start_ns is None:        # the first exchange: the clock starts now
                self._first_state_ns = time.monotonic_ns()
            else:
                self.scheduler.published(time.monotonic_ns())   # free-run drift at publication
        self.state_total += self._wait_start - c0
        self.joint_states_published += 1
        if self.reaction_pubs:
            # computed while engine_node and load_node answer (fwd_halfshaft's exact tripod:
            # ~11 us compiled, ~9-12 ms in Python since its Newton runs without BLAS)
            wrenches = self.outputs.wrenches(x, t_engine, t_load, (pos, vel, eff))
            for joint, pub in self.reaction_pubs.items():
                w = wrenches.get(joint)
                if w is None:
                    continue
                force, torque = w
                if raw:
                    pub.publish(self._reaction_cdr[joint].encode(sec, nanosec, *force, *torque))
                    continue
                wrench = self._reaction_msgs[joint].wrench
                f, m = wrench.force, wrench.torque
                f.x, f.y, f.z = force
                m.x, m.y, m.z = torque
                pub.publish(self._reaction_msgs[joint])

    # --- diagnostics ------------------------------------------------------------------------

    def _level(self) -> bytes:
        """WARN once a stamp was ignored, a torque held, a message dropped as malformed or a
        free-run tick overran, else OK."""
        overran = self.scheduler is not None and self.scheduler.overruns > 0
        return (WARN if self.ignored_stamps or self.held_torques or overran or self.malformed.counts
                else OK)

    def real_time_factor(self) -> float:
        """Simulated seconds per wall second since step 0."""
        wall = time.perf_counter() - self._t_wall0 if self.started else 0.0
        return (self.t_ns / NS_PER_S) / wall if wall > 0 else 0.0

    def loop_stats(self) -> dict[str, float | int]:
        """Loop metrics: steps, t (s), real-time factor, per-exchange wall/wait/integration/
        overhead (us), ignored stamps, rejected torques, energy residual (-) when tracked."""
        n = max(self.exchanges, 1)
        stats: dict[str, float | int] = {
            'steps': self.k, 'steps_total': self.n_steps, 't_sim_s': self.t_ns / NS_PER_S,
            'real_time_factor': self.real_time_factor(),
            'exchange_wall_us_mean': 1e6 * self.exchange_total / n,
            'lockstep_wait_us_mean': 1e6 * self.wait_total / n,
            'integration_us_mean': 1e6 * self.integration_total / n,
            'state_us_mean': 1e6 * self.state_total / max(self.joint_states_published, 1),
            # CPU time of this process (all threads, DDS included) per exchange since step 0
            'process_cpu_us_mean': 1e6 * (time.process_time() - self._cpu0) / n if self.started else 0.0,
            'overhead_us_mean': 1e6 * (self.exchange_total - self.integration_total) / n,
            'ignored_stamps': self.ignored_stamps, 'rejected_torques': self.rejected_torques,
            'held_torques': self.held_torques, MALFORMED_KEY: self.malformed.total,
        }
        if self.record_lag_ns:
            # the recorder gate: steps held for the bag, their wall time per exchange
            stats['record_waits'] = self.record_waits
            stats['record_wait_us_mean'] = 1e6 * self.record_wait_total / n
        if self.scheduler is not None:
            stats.update(self.scheduler.stats())
            stats['realtime_priority'] = self.realtime_priority
        # a vehicle scene: vehicle speed and per-wheel slip, tyre and normal force
        stats.update(vehicle_values(self.driveline, self.x))
        if self.hybrid is not None:       # engaged gear, clutch/brake modes, stall
            from cvj_ros.nodes.hybrid_backend import mode_values
            stats.update(mode_values(self.hybrid))
            stats['refused_commands'] = (stats['refused_commands']
                                         + sum(self.commands.refused.values()))
        if getattr(self.driveline, 'track_energy', False):
            try:
                stats['energy_residual'] = float(self.driveline.energy_residual(self.x, self.energy0))
            except (ValueError, IndexError):
                pass
        return stats

    def publish_diagnostics(self, level: bytes, message: str) -> None:
        publish_statuses(self.diag_pub, self.t_ns, self.diag_frame,
                         [plain_status('coupling_node: loop', level, message, self.loop_stats())])


def main(args: Sequence[str] | None = None) -> None:
    sys.exit(run_node(CouplingNode, args, prog='coupling_node'))


if __name__ == '__main__':
    main()
