"""`cvj-sim fit SCENE --data DATA --fit PATH=LO:HI ... [--json]`: identify scene parameters."""
from __future__ import annotations

import argparse
import json
import math

NAME = 'fit'
HELP = 'identify scene parameters from measured torques (least squares on order amplitudes)'
DESCRIPTION = """Fit fields of a scene to a measured torque: the torque's mean and its amplitudes per
order of the shaft angle, simulated on the compiled core, against the measurement's, by
least squares (scipy least_squares, bounded to each LO:HI). Prints every fitted value with its
95 % confidence interval (from the Jacobian at the optimum), the residual per order, and writes
a measured-vs-fitted plot. A parameter the data do not depend on is reported as not
identifiable instead of given a value. The same inputs give the same result.

--fit PATH=LO:HI names a field as scene errors print it (an element's name may replace its
index, as in cvj-sim sweep --set) and its range; the fit starts at the middle.
--data is one of
  davidbaev2023/4.N   a shipped measured table (Davidbaev et al. 2023, tables 4.2-4.11)
  FILE.csv            angle_deg + torque* columns (ordinates of one revolution, one column
                      per revolution, N m), or t_s, torque_Nm, angle_rad or speed_rad_s
  BAG                 a recorded bag: the torque and angle of --shaft from /driveline/joint_states
docs/fit.md has the details.

examples:
  cvj-sim fit kavz685_lever --data davidbaev2023/4.3 --shaft drive_shaft \\
      --fit 'driveline[coupling].params.alpha_deg=2:25' --fit load.mean=150:300
  cvj-sim fit kavz685_lever --data runs/lever/bag --fit 'driveline[bushings].stiffness=300:1500' --json
"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('scene', help='shipped scene name (see `cvj-sim scenes`) or YAML path')
    parser.add_argument('--data', required=True, metavar='DATA',
                        help='measured torque: davidbaev2023/4.N, a CSV file or a bag')
    parser.add_argument('--fit', dest='fits', action='append', default=[], metavar='PATH=LO:HI',
                        help='scene field to identify and its range (repeatable)')
    parser.add_argument('--orders', type=int, default=4,
                        help='orders of the shaft angle compared besides the mean (default 4)')
    parser.add_argument('--fit-orders', metavar='LIST',
                        help='orders the residuals hold, 0 being the mean (default all of '
                             '0..--orders; e.g. 0,2,4 for a model that produces only even orders)')
    parser.add_argument('--shaft', help="model shaft whose torque is compared (default the "
                                        "first; for a bag also the bag's shaft)")
    parser.add_argument('--angle-shaft', help='model shaft whose angle the orders refer to '
                                              '(default --shaft)')
    parser.add_argument('--duration', type=float, help='s simulated per model run (default the '
                                                       "scene's)")
    parser.add_argument('--skip', type=float, default=0.0,
                        help='s left out at the start of a measured time series (default 0)')
    parser.add_argument('--starts', type=int, default=1,
                        help='local fits from this many starting points (the middle of the '
                             'ranges, then a Halton sequence), the best kept (default 1)')
    parser.add_argument('--plot', default='fit.png', metavar='PNG',
                        help="measured-vs-fitted plot (default fit.png; 'none' for no plot)")
    parser.add_argument('--json', action='store_true', help='print one JSON object')


def run(args: argparse.Namespace) -> int:
    from cvj_ros.commands.sweep import load_scene_data
    from cvj_ros.errors import SceneError
    from cvj_ros.fit.data import read_measured
    from cvj_ros.fit.problem import FitProblem, parse_fit_parameter
    from cvj_ros.fit.report import format_result, result_dict, write_fit_plot
    from cvj_ros.fit.solve import solve_fit
    from cvj_ros.guard import reading
    from cvj_ros.physics.scene import find_scene
    from cvj_ros.sweep.spec import SweepError
    if not args.fits:
        raise SweepError('--fit: give at least one PATH=LO:HI '
                         "(e.g. --fit 'driveline[bushings].stiffness=300:1500')")
    if not 1 <= args.starts <= 1000:
        raise SceneError('--starts', f'must be in 1..1000, got {args.starts}')
    if not 1 <= args.orders <= 32:
        raise SceneError('--orders', f'must be in 1..32, got {args.orders}')
    for opt in ('duration', 'skip'):
        v = getattr(args, opt)
        if v is not None and not (math.isfinite(v) and (v > 0 or (opt == 'skip' and v >= 0))):
            raise SceneError(f'--{opt}', f'must be > 0, got {v}')
    use = None
    if args.fit_orders is not None:
        try:
            use = sorted({int(x) for x in args.fit_orders.split(',') if x.strip()})
        except ValueError:
            raise SceneError('--fit-orders', f'expected a list of integers such as 0,2,4, got '
                             f'{args.fit_orders!r}') from None
        if not use or use[0] < 0 or use[-1] > args.orders:
            raise SceneError('--fit-orders', f'orders must lie in 0..{args.orders} (--orders), got '
                             f'{args.fit_orders!r}')
    path = find_scene(args.scene)
    base = load_scene_data(path)
    params = [parse_fit_parameter(base, text) for text in args.fits]
    seen: dict[str, str] = {}
    for p in params:
        if p.field in seen:
            raise SweepError(f'--fit {p.path}: {p.field} is already fitted by --fit {seen[p.field]}')
        seen[p.field] = p.path
    with reading(f'--data {args.data}'):
        measured = read_measured(args.data, orders=args.orders, shaft=args.shaft, skip=args.skip)
    problem = FitProblem(base, params, orders=args.orders, shaft=args.shaft,
                         angle_shaft=args.angle_shaft or measured.angle_shaft,
                         duration=args.duration, revolutions=measured.revolutions,
                         start_time=measured.start_time)
    problem.predict([p.value(0.5) for p in params])   # model errors before the solver starts
    result = solve_fit(problem, measured.vector(), use=use, starts=args.starts)
    scene = str(base.get('name') or path)
    plot = None
    if args.plot.lower() != 'none':
        plot = str(write_fit_plot(args.plot, result, measured, scene=scene))
    if args.json:
        print(json.dumps(result_dict(result, measured, scene=scene, plot=plot)))
    else:
        print(format_result(result, measured, scene=scene, plot=plot))
    return 0
