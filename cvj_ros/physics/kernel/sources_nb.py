"""Compiled engine / load torque models.

``engine_eval(t, omega, phi, ip, fp, ioff, foff) -> (T, dT/domega, dT/dphi)`` (N m,
N m s/rad, N m/rad); ``load_eval`` likewise (positive load torque resists). Codes and
parameter layout: ``kernel/layout.py``. Covered: linear engine (Davidbaev et al. 2023, eq. 3.23,
M = x M1 - K1 omega), map engine (engine.map_engine_eval: full-load table, throttle, idle
governor, motoring, rev limiter, stall fade, firing ripple), constant load (Davidbaev et al. 2023, eq. 3.21, optional tanh(omega/s) sign), road
load (load.RoadLoad), seeded random load (Davidbaev et al. 2023, eq. 3.30, load.RandomLoad: PCHIP
Hermite between pre-generated knots), Fourier load over shaft angle (Davidbaev et al. 2023, eq. 4.4), brake steps, time series (bag replay).
"""
from __future__ import annotations

import math
import types

from numba import njit

from numba.extending import overload

from cvj_ros.physics.engine import hermite_table, map_engine_eval, smooth_ramp, smoothstep

smoothstep_nb = njit(cache=True)(smoothstep)     # engine.smoothstep, one source
smooth_ramp_nb = njit(cache=True)(smooth_ramp)
hermite_table_nb = njit(cache=True)(hermite_table)


def _same_code(f):
    """A new function object running f's code (an overload's implementation must not be the
    overloaded function itself)."""
    return types.FunctionType(f.__code__, f.__globals__, f.__name__, f.__defaults__, f.__closure__)


# Calls of the plain helpers inside other compiled plain functions (map_engine_eval)
# compile the same Python source, inlined at numba IR level: the implementation is the
# helper's own code (a call to its compiled dispatcher would stay a call into another
# library, docs/solvers.md "Where an rhs call's time goes"); the same operations, same bits.
@overload(smoothstep, inline='always')
def _smoothstep_in_jit(u):
    return _same_code(smoothstep)


@overload(smooth_ramp, inline='always')
def _smooth_ramp_in_jit(u, width):
    return _same_code(smooth_ramp)


@overload(hermite_table, inline='always')
def _hermite_table_in_jit(omega, w, tq, d):
    return _same_code(hermite_table)


map_engine_nb = njit(cache=True)(map_engine_eval)     # engine.map_engine_eval, one source
#: the same source inlined into the rhs (map_engine_at): no call, and the rhs uses only the
#: torque, so the compiler drops the slopes and the ripple's sine there
#: (docs/benchmark.md "The rhs closer to hand-written")
map_engine_inline_nb = njit(cache=True, inline='always')(map_engine_eval)


class CompiledMapEngineTorque:
    """A :class:`cvj_ros.physics.engine.MapEngine`'s ``torque`` through ``map_engine_nb``
    (numba's compile of the same ``engine.map_engine_eval`` source), called through its
    entry point: 0.60-0.65 us per call instead of 2.9-3.0 us in Python, the same bytes
    (test/nodes/test_engine_node.py). engine_node answers with it; ``make kernel`` warms
    it. The pedal position is read from the engine at every call (``set_throttle`` acts at
    once); every other attribute is the engine's. The Python model stays the offline
    reference."""

    def __init__(self, engine) -> None:
        import numpy as np

        from cvj_ros.physics.kernel import entry_point
        self.engine = engine
        # kernel_params() in the types of the Python-callable compile: float64 arrays, floats
        self._params = tuple(np.ascontiguousarray(v, dtype=np.float64)
                             if isinstance(v, (list, tuple, np.ndarray)) else float(v)
                             for v in engine.kernel_params())
        self._eval = entry_point(map_engine_nb, (0.0, 0.0, float(engine.throttle), *self._params))

    def torque(self, t: float, omega: float, phi: float = 0.0) -> float:
        """Engine torque (N m) at crank speed omega (rad/s) and angle phi (rad)."""
        return self._eval(float(omega), float(phi), float(self.engine.throttle), *self._params)[0]

    def __getattr__(self, name: str):
        return getattr(self.engine, name)


from cvj_ros.physics.kernel.layout import (ENGINE_LINEAR, ENGINE_MAP, LOAD_BRAKE_STEPS, LOAD_CONSTANT,
                                          LOAD_FOURIER, LOAD_TIME_SERIES,
                                          LOAD_RANDOM, LOAD_ROAD)


@njit(cache=True, inline='always')
def map_engine_at(omega, phi, fp, foff):
    """engine.map_engine_eval with its parameters read from fp[foff:], inlined into its
    callers (rhs, jac) with the map engine's own body."""
    # fp: x, p, c0, c1, c2, omega_s, idle_rpm, idle_gain, cutoff_rpm, cutoff_band,
    # stall_rpm, ripple_amplitude, ripple_order, ripple_phase, n, w[n], T[n], d[n]
    n = int(fp[foff + 14])
    o = foff + 15
    return map_engine_inline_nb(omega, phi, fp[foff], fp[o:o + n], fp[o + n:o + 2 * n],
                         fp[o + 2 * n:o + 3 * n], fp[foff + 1], fp[foff + 2], fp[foff + 3],
                         fp[foff + 4], fp[foff + 5], fp[foff + 6], fp[foff + 7],
                         fp[foff + 8], fp[foff + 9], fp[foff + 10], fp[foff + 11],
                         fp[foff + 12], fp[foff + 13])


@njit(cache=True, inline='always')
def engine_eval(t, omega, phi, ip, fp, ioff, foff):
    """Engine torque and slopes; ip[ioff] is the model code (rhs passes layout.H_ENGINE),
    fp[foff:] its parameters."""
    code = ip[ioff]
    if code == ENGINE_LINEAR:
        return fp[foff] * fp[foff + 1] - fp[foff + 2] * omega, -fp[foff + 2], 0.0
    if code == ENGINE_MAP:
        return map_engine_at(omega, phi, fp, foff)
    return 0.0, 0.0, 0.0


@njit(cache=True, inline='always')
def load_eval(t, omega, phi, ip, fp, ioff, foff):
    """Load torque (resisting) and slopes; ip[ioff] is the code (layout.H_LOAD)."""
    code = ip[ioff]
    if code == LOAD_CONSTANT:
        s = fp[foff + 1]
        if s == 0.0:
            return fp[foff], 0.0, 0.0
        th = math.tanh(omega / s)
        return fp[foff] * th, fp[foff] * (1.0 - th * th) / s, 0.0
    if code == LOAD_ROAD:
        roll = fp[foff]
        aero = fp[foff + 1]
        lever = fp[foff + 3]
        vs = fp[foff + 4]
        v = omega * lever
        th = math.tanh(v / vs)
        force = roll * th + aero * v * abs(v) + fp[foff + 2]
        dfdv = roll * (1.0 - th * th) / vs + 2.0 * aero * abs(v)
        return force * lever, dfdv * lever * lever, 0.0
    if code == LOAD_RANDOM:
        return random_load(t, fp, foff), 0.0, 0.0
    if code == LOAD_BRAKE_STEPS:
        # load.BrakeStepsLoad: L(t) = sum of jumps, each smoothstep-ramped over ramp s;
        # T = base + L tanh(omega / speed_scale) (speed_scale 0: T = base + L)
        ramp = fp[foff + 1]
        vs = fp[foff + 2]
        lv = 0.0
        for j in range(int(fp[foff + 3])):
            t_on = fp[foff + 4 + 2 * j]
            jump = fp[foff + 5 + 2 * j]
            if t < t_on:
                break
            if ramp > 0.0:
                lv += jump * smoothstep_nb((t - t_on) / ramp)[0]
            else:
                lv += jump
        if vs > 0.0:
            th = math.tanh(omega / vs)
            return fp[foff] + lv * th, lv * (1.0 - th * th) / vs, 0.0
        return fp[foff] + lv, 0.0, 0.0
    if code == LOAD_TIME_SERIES:
        return time_series_load(t, fp, foff), 0.0, 0.0
    if code == LOAD_FOURIER:
        # T = mean + sum a_n cos(n x) + b_n sin(n x), x = phi - phase (Davidbaev et al. 2023, eq. 4.4);
        # dT/dphi = sum n (b_n cos(n x) - a_n sin(n x)); same summation order as FourierLoad
        x = phi - fp[foff + 1]
        total = fp[foff]
        dphi = 0.0
        for j in range(int(fp[foff + 2])):
            o = foff + 3 + 3 * j
            n = fp[o]
            c = math.cos(n * x)
            sn = math.sin(n * x)
            total += fp[o + 1] * c + fp[o + 2] * sn
            dphi += n * (fp[o + 2] * c - fp[o + 1] * sn)
        return total, 0.0, dphi
    return 0.0, 0.0, 0.0


@njit(cache=True, inline='always')
def random_load(t, fp, foff):
    """M_m + A H(t) (N m): cubic Hermite with Fritsch-Butland PCHIP knot slopes between the
    pre-generated knots u_k at t_k = k dt (same expression order as load.RandomLoad)."""
    mean = fp[foff]
    amp = fp[foff + 1]
    dt = fp[foff + 2]
    k0 = int(fp[foff + 3])
    nk = int(fp[foff + 4])
    base = foff + 5
    s = t / dt
    k = math.floor(s)
    tau = s - k
    i = int(k) - 1 - k0
    if i < 0 or i + 3 >= nk:
        return math.nan
    um = fp[base + i]
    u0 = fp[base + i + 1]
    u1 = fp[base + i + 2]
    u2 = fp[base + i + 3]
    dm = u0 - um
    d0 = u1 - u0
    d1 = u2 - u1
    m0 = 2.0 * dm * d0 / (dm + d0) if dm * d0 > 0.0 else 0.0
    m1 = 2.0 * d0 * d1 / (d0 + d1) if d0 * d1 > 0.0 else 0.0
    t2 = tau * tau
    t3 = tau * tau * tau
    val = ((2 * t3 - 3 * t2 + 1) * u0 + (t3 - 2 * t2 + tau) * m0 + (-2 * t3 + 3 * t2) * u1
           + (t3 - t2) * m1)
    return mean + amp * val


@njit(cache=True, inline='always')
def time_series_load(t, fp, foff):
    """load.TimeSeriesLoad: linear interpolation of samples (t_i, T_i), held (or zero) outside."""
    n = int(fp[foff + 1])
    ts = foff + 2
    vs = ts + n
    if t <= fp[ts] or t >= fp[ts + n - 1]:
        if fp[foff] != 0.0 and (t < fp[ts] or t > fp[ts + n - 1]):
            return 0.0
        return fp[vs] if t <= fp[ts] else fp[vs + n - 1]
    lo = 0            # largest j with t_j <= t (bisect_right - 1), t_0 < t < t_n-1 here
    hi = n - 1
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if fp[ts + mid] <= t:
            lo = mid
        else:
            hi = mid
    w = (t - fp[ts + lo]) / (fp[ts + lo + 1] - fp[ts + lo])
    return fp[vs + lo] + w * (fp[vs + lo + 1] - fp[vs + lo])
