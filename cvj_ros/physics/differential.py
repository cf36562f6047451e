"""Bevel-gear differential: kinematics, kinetic energy, torque split (no ROS).

Members: input pinion (angle phi_in), carrier (phi_c) driven through the ring ratio
i = omega_in / omega_c, left and right side gears (phi_L, phi_R), n spider gears on pins
fixed in the carrier, meshing with both side gears (z_s side-gear, z_p spider teeth).
Rolling without slip at the two meshes of a spider (radius r_s from the axle axis, the
side gears turning about the axle axis, the spider about its pin) gives (Willis' relation
of a bevel epicyclic, e.g. Mueller, "Die Umlaufgetriebe", 1998; Chrono ChShaftsPlanetary
with r1 = r2 = 1/2, r3 = -1)::

    omega_c = (omega_L + omega_R) / 2,        psi_dot = (z_s / z_p) (omega_L - omega_R) / 2

with psi the spider's spin angle relative to the carrier. Coordinates used by the driveline:
the input section's q (carrier phi_c = phi_in(q) / i) and the half difference
delta = (phi_L - phi_R) / 2, so phi_L = phi_c + delta, phi_R = phi_c - delta.

Kinetic energy (spider axes principal: the carrier rate is along the axle, perpendicular to
the pin, so the spider's transverse and spin energies add)::

    2 T = J_c omega_c^2 + J_sL omega_L^2 + J_sR omega_R^2 + J_p psi_dot^2

J_c: carrier with the spiders' orbital and transverse inertia about the axle axis; J_p: sum
of the spiders' spin inertias about their pins. In (omega_L, omega_R), with
A = J_c (+ i^2 x the input's inertia), P = J_p (z_s/z_p)^2, the mass matrix is

    M = [[A/4 + J_sL + P/4, A/4 - P/4], [A/4 - P/4, A/4 + J_sR + P/4]]      (kg m^2)

and in (omega_c, delta_dot) it is diagonal: diag(A + J_sL + J_sR, J_sL + J_sR + P) plus the
off-diagonal (J_sL - J_sR) (zero for equal side gears).

Torques. Virtual work T_in dphi_in = (i T_in / 2)(dphi_L + dphi_R): an ideal (massless,
lossless) open differential passes equal side torques T_L = T_R = i T_in / 2 whatever the
speeds. Locked: omega_L = omega_R (one body; the split follows the wheels). Viscous coupling
(limited slip): a bias torque T_b = c_v (omega_L - omega_R) acts -T_b on the left and +T_b
on the right side gear (T_L = i T_in/2 - T_b, T_R = i T_in/2 + T_b); it dissipates
T_b (omega_L - omega_R) = c_v (omega_L - omega_R)^2 >= 0. A clutch-pack (preload + Coulomb
stick/slip) differential is a mode element: stuck it is 'locked', slipping 'open' with a
Coulomb bias torque (cvj_ros.physics.hybrid.tree).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

__all__ = ['Differential', 'DIFF_KINDS']

DIFF_KINDS = ('open', 'locked', 'viscous')


@dataclass(frozen=True)
class Differential:
    """kind 'open' | 'locked' | 'viscous'; ``ratio`` i = omega_in/omega_c (-); ``J_carrier``,
    ``J_spider`` (kg m^2, see module docstring); ``spider_ratio`` z_s/z_p (-); ``viscous``
    c_v (N m s/rad, kind 'viscous')."""

    kind: str = 'open'
    ratio: float = 1.0
    J_carrier: float = 0.0
    J_spider: float = 0.0
    spider_ratio: float = 1.0
    viscous: float = 0.0

    @property
    def has_dof(self) -> bool:
        """True when the side gears may turn relative to each other (not locked)."""
        return self.kind != 'locked'

    @property
    def spider_inertia(self) -> float:
        """P = J_p (z_s/z_p)^2 (kg m^2): the spiders' spin inertia referred to delta."""
        return self.J_spider * self.spider_ratio ** 2

    @staticmethod
    def carrier_speed(omega_l: float, omega_r: float) -> float:
        """omega_c = (omega_L + omega_R)/2 (rad/s)."""
        return 0.5 * (omega_l + omega_r)

    def input_speed(self, omega_l: float, omega_r: float) -> float:
        """omega_in = i (omega_L + omega_R)/2 (rad/s)."""
        return self.ratio * 0.5 * (omega_l + omega_r)

    def spider_speed(self, omega_l: float, omega_r: float) -> float:
        """Spider spin relative to the carrier, (z_s/z_p)(omega_L - omega_R)/2 (rad/s)."""
        return self.spider_ratio * 0.5 * (omega_l - omega_r)

    def side_speeds(self, omega_in: float, delta_dot: float) -> tuple[float, float]:
        """(omega_L, omega_R) = omega_in / i +/- delta_dot (rad/s)."""
        wc = omega_in / self.ratio
        return wc + delta_dot, wc - delta_dot

    def bias_torque(self, omega_l: float, omega_r: float) -> float:
        """T_b = c_v (omega_L - omega_R) (N m) for 'viscous', else 0."""
        return self.viscous * (omega_l - omega_r) if self.kind == 'viscous' else 0.0

    def dissipation(self, omega_l: float, omega_r: float) -> float:
        """Power lost in the coupling, T_b (omega_L - omega_R) (W)."""
        return self.bias_torque(omega_l, omega_r) * (omega_l - omega_r)

    def side_torques(self, torque_in: float, omega_l: float, omega_r: float) -> tuple[float, float]:
        """Quasi-static (T_L, T_R) (N m) for input torque ``torque_in``: i T_in/2 -/+ T_b.
        A locked differential's split is set by the wheels, not by the gears: ValueError."""
        if self.kind == 'locked':
            raise ValueError('a locked differential does not fix the torque split')
        half = 0.5 * self.ratio * torque_in
        tb = self.bias_torque(omega_l, omega_r)
        return half - tb, half + tb

    def mass_matrix(self, j_side_left: float, j_side_right: float, j_input: float = 0.0
                    ) -> NDArray[np.float64]:
        """2x2 mass matrix in (omega_L, omega_R) (kg m^2), ``j_input`` the input-side
        inertia at the pinion (referred to the carrier as i^2 j_input)."""
        a = self.J_carrier + self.ratio ** 2 * j_input
        p = self.spider_inertia
        off = 0.25 * a - 0.25 * p
        return np.array([[0.25 * a + j_side_left + 0.25 * p, off],
                         [off, 0.25 * a + j_side_right + 0.25 * p]])

    def kinetic_energy(self, omega_l: float, omega_r: float, j_side_left: float,
                       j_side_right: float, j_input: float = 0.0) -> float:
        """Sum of the members' kinetic energies (J), member by member (carrier, input,
        side gears, spiders' spin)."""
        wc = self.carrier_speed(omega_l, omega_r)
        win = self.ratio * wc
        ps = self.spider_speed(omega_l, omega_r)
        return 0.5 * (self.J_carrier * wc * wc + j_input * win * win + j_side_left * omega_l ** 2
                      + j_side_right * omega_r ** 2 + self.J_spider * ps * ps)
