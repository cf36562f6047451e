"""physics/tableaux.py: the coefficients the compiled steppers take, without scipy.integrate.

Reference: scipy.integrate.DOP853's own class attributes (the kernel used them directly
before); equality is bitwise (same source file, same slicing), so the compiled DOP853
takes the same steps to the last bit.
"""
from __future__ import annotations

import subprocess
import sys

import numpy as np

from cvj_ros.physics import solvers
from cvj_ros.physics.tableaux import (RODAS_FAC_MAX, ROSENBROCK_TABLEAUX,
                                      dop853_coefficients)


def test_dop853_coefficients_are_scipys_bit_for_bit() -> None:
    from scipy.integrate import DOP853
    (c, a, b, e5, e3), (d, a_extra, c_extra) = dop853_coefficients()
    ref = (DOP853.C, DOP853.A, DOP853.B, DOP853.E5, DOP853.E3, DOP853.D, DOP853.A_EXTRA,
           DOP853.C_EXTRA)
    for got, want in zip((c, a, b, e5, e3, d, a_extra, c_extra), ref):
        assert got.shape == want.shape
        np.testing.assert_array_equal(got, want)
        assert got.tobytes() == np.asarray(want).tobytes()


def test_dop853_coefficients_do_not_import_scipy_integrate() -> None:
    code = ('import sys; from cvj_ros.physics.tableaux import dop853_coefficients; '
            'dop853_coefficients(); print(sorted(m for m in sys.modules '
            'if m.startswith(("scipy.integrate", "scipy.linalg"))))')
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                         timeout=120, check=True).stdout
    assert out.strip() == '[]'


def test_rosenbrock_tableaux_are_the_python_steppers() -> None:
    for method, (tableau, order) in ROSENBROCK_TABLEAUX.items():
        cls = solvers.METHODS[method]
        assert cls._tableau is tableau
        assert (cls.order, cls.fac_max) == (order, RODAS_FAC_MAX)
        want, got = cls._tableau(), tableau()
        for key in want:
            np.testing.assert_array_equal(got[key], want[key])


def _classical_form(tab: dict, weights: np.ndarray) -> tuple[float, np.ndarray, np.ndarray,
                                                               np.ndarray]:
    """(gamma, Gamma, alpha, b) of a K-form tableau (Hairer & Wanner II, sec. IV.7, the
    transformation before (7.4)): Gamma^-1 = diag(1/gamma) - C, alpha = A Gamma,
    b = weights Gamma (weights M for the solution, M - E for the embedded one)."""
    g = float(tab['gamma'])
    s = len(tab['M'])
    G = np.linalg.inv(np.diag(np.full(s, 1.0 / g)) - tab['C'])
    return g, G, tab['A'] @ G, weights @ G


def _order_residuals(g: float, G: np.ndarray, al: np.ndarray, b: np.ndarray) -> list[float]:
    """Residuals of the Rosenbrock order conditions up to order 4 (Hairer & Wanner II,
    Table IV.7.1; beta_ij = alpha_ij + gamma_ij for j < i, beta'_i = sum_j beta_ij,
    alpha_i = sum_j alpha_ij): orders 1, 2, 3, 3, 4, 4, 4, 4."""
    beta = np.tril(al + G, -1)
    bp = beta.sum(1)
    a = al.sum(1)
    return [b.sum() - 1.0, b @ bp - (0.5 - g), b @ a ** 2 - 1 / 3,
            b @ beta @ bp - (1 / 6 - g + g * g), b @ a ** 3 - 0.25,
            (b * a) @ al @ bp - (1 / 8 - g / 3), b @ beta @ a ** 2 - (1 / 12 - g / 3),
            b @ beta @ beta @ bp - (1 / 24 - g / 2 + 1.5 * g * g - g ** 3)]


def test_rosenbrock_tableaux_meet_their_order_conditions() -> None:
    """Each K-form tableau, taken back to the classical form, meets the order conditions of
    its order (up to 4: RODAS5P's order-5 conditions are not listed here) and its embedded
    method those of the embedded order; the orders one above are not met (RODAS3 is order 3,
    not 4; the embedded methods are exactly the order the controller assumes). The time
    nodes and gamma sums the steppers read are the row sums of alpha and Gamma."""
    n_conditions = {1: 1, 2: 2, 3: 4, 4: 8}
    main_order = {'rodas3': 3, 'rodas4': 4, 'rosenbrock': 4}
    for method, (tableau, emb_order) in ROSENBROCK_TABLEAUX.items():
        tab = tableau()
        for weights, order in ((tab['M'], main_order[method]), (tab['M'] - tab['E'], emb_order)):
            g, G, al, b = _classical_form(tab, weights)
            res = _order_residuals(g, G, al, b)
            assert np.max(np.abs(res[:n_conditions[order]])) < 1e-12, (method, order, res)
            if order < 4 and method != 'rosenbrock':
                assert np.max(np.abs(res[n_conditions[order]:n_conditions[order + 1]])) > 1e-3
            np.testing.assert_allclose(al.sum(1), tab['alpha'], atol=1e-12)
            np.testing.assert_allclose(G.sum(1), tab['gamma_sum'], atol=1e-12)
