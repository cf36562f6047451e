"""Engine torque sources: closed forms, numerical slopes, governor in a 1-DOF run, validation."""
from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from cvj_ros.errors import SceneError
from cvj_ros.physics.engine import (KAVZ685_K1, RPM, LinearEngine, MapEngine, engine_from_spec,
                                   pchip_slopes,
                                    smooth_ramp, smoothstep)


def numerical_slope(src: Any, t: float, omega: float, phi: float = 0.0, h: float = 1e-5) -> float:
    return (src.torque(t, omega + h, phi) - src.torque(t, omega - h, phi)) / (2.0 * h)


RIPPLE_SPEC = {'model': 'map', 'cylinders': 4, 'ripple_amplitude': 0.3, 'ripple_phase_rad': 0.2,
               'stall_rpm': 400, 'throttle_exponent': 1.5}


# --- linear ---------------------------------------------------------------------------------

def test_linear_defaults_are_kavz685_and_closed_form() -> None:
    e = engine_from_spec({'model': 'linear'})
    assert isinstance(e, LinearEngine)
    assert e.m1 == 623.0
    assert e.k1 == pytest.approx((623.0 - 107.5) / 39.0)
    # eq. 3.23 at two speeds
    assert e.torque(0.0, 0.0) == pytest.approx(623.0)
    assert e.torque(0.0, 39.0) == pytest.approx(107.5)
    assert e.slope(0.0, 12.0) == pytest.approx(-KAVZ685_K1)
    assert e.slope(0.0, 12.0) == pytest.approx(numerical_slope(e, 0.0, 12.0))


def test_linear_no_load_speed_alternative_and_throttle_shift() -> None:
    e = engine_from_spec({'model': 'linear', 'm1': 500, 'no_load_speed': 50, 'throttle': 0.5})
    assert e.k1 == pytest.approx(10.0)
    assert e.torque(0, 0) == pytest.approx(250.0)
    e.set_throttle(1.0)
    assert e.torque(0, 50.0) == pytest.approx(0.0, abs=1e-12)


def test_linear_steady_speed_with_constant_load() -> None:
    """1-DOF J domega/dt = M1 - K1 omega - Mc settles at (M1 - Mc)/K1 (= 39 rad/s for KAVZ-685)."""
    e = engine_from_spec({'model': 'linear'})
    j, mc = 0.128 + 0.161, 107.5
    sol = solve_ivp(lambda t, y: [(e.torque(t, y[0]) - mc) / j], (0.0, 1.0), [0.0],
                    rtol=1e-10, atol=1e-12)
    expected = (623.0 - mc) / e.k1
    assert expected == pytest.approx(39.0)
    assert sol.y[0, -1] == pytest.approx(expected, rel=1e-6)
    # time constant J/K1: after 1 s (about 46 time constants) the transient is gone; at
    # t = J/K1 it is 1 - 1/e of the way
    tau = j / e.k1
    sol2 = solve_ivp(lambda t, y: [(e.torque(t, y[0]) - mc) / j], (0.0, tau), [0.0], rtol=1e-10,
                     atol=1e-12)
    assert sol2.y[0, -1] == pytest.approx(expected * (1 - math.exp(-1)), rel=1e-6)


# --- map ------------------------------------------------------------------------------------

@pytest.mark.parametrize('spec', [{'model': 'map'}, RIPPLE_SPEC,
                                  {'model': 'map', 'idle_rpm': 0, 'throttle': 0.3}])
@pytest.mark.parametrize('throttle', [0.0, 0.25, 1.0])
def test_map_slope_equals_numerical_derivative(spec: dict, throttle: float) -> None:
    e = engine_from_spec(spec)
    e.set_throttle(throttle)
    rng = np.random.default_rng(1)
    speeds = np.concatenate([rng.uniform(-20, 7200 * RPM, 200),
                             np.array([0.3, 350, 600, 760, 790, 810, 6650, 6750]) * RPM])
    for omega in speeds:
        phi = float(rng.uniform(0, 20))
        num = numerical_slope(e, 0.0, float(omega), phi)
        assert e.slope(0.0, float(omega), phi) == pytest.approx(num, rel=1e-5, abs=1e-5)


def test_map_full_load_through_table_and_monotone_pieces() -> None:
    e = engine_from_spec({'model': 'map', 'idle_rpm': 0, 'friction_c0': 0, 'friction_c1': 0,
                          'friction_c2': 0})
    for n, tq in zip(e.full_load_rpm, e.full_load_torque):
        assert e.torque(0, n * RPM) == pytest.approx(tq, rel=1e-12)
    # no overshoot between table points (monotone Hermite): torque within neighbours' range
    n = np.linspace(1000, 6500, 2001)
    vals = np.array([e.torque(0, x * RPM) for x in n])
    assert vals.max() <= max(e.full_load_torque) + 1e-9
    assert vals.min() >= min(e.full_load_torque) - 1e-9


def test_map_throttle_monotone() -> None:
    e = engine_from_spec({'model': 'map', 'throttle_exponent': 1.3})
    for n in (300, 900, 2000, 4000, 6000, 6700, 7000):
        vals = []
        for x in np.linspace(0, 1, 21):
            e.set_throttle(float(x))
            vals.append(e.torque(0, n * RPM))
        d = np.diff(vals)
        assert np.all(d >= -1e-12), n
        if 800 < n < 6500:   # below idle the saturated governor already gives full load
            assert vals[-1] - vals[0] > 10.0
        if n < 600:
            assert vals[-1] - vals[0] == pytest.approx(0.0, abs=1e-9)


def test_map_part_load_law_closed_form() -> None:
    e = engine_from_spec({'model': 'map', 'idle_rpm': 0})
    omega = 3000 * RPM
    tf, _ = e.full_load(omega)
    tm, _ = e.motoring(omega)
    assert tf == pytest.approx(195.0)
    c0, c1, c2 = 8.0, 0.02, 2e-5
    assert tm == pytest.approx(-(c0 * math.tanh(omega) + c1 * omega + c2 * omega ** 2))
    e.set_throttle(0.4)
    assert e.torque(0, omega) == pytest.approx(tm + 0.4 * (tf - tm))
    e.set_throttle(0.0)
    assert e.torque(0, omega) == pytest.approx(tm)
    assert e.torque(0, omega) < 0


def test_map_rev_limiter_cuts_fuel() -> None:
    e = engine_from_spec({'model': 'map'})
    above = 6900 * RPM
    assert e.torque(0, above) == pytest.approx(e.motoring(above)[0])
    assert e.torque(0, 6500 * RPM) == pytest.approx(155.0 + 0 * e.motoring(0)[0], abs=40)
    assert e.torque(0, 6500 * RPM) > 100


def test_map_stall_fade() -> None:
    e = engine_from_spec({'model': 'map', 'stall_rpm': 400})
    assert e.torque(0, 150 * RPM) == pytest.approx(e.motoring(150 * RPM)[0])
    assert e.torque(0, 500 * RPM) == pytest.approx(130.0)   # T_mot + 1 * (T_full - T_mot)


def test_firing_ripple_order_and_mean() -> None:
    """4-cylinder 4-stroke: 2 pulses per rev; relative amplitude of the fired torque; mean kept."""
    e = engine_from_spec({'model': 'map', 'cylinders': 4, 'ripple_amplitude': 0.25,
                          'idle_rpm': 0})
    plain = engine_from_spec({'model': 'map', 'idle_rpm': 0})
    omega = 3000 * RPM
    m = 64
    phis = np.arange(m) * 2 * math.pi / m
    tq = np.array([e.torque(0, omega, p) for p in phis])
    mean = plain.torque(0, omega)
    spec = np.fft.rfft(tq) / m
    assert spec[0].real == pytest.approx(mean, rel=1e-12)
    fired = mean - plain.motoring(omega)[0]
    assert 2 * abs(spec[2]) == pytest.approx(0.25 * fired, rel=1e-9)
    others = np.delete(np.abs(spec[1:]), 1)
    assert others.max() < 1e-9 * fired
    six = engine_from_spec({'model': 'map', 'cylinders': 6, 'ripple_amplitude': 0.1,
                            'strokes': 4})
    assert six.ripple_order == 3.0
    two = engine_from_spec({'model': 'map', 'cylinders': 1, 'ripple_amplitude': 0.1,
                            'strokes': 2})
    assert two.ripple_order == 1.0


def test_idle_governor_holds_idle_against_load() -> None:
    """Zero pedal, 15 N m accessory load on a 0.15 kg m^2 crank: the proportional governor
    settles near idle with the droop predicted by its gain, from above and from below."""
    e = engine_from_spec({'model': 'map', 'throttle': 0.0, 'idle_rpm': 800,
                          'idle_gain_per_rpm': 0.02, 'stall_rpm': 300})
    j, load = 0.15, 15.0
    finals = []
    for n0 in (1500.0, 500.0):
        sol = solve_ivp(lambda t, y: [(e.torque(t, y[0]) - load) / j], (0.0, 5.0), [n0 * RPM],
                        method='LSODA', rtol=1e-8, atol=1e-10,
                        jac=lambda t, y: [[e.slope(t, y[0]) / j]])
        finals.append(sol.y[0, -1] / RPM)
    # predicted droop: governor must supply load - T_mot: g = (load - tm)/(tf - tm) = K (800 - n)
    omega = 800 * RPM
    tm, tf = e.motoring(omega)[0], e.full_load(omega)[0]
    droop = (load - tm) / (tf - tm) / 0.02
    for n in finals:
        assert n == pytest.approx(800 - droop, abs=1.0)
        assert 780 < n < 800
    assert finals[0] == pytest.approx(finals[1], abs=1e-3)


def test_idle_governor_saturates_at_full_load() -> None:
    e = engine_from_spec({'model': 'map', 'throttle': 0.0})
    omega = 500 * RPM      # 300 rpm below idle: governor saturated
    assert e.torque(0, omega) == pytest.approx(e.full_load(omega)[0] + 0 * e.motoring(omega)[0])
    assert e.effective_throttle(omega)[0] == 1.0


def test_smooth_helpers_are_c1() -> None:
    for u in (-0.05, 0.05, 0.95, 1.05, 0.0, 0.5):
        v1, d1 = smooth_ramp(u - 1e-9, 0.05)
        v2, d2 = smooth_ramp(u + 1e-9, 0.05)
        assert v1 == pytest.approx(v2, abs=1e-8)
        assert d1 == pytest.approx(d2, abs=1e-6)
    assert smoothstep(0.5) == (0.5, 1.5)


# --- validation -----------------------------------------------------------------------------

@pytest.mark.parametrize('spec, field', [
    ({'model': 'linaer'}, 'engine.model'),
    ({}, 'engine.model'),
    ({'model': 'linear', 'm1': float('nan')}, 'engine.m1'),
    ({'model': 'linear', 'k1': -1}, 'engine.k1'),
    ({'model': 'linear', 'k1': 'fast'}, 'engine.k1'),
    ({'model': 'linear', 'k1': 1, 'no_load_speed': 3}, 'engine.no_load_speed'),
    ({'model': 'linear', 'kone': 1}, 'engine.kone'),
    ({'model': 'linear', 'throttle': 1.5}, 'engine.throttle'),
    ({'model': 'map', 'idle_rmp': 700}, 'engine.idle_rmp'),
    ({'model': 'map', 'full_load_rpm': [1000, 900, 2000]}, 'engine.full_load_rpm[1]'),
    ({'model': 'map', 'full_load_rpm': [1000, 2000], 'full_load_torque': [1, 2, 3]},
     'engine.full_load_torque'),
    ({'model': 'map', 'full_load_torque': [100, float('inf'), 3, 4, 5, 6, 7, 8]},
     'engine.full_load_torque[1]'),
    ({'model': 'map', 'full_load_rpm': 'fast'}, 'engine.full_load_rpm'),
    ({'model': 'map', 'cylinders': 2.5}, 'engine.cylinders'),
    ({'model': 'map', 'cylinders': True}, 'engine.cylinders'),
    ({'model': 'map', 'strokes': 3}, 'engine.strokes'),
    ({'model': 'map', 'ripple_amplitude': 0.2}, 'engine.cylinders'),
    ({'model': 'map', 'cutoff_rpm': 500}, 'engine.cutoff_rpm'),
    ({'model': 'map', 'stall_rpm': 900}, 'engine.stall_rpm'),
    ({'model': 'map', 'friction_c0': -1}, 'engine.friction_c0'),
])
def test_bad_specs_name_the_field(spec: dict, field: str) -> None:
    with pytest.raises(SceneError) as info:
        engine_from_spec(spec)
    assert info.value.field == field
    assert str(info.value).startswith(field + ':')


def test_did_you_mean_and_custom_field() -> None:
    with pytest.raises(SceneError, match=r"did you mean 'linear'"):
        engine_from_spec({'model': 'linaer'})
    with pytest.raises(SceneError, match=r"^scene\.engine\.idle_rmp: unknown key; did you mean 'idle_rpm'"):
        engine_from_spec({'model': 'map', 'idle_rmp': 700}, field='scene.engine')
    with pytest.raises(SceneError, match=r"^engine\.M1: unknown key; did you mean 'm1'"):
        engine_from_spec({'model': 'linear', 'M1': 600})
    with pytest.raises(SceneError, match=r'^engine: must be a mapping'):
        engine_from_spec(['linear'])  # type: ignore[arg-type]


@pytest.mark.parametrize('bad', [float('nan'), -0.1, 1.01, 'full', None])
def test_set_throttle_rejects(bad: object) -> None:
    e = engine_from_spec({'model': 'map'})
    with pytest.raises(SceneError, match='^throttle'):
        e.set_throttle(bad)  # type: ignore[arg-type]
    assert e.throttle == 1.0


def test_describe_one_line() -> None:
    for spec in ({'model': 'linear'}, RIPPLE_SPEC):
        d = engine_from_spec(spec).describe()
        assert d and '\n' not in d
    assert 'ripple' in engine_from_spec(RIPPLE_SPEC).describe()
    assert isinstance(engine_from_spec(RIPPLE_SPEC), MapEngine)


@pytest.mark.hard
def test_engine_stall_under_excess_friction_load() -> None:
    """Hard case (DESIGN section 8): a friction load above full-load torque drags the idling
    engine below stall speed; combustion stops and the crank comes to rest (no reverse run)."""
    from cvj_ros.physics.load import load_from_spec
    e = engine_from_spec({'model': 'map', 'throttle': 0.0, 'stall_rpm': 400})
    brake = load_from_spec({'model': 'brake_steps', 'steps': [[0.5, 250.0]], 'ramp_time': 0.05,
                            'speed_scale': 0.5}, seed=0)
    j = 0.15

    def rhs(t, y):
        return [(e.torque(t, y[0]) - brake.torque(t, y[0])) / j]

    def jac(t, y):
        return [[(e.slope(t, y[0]) - brake.slope(t, y[0])) / j]]

    sol = solve_ivp(rhs, (0.0, 4.0), [800 * RPM], method='Radau', jac=jac, rtol=1e-8, atol=1e-10)
    assert sol.success
    assert sol.y[0, -1] == pytest.approx(0.0, abs=0.05)
    assert np.min(sol.y[0]) > -0.05
    # once stalled only motoring acts: engine torque equals the motoring torque
    w = float(sol.y[0, -1])
    assert e.torque(0, w) == pytest.approx(e.motoring(w)[0])


def test_linear_engine_from_standstill_hits_steady_speed_with_random_load() -> None:
    """KAVZ-685 unit lumped to one inertia, seed 004 eq. 3.30 load: mean speed over 2..10 s
    near (M1 - M_m)/K1 = 39 rad/s; deviations bounded by delta M / K1."""
    from cvj_ros.physics.load import load_from_spec
    e = engine_from_spec({'model': 'linear'})
    load = load_from_spec({'model': 'random'}, seed=5)
    j = 0.128 + 0.161
    t_eval = np.linspace(2.0, 10.0, 4001)
    sol = solve_ivp(lambda t, y: [(e.torque(t, y[0]) - load.torque(t, y[0])) / j], (0.0, 10.0),
                    [0.0], t_eval=t_eval, rtol=1e-8, atol=1e-10, max_step=0.005)
    w = sol.y[0]
    assert w.mean() == pytest.approx(39.0, abs=0.1)
    assert np.max(np.abs(w - 39.0)) <= 8.8 / e.k1 + 1e-6


@pytest.mark.parametrize('seed', range(12))
def test_pchip_slopes_are_scipys_bytes(seed: int) -> None:
    """The map engine's interior PCHIP slopes (written out to keep scipy.interpolate out of
    the node processes' start-up) are scipy's PchipInterpolator derivatives at the knots,
    bit for bit: monotone tables, tables with a peak, flat pieces and sign changes."""
    from scipy.interpolate import PchipInterpolator
    rng = np.random.default_rng(seed)
    n = int(rng.integers(3, 14))
    x = np.cumsum(rng.uniform(50.0, 800.0, n))
    y = rng.uniform(-50.0, 300.0, n)
    if seed % 3 == 0:
        y = np.sort(y)                       # monotone
    if seed % 4 == 1:
        y[n // 2:] = y[n // 2]               # a flat piece: zero secants
    ref = PchipInterpolator(x, y).derivative()(x)
    got = pchip_slopes(x, y)
    assert got[1:-1].tobytes() == ref[1:-1].tobytes()
    assert got[0] == got[-1] == 0.0


def test_map_engine_build_does_not_import_scipy_interpolate() -> None:
    """A process that builds the default map engine does not pay for scipy.interpolate."""
    import subprocess
    import sys
    code = ('import sys; from cvj_ros.physics.engine import MapEngine; MapEngine(); '
            'print("scipy.interpolate" in sys.modules)')
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == 'False'
