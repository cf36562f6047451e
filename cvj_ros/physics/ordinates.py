"""Harmonic analysis of m equally spaced ordinates per revolution (Davidbaev et al. 2023, eqs. 4.1-4.5).

A periodic torque M(phi) read at phi_i = 2 pi i / m, i = 0..m-1 (the book's ordinates, m = 12),
is written M = mean + sum_n (a_n cos(n phi) + b_n sin(n phi)), n = 1..floor(m/2), with

    mean = (1/m) sum_i M_i                                   (eq. 4.3)
    a_n  = (2/m) sum_i M_i cos(n phi_i),  b_n = (2/m) sum_i M_i sin(n phi_i)   (eq. 4.2)

except at the Nyquist order n = m/2 (m even), where sin(n phi_i) = 0 and cos(n phi_i) = (-1)^i:
there eq. 4.2's a_n counts the term twice, so the series (eq. 4.4) needs a_{m/2}/2. The
coefficients returned here already carry that factor (a_{m/2} = (1/m) sum_i M_i (-1)^i,
b_{m/2} = 0), so the series through all orders reproduces every ordinate exactly.
Eq. 4.1 writes the constant as M_cp/2 although eq. 4.3 makes M_cp the mean; the constant of
the series is the mean itself.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ['OrdinateHarmonics', 'ordinate_harmonics']

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class OrdinateHarmonics:
    """Fourier coefficients of m ordinates per revolution.

    ``orders`` n = 1..floor(m/2); ``cos_coeffs`` a_n and ``sin_coeffs`` b_n in the unit of the
    ordinates (Nyquist factor included, module doc); ``amplitudes`` A_n = hypot(a_n, b_n);
    ``phases`` p_n (rad) of M = mean + sum A_n cos(n phi + p_n), p_n = atan2(-b_n, a_n), the
    convention of :class:`cvj_ros.physics.signal.AngleHarmonics`.
    """

    mean: float
    orders: NDArray[np.int64]
    cos_coeffs: FloatArray
    sin_coeffs: FloatArray
    amplitudes: FloatArray
    phases: FloatArray

    def synthesize(self, phi: ArrayLike) -> FloatArray:
        """The series mean + sum a_n cos(n phi) + b_n sin(n phi) at ``phi`` (rad)."""
        p = np.asarray(phi, dtype=float)[..., None]
        return self.mean + np.sum(self.cos_coeffs * np.cos(self.orders * p)
                                  + self.sin_coeffs * np.sin(self.orders * p), axis=-1)


def ordinate_harmonics(values: ArrayLike) -> OrdinateHarmonics:
    """Harmonics of ``values``: m >= 2 ordinates of one revolution at phi_i = 2 pi i / m.

    Raises ValueError (message starts with ``values``) for fewer than 2 ordinates, a
    non-1-D array or a non-finite ordinate.
    """
    v = np.asarray(values, dtype=float)
    if v.ndim != 1 or v.size < 2:
        raise ValueError(f'values: need a 1-D array of at least 2 ordinates, got shape {v.shape}')
    if not np.all(np.isfinite(v)):
        raise ValueError('values: every ordinate must be finite')
    m = v.size
    phi = 2.0 * math.pi * np.arange(m) / m
    orders = np.arange(1, m // 2 + 1)
    kp = orders[:, None] * phi[None, :]
    a = 2.0 / m * (np.cos(kp) @ v)
    b = 2.0 / m * (np.sin(kp) @ v)
    if m % 2 == 0:                  # Nyquist order: the term counted once (module doc)
        a[-1] *= 0.5
        b[-1] = 0.0
    return OrdinateHarmonics(mean=float(np.mean(v)), orders=orders, cos_coeffs=a, sin_coeffs=b,
                             amplitudes=np.hypot(a, b), phases=np.arctan2(-b, a))
