"""Load torque sources (no ROS): constant, seeded random, Fourier over angle, road, brake
steps, recorded time series, and sums of these.

Contract (docs/contracts.md, "Torque sources"): every load is a pure function of
(t, omega, phi) with

* ``torque(t, omega, phi=0.0)`` -> N m, *resisting* torque on the output shaft
  (positive opposes positive rotation),
* ``slope(t, omega, phi=0.0)``  -> dT/domega in N m s/rad (0 where T does not depend on omega),
* ``describe()``                -> one-line summary.

Units: t in s, omega in rad/s, phi in rad (unwrapped output-shaft angle), torque in N m.

``load_from_spec(spec, *, seed, field='load')``: ``spec`` is one mapping with ``model`` or
a list of such mappings whose torques are summed (e.g. road + brake_steps + random);
errors name ``f'{field}.<key>'`` or ``f'{field}[i].<key>'`` for list items.

Models: ``constant`` (Davidbaev et al. 2023, eq. 3.21, M2 = -M_c), ``random`` (Davidbaev et al. 2023, eq. 3.30,
M_c = M_m +- delta M_m), ``fourier`` (Davidbaev et al. 2023, eqs. 4.1-4.5, table 4.12), ``road``,
``brake_steps``, ``time_series``.
"""
from __future__ import annotations

import bisect
import functools
import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from cvj_ros.errors import SceneError
from cvj_ros.physics.engine import (KAVZ685_LOAD_DELTA, KAVZ685_LOAD_MEAN, SpecReader,
                                    check_array, check_increasing, did_you_mean, smoothstep)

GRAVITY = 9.81   # m/s^2 (Davidbaev et al. 2023 uses g = 9.81)


class Load:
    """Base of the load models (torque-source protocol)."""

    model = 'load'
    #: the torque does not depend on t explicitly (Rosenbrock steppers then skip f_t); False
    #: unless a model says so (random, brake steps and time series depend on t)
    time_invariant = False

    def torque(self, t: float, omega: float, phi: float = 0.0) -> float:  # pragma: no cover
        raise NotImplementedError

    def slope(self, t: float, omega: float, phi: float = 0.0) -> float:
        """dT/domega (N m s/rad); 0 unless the model depends on speed."""
        return 0.0

    def breakpoints(self, t0: float, t1: float) -> np.ndarray:
        """Times in the open interval (t0, t1) (s, ascending) where the torque is not smooth
        in t: a knot, kink, jump or ramp end. An integrator that stops there keeps its order
        (a step across one loses it and the step controller pays in rejected steps). Empty
        for a model smooth in t (the default)."""
        return np.empty(0)

    def describe(self) -> str:  # pragma: no cover
        raise NotImplementedError


def _inside(times: ArrayLike, t0: float, t1: float) -> np.ndarray:
    """The times strictly inside (t0, t1), ascending and unique (s)."""
    a = np.unique(np.asarray(times, dtype=float))
    return a[(a > t0) & (a < t1)]


# --- constant ------------------------------------------------------------------------------

class ConstantLoad(Load):
    """Constant resisting torque M_c, Davidbaev et al. 2023, eq. 3.21 (M2 = -M_c).

    Spec keys (``model: constant``):

    * ``torque``       N m, any finite value (negative = the load drives) [107.5, KAVZ-685 M_m]
    * ``speed_scale``  rad/s, > 0, optional: T = M_c tanh(omega / speed_scale), i.e. a
                       friction-like load whose sign follows the speed, smooth at standstill.
                       Absent: T = M_c at every speed (the paper's model).
    """

    model = 'constant'
    time_invariant = True

    def __init__(self, *, torque: float = KAVZ685_LOAD_MEAN, speed_scale: float | None = None) -> None:
        self.value = float(torque)
        self.speed_scale = speed_scale

    def torque(self, t: float, omega: float, phi: float = 0.0) -> float:
        if self.speed_scale is None:
            return self.value
        return self.value * math.tanh(omega / self.speed_scale)

    def slope(self, t: float, omega: float, phi: float = 0.0) -> float:
        if self.speed_scale is None:
            return 0.0
        th = math.tanh(omega / self.speed_scale)
        return self.value * (1.0 - th * th) / self.speed_scale

    def describe(self) -> str:
        s = f'constant load {self.value:g} N m'
        return s + (f' (tanh sign, {self.speed_scale:g} rad/s)' if self.speed_scale else '')

    @classmethod
    def from_reader(cls, r: SpecReader, *, seed: int, stream: int) -> ConstantLoad:
        return cls(torque=r.number('torque', KAVZ685_LOAD_MEAN),
                   speed_scale=r.optional_number('speed_scale', lo=0.0, lo_open=True))


# --- random --------------------------------------------------------------------------------

def _zigzag(b: int) -> int:
    """Map an integer block index to a non-negative one (0, -1, 1, -2 ... -> 0, 1, 2, 3 ...)."""
    return 2 * b if b >= 0 else -2 * b - 1


@functools.lru_cache(maxsize=1024)
def _uniform_block(seed: int, stream: int, b: int, size: int) -> np.ndarray:
    """Knot block b of a seeded random load: ``size`` uniform values in [-1, 1) from
    ``numpy.random.default_rng([seed, stream, zigzag(b)])``. A pure function of its
    arguments, cached per process (read-only) so the loads of a sweep's variants, which
    share the scene's seed, do not redraw the same blocks (~50 us a generator)."""
    blk = np.random.default_rng([seed, stream, _zigzag(b)]).uniform(-1.0, 1.0, size)
    blk.flags.writeable = False
    return blk


class RandomLoad(Load):
    """Technological load M_c = M_m + delta(t), Davidbaev et al. 2023, eq. 3.30 (KAVZ-685: 107.5 +- 8.8 N m).

    The random part is a pure function of t: knot values u_k, independent and uniform on
    [-A, A] (A = ``amplitude``, the paper's delta M_m read as a bound), sit on the fixed grid
    t_k = k * dt (dt = ``sample_interval``) for every integer k. Knots are drawn in blocks of
    256 from ``numpy.random.default_rng([seed, stream, zigzag(block)])``, so any t can be
    evaluated in any order and reruns are bit-identical; ``stream`` is the component's index
    in a summed load list (0 alone), so two random components of one scene differ.

    Between knots: cubic Hermite with the PCHIP (Fritsch-Butland harmonic-mean) knot slopes
    of a uniform grid, d_k = 2 D_{k-1} D_k/(D_{k-1} + D_k) if D_{k-1} D_k > 0 else 0 with
    D_k = u_{k+1} - u_k. The signal is C1, has no overshoot (it stays inside [M_m - A, M_m + A])
    and its spectrum is essentially below 1/(2 dt).

    Statistics: knots have mean M_m and standard deviation A/sqrt(3) (5.08 N m for KAVZ-685);
    the interpolated signal's time-averaged standard deviation is smaller, about 0.88 A/sqrt(3)
    (4.47 N m for KAVZ-685; measured over 1e5 knots, two seeds: 0.879 and 0.876); correlation time ~ dt.

    Spec keys (``model: random``):

    * ``mean``             N m, M_m [107.5]
    * ``amplitude``        N m, >= 0, bound A of the random part [8.8]
    * ``sample_interval``  s, > 0, knot spacing dt [0.01: about 50 Hz bandwidth; the paper gives
                           no correlation time, its oscillograms show 415-425 1/s components]
    """

    model = 'random'
    BLOCK = 256

    def __init__(self, *, seed: int, mean: float = KAVZ685_LOAD_MEAN,
                 amplitude: float = KAVZ685_LOAD_DELTA, sample_interval: float = 0.01,
                 stream: int = 0) -> None:
        self.seed = int(seed)
        self.stream = int(stream)
        self.mean = float(mean)
        self.amplitude = float(amplitude)
        self.dt = float(sample_interval)
        self._blocks: dict[int, np.ndarray] = {}

    def _block(self, b: int) -> np.ndarray:
        blk = self._blocks.get(b)
        if blk is None:
            if len(self._blocks) > 256:
                self._blocks.clear()
            blk = _uniform_block(self.seed, self.stream, b, self.BLOCK)
            self._blocks[b] = blk
        return blk

    def knot(self, k: int) -> float:
        """Normalised knot value u_k / A in [-1, 1] (-) at t = k * dt."""
        b, i = divmod(k, self.BLOCK)
        return float(self._block(b)[i])

    def unit_knots(self, k0: int, n: int) -> np.ndarray:
        """Normalised knots u_k / A (-) for k = k0 .. k0 + n - 1, the same values as
        :meth:`knot`, copied block by block (the kernel packs a horizon of them per run)."""
        out = np.empty(max(int(n), 0))
        k, j = int(k0), 0
        while j < out.size:
            b, i = divmod(k, self.BLOCK)
            take = min(self.BLOCK - i, out.size - j)
            out[j:j + take] = self._block(b)[i:i + take]
            k += take
            j += take
        return out

    def knots(self, k0: int, n: int) -> np.ndarray:
        """Knot torques M_m + A u_k (N m) for k = k0 .. k0 + n - 1."""
        return self.mean + self.amplitude * self.unit_knots(k0, n)

    def random_part(self, t: float) -> float:
        """delta(t) in N m (see class docstring)."""
        s = t / self.dt
        k = math.floor(s)
        tau = s - k
        um, u0, u1, u2 = (self.knot(k - 1), self.knot(k), self.knot(k + 1), self.knot(k + 2))
        dm, d0, d1 = u0 - um, u1 - u0, u2 - u1
        m0 = 2.0 * dm * d0 / (dm + d0) if dm * d0 > 0.0 else 0.0
        m1 = 2.0 * d0 * d1 / (d0 + d1) if d0 * d1 > 0.0 else 0.0
        t2, t3 = tau * tau, tau * tau * tau
        val = ((2 * t3 - 3 * t2 + 1) * u0 + (t3 - 2 * t2 + tau) * m0 + (-2 * t3 + 3 * t2) * u1
               + (t3 - t2) * m1)
        return self.amplitude * val

    def breakpoints(self, t0: float, t1: float) -> np.ndarray:
        """The knots t_k = k dt in (t0, t1): the PCHIP interpolant is C1 there, its second
        derivative jumps."""
        k_lo = math.floor(t0 / self.dt)
        k_hi = math.ceil(t1 / self.dt)
        knots = np.arange(k_lo, k_hi + 1) * self.dt   # ascending and unique already
        return knots[(knots > t0) & (knots < t1)]

    def torque(self, t: float, omega: float, phi: float = 0.0) -> float:
        """M_m + delta(t) (N m)."""
        return self.mean + self.random_part(t)

    def describe(self) -> str:
        return (f'random load {self.mean:g} +- {self.amplitude:g} N m (Davidbaev et al. 2023, eq. 3.30), '
                f'knots every {self.dt:g} s, seed {self.seed}/{self.stream}')

    @classmethod
    def from_reader(cls, r: SpecReader, *, seed: int, stream: int) -> RandomLoad:
        return cls(seed=seed, stream=stream, mean=r.number('mean', KAVZ685_LOAD_MEAN),
                   amplitude=r.number('amplitude', KAVZ685_LOAD_DELTA, lo=0.0),
                   sample_interval=r.number('sample_interval', 0.01, lo=0.0, lo_open=True))


# --- Fourier over angle --------------------------------------------------------------------

# Davidbaev et al. 2023, table 4.12 (measured KAVZ-685 torques, 12 ordinates per revolution, eqs. 4.2-4.3):
# per shaft and cycle: (mean N m, cos coefficients a_1..a_6 N m, sin coefficients b_1..b_5 N m).
# The table has no b_6, so b_6 = 0 (as in eq. 4.5). Transcription notes:
# * eq. 4.5 (cycle 1) prints "+ 1.772 cos 4phi1 + 1.169 cos 5phi1" for the sin terms, and
#   with the opposite sign for b_4; the table (b_4 = -1.772, b_5 = 1.169) is used.
# * the paper's amplitudes A_1 = 8.124 and A'_1 = 19.29 do not follow from its own coefficients
#   (sqrt(a^2 + b^2) = 8.146 and 19.316); tan(phi_21) = a'_1/b'_1 is +3.29, printed -3.29.
# * eq. 4.1 writes the constant as M_cp/2 with M_cp the mean of eq. 4.3; the constant term of
#   a Fourier series is the mean itself (eq. 4.4), which is what is used here.
# * driven cycle 2 a'_6 = 13.528 is larger than its a'_1; kept as printed.
TABLE_4_12: dict[str, list[tuple[float, tuple[float, ...], tuple[float, ...]]]] = {
    'driving': [
        (237.15, (-5.492, 7.124, 0.556, -3.912, 0.9314, 2.033), (6.016, -2.446, -2.667, -1.772, 1.169)),
        (243.4, (6.212, 8.15, -0.915, 0.991, 0.2524, 3.853), (-4.339, -6.726, -0.145, -2.276, 1.138)),
        (241.3, (-4.451, 4.312, -0.8219, -2.415, -1.174, 9.125), (-12.017, 9.517, 3.214, 6.150, -0.523)),
        (229.7, (-3.976, -4.655, -1.218, 1.167, -0.866, -1.625), (2.931, -3.238, -4.376, 0.188, -1.101)),
        (229.4, (-5.384, -3.473, -2.661, -2.667, -1.115, -0.817), (16.123, 3.015, -0.467, -3.437, -0.550)),
        (223.1, (4.021, 3.373, -1.972, -3.116, -3.928, -1.413), (-8.064, 0.2546, -1.476, -0.256, 0.328)),
    ],
    'driven': [
        (243.29, (-18.48, 6.817, -2.441, -4.646, 3.119, 4.025), (-5.621, -2.018, -4.645, 1.793, 1.178)),
        (246.17, (-15.30, 4.558, 0.885, 3.736, -0.664, 13.528), (-4.216, 6.092, 1.653, -0.561, 1.123)),
        (238.16, (-6.769, 7.178, -1.216, 1.923, -3.553, 8.312), (-14.372, 4.328, -0.442, -4.819, -0.623)),
        (229.91, (4.705, -8.918, -0.716, 2.765, -2.941, 1.134), (2.716, -0.613, 6.312, 3.273, -1.103)),
        (239.88, (-4.338, -4.851, -3.516, -4.911, -0.126, -4.416), (12.83, -6.254, -8.154, -0.256, -0.650)),
        (233.39, (8.495, 3.367, -1.718, 6.316, 1.157, -0.567), (-10.62, -4.205, -1.472, -3.437, 3.328)),
    ],
}


class FourierLoad(Load):
    """Load as a Fourier series over the shaft angle, Davidbaev et al. 2023, eqs. 4.1 and 4.4:

    ``T(phi) = mean + sum_n a_n cos(n (phi - phi0)) + b_n sin(n (phi - phi0))``  (N m)

    n = 1, 2, ... per shaft revolution. Equivalent amplitude-phase form (as in
    :mod:`cvj_ros.physics.signal`): ``T = mean + sum A_n cos(n (phi - phi0) + p_n)`` with
    A_n = hypot(a_n, b_n), p_n = atan2(-b_n, a_n); see :meth:`harmonics`.

    Spec keys (``model: fourier``), either explicit coefficients:

    * ``mean``       N m [0 with explicit coefficients; the table mean with ``table_4_12``]
    * ``cos``        N m, list a_1, a_2, ... (may be empty / absent)
    * ``sin``        N m, list b_1, b_2, ... (may be empty / absent)

    or the shipped measurement (Davidbaev et al. 2023, table 4.12, KAVZ-685):

    * ``table_4_12`` mapping ``{shaft: 'driven' | 'driving', cycle: 1..6}`` [driven, 1]
                     (driven cycle 1 is the paper's eq. 4.5 M_2)

    and in both cases

    * ``phase_rad``  rad, angle offset phi0 [0]
    """

    model = 'fourier'
    time_invariant = True

    def __init__(self, *, mean: float = 0.0, cos: Sequence[float] = (), sin: Sequence[float] = (),
                 phase_rad: float = 0.0, source: str = 'explicit') -> None:
        n = max(len(cos), len(sin))
        self.mean = float(mean)
        self.a = np.zeros(n)
        self.b = np.zeros(n)
        self.a[:len(cos)] = cos
        self.b[:len(sin)] = sin
        self.phase = float(phase_rad)
        self.source = source
        self._terms = [(k + 1, float(self.a[k]), float(self.b[k])) for k in range(n)
                       if self.a[k] != 0.0 or self.b[k] != 0.0]

    @classmethod
    def table_4_12(cls, *, shaft: str = 'driven', cycle: int = 1, phase_rad: float = 0.0) -> FourierLoad:
        """Davidbaev et al. 2023, table 4.12, KAVZ-685, ``shaft`` 'driven' (M_2) or 'driving' (M_1), cycle 1..6."""
        mean, a, b = TABLE_4_12[shaft][cycle - 1]
        return cls(mean=mean, cos=a, sin=b, phase_rad=phase_rad,
                   source=f'Davidbaev et al. 2023, table 4.12 {shaft} cycle {cycle}')

    def torque(self, t: float, omega: float, phi: float = 0.0) -> float:
        x = phi - self.phase
        total = self.mean
        for n, a, b in self._terms:
            total += a * math.cos(n * x) + b * math.sin(n * x)
        return total

    def harmonics(self) -> list[tuple[int, float, float]]:
        """[(order n, amplitude A_n N m, phase p_n rad)] with T = mean + sum A_n cos(n x + p_n)."""
        return [(k + 1, float(math.hypot(self.a[k], self.b[k])), float(math.atan2(-self.b[k], self.a[k])))
                for k in range(len(self.a))]

    def describe(self) -> str:
        amps = ', '.join(f'{a:.3g}' for _, a, _ in self.harmonics())
        return (f'Fourier load over shaft angle ({self.source}), mean {self.mean:g} N m, '
                f'harmonic amplitudes [{amps}] N m (Davidbaev et al. 2023, eq. 4.4)')

    @classmethod
    def from_reader(cls, r: SpecReader, *, seed: int, stream: int) -> FourierLoad:
        phase = r.number('phase_rad', 0.0)
        if r.has('table_4_12'):
            for key in ('cos', 'sin'):
                if r.has(key):
                    raise SceneError(r.path(key), 'give either table_4_12 or cos/sin coefficients')
            t = SpecReader(r.raw('table_4_12'), r.path('table_4_12'), ignore=())
            shaft = t.choice('shaft', ('driven', 'driving'), 'driven')
            cycle = t.integer('cycle', 1, lo=1, hi=6)
            t.finish()
            load = cls.table_4_12(shaft=shaft, cycle=cycle, phase_rad=phase)
            if r.has('mean'):
                load.mean = r.number('mean')
            return load
        a = r.array('cos', [], min_len=0)
        b = r.array('sin', [], min_len=0)
        return cls(mean=r.number('mean', 0.0), cos=a, sin=b, phase_rad=phase)


# --- road ----------------------------------------------------------------------------------

class RoadLoad(Load):
    """Vehicle road load referred to the shaft where the load acts (standard longitudinal
    vehicle resistance: rolling, aerodynamic drag, grade; not from the papers, which give
    only the measured technological load of Davidbaev et al. 2023).

    Vehicle speed v = omega r / i (m/s); with theta = atan(grade_percent / 100)::

        F = m g C_r cos(theta) tanh(v / v_s) + 1/2 rho C_d A v |v| + m g sin(theta)   (N)
        T = F r / i                                                                 (N m)
        dT/domega = (r / i)^2 [m g C_r cos(theta) (1 - tanh^2(v / v_s)) / v_s + rho C_d A |v|]

    tanh regularises the sign of rolling resistance at standstill over v_s (no jump that
    would break a stiff solver; slope at v = 0 is finite). Grade acts at every speed (a
    vehicle on a hill rolls back). The vehicle's mass is *not* a torque: add its equivalent
    inertia :meth:`equivalent_inertia` = m (r/i)^2 to the driveline's output inertia.

    Spec keys (``model: road``), defaults in brackets:

    * ``mass``               kg, > 0 (required)
    * ``wheel_radius``       m, > 0 (required)
    * ``final_drive_ratio``  -, > 0, shaft speed / wheel speed [1: the load acts on the wheel,
                             i.e. the driveline already contains the final drive as a gear
                             joint; give the ratio when the load acts on the propshaft]
    * ``rolling_coeff``      -, >= 0, C_r [0.012]
    * ``air_density``        kg/m^3, >= 0, rho [1.2]
    * ``drag_coeff``         -, >= 0, C_d [0.3]
    * ``frontal_area``       m^2, >= 0, A [2.2]
    * ``grade_percent``      %, rise per 100 m run, -100..100 [0]
    * ``speed_scale``        m/s, > 0, v_s [0.1]
    * ``gravity``            m/s^2, > 0 [9.81]
    """

    model = 'road'
    time_invariant = True

    def __init__(self, *, mass: float, wheel_radius: float, final_drive_ratio: float = 1.0,
                 rolling_coeff: float = 0.012, air_density: float = 1.2, drag_coeff: float = 0.3,
                 frontal_area: float = 2.2, grade_percent: float = 0.0, speed_scale: float = 0.1,
                 gravity: float = GRAVITY) -> None:
        self.mass, self.r, self.i = float(mass), float(wheel_radius), float(final_drive_ratio)
        self.cr, self.rho, self.cd, self.area = (float(rolling_coeff), float(air_density),
                                                 float(drag_coeff), float(frontal_area))
        self.grade = float(grade_percent)
        self.vs = float(speed_scale)
        self.g = float(gravity)
        theta = math.atan(self.grade / 100.0)
        self._roll = self.mass * self.g * self.cr * math.cos(theta)     # N
        self._climb = self.mass * self.g * math.sin(theta)              # N
        self._aero = 0.5 * self.rho * self.cd * self.area               # N s^2/m^2
        self._lever = self.r / self.i                                    # m (v = lever * omega)

    def vehicle_speed(self, omega: float) -> float:
        """v = omega r / i (m/s)."""
        return omega * self._lever

    def force(self, v: float) -> float:
        """Road resistance force at vehicle speed v (N)."""
        return self._roll * math.tanh(v / self.vs) + self._aero * v * abs(v) + self._climb

    def torque(self, t: float, omega: float, phi: float = 0.0) -> float:
        return self.force(omega * self._lever) * self._lever

    def slope(self, t: float, omega: float, phi: float = 0.0) -> float:
        v = omega * self._lever
        th = math.tanh(v / self.vs)
        dfdv = self._roll * (1.0 - th * th) / self.vs + 2.0 * self._aero * abs(v)
        return dfdv * self._lever * self._lever

    def equivalent_inertia(self) -> float:
        """Vehicle mass referred to the shaft, m (r/i)^2 (kg m^2)."""
        return self.mass * self._lever ** 2

    def describe(self) -> str:
        return (f'road load {self.mass:g} kg, r {self.r:g} m, i {self.i:g}, C_r {self.cr:g}, '
                f'C_d A {self.cd * self.area:g} m^2, grade {self.grade:g} %, '
                f'equivalent inertia {self.equivalent_inertia():.4g} kg m^2')

    @classmethod
    def from_reader(cls, r: SpecReader, *, seed: int, stream: int) -> RoadLoad:
        pos = dict(lo=0.0, lo_open=True)
        return cls(mass=r.number('mass', **pos), wheel_radius=r.number('wheel_radius', **pos),
                   final_drive_ratio=r.number('final_drive_ratio', 1.0, **pos),
                   rolling_coeff=r.number('rolling_coeff', 0.012, lo=0.0),
                   air_density=r.number('air_density', 1.2, lo=0.0),
                   drag_coeff=r.number('drag_coeff', 0.3, lo=0.0),
                   frontal_area=r.number('frontal_area', 2.2, lo=0.0),
                   grade_percent=r.number('grade_percent', 0.0, lo=-100.0, hi=100.0),
                   speed_scale=r.number('speed_scale', 0.1, **pos),
                   gravity=r.number('gravity', GRAVITY, **pos))


# --- brake steps ---------------------------------------------------------------------------

class BrakeStepsLoad(Load):
    """Brake torque switched in steps on top of a constant base load.

    Step i sets the brake level to ``torque_i`` (N m) from ``t_i`` on; levels are not
    cumulative. A negative level is a driving torque (load reversal, e.g. downhill). With ramp time tau > 0 each change follows a cubic smoothstep over
    [t_i, t_i + tau] (C1 in t); tau = 0 gives true steps (restart the solver there)::

        L(t) = sum_i (T_i - T_{i-1}) S((t - t_i) / tau),  T_{-1} = 0
        T = base + L(t) tanh(omega / omega_s)      (or L(t) alone with speed_scale 0)

    With speed_scale > 0 the brake acts like friction: tanh makes a positive level oppose
    the motion in either direction and vanish smoothly at standstill (a negative level then
    pushes along the motion).

    Spec keys (``model: brake_steps``):

    * ``steps``        list of ``[t_on, torque]`` or ``{t: s, torque: N m}``; t strictly
                       increasing, >= 0; torque any finite value (required, at least one)
    * ``ramp_time``    s, >= 0 [0.01]
    * ``base``         N m, constant base load [0]
    * ``speed_scale``  rad/s, >= 0; 0 = brake torque independent of speed [1]
    """

    model = 'brake_steps'

    def __init__(self, *, times: Sequence[float], torques: Sequence[float], ramp_time: float = 0.01,
                 base: float = 0.0, speed_scale: float = 1.0) -> None:
        self.times = [float(x) for x in times]
        self.levels = [float(x) for x in torques]
        prev = [0.0] + self.levels[:-1]
        self._jumps = [lv - p for lv, p in zip(self.levels, prev)]
        self.ramp = float(ramp_time)
        self.base = float(base)
        self.speed_scale = float(speed_scale)

    def breakpoints(self, t0: float, t1: float) -> np.ndarray:
        """Each step's start and ramp end (t_on, t_on + ramp): the smoothstep is C1 there
        (a jump without a ramp)."""
        ends = [t + self.ramp for t in self.times] if self.ramp > 0.0 else []
        return _inside(self.times + ends, t0, t1)

    def level(self, t: float) -> float:
        """Brake level L(t) (N m)."""
        total = 0.0
        for t_on, jump in zip(self.times, self._jumps):
            if t < t_on:
                break
            if self.ramp > 0.0:
                total += jump * smoothstep((t - t_on) / self.ramp)[0]
            else:
                total += jump
        return total

    def torque(self, t: float, omega: float, phi: float = 0.0) -> float:
        lv = self.level(t)
        if self.speed_scale > 0.0:
            lv *= math.tanh(omega / self.speed_scale)
        return self.base + lv

    def slope(self, t: float, omega: float, phi: float = 0.0) -> float:
        if self.speed_scale <= 0.0:
            return 0.0
        th = math.tanh(omega / self.speed_scale)
        return self.level(t) * (1.0 - th * th) / self.speed_scale

    def describe(self) -> str:
        steps = ', '.join(f'{lv:g} N m at {t:g} s' for t, lv in zip(self.times, self.levels))
        return f'brake steps [{steps}] (ramp {self.ramp:g} s) on base {self.base:g} N m'

    @classmethod
    def from_reader(cls, r: SpecReader, *, seed: int, stream: int) -> BrakeStepsLoad:
        raw = r.raw('steps')
        path = r.path('steps')
        if isinstance(raw, (str, bytes, Mapping)) or not isinstance(raw, Sequence) or not raw:
            raise SceneError(path, 'must be a non-empty list of [t_on, torque] or {t, torque}')
        times, torques = [], []
        for i, item in enumerate(raw):
            p = f'{path}[{i}]'
            if isinstance(item, Mapping):
                s = SpecReader(item, p, ignore=())
                t_on, tq = s.number('t', lo=0.0), s.number('torque')
                s.finish()
            else:
                pair = check_array(p, item, min_len=2)
                if len(pair) != 2:
                    raise SceneError(p, f'must be [t_on, torque], got {len(pair)} values')
                if pair[0] < 0.0:
                    raise SceneError(f'{p}[0]', f'must be >= 0 s, got {pair[0]:g}')
                t_on, tq = float(pair[0]), float(pair[1])
            if times and t_on <= times[-1]:
                raise SceneError(p, f'step times must be strictly increasing: {t_on:g} s '
                                    f'follows {times[-1]:g} s')
            times.append(t_on)
            torques.append(tq)
        return cls(times=times, torques=torques, ramp_time=r.number('ramp_time', 0.01, lo=0.0),
                   base=r.number('base', 0.0), speed_scale=r.number('speed_scale', 1.0, lo=0.0))


# --- time series ---------------------------------------------------------------------------

class TimeSeriesLoad(Load):
    """Torque samples (t_j, T_j) with linear interpolation, e.g. a torque recorded in a bag.

    Outside [t_0, t_last] the end values are held (``outside: hold``) or the torque is 0
    (``outside: zero``). Speed-independent (slope 0).

    Spec keys (``model: time_series``), samples inline or from a file:

    * ``t``        s, strictly increasing finite times (>= 2 values)
    * ``torque``   N m, finite, same length
    * ``file``     path instead of ``t``/``torque`` (relative to the working directory):
                   ``.npz`` with arrays ``t`` and ``torque``; ``.yaml``/``.yml``/``.json``
                   mapping with lists ``t`` and ``torque``; ``.csv``/``.txt`` two columns
                   t, torque (comma or whitespace separated, one optional header line)
    * ``outside``  'hold' | 'zero' ['hold']

    The ROS layer builds it with :meth:`from_arrays` from a recorded bag's torque (the bag
    reader lives outside physics: physics imports nothing ROS).
    """

    model = 'time_series'

    def __init__(self, t: Sequence[float], torque: Sequence[float], *, outside: str = 'hold',
                 label: str = 'samples') -> None:
        self.t = [float(x) for x in t]
        self.values = [float(x) for x in torque]
        self.outside = outside
        self.label = label

    @classmethod
    def from_arrays(cls, t: ArrayLike, torque: ArrayLike, *, outside: str = 'hold',
                    field: str = 'load', label: str = 'recorded torque') -> TimeSeriesLoad:
        """Validated construction from arrays: t (s) strictly increasing, torque (N m) finite.

        Errors: SceneError(f'{field}.t[i]') / (f'{field}.torque[i]') naming the bad index.
        """
        ta = check_array(f'{field}.t', np.asarray(t, dtype=float).ravel().tolist(), min_len=2)
        check_increasing(f'{field}.t', ta)
        va = check_array(f'{field}.torque', np.asarray(torque, dtype=float).ravel().tolist(),
                         min_len=2)
        if len(va) != len(ta):
            raise SceneError(f'{field}.torque', f'must have as many values as t ({len(ta)}), '
                                                f'got {len(va)}')
        if outside not in ('hold', 'zero'):
            raise SceneError(f'{field}.outside', f"must be 'hold' or 'zero', got {outside!r}"
                             + did_you_mean(str(outside), ('hold', 'zero')))
        return cls(ta, va, outside=outside, label=label)

    @classmethod
    def from_file(cls, path: str, *, outside: str = 'hold', field: str = 'load') -> TimeSeriesLoad:
        """Samples from ``path`` (.npz, .yaml/.yml/.json, .csv/.txt; see class docstring).

        File problems raise SceneError(f'{field}.file'), bad samples f'{field}.t[i]' etc.
        """
        import json
        import os

        fpath = f'{field}.file'
        if not isinstance(path, (str, os.PathLike)) or not str(path):
            raise SceneError(fpath, f'must be a file path, got {path!r}')
        path = str(path)
        ext = os.path.splitext(path)[1].lower()
        try:
            if ext == '.npz':
                with np.load(path) as data:
                    t, tq = np.asarray(data['t'], float), np.asarray(data['torque'], float)
            elif ext in ('.yaml', '.yml', '.json'):
                with open(path, encoding='utf-8') as fh:
                    if ext == '.json':
                        data = json.load(fh)
                    else:
                        import yaml
                        data = yaml.safe_load(fh)
                if not isinstance(data, Mapping):
                    raise SceneError(fpath, f'{path}: must hold a mapping with lists t and torque')
                t, tq = data['t'], data['torque']
            elif ext in ('.csv', '.txt'):
                with open(path, encoding='utf-8') as fh:
                    lines = [ln.replace(',', ' ').split() for ln in fh if ln.strip()]
                if lines and lines[0] and not _is_number(lines[0][0]):
                    lines = lines[1:]
                bad = [i for i, ln in enumerate(lines) if len(ln) != 2]
                if bad:
                    raise SceneError(fpath, f'{path}: data row {bad[0]} must have 2 columns (t, torque)')
                t = [_to_float(fpath, path, ln[0]) for ln in lines]
                tq = [_to_float(fpath, path, ln[1]) for ln in lines]
            else:
                raise SceneError(fpath, f'{path}: unknown file type {ext!r} '
                                        '(use .npz, .yaml, .yml, .json, .csv or .txt)')
        except OSError as exc:
            raise SceneError(fpath, f'{path}: cannot read ({exc.strerror or exc})') from None
        except KeyError as exc:
            raise SceneError(fpath, f'{path}: missing {exc.args[0]!r} (need t and torque)') from None
        except (ValueError, TypeError) as exc:
            raise SceneError(fpath, f'{path}: {str(exc).splitlines()[0]}') from None
        except Exception as exc:  # yaml/json parse errors
            if isinstance(exc, SceneError):
                raise
            raise SceneError(fpath, f'{path}: {str(exc).splitlines()[0]}') from None
        check_array(f'{field}.t', t, min_len=2)
        check_array(f'{field}.torque', tq, min_len=2)
        return cls.from_arrays(t, tq, outside=outside, field=field, label=os.path.basename(path))

    def breakpoints(self, t0: float, t1: float) -> np.ndarray:
        """The sample times: linear interpolation has a kink at each."""
        return _inside(self.t, t0, t1)

    def torque(self, t: float, omega: float = 0.0, phi: float = 0.0) -> float:
        ts, vs = self.t, self.values
        if t <= ts[0] or t >= ts[-1]:
            if self.outside == 'zero' and (t < ts[0] or t > ts[-1]):
                return 0.0
            return vs[0] if t <= ts[0] else vs[-1]
        j = bisect.bisect_right(ts, t) - 1
        w = (t - ts[j]) / (ts[j + 1] - ts[j])
        return vs[j] + w * (vs[j + 1] - vs[j])

    def describe(self) -> str:
        return (f'time series load ({self.label}), {len(self.t)} samples over '
                f'{self.t[0]:g}..{self.t[-1]:g} s, outside: {self.outside}')

    @classmethod
    def from_reader(cls, r: SpecReader, *, seed: int, stream: int) -> TimeSeriesLoad:
        if r.has('file'):
            for key in ('t', 'torque'):
                if r.has(key):
                    raise SceneError(r.path(key), 'give either file or t/torque samples')
            outside = r.choice('outside', ('hold', 'zero'), 'hold')
            return cls.from_file(r.raw('file'), outside=outside, field=r.field)
        t = r.raw('t')
        tq = r.raw('torque')
        outside = r.choice('outside', ('hold', 'zero'), 'hold')
        if isinstance(t, (str, bytes, Mapping)) or not isinstance(t, (Sequence, np.ndarray)):
            raise SceneError(r.path('t'), f'must be a list of numbers, got {type(t).__name__}')
        if isinstance(tq, (str, bytes, Mapping)) or not isinstance(tq, (Sequence, np.ndarray)):
            raise SceneError(r.path('torque'), f'must be a list of numbers, got {type(tq).__name__}')
        # element-wise check first so non-numbers are named by index
        check_array(r.path('t'), t, min_len=2)
        check_array(r.path('torque'), tq, min_len=2)
        return cls.from_arrays(t, tq, outside=outside, field=r.field, label='scene samples')


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _to_float(fpath: str, path: str, text: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise SceneError(fpath, f'{path}: not a number: {text!r}') from None


# --- sum -----------------------------------------------------------------------------------

class SumLoad(Load):
    """Sum of load components (torques and slopes add)."""

    model = 'sum'

    def __init__(self, components: Sequence[Load]) -> None:
        self.components = list(components)
        self.time_invariant = all(getattr(c, 'time_invariant', False) for c in self.components)

    def torque(self, t: float, omega: float, phi: float = 0.0) -> float:
        return sum(c.torque(t, omega, phi) for c in self.components)

    def slope(self, t: float, omega: float, phi: float = 0.0) -> float:
        return sum(c.slope(t, omega, phi) for c in self.components)

    def breakpoints(self, t0: float, t1: float) -> np.ndarray:
        return _inside(np.concatenate([np.empty(0)] + [c.breakpoints(t0, t1)
                                                       for c in self.components]), t0, t1)

    def describe(self) -> str:
        return ' + '.join(c.describe() for c in self.components)


LOAD_MODELS: dict[str, Any] = {
    'constant': ConstantLoad, 'random': RandomLoad, 'fourier': FourierLoad, 'road': RoadLoad,
    'brake_steps': BrakeStepsLoad, 'time_series': TimeSeriesLoad,
}


def _one_load(spec: Any, *, seed: int, stream: int, field: str) -> Load:
    r = SpecReader(spec, field)
    model = r.raw('model')
    if not isinstance(model, str) or model not in LOAD_MODELS:
        raise SceneError(r.path('model'), f'unknown load model {model!r}'
                         + did_you_mean(str(model), list(LOAD_MODELS))
                         + f' (known: {", ".join(LOAD_MODELS)})')
    load = LOAD_MODELS[model].from_reader(r, seed=seed, stream=stream)
    r.finish()
    return load


def load_from_spec(spec: Mapping[str, Any] | Sequence[Mapping[str, Any]], *, seed: int,
                   field: str = 'load') -> Load:
    """Build a load from one spec mapping or a list of them (summed).

    ``seed`` (int >= 0) drives every random component; component i of a list uses random
    stream i. Raises :class:`SceneError` naming ``f'{field}.<key>'`` (``f'{field}[i].<key>'``
    inside a list) for unknown models/keys (did-you-mean), missing keys, NaN/inf, wrong
    types and impossible values.
    """
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise SceneError('seed', f'must be an integer >= 0, got {seed!r}')
    if isinstance(spec, Mapping):
        return _one_load(spec, seed=int(seed), stream=0, field=field)
    if isinstance(spec, (str, bytes)) or not isinstance(spec, Sequence):
        raise SceneError(field, f'must be a mapping or a list of mappings, got {type(spec).__name__}')
    if not spec:
        raise SceneError(field, 'empty list: give at least one load component')
    return SumLoad([_one_load(item, seed=int(seed), stream=i, field=f'{field}[{i}]')
                    for i, item in enumerate(spec)])
