"""Where a short Rosenbrock run's fixed cost goes inside the compiled call (docs/benchmark.md,
"The stiff run's fixed cost").

Binds the bench's call (``Simulation.run(1.0, sample_dt=0.05, breakpoints=True,
sampling='dense', reuse_trace=True)``) and times, in compiled loops over the same arguments
(CPU time of this thread, least ~0.2 ms batch, median of ROUNDS rounds), us per run:

- ``whole``: ``Simulation.run`` as the bench calls it;
- ``run``: ``run_nb.ros_run`` (the compiled run, outputs included);
- ``no_outputs``: the same integration without the samples' outputs (a copy of ``ros_run``'s
  body up to its last line);
- ``outputs``: ``sample_outputs`` (+ ``fill_mid_samples``) alone over the run's samples;
- ``rhs``, ``jac``: the run's evaluations x ns per call at the run's states (arrays borrowed
  as the stepper passes them); a model whose Jacobian block is kept (layout.H_JAC_CONST):
  one ``jac`` and njev - 1 ``jac_energy_rows``; ``jac_ns``, ``rows_ns``: ns per call;
- ``allocs_run``, ``allocs_outputs``: NRT allocations per run (numba's
  ``rtsys.get_allocation_stats`` over a loop of runs), in the run and in the outputs alone;
  only with ``NUMBA_NRT_STATS=1`` (the counters are off by default).

    PYTHONPATH=. python scripts/stiff_fixed_cost.py [SCENE [METHOD [TOL [ROUNDS]]]]

(default: stiff rodas3 1e-3 7, ideal fidelity, dense sampling: the bench's cheapest stiff run).
"""
from __future__ import annotations

import sys

import numpy as np
from numba import config, njit
from numba.core.runtime import rtsys

from cvj_ros import bench
from cvj_ros.physics.kernel import run_nb
from cvj_ros.physics.kernel.layout import H_JAC_CONST
from cvj_ros.physics.kernel.steppers_nb import ST_OK, ros_land, ros_sample
from cvj_ros.physics.simulate import Simulation
from run_profile import (   # scripts/ is on the path when run as a script
    _jac_loop, _min_cpu, _outputs_loop, _rhs_loop, _rows_loop)
from run_profile import _run_loop as _loop


# A copy of run_nb.ros_run without its last line (the outputs): keep it in step with ros_run.
@njit
def _ros_run_no_outputs(fpk, ipk, fbuf, ibuf, y, ip, fp, mfp, h0, rtol, max_step, autonomous,
                        constant_jac, gamma, order, fac_max, hermite_row, e0, X, XG, pos, vel,
                        eff, te, tl, res):
    (fpk, ipk, fbuf, ibuf, y, ip, fp, mfp, X, XG) = run_nb.borrowed_all(
        (fpk, ipk, fbuf, ibuf, y, ip, fp, mfp, X, XG))
    (x0, times, grid, brk, tb, two, atol, fs, y_old, K, work, rows, seg, tab,
     cnt) = run_nb._common(fpk, ipk, fbuf, ibuf)
    J, LU, ft, piv = run_nb._linear(fpk, ipk, fbuf, ibuf)
    A, C = run_nb._f2(run_nb.E_A, fpk, ipk, fbuf), run_nb._f2(run_nb.E_C, fpk, ipk, fbuf)
    H = run_nb._f2(run_nb.E_H, fpk, ipk, fbuf)
    M, E = run_nb._f1(run_nb.E_MW, fpk, ipk, fbuf), run_nb._f1(run_nb.E_E, fpk, ipk, fbuf)
    alpha = run_nb._f1(run_nb.E_ALPHA, fpk, ipk, fbuf)
    gsum = run_nb._f1(run_nb.E_GSUM, fpk, ipk, fbuf)
    run_nb._start(x0, h0, X, fbuf, ibuf, y, y_old, fs)
    if grid.shape[0] > 0:
        st, _k = ros_land(grid, XG, y, y_old, ip, fp, fs, cnt, rtol, atol, max_step,
                          autonomous, constant_jac, gamma, A, C, M, E, alpha, gsum, order,
                          fac_max, J, LU, piv, ft, K, work)
        if st != ST_OK:
            return st, -1
        run_nb._gather(X, XG, rows)
    else:
        for i in range(seg.shape[0]):
            k, k_end = seg[i, 0], seg[i, 1]
            if k_end > k:
                st, _k = ros_sample(times[k:k_end], X[k:k_end], y, y_old, ip, fp, fs, cnt,
                                    rtol, atol, max_step, autonomous, constant_jac, gamma, A,
                                    C, M, E, alpha, gsum, order, fac_max, J, LU, piv, ft, K,
                                    work, H, hermite_row)
                if st != ST_OK:
                    return st, -1
            if run_nb._to_breakpoint(brk[i], fs, tb):
                st, _k = ros_land(tb, two, y, y_old, ip, fp, fs, cnt, rtol, atol,
                                  max_step, autonomous, constant_jac, gamma, A, C, M, E,
                                  alpha, gsum, order, fac_max, J, LU, piv, ft, K, work)
                if st != ST_OK:
                    return st, -1
    return ST_OK, -1


def _allocs(loop, reps: int = 100) -> float:
    """NRT allocations per pass of the compiled ``loop(n)`` (numba's allocation counters):
    the difference between ``reps + 1`` passes and one, so the meminfos that unboxing the
    arguments from Python allocates per call are not counted."""
    def count(n: int) -> int:
        a0 = rtsys.get_allocation_stats().alloc
        loop(n)
        return rtsys.get_allocation_stats().alloc - a0
    count(1)
    return (count(reps + 1) - count(1)) / reps


def profile(scene_name: str = 'stiff', method: str = 'rodas3', tol: float = 1e-3,
            rounds: int = 7, fidelity: str = 'ideal') -> dict[str, float]:
    scene = bench._scene_for(bench.resolve_scene(scene_name))
    sim = Simulation(scene, method=method, rtol=tol, atol=tol,
                     fidelity=bench.forced_levels(scene, fidelity))

    def whole():
        return sim.run(1.0, sample_dt=1 / 20, breakpoints=True, sampling='dense',
                       reuse_trace=True)
    tr = whole()
    whole()
    plan = next(iter(sim._plans.values()))
    trace, per_run, _final = plan.kept
    head = plan.call.args                          # the bound entry point's fixed arguments
    e0 = sim._initial_energy(sim.driveline.x0)
    args = (*head, e0, *per_run)
    X, pos, vel, eff, te, tl, res = per_run[0], *per_run[2:]
    ip, fp, tab = sim.model.ip, sim.model.fp, sim._shaft_table
    mtab, mfp, _python = sim._mid_table
    times = plan.times
    n = X.shape[1]
    dy, J = np.empty(n), np.zeros((n, n))
    out_args = (times, X, ip, fp, tab, e0, pos, vel, eff, te, tl, res, mtab, mfp)
    _loop(1, run_nb.ros_run, args)
    _loop(1, _ros_run_no_outputs, args)
    _outputs_loop(1, *out_args)
    _rhs_loop(1, X, ip, fp, times, dy)
    _jac_loop(1, X, ip, fp, times, J)
    nfev, njev = int(tr.solver['nfev']), int(tr.solver.get('njev', 0))
    # a model whose Jacobian block is kept (layout.H_JAC_CONST): one whole jac, then the
    # work integrals' rows at each later evaluation (steppers_nb._ros_jacobian)
    kept = bool(ip[H_JAC_CONST]) and njev > 0
    n_full, n_rows = (1, njev - 1) if kept else (njev, 0)
    if kept:
        _rows_loop(1, X, ip, fp, times, J)
    out: dict[str, list[float]] = {k: [] for k in ('whole', 'run', 'no_outputs', 'outputs',
                                                   'rhs', 'jac', 'jac_ns', 'rows_ns')}
    k = 20
    for _ in range(rounds):
        out['whole'].append(_min_cpu(whole, 2000))
        out['run'].append(_min_cpu(lambda: _loop(k, run_nb.ros_run, args), 200) / k)
        out['no_outputs'].append(_min_cpu(lambda: _loop(k, _ros_run_no_outputs, args), 200) / k)
        out['outputs'].append(_min_cpu(lambda: _outputs_loop(k, *out_args), 200) / k)
        out['rhs'].append(_min_cpu(lambda: _rhs_loop(10_000, X, ip, fp, times, dy), 10)
                          / 10_000 * nfev)
        jac_s = _min_cpu(lambda: _jac_loop(10_000, X, ip, fp, times, J), 10) / 10_000
        rows_s = (_min_cpu(lambda: _rows_loop(10_000, X, ip, fp, times, J), 10) / 10_000
                  if kept else 0.0)
        out['jac'].append(jac_s * n_full + rows_s * n_rows)
        out['jac_ns'].append(jac_s * 1e3)
        out['rows_ns'].append(rows_s * 1e3)
    med = {key: float(np.median(v)) * 1e6 for key, v in out.items()}
    med['rest'] = med['no_outputs'] - med['rhs'] - med['jac']
    if config.NRT_STATS:    # NUMBA_NRT_STATS=1 (counters off by default: timed without)
        med['allocs_run'] = _allocs(lambda n: _loop(n, run_nb.ros_run, args))
        med['allocs_outputs'] = _allocs(lambda n: _outputs_loop(n, *out_args))
    med['nfev'], med['njev'] = nfev, njev
    med['steps'] = int(tr.solver['naccept']) + int(tr.solver['nreject'])
    med['samples'] = int(times.shape[0])
    return med


def main() -> None:
    argv = sys.argv[1:]
    scene = argv[0] if argv else 'stiff'
    method = argv[1] if len(argv) > 1 else 'rodas3'
    tol = float(argv[2]) if len(argv) > 2 else 1e-3
    rounds = int(argv[3]) if len(argv) > 3 else 7
    med = profile(scene, method, tol, rounds)
    print(f'{scene} {method} tol={tol:g} dense (us per run): ' + ', '.join(
        f'{k} {v:.2f}' if isinstance(v, float) else f'{k} {v}' for k, v in med.items()))


if __name__ == '__main__':
    main()
