"""Harmonics of m ordinates per revolution (Davidbaev et al. 2023 eqs. 4.1-4.5) against known signals."""
import math

import numpy as np
import pytest

from cvj_ros.physics.ordinates import ordinate_harmonics


def _signal(phi):
    # known harmonics: mean 230, orders 1..6 (6 = Nyquist of m = 12, a cosine there)
    return (230.0 + 25.0 * np.cos(phi - 0.4) + 8.0 * np.sin(2 * phi) - 3.0 * np.cos(3 * phi)
            + 2.5 * np.cos(4 * phi + 1.1) + 1.5 * np.sin(5 * phi + 0.3) + 1.2 * np.cos(6 * phi))


def test_recovers_known_harmonics_including_nyquist():
    phi = 2 * math.pi * np.arange(12) / 12
    h = ordinate_harmonics(_signal(phi))
    assert h.mean == pytest.approx(230.0, abs=1e-12)
    np.testing.assert_allclose(h.amplitudes, [25.0, 8.0, 3.0, 2.5, 1.5, 1.2], atol=1e-12)
    # order 1: 25 cos(phi - 0.4) = A cos(phi + p) with p = -0.4
    assert h.phases[0] == pytest.approx(-0.4, abs=1e-12)
    # the Nyquist term carries a6/2: eq. 4.2's a6 would be twice the true 1.2
    nyq_eq42 = 2 / 12 * np.sum(_signal(phi) * np.cos(6 * phi))
    assert nyq_eq42 == pytest.approx(2.4, abs=1e-12)
    assert h.cos_coeffs[-1] == pytest.approx(1.2, abs=1e-12) and h.sin_coeffs[-1] == 0.0


def test_series_reproduces_every_ordinate():
    rng = np.random.default_rng(4)
    for m in (12, 13, 2, 3):
        v = rng.normal(200.0, 20.0, m)
        h = ordinate_harmonics(v)
        np.testing.assert_allclose(h.synthesize(2 * math.pi * np.arange(m) / m), v, atol=1e-10)


def test_bad_input_names_values():
    for bad in ([1.0], [[1.0, 2.0]], [1.0, math.nan]):
        with pytest.raises(ValueError, match='^values'):
            ordinate_harmonics(bad)
