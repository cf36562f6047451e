"""What a run reports: metrics read back from the bag, loop and identity counters, free-run
timing, monitor statuses, --fail-on, report.json and the printed report (shared by the
separate-process and the composed run)."""
from __future__ import annotations

import json
import math
import time
from dataclasses import asdict
from pathlib import Path
from typing import Any, TextIO

import numpy as np

from cvj_ros import bag as bagmod
from cvj_ros.errors import CvjError
from cvj_ros.orchestrate.options import RunOptions, RunResult, _Prepared


def result_from_recording(options: RunOptions, prep: _Prepared, out: Path, domain: int, *,
                          code: int, error: str | None, stopped_by: str | None,
                          counts: dict[str, int], rec_state: Any,
                          exit_codes: dict[str, int | None], phases: dict[str, float],
                          wall: float, steps: int) -> RunResult:
    """The RunResult of a finished run from the recorder's counts and first/last wall times
    per topic (``rec_state``): simulated span = (joint states - 1) x h, loop wall = first to
    last joint state, real-time factor = their ratio."""
    js = bagmod.JOINT_STATES_TOPIC
    loop_wall = wall_per_step = None
    if rec_state and js in rec_state[0] and counts.get(js, 0) > 1:
        loop_wall = rec_state[1][js] - rec_state[0][js]
        wall_per_step = loop_wall / (counts[js] - 1)
    sim_done = (counts.get(js, 1) - 1) * prep.exchange_step if counts.get(js) else 0.0
    return RunResult(
        exit_code=code, out=out, bag=out / 'bag', scene_path=str(prep.scene_path), domain_id=domain,
        sim_duration=sim_done, exchange_step=prep.exchange_step, steps_expected=steps,
        wall_time=wall, loop_wall_time=loop_wall, wall_per_step=wall_per_step,
        real_time_factor=sim_done / loop_wall if loop_wall else None,
        counts=counts, node_exit_codes=exit_codes, error=error, stopped_by=stopped_by,
        phases=phases, external=list(options.external))


def finish_result(result: RunResult, options: RunOptions, prep: _Prepared, *, stream: TextIO,
                  foreign_dropped: dict[str, int], malformed_dropped: dict[str, int] | None = None,
                  settings: dict[str, Any] | None = None) -> RunResult:
    """The tail of every run (separate processes or composed): metrics read back from the bag,
    loop counters, run identity, free-run timing, gaps in the record, monitor statuses, settings, --fail-on,
    report.json and the printed report."""
    loop_wall = result.loop_wall_time
    t_report = time.monotonic()
    n_msgs = sum(result.counts.values())
    print(f'cvj-sim run: bag closed ({n_msgs} messages); computing the report from it',
          file=stream, flush=True)
    # every figure below from the bag in two streaming passes (memory independent of the
    # run's length but 16 bytes per exchange: cvj_ros.orchestrate.report_stream); a bag
    # that cannot be streamed is read once into arrays (speeds and torques, no positions)
    from cvj_ros.orchestrate.report_stream import NotStreamable, stream_bag_metrics
    data: dict[str, Any] | None = None
    try:
        result.metrics, side = stream_bag_metrics(result.bag)
        diags, diags_read = side['diagnostics'], True
        data = {bagmod.SCENE_TOPIC: bagmod.TextSeries(np.zeros(1), [side['scene']], np.zeros(1))
                } if side['scene'] is not None else {}
    except (NotStreamable, CvjError, Exception):  # noqa: BLE001 (never lose the report to it)
        try:
            data = bagmod.read_bag(result.bag, None, columns=('velocity', 'effort'))
            result.metrics = bag_metrics(result.bag, data=data)
        except CvjError as exc:
            result.metrics = {'error': str(exc)}
        diags = data.get('/diagnostics') if data is not None else None
        diags_read = data is not None
    counters = loop_counters(result.bag, diags=diags)
    if counters:
        result.metrics['loop_counters'] = counters
    modes = loop_modes(result.bag, diags=diags)
    if modes:
        result.metrics['modes'] = modes
    if options.mode == 'lockstep':
        timing = loop_timing(result.bag, diags=diags)
        if timing:
            result.metrics['loop_timing'] = timing
    # messages the recorder dropped: not the run's publishers', or malformed (BagRecorder)
    result.metrics['run_identity'] = {'foreign_dropped': foreign_dropped,
                                      'malformed_dropped': dict(malformed_dropped or {})}
    if options.mode == 'free-run':
        timing = free_run_timing(result.bag, diags=diags)
        if timing:
            result.metrics['free_run'] = timing
            # skipped ticks advance simulated time without a joint state: the simulated
            # span is ticks handled x h, not (joint states - 1) x h
            if timing.get('ticks_handled'):
                result.sim_duration = timing['ticks_handled'] * prep.exchange_step
                if loop_wall:
                    result.real_time_factor = result.sim_duration / loop_wall
    try:   # missing sample times on the loop topics, starved steady-window slices
        from cvj_ros.orchestrate.gaps import run_gaps
        gaps = run_gaps(result.bag, prep.exchange_step, counts=result.counts)
    except (CvjError, Exception):  # noqa: BLE001 (never lose the report to it)
        gaps = {}
    if gaps:
        result.metrics['gaps'] = gaps
    if diags_read:
        result.metrics['monitor'] = monitor_statuses(result.bag, diags=diags)
    result.settings = {'seed': prep.seed if prep.seed is not None else prep.scene.seed,
                       'mode': options.mode, 'scheme': options.scheme,
                       'storage': options.storage, **(settings or {})}
    fid = _recorded_fidelity(result.bag, data=data)
    if fid:
        result.settings['fidelity'] = fid
    mon = result.metrics.get('monitor', {})
    if result.exit_code == 0 and (
            (options.fail_on == 'error' and mon.get('error')) or
            (options.fail_on == 'warn' and (mon.get('error') or mon.get('warn')))):
        result.exit_code = 1
        result.error = (f'monitor: {mon.get("error", 0)} ERROR and {mon.get("warn", 0)} WARN '
                        f'statuses (--fail-on {options.fail_on}); worst: {mon.get("worst")}')
    report_s = time.monotonic() - t_report
    if 'bag_closed' in result.phases:
        result.phases['report_done'] = round(result.phases['bag_closed'] + report_s, 4)
    result.wall_time += report_s        # the whole command, up to the printed report
    (result.out / 'report.json').write_text(json.dumps(_jsonable(asdict(result)), indent=2))
    print_report(result, stream)
    return result


def loop_ended_line(phases: dict[str, float]) -> str:
    """The progress line printed when the loop has ended (the phases after it follow)."""
    return (f'cvj-sim run: loop ended after {phases["coupling_exited"] - phases["loop_started"]:.2f} s; '
            'waiting for its last messages and closing the bag')


def command_started() -> float | None:
    """``time.monotonic()`` at the start of this process (Linux: /proc/self/stat's start time
    against /proc/uptime, 10 ms resolution), so a report's wall time covers the whole command,
    imports included; None where /proc is not there."""
    import os
    try:
        with open('/proc/self/stat', encoding='ascii') as fh:
            start_ticks = int(fh.read().rsplit(')', 1)[1].split()[19])
        with open('/proc/uptime', encoding='ascii') as fh:
            uptime = float(fh.read().split()[0])
        age = uptime - start_ticks / os.sysconf('SC_CLK_TCK')
    except (OSError, ValueError, IndexError):
        return None
    return time.monotonic() - max(age, 0.0)


def wall_line(r: RunResult) -> str:
    """The report's wall-time line: the whole command (to the printed report) and where it
    went - start-up (to the first recorded joint state), the loop, and the phases after it
    (waiting for the last messages, closing the bag, the report) from ``r.phases``."""
    ph = r.phases
    parts = []
    if 'loop_started' in ph:
        parts.append(f'start-up {ph["loop_started"]:.2f} s' + (
            f' (compiling the physics kernel {ph["kernel_compile_s"]:.2f} s)'
            if ph.get('kernel_compile_s') else ''))
    if r.loop_wall_time is not None:
        parts.append(f'loop {r.loop_wall_time:.3f} s')
    after = [(name, ph[b] - ph[a]) for name, a, b in (
        ('last messages', 'coupling_exited', 'drained'), ('closing the bag', 'drained', 'bag_closed'),
        ('report', 'bag_closed', 'report_done')) if a in ph and b in ph]
    if after and 'coupling_exited' in ph and 'report_done' in ph:
        parts.append(f'after the loop {ph["report_done"] - ph["coupling_exited"]:.2f} s ('
                     + ', '.join(f'{name} {v:.2f} s' for name, v in after) + ')')
    return f'  wall time {r.wall_time:.2f} s' + (': ' + ', '.join(parts) if parts else '')


def rate_line(r: RunResult) -> str:
    """The report's real-time factor line, with what it is computed on."""
    if not r.real_time_factor or r.loop_wall_time is None:
        return '  real-time factor n/a (fewer than two joint states recorded)'
    line = (f'  real-time factor {r.real_time_factor:.3g} = {r.sim_duration:.6g} s simulated / '
            f'{r.loop_wall_time:.3f} s of loop (first to last joint state recorded)')
    if r.wall_time > 0:
        line += f'; {r.sim_duration / r.wall_time:.3g} over the whole command'
    if r.wall_per_step:
        line += f'; wall per exchange step {r.wall_per_step * 1e6:.0f} us'
    return line


def _recorded_fidelity(bag: Path, *, data: dict[str, Any] | None = None) -> str | None:
    """'joint=level ...' from the recorded /driveline/scene message, if any (``data``: the
    bag already read)."""
    try:
        from cvj_ros.analysis import _scene_summary
        msgs = (data if data is not None else
                bagmod.read_bag(bag, [bagmod.SCENE_TOPIC])).get(bagmod.SCENE_TOPIC)
        text = msgs.data[0] if msgs is not None and getattr(msgs, 'data', None) else None
    except (CvjError, AttributeError, IndexError):
        return None
    return _scene_summary(text).get('fidelity') if text else None


def _jsonable(value: Any) -> Any:
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, Path):
        return str(value)
    if isinstance(value, (np.floating, np.integer)):
        return value.item()
    return value


def bag_metrics(bag: Path, *, transient: float | None = None,
                data: dict[str, Any] | None = None) -> dict[str, Any]:
    """Key metrics of a run bag over its steady window (:mod:`cvj_ros.physics.steady`, the
    definition ``simulate`` and ``analyze`` share: found by its criterion, or starting
    ``transient`` s after the first sample when given).

    ``window_s``: [start, end] (s); ``window``: the window's evidence
    (:meth:`SteadyWindow.to_dict`) and ``window_text`` its one-line description;
    ``shafts``: per JointState name ``mean_speed`` (rad/s), ``delta`` = speed nonuniformity
    (w_max - w_min)/w_mean (-, Davidbaev et al. 2023), ``speed_amplitude`` (rad/s),
    ``acceleration_amplitude`` (rad/s^2), ``mean_torque`` and ``torque_amplitude`` =
    (max - min)/2 (N m, Davidbaev et al. 2023, section 3.3.2) of the shaft torque; ``wrenches``: per
    WrenchStamped topic ``mean_torque`` and ``torque_amplitude`` of torque.z (N m) over the
    same time window; ``speed_trend``: the line naming a speed trend that dominates a shaft's
    max - min in the window (:func:`cvj_ros.physics.degenerate.trend_line`), else None.
    ``data``: the bag already read (:func:`cvj_ros.bag.read_bag`).
    """
    from cvj_ros.physics import metrics
    if data is None:
        data = bagmod.read_bag(bag, None, columns=('velocity', 'effort'))
    out: dict[str, Any] = {'shafts': {}, 'wrenches': {}}
    js = data.get(bagmod.JOINT_STATES_TOPIC)
    if js is None or js.t.size < 3:
        return out
    win = metrics.steady_window(js.t, js.names, js.velocity, js.effort, transient=transient)
    mask = win.mask(js.t)
    out['window_s'] = [float(js.t[mask][0]), float(js.t[mask][-1])]
    out['window'] = win.to_dict()
    out['window_text'] = win.describe()
    out['shafts'] = metrics.shaft_metrics(js.t, js.names, js.velocity, js.effort, window=win)
    from cvj_ros.physics.degenerate import trend_line
    out['speed_trend'] = trend_line(js.t[mask], {n: js.velocity[mask, i] for i, n in enumerate(js.names)})
    for topic, series in data.items():
        if isinstance(series, bagmod.WrenchSeries) and series.t.size >= 3:
            m = (series.t >= out['window_s'][0]) & (series.t <= out['window_s'][1])
            if np.count_nonzero(m) < 2:
                continue
            tz = series.torque_z[m]
            out['wrenches'][topic] = {'mean_torque': float(np.mean(tz)),
                                      'torque_amplitude': metrics.amplitude(tz)}
    return out


LOOP_COUNTERS = ('ignored_stamps', 'rejected_torques', 'held_torques')
# boundary: answers the coupling node dropped as malformed (cvj_ros.nodes.malformed)
IDENTITY_COUNTERS = ('malformed_messages',)


#: ``diags`` not given: the functions below read the bag's /diagnostics themselves
_READ = object()


def read_diagnostics(bag: Path) -> Any:
    """The bag's /diagnostics series (bag.DiagnosticsSeries), or None when it has none: read
    once by :func:`finish_result` for every figure below (one read of a 5 s run's bag costs
    ~0.1 s)."""
    return bagmod.read_bag(bag, ['/diagnostics']).get('/diagnostics')


def _last_loop_values(bag: Path, diags: Any, key: str | None = None) -> dict[str, str] | None:
    """The values of the coupling node's last ``coupling_node: loop`` status (the last one
    holding ``key``, if given) on /diagnostics; None when there is none."""
    if diags is _READ:
        diags = read_diagnostics(bag)
    if diags is None:
        return None
    for statuses in reversed(diags.statuses):
        for st in statuses:
            if st['name'] == 'coupling_node: loop' and (key is None or key in st['values']):
                return st['values']
    return None


def loop_counters(bag: Path, *, diags: Any = _READ) -> dict[str, int]:
    """The coupling node's last recorded counters (``/diagnostics`` status ``coupling_node:
    loop``): ignored stamps, rejected and held (``nonfinite_torque=hold``) torques.
    ``diags``: the bag's /diagnostics already read (:func:`read_diagnostics`)."""
    vals = _last_loop_values(bag, diags)
    if vals is None:
        return {}
    return {k: int(float(vals[k])) for k in LOOP_COUNTERS + IDENTITY_COUNTERS if k in vals}


#: prefixes of the mode-model values in the loop diagnostics (cvj_ros.nodes.hybrid_backend)
MODE_PREFIXES = ('clutch_state.', 'gear.', 'brake_state.')
MODE_KEYS = ('mode_events', 'refused_commands', 'last_refused', 'stall')


def loop_modes(bag: Path, *, diags: Any = _READ) -> dict[str, str]:
    """A mode scene's last recorded modes (engaged gear, clutch and brake slip+ / stuck /
    slip-), its mode-event and refused-command counts, the last refused command and the stall
    line, from the coupling node's last loop status; {} for other scenes."""
    if diags is _READ:
        diags = read_diagnostics(bag)
    if diags is None:
        return {}
    vals, last = None, (-1.0, False)
    for statuses in diags.statuses:   # the latest by step (a DDS copy may come late in bag order)
        for st in statuses:
            v = st['values']
            if st['name'] == 'coupling_node: loop' and 'mode_events' in v:
                key = (float(v.get('steps', 0)), st['message'] == 'finished')
                if key >= last:
                    vals, last = v, key
    if vals is None:
        return {}
    return {k: v for k, v in vals.items() if k.startswith(MODE_PREFIXES) or k in MODE_KEYS}


def modes_line(modes: dict[str, str]) -> str:
    """``  modes at the end: clutch stuck, gearbox gear 3, brake slip+; 14 mode events``
    (then the refused commands and the stall, when there are)."""
    parts = []
    for k, v in modes.items():
        if k.startswith(MODE_PREFIXES):
            name = k.split('.', 1)[1]
            parts.append(f'{name} gear {v}' if k.startswith('gear.') else f'{name} {v}')
    line = f'  modes at the end: {", ".join(parts)}; {modes.get("mode_events", 0)} mode events'
    if modes.get('refused_commands', '0') not in ('0', ''):
        line += f'; {modes["refused_commands"]} commands refused (last: {modes.get("last_refused", "-")})'
    if modes.get('stall'):
        line += f'\n  STALL {modes["stall"]}'
    return line


#: the coupling node's per-exchange figures (us, means since step 0) in its loop diagnostics
LOOP_TIMING_KEYS = ('exchange_wall_us_mean', 'integration_us_mean', 'overhead_us_mean',
                    'lockstep_wait_us_mean', 'state_us_mean')
#: the development targets of a lockstep run's real-time factor at 1 ms exchange steps, per
#: process layout: `cvj-sim bench` states them, the run report does not
REAL_TIME_TARGETS = {'composed': 10.0, 'separate': 2.0}


def loop_timing(bag: Path, *, diags: Any = _READ) -> dict[str, float]:
    """Per-exchange wall, integration, overhead (wall - integration), lockstep wait and
    state evaluation + publication (us) of the coupling node's last recorded loop
    diagnostics; empty when not recorded."""
    vals = _last_loop_values(bag, diags, 'overhead_us_mean')
    out: dict[str, float] = {}
    for key in LOOP_TIMING_KEYS if vals is not None else ():
        try:
            out[key] = float(vals[key])
        except (KeyError, ValueError):
            pass
    return out


def loop_line(r: RunResult) -> str | None:
    """The report's per-exchange line of a lockstep run: where the wall time of an exchange
    goes (means over the run, from the coupling node's loop diagnostics); None without them.
    Facts only: the development targets of :data:`REAL_TIME_TARGETS` are `cvj-sim bench`'s."""
    t = r.metrics.get('loop_timing') or {}
    if 'overhead_us_mean' not in t or r.settings.get('mode') != 'lockstep':
        return None
    return (f'  loop per exchange: wall {t.get("exchange_wall_us_mean", math.nan):.0f} us = integration '
            f'{t.get("integration_us_mean", math.nan):.0f} us + overhead {t["overhead_us_mean"]:.0f} us '
            f'(lockstep wait {t.get("lockstep_wait_us_mean", math.nan):.0f} us, state evaluation + '
            f'publication {t.get("state_us_mean", math.nan):.0f} us)')


FREE_RUN_KEYS = ('catch_up', 'ticks_handled', 'ticks_run', 'ticks_skipped', 'overruns',
                 'lateness_us_p50', 'lateness_us_p99', 'lateness_us_max', 'lateness_us_mean',
                 'drift_s', 'drift_max_s', 'realtime_priority')


def free_run_line(fr: dict[str, Any]) -> str:
    """The report's one free-run line: ticks run and skipped (with the skipped share: each
    run tick after a skip integrates the skipped interval with its torques held, so a large
    share means the run is not the scene's at this exchange step), overruns, lateness and
    drift."""
    rt = f', SCHED_FIFO {fr["realtime_priority"]}' if fr.get('realtime_priority') else ''
    run, skipped = int(fr.get('ticks_run', 0)), int(fr.get('ticks_skipped', 0))
    share = f' ({100.0 * skipped / (run + skipped):.1f} % of the ticks)' if skipped else ''
    return (f'  free-run (catch-up {fr.get("catch_up")}{rt}): {run} ticks run, '
            f'{skipped} skipped{share}, {fr.get("overruns", 0)} overruns (late by >= 1 step); '
            f'lateness p50 {fr.get("lateness_us_p50", 0):.0f} us, p99 {fr.get("lateness_us_p99", 0):.0f} us, '
            f'max {fr.get("lateness_us_max", 0):.0f} us; drift {1e3 * fr.get("drift_s", 0):.3f} ms '
            f'(max {1e3 * fr.get("drift_max_s", 0):.3f} ms)')


def free_run_timing(bag: Path, *, diags: Any = _READ) -> dict[str, Any]:
    """Free-run deadline figures of the coupling node's last recorded loop diagnostics:
    catch-up policy, ticks run/skipped, overruns (ticks late by >= one exchange step),
    lateness p50/p99/max/mean (us), drift (s; wall time since start - simulated time at the
    last publication, and its largest magnitude); empty when not recorded."""
    vals = _last_loop_values(bag, diags, 'overruns')
    if vals is None:
        return {}
    return {k: (vals[k] if k == 'catch_up' else
                int(float(vals[k])) if k.startswith(('ticks', 'overruns', 'realtime'))
                else float(vals[k]))
            for k in FREE_RUN_KEYS if k in vals}


def monitor_statuses(bag: Path, *, diags: Any = _READ) -> dict[str, Any]:
    """WARN and ERROR statuses recorded on /diagnostics (every node but the coupling loop's
    counters, reported on their own): counts, the first of each level and the first of the
    worst level seen, each as 't = T s NAME: MESSAGE'."""
    if diags is _READ:
        diags = read_diagnostics(bag)
    out: dict[str, Any] = {'warn': 0, 'error': 0}
    if diags is None:
        return out
    for t, statuses in zip(diags.t, diags.statuses):
        for st in statuses:
            level = int(st['level'])
            if st['name'] == 'coupling_node: loop' or level not in (1, 2):
                continue
            key = 'warn' if level == 1 else 'error'
            out[key] += 1
            out.setdefault(f'first_{key}', f't = {float(t):.6g} s {st["name"]}: '
                                           f'{st["message"] or st["values"]}')
    worst = 'error' if out['error'] else ('warn' if out['warn'] else None)
    if worst:
        out['worst'] = f'{worst.upper()} ' + out[f'first_{worst}']
    return out


def print_report(r: RunResult, stream: TextIO) -> None:
    """The short human report of a run."""
    p = lambda s='': print(s, file=stream)  # noqa: E731
    status = 'finished' if r.exit_code == 0 else (f'stopped by {r.stopped_by}' if r.stopped_by else 'FAILED')
    p(f'cvj-sim run: {status}  scene={r.scene_path}  domain={r.domain_id}'
      + (f'  external={",".join(r.external)}' if r.external else ''))
    if r.error:
        p(f'  error: {r.error}')
    p(f'  simulated {r.sim_duration:.6g} s in {max(0, r.counts.get(bagmod.JOINT_STATES_TOPIC, 0) - 1)} exchange steps '
      f'of {r.exchange_step:.6g} s (expected {r.steps_expected})')
    p(wall_line(r))
    p(rate_line(r))
    line = loop_line(r)
    if line:
        p(line)
    shafts = r.metrics.get('shafts', {})
    if shafts:
        p(f'  steady window {r.metrics.get("window_text", "")}:')
        if 'window' in r.metrics:
            p(f'    ({r.metrics["window"]["criterion"]})')
        p(f'    {"shaft":24s} {"mean speed rad/s":>16s} {"nonuniformity":>14s} {"torque ampl N m":>16s}')
        for name, m in shafts.items():
            p(f'    {name:24s} {m["mean_speed"]:16.4f} {m["delta"]:14.3e} {m["torque_amplitude"]:16.4f}')
    for topic, m in r.metrics.get('wrenches', {}).items():
        p(f'    {topic:24s} mean torque {m["mean_torque"]:.4f} N m, amplitude {m["torque_amplitude"]:.4f} N m')
    if 'error' in r.metrics:
        p(f'  metrics: {r.metrics["error"]}')
    identity = r.metrics.get('run_identity', {})
    malformed = r.metrics.get('loop_counters', {}).get('malformed_messages', 0)
    dropped = identity.get('foreign_dropped', {})
    bad = identity.get('malformed_dropped', {})
    if malformed or dropped or bad:
        p(f'  outside the run: the recorder dropped {sum(dropped.values())} messages of other '
          f'publishers ({", ".join(f"{t} {n}" for t, n in sorted(dropped.items())) or "none"}) '
          f'and {sum(bad.values())} malformed ones; the loop dropped {malformed} malformed answers')
    if r.metrics.get('modes'):
        p(modes_line(r.metrics['modes']))
    counters = {k: v for k, v in r.metrics.get('loop_counters', {}).items() if k in LOOP_COUNTERS}
    if any(counters.values()):   # WARN level in /diagnostics: say it in the report too
        p('  WARN coupling loop: ' + ', '.join(f'{k.replace("_", " ")} {v}' for k, v in counters.items())
          + (' (non-finite answers replaced by the last finite torque, --nonfinite-torque hold)'
             if counters.get('held_torques') else ''))
    fr = r.metrics.get('free_run', {})
    if fr:
        p(free_run_line(fr))
    from cvj_ros.orchestrate.gaps import gap_line
    line = gap_line(r.metrics.get('gaps', {}), int(fr.get('ticks_skipped', 0)))
    if line:
        p(line)
    mon = r.metrics.get('monitor', {})
    if mon.get('warn') or mon.get('error'):
        p(f'  monitor: {mon.get("error", 0)} ERROR and {mon.get("warn", 0)} WARN statuses; '
          f'worst: {mon.get("worst")}')
        for key in ('first_error', 'first_warn'):
            if key in mon:
                p(f'    first {key[6:].upper()}: {mon[key]}')
    if r.settings:
        p('  settings: ' + ', '.join(f'{k} {v}' for k, v in r.settings.items()))
    p('  messages: ' + ', '.join(f'{t} {n}' for t, n in sorted(r.counts.items())))
    p(f'  bag: {r.bag}')
