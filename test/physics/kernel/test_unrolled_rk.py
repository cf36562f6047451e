"""The unrolled explicit steppers (scripts/gen_unrolled_rk.py): the generated parts of
kernel/steppers_rk_nb.py and kernel/steppers_nb.py are the script's output for the current
tableaux, and each unrolled function gives the bits of the loop over the tableau arrays it
replaces (an attempt, the interpolant's extra stages and weights, DOP853's attempt), on a toy
compiled rhs, at random states and step sizes, a stage with a non-finite component included."""
from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest
from numba import njit

from cvj_ros.physics.erk_tableaux import ERK_METHODS, erk_tableau
from cvj_ros.physics.kernel import steppers_nb, steppers_rk_nb
from cvj_ros.physics.kernel.stepper import _dop853_args, steppers_for

ROOT = Path(__file__).resolve().parents[3]
N = 5
IP = np.zeros(1, np.int64)
FP = np.array([0.7, -1.3])


@njit(cache=False)  # toy rhs: not cached
def toy_rhs(t, y, ip, fp, dy):
    n = y.shape[0]
    for i in range(n):
        dy[i] = fp[0] * y[(i + 1) % n] - fp[1] * y[i] * y[i] + t


def _gen():
    spec = importlib.util.spec_from_file_location('gen_unrolled_rk',
                                                  ROOT / 'scripts' / 'gen_unrolled_rk.py')
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_generated_parts_are_the_generators_output():
    gen = _gen()
    for name, (begin, region) in gen.REGIONS.items():
        text = (gen.KERNEL / name).read_text()
        assert gen.rewritten(text, begin, region) == text, name


def _cases(rng, ns_rows):
    """(h, y, K) draws: K's first row f(t, y) and the rest noise (overwritten by the stages
    the attempt evaluates); the last case puts a NaN in one component of K[0]."""
    for k in range(6):
        y = rng.normal(size=N) * 10.0 ** rng.integers(-3, 3)
        K = rng.normal(size=(ns_rows, N))
        h = 10.0 ** rng.uniform(-6, -1)
        if k == 5:
            K[0, 2] = np.nan
        yield h, y, K


def _same(a, b):
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    assert np.array_equal(np.isnan(a), np.isnan(b))
    fin = ~np.isnan(a)
    assert a[fin].tobytes() == b[fin].tobytes()


@pytest.mark.parametrize('method', ERK_METHODS)
def test_erk_unrolled_functions_give_the_loops_bits(method):
    m = steppers_for(toy_rhs, None, steppers_rk_nb)
    tab = erk_tableau(method)
    C, A, B, E, P = tab['C'], tab['A'], tab['B'], tab['E'], tab['P']
    ns, s_all = B.shape[0], C.shape[0]
    rng = np.random.default_rng(11)
    atol = np.full(N, 1e-6)
    for h, y, K in _cases(rng, s_all):
        out = []
        for attempt in (m._attempt, m._attempt_loop):
            Kc, work = K.copy(), np.zeros((4, N))
            fs, cnt = np.zeros(steppers_nb.NFS), np.zeros(steppers_nb.NCNT, np.int64)
            fs[steppers_nb.FS_T] = 0.3
            err = attempt(h, y, IP, FP, fs, cnt, 1e-5, atol, C, A, B, E, Kc, work)
            out.append((err, Kc, work[1].copy(), cnt[steppers_nb.C_NFEV]))
        _same(out[0][0], out[1][0])
        _same(out[0][1], out[1][1])
        _same(out[0][2], out[1][2])
        assert out[0][3] == out[1][3] == ns - 1
        dense = []
        for extra, weights in ((m._extra, m._weights), (m._extra_loop, m._weights_loop)):
            Kc, arg, res = K.copy(), np.zeros(N), np.zeros(N)
            if s_all > ns:
                extra(h, y, IP, FP, 0.3, C, A, ns, Kc, arg)
            for x in (0.0, 0.37, 1.0):
                if weights is m._weights:
                    weights(x, h, y, P, ns, Kc, res)
                else:
                    weights(x, h, y, P, Kc, res)
                dense.append(res.copy())
            dense.append(Kc)
        for a, b in zip(dense[:4], dense[4:]):
            _same(a, b)


def test_dop853_unrolled_attempt_gives_the_loops_bits():
    m = steppers_for(toy_rhs, None, steppers_nb)
    (C, A, B, E5, E3), _dense = _dop853_args()
    rng = np.random.default_rng(12)
    atol = np.full(N, 1e-6)
    for h, y, K in _cases(rng, 23):
        out = []
        for k in range(2):
            Kc, work = K.copy(), np.zeros((4, N))
            if k == 0:
                e = m._dop853_attempt(h, y, IP, FP, 0.3, 1e-5, atol, Kc, work)
            else:
                e = m._dop853_attempt_loop(h, y, IP, FP, 0.3, 1e-5, atol, C, A, B, E5, E3, Kc,
                                           work)
            out.append((e, Kc[:13], work[1].copy()))
        _same(out[0][0], out[1][0])
        _same(out[0][1], out[1][1])
        _same(out[0][2], out[1][2])
