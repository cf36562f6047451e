"""Engine torque sources (no ROS): linear working zone and a full engine map.

Contract (docs/contracts.md, "Torque sources"): every engine is a pure function of
(t, omega, phi) with

* ``torque(t, omega, phi=0.0)`` -> N m, drives the crank (positive along positive rotation),
* ``slope(t, omega, phi=0.0)``  -> dT/domega in N m s/rad (analytic),
* ``set_throttle(x)``           -> pedal position 0..1 (NaN rejected),
* ``describe()``                -> one-line summary.

Units: t in s, omega in rad/s, phi in rad (unwrapped crank angle), torque in N m. Spec keys
carry their unit in the name where it is not SI (``idle_rpm``, ``full_load_rpm``).

Models (``engine_from_spec(spec, *, field='engine')``, ``spec['model']``):

``linear``  Davidbaev et al. 2023, eq. 3.23, the working zone AB of the engine characteristic
            M = x M1 - K1 omega (x = throttle, 1 by default: the paper's line).
``map``     full-load curve (PCHIP over a table), part-load law, motoring friction, idle
            governor, rev limiter and optional firing-pulse ripple (see :class:`MapEngine`).

Spec validation raises :class:`cvj_ros.errors.SceneError` whose field is
``f'{field}.<key>'``. The small :class:`SpecReader` here is shared with
:mod:`cvj_ros.physics.load`.
"""
from __future__ import annotations

import difflib
import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from cvj_ros.errors import SceneError, not_a_number

TWO_PI = 2.0 * math.pi
RPM = TWO_PI / 60.0          # rad/s per rpm

# KAVZ-685 machine unit, Davidbaev et al. 2023, section 3.3.1 (after eq. 3.30) and 3.3.2.
KAVZ685_M1 = 623.0                      # N m, initial moment of eq. 3.23
KAVZ685_OMEGA0 = 39.0                   # rad/s, initial drive-shaft speed (3.3.2)
KAVZ685_LOAD_MEAN = 107.5               # N m, M_m of eq. 3.30
KAVZ685_LOAD_DELTA = 8.8                # N m, delta M_m of eq. 3.30
# K1 is not printed in the paper (only K1 = tan(alpha1) = M1/delta omega). We take the
# slope that makes omega0 the steady speed under the paper's mean load:
# (M1 - M_m)/K1 = omega0  ->  K1 = (623 - 107.5)/39 = 13.218 N m s/rad.
KAVZ685_K1 = (KAVZ685_M1 - KAVZ685_LOAD_MEAN) / KAVZ685_OMEGA0

_REQUIRED = object()


# --- spec reading --------------------------------------------------------------------------

def did_you_mean(name: str, choices: Sequence[str]) -> str:
    """'; did you mean X?' suffix or ''. difflib first, then a choice containing the name
    (``grade`` -> ``grade_percent``: keys gained a unit suffix)."""
    name = str(name)
    close = [c for c in choices if c.lower() == name.lower()][:1]      # 'M1' -> 'm1'
    close = close or difflib.get_close_matches(name, list(choices), n=1, cutoff=0.6)
    if not close and len(name) >= 3:
        close = [c for c in choices if name.lower() in c.lower()][:1]
    return f'; did you mean {close[0]!r}?' if close else ''


class SpecReader:
    """Validating reader of one spec mapping; every error names ``f'{field}.<key>'``.

    Usage: read every key with :meth:`number`, :meth:`integer`, :meth:`array` ...,
    then call :meth:`finish` to reject keys nobody read (with did-you-mean).
    """

    def __init__(self, spec: Any, field: str, *, ignore: Sequence[str] = ('model',)) -> None:
        if not isinstance(spec, Mapping):
            raise SceneError(field, f'must be a mapping, got {type(spec).__name__}')
        for key in spec:
            if not isinstance(key, str):
                raise SceneError(field, f'keys must be strings, got {key!r}')
        self.spec = spec
        self.field = field
        self._known: list[str] = list(ignore)

    def path(self, key: str) -> str:
        return f'{self.field}.{key}'

    def has(self, key: str) -> bool:
        self._known.append(key)
        return key in self.spec and self.spec[key] is not None

    def raw(self, key: str, default: Any = _REQUIRED) -> Any:
        self._known.append(key)
        if key not in self.spec or self.spec[key] is None:
            if default is _REQUIRED:
                raise SceneError(self.path(key), 'missing (required)')
            return default
        return self.spec[key]

    def number(self, key: str, default: Any = _REQUIRED, *, lo: float | None = None,
               hi: float | None = None, lo_open: bool = False, hi_open: bool = False,
               unit: str = '') -> float:
        """Finite float within the given bounds (inclusive unless ``*_open``)."""
        value = self.raw(key, default)
        return check_number(self.path(key), value, lo=lo, hi=hi, lo_open=lo_open,
                            hi_open=hi_open, unit=unit)

    def optional_number(self, key: str, **bounds: Any) -> float | None:
        if not self.has(key):
            return None
        return self.number(key, **bounds)

    def integer(self, key: str, default: Any = _REQUIRED, *, lo: int | None = None,
                hi: int | None = None) -> int:
        value = self.raw(key, default)
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
            if isinstance(value, float) and value.is_integer():
                value = int(value)
            else:
                raise SceneError(self.path(key), f'must be an integer, got {value!r}')
        value = int(value)
        if lo is not None and value < lo:
            raise SceneError(self.path(key), f'must be >= {lo}, got {value}')
        if hi is not None and value > hi:
            raise SceneError(self.path(key), f'must be <= {hi}, got {value}')
        return value

    def choice(self, key: str, choices: Sequence[str], default: Any = _REQUIRED) -> str:
        value = self.raw(key, default)
        if not isinstance(value, str) or value not in choices:
            raise SceneError(self.path(key), f'must be one of {", ".join(choices)}, got {value!r}'
                             + did_you_mean(str(value), choices))
        return value

    def array(self, key: str, default: Any = _REQUIRED, *, min_len: int = 1,
              lo: float | None = None, lo_open: bool = False) -> np.ndarray:
        """1-D finite float array; element errors name ``key[i]``."""
        value = self.raw(key, default)
        return check_array(self.path(key), value, min_len=min_len, lo=lo, lo_open=lo_open)

    def finish(self) -> None:
        for key in self.spec:
            if key not in self._known:
                known = sorted(set(self._known))
                raise SceneError(self.path(key), 'unknown key' + did_you_mean(key, known)
                                 + f' (known: {", ".join(known)})')


def check_number(path: str, value: Any, *, lo: float | None = None, hi: float | None = None,
                 lo_open: bool = False, hi_open: bool = False, unit: str = '') -> float:
    """``float(value)`` if it is a finite real number within bounds, else SceneError(path)."""
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise SceneError(path, not_a_number(value))
    v = float(value)
    if not math.isfinite(v):
        raise SceneError(path, f'must be finite, got {v}')
    if lo is not None and (v < lo or (lo_open and v == lo)):
        raise SceneError(path, f'must be {">" if lo_open else ">="} {lo}{unit}, got {v}{unit}')
    if hi is not None and (v > hi or (hi_open and v == hi)):
        raise SceneError(path, f'must be {"<" if hi_open else "<="} {hi}{unit}, got {v}{unit}')
    return v


def check_array(path: str, value: Any, *, min_len: int = 1, lo: float | None = None,
                lo_open: bool = False) -> np.ndarray:
    """1-D array of finite floats; a bad element raises SceneError(f'{path}[i]')."""
    if isinstance(value, (str, bytes, Mapping)) or not isinstance(value, (Sequence, np.ndarray)):
        raise SceneError(path, f'must be a list of numbers, got {type(value).__name__}')
    items = list(np.asarray(value).ravel()) if isinstance(value, np.ndarray) else list(value)
    out = np.empty(len(items))
    for i, item in enumerate(items):
        out[i] = check_number(f'{path}[{i}]', item, lo=lo, lo_open=lo_open)
    if len(out) < min_len:
        raise SceneError(path, f'needs at least {min_len} values, got {len(out)}')
    return out


def check_increasing(path: str, x: np.ndarray) -> None:
    """Strictly increasing, else SceneError naming the first offending index."""
    bad = np.nonzero(np.diff(x) <= 0.0)[0]
    if bad.size:
        i = int(bad[0]) + 1
        raise SceneError(f'{path}[{i}]', f'must be strictly increasing: {x[i]:g} follows {x[i - 1]:g}')


def check_throttle(x: Any, path: str = 'throttle') -> float:
    """Pedal position in [0, 1] (NaN, inf and non-numbers rejected)."""
    return check_number(path, x, lo=0.0, hi=1.0)


# --- smooth helpers ------------------------------------------------------------------------

def smooth_ramp(u: float, width: float) -> tuple[float, float]:
    """C1 saturation of u to [0, 1] with quadratic corners of half-width ``width`` (< 0.5).

    Returns (value, d value/du). Exact identity on [width, 1 - width].
    """
    w = width
    if u <= -w:
        return 0.0, 0.0
    if u < w:
        return (u + w) ** 2 / (4.0 * w), (u + w) / (2.0 * w)
    if u <= 1.0 - w:
        return u, 1.0
    if u < 1.0 + w:
        return 1.0 - (1.0 + w - u) ** 2 / (4.0 * w), (1.0 + w - u) / (2.0 * w)
    return 1.0, 0.0


def smoothstep(u: float) -> tuple[float, float]:
    """Cubic smoothstep 3u^2 - 2u^3 clamped to [0, 1]; returns (value, d/du). C1."""
    if u <= 0.0:
        return 0.0, 0.0
    if u >= 1.0:
        return 1.0, 0.0
    return u * u * (3.0 - 2.0 * u), 6.0 * u * (1.0 - u)


def hermite_table(omega: float, w, tq, d) -> tuple[float, float]:
    """C1 cubic Hermite through (w[i], tq[i]) with slopes d[i], held flat outside the table:
    value (N m) and d/domega (N m s/rad). ``w`` strictly increasing (rad/s); lists or arrays
    (the compiled kernel calls this same function). Bisection by hand (same interval as
    bisect_right - 1)."""
    n = len(w)
    if omega <= w[0]:
        return tq[0], 0.0
    if omega >= w[n - 1]:
        return tq[n - 1], 0.0
    lo, hi = 0, n - 1          # w[lo] <= omega < w[hi]
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if w[mid] <= omega:
            lo = mid
        else:
            hi = mid
    i = lo
    h = w[i + 1] - w[i]
    s = (omega - w[i]) / h
    s2, s3 = s * s, s * s * s
    h00, h10, h01, h11 = 2 * s3 - 3 * s2 + 1, s3 - 2 * s2 + s, -2 * s3 + 3 * s2, s3 - s2
    val = h00 * tq[i] + h10 * h * d[i] + h01 * tq[i + 1] + h11 * h * d[i + 1]
    dh00, dh10, dh01, dh11 = 6 * s2 - 6 * s, 3 * s2 - 4 * s + 1, -6 * s2 + 6 * s, 3 * s2 - 2 * s
    der = (dh00 * tq[i] + dh01 * tq[i + 1]) / h + dh10 * d[i] + dh11 * d[i + 1]
    return val, der


def map_engine_eval(omega: float, phi: float, x: float, w, tq, d, p: float, c0: float,
                    c1: float, c2: float, omega_s: float, idle_rpm: float, idle_gain: float,
                    cutoff_rpm: float, cutoff_band: float, stall_rpm: float,
                    ripple_amplitude: float, ripple_order: float, ripple_phase: float
                    ) -> tuple[float, float, float]:
    """Map engine (MapEngine's docstring states every piece): T (N m), dT/domega
    (N m s/rad), dT/dphi (N m/rad) at crank speed omega (rad/s), angle phi (rad), pedal x.
    The one source of the formula: MapEngine.torque/slope and the compiled kernel
    (kernel/sources_nb.py) both call it. ``ripple_amplitude`` 0 = no ripple."""
    tf, dtf = hermite_table(omega, w, tq, d)
    # motoring: -(c0 tanh(omega/omega_s) + c1 omega + c2 omega |omega|)
    th = math.tanh(omega / omega_s)
    tm = -(c0 * th + c1 * omega + c2 * omega * abs(omega))
    dtm = -(c0 * (1.0 - th * th) / omega_s + c1 + 2.0 * c2 * abs(omega))
    # effective throttle with the proportional idle governor
    if idle_rpm <= 0.0:
        xe, dxe = x, 0.0
    else:
        g, dg_du = smooth_ramp(idle_gain * (idle_rpm - omega / RPM), 0.05)
        xe, dxe = x + (1.0 - x) * g, (1.0 - x) * dg_du * (-idle_gain / RPM)
    # combustion factor: rev limiter times the optional stall fade
    n_rpm = omega / RPM
    sc, dsc = smoothstep((n_rpm - cutoff_rpm + cutoff_band) / cutoff_band)
    c, dc = 1.0 - sc, -dsc / (cutoff_band * RPM)
    if stall_rpm > 0.0:
        half = 0.5 * stall_rpm
        f, df = smoothstep((n_rpm - half) / half)
        c, dc = c * f, dc * f + c * df / (half * RPM)
    if p == 1.0:
        gx, dgx = xe, dxe
    else:
        gx = xe ** p
        dgx = p * xe ** (p - 1.0) * dxe if xe > 0.0 else 0.0
    span, dspan = tf - tm, dtf - dtm
    fired = gx * span * c
    dfired = dgx * span * c + gx * dspan * c + gx * span * dc
    if ripple_amplitude == 0.0:
        return tm + fired, dtm + dfired, 0.0
    arg = ripple_order * (phi - ripple_phase)
    rip = 1.0 + ripple_amplitude * math.cos(arg)
    return (tm + fired * rip, dtm + dfired * rip,
            -fired * ripple_amplitude * ripple_order * math.sin(arg))


# --- engines -------------------------------------------------------------------------------

class Engine:
    """Base of the engine models: throttle state and the torque-source protocol."""

    model = 'engine'
    #: the torque does not depend on t explicitly (only on omega, phi and the throttle, which
    #: changes between runs or exchange steps): Rosenbrock steppers then skip f_t. False unless
    #: a model says so; any torque source without the attribute counts as time-dependent.
    time_invariant = False

    def __init__(self, *, throttle: float = 1.0) -> None:
        self.throttle = check_throttle(throttle)

    def set_throttle(self, x: float) -> None:
        """Set the pedal position x in [0, 1] (-); NaN or out of range -> SceneError('throttle')."""
        self.throttle = check_throttle(x)

    def torque(self, t: float, omega: float, phi: float = 0.0) -> float:  # pragma: no cover
        raise NotImplementedError

    def slope(self, t: float, omega: float, phi: float = 0.0) -> float:  # pragma: no cover
        raise NotImplementedError

    def describe(self) -> str:  # pragma: no cover
        raise NotImplementedError


class LinearEngine(Engine):
    """Linear working zone of the engine characteristic, Davidbaev et al. 2023, eq. 3.23.

    ``M = x * M1 - K1 * omega``  (N m), x = throttle (default 1: exactly the paper's line).
    The throttle shifts the line, the slope -K1 stays.

    Spec keys (``model: linear``):

    * ``m1``        N m, initial moment M1 (default 623, KAVZ-685, Davidbaev et al. 2023 after eq. 3.30)
    * ``k1``        N m s/rad, slope coefficient K1 > 0 (default (623 - 107.5)/39 = 13.218:
                    makes omega0 = 39 rad/s, the paper's initial speed, the steady speed
                    (M1 - M_c)/K1 under its mean load M_c = 107.5 N m; the paper gives no
                    number for K1). Alternatively give
    * ``no_load_speed`` rad/s, omega at which M = 0 with x = 1 (K1 = M1/no_load_speed).
    * ``throttle``  -, initial pedal position 0..1 (default 1)
    """

    model = 'linear'
    time_invariant = True

    def __init__(self, *, m1: float = KAVZ685_M1, k1: float = KAVZ685_K1,
                 throttle: float = 1.0) -> None:
        super().__init__(throttle=throttle)
        self.m1 = float(m1)
        self.k1 = float(k1)

    def torque(self, t: float, omega: float, phi: float = 0.0) -> float:
        """M = x M1 - K1 omega (N m), Davidbaev et al. 2023, eq. 3.23."""
        return self.throttle * self.m1 - self.k1 * omega

    def slope(self, t: float, omega: float, phi: float = 0.0) -> float:
        """dM/domega = -K1 (N m s/rad)."""
        return -self.k1

    def steady_speed(self, load_torque: float) -> float:
        """Speed where x M1 - K1 omega = load_torque (rad/s)."""
        return (self.throttle * self.m1 - load_torque) / self.k1

    def describe(self) -> str:
        return (f'linear engine M = {self.throttle:g}*{self.m1:g} - {self.k1:.4g}*omega N m '
                f'(Davidbaev et al. 2023, eq. 3.23), no-load speed {self.m1 / self.k1:.4g} rad/s')

    @classmethod
    def from_reader(cls, r: SpecReader) -> LinearEngine:
        m1 = r.number('m1', KAVZ685_M1, lo=0.0, lo_open=True)
        if r.has('k1') and r.has('no_load_speed'):
            raise SceneError(r.path('no_load_speed'), 'give either k1 or no_load_speed, not both')
        if r.has('no_load_speed'):
            k1 = m1 / r.number('no_load_speed', lo=0.0, lo_open=True)
        else:
            k1 = r.number('k1', KAVZ685_K1, lo=0.0, lo_open=True)
        throttle = r.number('throttle', 1.0, lo=0.0, hi=1.0)
        return cls(m1=m1, k1=k1, throttle=throttle)


# Generic 2 l spark-ignition full-load curve (default of the map model; illustrative).
DEFAULT_FULL_LOAD_RPM = (1000.0, 1500.0, 2000.0, 3000.0, 4000.0, 5000.0, 6000.0, 6500.0)
DEFAULT_FULL_LOAD_TORQUE = (130.0, 160.0, 180.0, 195.0, 200.0, 190.0, 170.0, 155.0)


def pchip_slopes(x: Sequence[float] | np.ndarray, y: Sequence[float] | np.ndarray) -> np.ndarray:
    """Slopes dy/dx at the interior knots of the PCHIP interpolant through (x, y) (x strictly
    increasing, at least 3 knots; units of y per unit of x): Fritsch and Carlson 1980 - zero
    where the neighbouring secant slopes m_(k-1), m_k differ in sign or one is zero, else the
    weighted harmonic mean 1/d_k = (w1/m_(k-1) + w2/m_k)/(w1 + w2), w1 = 2 h_k + h_(k-1),
    w2 = h_k + 2 h_(k-1), with h_k = x_(k+1) - x_k. The same operations in the same order as
    scipy.interpolate.PchipInterpolator (1.17, ``_find_derivatives``), so the same bytes
    (test/physics/test_engine.py); written out because importing scipy.interpolate took
    0.4-0.9 s of every process that builds a map engine. The end slopes are left 0 (the
    map engine holds them flat)."""
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    hk = x[1:] - x[:-1]
    mk = (y[1:] - y[:-1]) / hk
    smk = np.sign(mk)
    condition = (smk[1:] != smk[:-1]) | (mk[1:] == 0) | (mk[:-1] == 0)
    w1 = 2 * hk[1:] + hk[:-1]
    w2 = hk[1:] + 2 * hk[:-1]
    with np.errstate(divide='ignore', invalid='ignore'):
        whmean = (w1 / mk[:-1] + w2 / mk[1:]) / (w1 + w2)
    dk = np.zeros_like(y)
    dk[1:-1][~condition] = 1.0 / whmean[~condition]
    return dk


class MapEngine(Engine):
    """Engine map: full-load curve, part-load law, motoring friction, idle governor,
    rev limiter, firing-pulse ripple. All terms are pure functions of (omega, phi) and the
    throttle; every piece is C1 in omega so dT/domega is continuous and analytic.

    Source: none of the papers gives an engine map (Davidbaev et al. 2023, fig. 3.9 only sketches the static
    characteristic: idle speed, nominal speed, starting and nominal moment); the pieces
    below are the usual mean-value engine model, stated here in full. PCHIP: Fritsch and
    Carlson 1980, as in scipy.interpolate.PchipInterpolator.

    With omega in rad/s, n = omega/RPM in rpm:

    * full load ``T_full(omega)``: C1 monotone cubic Hermite through the table
      (``full_load_rpm``, ``full_load_torque``) with PCHIP (Fritsch-Carlson) interior slopes
      and zero end slopes, held constant outside the table (no overshoot, no extrapolation).
    * motoring (friction + pumping, fuel off) ``T_mot = -(c0 tanh(omega/omega_s) + c1 omega
      + c2 omega |omega|)`` (N m, negative for omega > 0; tanh regularises the sign at
      standstill over ``friction_speed_scale`` omega_s).
    * effective throttle from pedal x and the idle governor: ``x_eff = x + (1 - x) g(omega)``,
      ``g = ramp(K_g (n_idle - n))``; ramp = C1 saturation to [0, 1] (quadratic corners).
      The governor is proportional (no integral state) so the engine stays a pure function
      of (t, omega, phi) as the torque-source contract requires: solvers evaluate at trial
      points and in any order, and an integrator state inside the source would be advanced
      by rejected steps. Its steady droop below idle is about T_needed / (K_g (T_full - T_mot))
      rpm, where T_needed is the torque the governor must add above motoring.
    * part-load law: fired part ``F = x_eff^p (T_full - T_mot) * c(n)``, torque
      ``T = T_mot + F (1 + a cos(k (phi - phi0)))``. p = ``throttle_exponent`` (1: torque
      linear in pedal between motoring and full load). Monotone in x because T_full > T_mot.
    * rev limiter: ``c(n) = 1 - smoothstep((n - n_cut + band)/band)``: fuel cut complete at
      ``cutoff_rpm``, starting ``cutoff_band_rpm`` below it; above it only motoring remains.
    * stall (optional, ``stall_rpm`` > 0): c is multiplied by smoothstep((n - n_s/2)/(n_s/2)):
      no combustion below n_s/2, full at n_s; the engine then stalls under a load instead of
      delivering full-load torque at standstill. With stall_rpm = 0 (default) the full-load
      curve is held down to standstill (clutch slip / starter idealised), so a scene can
      start from rest.
    * firing ripple (optional): k = cylinders/2 pulses per crank revolution for 4 strokes
      (cylinders for 2 strokes); relative amplitude a of the fired torque, phase phi0.
      The mean over a revolution is unchanged.

    Spec keys (``model: map``), defaults in brackets:

    * ``full_load_rpm``    rpm, strictly increasing table speeds [1000 ... 6500]
    * ``full_load_torque`` N m, > 0, same length [130 ... 155, a generic 2 l petrol engine]
    * ``throttle``         -, initial pedal 0..1 [1]
    * ``throttle_exponent`` -, p > 0 [1]
    * ``friction_c0``      N m, >= 0 [8]
    * ``friction_c1``      N m s/rad, >= 0 [0.02]
    * ``friction_c2``      N m s^2/rad^2, >= 0 [2e-5]
    * ``friction_speed_scale`` rad/s, > 0 [1]
    * ``idle_rpm``         rpm, >= 0; 0 disables the governor [800]
    * ``idle_gain_per_rpm`` 1/rpm, > 0, governor gain K_g [0.01: full fuel 100 rpm below idle]
    * ``cutoff_rpm``       rpm, > idle_rpm [6800]
    * ``cutoff_band_rpm``  rpm, > 0 [200]
    * ``stall_rpm``        rpm, >= 0, < idle_rpm when the governor is on; 0 disables [0]
    * ``cylinders``        integer >= 0; 0 = no ripple [0]
    * ``strokes``          2 or 4 [4]
    * ``ripple_amplitude`` -, relative to the fired torque, 0..1 [0]
    * ``ripple_phase_rad`` rad [0]
    """

    model = 'map'
    time_invariant = True

    def __init__(self, *, full_load_rpm: Sequence[float] = DEFAULT_FULL_LOAD_RPM,
                 full_load_torque: Sequence[float] = DEFAULT_FULL_LOAD_TORQUE,
                 throttle: float = 1.0, throttle_exponent: float = 1.0,
                 friction_c0: float = 8.0, friction_c1: float = 0.02, friction_c2: float = 2e-5,
                 friction_speed_scale: float = 1.0, idle_rpm: float = 800.0,
                 idle_gain_per_rpm: float = 0.01, cutoff_rpm: float = 6800.0,
                 cutoff_band_rpm: float = 200.0, stall_rpm: float = 0.0,
                 cylinders: int = 0, strokes: int = 4,
                 ripple_amplitude: float = 0.0, ripple_phase_rad: float = 0.0) -> None:
        super().__init__(throttle=throttle)
        rpm = np.asarray(full_load_rpm, dtype=float)
        tq = np.asarray(full_load_torque, dtype=float)
        self.full_load_rpm = rpm
        self.full_load_torque = tq
        omega_tab = rpm * RPM
        # PCHIP interior slopes, zero end slopes: C1, monotone-preserving, flat outside.
        d = pchip_slopes(omega_tab, tq) if len(rpm) >= 3 else np.zeros_like(tq)
        d[0] = d[-1] = 0.0
        # plain Python lists: the scalar fast path avoids numpy scalar overhead
        self._w = [float(x) for x in omega_tab]
        self._t = [float(x) for x in tq]
        self._d = [float(x) for x in d]
        self.p = float(throttle_exponent)
        self.c0, self.c1, self.c2 = float(friction_c0), float(friction_c1), float(friction_c2)
        self.omega_s = float(friction_speed_scale)
        self.idle_rpm = float(idle_rpm)
        self.idle_gain = float(idle_gain_per_rpm)
        self.cutoff_rpm = float(cutoff_rpm)
        self.cutoff_band = float(cutoff_band_rpm)
        self.stall_rpm = float(stall_rpm)
        self.cylinders = int(cylinders)
        self.strokes = int(strokes)
        self.ripple_amplitude = float(ripple_amplitude)
        self.ripple_phase = float(ripple_phase_rad)
        self.ripple_order = (self.cylinders / 2.0 if self.strokes == 4 else float(self.cylinders))

    # -- pieces (each returns value and d/domega) --
    def full_load(self, omega: float) -> tuple[float, float]:
        """T_full (N m) and dT_full/domega (N m s/rad); C1 Hermite, flat outside the table."""
        return hermite_table(omega, self._w, self._t, self._d)

    def motoring(self, omega: float) -> tuple[float, float]:
        """T_mot (N m, <= 0 for omega >= 0) and its slope (N m s/rad)."""
        th = math.tanh(omega / self.omega_s)
        val = -(self.c0 * th + self.c1 * omega + self.c2 * omega * abs(omega))
        der = -(self.c0 * (1.0 - th * th) / self.omega_s + self.c1 + 2.0 * self.c2 * abs(omega))
        return val, der

    def effective_throttle(self, omega: float) -> tuple[float, float]:
        """x_eff = x + (1 - x) g(omega) with the idle governor g (-), and dx_eff/domega (s/rad)."""
        x = self.throttle
        if self.idle_rpm <= 0.0:
            return x, 0.0
        u = self.idle_gain * (self.idle_rpm - omega / RPM)
        g, dg_du = smooth_ramp(u, 0.05)
        return x + (1.0 - x) * g, (1.0 - x) * dg_du * (-self.idle_gain / RPM)

    def cut_factor(self, omega: float) -> tuple[float, float]:
        """Combustion factor c in [0, 1] (-) and dc/domega (s/rad): rev limiter times stall fade."""
        n = omega / RPM
        u = (n - self.cutoff_rpm + self.cutoff_band) / self.cutoff_band
        s, ds = smoothstep(u)
        c, dc = 1.0 - s, -ds / (self.cutoff_band * RPM)
        if self.stall_rpm > 0.0:
            half = 0.5 * self.stall_rpm
            f, df = smoothstep((n - half) / half)
            c, dc = c * f, dc * f + c * df / (half * RPM)
        return c, dc

    def _parts(self, omega: float) -> tuple[float, float, float, float]:
        tf, dtf = self.full_load(omega)
        tm, dtm = self.motoring(omega)
        xe, dxe = self.effective_throttle(omega)
        c, dc = self.cut_factor(omega)
        if self.p == 1.0:
            gx, dgx = xe, dxe
        else:
            gx = xe ** self.p
            dgx = self.p * xe ** (self.p - 1.0) * dxe if xe > 0.0 else 0.0
        span, dspan = tf - tm, dtf - dtm
        fired = gx * span * c
        dfired = dgx * span * c + gx * dspan * c + gx * span * dc
        return tm, dtm, fired, dfired

    def _ripple(self, phi: float) -> float:
        if self.ripple_amplitude == 0.0 or self.cylinders == 0:
            return 1.0
        return 1.0 + self.ripple_amplitude * math.cos(self.ripple_order * (phi - self.ripple_phase))

    def kernel_params(self) -> tuple:
        """Arguments of :func:`map_engine_eval` after (omega, phi, x): table and constants."""
        amp = self.ripple_amplitude if self.cylinders else 0.0
        return (self._w, self._t, self._d, self.p, self.c0, self.c1, self.c2, self.omega_s,
                self.idle_rpm, self.idle_gain, self.cutoff_rpm, self.cutoff_band, self.stall_rpm,
                amp, self.ripple_order, self.ripple_phase)

    def torque(self, t: float, omega: float, phi: float = 0.0) -> float:
        """T = T_mot + F (1 + a cos(k (phi - phi0))) in N m (see class docstring)."""
        return map_engine_eval(omega, phi, self.throttle, *self.kernel_params())[0]

    def slope(self, t: float, omega: float, phi: float = 0.0) -> float:
        """dT/domega (N m s/rad), analytic."""
        return map_engine_eval(omega, phi, self.throttle, *self.kernel_params())[1]

    def describe(self) -> str:
        i = int(np.argmax(self.full_load_torque))
        s = (f'map engine, peak {self.full_load_torque[i]:g} N m at {self.full_load_rpm[i]:g} rpm, '
             f'throttle {self.throttle:g}')
        s += f', idle governor {self.idle_rpm:g} rpm' if self.idle_rpm > 0 else ', no idle governor'
        s += f', cut-off {self.cutoff_rpm:g} rpm'
        if self.stall_rpm > 0:
            s += f', stalls below {self.stall_rpm:g} rpm'
        if self.cylinders and self.ripple_amplitude:
            s += (f', {self.cylinders} cyl {self.strokes}-stroke ripple '
                  f'{self.ripple_amplitude:g} at order {self.ripple_order:g}')
        return s

    @classmethod
    def from_reader(cls, r: SpecReader) -> MapEngine:
        rpm = r.array('full_load_rpm', list(DEFAULT_FULL_LOAD_RPM), min_len=2, lo=0.0)
        check_increasing(r.path('full_load_rpm'), rpm)
        tq = r.array('full_load_torque', list(DEFAULT_FULL_LOAD_TORQUE), min_len=2, lo=0.0,
                     lo_open=True)
        if len(tq) != len(rpm):
            raise SceneError(r.path('full_load_torque'),
                             f'must have as many values as full_load_rpm ({len(rpm)}), got {len(tq)}')
        kw: dict[str, Any] = dict(full_load_rpm=rpm, full_load_torque=tq)
        kw['throttle'] = r.number('throttle', 1.0, lo=0.0, hi=1.0)
        kw['throttle_exponent'] = r.number('throttle_exponent', 1.0, lo=0.0, lo_open=True)
        kw['friction_c0'] = r.number('friction_c0', 8.0, lo=0.0)
        kw['friction_c1'] = r.number('friction_c1', 0.02, lo=0.0)
        kw['friction_c2'] = r.number('friction_c2', 2e-5, lo=0.0)
        kw['friction_speed_scale'] = r.number('friction_speed_scale', 1.0, lo=0.0, lo_open=True)
        kw['idle_rpm'] = r.number('idle_rpm', 800.0, lo=0.0)
        kw['idle_gain_per_rpm'] = r.number('idle_gain_per_rpm', 0.01, lo=0.0, lo_open=True)
        kw['cutoff_band_rpm'] = r.number('cutoff_band_rpm', 200.0, lo=0.0, lo_open=True)
        kw['cutoff_rpm'] = r.number('cutoff_rpm', 6800.0, lo=kw['idle_rpm'], lo_open=True)
        if kw['cutoff_rpm'] - kw['cutoff_band_rpm'] <= kw['idle_rpm']:
            raise SceneError(r.path('cutoff_band_rpm'),
                             f'cut-off band must start above idle_rpm ({kw["idle_rpm"]:g} rpm)')
        kw['stall_rpm'] = r.number('stall_rpm', 0.0, lo=0.0)
        if kw['idle_rpm'] > 0.0 and kw['stall_rpm'] >= kw['idle_rpm']:
            raise SceneError(r.path('stall_rpm'), f'must be < idle_rpm ({kw["idle_rpm"]:g}), '
                                                  f'got {kw["stall_rpm"]:g}')
        kw['cylinders'] = r.integer('cylinders', 0, lo=0, hi=24)
        kw['strokes'] = r.integer('strokes', 4, lo=2, hi=4)
        if kw['strokes'] not in (2, 4):
            raise SceneError(r.path('strokes'), f'must be 2 or 4, got {kw["strokes"]}')
        kw['ripple_amplitude'] = r.number('ripple_amplitude', 0.0, lo=0.0, hi=1.0)
        kw['ripple_phase_rad'] = r.number('ripple_phase_rad', 0.0)
        if kw['ripple_amplitude'] > 0.0 and kw['cylinders'] == 0:
            raise SceneError(r.path('cylinders'), 'must be >= 1 when ripple_amplitude > 0')
        return cls(**kw)


ENGINE_MODELS: dict[str, type[Engine]] = {'linear': LinearEngine, 'map': MapEngine}


def engine_from_spec(spec: Mapping[str, Any], *, field: str = 'engine') -> Engine:
    """Build an engine from a scene mapping ``{'model': 'linear' | 'map', ...}``.

    Raises :class:`SceneError` naming ``f'{field}.<key>'`` for unknown models or keys
    (with did-you-mean), missing keys, NaN/inf, wrong types and out-of-range values.
    """
    r = SpecReader(spec, field)
    model = r.raw('model')
    if not isinstance(model, str) or model not in ENGINE_MODELS:
        raise SceneError(r.path('model'), f'unknown engine model {model!r}'
                         + did_you_mean(str(model), list(ENGINE_MODELS))
                         + f' (known: {", ".join(ENGINE_MODELS)})')
    engine = ENGINE_MODELS[model].from_reader(r)  # type: ignore[attr-defined]
    r.finish()
    return engine
