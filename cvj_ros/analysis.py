"""Offline analysis of a recorded driveline bag (`cvj-sim analyze`).

Reads a rosbag2 bag (mcap or sqlite3) through ``rosbags`` and reports, per shaft of
``/driveline/joint_states``: mean speed, speed nonuniformity delta, amplitudes ((max - min)/2,
Davidbaev et al. 2023, ch. 4) of speed, acceleration and torque, and the harmonics of the shaft torque over
the shaft angle (Davidbaev et al. 2023, eqs. 4.1-4.3); per joint (names ``<joint>_input``/``<joint>_output``)
the geometric and kinematic nonuniformity (Bugaru & Vasile 2021, eqs. 20-23); engine and load torque;
energy residual and wait times found on ``/diagnostics``; for a scene with clutch, gearbox
or brakes its mode events and final modes (``/diagnostics``); per ``/coupling/<joint>/wrench``
(a chain's joints or every branch's of a vehicle scene) the mean and amplitude of each
reaction force and torque component in the joint's housing frame; lockstep statistics; and,
for a bag of the ROS loop, the sample times its loop topics lack (the gaps line of ``cvj-sim
run``'s report, :mod:`cvj_ros.orchestrate.gaps`).

Steady window: :mod:`cvj_ros.physics.steady`, the one definition shared with ``cvj-sim
simulate`` and ``run`` (same bag -> same window -> same numbers): the slices of the record
that agree with its last slice in mean speed and amplitudes, or from ``skip_s`` seconds on
when given. Every figure except the lockstep statistics is computed on the steady window.
The signal processing itself lives in :mod:`cvj_ros.physics.signal` (no ROS).
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from cvj_ros.errors import BagError
from cvj_ros.physics import signal, steady

FloatArray = NDArray[np.float64]

JOINT_STATES = '/driveline/joint_states'
ENGINE_WRENCH = '/engine/wrench'
LOAD_WRENCH = '/load/wrench'
DIAGNOSTICS = '/diagnostics'
SCENE = '/driveline/scene'
_REACTION_TOPIC = re.compile(r'/coupling/([^/]+)/wrench')
# Diagnostic keys reported as loop / energy figures (case-insensitive substring match).
_DIAG_PATTERNS = {'energy': re.compile('energy', re.I), 'wait': re.compile('wait', re.I),
                  'loop': re.compile('overhead|round_trip|rtf|real_time|exchange|integration|ignored|rejected',
                                     re.I),
                  # a vehicle scene's loop values (cvj_ros.nodes.vehicle_diagnostics)
                  'vehicle': re.compile(r'vehicle_speed|\.(slip|fx_N|fz_N|status)$')}


@dataclass
class BagSignals:
    """Signals of one bag as arrays. Times in s (message stamps = simulated time)."""

    path: Path
    joint_names: list[str]
    t: FloatArray                      # (n,) joint-state stamps, s
    position: FloatArray               # (n, j) rad, unwrapped
    velocity: FloatArray               # (n, j) rad/s
    effort: FloatArray                 # (n, j) N m
    engine_t: FloatArray = field(default_factory=lambda: np.zeros(0))
    engine_torque: FloatArray = field(default_factory=lambda: np.zeros(0))   # N m
    load_t: FloatArray = field(default_factory=lambda: np.zeros(0))
    load_torque: FloatArray = field(default_factory=lambda: np.zeros(0))     # N m
    # (t s, status name, level 0 OK / 1 WARN / 2 ERROR, message, key/values)
    diagnostics: list[tuple[float, str, int, str, dict[str, str]]] = field(default_factory=list)
    scene_yaml: str | None = None
    message_counts: dict[str, int] = field(default_factory=dict)
    # messages left out per topic as not the run's (other joint names, undecodable)
    foreign: dict[str, int] = field(default_factory=dict)
    # per joint of /coupling/<joint>/wrench: (t s, force (n, 3) N, torque (n, 3) N m, frame_id)
    reactions: dict[str, tuple[FloatArray, FloatArray, FloatArray, str]] = field(default_factory=dict)
    # missing sample times on the loop topics of a ROS loop's bag (cvj_ros.orchestrate.gaps.run_gaps)
    gaps: dict[str, Any] = field(default_factory=dict)

    def column(self, name: str) -> int:
        return self.joint_names.index(name)


def read_bag_signals(path: str | Path) -> BagSignals:
    """Read the topics the analysis needs from a bag directory, through :mod:`cvj_ros.bag`.

    Raises :class:`BagError` when the bag is missing or unreadable (message starts with the
    path) or has no ``/driveline/joint_states`` messages (message starts with the topic).
    """
    from cvj_ros import bag as bagio

    info = bagio.bag_info(path)
    if not info.counts.get(JOINT_STATES):
        raise BagError(f'{JOINT_STATES}: no messages in bag {path} (topics: '
                       f'{", ".join(sorted(t for t, n in info.counts.items() if n)) or "none"})')
    wanted = [t for t in (JOINT_STATES, ENGINE_WRENCH, LOAD_WRENCH, DIAGNOSTICS, SCENE)
              if info.counts.get(t)]
    wanted += sorted(t for t, n in info.counts.items() if n and _REACTION_TOPIC.fullmatch(t))
    data = bagio.read_bag(path, wanted)
    js = data[JOINT_STATES]
    sig = BagSignals(path=Path(path), joint_names=list(js.names), t=js.t, position=js.position,
                     velocity=js.velocity, effort=js.effort,
                     message_counts={t: int(n) for t, n in info.counts.items() if n},
                     foreign={t: int(x.foreign) for t, x in data.items() if getattr(x, 'foreign', 0)})
    if ENGINE_WRENCH in data:
        sig.engine_t, sig.engine_torque = data[ENGINE_WRENCH].t, data[ENGINE_WRENCH].torque_z
    if LOAD_WRENCH in data:
        sig.load_t, sig.load_torque = data[LOAD_WRENCH].t, data[LOAD_WRENCH].torque_z
    if DIAGNOSTICS in data:
        d = data[DIAGNOSTICS]
        sig.diagnostics = [(float(t), str(st['name']), int(st['level']), str(st.get('message', '')),
                            {str(k): str(v) for k, v in st['values'].items()})
                           for t, statuses in zip(d.t, d.statuses) for st in statuses]
    for topic in wanted:
        m = _REACTION_TOPIC.fullmatch(topic)
        if m and topic in data:
            w = data[topic]
            sig.reactions[m.group(1)] = (w.t, w.force, w.torque, w.frame_id)
    if SCENE in data and data[SCENE].data:
        sig.scene_yaml = data[SCENE].data[0]
    elif 'cvj_ros.scene' in info.custom_data:
        sig.scene_yaml = info.custom_data['cvj_ros.scene']
    h = loop_exchange_step(sig.scene_yaml, info.custom_data)
    if h is not None:
        from cvj_ros.errors import CvjError
        from cvj_ros.orchestrate.gaps import run_gaps
        try:
            sig.gaps = run_gaps(Path(path), h, counts=info.counts)
        except CvjError:      # a summary line: never the reason the analysis fails
            sig.gaps = {}
    return sig


def loop_exchange_step(scene_yaml: str | None, custom_data: dict[str, str]) -> float | None:
    """The exchange step h (s) of a bag recorded from the ROS loop (lockstep or free-run),
    whose loop topics then hold one sample per t_k = k h: from the coupling node's
    /driveline/scene, else the metadata `cvj-sim run` writes; None for other bags (an
    offline `cvj-sim simulate` bag samples at its own period)."""
    import yaml
    try:
        data = yaml.safe_load(scene_yaml) if scene_yaml else None
    except yaml.YAMLError:
        data = None
    if isinstance(data, dict) and data.get('mode') in ('lockstep', 'free-run'):
        h = data.get('exchange_step')
    elif custom_data.get('cvj_ros.mode') in ('lockstep', 'free-run'):
        h = custom_data.get('cvj_ros.exchange_step')
    else:
        return None
    try:
        h = float(h)
    except (TypeError, ValueError):
        return None
    return h if math.isfinite(h) and h > 0 else None


def ticks_skipped(diags: list[tuple[float, str, int, str, dict[str, str]]]) -> int:
    """The free-run ticks skipped to catch up with wall time, from the coupling node's last
    loop diagnostics holding the count (0 when none is recorded)."""
    for _t, name, _level, _msg, values in reversed(diags):
        if name == 'coupling_node: loop' and 'ticks_skipped' in values:
            try:
                return int(float(values['ticks_skipped']))
            except ValueError:
                return 0
    return 0


def _f(x: float) -> float | None:
    """JSON-safe float (None for NaN/inf)."""
    x = float(x)
    return x if math.isfinite(x) else None


def _harmonics_dict(h: signal.AngleHarmonics) -> dict[str, Any]:
    return {'mean': _f(h.mean), 'revolutions': h.revolutions,
            'orders': [int(k) for k in h.orders],
            'amplitude': [_f(a) for a in h.amplitudes],
            'phase_rad': [_f(p) for p in h.phases],
            'a_cos': [_f(a) for a in h.cos_coeffs], 'b_sin': [_f(b) for b in h.sin_coeffs]}


def _try_harmonics(phi: FloatArray, values: FloatArray, *, n_harmonics: int,
                   samples_per_rev: int) -> tuple[signal.AngleHarmonics | None, str | None]:
    ok = np.isfinite(phi) & np.isfinite(values)
    try:
        return signal.harmonics_over_angle(phi[ok], values[ok], n_harmonics=n_harmonics,
                                           samples_per_rev=samples_per_rev), None
    except ValueError as exc:
        return None, str(exc)


def joint_pairs(names: list[str]) -> list[tuple[str, str, str]]:
    """(joint, input name, output name) for every ``<joint>_input`` with a ``<joint>_output``."""
    out = []
    for n in names:
        if n.endswith('_input') and n[:-6] + '_output' in names:
            out.append((n[:-6], n, n[:-6] + '_output'))
    return out


def _lockstep_stats(sig: BagSignals) -> dict[str, Any]:
    t = sig.t
    dt = np.diff(t)
    stats: dict[str, Any] = {
        'steps': int(t.size),
        'duration_s': _f(t[-1] - t[0]) if t.size else 0.0,
        'stamps_strictly_increasing': bool(np.all(dt > 0)) if dt.size else True,
        'non_increasing_stamps': int(np.count_nonzero(dt <= 0)),
    }
    if dt.size:
        pos = dt[dt > 0]
        h = float(np.median(pos)) if pos.size else math.nan
        stats.update(exchange_step_s=_f(h), exchange_step_min_s=_f(np.min(dt)),
                     exchange_step_max_s=_f(np.max(dt)),
                     exchange_step_jitter=_f((np.max(pos) - np.min(pos)) / h) if pos.size else None)
    stamps_ns = set(np.round(t * 1e9).astype(np.int64).tolist())
    for key, tt in (('engine', sig.engine_t), ('load', sig.load_t)):
        if tt.size:
            echoed = set(np.round(tt * 1e9).astype(np.int64).tolist())
            stats[f'{key}_answers'] = int(tt.size)
            stats[f'{key}_echo_fraction'] = _f(len(stamps_ns & echoed) / len(stamps_ns))
    return stats


def _diagnostic_figures(diags: list[tuple[float, str, int, str, dict[str, str]]]) -> dict[str, Any]:
    series: dict[str, list[float]] = {}
    levels = {'ok': 0, 'warn': 0, 'error': 0, 'stale': 0}
    messages: list[str] = []
    for t, name, level, message, values in diags:
        levels[{0: 'ok', 1: 'warn', 2: 'error'}.get(level, 'stale')] += 1
        if level >= 2 and len(messages) < 5:
            messages.append(f'{name} at t = {t:g} s: {message or values}')
        for key, val in values.items():
            if not any(pat.search(key) for pat in _DIAG_PATTERNS.values()):
                continue
            try:
                x = float(val)
            except ValueError:
                continue
            series.setdefault(f'{name}/{key}' if name else key, []).append(x)
    figures = {}
    for key, xs in sorted(series.items()):
        arr = np.asarray(xs, dtype=float)
        figures[key] = {'last': _f(arr[-1]), 'mean': _f(np.nanmean(arr)),
                        'max_abs': _f(np.nanmax(np.abs(arr))), 'count': int(arr.size)}
    return {'levels': levels, 'figures': figures, 'errors': messages}


#: loop-status keys of a scene with clutch, gearbox or brakes (coupling node and simulate bags)
_MODE_KEY = re.compile(r'^(clutch_state|gear|brake_state|pack_state)\.|^(mode_events|stall)$')
#: per-event status of an offline run's bag (cvj_ros.mode_outputs.EVENT_STATUS)
_EVENT_STATUS = 'cvj-sim simulate: mode event'


def _mode_summary(diags: list[tuple[float, str, int, str, dict[str, str]]]) -> dict[str, Any]:
    """Modes of a scene with clutch, gearbox or brakes from ``/diagnostics``: the located
    events (one status each in an offline run's bag) and the last value of every mode key
    (``clutch_state.*``, ``gear.*``, ``brake_state.*``, ``pack_state.*``, ``mode_events``,
    ``stall``); empty when the bag has none."""
    events = [{'t_s': _f(float(v.get('t_s', t))), 'element': v.get('element', ''),
               'before': v.get('before', ''), 'after': v.get('after', ''), 'cause': v.get('cause', '')}
              for t, name, _lev, _msg, v in diags if name == _EVENT_STATUS]
    final: dict[str, str] = {}
    for _t, _name, _lev, _msg, values in diags:
        final.update({k: v for k, v in values.items() if _MODE_KEY.search(k)})
    if not events and not final:
        return {}
    return {'events': events, 'final': final}


def analyze_signals(sig: BagSignals, *, skip_s: float | None = None,
                    skip_fraction: float | None = None, n_harmonics: int = 6, samples_per_rev: int = 72) -> dict[str, Any]:
    """Analysis report (JSON-ready dict) of the signals of a bag; see the module docstring.

    Window: the steady-window criterion (:mod:`cvj_ros.physics.steady`), or from ``skip_s``
    seconds (or ``skip_fraction`` of the record) after the first sample when given; the
    criterion's verdict on a user-set window is reported too.
    Units: speeds rad/s, accelerations rad/s^2, torques N m, angles rad, times s.
    """
    if sig.t.size < 2:
        raise BagError(f'{JOINT_STATES}: need at least 2 messages, got {sig.t.size}')
    if skip_s is None and skip_fraction is not None:   # a user-set start as a fraction of the record
        if not (math.isfinite(skip_fraction) and 0.0 <= skip_fraction < 1.0):
            raise BagError(f'skip_fraction: must be in [0, 1), got {skip_fraction}')
        skip_s = skip_fraction * float(sig.t[-1] - sig.t[0])
    try:
        win = steady.joint_state_window(sig.t, sig.joint_names, sig.velocity, sig.effort, skip_s=skip_s)
    except ValueError as exc:
        raise BagError(f'{exc}') from None
    mask = win.mask(sig.t)
    t = sig.t[mask]
    report: dict[str, Any] = {
        'bag': str(sig.path),
        'window': {'start_s': _f(t[0]), 'end_s': _f(t[-1]), 'samples': int(t.size),
                   'skipped_s': _f(t[0] - sig.t[0]), 'steady': win.steady, 'source': win.source,
                   'drift': _f(win.drift), 'amplitude_change': _f(win.amplitude_change),
                   'amplitude_signal': win.amplitude_signal, 'slice_s': _f(win.slice_s),
                   'slices': win.slices, 'criterion': win.criterion(), 'text': win.describe()},
        'topics': dict(sig.message_counts), 'shafts': {}, 'joints': {},
        'foreign_messages': dict(sig.foreign),
    }
    for j, name in enumerate(sig.joint_names):
        phi, w, tq = sig.position[mask, j], sig.velocity[mask, j], sig.effort[mask, j]
        # derivative over the whole record, then windowed: the same numbers as the run report
        acc = signal.time_derivative(sig.t, sig.velocity[:, j])[mask]
        entry: dict[str, Any] = {
            'mean_speed_rad_s': _f(np.mean(w)),
            'speed_nonuniformity': _f(signal.speed_nonuniformity(w)),
            'speed_amplitude_rad_s': _f(signal.half_range(w)),
            'acceleration_amplitude_rad_s2': _f(signal.half_range(acc)),
            'mean_torque_Nm': _f(np.mean(tq)),
            'torque_amplitude_Nm': _f(signal.half_range(tq)),
        }
        h, why = _try_harmonics(phi, tq, n_harmonics=n_harmonics, samples_per_rev=samples_per_rev)
        entry['torque_harmonics'] = _harmonics_dict(h) if h is not None else {'skipped': why}
        report['shafts'][name] = entry
    for joint, n_in, n_out in joint_pairs(sig.joint_names):
        i, o = sig.column(n_in), sig.column(n_out)
        nu = signal.joint_nonuniformity(sig.position[mask, i], sig.position[mask, o],
                                        sig.velocity[mask, i], sig.velocity[mask, o])
        report['joints'][joint] = {'nominal_ratio': _f(nu.nominal_ratio),
                                   'geometric_min_rad': _f(nu.geometric_min),
                                   'geometric_max_rad': _f(nu.geometric_max),
                                   'geometric_amplitude_rad': _f(nu.geometric_amplitude),
                                   'kinematic_min': _f(nu.kinematic_min),
                                   'kinematic_max': _f(nu.kinematic_max)}
    for key, tt, tq, shaft in (('engine', sig.engine_t, sig.engine_torque, engine_shaft(sig)),
                               ('load', sig.load_t, sig.load_torque, load_shaft(sig))):
        if not tt.size:
            continue
        m = tt >= t[0]
        if np.count_nonzero(m) < 2:
            continue
        entry = {'shaft': shaft, 'mean_torque_Nm': _f(np.mean(tq[m])),
                 'torque_amplitude_Nm': _f(signal.half_range(tq[m]))}
        j = sig.column(shaft)
        phi_at = np.interp(tt[m], sig.t, sig.position[:, j])
        h, why = _try_harmonics(phi_at, tq[m], n_harmonics=n_harmonics, samples_per_rev=samples_per_rev)
        entry['torque_harmonics'] = _harmonics_dict(h) if h is not None else {'skipped': why}
        report[key] = entry
    reactions = {}
    for joint, (tt, force, torque, frame) in sig.reactions.items():
        m = (tt >= t[0]) & (tt <= t[-1])
        if np.count_nonzero(m) < 2:
            continue
        reactions[joint] = {'frame_id': frame, 'samples': int(np.count_nonzero(m)),
                            'mean_force_N': [_f(v) for v in np.mean(force[m], axis=0)],
                            'force_amplitude_N': [_f(signal.half_range(force[m, k])) for k in range(3)],
                            'mean_torque_Nm': [_f(v) for v in np.mean(torque[m], axis=0)],
                            'torque_amplitude_Nm': [_f(signal.half_range(torque[m, k])) for k in range(3)]}
    if reactions:
        report['reactions'] = reactions
    report['lockstep'] = _lockstep_stats(sig)
    report['diagnostics'] = _diagnostic_figures(sig.diagnostics)
    modes = _mode_summary(sig.diagnostics)
    if modes:
        report['modes'] = modes
    report['scene'] = _scene_summary(sig.scene_yaml)
    if sig.gaps:   # the same figures as `cvj-sim run`'s report.json metrics.gaps
        report['gaps'] = dict(sig.gaps, ticks_skipped=ticks_skipped(sig.diagnostics))
    return report


def engine_shaft(sig: BagSignals) -> str:
    """Shaft the engine acts on: ``engine_crank`` if present, else the first joint-state name."""
    return 'engine_crank' if 'engine_crank' in sig.joint_names else sig.joint_names[0]


def load_shaft(sig: BagSignals) -> str:
    """Shaft the load acts on: ``wheel`` if present, else the last joint-state name."""
    return 'wheel' if 'wheel' in sig.joint_names else sig.joint_names[-1]


def _scene_summary(scene_yaml: str | None) -> dict[str, Any]:
    if scene_yaml is None:
        return {'present': False}
    import yaml
    out: dict[str, Any] = {'present': True, 'chars': len(scene_yaml)}
    try:
        data = yaml.safe_load(scene_yaml)
    except yaml.YAMLError as exc:
        out['parse_error'] = str(exc).splitlines()[0]
        return out
    if isinstance(data, dict):
        for key in ('name', 'seed', 'mode', 'coupling_scheme', 'exchange_step'):
            if key in data:
                out[key] = data[key]
        fid = data.get('fidelity')
        if isinstance(fid, dict) and isinstance(fid.get('choices'), list):   # FidelityReport.to_dict()
            out['fidelity'] = ' '.join(f"{c.get('name')}={c.get('chosen')}" for c in fid['choices']
                                       if isinstance(c, dict))
        elif isinstance(fid, dict):     # {'levels': {...}} or {name: level} (mode scenes)
            levels = fid.get('levels', fid)
            if isinstance(levels, dict) and levels:
                out['fidelity'] = ' '.join(f'{k}={v}' for k, v in levels.items())
        elif fid is not None:
            out['fidelity'] = fid
    return out


def analyze_bag(path: str | Path, **options: Any) -> dict[str, Any]:
    """Read a bag and analyse it: ``analyze_signals(read_bag_signals(path), **options)``."""
    return analyze_signals(read_bag_signals(path), **options)


def _fmt(x: Any, unit: str = '', digits: int = 4) -> str:
    if x is None:
        return 'n/a'
    return f'{x:.{digits}g}{unit}'


def foreign_line(foreign: dict[str, int]) -> str:
    """One line naming the messages left out as not the run's, per topic."""
    parts = ', '.join(f'{n} on {t}' for t, n in sorted(foreign.items()))
    return (f'left out as not the run\'s (other joint names, undecodable): {parts} '
            f'({sum(foreign.values())} messages)')


def format_report(report: dict[str, Any]) -> str:
    """Human-readable text of an :func:`analyze_signals` report."""
    w = report['window']
    lines = [f"bag: {report['bag']}",
             f"steady window: {_fmt(w['start_s'])} .. {_fmt(w['end_s'])} s "
             f"({w['samples']} samples, start transient {_fmt(w['skipped_s'])} s skipped)",
             f"  {w.get('text', '')}", f"  ({w.get('criterion', '')})", '',
             f"{'shaft':<22}{'mean w rad/s':>13}{'delta':>10}{'A_w rad/s':>11}"
             f"{'A_acc rad/s2':>13}{'mean T N m':>12}{'A_T N m':>10}"]
    if report.get('foreign_messages'):
        lines.insert(1, foreign_line(report['foreign_messages']))
    for name, s in report['shafts'].items():
        lines.append(f"{name:<22}{_fmt(s['mean_speed_rad_s']):>13}{_fmt(s['speed_nonuniformity']):>10}"
                     f"{_fmt(s['speed_amplitude_rad_s']):>11}{_fmt(s['acceleration_amplitude_rad_s2']):>13}"
                     f"{_fmt(s['mean_torque_Nm']):>12}{_fmt(s['torque_amplitude_Nm']):>10}")
    lines.append('')
    lines.append('torque harmonics over shaft angle, T = mean + sum A_k cos(k phi + p_k) '
                 '(A_k N m / p_k deg):')
    sources = [(n, s['torque_harmonics']) for n, s in report['shafts'].items()]
    sources += [(f'{k} wrench', report[k]['torque_harmonics']) for k in ('engine', 'load') if k in report]
    for name, h in sources:
        if 'skipped' in h:
            lines.append(f'  {name:<20} skipped: {h["skipped"]}')
            continue
        tiny = 1e-6 * max(1.0, abs(h['mean'] or 0.0))   # below this the phase is noise
        parts = ' '.join(f'{k}:{_fmt(a, digits=3)}/'
                         + (f'{math.degrees(p):.0f}' if a is not None and p is not None and a > tiny else '-')
                         for k, a, p in zip(h['orders'], h['amplitude'], h['phase_rad']))
        lines.append(f"  {name:<20} mean {_fmt(h['mean'])} over {h['revolutions']} rev  {parts}")
    if report['joints']:
        lines.append('')
        lines.append('joint nonuniformity (Bugaru & Vasile 2021): geometric phi_out - phi_in (rad), '
                     'kinematic w_out/w_in - 1:')
        for name, j in report['joints'].items():
            ratio = '' if j['nominal_ratio'] == 1.0 else f" (ratio {_fmt(j['nominal_ratio'])})"
            lines.append(f"  {name + ratio:<20} geometric {_fmt(j['geometric_min_rad'])} .. {_fmt(j['geometric_max_rad'])}"
                         f" (amplitude {_fmt(j['geometric_amplitude_rad'])})   kinematic "
                         f"{_fmt(j['kinematic_min'])} .. {_fmt(j['kinematic_max'])}")
    for key in ('engine', 'load'):
        if key in report:
            e = report[key]
            lines.append(f"{key} torque on {e['shaft']}: mean {_fmt(e['mean_torque_Nm'])} N m, "
                         f"amplitude {_fmt(e['torque_amplitude_Nm'])} N m")
    if report.get('reactions'):
        lines.append('')
        lines.append('reaction wrenches (housing frame), mean +/- amplitude per x, y, z: '
                     'force N, torque N m:')
        for joint, r in report['reactions'].items():
            f = ' '.join(f"{_fmt(a, digits=3)}+/-{_fmt(b, digits=2)}"
                         for a, b in zip(r['mean_force_N'], r['force_amplitude_N']))
            q = ' '.join(f"{_fmt(a, digits=3)}+/-{_fmt(b, digits=2)}"
                         for a, b in zip(r['mean_torque_Nm'], r['torque_amplitude_Nm']))
            lines.append(f'  {joint:<20} F {f}   T {q}')
    ls = report['lockstep']
    lines.append('')
    mode = report.get('scene', {}).get('mode') or 'lockstep'    # recorded by the coupling node
    lines.append(f"{mode}: {ls['steps']} steps over {_fmt(ls['duration_s'])} s, exchange step "
                 f"{_fmt(ls.get('exchange_step_s'))} s (min {_fmt(ls.get('exchange_step_min_s'))}, "
                 f"max {_fmt(ls.get('exchange_step_max_s'))}), stamps "
                 f"{'strictly increasing' if ls['stamps_strictly_increasing'] else 'NOT monotonic (%d)' % ls['non_increasing_stamps']}")
    for key in ('engine', 'load'):
        if f'{key}_echo_fraction' in ls:
            lines.append(f"  {key} answers: {ls[f'{key}_answers']}, echoing "
                         f"{100 * ls[f'{key}_echo_fraction']:.1f} % of joint-state stamps")
    if report.get('gaps'):   # `cvj-sim run`'s gaps line, when there is something to say
        from cvj_ros.orchestrate.gaps import gap_line
        line = gap_line(report['gaps'], int(report['gaps'].get('ticks_skipped', 0)))
        if line:
            lines.append(line)
    d = report['diagnostics']
    lev = d['levels']
    lines.append(f"diagnostics: {lev['ok']} OK, {lev['warn']} WARN, {lev['error']} ERROR")
    for key, fig in d['figures'].items():
        lines.append(f"  {key}: last {_fmt(fig['last'])}, mean {_fmt(fig['mean'])}, "
                     f"max |.| {_fmt(fig['max_abs'])} ({fig['count']} values)")
    if not any(_DIAG_PATTERNS['energy'].search(k) for k in d['figures']):
        lines.append('  energy residual: not recorded in this bag')
    for m in d['errors']:
        lines.append(f'  ERROR {m}')
    if report.get('modes'):
        md = report['modes']
        fin = md['final']
        lines.append(f"modes: {fin.get('mode_events', len(md['events']))} mode events; at the end "
                     + (', '.join(f'{k} {v}' for k, v in fin.items()
                                  if k not in ('mode_events', 'stall')) or 'not recorded'))
        if fin.get('stall'):
            lines.append(f"  {fin['stall']}")
        for e in md['events']:
            lines.append(f"  t = {_fmt(e['t_s'], digits=6)} s  {e['element']}: {e['before']} -> "
                         f"{e['after']} ({e['cause']})")
    sc = report['scene']
    lines.append('scene: ' + ('not recorded' if not sc['present'] else
                              ', '.join(f'{k}={v}' for k, v in sc.items() if k != 'present')))
    return '\n'.join(lines)
