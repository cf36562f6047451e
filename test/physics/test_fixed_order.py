"""cvj_ros.physics.fixed_order: the BLAS-free small solves agree with LAPACK to rounding
and give the same bytes whatever OPENBLAS_CORETYPE says."""
from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest

from cvj_ros.physics.fixed_order import dot, matvec, solve, solve_batched


def test_batched_3x3_matches_lapack_to_rounding() -> None:
    """Random systems with condition number <= 1e3: Gaussian elimination with partial
    pivoting is backward stable, so |x - x_lapack| / |x| <= ~cond * n * eps ~ 1e-12."""
    rng = np.random.default_rng(3)
    A = rng.normal(size=(500, 3, 3))
    b = rng.normal(size=(500, 3))
    cond = np.linalg.cond(A)
    keep = cond < 1e3
    x = solve_batched(A[keep], b[keep])
    ref = np.linalg.solve(A[keep], b[keep][..., None])[..., 0]
    err = np.max(np.abs(x - ref), axis=1) / np.max(np.abs(ref), axis=1)
    assert np.max(err) < 1e-12
    np.testing.assert_allclose(np.einsum('nij,nj->ni', A[keep], x), b[keep], atol=1e-12)


def test_pivoting_handles_a_zero_leading_pivot_and_10x10() -> None:
    A = np.array([[0.0, 2.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 3.0]])
    b = np.array([3.0, 1.0, 4.0])
    np.testing.assert_allclose(solve(A, b), np.linalg.solve(A, b), rtol=1e-14)
    rng = np.random.default_rng(5)
    A10 = rng.normal(size=(10, 10)) + 10 * np.eye(10)
    b10 = rng.normal(size=10)
    np.testing.assert_allclose(solve(A10, b10), np.linalg.solve(A10, b10), rtol=1e-13)
    # leading axes are kept
    assert solve_batched(np.broadcast_to(A, (2, 4, 3, 3)), np.broadcast_to(b, (2, 4, 3))).shape == (2, 4, 3)


def test_matvec_and_dot_sum_in_index_order() -> None:
    M = np.array([[1e16, 1.0, -1e16], [1.0, 2.0, 3.0]])
    v = np.array([1.0, 1.0, 1.0])
    # in index order: (1e16 + 1) - 1e16 = 0 (1 is lost to rounding), 1 + 2 + 3 = 6
    np.testing.assert_array_equal(matvec(M, v), [0.0, 6.0])
    assert dot([1e16, 1.0, -1e16], [1.0, 1.0, 1.0]) == 0.0
    rng = np.random.default_rng(1)
    M = rng.normal(size=(7, 40))
    v = rng.normal(size=40)
    np.testing.assert_allclose(matvec(M, v), M @ v, rtol=1e-13, atol=1e-13)
    with pytest.raises(ValueError):
        matvec(M, v[:3])


CORES = ('Haswell', 'Sandybridge', 'Prescott')
PROBE = '''
import hashlib, numpy as np
from cvj_ros.physics.fixed_order import solve_batched, matvec
rng = np.random.default_rng(11)
A = rng.normal(size=(300, 3, 3)); b = rng.normal(size=(300, 3))
M = rng.normal(size=(300, 64)); v = rng.normal(size=64)
print(hashlib.sha256(solve_batched(A, b).tobytes() + matvec(M, v).tobytes()).hexdigest())
'''


def test_bytes_do_not_depend_on_the_openblas_kernel() -> None:
    """Fresh interpreters under several OPENBLAS_CORETYPE values print one digest
    (SkylakeX is left out: forcing it on a CPU without AVX-512 dies with SIGILL)."""
    digests = set()
    for core in CORES:
        env = dict(os.environ, OPENBLAS_CORETYPE=core)
        r = subprocess.run([sys.executable, '-c', PROBE], env=env, capture_output=True, text=True,
                           timeout=120)
        assert r.returncode == 0, r.stderr
        digests.add(r.stdout.strip())
    assert len(digests) == 1, digests
