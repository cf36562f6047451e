"""`cvj-sim kinematics JOINT`: tabulate a joint's position function, ratio and slope.

Prints one row per input angle: phi_in, phi_out, ratio, ratio_slope (and phi_mid
where the joint has an intermediate member). ``--csv`` writes machine-readable CSV
(angles in rad); otherwise a readable table (angles in deg) and a summary line.
Parameters come from the joint registry: the named flags (--beta, --delta ...) are
conveniences, ``--param NAME=VALUE`` sets any registered parameter of any joint,
including joints added later (values in SI: rad, m; ``NAME_deg=VALUE`` takes degrees).
"""
from __future__ import annotations

import argparse
import csv
import math
import sys
from typing import Any

import numpy as np

from cvj_ros.errors import CvjError, GeometryError
from cvj_ros.physics.joints import JOINTS, make_joint

NAME = 'kinematics'
HELP = 'tabulate a joint: phi_out, ratio, ratio slope (and intermediate angle) over input angle'

# named flag -> (registry parameter candidates in order, converter to SI)
_FLAG_PARAMS: dict[str, tuple[tuple[str, ...], Any]] = {
    'beta': (('beta', 'beta1', 'delta'), math.radians),
    'beta2': (('beta2',), math.radians),
    'phase': (('phase',), math.radians),
    'delta': (('delta', 'beta'), math.radians),
    'alpha': (('alpha',), math.radians),
    'r': (('r',), float),
    'l': (('l',), float),
}


def _description() -> str:
    from cvj_ros.physics import joints as _j  # noqa: F401  (fills the registry)
    lines = ['Tabulate a joint model over input angle.', '', 'joints (fidelities; parameters):']
    for kind in sorted(JOINTS):
        spec = JOINTS[kind]
        lines.append(f'  {kind} [{", ".join(spec.fidelities)}]  source: {spec.source}')
        for name, desc in spec.params.items():
            lines.append(f'      {name}: {desc}')
    lines += ['', 'Named flags are in degrees / metres; --param NAME=VALUE sets any parameter in SI '
                  '(rad, m), NAME_deg=VALUE in degrees.']
    return '\n'.join(lines)


DESCRIPTION = _description()


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.description = DESCRIPTION
    parser.add_argument('joint', metavar='JOINT', help=f'joint kind: {", ".join(sorted(JOINTS))}')
    parser.add_argument('--beta', type=float, help='bend angle (deg): hooke beta, double_cardan beta1, '
                                                   'rzeppa delta, tripod/lever beta')
    parser.add_argument('--beta2', type=float, help='second bend angle (deg), double_cardan')
    parser.add_argument('--phase', type=float,
                        help='yoke phase (deg): double_cardan intermediate yokes, '
                             'hooke driving yoke')
    parser.add_argument('--r', type=float, help='radius (m): tripod roller / rzeppa ball pitch radius')
    parser.add_argument('--l', type=float, help='length (m): tripod shaft length')
    parser.add_argument('--delta', type=float, help='bend angle (deg), rzeppa')
    parser.add_argument('--alpha', type=float, help='cage-plane angle (deg), rzeppa; default delta/2')
    parser.add_argument('--param', action='append', default=[], metavar='NAME=VALUE',
                        help='any registered parameter, SI units (NAME_deg=VALUE in degrees); repeatable')
    parser.add_argument('--model', default='exact', help='fidelity: ideal | closed | exact (default exact)')
    parser.add_argument('--samples', type=int, default=25, help='rows (input angles), default 25')
    parser.add_argument('--revolutions', type=float, default=1.0,
                        help='input revolutions covered, default 1 (samples span [0, 2 pi N])')
    parser.add_argument('--start', type=float, default=0.0, help='first input angle (deg), default 0')
    parser.add_argument('--csv', action='store_true', help='CSV to stdout (angles in rad)')


def _parse_value(text: str) -> Any:
    try:
        return float(text)
    except ValueError:
        return text


def joint_params(args: argparse.Namespace, kind: str) -> dict[str, Any]:
    """Map the named flags and ``--param`` entries onto the registry's parameter names."""
    known = JOINTS[kind].params
    params: dict[str, Any] = {}
    for flag, (candidates, conv) in _FLAG_PARAMS.items():
        value = getattr(args, flag, None)
        if value is None:
            continue
        target = next((c for c in candidates if c in known), None)
        if target is None:
            raise GeometryError(flag, f'{kind} has no such parameter (parameters: '
                                      f'{", ".join(known) or "none"})')
        if not math.isfinite(value):
            raise GeometryError(flag, f'must be finite, got {value}')
        params[target] = conv(value)
    for item in args.param:
        name, sep, text = item.partition('=')
        name = name.strip()
        if not sep or not name:
            raise GeometryError('param', f'expected NAME=VALUE, got {item!r}')
        value = _parse_value(text.strip())
        if name.endswith('_deg') and name[:-4] in known:
            if not isinstance(value, float):
                raise GeometryError(name, f'must be a number (deg), got {text!r}')
            name, value = name[:-4], math.radians(value)
        if name not in known:
            raise GeometryError(name, f'unknown parameter for {kind} (parameters: '
                                      f'{", ".join(known) or "none"})')
        params[name] = value
    return params


def run(args: argparse.Namespace) -> int:
    kind = args.joint
    if kind not in JOINTS:
        raise GeometryError('JOINT', f'unknown joint {kind!r}; known: {", ".join(sorted(JOINTS))}')
    if args.samples < 2:
        raise CvjError(f'samples: must be >= 2, got {args.samples}')
    if not (math.isfinite(args.revolutions) and args.revolutions > 0):
        raise CvjError(f'revolutions: must be > 0, got {args.revolutions}')
    if not math.isfinite(args.start):
        raise CvjError(f'start: must be finite, got {args.start}')
    params = joint_params(args, kind)
    if args.model not in ('ideal', 'closed', 'exact'):
        raise GeometryError('model', f"must be ideal, closed or exact, got {args.model!r}")
    try:
        joint = make_joint(kind, fidelity=args.model, **params)
    except GeometryError as exc:
        if exc.parameter == 'fidelity':
            raise GeometryError('model', str(exc).split(': ', 1)[1]) from None
        raise
    phi0 = math.radians(args.start)
    phi = phi0 + np.linspace(0.0, 2.0 * math.pi * args.revolutions, args.samples)
    ev = joint.evaluate(phi)
    cols = [('phi_in', phi), ('phi_out', ev.phi_out), ('ratio', ev.ratio), ('ratio_slope', ev.ratio_slope)]
    if ev.phi_mid is not None:
        cols.append(('phi_mid', ev.phi_mid))
    out = sys.stdout
    if args.csv:
        writer = csv.writer(out, lineterminator='\n')
        writer.writerow([c[0] for c in cols])
        for k in range(phi.size):
            writer.writerow([repr(float(c[1][k])) for c in cols])
        return 0
    angle = {'phi_in', 'phi_out', 'phi_mid'}
    heads = [f'{n}[deg]' if n in angle else (f'{n}[1/rad]' if n == 'ratio_slope' else n) for n, _ in cols]
    width = 18
    pstr = ', '.join(f'{k}={v:.6g}' if isinstance(v, float) else f'{k}={v}'
                     for k, v in joint.params().items() if not isinstance(v, (list, tuple)))
    print(f'# {kind} ({joint.fidelity})' + (f': {pstr}' if pstr else '') +
          (f'; phi_mid = {joint.mid_name} angle' if ev.phi_mid is not None else ''), file=out)
    print(' '.join(h.rjust(width) for h in heads), file=out)
    for k in range(phi.size):
        row = [math.degrees(v[k]) if n in angle else v[k] for n, v in cols]
        print(' '.join(f'{x:{width}.9g}' for x in row), file=out)
    dev = ev.phi_out - phi
    mean_ratio = float(np.mean(ev.ratio))
    nonu = getattr(joint, 'nonuniformity', None)
    # two measures, two names: an angle (rad) here, the speed ratio that simulate/run print
    nonu_txt = (f', angle deviation over a revolution {nonu():.6g} rad' if callable(nonu) else '')
    rmin, rmax = float(ev.ratio.min()), float(ev.ratio.max())
    print(f'# max |phi_out - phi_in| {float(np.abs(dev).max()):.6g} rad '
          f'({math.degrees(float(np.abs(dev).max())):.6g} deg), ratio min {rmin:.9g} max {rmax:.9g} '
          f'(speed nonuniformity (max-min)/mean of the ratio {(rmax - rmin) / mean_ratio:.6g})'
          + nonu_txt, file=out)
    return 0
