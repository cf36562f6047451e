"""Measured data for a fit: a CSV of torque over shaft angle or time, a bag, or a shipped table.

Everything is reduced to the torque's mean and harmonic amplitudes per order of the shaft
angle (N m), the quantities the fit compares (docs/fit.md says why not the time series):

* per-revolution ordinates (a CSV with an ``angle_deg`` column, equally spaced over 0..360,
  and one ``torque*`` column per measured revolution, N m; or a shipped table
  ``davidbaev2023/4.N``): eqs. 4.2-4.3 of Davidbaev et al. 2023
  (:func:`cvj_ros.physics.ordinates.ordinate_harmonics`) on the cycle-averaged ordinates;
* a time series (a CSV with ``t_s``, ``torque_Nm`` and ``angle_rad`` or ``speed_rad_s``; or a
  bag's ``/driveline/joint_states`` of one shaft): the torque resampled over the shaft angle
  (:func:`cvj_ros.physics.signal.harmonics_over_angle`) after ``skip`` seconds.
"""
from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from cvj_ros.errors import CvjError

__all__ = ['FitDataError', 'MeasuredOrders', 'read_measured', 'orders_of_series', 'SHIPPED_PREFIX']

FloatArray = NDArray[np.float64]
SHIPPED_PREFIX = 'davidbaev2023/'
MAX_BYTES = 64 * 1024 * 1024


class FitDataError(CvjError, ValueError):
    """A measured-data file that cannot be used (the message starts with the file or field)."""


@dataclass(frozen=True)
class MeasuredOrders:
    """Mean (N m) and amplitudes of orders 1..n (N m) of a measured torque.

    ``kind`` 'ordinates' or 'series'; ``shaft``/``angle_shaft`` the shafts the data name
    (None: the CSV does not say); ``waveform`` one revolution of the measured torque at
    ``waveform_phi`` (rad) for the plot. A series also gives the ``start_time`` (s after its
    first sample) and the whole ``revolutions`` analysed, so the model can analyse the same
    window. ``stderr`` [mean, orders] (N m), with two or more
    measured revolutions of ordinates: the standard error of the cycle mean, and per order
    that of the complex coefficient a_n - i b_n, sqrt(sum_i |c_i - c|^2 / (N (N - 1))) over
    the N revolutions (it bounds the amplitude's); None otherwise.
    """

    source: str
    kind: str
    mean: float
    amplitudes: FloatArray
    shaft: str | None = None
    angle_shaft: str | None = None
    waveform_phi: FloatArray | None = None
    waveform: FloatArray | None = None
    stderr: FloatArray | None = None
    start_time: float | None = None     # series: s after the first sample where analysis starts
    revolutions: int | None = None      # series: whole revolutions analysed

    @property
    def orders(self) -> int:
        return int(self.amplitudes.size)

    def vector(self) -> FloatArray:
        """[mean, A_1 .. A_n] (N m): the measured side of the residuals."""
        return np.concatenate([[self.mean], self.amplitudes])


def read_measured(source: str, *, orders: int, shaft: str | None = None,
                  skip: float = 0.0) -> MeasuredOrders:
    """Read ``source`` (a shipped table ``davidbaev2023/4.N``, a CSV file or a bag) and
    reduce it to the mean and ``orders`` amplitudes. ``shaft`` names the bag's shaft
    (default its first); ``skip`` (s) leaves the start of a time series out."""
    if source.startswith(SHIPPED_PREFIX):
        return _shipped(source, orders)
    path = Path(source)
    if not path.exists():
        raise FitDataError(f'--data {source}: no such file, bag or shipped table '
                           f'(shipped: {SHIPPED_PREFIX}4.2 .. {SHIPPED_PREFIX}4.11)')
    if path.is_dir() or path.suffix in ('.mcap', '.db3'):
        return _bag(path, orders, shaft, skip)
    return _csv(path, orders, skip)


def _shipped(source: str, orders: int) -> MeasuredOrders:
    from cvj_ros.measurements import TABLE_NAMES, load_table
    name = source[len(SHIPPED_PREFIX):]
    if name not in TABLE_NAMES:
        raise FitDataError(f'--data {source}: no such shipped table; tables: '
                           f'{", ".join(SHIPPED_PREFIX + n for n in TABLE_NAMES)}')
    t = load_table(name)
    return _from_ordinates(source, t.ordinates, orders, shaft=None, angle_shaft=None)


def _from_ordinates(source: str, ordinates: FloatArray, orders: int, *, shaft: str | None,
                    angle_shaft: str | None) -> MeasuredOrders:
    from cvj_ros.physics.ordinates import ordinate_harmonics
    mean_rev = ordinates.mean(axis=0)
    m = mean_rev.size
    if orders >= m / 2:
        raise FitDataError(f'--orders: {orders} needs more than {2 * orders} ordinates per '
                           f'revolution, {source} has {m} (the Nyquist order m/2 is not used)')
    h = ordinate_harmonics(mean_rev)
    phi = 2 * math.pi * np.arange(m + 1) / m
    stderr = None
    n = ordinates.shape[0]
    if n >= 2:
        cyc = [ordinate_harmonics(row) for row in ordinates]
        means = np.array([c.mean for c in cyc])
        coef = np.array([c.cos_coeffs[:orders] - 1j * c.sin_coeffs[:orders] for c in cyc])
        spread = np.sum(np.abs(coef - coef.mean(axis=0)) ** 2, axis=0) / (n * (n - 1))
        stderr = np.concatenate([[np.std(means, ddof=1) / math.sqrt(n)], np.sqrt(spread)])
    return MeasuredOrders(source=source, kind='ordinates', mean=h.mean,
                          amplitudes=h.amplitudes[:orders].copy(), shaft=shaft,
                          angle_shaft=angle_shaft, waveform_phi=phi,
                          waveform=np.append(mean_rev, mean_rev[0]), stderr=stderr)


def _csv(path: Path, orders: int, skip: float) -> MeasuredOrders:
    from cvj_ros.textfile import read_text_file
    text = read_text_file(path, what='data file', limit=MAX_BYTES)
    rows = list(csv.reader(io.StringIO(text)))
    rows = [r for r in rows if r and not r[0].lstrip().startswith('#')]
    if len(rows) < 3:
        raise FitDataError(f'{path}: needs a header line and at least 2 data lines')
    head = [h.strip() for h in rows[0]]
    data: dict[str, FloatArray] = {}
    for j, name in enumerate(head):
        col = []
        for i, r in enumerate(rows[1:], start=2):
            if len(r) != len(head):
                raise FitDataError(f'{path}: line {i}: {len(r)} fields, the header has {len(head)}')
            try:
                v = float(r[j])
            except ValueError:
                raise FitDataError(f'{path}: line {i}, column {name}: not a number: '
                                   f'{r[j].strip()[:40]!r}') from None
            if not math.isfinite(v):
                raise FitDataError(f'{path}: line {i}, column {name}: not finite')
            col.append(v)
        data[name] = np.array(col)
    if 'angle_deg' in data and 't_s' not in data:
        torques = [c for c in head if c.startswith('torque')]
        if not torques:
            raise FitDataError(f'{path}: an angle_deg table needs torque columns (one per '
                               f'revolution, N m), e.g. torque_Nm')
        ang = data['angle_deg']
        m = ang.size
        if not np.allclose(ang, np.arange(m) * 360.0 / m, atol=1e-6):
            raise FitDataError(f'{path}: column angle_deg: must be 0, 360/m, ..., 360 (m-1)/m '
                               f'(equally spaced ordinates of one revolution)')
        return _from_ordinates(str(path), np.array([data[c] for c in torques]), orders,
                               shaft=None, angle_shaft=None)
    for need in ('t_s', 'torque_Nm'):
        if need not in data:
            raise FitDataError(f'{path}: column {need}: missing; give angle_deg + torque '
                               f'columns (ordinates) or t_s, torque_Nm and angle_rad or '
                               f'speed_rad_s (time series)')
    t = data['t_s']
    if 'angle_rad' in data:
        phi = data['angle_rad']
    elif 'speed_rad_s' in data:
        w = data['speed_rad_s']
        phi = np.concatenate([[0.0], np.cumsum(0.5 * (w[1:] + w[:-1]) * np.diff(t))])
    else:
        raise FitDataError(f'{path}: column angle_rad or speed_rad_s: missing (the shaft angle '
                           f'of the time series)')
    return orders_of_series(str(path), t, phi, data['torque_Nm'], orders, skip, None)


def orders_of_series(source: str, t: FloatArray, phi: FloatArray, torque: FloatArray,
                     orders: int, skip: float, shaft: str | None) -> MeasuredOrders:
    """Mean and ``orders`` amplitudes of ``torque`` (N m) over the angle ``phi`` (rad) of a time
    series ``t`` (s), from ``skip`` s after its first sample, over its whole revolutions;
    ``source`` names it in errors."""
    from cvj_ros.physics.signal import harmonics_over_angle
    if np.any(np.diff(t) <= 0):
        raise FitDataError(f'{source}: column t_s: times must increase')
    mask = t >= t[0] + skip
    try:
        h = harmonics_over_angle(phi[mask], torque[mask], n_harmonics=orders,
                                 samples_per_rev=max(72, 2 * orders + 2))
    except ValueError as exc:
        raise FitDataError(f'{source}: {exc}') from None
    n = h.phi_grid.size // h.revolutions
    wave = h.values_grid.reshape(h.revolutions, n).mean(axis=0)
    return MeasuredOrders(source=source, kind='series', mean=h.mean,
                          amplitudes=h.amplitudes.copy(), shaft=shaft, angle_shaft=shaft,
                          waveform_phi=2 * math.pi * np.arange(n + 1) / n,
                          waveform=np.append(wave, wave[0]), start_time=float(skip),
                          revolutions=int(h.revolutions))


def _bag(path: Path, orders: int, shaft: str | None, skip: float) -> MeasuredOrders:
    from cvj_ros.analysis import read_bag_signals
    sig = read_bag_signals(path)
    name = shaft or sig.joint_names[0]
    if name not in sig.joint_names:
        raise FitDataError(f'--shaft {name}: not in bag {path}; shafts: '
                           f'{", ".join(sig.joint_names)}')
    j = sig.column(name)
    return orders_of_series(str(path), sig.t, sig.position[:, j], sig.effort[:, j], orders, skip, name)
