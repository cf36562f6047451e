"""Magic-formula tyre: closed forms of the curve (slope B C D at zero slip, peak D at the
stated slip, asymptote D sin(C pi/2)), the relaxed slip against its exponential solution,
finite from rest, and the no-load status."""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from cvj_ros.physics.tyre import DRY_TARMAC, TYRE_NO_LOAD, TYRE_OK, MagicFormula, Tyre


def test_curve_through_origin_odd_and_slope_bcd() -> None:
    mf = DRY_TARMAC
    assert mf.shape(0.0) == 0.0
    for k in (0.01, 0.1, 0.5, 2.0):
        assert mf.shape(-k) == -mf.shape(k)
    # dF/dkappa at 0 = B C D (Pacejka 2012 ch. 4): the longitudinal slip stiffness
    assert mf.slope(0.0) == pytest.approx(mf.B * mf.C, rel=1e-14)
    h = 1e-6
    assert (mf.shape(h) - mf.shape(-h)) / (2 * h) == pytest.approx(mf.B * mf.C, rel=1e-9)


@pytest.mark.parametrize('mf', [DRY_TARMAC, MagicFormula(12.0, 2.3, 1.0), MagicFormula(5.0, 2.0, 1.0),
                                MagicFormula(4.0, 2.0, 1.0), MagicFormula(8.0, 1.6, 0.5)])
def test_peak_equals_d_at_the_stated_slip(mf: MagicFormula) -> None:
    kp = mf.peak_slip()
    # the peak: C atan(x) = pi/2 exactly, y = 1 (F_x = D)
    assert mf.shape(kp) == pytest.approx(1.0, abs=1e-14)
    grid = np.linspace(0.0, 1.0, 200001)
    y = np.array([mf.shape(k) for k in grid])
    assert grid[int(np.argmax(y))] == pytest.approx(kp, abs=1e-5)
    assert y.max() <= 1.0 + 1e-15
    # slope changes sign at the peak
    assert mf.slope(0.99 * kp) > 0 > mf.slope(1.01 * kp)


def test_dry_tarmac_published_shape() -> None:
    """Typical dry-tarmac set B = 10, C = 1.9, E = 0.97 (quoted with Pacejka 2012): peak near
    10 % slip (the closed form x = tan(pi/(2C)) solved for kappa), slow fall-off to the
    locked-wheel value D sin(C pi/2) = 0.156 D."""
    mf = DRY_TARMAC
    kp = mf.peak_slip()
    target = math.tan(math.pi / (2 * mf.C))
    bk = mf.B * kp
    assert bk - mf.E * (bk - math.atan(bk)) == pytest.approx(target, rel=1e-12)
    assert 0.08 < kp < 0.2
    assert mf.shape(1e9) == pytest.approx(math.sin(mf.C * math.pi / 2), abs=1e-6)
    assert mf.shape(1.0) == pytest.approx(math.sin(mf.C * math.atan(10 - 0.97 * (10 - math.atan(10)))),
                                          rel=1e-15)


def test_slope_matches_numerical_derivative() -> None:
    for mf in (DRY_TARMAC, MagicFormula(8.0, 1.6, 0.5)):
        for k in np.linspace(-1.5, 1.5, 61):
            h = 1e-6
            num = (mf.shape(k + h) - mf.shape(k - h)) / (2 * h)
            assert mf.slope(float(k)) == pytest.approx(num, rel=1e-6, abs=1e-8)


def test_force_scales_with_mu_fz_and_no_load_status() -> None:
    ty = Tyre(mu=0.9, radius=0.3)
    f, st = ty.force(0.05, 4000.0)
    assert st == TYRE_OK
    assert f == pytest.approx(0.9 * 4000.0 * DRY_TARMAC.shape(0.05), rel=1e-15)
    for fz in (0.0, -10.0, float('nan')):
        f, st = ty.force(0.2, fz)
        assert (f, st) == (0.0, TYRE_NO_LOAD)


def test_relaxed_slip_follows_its_exponential_solution() -> None:
    """sigma k' = (omega r - v) - |v| k at constant omega, v: k(t) = k_ss + (k0 - k_ss)
    exp(-|v| t / sigma), k_ss the slip ratio (omega r - v)/|v|."""
    ty = Tyre(radius=0.3, sigma=0.25)
    omega, v, k0 = 80.0, 20.0, -0.1
    kss = ty.slip_ratio(omega, v)
    assert kss == pytest.approx((80 * 0.3 - 20) / 20)
    sol = solve_ivp(lambda t, y: [ty.slip_rate(y[0], omega, v)], (0, 0.05), [k0], rtol=1e-11,
                    atol=1e-13, t_eval=[0.01, 0.05])
    exact = kss + (k0 - kss) * np.exp(-abs(v) * sol.t / ty.sigma)
    assert sol.y[0] == pytest.approx(exact, rel=1e-8)
    # reverse: |v| keeps the relaxation stable
    assert ty.slip_rate(0.0, -10.0 / 0.3, -10.0) == 0.0


def test_from_rest_slip_is_finite_and_integrates_the_slip_velocity() -> None:
    ty = Tyre(radius=0.3, sigma=0.2)
    # v = 0: dk/dt = omega r / sigma, no division by zero
    assert ty.slip_rate(0.0, 10.0, 0.0) == pytest.approx(10 * 0.3 / 0.2)
    assert ty.slip_rate(0.0, 0.0, 0.0) == 0.0
    with pytest.raises(ZeroDivisionError):
        ty.slip_ratio(1.0, 0.0)
