"""Longitudinal tyre: Pacejka's magic formula with a first-order slip relaxation.

Steady-state force (Pacejka 2012, "Tire and Vehicle Dynamics", 3rd ed., ch. 4; Pacejka &
Bakker 1992), slip ratio kappa (-), normal load F_z (N), friction coefficient mu (-)::

    F_x = D sin(C atan(B kappa - E (B kappa - atan(B kappa)))),   D = mu F_z     (N)

B stiffness factor, C shape factor, E curvature factor (-). Defaults B = 10, C = 1.9,
E = 0.97: the typical dry-tarmac set quoted with Pacejka 2012 (Simscape Driveline,
Tire-Road Interaction (Magic Formula) block). Slope at kappa = 0: B C D (N per unit slip);
peak D where C atan(x) = pi/2; for kappa -> inf F_x -> D sin(C pi/2) (E < 1).

Low speed. The slip ratio kappa = (omega r - v)/|v| is singular at v = 0. Instead the force
follows a *relaxed* slip kappa' (a state) with relaxation length sigma (m), the transient
single-contact-point model (Pacejka 2012, ch. 7; Bernard & Clover 1995, SAE 950311)::

    sigma dkappa'/dt = (omega r - v) - |v| kappa'                                  (1/s)

At |v| >> sigma / t kappa' tends to the slip ratio; at v = 0 it integrates the slip
velocity (the contact patch deflects like a spring of stiffness B C D / sigma), so a start
from rest is finite. F_z <= 0 (a lifted wheel) gives F_x = 0 with status NO_LOAD, never NaN.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ['MagicFormula', 'Tyre', 'TYRE_OK', 'TYRE_NO_LOAD', 'TYRE_STATUS',
           'DRY_TARMAC', 'DEFAULT_RELAXATION_LENGTH']

#: tyre status codes (per wheel, per evaluation)
TYRE_OK = 0
TYRE_NO_LOAD = 1          # F_z <= 0: the wheel carries no load, no longitudinal force
TYRE_STATUS = {TYRE_OK: 'ok', TYRE_NO_LOAD: 'no load (F_z <= 0): wheel lifted, F_x = 0'}
#: relaxation length sigma (m): of the order of half the contact length to a tyre radius
#: for passenger tyres (Pacejka 2012, ch. 7); 0.2 m
DEFAULT_RELAXATION_LENGTH = 0.2


@dataclass(frozen=True)
class MagicFormula:
    """Normalised magic formula y(kappa) = F_x / D = sin(C atan(B k - E (B k - atan(B k)))).

    B, C, E dimensionless; valid for B > 0, 0 < C < 2, E <= 1 (then the inner argument is
    monotone in kappa and the curve has one peak per sign).
    """

    B: float = 10.0
    C: float = 1.9
    E: float = 0.97

    def _x(self, kappa: float) -> float:
        bk = self.B * kappa
        return bk - self.E * (bk - math.atan(bk))

    def shape(self, kappa: float) -> float:
        """F_x / D at slip ``kappa`` (-)."""
        return math.sin(self.C * math.atan(self._x(kappa)))

    def slope(self, kappa: float) -> float:
        """d(F_x / D)/dkappa (-)."""
        bk = self.B * kappa
        x = bk - self.E * (bk - math.atan(bk))
        dx = self.B * (1.0 - self.E) + self.E * self.B / (1.0 + bk * bk)
        return math.cos(self.C * math.atan(x)) * self.C * dx / (1.0 + x * x)

    def peak_slip(self) -> float:
        """kappa > 0 of the peak y = 1: B k - E (B k - atan(B k)) = tan(pi / (2 C)), solved
        by bisection (the left side increases monotonically in k for E <= 1)."""
        target = math.tan(0.5 * math.pi / self.C)
        lo, hi = 0.0, 1.0
        while self._x(hi) < target:
            hi *= 2.0
        for _ in range(200):
            mid = 0.5 * (lo + hi)
            if self._x(mid) < target:
                lo = mid
            else:
                hi = mid
        return 0.5 * (lo + hi)


DRY_TARMAC = MagicFormula(10.0, 1.9, 0.97)


@dataclass(frozen=True)
class Tyre:
    """A wheel's longitudinal tyre: magic formula ``mf``, friction ``mu`` (-), rolling
    radius ``radius`` (m), relaxation length ``sigma`` (m)."""

    mu: float = 0.9
    radius: float = 0.3
    mf: MagicFormula = DRY_TARMAC
    sigma: float = DEFAULT_RELAXATION_LENGTH

    def force(self, kappa: float, fz: float) -> tuple[float, int]:
        """(F_x in N, status): F_x = mu F_z y(kappa); F_z <= 0 gives (0.0, TYRE_NO_LOAD)."""
        if not fz > 0.0:
            return 0.0, TYRE_NO_LOAD
        return self.mu * fz * self.mf.shape(kappa), TYRE_OK

    def slip_rate(self, kappa: float, omega: float, v: float) -> float:
        """dkappa'/dt = ((omega r - v) - |v| kappa') / sigma (1/s); finite at v = 0."""
        return (omega * self.radius - v - abs(v) * kappa) / self.sigma

    def slip_ratio(self, omega: float, v: float) -> float:
        """Steady slip ratio (omega r - v)/|v| (-), the fixed point of :meth:`slip_rate`;
        undefined at v = 0 (ZeroDivisionError)."""
        return (omega * self.radius - v) / abs(v)
