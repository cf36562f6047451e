"""Inside the compiled Rosenbrock stepper: each piece of a step timed alone (docs/benchmark.md,
"Where the time goes").

Runs the bench's call (``Simulation.run(1.0, sample_dt=0.05)``) once, then takes the plan
stepper's arrays at the run's end (its state, last Jacobian, LU, stages) as the data of
compiled loops that repeat one piece of ``kernel/steppers_nb.py``'s ``ros_step`` per pass,
restoring what the piece writes between passes (the restore loop is timed alone and
subtracted). Per piece: ns per call (CPU time of this thread, least ~0.2 ms batch, median of
ROUNDS rounds), and per run (x the run's count of that piece):

- ``start``: ``run_nb._start`` (zero the stepper's buffers, x0 into y, y_old, X[0]);
- ``hinit``: ``_initial_step`` (Hairer's HINIT) minus its one rhs;
- ``lu``: I/(h gamma) - J assembled and ``lu_factor`` of its coupled block (``_coupled_size``):
  ``_ros_prepare`` with f and J valid, so it refactors only;
- ``solve``: one ``lu_solve`` (a Rosenbrock step makes one per stage);
- ``stages``: ``_ros_stages`` minus its rhs evaluations (the stage sums and the solves);
- ``error``: the error norm and the PI controller (``_proposal``: two powers);
- ``step``: a whole accepted ``ros_step`` with a new Jacobian minus its rhs and Jacobian
  evaluations;
- ``stages_hoisted``: a candidate ``_ros_stages`` dividing C_sj by h once per (s, j) (not
  the kernel's code; its bytes are checked against the kernel's, ``hoisted_same_bytes``);
- ``dense``: one cubic Hermite sample (rodas3 / rodas4 samples between steps), the body
  ``ros_sample`` inlines (``_hermite_into``);
- ``rhs``, ``jac``: one evaluation each, to subtract.

    PYTHONPATH=. python scripts/rosenbrock_profile.py [SCENE [METHOD [TOL [ROUNDS]]]]

(default: stiff rodas3 1e-3 5, dense sampling as the bench's cheapest stiff run).
"""
from __future__ import annotations

import math
import sys

import numpy as np
from numba import njit

from cvj_ros import bench
from cvj_ros.physics.kernel import run_nb, steppers_nb as nb
from cvj_ros.physics.kernel.borrow_nb import borrowed_all
from cvj_ros.physics.kernel.rhs_nb import jac as JAC
from cvj_ros.physics.kernel.rhs_nb import rhs as RHS
from cvj_ros.physics.simulate import Simulation
from run_profile import _min_cpu   # scripts/ is on the path when run as a script


@njit
def _restore(reps, y, y0, fs, fs0, cnt, cnt0):
    acc = 0.0
    for _ in range(reps):
        y[:] = y0
        fs[:] = fs0
        cnt[:] = cnt0
        acc += y[0]
    return acc


@njit
def _start_loop(reps, x0, h0, X, fbuf, ibuf, y, y_old, fs):
    acc = 0.0
    for _ in range(reps):
        run_nb._start(x0, h0, X, fbuf, ibuf, y, y_old, fs)
        acc += fs[nb.FS_H]
    return acc


@njit
def _hinit_loop(reps, y, f0, ip, fp, fs, cnt, rtol, atol, order, tmp, f1):
    acc = 0.0
    for _ in range(reps):
        acc += nb._initial_step(y, f0, ip, fp, fs, cnt, rtol, atol, math.inf, order, tmp, f1)
    return acc


@njit
def _lu_loop(reps, h, gamma, y, ip, fp, fs, cnt, autonomous, J, LU, piv, ft, K, work):
    """The kernel's own ``_ros_prepare`` with f(t, y) and the Jacobian valid (C_HAVEF,
    C_HAVEJ set by the caller) and the LU marked stale each pass: it assembles
    I/(h gamma) - J and factors its coupled block, nothing else."""
    ok = 0
    for _ in range(reps):
        cnt[nb.C_HAVELU] = 0
        ok += nb._ros_prepare(h, gamma, y, ip, fp, fs, cnt, autonomous, J, LU, piv, ft, K,
                              work) == nb.ST_OK
    return ok


@njit
def _solve_loop(reps, LU, piv, b, b0, m):
    acc = 0.0
    for _ in range(reps):
        b[:] = b0
        nb.lu_solve(LU, piv, b, m)
        acc += b[0]
    return acc


@njit
def _copy_loop(reps, b, b0):
    acc = 0.0
    for _ in range(reps):
        b[:] = b0
        acc += b[0]
    return acc


@njit
def _stages_loop(reps, h, y, ip, fp, fs, cnt, A, C, M, alpha, gsum, LU, piv, ft, K, work):
    acc = 0.0
    for _ in range(reps):
        nb._ros_stages(h, y, ip, fp, fs, cnt, A, C, M, alpha, gsum, LU, piv, ft, K, work)
        acc += work[1, 0]
    return acc


# A copy of kernel/steppers_nb._ros_stages, changed where the candidate differs (the C sums):
# what it measures is that change, so it cannot call the kernel's function. Keep the rest in
# step with _ros_stages; the run prints hoisted_same_bytes 0 once the two give other bytes.
@njit(inline='always')
def _stages_hoisted(h, y, ip, fp, fs, cnt, A, C, M, alpha, gsum, LU, piv, ft, K, work):
    """``_ros_stages`` with the C sums run j outside i (C_sj / h divided once per (s, j),
    accumulated in work[0]): the same additions per state in the same order - a candidate
    timed beside the kernel's own (``stages_hoisted``) and checked for the same bytes."""
    n = y.shape[0]
    st = M.shape[0]
    t = fs[nb.FS_T]
    arg = work[0]
    lum = cnt[nb.C_LUM]
    for s in range(st):
        b = K[s + 1]
        if s == 0:
            for i in range(n):
                b[i] = K[0, i] + (h * gsum[0]) * ft[i]
        elif nb._stage_at_start(s, A, alpha):
            for i in range(n):
                b[i] = K[0, i]
        else:
            for i in range(n):
                acc = 0.0
                for j in range(s):
                    acc += A[s, j] * K[j + 1, i]
                arg[i] = y[i] + acc
            RHS(t + alpha[s] * h, arg, ip, fp, b)
            cnt[nb.C_NFEV] += 1
        if s > 0:
            for i in range(n):
                arg[i] = 0.0
            for j in range(s):
                c = C[s, j] / h
                for i in range(n):
                    arg[i] += c * K[j + 1, i]
            hg = h * gsum[s]
            for i in range(n):
                b[i] += arg[i] + hg * ft[i]
        nb.lu_solve(LU, piv, b, lum)
    ynew = work[1]
    for i in range(n):
        acc = 0.0
        for j in range(st):
            acc += M[j] * K[j + 1, i]
        ynew[i] = y[i] + acc


@njit
def _hoisted_loop(reps, h, y, ip, fp, fs, cnt, A, C, M, alpha, gsum, LU, piv, ft, K, work):
    acc = 0.0
    for _ in range(reps):
        _stages_hoisted(h, y, ip, fp, fs, cnt, A, C, M, alpha, gsum, LU, piv, ft, K, work)
        acc += work[1, 0]
    return acc


# A copy of the error norm in kernel/steppers_nb.ros_step (written inline there, no function
# to call) followed by the kernel's own _proposal: keep it in step with ros_step.
@njit
def _error_loop(reps, h, y, ynew, K, E, rtol, atol, fs, errold, order, fac_max):
    n = y.shape[0]
    st_n = E.shape[0]
    expo = 1.0 / (order + 1) - 0.75 * nb.BETA
    acc = 0.0
    for _ in range(reps):
        fs[nb.FS_ERROLD] = errold
        ss = 0.0
        for i in range(n):
            e = 0.0
            for j in range(st_n):
                e += E[j] * K[j + 1, i]
            sc = max(abs(y[i]), abs(ynew[i])) * rtol + atol[i]
            ss += (e / sc) ** 2
        err = math.sqrt(ss / n)
        acc += nb._proposal(h, err, fs, expo, fac_max)
    return acc


@njit
def _step_loop(reps, y, y0, fs, fs0, cnt, cnt0, y_old, ip, fp, rtol, atol, autonomous, gamma,
               A, C, M, E, alpha, gsum, order, fac_max, J, LU, piv, ft, K, work):
    acc = 0.0
    for _ in range(reps):
        y[:] = y0
        fs[:] = fs0
        cnt[:] = cnt0
        nb.ros_step(math.inf, y, y_old, ip, fp, fs, cnt, rtol, atol, math.inf, autonomous,
                    False, gamma, A, C, M, E, alpha, gsum, order, fac_max, J, LU, piv, ft, K,
                    work)
        acc += y[0]
    return acc


@njit
def _dense_loop(reps, t, y, y_old, ip, fp, fs, cnt, K, out, frow):
    # borrowed as ros_sample's arrays are (the inlined body's views count no references)
    y, y_old, ip, fp, fs, cnt, K, out = borrowed_all((y, y_old, ip, fp, fs, cnt, K, out))
    acc = 0.0
    for _ in range(reps):
        nb._hermite_into(t, y, y_old, ip, fp, fs, cnt, K, out, frow)
        acc += out[0]
    return acc


@njit
def _rhs_loop(reps, t, y, ip, fp, dy):
    acc = 0.0
    for _ in range(reps):
        RHS(t, y, ip, fp, dy)
        acc += dy[0]
    return acc


@njit
def _jac_loop(reps, t, y, ip, fp, J):
    acc = 0.0
    for _ in range(reps):
        JAC(t, y, ip, fp, J)
        acc += J[0, 0]
    return acc


def profile(scene_name: str = 'stiff', method: str = 'rodas3', tol: float = 1e-3,
            rounds: int = 5, sampling: str = 'dense') -> dict[str, float]:
    """ns per call of each piece (see the module docstring) and the run's counts."""
    scene = bench.resolve_scene(scene_name)
    sim = Simulation(scene, method=method, rtol=tol, atol=tol,
                     fidelity=bench.forced_levels(scene, 'exact'))
    tr = sim.run(1.0, sample_dt=0.05, sampling=sampling)
    plan = next(iter(sim._plans.values()))
    st = plan.stepper
    ip, fp = sim.model.ip, sim.model.fp
    gamma, A, C, M, E, alpha, gsum, order, fac_max = st._tab
    y, fs, cnt, K, work = st._y, st._fs, st._cnt, st._K, st._work
    J, LU, piv, ft, atol = st._J, st._LU, st._piv, st._ft, st._atol
    n = y.size
    h = float(fs[nb.FS_HLAST])
    t = float(fs[nb.FS_T])
    y0, fs0 = y.copy(), fs.copy()
    cnt0 = cnt.copy()
    cnt0[nb.C_HAVEF] = 1          # K[0] = f(t, y) valid: the step starts with its Jacobian
    cnt0[nb.C_HAVEJ] = 0
    cnt0[nb.C_HAVELU] = 0
    RHS(t, y, ip, fp, K[0])
    JAC(t, y, ip, fp, J)
    X = np.empty((2, n))
    m = int(cnt[nb.C_LUM]) or n
    b0 = K[0].copy()
    b = np.empty(n)
    dy = np.empty(n)
    tmp, f1 = np.empty(n), np.empty(n)
    frow = K.shape[0] - 1
    errold = float(fs[nb.FS_ERROLD])
    h0 = 0.0
    fbuf, ibuf = st._fbuf.copy(), st._ibuf.copy()   # _start zeroes these: copies
    fsv, yv = fbuf[:nb.NFS], np.empty(n)
    autonomous = sim.autonomous
    cnt_lu = cnt0.copy()
    cnt_lu[nb.C_HAVEJ] = 1        # the 'lu' piece: J valid, so _ros_prepare only refactors
    reps = 2000
    pieces = {
        'restore': lambda: _restore(reps, y, y0, fs, fs0, cnt, cnt0),
        'copy': lambda: _copy_loop(reps, b, b0),
        'start': lambda: _start_loop(reps, y0, h0, X, fbuf, ibuf, yv, tmp, fsv),
        'hinit': lambda: _hinit_loop(reps, y0, b0, ip, fp, fs0.copy(), cnt0.copy(), tol, atol,
                                     order, tmp, f1),
        'lu': lambda: _lu_loop(reps, h, gamma, y0, ip, fp, fs0.copy(), cnt_lu.copy(), autonomous,
                               J, LU, piv, ft, K, work),
        'solve': lambda: _solve_loop(reps, LU, piv, b, b0, m),
        'stages': lambda: _stages_loop(reps, h, y0, ip, fp, fs0.copy(), cnt0.copy(), A, C, M,
                                       alpha, gsum, LU, piv, ft, K, work),
        'stages_hoisted': lambda: _hoisted_loop(reps, h, y0, ip, fp, fs0.copy(), cnt0.copy(), A,
                                                C, M, alpha, gsum, LU, piv, ft, K, work),
        'error': lambda: _error_loop(reps, h, y0, work[1], K, E, tol, atol, fs0.copy(), errold,
                                     order, fac_max),
        'step': lambda: _step_loop(reps, y, y0, fs, fs0, cnt, cnt0, X[1], ip, fp, tol, atol,
                                   autonomous, gamma, A, C, M, E, alpha, gsum, order, fac_max,
                                   J, LU, piv, ft, K, work),
        'dense': lambda: _dense_loop(reps, t - 0.5 * h, y0, y0.copy(), ip, fp, fs0, cnt0, K,
                                     tmp, frow),
        'rhs': lambda: _rhs_loop(reps, t, y0, ip, fp, dy),
        'jac': lambda: _jac_loop(reps, t, y0, ip, fp, J),
    }
    for fn in pieces.values():   # compile
        fn()
    # the candidate gives the kernel's bytes: stages and y_new of both from the same start
    _stages_loop(1, h, y0, ip, fp, fs0.copy(), cnt0.copy(), A, C, M, alpha, gsum, LU, piv,
                 ft, K, work)
    kernel_bytes = K.tobytes() + work[1].tobytes()
    _hoisted_loop(1, h, y0, ip, fp, fs0.copy(), cnt0.copy(), A, C, M, alpha, gsum, LU, piv,
                  ft, K, work)
    same = K.tobytes() + work[1].tobytes() == kernel_bytes
    # the stage's rhs count: the stages that evaluate f (not at (t, y) itself)
    stage_rhs = sum(1 for s in range(1, M.size)
                    if alpha[s] != 0.0 or any(A[s, j] != 0.0 for j in range(s)))
    out: dict[str, list[float]] = {k: [] for k in pieces}
    for _ in range(rounds):
        for k, fn in pieces.items():
            out[k].append(_min_cpu(fn, 20) / reps * 1e9)
    med = {k: float(np.median(v)) for k, v in out.items()}
    med['hinit'] -= med['rhs']
    med['solve'] -= med['copy']
    med['stages'] -= stage_rhs * med['rhs']
    med['stages_hoisted'] -= stage_rhs * med['rhs']
    med['hoisted_same_bytes'] = int(same)
    ft_rhs = 0 if autonomous else 2   # f_t by a central difference with a new Jacobian
    med['step'] -= med['restore'] + (stage_rhs + ft_rhs) * med['rhs'] + med['jac'] + med['lu']
    med['step_lu'] = med['lu']
    med['steps'] = int(tr.solver['naccept']) + int(tr.solver['nreject'])
    med['nfev'] = int(tr.solver['nfev'])
    med['njev'] = int(tr.solver['njev'])
    med['nlu'] = int(tr.solver['nlu'])
    med['stage_solves'] = int(M.size)
    med['stage_rhs'] = stage_rhs
    med['n'], med['lu_block'] = n, m
    return med


def main() -> None:
    a = sys.argv[1:]
    med = profile(a[0] if a else 'stiff', a[1] if len(a) > 1 else 'rodas3',
                  float(a[2]) if len(a) > 2 else 1e-3, int(a[3]) if len(a) > 3 else 5)
    print(', '.join(f'{k} {v:.1f}' if isinstance(v, float) else f'{k} {v}'
                    for k, v in med.items()))
    steps, nlu = med['steps'], med['nlu']
    print(f"per run (us): start {med['start'] / 1e3:.2f}, hinit {med['hinit'] / 1e3:.2f}, "
          f"LU x{nlu} {med['lu'] * nlu / 1e3:.2f}, stages x{steps} (of it "
          f"{med['stage_solves']} solves each: {med['solve'] * med['stage_solves'] * steps / 1e3:.2f}) "
          f"{med['stages'] * steps / 1e3:.2f}, error+control x{steps} {med['error'] * steps / 1e3:.2f}, "
          f"step's own without LU x{steps} {med['step'] * steps / 1e3:.2f}")


if __name__ == '__main__':
    main()
