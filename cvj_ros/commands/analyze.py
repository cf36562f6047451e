"""`cvj-sim analyze BAG`: offline analysis of a recorded bag (see :mod:`cvj_ros.analysis`)."""
from __future__ import annotations

import argparse
import json
import math

from cvj_ros.errors import BagError

NAME = 'analyze'
HELP = 'analyse a recorded bag: speeds, nonuniformity, torque harmonics, lockstep statistics'
DESCRIPTION = """\
Analyse a rosbag2 bag (mcap or sqlite3) recorded by `cvj-sim run`.

Per shaft of /driveline/joint_states: mean speed, speed nonuniformity
delta = (w_max - w_min)/w_mean, amplitudes (max - min)/2 of speed, acceleration and
torque (Davidbaev et al. 2023, ch. 4), torque harmonics over shaft angle (Davidbaev et al. 2023, eqs. 4.1-4.3).
Per joint (<joint>_input/<joint>_output): geometric and kinematic nonuniformity
(Bugaru & Vasile 2021). Engine/load torque, energy residual and wait times from /diagnostics,
lockstep statistics. All over the steady window (the slices that agree with the last slice
in mean speed and amplitudes, the same criterion as `cvj-sim run` and `simulate`; its
verdict is printed), or from --skip seconds on.
"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('bag', help='bag directory (or its .mcap/.db3 file)')
    parser.add_argument('--json', action='store_true', help='print the report as JSON')
    parser.add_argument('--plots', metavar='DIR', help='write PNG figures to DIR')
    parser.add_argument('--no-internal-members', action='store_true',
                        help="leave the joints' internal members (Rzeppa cage, tripod spider, lever-hinge "
                             "earring: no line torque) out of speeds_torques.png of --plots")
    parser.add_argument('--skip', type=float, default=None, metavar='SECONDS',
                        help='start the window SECONDS after the first sample (default: the steady-window '
                             'criterion, docs/scenes.md)')
    parser.add_argument('--harmonics', type=int, default=6, metavar='N',
                        help='number of torque harmonics (default 6)')


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from cvj_ros import analysis

    if args.skip is not None and not (math.isfinite(args.skip) and args.skip >= 0):
        raise BagError(f'--skip: must be a finite number >= 0, got {args.skip}')
    if not 1 <= args.harmonics <= 60:
        raise BagError(f'--harmonics: must be in 1..60, got {args.harmonics}')
    sig = analysis.read_bag_signals(args.bag)
    if sig.position.size and bool(np.all(np.isnan(sig.position))):
        raise BagError(f'{args.bag}: its joint states carry no shaft angles (a bag of speeds only, '
                       'as `cvj-sim simulate` wrote for scenes with clutch, gearbox, brake or commands '
                       'before it sampled angles: write it again with `cvj-sim simulate SCENE --bag DIR`)')
    report = analysis.analyze_signals(sig, skip_s=args.skip, n_harmonics=args.harmonics,
                                      samples_per_rev=max(72, 4 * args.harmonics))
    if args.plots:
        from cvj_ros.plots import write_analysis_plots
        report['plots'] = [str(p) for p in write_analysis_plots(
            sig, report, args.plots, internal=not args.no_internal_members)]
    if args.json:
        print(json.dumps(report, indent=1, default=str))
    else:
        print(analysis.format_report(report))
        for p in report.get('plots', []):
            print(f'wrote {p}')
    return 0
