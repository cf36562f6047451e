"""Imported once by the process pool's fork server (``multiprocessing`` forkserver preload):
loads the compiled kernel there, so every worker forked from it starts with the kernel
loaded instead of loading it itself (measured here: ~2-5 s per spawned worker on a shared
2-core machine). Loading is done by running a tiny scene through the same path a variant
takes (Simulation.run with dense sampling, compiled outputs, metrics; the batched path's
compiled reduction). Any failure here is
harmless: a worker then loads the kernel on its first variant.

numba imports ``coverage`` (when installed) only to report the lines it compiles to an
active coverage run; none runs in the server (a fresh interpreter; coverage started at its
start-up, or asked for by COVERAGE_PROCESS_START, is left alone), so the server marks it
absent first and does not import it: its load is the start every worker waits for."""
from __future__ import annotations

import os
import sys

if 'coverage' not in sys.modules and not os.environ.get('COVERAGE_PROCESS_START'):
    sys.modules['coverage'] = None      # type: ignore[assignment]  (import coverage: ImportError)


def warm() -> None:
    """Run a 10 ms two-inertia scene with the default method (dopri5, both samplings); other
    methods load in a worker on first use."""
    from cvj_ros.physics.scene import parse_scene
    from cvj_ros.physics.simulate import Simulation
    for method in ('dopri5',):
        scene = parse_scene({
            'name': 'preload', 'duration': 0.01, 'exchange_step': 0.001,
            'solver': {'method': method},
            'driveline': [{'type': 'inertia', 'name': 'a', 'J': 0.1},
                          {'type': 'spring', 'name': 's', 'stiffness': 1000.0, 'damping': 1.0},
                          {'type': 'inertia', 'name': 'b', 'J': 0.2}],
            'engine': {'model': 'linear', 'm1': 10.0, 'k1': 0.1},
            'load': {'model': 'constant', 'torque': 5.0}})
        for sampling in ('dense', 'land'):
            sim = Simulation(scene)
            sim.run(sampling=sampling)
            sim.summary()


def warm_batch() -> None:
    """Import the batched path (cvj_ros.sweep.batch, run, spec, reparse, orders) and load
    its compiled reduction (kernel/reduce_nb.py, both forms) on a tiny record and the
    members' fill (outputs_nb.fill_mid_samples: the entry point bind_lean keeps, for the
    argument types it passes), so a forked worker has them."""
    import numpy as np

    import cvj_ros.sweep.batch  # noqa: F401
    import cvj_ros.sweep.orders  # noqa: F401
    import cvj_ros.sweep.reparse  # noqa: F401
    import cvj_ros.sweep.spec  # noqa: F401
    from cvj_ros.physics.kernel import entry_point_once
    from cvj_ros.physics.kernel.outputs_nb import fill_mid_samples
    from cvj_ros.sweep.reduce import load_entries
    load_entries()
    args = (np.empty((0, 1)), np.empty((0, 1)), np.zeros((0, 4), np.int64), np.zeros(1))
    entry_point_once(fill_mid_samples, args)(*args)


try:
    warm()
    warm_batch()
except Exception:  # noqa: BLE001  (see the module docstring)
    pass
