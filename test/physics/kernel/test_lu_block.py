"""The Rosenbrock steppers' linear solve (kernel/steppers_nb.py: lu_factor, lu_solve,
_coupled_size) against numpy.linalg.solve on block lower-triangular matrices, the shape
I/(h gamma) - J takes when the trailing states are quadratures (the energy work integrals:
their columns of J are zero)."""
from __future__ import annotations

import numpy as np
import pytest

from cvj_ros.physics.kernel.steppers_nb import _coupled_size, lu_factor, lu_solve


def _block_matrix(rng: np.random.Generator, n: int, m: int) -> np.ndarray:
    """[[G11, 0], [G21, D]]: G11 m x m (diagonally weighted, with off-diagonal entries large
    enough that partial pivoting swaps rows), G21 dense, D diagonal."""
    G = np.zeros((n, n))
    G[:m, :m] = rng.normal(size=(m, m)) * 3.0 + np.diag(rng.uniform(0.5, 2.0, m))
    G[m:, :m] = rng.normal(size=(n - m, m)) * 10.0
    G[m:, m:] = np.diag(rng.uniform(0.1, 5.0, n - m))
    return G


@pytest.mark.parametrize('n,m', [(7, 4), (5, 5), (23, 20), (3, 1)])
def test_block_solve_matches_numpy(n: int, m: int) -> None:
    rng = np.random.default_rng(n * 100 + m)
    for _ in range(20):
        G = _block_matrix(rng, n, m)
        b = rng.normal(size=n)
        LU = G.copy()
        piv = np.zeros(n, np.int64)
        assert lu_factor(LU, piv, m)
        x = b.copy()
        lu_solve(LU, piv, x, m)
        ref = np.linalg.solve(G, b)
        cond = np.linalg.cond(G)
        assert np.max(np.abs(x - ref)) <= 1e-13 * cond * np.max(np.abs(ref))


def test_block_and_full_factorisation_solve_the_same_system() -> None:
    """m = n is the plain LU; on a block matrix both solve G x = b (to rounding)."""
    rng = np.random.default_rng(3)
    G = _block_matrix(rng, 7, 4)
    b = rng.normal(size=7)
    xs = []
    for m in (4, 7):
        LU, piv, x = G.copy(), np.zeros(7, np.int64), b.copy()
        assert lu_factor(LU, piv, m)
        lu_solve(LU, piv, x, m)
        xs.append(x)
    np.testing.assert_allclose(xs[0], xs[1], rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(G @ xs[0], b, rtol=1e-12, atol=1e-12)


def test_coupled_size_is_the_last_nonzero_column() -> None:
    J = np.zeros((7, 7))
    assert _coupled_size(J) == 0
    J[0, 3] = 1.0            # a driveline of 2 DOF: d(phi_0)/dt = omega_0 ...
    J[5, 1] = -2.0           # ... and an energy row reading a position: columns 4.. are zero
    assert _coupled_size(J) == 4
    J[6, 6] = 1e-300         # any non-zero entry in the last column: the full matrix
    assert _coupled_size(J) == 7


def test_singular_blocks_are_reported() -> None:
    rng = np.random.default_rng(5)
    for hit in ('leading', 'trailing', 'nonfinite'):
        G = _block_matrix(rng, 7, 4)
        if hit == 'leading':
            G[:4, 2] = 0.0
        elif hit == 'trailing':
            G[5, 5] = 0.0
        else:
            G[6, 1] = np.nan
        assert not lu_factor(G, np.zeros(7, np.int64), 4), hit
