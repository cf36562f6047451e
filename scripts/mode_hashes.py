"""Hashes of the compiled kernel's mode-scene runs, for a before/after comparison of a change
that must not change them (docs/benchmark.md, "The mode rhs inside the segment stepper").

For every mode scene (``Scene.has_modes``) x method x rtol (atol = rtol / 100, 20 samples),
one kernel run's samples (t, speeds, energy residual, gear), events (time, element, modes),
statuses, final state, end time and counters go into one sha256.

    PYTHONPATH=. python scripts/mode_hashes.py OUT.txt [--methods dopri5,vern7]
        [--tols 1e-5,1e-8]

then ``diff`` two OUT files.
"""
from __future__ import annotations

import hashlib
import sys

import numpy as np

from cvj_ros.physics.hybrid.from_scene import hybrid_simulation
from cvj_ros.physics.kernel.modes import KernelHybridSimulation
from cvj_ros.physics.kernel.tree_modes import KernelHybridTreeSimulation
from cvj_ros.physics.scene import load_scene, shipped_scenes


def mode_hashes(methods: tuple[str, ...], tols: tuple[float, ...]) -> dict[str, str]:
    """{'scene method rtol': sha256 prefix of one kernel run's results}."""
    out: dict[str, str] = {}
    for name, path in sorted(shipped_scenes().items()):
        scene = load_scene(path)
        if not scene.has_modes:
            continue
        kern = KernelHybridTreeSimulation if scene.is_tree else KernelHybridSimulation
        for method in methods:
            for tol in tols:
                ref = hybrid_simulation(scene, method=method, rtol=tol, atol=tol * 1e-2,
                                        sample_dt=scene.duration / 20, duration=scene.duration)
                r = kern.from_reference(ref).run()
                h = hashlib.sha256()
                for a in (r.t, r.speed, r.energy_residual, r.gear):
                    h.update(np.ascontiguousarray(a).tobytes())
                h.update(repr([(e.t, e.element, e.before, e.after) for e in r.events]).encode())
                h.update(repr((r.statuses, r.stall, r.final, r.final_mode, r.t_end,
                               sorted(r.stats.items()))).encode())
                key = f'{name} {method} {tol:g}'
                out[key] = h.hexdigest()[:16]
                print(key, out[key], len(r.events), r.stats.get('nfev'), flush=True)
    return out


def main() -> None:
    args = sys.argv[1:]
    methods, tols = ('dopri5', 'vern7'), (1e-5, 1e-8)
    if '--methods' in args:
        i = args.index('--methods')
        methods = tuple(args[i + 1].split(','))
        del args[i:i + 2]
    if '--tols' in args:
        i = args.index('--tols')
        tols = tuple(float(x) for x in args[i + 1].split(','))
        del args[i:i + 2]
    if len(args) != 1:
        raise SystemExit('mode_hashes: usage: mode_hashes.py OUT.txt [--methods m1,m2] '
                         '[--tols t1,t2]')
    out = mode_hashes(methods, tols)
    with open(args[0], 'w') as fh:
        for k, v in out.items():
            fh.write(f'{k} {v}\n')


if __name__ == '__main__':
    main()
