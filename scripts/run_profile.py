"""Where one short benchmarked run's time goes (docs/benchmark.md, "Where the time goes").

Times the bench's own call (``bench.run_project``'s ``Simulation.run(horizon, sample_dt,
breakpoints, sampling)`` on one Simulation, its plan kept) for a scene and configuration,
and splits it into pieces timed the same way (CPU time of this thread, min over CALLS
calls, median of ROUNDS rounds):

- ``whole``: ``Simulation.run`` as the bench calls it (``reuse_trace=True``: the run
  rewrites one Trace in place); ``whole_fresh``: the same call without it (new arrays and
  a new Trace per run);
- ``call``: the plan's one-call run (``KernelStepper.bind_run``) alone, the run's
  arrays allocated once outside the timing; ``kept_call``: a Rosenbrock run's kept call
  (``kernel/kept_nb.py``: the arrays by address, what ``whole`` calls), ``python_kept``
  the whole run minus it;
- ``dispatch``: a compiled function that does nothing, with the same arguments, called the
  same way (functools.partial over the compiled entry point): numba's unboxing;
- ``compiled_run``: the same run function called from a compiled loop (no dispatch);
- ``outputs``: the samples' outputs (``sample_outputs`` and the intermediate members'
  ``fill_mid_samples``) in a compiled loop;
- ``jac``: the Jacobian evaluations x its ns per call in a compiled loop;
- ``rhs``: the evaluations x the rhs's ns per call in a compiled loop at the run's states;
- ``python``: the whole run minus the call (``python_fresh``: without ``reuse_trace``);
  ``call_overhead``: the call minus the compiled
  run; ``integration_rest``: the compiled run minus outputs, rhs and Jacobian (the stepper's
  own arithmetic: start, step-size control, LU and solves, dense output).

    PYTHONPATH=. python scripts/run_profile.py stiff rodas3 1e-3 dense [ROUNDS [across]]
        [--fidelity auto]

(``across``: step across the load's breakpoints instead of landing on them; ``--fidelity``:
the bench's fidelity column, default exact.) The rhs and Jacobian are timed on the run's
own model (an ``auto`` or ``ideal`` run's cheaper model, not the exact one).
"""
from __future__ import annotations

import functools
import sys
import time

import numpy as np
from numba import njit

from cvj_ros import bench
from cvj_ros.physics.kernel import rhs_nb
from cvj_ros.physics.kernel.borrow_nb import borrowed_all
from cvj_ros.physics.kernel.outputs_nb import fill_mid_samples, sample_outputs
from cvj_ros.physics.simulate import Simulation


def _min_cpu(fn, calls: int) -> float:
    """Least CPU time of one call of fn over ``calls`` calls (s)."""
    clock = time.thread_time
    best = np.inf
    for _ in range(calls):
        t0 = clock()
        fn()
        best = min(best, clock() - t0)
    return best


def _batch_cpu(fn, batches: int) -> float:
    """Least CPU time of one call of fn over ``batches`` calls (s): fn is a compiled loop
    over many repetitions of a piece (the caller divides by them), so the least batch is
    the piece's cost with the fewest interruptions, as the runs' min is."""
    return _min_cpu(fn, batches)


def _noop(arity: int):
    """A compiled function of ``arity`` arguments that does nothing (returns (0, -1), as a
    run does)."""
    names = ', '.join(f'a{i}' for i in range(arity))
    scope: dict = {}
    exec(f'def noop({names}):\n    return 0, -1\n', scope)
    return njit(scope['noop'])


@njit
def _outputs_loop(n, times, X, ip, fp, tab, e0, pos, vel, eff, te, tl, res, mtab, mfp):
    bad = 0
    for _ in range(n):
        bad += sample_outputs(times, X, ip, fp, tab, e0, pos, vel, eff, te, tl, res)
        if mtab.shape[0] > 0:
            fill_mid_samples(pos, vel, mtab, mfp)
    return bad


@njit
def _run_loop(n, fn, args):
    bad = 0
    for _ in range(n):
        st, b = fn(*args)
        bad += b + st
    return bad


@njit
def _jac_loop(n, X, ip, fp, times, J):
    # borrowed as the stepper passes them (ros_step borrows its arrays): owned arrays would
    # add jac's reference counts, ~75 ns a call on the stiff model (~77 against ~150 ns)
    (X, ip, fp, times, J) = borrowed_all((X, ip, fp, times, J))
    acc = 0.0
    for r in range(n):
        k = r % X.shape[0]
        rhs_nb.jac(times[k], X[k], ip, fp, J)
        acc += J[0, 0]
    return acc


@njit
def _rows_loop(n, X, ip, fp, times, J):
    """rhs_nb.jac_energy_rows (the refresh of a kept Jacobian) at the run's states."""
    (X, ip, fp, times, J) = borrowed_all((X, ip, fp, times, J))
    acc = 0.0
    for r in range(n):
        k = r % X.shape[0]
        rhs_nb.jac_energy_rows(times[k], X[k], ip, fp, J)
        acc += J[J.shape[0] - 1, 0]
    return acc


@njit
def _rhs_loop(n, X, ip, fp, times, dy):
    acc = 0.0
    for r in range(n):
        k = r % X.shape[0]
        rhs_nb.rhs(times[k], X[k], ip, fp, dy)
        acc += dy[0]
    return acc


def _run_function(sim):
    """The run_nb function of the simulation's method."""
    from cvj_ros.physics.kernel import run_nb
    from cvj_ros.physics.kernel.run_rk_nb import erk_run
    if sim.method in ('tsit5', 'vern6', 'vern7', 'vern8'):
        return erk_run
    return {'dopri5': run_nb.dopri5_run, 'dop853': run_nb.dop853_run, 'rk4': run_nb.rk4_run,
            'ros2': run_nb.ros2_run}.get(sim.method, run_nb.ros_run)


def profile(scene_name: str, solver: str, tol: float, sampling: str, rounds: int = 5,
            calls: int = 2000, horizon: float = 1.0, samples: int = 20,
            breakpoints: bool = True, fidelity: str = 'exact') -> dict[str, float]:
    scene = bench.resolve_scene(scene_name)
    sim = Simulation(scene, method=solver, rtol=tol, atol=tol,
                     fidelity=bench.forced_levels(scene, fidelity))
    dt = horizon / samples
    tr = sim.run(horizon, sample_dt=dt, sampling=sampling, breakpoints=breakpoints)
    sim.run(horizon, sample_dt=dt, sampling=sampling, breakpoints=breakpoints,
            reuse_trace=True)
    plan = next(iter(sim._plans.values()))
    m, n, n_sh = plan.shape
    X, pos, vel, eff = np.empty((m, n)), np.empty((m, n_sh)), np.empty((m, n_sh)), np.empty((m, n_sh))
    te, tl, res = np.empty(m), np.empty(m), np.empty(m)
    XG = X if plan.XG is None else plan.XG
    e0 = sim._initial_energy(sim.driveline.x0)
    per_run = (e0, X, XG, pos, vel, eff, te, tl, res)
    plan.run(*per_run)
    bound = plan.run.__closure__   # the partial over the entry point (after the first call)
    head = None
    for cell in bound:
        v = cell.cell_contents
        if isinstance(v, functools.partial):
            head = v.args
    noop = _noop(len(head) + len(per_run))
    noop(*head, *per_run)
    noop_entry = functools.partial(noop.overloads[noop.signatures[0]].entry_point, *head)
    tab = sim._shaft_table
    ip, fp = sim.model.ip, sim.model.fp
    mtab, mfp, _python = sim._mid_table
    _outputs_loop(1, plan.times, X, ip, fp, tab, e0, pos, vel, eff, te, tl, res, mtab, mfp)
    dy = np.empty(n)
    _rhs_loop(1, X, ip, fp, plan.times, dy)
    nfev = int(tr.solver['nfev'])
    run_fn = _run_function(sim)
    args = (*head, *per_run)
    _run_loop(1, run_fn, args)
    J = np.zeros((n, n))
    _jac_loop(1, X, ip, fp, plan.times, J)
    njev = int(tr.solver.get('njev', 0))
    kept_call = plan.kept_call
    out: dict[str, list[float]] = {k: [] for k in ('whole', 'whole_fresh', 'call', 'dispatch',
                                                   'outputs', 'rhs', 'compiled_run', 'jac')}
    if kept_call is not None:
        out['kept_call'] = []
    for _ in range(rounds):
        out['whole'].append(_min_cpu(lambda: sim.run(horizon, sample_dt=dt, sampling=sampling,
                                                      breakpoints=breakpoints,
                                                      reuse_trace=True), calls))
        out['whole_fresh'].append(_min_cpu(lambda: sim.run(
            horizon, sample_dt=dt, sampling=sampling, breakpoints=breakpoints), calls))
        out['call'].append(_min_cpu(lambda: plan.run(*per_run), calls))
        if kept_call is not None:
            out['kept_call'].append(_min_cpu(lambda: kept_call(e0), calls))
        out['dispatch'].append(_batch_cpu(lambda: [noop_entry(*per_run) for _ in range(100)], 20)
                               / 100)
        k = max(1, int(2e-4 / max(out['call'][-1], 1e-7)))   # ~0.2 ms batches
        out['compiled_run'].append(_batch_cpu(lambda: _run_loop(k, run_fn, args), 30) / k)
        out['outputs'].append(_batch_cpu(
            lambda: _outputs_loop(k, plan.times, X, ip, fp, tab, e0, pos, vel, eff, te, tl, res,
                                  mtab, mfp), 30) / k)
        out['jac'].append(_batch_cpu(lambda: _jac_loop(10_000, X, ip, fp, plan.times, J), 10)
                          / 10_000 * njev)
        out['rhs'].append(_batch_cpu(lambda: _rhs_loop(10_000, X, ip, fp, plan.times, dy), 10)
                          / 10_000 * nfev)
    med = {k: float(np.median(v)) * 1e6 for k, v in out.items()}
    med['nfev'] = nfev
    med['steps'] = int(tr.solver['naccept']) + int(tr.solver['nreject'])
    med['njev'] = int(tr.solver.get('njev', 0))
    med['python'] = med['whole'] - med['call']
    med['python_fresh'] = med['whole_fresh'] - med['call']
    if kept_call is not None:
        med['python_kept'] = med['whole'] - med['kept_call']
    med['call_overhead'] = med['call'] - med['compiled_run']
    med['integration_rest'] = med['compiled_run'] - med['outputs'] - med['rhs'] - med['jac']
    return med


def main() -> None:
    argv = sys.argv[1:]
    fidelity = 'exact'
    if '--fidelity' in argv:
        i = argv.index('--fidelity')
        fidelity = argv[i + 1]
        del argv[i:i + 2]
    scene, solver, tol, sampling = argv[0], argv[1], float(argv[2]), argv[3]
    rounds = int(argv[4]) if len(argv) > 4 else 5
    across = len(argv) > 5 and argv[5] == 'across'
    med = profile(scene, solver, tol, sampling, rounds, breakpoints=not across,
                  fidelity=fidelity)
    print(f'{scene} {solver} tol={tol:g} {sampling}: ' + ', '.join(
        f'{k} {v:.2f}' if isinstance(v, float) else f'{k} {v}' for k, v in med.items()))


if __name__ == '__main__':
    main()
