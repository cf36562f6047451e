"""Signal processing of recorded shaft signals (no ROS): amplitudes, nonuniformity, harmonics.

Definitions used throughout (SI units: rad, rad/s, rad/s^2, N m, s):

* amplitude of a signal = (max - min) / 2 over the analysed window
  (Davidbaev et al. 2023, ch. 4, "amplitude of oscillations A_M", read from oscillograms);
* speed nonuniformity delta = (omega_max - omega_min) / omega_mean (the "unevenness of the
  angular velocities" delta_1, delta_2 of Davidbaev et al. 2023, sections 3.3 and 4, fig. 4.9);
* harmonic analysis over shaft angle (Davidbaev et al. 2023, eqs. 4.1-4.3): the signal is resampled on a
  uniform grid of m points per revolution over whole revolutions and
  a_k = (2/M) sum_i T_i cos(k phi_i), b_k = (2/M) sum_i T_i sin(k phi_i), mean = (1/M) sum_i T_i,
  M = m * revolutions. Written as T = mean + sum A_k cos(k phi + p_k):
  A_k = sqrt(a_k^2 + b_k^2), p_k = atan2(-b_k, a_k). (The seed's own phase convention,
  T = mean + sum A_k sin(k phi + psi_k), is psi_k = atan2(a_k, b_k) = p_k + pi/2.)
* joint nonuniformity (Bugaru & Vasile 2021, eqs. 20-23): geometric Delta phi = phi_out - phi_in (rad),
  kinematic = omega_out / omega_in - 1 (-).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]


def half_range(values: ArrayLike) -> float:
    """Amplitude (max - min) / 2 of a signal, same unit as ``values`` (Davidbaev et al. 2023, ch. 4)."""
    arr = np.asarray(values, dtype=float)
    if arr.size == 0:
        raise ValueError('values: empty signal')
    return float(0.5 * (np.max(arr) - np.min(arr)))


def speed_nonuniformity(omega: ArrayLike) -> float:
    """Speed unevenness delta = (w_max - w_min) / w_mean (-), Davidbaev et al. 2023, fig. 4.9 (delta_1, delta_2).

    ``omega`` in rad/s. Returns ``nan`` when the mean speed is zero (standstill).
    """
    w = np.asarray(omega, dtype=float)
    if w.size == 0:
        raise ValueError('omega: empty signal')
    mean = float(np.mean(w))
    if mean == 0.0:
        return math.nan
    return float((np.max(w) - np.min(w)) / abs(mean))


def time_derivative(t: ArrayLike, values: ArrayLike) -> FloatArray:
    """Second-order central difference d(values)/dt on a possibly non-uniform grid (unit/s)."""
    tt = np.asarray(t, dtype=float)
    vv = np.asarray(values, dtype=float)
    if tt.size < 2:
        return np.zeros_like(vv)
    return np.gradient(vv, tt, edge_order=2 if tt.size > 2 else 1)


@dataclass(frozen=True)
class AngleHarmonics:
    """Fourier analysis of a signal over shaft angle (Davidbaev et al. 2023, eqs. 4.1-4.3).

    ``orders`` k = 1..n; ``cos_coeffs`` a_k, ``sin_coeffs`` b_k, ``amplitudes`` A_k in the unit of
    the signal; ``phases`` p_k (rad, in (-pi, pi]) of T = mean + sum A_k cos(k phi + p_k);
    ``revolutions`` analysed; ``phi_grid`` (rad, uniform, whole revolutions) and ``values_grid``
    the resampled signal.
    """

    mean: float
    orders: NDArray[np.int64]
    cos_coeffs: FloatArray
    sin_coeffs: FloatArray
    amplitudes: FloatArray
    phases: FloatArray
    revolutions: int
    phi_grid: FloatArray
    values_grid: FloatArray

    def synthesize(self, phi: ArrayLike) -> FloatArray:
        """The truncated series mean + sum A_k cos(k phi + p_k) at ``phi`` (rad)."""
        p = np.asarray(phi, dtype=float)[..., None]
        return self.mean + np.sum(self.amplitudes * np.cos(self.orders * p + self.phases), axis=-1)


def harmonics_over_angle(phi: ArrayLike, values: ArrayLike, *, n_harmonics: int = 6,
                         samples_per_rev: int = 72) -> AngleHarmonics:
    """Harmonics of ``values`` (e.g. torque, N m) as a function of shaft angle ``phi`` (rad).

    Davidbaev et al. 2023, eqs. 4.1-4.3 with m = ``samples_per_rev`` ordinates per revolution (the paper uses
    m = 12; a finer grid keeps aliasing of high orders out of the first harmonics). The
    signal is linearly interpolated on phi_i = phi_start + 2 pi i / m over the largest whole
    number of revolutions in the record, phi_start being the first multiple of 2 pi/m reached,
    so phases refer to the absolute angle phi = 0. Sums over N revolutions average the
    revolutions (a cycle-averaged oscillogram). ``phi`` must be monotonic (either sense).

    Raises ValueError (message starts with the parameter) for fewer than one revolution,
    non-monotonic angle, or bad options.
    """
    if n_harmonics < 1:
        raise ValueError(f'n_harmonics: must be >= 1, got {n_harmonics}')
    if samples_per_rev < 2 * n_harmonics + 1:
        raise ValueError(f'samples_per_rev: must be > 2 * n_harmonics, got {samples_per_rev}')
    p = np.asarray(phi, dtype=float)
    v = np.asarray(values, dtype=float)
    if p.shape != v.shape or p.ndim != 1:
        raise ValueError('phi: must be a 1-D array of the same length as values')
    d = np.diff(p)
    if p.size < 2 or not (np.all(d > 0) or np.all(d < 0)):
        raise ValueError('phi: shaft angle must be strictly monotonic over the window')
    if d[0] < 0:
        p, v = p[::-1], v[::-1]
    dphi = 2.0 * math.pi / samples_per_rev
    start = math.ceil(p[0] / dphi - 1e-9) * dphi
    revolutions = int(math.floor((p[-1] - start) / (2.0 * math.pi) + 1e-9))
    if revolutions < 1:
        raise ValueError(f'phi: need at least one whole revolution, got {(p[-1] - p[0]) / (2 * math.pi):.3f}')
    n_grid = revolutions * samples_per_rev
    grid = start + dphi * np.arange(n_grid)
    vg = np.interp(grid, p, v)
    orders = np.arange(1, n_harmonics + 1)
    kp = orders[:, None] * grid[None, :]
    a = 2.0 / n_grid * (np.cos(kp) @ vg)
    b = 2.0 / n_grid * (np.sin(kp) @ vg)
    return AngleHarmonics(mean=float(np.mean(vg)), orders=orders, cos_coeffs=a, sin_coeffs=b,
                          amplitudes=np.hypot(a, b), phases=np.arctan2(-b, a),
                          revolutions=revolutions, phi_grid=grid, values_grid=vg)


@dataclass(frozen=True)
class JointNonuniformity:
    """Geometric and kinematic nonuniformity of one joint (Bugaru & Vasile 2021, eqs. 20-23).

    ``nominal_ratio`` i (-): 1 for a constant-velocity or cardan joint, the mean transmission
    ratio for a gear or chain stage. ``geometric_min``/``geometric_max``: range of
    Delta phi = phi_out - i phi_in (rad; a constant offset of whole turns, or for i != 1 the
    mean, is removed); ``geometric_amplitude`` = (max - min)/2 (rad).
    ``kinematic_min``/``kinematic_max``: range of omega_out/(i omega_in) - 1 (-).
    """

    nominal_ratio: float
    geometric_min: float
    geometric_max: float
    geometric_amplitude: float
    kinematic_min: float
    kinematic_max: float


def joint_nonuniformity(phi_in: ArrayLike, phi_out: ArrayLike, omega_in: ArrayLike,
                        omega_out: ArrayLike, *, min_speed: float = 1e-6,
                        nominal_ratio: float | None = None) -> JointNonuniformity:
    """Nonuniformity of a joint from recorded input/output angles (rad) and speeds (rad/s).

    ``nominal_ratio`` (-): default 1, unless the mean output/input speed ratio differs from
    1 by more than 1 % (a gear stage), then the least-squares slope of phi_out over phi_in.
    Samples with |omega_in| below ``min_speed`` (rad/s) are left out of the kinematic ratio.
    """
    pi_ = np.asarray(phi_in, dtype=float)
    po = np.asarray(phi_out, dtype=float)
    wi = np.asarray(omega_in, dtype=float)
    wo = np.asarray(omega_out, dtype=float)
    if nominal_ratio is None:
        nominal_ratio = 1.0
        mean_in = float(np.mean(wi))
        if mean_in != 0.0 and abs(float(np.mean(wo)) / mean_in - 1.0) > 0.01 and np.ptp(pi_) > 0:
            nominal_ratio = float(np.polyfit(pi_, po, 1)[0])
    dev = po - nominal_ratio * pi_
    if nominal_ratio == 1.0:
        dev = dev - 2.0 * math.pi * round(float(np.mean(dev)) / (2.0 * math.pi))
    else:
        dev = dev - float(np.mean(dev))
    ok = np.abs(wi) > min_speed
    kin = wo[ok] / (nominal_ratio * wi[ok]) - 1.0 if np.any(ok) else np.array([math.nan])
    return JointNonuniformity(nominal_ratio=nominal_ratio,
                              geometric_min=float(np.min(dev)), geometric_max=float(np.max(dev)),
                              geometric_amplitude=half_range(dev),
                              kinematic_min=float(np.min(kin)), kinematic_max=float(np.max(kin)))
