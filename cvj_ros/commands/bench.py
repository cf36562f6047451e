"""`cvj-sim bench`: work-precision benchmark against scipy's solve_ivp (see :mod:`cvj_ros.bench`)."""
from __future__ import annotations

import argparse
import dataclasses
import math
import sys

from cvj_ros.errors import SceneError

NAME = 'bench'
HELP = 'work-precision benchmark: project solvers and fidelities vs solve_ivp, lockstep loop'
DESCRIPTION = """\
For each reference scene, solver (dopri5, dop853, rosenbrock, rodas4, rodas3, tsit5, vern6,
vern7, vern8, rk4 fixed step), tolerance
and fidelity (ideal/closed/exact, the fidelity chooser's pick 'auto', and 'rigid': exact
joints with every spring rigid), with and without the work integrals: wall seconds per
simulated second, rhs evaluations, max relative error of the output speed and max error of
the output angle against a dop853 reference at exact fidelity. The same equations are solved
by plain scipy.integrate.solve_ivp (RK45, LSODA, Radau) as the baseline in the same run.
Also the lockstep loop (exchange step vs error per coupling scheme, real-time factor) and
the rclpy round trip. Writes bench.csv, lockstep.csv, rhs.csv, bench.md and wp_<scene>.png to
--out; --report DIR rebuilds the per-level speedup table from DIR/bench.csv alone.
On a terminal, stderr shows a progress line (solver runs done, ETA) at most once a second.
"""


def _floats(text: str) -> list[float]:
    try:
        return [float(x) for x in text.split(',') if x.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f'not a comma-separated list of numbers: {text!r}') from None


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--quick', action='store_true',
                        help='reduced set (2 scenes, 4 tolerances, short horizon): under two minutes')
    parser.add_argument('--out', default='runs/bench', metavar='DIR', help='output directory (default runs/bench)')
    parser.add_argument('--scenes', nargs='+', metavar='SCENE', help='scene names or YAML paths')
    parser.add_argument('--solvers', nargs='+', metavar='SOLVER', help='dopri5 dop853 rosenbrock rodas4 rodas3 tsit5 vern6 vern7 vern8 rk4 ros2')
    parser.add_argument('--fidelities', nargs='+', metavar='LEVEL',
                        help='ideal closed exact auto rigid (rigid: exact joints, every spring rigid)')
    parser.add_argument('--energy', nargs='+', metavar='ON_OFF',
                        help='project runs with (on) and/or without (off) the work integrals '
                             '[on off]; off rows are labelled no-energy')
    parser.add_argument('--baselines', nargs='+', metavar='METHOD', help='solve_ivp methods (RK45 LSODA Radau)')
    parser.add_argument('--tolerances', type=_floats, metavar='T1,T2,..', help='rtol = atol values')
    parser.add_argument('--rk4-steps', type=_floats, metavar='H1,H2,..', help='fixed steps for rk4, s')
    parser.add_argument('--exchange-steps', type=_floats, metavar='H1,H2,..', help='lockstep exchange steps, s')
    parser.add_argument('--horizon', type=float, metavar='SECONDS', help='simulated time per run, s')
    parser.add_argument('--samples', type=int, metavar='N', help='error sample points per run')
    parser.add_argument('--repeats', type=int, metavar='N', help='timing repeats (min is reported)')
    parser.add_argument('--passes', type=int, metavar='N',
                        help="spread each configuration's repeats over N passes of its scene [2]")
    parser.add_argument('--mode-scenes', nargs='*', metavar='SCENE',
                        help='scenes with clutch, gearbox or brake, timed as the kernel against '
                             'solve_ivp with event functions (default: launch_clutch_chain and '
                             'launch_clutch; '
                             'none with --quick or --scenes; give no name to skip)')
    parser.add_argument('--no-ros', action='store_true', help='skip the rclpy round-trip measurement')
    parser.add_argument('--real-lockstep', action='store_true',
                        help='also time real `cvj-sim run` lockstep runs (5 s simulated) of the '
                             'lockstep scenes (kavz685_lever and fwd_halfshaft; with --scenes the '
                             'first one), one process per loop node and --composed')
    parser.add_argument('--real-lockstep-runs', type=int, metavar='N',
                        help='rounds of real lockstep runs, every scene and mode once per round [2]')
    parser.add_argument('--studies', action='store_true', help='run `pytest -m slow` and append its summary')
    parser.add_argument('--startup', action='store_true',
                        help="time the kernel's cold compile of every method (empty cache; "
                             'docs/solvers.md "First run") and a warm '
                             '`cvj-sim simulate kavz685_lever --duration 2`')
    parser.add_argument('--report', metavar='DIR',
                        help='only rebuild the per-level speedup summary (DIR/summary.md, printed) '
                             'from an earlier run\'s DIR/bench.csv, without re-running')
    parser.add_argument('--sweep', type=int, metavar='N',
                        help='only the sweep line: variants/s of N kavz685_lever variants with 1 and '
                             'all workers, scaling efficiency (docs/sweeps.md)')


def config_from_args(args: argparse.Namespace) -> object:
    """BenchConfig from the command line (quick or full defaults, then explicit options)."""
    from cvj_ros.bench import BenchConfig, check_config
    cfg = BenchConfig.quick() if args.quick else BenchConfig()
    updates = {k: v for k, v in {
        'scenes': args.scenes, 'solvers': args.solvers, 'fidelities': args.fidelities,
        'energy': getattr(args, 'energy', None),
        'baselines': args.baselines, 'tolerances': args.tolerances, 'rk4_steps': args.rk4_steps,
        'exchange_steps': args.exchange_steps, 'horizon': args.horizon, 'samples': args.samples,
        'repeats': args.repeats, 'passes': args.passes}.items() if v is not None}
    if args.samples is not None and args.samples < 2:
        raise SceneError('--samples', f'must be >= 2, got {args.samples}')
    if args.horizon is not None and not (math.isfinite(args.horizon) and args.horizon > 0):
        raise SceneError('--horizon', f'must be > 0, got {args.horizon}')
    cfg = dataclasses.replace(cfg, **updates)
    if args.scenes:
        cfg.lockstep_scenes = None     # the first given scene
    if args.no_ros:
        cfg.round_trip_n = 0
    from cvj_ros.bench_modes import MODE_SCENES
    modes = getattr(args, 'mode_scenes', None)
    cfg.mode_scenes = tuple(modes) if modes is not None else \
        (() if args.quick or args.scenes else MODE_SCENES)
    for name in cfg.mode_scenes:
        from cvj_ros.physics.scene import find_scene, load_scene
        if not load_scene(find_scene(name)).has_modes:
            raise SceneError('--mode-scenes', f'{name}: no clutch, gearbox, brake or commands')
    cfg.real_lockstep = bool(args.real_lockstep)
    if args.real_lockstep_runs is not None:
        if not 1 <= args.real_lockstep_runs <= 100:
            raise SceneError('--real-lockstep-runs', f'must be in 1..100, got {args.real_lockstep_runs}')
        cfg.real_lockstep_runs = args.real_lockstep_runs
    cfg.studies = bool(args.studies)
    cfg.startup = bool(args.startup)
    check_config(cfg)
    return cfg


def run(args: argparse.Namespace) -> int:
    if getattr(args, 'report', None) is not None:
        from pathlib import Path

        from cvj_ros.bench_report import write_summary
        if not (Path(args.report) / 'bench.csv').is_file():
            raise SceneError('--report', f'no bench.csv in {args.report}')
        try:
            path = write_summary(args.report)
        except (ValueError, KeyError) as exc:
            raise SceneError('--report', str(exc).splitlines()[0]) from None
        print(path.read_text(), end='')
        return 0
    if args.sweep is not None:
        from cvj_ros.bench import format_sweep_rates, sweep_rates
        from cvj_ros.sweep.run import default_workers
        if not 1 <= args.sweep <= 1_000_000:
            raise SceneError('--sweep', f'must be in 1..1000000 variants, got {args.sweep}')
        n = default_workers()
        print(format_sweep_rates(sweep_rates(args.sweep, (1, n) if n > 1 else (1,))))
        return 0
    from cvj_ros.bench import resolve_scene, run_bench
    cfg = config_from_args(args)
    for s in cfg.scenes:           # fail fast on a bad scene name, before any timing
        resolve_scene(s)
    from cvj_ros.bench import planned_runs
    from cvj_ros.progress import Progress
    # progress line on stderr, only on a terminal; cleared before every log line
    progress = Progress(planned_runs(cfg), label='cvj-sim bench', unit='runs')

    def log(message: str) -> None:
        progress.clear()
        print(message, file=sys.stderr)
    try:
        res = run_bench(cfg, args.out, log=log, progress=progress.update)
    finally:
        progress.close()
    print((res['paths'][-1]).read_text())
    return 0
