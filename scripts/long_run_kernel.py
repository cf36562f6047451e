#!/usr/bin/env python3
"""The 6000 rpm long-run study on the compiled kernel (docs/benchmark.md, "Peak memory"):
a rigid Hooke driveline (1 kg m^2, Hooke joint at 10 deg, 0.05 kg m^2) spinning freely at
6000 rpm for N revolutions, dop853 rtol = atol = 1e-10, 200 samples, through
``Simulation(scene)`` (linear engine at throttle 0 and k1 = 1e-300, constant load 0: the
kernel's own sources, so nothing falls back to Python). Prints the f-evals, the wall time
and the largest energy residual.

Usage: ``python scripts/peak_rss.py -- python scripts/long_run_kernel.py 1e5``
"""
from __future__ import annotations

import math
import resource
import sys
import time
from typing import Any

from cvj_ros.physics.scene import parse_scene
from cvj_ros.physics.simulate import Simulation

OMEGA = 6000 * math.pi / 30   # rad/s


def simulation() -> Simulation:
    """The study's Simulation: the rigid Hooke driveline at 6000 rpm, dop853 at 1e-10."""
    scene = parse_scene({
        'name': 'hooke_6000rpm', 'duration': 1.0, 'exchange_step': 0.001,
        'engine': {'model': 'linear', 'm1': 1.0, 'k1': 1e-300, 'throttle': 0.0},
        'load': {'model': 'constant', 'torque': 0.0},
        'initial': {'speed_rad_s': OMEGA},
        'driveline': [{'type': 'inertia', 'name': 'a', 'J': 1.0},
                      {'type': 'joint', 'name': 'h', 'kind': 'hooke', 'params': {'beta_deg': 10.0}},
                      {'type': 'inertia', 'name': 'b', 'J': 0.05}]})
    return Simulation(scene, method='dop853', rtol=1e-10, atol=1e-10)


def run(sim: Simulation, revs: float) -> Any:
    """``revs`` revolutions from the start, 200 samples: the Trace."""
    period = 2 * math.pi / OMEGA
    return sim.run(revs * period, sample_dt=revs * period / 200)


def peak_rss_mib() -> float:
    """This process's peak resident set size so far (MiB; Linux reports KiB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def main(argv: list[str]) -> int:
    revs = float(argv[0]) if argv else 1e5
    sim = simulation()
    t0 = time.perf_counter()
    tr = run(sim, revs)
    print(f'{revs:g} revolutions on the {sim.backend} backend: {tr.solver.get("nfev")} f-evals, '
          f'{time.perf_counter() - t0:.2f} s, largest energy residual {tr.max_energy_residual:.2e}, '
          f'peak RSS {peak_rss_mib():.1f} MiB')
    return 0

if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
