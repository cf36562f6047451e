"""cvj_ros.physics.degenerate: the fastest mode against the two-mass closed form, the
Nyquist line, the stall and angle-limit lines."""
from __future__ import annotations

import math

import pytest

from cvj_ros.physics import degenerate as dg
from cvj_ros.physics.driveline import Driveline
from cvj_ros.physics.scene import parse_scene

J1, J2, C, B = 0.128, 0.161, 715.4, 6.35


def _scene(joint: dict | None = None, **extra: object) -> object:
    chain = [{'type': 'inertia', 'name': 'a', 'J': J1},
             {'type': 'spring', 'name': 's', 'stiffness': C, 'damping': B},
             *([joint] if joint else []),
             {'type': 'inertia', 'name': 'b', 'J': J2}]
    return parse_scene({'name': 't', 'duration': 0.1, 'exchange_step': 1e-3,
                        'engine': {'model': 'linear'}, 'load': {'model': 'constant', 'torque': 10.0},
                        'driveline': chain, **extra})


def test_fastest_mode_is_the_two_mass_closed_form() -> None:
    # lambda = (-B +- sqrt(B^2 - 4 mu C)) / (2 mu): imaginary part sqrt(4 mu C - B^2) / (2 mu)
    mu = J1 * J2 / (J1 + J2)
    omega = math.sqrt(4 * mu * C - B * B) / (2 * mu)
    mode = dg.fastest_mode(Driveline.from_scene(_scene()))
    assert mode.omega == pytest.approx(omega, rel=1e-9)
    assert mode.period == pytest.approx(2 * math.pi / omega, rel=1e-12)


def test_coarse_step_line_at_half_the_period() -> None:
    mode = dg.Mode(100.0, 2 * math.pi / 100.0)
    assert dg.coarse_step_line(0.5 * mode.period, mode, 'sample step') is None
    line = dg.coarse_step_line(0.05, mode, 'exchange step')
    assert line.startswith("exchange step 0.05 s is too coarse for the scene's fastest mode "
                           '(100 rad/s, period 0.0628 s)')
    assert dg.coarse_step_line(1.0, None, 'sample step') is None


def test_stall_line() -> None:
    assert dg.stall_line({'a': 30.0, 'b': 29.0}, 31.4) is None
    assert dg.stall_line({'a': -0.002, 'b': 0.2}, 31.4).startswith(
        'stall: the line stopped (mean speeds within 0.314 rad/s of 0, e.g. b 0.2 rad/s')
    assert dg.stall_line({'a': 0.01}, 0.0) is not None           # from standstill: 0.05 rad/s
    assert dg.stall_line({'a': float('nan')}, 10.0) is None
    assert dg.stall_line({}, 10.0) is None


def test_angle_limit_lines_as_the_monitor() -> None:
    tripod = {'type': 'joint', 'name': 'tj', 'kind': 'tripod', 'params': {'beta_deg': 40.0}}
    assert dg.angle_limit_lines(_scene(tripod)) == [
        'limit exceeded: joint tj bent 40 deg, above the recommended limit for a tripod joint 25 deg']
    hooke = {'type': 'joint', 'name': 'h', 'kind': 'hooke', 'params': {'beta_deg': 40.0},
             'limits': {'max_angle_deg': 25.0}}
    assert dg.angle_limit_lines(_scene(hooke)) == [
        'limit exceeded: joint h bent 40 deg, above its limits.max_angle_deg 25 deg']
    hooke['params']['beta_deg'] = 20.0
    assert dg.angle_limit_lines(_scene(hooke)) == []
    hooke.pop('limits')
    hooke['params']['beta_deg'] = 80.0
    assert dg.angle_limit_lines(_scene(hooke)) == []              # no limit known for hooke


def test_trend_line_names_a_ramp_not_a_fluctuation() -> None:
    import numpy as np
    t = np.linspace(0.0, 2.0, 2001)
    ramp = 100.0 + 3.0 * t                      # +6 rad/s over the window, all of max - min
    line = dg.trend_line(t, {'crank': ramp})
    assert line == ('speed trend: crank accelerates by +6 rad/s over the window (+3 rad/s^2), 100% '
                    'of its max - min speed: the speed nonuniformity there measures that trend, '
                    'not a fluctuation')
    wave = 100.0 + 2.0 * np.sin(2 * np.pi * 5.0 * t)   # whole periods: least-squares slope ~0
    assert dg.trend_line(t, {'crank': wave}) is None
    # a ramp of 1 rad/s under a +-2 rad/s wave: change 1 < 0.5 * span (~5): not named
    assert dg.trend_line(t, {'crank': wave + 0.5 * t}) is None
    assert dg.trend_line(t[:2], {'crank': ramp[:2]}) is None
