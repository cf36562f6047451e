"""Small linear algebra in a fixed operation order, independent of the CPU's BLAS kernel.

``np.linalg.solve`` (LAPACK getrf/getrs) and ``@`` on float arrays (BLAS gemv/gemm/dot)
pick their kernels by CPU (OPENBLAS_CORETYPE), and kernels differ in summation order and
FMA use, so the last bits of their results differ between machines (measured: the exact
tripod's Fourier table, built with them, gave other bytes under Sandybridge than under
Haswell, and so did every trace of an exact-tripod scene). The functions here use only
elementwise IEEE operations (+, -, *, /, abs: correctly rounded, so the same bytes on every
CPU) in an order fixed by the code. They serve the joint set-up and reaction paths, where
the systems are 3 x 3 (batched) or 10 x 10 and speed is not the point.
"""
from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]


def solve_batched(A: FloatArray, b: FloatArray) -> FloatArray:
    """x with A[..., :, :] x[...] = b[...]: Gaussian elimination with partial pivoting
    (row of largest |pivot| first, ties to the lower row index), vectorised over the
    leading axes. A: (..., n, n), b: (..., n); returns (..., n). A singular system gives
    inf/NaN entries (as a zero pivot divides), never an exception."""
    M = np.array(A, dtype=float, copy=True)
    x = np.array(b, dtype=float, copy=True)
    n = M.shape[-1]
    if M.shape[-2:] != (n, n) or x.shape != M.shape[:-1]:
        raise ValueError(f'solve_batched: A {M.shape} and b {x.shape} do not match')
    lead = M.shape[:-2]
    M = M.reshape((-1, n, n))
    x = x.reshape((-1, n))
    rows = np.arange(M.shape[0])
    for k in range(n):
        p = k + np.argmax(np.abs(M[:, k:, k]), axis=1)    # argmax: first of equal maxima
        swap = p != k
        if np.any(swap):
            r, pk = rows[swap], p[swap]
            Mk, Mp = M[r, k, :].copy(), M[r, pk, :].copy()
            M[r, k, :], M[r, pk, :] = Mp, Mk
            xk, xp = x[r, k].copy(), x[r, pk].copy()
            x[r, k], x[r, pk] = xp, xk
        piv = M[:, k, k]
        for i in range(k + 1, n):
            f = M[:, i, k] / piv
            for j in range(k, n):
                M[:, i, j] = M[:, i, j] - f * M[:, k, j]
            x[:, i] = x[:, i] - f * x[:, k]
    for k in range(n - 1, -1, -1):
        s = x[:, k]
        for j in range(k + 1, n):
            s = s - M[:, k, j] * x[:, j]
        x[:, k] = s / M[:, k, k]
    return x.reshape(lead + (n,))


def solve(A: FloatArray, b: FloatArray) -> FloatArray:
    """x with A x = b for one (n, n) system (see :func:`solve_batched`)."""
    return solve_batched(np.asarray(A, dtype=float)[None], np.asarray(b, dtype=float)[None])[0]


def matvec(M: FloatArray, v: FloatArray) -> FloatArray:
    """M @ v over the last axis of M, summed in index order: sum_j M[..., j] v[j]
    (real arrays: numpy's complex multiply loops are SIMD-dispatched per CPU)."""
    M = np.asarray(M, dtype=float)
    v = np.asarray(v, dtype=float)
    if M.shape[-1] != v.shape[0] or v.ndim != 1:
        raise ValueError(f'matvec: M {M.shape} and v {v.shape} do not match')
    acc = np.zeros(M.shape[:-1])
    for j in range(v.shape[0]):
        acc = acc + M[..., j] * v[j]
    return acc


def dot(a: FloatArray, b: FloatArray) -> float:
    """sum_j a[j] b[j] in index order (1-d float arrays)."""
    s = 0.0
    for x, y in zip(np.asarray(a, dtype=float).tolist(), np.asarray(b, dtype=float).tolist()):
        s += x * y
    return s
