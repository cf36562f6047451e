"""Bevel differential: Willis' relation from rolling contact in 3-D, the 2x2 mass matrix
against the members' kinetic energies, torque split and power balance."""
from __future__ import annotations

import numpy as np
import pytest

from cvj_ros.physics.differential import Differential


def _rolling_contact(omega_l: float, omega_r: float, r_side: float, r_spider: float
                     ) -> tuple[float, float]:
    """(omega_c, psi_dot) from no-slip at the spider's two mesh points, built with vectors:
    axle along x, spider pin along y at distance r_side, mesh points (-/+ r_spider, r_side, 0);
    side gear velocity omega x_hat x p equals the spider's (omega_c x_hat + psi_dot y_hat) x p."""
    x, y = np.array([1.0, 0, 0]), np.array([0, 1.0, 0])
    rows, rhs = [], []
    for om, p in ((omega_l, np.array([-r_spider, r_side, 0])), (omega_r, np.array([r_spider, r_side, 0]))):
        v_gear = np.cross(om * x, p)
        # unknowns (omega_c, psi_dot): velocity = omega_c (x cross p) + psi_dot (y cross p)
        a = np.stack([np.cross(x, p), np.cross(y, p)], axis=1)
        rows.append(a)
        rhs.append(v_gear)
    sol, *_ = np.linalg.lstsq(np.vstack(rows), np.concatenate(rhs), rcond=None)
    return float(sol[0]), float(sol[1])


@pytest.mark.parametrize('wl, wr', [(10.0, 10.0), (30.0, 10.0), (-5.0, 12.0), (0.0, 40.0)])
def test_willis_relation_from_rolling_contact(wl: float, wr: float) -> None:
    r_s, r_p = 0.045, 0.03      # z_s/z_p = r_s/r_p = 1.5
    wc, psi = _rolling_contact(wl, wr, r_s, r_p)
    d = Differential(ratio=3.9, spider_ratio=r_s / r_p)
    assert d.carrier_speed(wl, wr) == pytest.approx(wc, abs=1e-12)
    assert d.spider_speed(wl, wr) == pytest.approx(psi, abs=1e-12)
    assert d.input_speed(wl, wr) == pytest.approx(3.9 * wc, abs=1e-12)
    wl2, wr2 = d.side_speeds(d.input_speed(wl, wr), 0.5 * (wl - wr))
    assert (wl2, wr2) == pytest.approx((wl, wr), abs=1e-12)


def test_mass_matrix_is_the_kinetic_energy() -> None:
    d = Differential(ratio=3.9, J_carrier=0.02, J_spider=0.0012, spider_ratio=1.6)
    m = d.mass_matrix(0.004, 0.006, j_input=0.001)
    assert np.allclose(m, m.T)
    assert np.all(np.linalg.eigvalsh(m) > 0)
    rng = np.random.default_rng(1)
    for wl, wr in rng.uniform(-100, 100, (20, 2)):
        w = np.array([wl, wr])
        assert 0.5 * w @ m @ w == pytest.approx(d.kinetic_energy(wl, wr, 0.004, 0.006, 0.001), rel=1e-13)


def test_open_differential_equal_torques_and_power_balance() -> None:
    d = Differential(kind='open', ratio=3.9)
    tl, tr = d.side_torques(100.0, 50.0, 10.0)
    assert tl == tr == pytest.approx(195.0)
    # power in = power out (lossless) at any speeds
    wl, wr = 50.0, 10.0
    assert 100.0 * d.input_speed(wl, wr) == pytest.approx(tl * wl + tr * wr, rel=1e-14)
    assert d.dissipation(wl, wr) == 0.0


def test_viscous_bias_and_dissipation() -> None:
    d = Differential(kind='viscous', ratio=4.0, viscous=2.5)
    wl, wr = 60.0, 20.0
    tl, tr = d.side_torques(100.0, wl, wr)
    assert tr - tl == pytest.approx(2 * 2.5 * 40.0)
    assert tl + tr == pytest.approx(400.0)
    # P_in = P_out + c_v (w_L - w_R)^2
    assert 100.0 * d.input_speed(wl, wr) == pytest.approx(tl * wl + tr * wr + d.dissipation(wl, wr))
    assert d.dissipation(wl, wr) == pytest.approx(2.5 * 40.0 ** 2)


def test_locked_split_is_not_the_gears() -> None:
    d = Differential(kind='locked')
    assert not d.has_dof
    with pytest.raises(ValueError):
        d.side_torques(1.0, 1.0, 1.0)
