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
