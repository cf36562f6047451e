"""Longitudinal vehicle body shared by all wheels (no ROS).

Newton along the road, speed v (m/s), grade angle theta = atan(grade_percent/100)::

    m dv/dt = sum F_x - F_roll(v) - m g sin(theta) - 1/2 rho C_d A v |v|             (N)
    F_roll  = m g C_r cos(theta) tanh(v / v_s)

The rolling resistance changes sign with v; tanh regularises the sign over v_s (m/s, as
cvj_ros.physics.load.RoadLoad does), so the force is smooth at v = 0. Drag uses v |v| so it
opposes motion in reverse too.

Normal loads. Statically wheel i carries share_i m g cos(theta). With a CG height h and a
wheelbase L (CG a distance l_r ahead of the rear axle: the front axle's static share is
l_r / L) the longitudinal load transfer follows from moments about the rear contact point
(ground forces have no arm; gravity, inertia and drag act at h)::

    F_zf L = m g cos(theta) l_r - h (m a + m g sin(theta) + F_aero) = m g cos(theta) l_r - h (sum F_x - F_roll)

(Gillespie 1992, "Fundamentals of Vehicle Dynamics", ch. 2; drag taken at CG height).
Each tyre force is linear in its own normal load, F_x,i = F_z,i y_i with y_i = mu_i MF(kappa_i),
so with F_z,i = F_zf s_i / S_f (front) or F_zr s_i / S_r (rear), F_zr = m g cos(theta) - F_zf,
the moment equation is linear in F_zf and solved in closed form (no algebraic loop).
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

__all__ = ['VehicleBody', 'GRAVITY']

GRAVITY = 9.81   # m/s^2, as cvj_ros.physics.load


@dataclass(frozen=True)
class VehicleBody:
    """Mass ``mass`` (kg), ``grade_percent`` (%), rolling coefficient ``rolling_coeff`` C_r (-),
    ``drag_area`` C_d A (m^2), ``air_density`` rho (kg/m^3), ``speed_scale`` v_s (m/s),
    optional ``cg_height`` h (m), ``wheelbase`` L (m) and ``front_share`` (static share of the
    weight on the front axle, l_r / L) for load transfer (all three or none)."""

    mass: float
    grade_percent: float = 0.0
    rolling_coeff: float = 0.012
    drag_area: float = 0.66
    air_density: float = 1.2
    speed_scale: float = 0.1
    cg_height: float | None = None
    wheelbase: float | None = None
    front_share: float | None = None
    gravity: float = GRAVITY

    @property
    def theta(self) -> float:
        """Grade angle (rad)."""
        return math.atan(self.grade_percent / 100.0)

    @property
    def weight_normal(self) -> float:
        """m g cos(theta) (N): the sum of the wheels' normal loads."""
        return self.mass * self.gravity * math.cos(self.theta)

    def resistance(self, v: float) -> float:
        """F_roll(v) + m g sin(theta) + 1/2 rho C_d A v |v| (N), the force opposing the
        drive at speed v (m/s)."""
        return self.rolling(v) + self.climbing() + self.aero(v)

    def rolling(self, v: float) -> float:
        """m g C_r cos(theta) tanh(v / v_s) (N)."""
        return self.weight_normal * self.rolling_coeff * math.tanh(v / self.speed_scale)

    def climbing(self) -> float:
        """m g sin(theta) (N)."""
        return self.mass * self.gravity * math.sin(self.theta)

    def aero(self, v: float) -> float:
        """1/2 rho C_d A v |v| (N)."""
        return 0.5 * self.air_density * self.drag_area * v * abs(v)

    def acceleration(self, v: float, sum_fx: float) -> float:
        """dv/dt (m/s^2) for total tyre force ``sum_fx`` (N)."""
        return (sum_fx - self.resistance(v)) / self.mass

    def normal_loads(self, share: Sequence[float], axle: Sequence[int],
                     grip: Sequence[float], v: float) -> list[float]:
        """Per driven wheel F_z (N) given its static share of the weight, its axle (+1 front,
        -1 rear) and its grip y_i = F_x,i / F_z,i (-). Wheels not listed (undriven) roll
        freely: F_x = 0.

        Without ``cg_height`` F_z,i = share_i m g cos(theta). With it, the front axle carries
        F_zf from the moment equation of the module docstring (static front share
        f = ``front_share``, linear in F_zf, closed form), each wheel its static fraction of
        its axle's load (share_i / f front, share_i / (1 - f) rear)."""
        w = self.weight_normal
        if self.cg_height is None or self.wheelbase is None or self.front_share is None:
            return [s * w for s in share]
        sf = self.front_share
        sr = 1.0 - sf
        gf = sum(s * y for s, y, a in zip(share, grip, axle) if a > 0) / sf if sf > 0 else 0.0
        gr = sum(s * y for s, y, a in zip(share, grip, axle) if a < 0) / sr if sr > 0 else 0.0
        h, el = self.cg_height, self.wheelbase
        # F_zf L = W f L - h (F_zf gf + (W - F_zf) gr - F_roll)
        fzf = (w * sf * el - h * (w * gr - self.rolling(v))) / (el + h * (gf - gr))
        # a lifted axle (wheelie, stoppie) is outside this model: clamp, the tyre reports NO_LOAD
        fzf = min(max(fzf, 0.0), w)
        fzr = w - fzf
        return [fzf * s / sf if a > 0 else fzr * s / sr for s, a in zip(share, axle)]
