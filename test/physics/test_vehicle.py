"""Vehicle body: coast-down in closed form, grade and rolling resistance, load transfer
checked against the moment balance it must satisfy."""
from __future__ import annotations

import math

import pytest
from scipy.integrate import solve_ivp

from cvj_ros.physics.vehicle import VehicleBody


def test_coast_down_drag_only_closed_form() -> None:
    """m dv/dt = -k v^2 (k = rho C_d A / 2): v(t) = v0 / (1 + k v0 t / m)."""
    body = VehicleBody(mass=1500.0, rolling_coeff=0.0, drag_area=0.66, air_density=1.2)
    k = 0.5 * 1.2 * 0.66
    v0 = 30.0
    sol = solve_ivp(lambda t, y: [body.acceleration(y[0], 0.0)], (0, 60), [v0], rtol=1e-11,
                    atol=1e-12, t_eval=[10, 60])
    assert sol.y[0] == pytest.approx(v0 / (1 + k * v0 * sol.t / 1500.0), rel=1e-8)
    # drag opposes motion in reverse too
    assert body.aero(-10.0) == -body.aero(10.0) < 0


def test_rolling_resistance_regularised_sign_and_grade() -> None:
    body = VehicleBody(mass=1000.0, grade_percent=10.0, rolling_coeff=0.015, drag_area=0.0,
                       speed_scale=0.1)
    th = math.atan(0.1)
    assert body.theta == pytest.approx(th)
    assert body.rolling(0.0) == 0.0
    assert body.rolling(-5.0) == pytest.approx(-body.rolling(5.0))
    assert body.rolling(5.0) == pytest.approx(1000 * 9.81 * 0.015 * math.cos(th), rel=1e-12)
    # holding the car at rest on the grade takes exactly m g sin(theta)
    assert body.acceleration(0.0, 1000 * 9.81 * math.sin(th)) == pytest.approx(0.0, abs=1e-12)
    # released, it rolls back
    assert body.acceleration(0.0, 0.0) < 0


def test_static_normal_loads_are_the_shares() -> None:
    body = VehicleBody(mass=1500.0, grade_percent=5.0)
    w = 1500 * 9.81 * math.cos(math.atan(0.05))
    fz = body.normal_loads([0.3, 0.3, 0.2, 0.2], [1, 1, -1, -1], [0.5, 0.5, 0.0, 0.0], 10.0)
    assert fz == pytest.approx([0.3 * w, 0.3 * w, 0.2 * w, 0.2 * w], rel=1e-15)


@pytest.mark.parametrize('grip', [[0.6, 0.4, 0.0, 0.0], [0.0, 0.0, 0.8, 0.7], [-0.9, -0.9, -0.5, -0.5],
                                  [0.3, 0.3, 0.3, 0.3]])
def test_load_transfer_satisfies_the_moment_balance(grip: list[float]) -> None:
    """Independent check of the closed-form solve: total F_z = m g cos(theta), and the moment
    balance about the rear contact F_zf L = m g cos(theta) l_r - h (sum F_x - F_roll) with
    sum F_x computed from the returned loads (F_x,i = F_z,i y_i)."""
    body = VehicleBody(mass=1500.0, grade_percent=8.0, cg_height=0.55, wheelbase=2.6, front_share=0.62)
    share, axle = [0.31, 0.31, 0.19, 0.19], [1, 1, -1, -1]
    v = 15.0
    fz = body.normal_loads(share, axle, grip, v)
    w = body.weight_normal
    assert sum(fz) == pytest.approx(w, rel=1e-13)    # all wheels listed: shares sum to 1
    sum_fx = sum(f * y for f, y in zip(fz, grip))
    fzf = fz[0] + fz[1]
    lhs = fzf * 2.6
    rhs = w * 2.6 * 0.62 - 0.55 * (sum_fx - body.rolling(v))
    assert lhs == pytest.approx(rhs, rel=1e-12)
    assert fz[0] / fz[1] == pytest.approx(1.0)
    # driving forces move load to the rear, braking to the front
    if sum_fx - body.rolling(v) > 0:
        assert fzf < 0.62 * w
    else:
        assert fzf > 0.62 * w


def test_load_transfer_with_undriven_wheels() -> None:
    """Front-wheel drive: only the front wheels are listed; the rear axle carries the rest."""
    body = VehicleBody(mass=1500.0, cg_height=0.55, wheelbase=2.6, front_share=0.6)
    fz = body.normal_loads([0.3, 0.3], [1, 1], [0.8, 0.2], 20.0)
    w = body.weight_normal
    sum_fx = fz[0] * 0.8 + fz[1] * 0.2
    assert (fz[0] + fz[1]) * 2.6 == pytest.approx(w * 0.6 * 2.6 - 0.55 * (sum_fx - body.rolling(20.0)),
                                                  rel=1e-12)
