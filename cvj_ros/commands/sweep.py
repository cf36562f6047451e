"""`cvj-sim sweep SCENE --set PATH=SPEC ... --out DIR`: parameter study of a scene."""
from __future__ import annotations

import argparse
import math
import sys
import time

from cvj_ros.errors import SceneError
from cvj_ros.progress import Progress

NAME = 'sweep'
HELP = 'parameter study: simulate many variants of a scene (grid or random), table and maps'
DESCRIPTION = """Vary fields of a scene, simulate every variant offline (compiled kernel, the scene's
fidelity rule) on local worker processes or a Dask cluster, and reduce each to the metrics
`cvj-sim simulate` prints (per shaft mean speed, nonuniformity delta, speed / acceleration /
torque amplitude, mean torque; energy residual; solver counters).

--set PATH=SPEC names a field as scene errors print it (an element's name may replace its
index) and its values:
  start:stop:n       n evenly spaced values (both ends); start:stop:n:log log-spaced
  a,b,c              a list (numbers or words); one value fixes the field
  lo:hi              a range, with --samples N: seeded uniform sampling (lo:hi:log log-uniform)
Grid axes combine as a product (first --set varies slowest). Results in DIR: results.csv
(variant order, exact float text: the same bytes for any executor), timing.csv (wall time
per variant), sweep.json (definition, versions, runs), plots/*.png. Rerunning the same
command skips finished variants (Ctrl-C keeps them). docs/sweeps.md has the details.

examples:
  cvj-sim sweep kavz685_lever --set 'driveline[coupling].params.alpha_deg=5:25:5' \\
      --set 'driveline[bushings].stiffness=400:1200:5' --out runs/sweep_lever
  cvj-sim sweep fwd_halfshaft --set 'initial.speed_rpm=500:3000:11' --out runs/speed
  cvj-sim sweep kavz685_lever --set 'driveline[bushings].stiffness=300:3000:log' \\
      --samples 200 --seed 1 --out runs/random --workers 2
  cvj-sim sweep kavz685_lever --set 'engine.m1=500,623,700' --out runs/m1 --cluster tcp://10.0.0.5:8786
  cvj-sim sweep --replot runs/sweep_lever --metric driven_shaft.torque_amplitude
"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('scene', nargs='?', help='shipped scene name (see `cvj-sim scenes`) or YAML path')
    parser.add_argument('--set', dest='sets', action='append', default=[], metavar='PATH=SPEC',
                        help='field to vary and its values (repeatable; see above)')
    parser.add_argument('--samples', type=int, help='random sampling: number of variants')
    parser.add_argument('--seed', type=int, default=0, help='random sampling seed (default 0)')
    parser.add_argument('--out', metavar='DIR', help='result directory (created; rerun to resume)')
    parser.add_argument('--workers', type=int, help='local worker processes (default: all cores)')
    parser.add_argument('--cluster', metavar='ADDRESS',
                        help='run on a Dask distributed scheduler, e.g. tcp://host:8786')
    parser.add_argument('--on-error', choices=('skip', 'stop'), default='skip',
                        help='a bad or failing variant: skip it (recorded with its error; '
                             'default) or stop the sweep')
    parser.add_argument('--sample-dt', type=float,
                        help='sample period of each run for the metrics, s (default: the scene\'s '
                             'sample_step or exchange_step, as cvj-sim simulate)')
    parser.add_argument('--sampling', choices=('dense', 'land'), default='dense',
                        help='dense (default): samples from the solver\'s dense output, steps '
                             'free; land: steps land on every sample (cvj-sim simulate\'s '
                             'default; ~1.3x the CPU, metrics within 2e-3 relative here)')
    parser.add_argument('--orders', type=int, default=4,
                        help="engine orders of a shaft's torque kept per variant (columns "
                             'SHAFT.torque_order<k>, N m; 0: none; default 4)')
    parser.add_argument('--orders-shaft', metavar='SHAFT',
                        help='shaft whose torque --orders analyses (default: the first, the '
                             'torque the engine shaft passes on)')
    parser.add_argument('--transient', type=float,
                        help='seconds skipped before the metrics window (default: the steady-window '
                             'criterion, docs/scenes.md)')
    parser.add_argument('--fidelity', nargs='+', default=[], metavar='NAME=LEVEL',
                        help='force fidelity: joint=ideal|closed|exact, spring=elastic|rigid')
    parser.add_argument('--backend', choices=('kernel', 'python'), default='kernel',
                        help='kernel: compiled (default); python: the reference rhs (slow)')
    parser.add_argument('--fresh', action='store_true',
                        help='discard an earlier sweep in DIR instead of resuming it')
    parser.add_argument('--metric', default=None,
                        help='metric of the plots (results.csv column, default: the last '
                             "shaft's delta)")
    parser.add_argument('--no-plots', action='store_true', help='write no PNGs')
    parser.add_argument('--replot', metavar='DIR',
                        help='only redraw the plots of the finished sweep in DIR')


class SweepProgress(Progress):
    """Progress of a sweep: count, percent, rate (variants/s) and ETA from that rate."""

    def text(self, done: float, now: float) -> str:
        assert self._t0 is not None
        wall = now - self._t0
        frac = min(max(done / self.total, 0.0), 1.0) if self.total > 0 else 1.0
        head = f'{self.label}: {done:g}/{self.total:g} variants ({100 * frac:.0f}%)'
        new = done - self.start
        if new <= 0 or wall <= 0:
            return head
        from cvj_ros.progress import format_duration
        rate = new / wall
        return f'{head}, {rate:.3g} variants/s, ETA {format_duration((self.total - done) / rate)}'

    start = 0.0


def _sweep_error(message: str) -> Exception:
    """A SweepError (its module, and numpy with it, imported only to raise one)."""
    from cvj_ros.sweep.spec import SweepError
    return SweepError(message)


def run(args: argparse.Namespace) -> int:
    started = time.perf_counter()
    if args.replot:
        return _replot(args)
    if not args.scene:
        raise _sweep_error('scene: give a scene (shipped name or YAML path), or --replot DIR')
    if not args.out:
        raise _sweep_error('--out: give the result directory (DIR; rerun the same command to '
                           'resume)')
    for opt in ('sample_dt', 'transient'):
        v = getattr(args, opt)
        if v is not None and not (math.isfinite(v) and (v > 0 or (opt == 'transient' and v >= 0))):
            raise SceneError(f'--{opt.replace("_", "-")}', f'must be > 0, got {v}')
    if not 0 <= args.orders <= 64:
        raise _sweep_error(f'--orders: must be in 0..64, got {args.orders}')
    if args.workers is not None and args.workers < 1:
        raise _sweep_error(f'--workers: must be >= 1, got {args.workers}')
    if args.workers is not None and args.cluster:
        raise _sweep_error('--workers: not with --cluster (the cluster has its own workers)')
    from pathlib import Path
    if Path(args.out).exists() and not Path(args.out).is_dir():
        raise _sweep_error(f'--out {args.out}: exists and is not a directory')
    if not args.cluster:
        # a local pool's fork server loads the kernel (~0.55 s CPU) while this process
        # imports numpy and the sweep, reads the scene and expands the sweep
        from cvj_ros.sweep.server import start_fork_server, usable_cores
        if (args.workers if args.workers is not None else usable_cores()) > 1:
            start_fork_server()
    from cvj_ros.physics.scene import find_scene
    from cvj_ros.sweep.spec import SweepError, build_sweep
    from cvj_ros.commands.simulate import parse_fidelity
    from cvj_ros.sweep.run import RunOptions, execute, make_executor
    path = find_scene(args.scene)
    # a local pool starts (its fork server loads the kernel) while this process reads the
    # scene and expands the sweep; a cluster is contacted once the sweep is known valid
    executor = None if args.cluster else make_executor(args.workers, None)
    try:
        base = load_scene_data(path)
        from cvj_ros.physics.scene import parse_scene
        scene = parse_scene(base)
        if scene.has_modes and args.orders_shaft is not None:   # clutch, gearbox, brake, commands
            raise SweepError('--orders-shaft: a scene with clutch, gearbox, brake or commands is '
                             'swept on the Python reference, which keeps speeds, not shaft '
                             'torques')
        sweep = build_sweep(base, args.sets, samples=args.samples, seed=args.seed)
        if args.orders_shaft is not None:
            from cvj_ros.physics.driveline import build_driveline
            from cvj_ros.physics.scene import parse_scene
            shafts = build_driveline(parse_scene(base)).shaft_names
            if args.orders_shaft not in shafts:
                raise SweepError(f'--orders-shaft {args.orders_shaft}: no such shaft in '
                                 f'{base.get("name")}; shafts: {", ".join(shafts)}')
        options = RunOptions(sample_dt=args.sample_dt, transient=args.transient,
                             fidelity=parse_fidelity(args.fidelity), backend=args.backend,
                             sampling=args.sampling, orders=args.orders,
                             orders_shaft=args.orders_shaft)
        if executor is None:
            executor = make_executor(args.workers, args.cluster)
    except BaseException:
        if executor is not None:
            executor.close()    # execute() closes it from here on
        raise
    where = f'Dask cluster {executor.address}' if args.cluster else (
        f'{executor.workers} local worker process{"es" if executor.workers > 1 else ""}'
        if executor.workers > 1 else 'this process')
    print(f'cvj-sim sweep: {len(sweep)} variant{"s" if len(sweep) != 1 else ""} of '
          f'{base.get("name")} on {where}', file=sys.stderr)
    progress = SweepProgress(len(sweep), label='cvj-sim sweep', unit='variants')
    first = True

    def update(done: int) -> None:
        nonlocal first
        if first:            # variants already done (resume) do not count in the rate
            progress.start = float(done)
            first = False
        progress.update(done)

    try:
        report = execute(sweep, options, args.out, executor=executor, on_error=args.on_error,
                         scene_source=str(path), fresh=args.fresh, progress=update,
                         started=started)
    except KeyboardInterrupt:
        progress.close()
        from cvj_ros.sweep.results import ResultStore
        n = len(ResultStore(args.out).load_done())
        print(f'cvj-sim sweep: interrupted; {n} of {len(sweep)} variants finished and kept in '
              f'{args.out} (rerun the same command to resume)', file=sys.stderr)
        raise
    finally:
        progress.close()
    c = report.counts
    print(f'{report.total} variants: {c.get("ok", 0)} ok, {c.get("invalid", 0)} invalid, '
          f'{c.get("failed", 0)} failed' + (f'; {report.skipped} already done (resumed)'
                                            if report.skipped else ''))
    if report.ran:
        print(f'ran {report.ran} in {report.run_wall:.2f} s wall ({report.rate:.1f} variants/s, '
              f'{report.executor}, {report.workers} worker{"s" if report.workers > 1 else ""}); '
              f'{report.total_wall:.2f} s including start-up')
    if report.first_bad:
        print(f'first bad variant: {report.first_bad}')
    print(f'results: {args.out}/results.csv (timing.csv, sweep.json)')
    if not args.no_plots:
        from cvj_ros.sweep.plots import write_sweep_plots
        notes: list[str] = []
        for p in write_sweep_plots(args.out, metric=args.metric, notes=notes):
            print(f'plot: {p}')
        for n in notes:
            print(f'plot note: {n}')
    return 0


def load_scene_data(path) -> dict:
    """The scene file as a plain dict (as written: keys and units of the file), validated."""
    from cvj_ros.physics.scene import load_scene, parse_scene
    from cvj_ros.textfile import load_yaml_bounded, read_text_file
    load_scene(path)                  # the base scene must be valid (errors name file and field)
    data = load_yaml_bounded(read_text_file(path, what='scene file'), str(path))
    parse_scene(data)
    return data


def _replot(args: argparse.Namespace) -> int:
    from cvj_ros.sweep.plots import write_sweep_plots
    notes: list[str] = []
    for p in write_sweep_plots(args.replot, metric=args.metric, required=True, notes=notes):
        print(f'plot: {p}')
    for n in notes:
        print(f'plot note: {n}')
    return 0
