"""`cvj-sim simulate SCENE`: offline closed-loop run of a scene (no ROS), printed summary."""
from __future__ import annotations

import argparse
import json
import math
from typing import Any

from cvj_ros.errors import SceneError

NAME = 'simulate'
# every file (CSV, bag, plots) is closed when run() returns: as a program, skip the
# interpreter's teardown (cli.exit_without_teardown, ~0.15-0.2 s of numba objects)
EXIT_WITHOUT_TEARDOWN = True
HELP = 'run a scene offline (engine and load in the loop, no ROS) and print a summary'
DESCRIPTION = """Integrate a scene offline with one persistent solver (engine and load inside the
right-hand side) and print: mean speed, nonuniformity delta and torque amplitude per shaft
over the steady window (docs/scenes.md "Steady window": the slices of the run that agree
with its last slice in mean speed and amplitudes; --transient sets the start instead;
the window and the criterion's verdict are printed), the energy-balance residual, solver counters, wall time per simulated second and the fidelity report.
On a terminal, stderr shows a progress line (simulated time, real-time factor, ETA) at
most once a second; nothing when stderr is not a terminal.

examples:
  cvj-sim simulate kavz685_lever
  cvj-sim simulate fwd_halfshaft --duration 1 --fidelity tripod=exact rzeppa=exact
  cvj-sim simulate stiff --method rosenbrock --rtol 1e-8 --json
  cvj-sim simulate my_scene.yaml --csv run.csv
  cvj-sim simulate kavz685_lever --plots runs/kavz_offline/plots
  cvj-sim simulate fwd_halfshaft --bag runs/offline/bag   # then: cvj-sim analyze runs/offline/bag
"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('scene', help='shipped scene name (see `cvj-sim scenes`) or YAML path')
    parser.add_argument('--duration', type=float, help='simulated seconds (default: the scene\'s)')
    parser.add_argument('--sample-dt', type=float, help='sample period, s (default: scene exchange_step)')
    parser.add_argument('--method', help='solver: dopri5, dop853, rosenbrock, rodas4, rodas3, rk4, ros2, tsit5, vern6, vern7, vern8 (default: scene)')
    parser.add_argument('--rtol', type=float, help='relative tolerance (default: scene)')
    parser.add_argument('--atol', type=float, help='absolute tolerance (default: scene)')
    parser.add_argument('--fidelity', nargs='+', default=[], metavar='NAME=LEVEL',
                        help='force fidelity: joint=ideal|closed|exact, spring=elastic|rigid')
    parser.add_argument('--dense', action='store_true',
                        help='sample from the dense output (free steps) instead of landing on samples')
    parser.add_argument('--transient', type=float, help='seconds skipped before the metrics window')
    parser.add_argument('--csv', metavar='FILE', help='write the sampled trace as CSV')
    parser.add_argument('--plots', metavar='DIR',
                        help='write the PNG figures of `cvj-sim analyze --plots` for this run '
                             '(speeds_torques, nonuniformity, harmonics) to DIR; a scene with '
                             'clutch, gearbox, brake or commands: mode_speeds.png (speeds, gear, '
                             'events)')
    parser.add_argument('--no-internal-members', action='store_true',
                        help="leave the joints' internal members (Rzeppa cage, tripod spider, lever-hinge "
                             "earring: no line torque) out of speeds_torques.png of --plots")
    parser.add_argument('--bag', metavar='DIR',
                        help='write the sampled trace as a rosbag2 bag (joint states, engine and load '
                             'wrench, scene) that `cvj-sim analyze` reads; a scene with clutch, '
                             'gearbox, brake or commands: speeds, commands, mode events on '
                             '/diagnostics')
    parser.add_argument('--overwrite', action='store_true', help='replace an existing --bag directory')
    parser.add_argument('--json', action='store_true', help='print the summary as JSON')
    parser.add_argument('--backend', choices=('kernel', 'python'), default='kernel',
                        help='kernel: compiled (default; an element it does not cover falls back '
                             'to python with one line on stderr); python: the reference rhs')


def parse_fidelity(items: list[str]) -> dict[str, str]:
    """['tripod=exact', ...] -> {'tripod': 'exact'}; SceneError('fidelity', ...) if malformed."""
    out: dict[str, str] = {}
    for item in items:
        name, sep, level = item.partition('=')
        if not sep or not name or not level:
            raise SceneError('--fidelity', f'expected NAME=LEVEL, got {item!r}')
        out[name] = level
    return out


def format_summary(summary: dict) -> str:
    """Human-readable summary text."""
    lines = [f"scene {summary['scene']}: {summary['duration']:g} s simulated, "
             f"wall {summary['wall_time']:.3f} s ({summary['wall_per_sim_second']:.4g} s per simulated s)"
             + (f", including {summary['compile_seconds']:.1f} s compiling the kernel (first run)"
                if summary.get('compile_seconds') else '')]
    sol = summary['solver']
    lines.append(f"solver {sol['method']} rtol {sol['rtol']:g} atol {sol['atol']:g}: "
                 f"{sol.get('naccept', 0)} steps, {sol.get('nreject', 0)} rejected, "
                 f"{sol.get('nfev', 0)} rhs evaluations, {sol.get('njev', 0)} Jacobians")
    fallback = sol.get('backend_fallback')
    lines.append(f"backend {sol.get('backend', 'python')}" + (f" ({fallback})" if fallback else ''))
    lines.append(f"energy balance residual {summary['energy_residual']:.3e} (relative)")
    if 'window_text' in summary:
        lines.append(f"steady window {summary['window_text']}")
        lines.append(f"  ({summary['window']['criterion']})")
    # delta: speed nonuniformity (w_max - w_min)/w_mean, a ratio (kinematics prints the
    # angle deviation in rad instead)
    lines.append(f"{'shaft':<24}{'mean rad/s':>12}{'speed nonu':>11}{'A_speed':>11}{'A_accel':>11}"
                 f"{'mean N m':>11}{'A_torque':>11}")
    for name, m in summary['shafts'].items():
        lines.append(f"{name:<24}{m['mean_speed']:>12.5g}{m['delta']:>11.3e}{m['speed_amplitude']:>11.4g}"
                     f"{m['acceleration_amplitude']:>11.4g}{m['mean_torque']:>11.5g}{m['torque_amplitude']:>11.4g}")
    veh = summary.get('vehicle')
    if veh:
        lines.append(f"vehicle speed {veh['speed_start_kmh']:.4g} -> {veh['speed_end_kmh']:.4g} km/h")
        lines.append(f"{'wheel':<24}{'slip (end)':>12}{'mean F_x N':>12}{'mean F_z N':>12}{'no-load samples':>17}")
        for name, w in veh['wheels'].items():
            lines.append(f"{name:<24}{w['slip_end']:>12.4g}{w['fx_mean']:>12.5g}{w['fz_mean']:>12.5g}"
                         f"{w['no_load_samples']:>17d}")
    lines.append(summary['fidelity_text'])
    lines.extend(f'note: {n}' for n in summary.get('notes', ()))
    return '\n'.join(lines)


def degenerate_notes(scene: Any, sim: Any, summary: dict, trace: Any) -> list[str]:
    """The lines of :mod:`cvj_ros.physics.degenerate` for this offline run: joints beyond
    their angle limits (as the ROS monitor says them), a sample step too coarse for the
    fastest mode, a stall."""
    from cvj_ros.physics import degenerate as dg
    notes = dg.angle_limit_lines(scene)
    if len(trace.t) > 1:
        try:
            mode = dg.fastest_mode(sim.driveline)
        except Exception:   # noqa: BLE001 (a note, never a failure of the run)
            mode = None
        line = dg.coarse_step_line(float(trace.t[1] - trace.t[0]), mode, 'sample step')
        if line:
            notes.append(line)
    stall = dg.stall_line({n: float(m['mean_speed']) for n, m in summary.get('shafts', {}).items()},
                          float(scene.initial_speed))
    if stall:
        notes.append(stall)
    else:
        window = summary.get('window') or {}
        if 'start_s' in window and len(trace.t):
            import numpy as np
            m = (trace.t >= window['start_s']) & (trace.t <= window['end_s'])
            trend = dg.trend_line(trace.t[m], {n: trace.velocity[m, i] for i, n in enumerate(trace.names)
                                              if n in summary.get('shafts', {})})
            if trend:
                notes.append(trend)
    return notes


def _physical_memory() -> int | None:
    """Bytes of RAM of this machine (sysconf), or None where the platform does not say."""
    import os
    try:
        return int(os.sysconf('SC_PAGE_SIZE')) * int(os.sysconf('SC_PHYS_PAGES'))
    except (AttributeError, ValueError, OSError):
        return None


KNOT_BYTES = 16.0       # a random load's knot in a run: packed array + the run's copy


def check_run_size(scene: Any, duration: float | None, sample_dt: float | None,
                   memory: int | None = None) -> None:
    """SceneError when an offline run of ``scene`` cannot fit in the machine's memory: its
    trace holds at least 24 bytes per sample (time, one angle, one speed as float64) and a
    seeded random load 16 bytes per knot over the run's duration (knots every
    ``sample_interval``: the packed model's float64 array, kept, and each run's copy of
    it, Simulation._model); a lower bound above the physical RAM (``memory``, default
    sysconf) names the field instead of a MemoryError deep in numpy."""
    memory = _physical_memory() if memory is None else memory
    if not memory:
        return
    dur = scene.duration if duration is None else duration
    dt = sample_dt or scene.sample_step or scene.exchange_step
    samples = dur / dt + 1.0
    where = '--duration' if duration is not None else 'duration'
    if 24.0 * samples > memory:
        step = '--sample-dt' if sample_dt else ('sample_step' if scene.sample_step else 'exchange_step')
        raise SceneError(f'{where} / {step}', f'{dur:g} s in samples of {dt:g} s are {samples:.3g} '
                                              f'samples, at least {24.0 * samples / 2**30:.3g} GiB; '
                                              f'this machine has {memory / 2**30:.3g} GiB')
    specs = scene.load if isinstance(scene.load, (list, tuple)) else [scene.load]
    for i, spec in enumerate(specs):
        if not hasattr(spec, 'get') or spec.get('model') != 'random':
            continue
        knot_dt = float(spec.get('sample_interval', 0.01))
        knots = dur / knot_dt
        if KNOT_BYTES * knots > memory:
            field = 'load.sample_interval' if len(specs) == 1 else f'load[{i}].sample_interval'
            raise SceneError(f'{where} / {field}',
                             f'a random load over {dur:g} s in knots of {knot_dt:g} s needs '
                             f'{knots:.3g} knots, at least {KNOT_BYTES * knots / 2**30:.3g} GiB; this '
                             f'machine has {memory / 2**30:.3g} GiB: shorten duration or lengthen '
                             'sample_interval')


def run(args: argparse.Namespace) -> int:
    from cvj_ros.physics.scene import find_scene, load_scene
    from cvj_ros.physics.simulate import Simulation
    for opt in ('duration', 'sample_dt', 'rtol', 'atol', 'transient'):
        v = getattr(args, opt)
        if v is not None and not (math.isfinite(v) and (v > 0 or (opt == 'transient' and v >= 0))):
            raise SceneError(f'--{opt.replace("_", "-")}', f'must be > 0, got {v}')
    if args.method is not None:
        from cvj_ros.physics.scene import OFFLINE_METHODS
        if args.method not in OFFLINE_METHODS:
            raise SceneError('--method', f'must be one of {", ".join(OFFLINE_METHODS)}, got {args.method!r}')
    scene = load_scene(find_scene(args.scene))
    check_run_size(scene, args.duration, args.sample_dt)
    if scene.has_modes:
        return _run_modes(scene, args)
    sim = Simulation(scene, method=args.method, rtol=args.rtol, atol=args.atol,
                     fidelity=parse_fidelity(args.fidelity), backend=args.backend)
    import sys
    if sim.backend_note:
        print(f'cvj-sim simulate: {sim.backend_note}', file=sys.stderr)
    from cvj_ros.progress import Progress
    # progress line on stderr, only on a terminal (stdout keeps the summary / JSON)
    progress = Progress(scene.duration if args.duration is None else args.duration,
                        label='cvj-sim simulate')
    try:
        # no callback when no line can show: the kernel then lands on all samples in one
        # compiled call instead of one call per sample (same bytes, test_backends.py)
        trace = sim.run(args.duration, sample_dt=args.sample_dt,
                        sampling='dense' if args.dense else 'land',
                        progress=progress.update if progress.enabled else None)
    finally:
        progress.close()
    if sim.compile_seconds:
        print(f'cvj-sim simulate: compiled the kernel in {sim.compile_seconds:.1f} s (first run; '
              f'cached in {sim.cache_path} for later runs)', file=sys.stderr)
    summary = sim.summary(transient=args.transient)
    if sim.compile_seconds:   # inside the run's wall time: said on the summary's first line
        summary['compile_seconds'] = float(sim.compile_seconds)
    summary['notes'] = degenerate_notes(scene, sim, summary, trace)
    if args.csv:
        trace.to_csv(args.csv)
    if args.plots:
        summary['plots'] = [str(p) for p in _write_plots(sim, trace, args)]
    if args.bag:
        from cvj_ros.trace_bag import scene_message, write_trace_bag
        text = scene_message(scene, sim.fidelity_report.to_dict(), solver=summary['solver'],
                             duration=float(trace.t[-1]), names=list(trace.names),
                             sample_dt=float(trace.t[1] - trace.t[0]) if len(trace.t) > 1 else 0.0)
        counts = write_trace_bag(trace, args.bag, scene_yaml=text, overwrite=args.overwrite)
        print(f'cvj-sim simulate: wrote {counts.get("/driveline/joint_states", 0)} samples to bag '
              f'{args.bag}', file=sys.stderr)
    if args.json:
        print(json.dumps(summary, indent=1))
    else:
        summary['fidelity_text'] = str(sim.fidelity_report)
        print(format_summary(summary))
    return 0


def _run_modes(scene: Any, args: argparse.Namespace) -> int:
    """A scene with clutch, gearbox, brake or commands: stick/slip modes with events
    (docs/clutch_gearbox.md) on the compiled kernel (every method with dense output;
    ``--backend python`` runs the Python reference); prints events per element."""
    import sys
    import time

    from cvj_ros.physics.hybrid.from_scene import (format_hybrid_summary, hybrid_simulation,
                                                   hybrid_summary)
    if args.dense:
        raise SceneError('--dense', 'not available for a scene with clutch, gearbox, brake or '
                                    'commands (its samples come from the dense output already)')
    from pathlib import Path
    if args.bag and not args.overwrite and Path(args.bag).exists():    # before the run, not after
        raise SceneError('--bag', f'{args.bag} exists (use --overwrite to replace it)')
    from cvj_ros.physics.hybrid.scene_keys import DENSE_METHODS
    if args.method is not None and args.method not in DENSE_METHODS:
        raise SceneError('--method', f'a scene with clutch, gearbox, brake or commands needs one of '
                                     f'{", ".join(DENSE_METHODS)} (dense output), got {args.method!r}')
    from cvj_ros.physics.simulate import scene_explicit_step_check
    scene_explicit_step_check(scene, args.method or scene.solver.method,
                              scene.duration if args.duration is None else args.duration,
                              overrides=parse_fidelity(args.fidelity))
    sim = hybrid_simulation(scene, method=args.method, rtol=args.rtol, atol=args.atol,
                            fidelity=parse_fidelity(args.fidelity), duration=args.duration,
                            sample_dt=args.sample_dt)
    note = ''
    backend = 'python'
    if args.backend == 'kernel' and scene.is_tree:
        from cvj_ros.physics.kernel.tree_modes import (KERNEL_TREE_MODE_METHODS,
                                                       KernelHybridTreeSimulation)
        if sim.method in KERNEL_TREE_MODE_METHODS:
            try:
                sim = KernelHybridTreeSimulation.from_reference(sim)
                backend = 'kernel'
            except NotImplementedError as exc:
                note = f'{exc}; running the Python reference'
        else:
            note = (f'compiled kernel: mode scenes run with {", ".join(KERNEL_TREE_MODE_METHODS)}, '
                    f'not {sim.method}; running the Python reference')
        if note:
            print(f'cvj-sim simulate: {note}', file=sys.stderr)
    elif args.backend == 'kernel':
        from cvj_ros.physics.kernel.modes import KERNEL_MODE_METHODS, KernelHybridSimulation
        if sim.method in KERNEL_MODE_METHODS:
            sim = KernelHybridSimulation.from_reference(sim)
            backend = 'kernel'
        else:
            note = (f'compiled kernel: mode scenes run with {", ".join(KERNEL_MODE_METHODS)}, '
                    f'not {sim.method}; running the Python reference')
            print(f'cvj-sim simulate: {note}', file=sys.stderr)
    sim.joint_samples = bool(args.bag)      # positions and efforts for the bag's joint states
    t0 = time.perf_counter()
    result = sim.run()
    wall = time.perf_counter() - t0
    summary = hybrid_summary(scene, sim, result, wall, note)
    summary['solver']['backend'] = backend
    if result.stall:
        print(f'cvj-sim simulate: {result.stall}', file=sys.stderr)
    if args.csv:
        import numpy as np
        cols = ['t_s'] + [f'{n}_velocity_rad_s' for n in result.shafts] + ['gear', 'energy_residual']
        data = np.column_stack([result.t, result.speed, result.gear, result.energy_residual])
        np.savetxt(args.csv, data, delimiter=',', header=','.join(cols), comments='')
    if args.plots:
        from cvj_ros.mode_outputs import write_mode_plots
        summary['plots'] = [str(p) for p in write_mode_plots(scene, result, args.plots)]
        for p in summary['plots']:
            print(f'cvj-sim simulate: wrote {p}', file=sys.stderr)
    if args.bag:
        import yaml

        from cvj_ros.mode_outputs import write_mode_bag
        text = yaml.safe_dump({'scene': scene.to_dict(), 'seed': scene.seed, 'mode': 'offline',
                               'duration': float(result.t_end), 'commands': 'offline',
                               'solver': {k: summary['solver'].get(k)
                                          for k in ('method', 'rtol', 'atol', 'backend')},
                               'shaft_names': list(result.shafts)}, sort_keys=False)
        counts = write_mode_bag(scene, result, summary, args.bag, scene_yaml=text,
                                overwrite=args.overwrite)
        print(f'cvj-sim simulate: wrote {counts.get("/driveline/joint_states", 0)} samples, '
              f'{len(result.events)} mode events and the commands to bag {args.bag}', file=sys.stderr)
    if args.json:
        print(json.dumps(summary, indent=1))
    else:
        print(format_hybrid_summary(summary))
    return 0


def _write_plots(sim: Any, trace: Any, args: argparse.Namespace) -> list[Any]:
    """The analysis figures of an offline trace (same window rule as ``cvj-sim analyze``:
    ``--transient`` seconds skipped, else its default); stderr names each file."""
    import sys

    import yaml

    from cvj_ros.analysis import analyze_signals
    from cvj_ros.plots import signals_from_trace, write_analysis_plots
    scene = sim.scene.to_dict()
    scene['solver'] = {**scene.get('solver', {}), 'method': sim.method, 'rtol': sim.rtol, 'atol': sim.atol}
    scene['fidelity'] = sim.fidelity_report.to_dict()
    sig = signals_from_trace(trace, scene_yaml=yaml.safe_dump(scene, sort_keys=False),
                             label=f'simulate {sim.scene.name}')
    report = analyze_signals(sig, skip_s=args.transient)
    paths = write_analysis_plots(sig, report, args.plots, internal=not args.no_internal_members)
    for p in paths:
        print(f'cvj-sim simulate: wrote {p}', file=sys.stderr)
    return paths
