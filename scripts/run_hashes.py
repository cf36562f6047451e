"""Hashes of ``Simulation.run``'s results on the reference scenes, for a before/after
comparison of a change that must not change them (docs/benchmark.md, "Where the time goes").

For every scene x method x tolerance x sampling (land, dense), one Simulation runs the
bench's call (``run(1.0, sample_dt=0.05)``) twice - a fresh plan, then the reused one - and
each run's outputs (t, position, velocity, effort, torques, energy residual, the final
state) and counters (nfev, njev, nlu, naccept, nreject, t, h) go into one sha256. The
Rosenbrock methods run the non-stiff scenes at the loose tolerance only (as the bench).

    PYTHONPATH=. python scripts/run_hashes.py OUT.txt [SCENE ...] [--pairs] [--reuse]
        [--fidelity ideal] [--methods vern6,vern7,...]

then ``diff`` two OUT files: 90 lines for the five methods on the six scenes, 138 with
tsit5 and vern6 (``--pairs``); ``--methods m1,m2,..``: these methods instead. ``--fidelity``:
the bench's fidelity column (default exact; the bench's stiff rows run ideal). ``--reuse``:
every run with ``reuse_trace=True`` (the second run rewrites the first's Trace in place),
whose hashes must equal the runs' without it.
"""
from __future__ import annotations

import hashlib
import sys

import numpy as np

from cvj_ros import bench
from cvj_ros.physics.simulate import Simulation

__all__ = ['FIELDS', 'run_hashes']

FIELDS = ('t', 'position', 'velocity', 'effort', 'engine_torque', 'load_torque',
          'energy_residual')
SCENES = ('stiff', 'fwd_halfshaft', 'kavz685_lever', 'cardan_truck', 'tripod_xiu2024',
          'fwd_axle')
METHODS = ('rodas3', 'rosenbrock', 'rodas4', 'dopri5', 'dop853')
PAIRS = ('tsit5', 'vern6')


def run_hashes(scenes: tuple[str, ...] = SCENES, methods: tuple[str, ...] = METHODS,
               reuse: bool = False, fidelity: str = 'exact') -> dict[str, str]:
    """{'scene method tol sampling': sha256 prefix of two runs' outputs and counters}."""
    out: dict[str, str] = {}
    for name in scenes:
        scene = bench.resolve_scene(name)
        for method in methods:
            for tol in (1e-3, 1e-6):
                for sampling in ('land', 'dense'):
                    if method.startswith('ro') and name != 'stiff' and tol == 1e-6:
                        continue
                    sim = Simulation(scene, method=method, rtol=tol, atol=tol,
                                     fidelity=bench.forced_levels(scene, fidelity))
                    h = hashlib.sha256()
                    for _rep in range(2):
                        tr = sim.run(1.0, sample_dt=0.05, sampling=sampling,
                                     reuse_trace=reuse)
                        for f in FIELDS:
                            h.update(np.ascontiguousarray(getattr(tr, f)).tobytes())
                        h.update(np.ascontiguousarray(sim.final_state).tobytes())
                        h.update(repr({k: tr.solver[k] for k in (
                            'nfev', 'njev', 'nlu', 'naccept', 'nreject', 't', 'h')}).encode())
                    key = f'{name} {method} {tol:g} {sampling}'
                    out[key] = h.hexdigest()[:16]
                    print(key, out[key], tr.solver['nfev'], flush=True)
    return out


def main() -> None:
    args = [a for a in sys.argv[1:] if a not in ('--pairs', '--reuse')]
    fidelity = 'exact'
    if '--fidelity' in args:
        i = args.index('--fidelity')
        fidelity = args[i + 1]
        del args[i:i + 2]
    methods = METHODS + PAIRS if '--pairs' in sys.argv else METHODS
    if '--methods' in args:
        i = args.index('--methods')
        methods = tuple(args[i + 1].split(','))
        del args[i:i + 2]
    out = run_hashes(tuple(args[1:]) or SCENES, methods, reuse='--reuse' in sys.argv,
                     fidelity=fidelity)
    with open(args[0], 'w') as fh:
        for k, v in out.items():
            fh.write(f'{k} {v}\n')


if __name__ == '__main__':
    main()
