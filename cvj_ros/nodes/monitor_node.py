"""monitor_node: rolling metrics of a run, published on /diagnostics with OK/WARN/ERROR.

Subscribes /driveline/joint_states, /engine/wrench, /load/wrench, /driveline/scene and
/diagnostics (the coupling node's loop status). Every ``publish_every`` joint-state
samples it publishes one DiagnosticArray (stamp = latest joint-state stamp) with:

* ``monitor: <shaft>`` per shaft: mean speed (rad/s), speed nonuniformity
  delta = (w_max - w_min)/w_mean (Davidbaev et al. 2023, sec. 4) over the last ``window`` seconds,
  speed and torque (effort) amplitudes (max - min)/2; level from the
  ``nonuniformity_warn`` / ``nonuniformity_error`` thresholds;
* ``monitor: torques``: engine and load torque mean and amplitude (N m);
* ``monitor: joint <name>``: bend angle (deg) vs recommended limit (scene
  ``limits.max_angle_deg``, else RECOMMENDED_MAX_ANGLE_DEG: tripod 25 deg Xiu et al. 2024,
  Rzeppa 47 deg Bugaru & Vasile 2021); WARN above the limit, ERROR above limit + 5 deg;
* ``monitor: loop``: energy residual, real-time factor, lockstep wait (us) from the
  coupling node's diagnostics, with the ``energy_residual_*`` and ``real_time_factor_warn``
  thresholds;
* ``monitor: modes`` (scenes with clutch, gearbox or brakes): the operating state from the
  coupling node's loop status (:mod:`cvj_ros.nodes.monitor_modes`): OK in steady running and
  in the transient states (vehicle held at rest, clutch slipping, neutral, shift running),
  WARN after a stall. A shaft's nonuniformity over a window that is not wholly steady running
  is reported at level OK with the reason: the limits are for steady running.

The scene comes from the ``scene`` parameter or, when empty, from /driveline/scene.
"""
from __future__ import annotations

import math
import sys
from collections.abc import Sequence
from typing import Any

import yaml
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import WrenchStamped
from sensor_msgs.msg import JointState
from std_msgs.msg import String

from cvj_ros.nodes.common import (ERROR, OK, WARN, CvjNode, ParamSpec, declare_parameters,
                                  load_scene_param, run_node, scene_dict, stamp_to_ns)
from cvj_ros.nodes.diagnostics import Status, plain_status, publish_statuses
from cvj_ros.nodes.qos import (DATA_QOS, DIAGNOSTICS_TOPIC, ENGINE_WRENCH_TOPIC, JOINT_STATES_TOPIC,
                               LATCHED_QOS, LOAD_WRENCH_TOPIC, SCENE_TOPIC)
from cvj_ros.nodes.malformed import MalformedInputs
from cvj_ros.nodes.monitor_modes import DrivelineStates, scene_has_modes
from cvj_ros.nodes.parameters import scene_elements
from cvj_ros.nodes.cdr import (CdrError, JointStateDecoder, decode_string, decode_wrench_header_torque_z,
                               decode_diagnostic_array, read_joint_state_block,
                               read_wrench_torque_z_block)
from cvj_ros.physics.monitor_metrics import (DEFAULT_NONUNIFORMITY_ERROR,
                                             DEFAULT_NONUNIFORMITY_WARN,
                                             RECOMMENDED_MAX_ANGLE_DEG, RollingWindow,
                                             angle_level, detrended_nonuniformity, level,
                                             nonuniformity_from_stats)

LEVELS = (OK, WARN, ERROR)

# Joint members that are not shafts: their angle follows the joint's kinematics (a Rzeppa
# cage turns about the bisector-plane axis with a Hooke-like law, 1/cos a - cos a = 0.173 at
# a = 23.5 deg), but they carry no drive torque to a machine; Davidbaev et al. 2023's nonuniformity
# recommendations (sec. 4) concern drive and driven shafts. Their nonuniformity is reported
# at level OK; a non-finite speed stays an ERROR. Intermediate shafts of a cardan chain and
# a double cardan's centre yoke are shafts and keep the limits.
INTERNAL_MEMBERS = {'rzeppa': 'cage', 'tripod': 'spider', 'lever_hinge': 'earring'}

PARAMS = (
    ParamSpec('scene', '', 'scene name or YAML path; empty = take it from /driveline/scene'),
    ParamSpec('window', 1.0, 'rolling window length [s] of simulated time', lo=0.0, hi=1e6,
              lo_open=True, read_only=False),
    ParamSpec('capacity', 20000, 'most samples kept per window', lo=2, hi=10**7),
    ParamSpec('publish_every', 100, 'publish /diagnostics every N joint-state samples',
              lo=1, hi=10**9, read_only=False),
    ParamSpec('min_speed', 1.0, 'shafts slower than this mean speed get no nonuniformity [rad/s]',
              lo=0.0, hi=1e6, read_only=False),
    ParamSpec('nonuniformity_warn', DEFAULT_NONUNIFORMITY_WARN,
              'speed nonuniformity WARN threshold [-] (Davidbaev et al. 2023, sec. 4); 0 = off',
              lo=0.0, hi=10.0, read_only=False),
    ParamSpec('nonuniformity_error', DEFAULT_NONUNIFORMITY_ERROR,
              'speed nonuniformity ERROR threshold [-] (Davidbaev et al. 2023, sec. 4); 0 = off',
              lo=0.0, hi=10.0, read_only=False),
    ParamSpec('energy_residual_warn', 1e-3, 'relative energy residual WARN threshold [-]; 0 = off',
              lo=0.0, hi=1.0, read_only=False),
    ParamSpec('energy_residual_error', 1e-2, 'relative energy residual ERROR threshold [-]; 0 = off',
              lo=0.0, hi=1.0, read_only=False),
    ParamSpec('real_time_factor_warn', 0.0, 'WARN when the real-time factor falls below this [-] '
              '(free-run: 1.0); 0 = off', lo=0.0, hi=1e6, read_only=False),
    ParamSpec('angle_error_margin_deg', 5.0, 'ERROR when a joint angle exceeds its recommended '
              'limit by more than this [deg]', lo=0.0, hi=90.0, read_only=False),
)


#: samples collected before they are read into the windows anyway (bounds the memory with a
#: large publish_every: the windows are fixed-size ring buffers, the collection is not)
MAX_COLLECTED = 1000


#: loop statuses held ahead of the joint states at most (one per diagnostics_every steps)
MAX_PENDING_LOOP = 256


class MonitorNode(CvjNode):
    """Rolling-window run monitor (see module docstring). Parameters: :data:`PARAMS`."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__('monitor_node', **kwargs)
        self.params = declare_parameters(self, PARAMS)
        # messages that arrive while their loop topic has more than one publisher (whose
        # they are cannot be told: cvj_ros.nodes.peers) are ignored and counted
        self.foreign_messages = 0
        self.malformed = MalformedInputs(self.get_logger())   # undecodable inputs, per topic
        self._diag_frame = 'monitor_node'
        self.joint_limits: dict[str, tuple[float, float]] = {}   # joint -> (angle deg, limit deg)
        self.internal_members: set[str] = set()   # shafts of INTERNAL_MEMBERS: no limit
        self.states = DrivelineStates()           # steady running or a mode transient
        if self.params['scene']:
            self._use_scene(scene_dict(load_scene_param(self.params['scene'])))
        self.names: list[str] = []
        self.speeds: RollingWindow | None = None
        self.efforts: RollingWindow | None = None
        cap = self.params['capacity']
        self._engine_torque = RollingWindow(cap, 1)
        self._load_torque = RollingWindow(cap, 1)
        self.loop_values: dict[str, float] = {}
        # coupling node statuses stamped after the latest joint state taken, held until the
        # monitor's time reaches them (_take_loop_status)
        self._pending_loop: list[tuple[int, dict[str, str]]] = []
        self.samples = 0
        self.last_ns = 0
        self.published = 0
        self.last_statuses: list[Status] = []
        from cvj_ros.nodes.intra import loop_publisher, loop_subscription
        self.diag_pub = loop_publisher(self, DiagnosticArray, DIAGNOSTICS_TOPIC, DATA_QOS)
        # joint states as raw CDR too, read by JointStateDecoder (rclpy's Python JointState
        # per sample cost ~4x more)
        self._js_decoder = JointStateDecoder()
        self._decode = self._js_decoder.decode
        # the compiled window kernels loaded now, not at the first publication inside the loop
        # (a fresh `cvj-sim run --composed` ran its 5 s loop ~20 % slower before)
        from cvj_ros.physics.kernel import window_nb
        window_nb.warm()
        # Samples are collected as they come and read in bulk when the statuses are computed
        # (every publish_every joint states): the per-sample callback only checks the run
        # publisher count and appends (composed mode, in-process bus: ~45 -> ~10 us per exchange).
        self._js_batch: list[bytes] = []
        # the answers per window, in arrival order (one list each: grouping (bytes, window)
        # pairs at every publication cost ~100 us of its ~800 in a running composed loop)
        self._engine_batch: list[bytes] = []
        self._load_batch: list[bytes] = []
        # (from the in-process bus in composed mode: cvj_ros.nodes.intra)
        self.js_sub = loop_subscription(self, JointState, JOINT_STATES_TOPIC,
                                        self._on_joint_states_raw, DATA_QOS)
        # the answers as raw CDR: stamp, frame_id and torque.z read in place
        # (decode_wrench_header_torque_z) instead of rclpy building a Python WrenchStamped per
        # sample (measured 75-145 us each, two per exchange; docs/nodes.md, composed mode)
        self.engine_sub = loop_subscription(self, WrenchStamped, ENGINE_WRENCH_TOPIC,
                                            self._collect_engine, DATA_QOS)
        self.load_sub = loop_subscription(self, WrenchStamped, LOAD_WRENCH_TOPIC,
                                          self._collect_load, DATA_QOS)
        self.diag_sub = loop_subscription(self, DiagnosticArray, DIAGNOSTICS_TOPIC,
                                          self._on_diagnostics_raw, DATA_QOS)
        self.scene_sub = loop_subscription(self, String, SCENE_TOPIC, self._on_scene_raw,
                                           LATCHED_QOS)

    # --- inputs -----------------------------------------------------------------------------

    def _use_scene(self, scene: dict[str, Any]) -> None:
        """Collect joint bend angles and their recommended limits from a scene dict, and the
        joints' internal members (INTERNAL_MEMBERS)."""
        limits: dict[str, tuple[float, float]] = {}
        members: set[str] = set()
        for el in scene_elements(scene.get('driveline')):    # a vehicle scene's branches too
            if el.get('type') != 'joint':
                continue
            if el.get('kind') in INTERNAL_MEMBERS and 'name' in el:
                members.add(f"{el['name']}_{INTERNAL_MEMBERS[el['kind']]}")
            params = el.get('params', {}) or {}
            angle = None
            for key in ('beta_deg', 'beta2_deg', 'delta_deg', 'alpha_deg', 'beta1_deg'):
                if key in params:
                    angle = max(float(params[key]), angle or 0.0)
            if angle is None and 'beta' in params:
                angle = math.degrees(float(params['beta']))
            limit = (el.get('limits', {}) or {}).get('max_angle_deg',
                                                     RECOMMENDED_MAX_ANGLE_DEG.get(el.get('kind', '')))
            if angle is not None and limit is not None:
                limits[str(el['name'])] = (angle, float(limit))
        self.joint_limits = limits
        self.internal_members = members
        self.states.expect_modes = scene_has_modes(scene_elements(scene.get('driveline')))

    def _foreign(self, sub: Any) -> bool:
        """True (and counted) when ``sub`` (a DDS subscription of a loop topic) has more than
        one publisher: whose the message is cannot be told (cvj_ros.nodes.peers). In
        composed mode and beside the recorder the monitor gets the run's messages only."""
        if hasattr(sub, 'bus') or sub.get_publisher_count() <= 1:
            return False
        self.foreign_messages += 1
        return True

    def _drop(self, topic: str, reason: str) -> None:
        """A message the checked decoders refused: dropped, counted (``malformed_messages``),
        the first one per topic in one WARN line."""
        self.malformed.drop(topic, reason)

    def _on_scene_raw(self, data: bytes) -> None:
        try:
            text = decode_string(data)
        except CdrError as exc:
            self._drop(SCENE_TOPIC, str(exc))
            return
        self._on_scene(String(data=text))

    def _on_scene(self, msg: String) -> None:
        if self.params['scene']:
            return
        try:
            data = yaml.safe_load(msg.data)
        except yaml.YAMLError:
            self.get_logger().error('/driveline/scene: not valid YAML; joint angles not monitored')
            return
        if isinstance(data, dict) and isinstance(data.get('scene'), dict):
            self._use_scene(data['scene'])

    def _on_joint_states_raw(self, data: bytes) -> None:
        """A serialised joint state: dropped (counted) if another run's, else collected; the
        statuses are published at every publish_every-th accepted sample."""
        if self._foreign(self.js_sub):
            return
        batch = self._js_batch
        batch.append(data)
        if (self.samples + len(batch)) % self.params['publish_every'] == 0:
            self.publish()
        elif len(batch) >= MAX_COLLECTED:
            self.take_samples()

    def _collect_engine(self, data: bytes) -> None:
        """A serialised /engine/wrench answer, kept for :meth:`take_samples`."""
        if self._foreign(self.engine_sub):
            return
        batch = self._engine_batch
        batch.append(data)
        if len(batch) >= MAX_COLLECTED:
            self.take_samples()

    def _collect_load(self, data: bytes) -> None:
        """A serialised /load/wrench answer, kept for :meth:`take_samples`."""
        if self._foreign(self.load_sub):
            return
        batch = self._load_batch
        batch.append(data)
        if len(batch) >= MAX_COLLECTED:
            self.take_samples()

    @property
    def engine_torque(self) -> RollingWindow:
        """The engine answers' torque.z window (N m; collected samples read first)."""
        self.take_samples()
        return self._engine_torque

    @property
    def load_torque(self) -> RollingWindow:
        """The load answers' torque.z window (N m; collected samples read first)."""
        self.take_samples()
        return self._load_torque

    def take_samples(self) -> None:
        """Read the collected joint states and answers into the windows (in arrival order).

        A batch of one layout (the coupling node's samples) is read at once
        (:func:`~cvj_ros.nodes.cdr.read_joint_state_block`, one ``push_many`` per window);
        anything else (names changing, short arrays, other encodings) sample by sample."""
        if self._js_batch:
            batch, self._js_batch = self._js_batch, []
            block = read_joint_state_block(batch, self._js_decoder, position=False)
            if block is None:
                self._take_js_one_by_one(batch)
            else:
                self._use_names(block.name)
                t = block.stamp_ns / 1e9
                self.last_ns = int(block.stamp_ns[-1])
                self._push_js(t, block.velocity, block.effort)
        if self._engine_batch:
            batch, self._engine_batch = self._engine_batch, []
            self._take_torques(self._engine_torque, batch, ENGINE_WRENCH_TOPIC)
        if self._load_batch:
            batch, self._load_batch = self._load_batch, []
            self._take_torques(self._load_torque, batch, LOAD_WRENCH_TOPIC)

    def _take_torques(self, window: RollingWindow, samples: list[bytes], topic: str) -> None:
        block = read_wrench_torque_z_block(samples)
        if block is not None:
            stamp_ns, _frame, torque_z = block
            window.push_many(stamp_ns / 1e9, torque_z)
            return
        t: list[float] = []
        z: list[float] = []
        for data in samples:
            try:
                stamp_ns, _frame, torque_z = decode_wrench_header_torque_z(data)
            except CdrError as exc:
                self._drop(topic, str(exc))
                continue
            t.append(stamp_ns / 1e9)
            z.append(torque_z)
        window.push_many(t, z)

    def _take_js_one_by_one(self, batch: list[bytes]) -> None:
        decode = self._decode
        ts: list[float] = []
        vel: list[Any] = []
        eff: list[Any] = []
        for data in batch:
            try:
                msg = decode(data)
            except CdrError as exc:
                self._drop(JOINT_STATES_TOPIC, str(exc))
                continue
            if msg.name is not self.names and ts:
                self._push_js(ts, vel, eff)          # the samples before a change of names
                ts, vel, eff = [], [], []
            row = self._read_joint_state(msg)
            if row is not None:
                ts.append(row[0])
                vel.append(row[1])
                eff.append(row[2])
        self._push_js(ts, vel, eff)

    def _use_names(self, names: list[str]) -> None:
        """Windows for shafts ``names`` (new ones when the names change)."""
        if names is not self.names:
            if names != self.names or self.speeds is None:
                cap = self.params['capacity']
                self.speeds = RollingWindow(cap, max(len(names), 1))
                self.efforts = RollingWindow(cap, max(len(names), 1))
            self.names = names

    def _read_joint_state(self, msg: Any) -> tuple[float, Any, Any] | None:
        """(t in s, velocity row, effort row) of one joint state for the windows (NaN rows
        for arrays shorter than the names); the windows follow its names."""
        names = msg.name     # a decoder's cached list: identical object while names repeat
        self._use_names(names)
        self.last_ns = stamp_to_ns(msg.header.stamp)
        n = len(names)
        vel = msg.velocity if len(msg.velocity) == n else [math.nan] * n
        eff = msg.effort if len(msg.effort) == n else [math.nan] * n
        return self.last_ns / 1e9, vel, eff

    def _push_js(self, ts: Any, vel: Any, eff: Any) -> None:
        if len(ts):
            assert self.speeds is not None and self.efforts is not None
            self.speeds.push_many(ts, vel)
            self.efforts.push_many(ts, eff)
            self.samples += len(ts)

    def _on_joint_states(self, msg: Any, *, publish: bool = True) -> None:
        """One joint state (a JointState or a :class:`~cvj_ros.nodes.cdr.JointStateView`)."""
        self.take_samples()                      # keep arrival order with collected samples
        row = self._read_joint_state(msg)
        if row is None:
            return
        self._push_js((row[0],), (row[1],), (row[2],))
        if publish and self.samples % self.params['publish_every'] == 0:
            self.publish()

    def _on_torque_raw(self, data: bytes, window: RollingWindow, topic: str = ENGINE_WRENCH_TOPIC) -> None:
        """A serialised WrenchStamped answer: dropped (counted) if malformed, else torque.z
        (N m) at its stamp into ``window``."""
        try:
            stamp_ns, _frame, torque_z = decode_wrench_header_torque_z(data)
        except CdrError as exc:
            self._drop(topic, str(exc))
            return
        window.push(stamp_ns / 1e9, [torque_z])

    def _on_diagnostics_raw(self, data: bytes) -> None:
        """A serialised /diagnostics message: another run's counted; deserialised (200-400 us
        with rclpy) only when it can hold a coupling node status - its own and the peers'
        statuses (one per publication) have nothing the monitor reads."""
        if b'coupling_node' not in data:
            return
        try:
            stamp_ns, frame, statuses = decode_diagnostic_array(data)
        except CdrError as exc:
            self._drop(DIAGNOSTICS_TOPIC, str(exc))
            return
        self._take_loop_status(frame, [(name, values) for _l, name, _m, _h, values in statuses],
                               stamp_ns)

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        self._take_loop_status(msg.header.frame_id, [(st.name, [(kv.key, kv.value) for kv in st.values])
                                                     for st in msg.status],
                               stamp_to_ns(msg.header.stamp))

    def _take_loop_status(self, frame_id: str, statuses: list[tuple[str, list[tuple[str, str]]]],
                          stamp_ns: int | None = None) -> None:
        """Keep the float values of the coupling node's statuses (name, key/values) of one
        /diagnostics message with header.frame_id ``frame_id`` and stamp ``stamp_ns`` (the
        loop's t_k), and its modes (:class:`DrivelineStates`).

        A status stamped after the latest joint state taken is held and used once the
        monitor's time reaches its stamp: a publication at t_j sees the loop statuses stamped
        <= t_j, whichever arrived first (a busy monitor used to see the status of t_100 in its
        statuses of t_99, an idle one not)."""
        for name, values in statuses:
            if not name.startswith('coupling_node'):
                continue
            stamp = self.last_ns if stamp_ns is None else stamp_ns
            if stamp <= self.last_ns:
                self._use_loop_status(stamp, dict(values))
            else:
                self._pending_loop.append((stamp, dict(values)))
                if len(self._pending_loop) > MAX_PENDING_LOOP:   # no joint states: stamps never reached
                    self._pending_loop.sort(key=lambda p: p[0])
                    self._use_loop_status(*self._pending_loop.pop(0))

    def _use_loop_status(self, stamp_ns: int, values: dict[str, str]) -> None:
        self.states.take(stamp_ns, values)
        for key, value in values.items():
            try:
                self.loop_values[key] = float(value)
            except ValueError:
                pass

    def _take_pending_loop_statuses(self) -> None:
        """The held loop statuses stamped <= the latest joint state, in stamp order."""
        if not self._pending_loop:
            return
        due = sorted((p for p in self._pending_loop if p[0] <= self.last_ns), key=lambda p: p[0])
        if due:
            self._pending_loop = [p for p in self._pending_loop if p[0] > self.last_ns]
            for stamp, values in due:
                self._use_loop_status(stamp, values)

    # --- output -----------------------------------------------------------------------------

    def compute(self) -> list[Status]:
        """The statuses of one /diagnostics message from the current windows."""
        self.take_samples()
        self._take_pending_loop_statuses()
        p = self.params
        out: list[Status] = []
        if self.speeds is not None and self.efforts is not None and len(self.speeds):
            n_w, w_mean, w_lo, w_hi = self.speeds.stats(p['window'])
            _n, _e_mean, e_lo, e_hi = self.efforts.stats(p['window'])
            delta = nonuniformity_from_stats(w_mean, w_lo, w_hi, min_speed=max(p['min_speed'], 1e-12))
            w_amp, e_amp = 0.5 * (w_hi - w_lo), 0.5 * (e_hi - e_lo)
            # a launch, a shift, a stall within the window: not steady running (module docstring)
            transient = self.states.not_steady(self.last_ns - int(p['window'] * 1e9))
            trend = None
            if self.states.expect_modes and not transient:
                # a vehicle accelerating in gear: judged about the window's speed trend
                tw, ww = self.speeds.window(p['window'])
                trend = detrended_nonuniformity(tw, ww, min_speed=max(p['min_speed'], 1e-12))
            for i, name in enumerate(self.names):
                d = float(delta[i])
                if trend is not None and math.isfinite(float(trend[0][i])):
                    d = float(trend[0][i])
                lv = 0 if math.isnan(d) and math.isfinite(w_mean[i]) else level(
                    d, p['nonuniformity_warn'], p['nonuniformity_error'])
                msg = ('standstill' if math.isnan(d) and lv == 0
                       else f'nonuniformity {d:.4g}')
                if trend is not None and math.isfinite(d):
                    msg += (f' about the speed trend ({float(trend[1][i]):+.4g} rad/s^2; '
                            f'max-min over mean {float(delta[i]):.4g})')
                if name in self.internal_members and math.isfinite(d):
                    lv = 0   # the thresholds are for shafts (Davidbaev et al. 2023, sec. 4), not a cage
                    msg += ' (internal member: no limit)'
                elif transient and math.isfinite(w_mean[i]):
                    lv = 0   # the thresholds are for steady running (Davidbaev et al. 2023, sec. 4)
                    if not math.isnan(d):
                        msg += f' (not judged: {transient} within the window)'
                out.append(plain_status(f'monitor: {name}', LEVELS[lv], msg, {
                    'speed_mean_rad_s': float(w_mean[i]), 'nonuniformity': float(delta[i]),
                    **({'nonuniformity_about_trend': d} if trend is not None else {}),
                    'speed_amplitude_rad_s': float(w_amp[i]),
                    'torque_amplitude_nm': float(e_amp[i]), 'samples': int(n_w)}))
        values: dict[str, float] = {}
        for label, win in (('engine', self.engine_torque), ('load', self.load_torque)):
            n, mean, lo, hi = win.stats(p['window'])
            if n:
                values[f'{label}_torque_mean_nm'] = float(mean[0])
                values[f'{label}_torque_amplitude_nm'] = float(0.5 * (hi[0] - lo[0]))
        if values:
            ok = all(math.isfinite(v) for v in values.values())
            out.append(plain_status('monitor: torques', OK if ok else ERROR,
                                   'ok' if ok else 'non-finite torque', values))
        for joint, (angle, limit) in self.joint_limits.items():
            lv = angle_level(angle, limit, error_margin_deg=p['angle_error_margin_deg'])
            out.append(plain_status(f'monitor: joint {joint}', LEVELS[lv],
                                   f'angle {angle:.3g} deg, recommended <= {limit:.3g} deg',
                                   {'angle_deg': angle, 'limit_deg': limit}))
        if self.states.seen or self.states.expect_modes:
            st = self.states
            line = st.state_line()
            out.append(plain_status('monitor: modes', WARN if st.modes.get('stall') else OK,
                                   st.modes.get('stall') or line,
                                   {'state': line, **{k: v for k, v in st.modes.items() if k != 'stall'}}))
        if self.loop_values:
            lv = 0
            lv_msgs = []
            res = self.loop_values.get('energy_residual')
            if res is not None:
                r = level(abs(res), p['energy_residual_warn'], p['energy_residual_error'])
                if r:
                    lv_msgs.append(f'energy residual {res:.3g}')
                lv = max(lv, r)
            rtf = self.loop_values.get('real_time_factor')
            if rtf is not None and p['real_time_factor_warn'] > 0 and rtf < p['real_time_factor_warn']:
                lv = max(lv, 1)
                lv_msgs.append(f'real-time factor {rtf:.3g} < {p["real_time_factor_warn"]:g}')
            keys = ('energy_residual', 'real_time_factor', 'lockstep_wait_us_mean',
                    'overhead_us_mean', 'integration_us_mean', 'steps', 'ignored_stamps',
                    'rejected_torques', 'held_torques')
            out.append(plain_status('monitor: loop', LEVELS[lv], '; '.join(lv_msgs) or 'ok',
                                   {k: self.loop_values[k] for k in keys if k in self.loop_values}))
        return out

    def publish(self) -> None:
        self.last_statuses = self.compute()
        if self.last_statuses:
            publish_statuses(self.diag_pub, self.last_ns, self._diag_frame, self.last_statuses)
            self.published += 1


def main(args: Sequence[str] | None = None) -> None:
    sys.exit(run_node(MonitorNode, args, prog='monitor_node'))


if __name__ == '__main__':
    main()
