"""Hooke (cardan) joint: kinematics and the reaction wrench of the cross.

Geometry and conventions (used by the tests' rotation-matrix construction too).
Housing frame = input-shaft frame: y along the input shaft axis a1, z in the bend
plane, x = y x z normal to it. The output axis is a2 = R_x(beta) e_y =
(0, cos b, sin b), bend angle beta with 0 <= beta < 90 deg. Shaft k turns by phi_k
right-handed about its own axis a_k (R_y(phi1) for the input, R_x(beta) R_y(phi2)
for the output), so positive rotation has the same sense on both shafts.
Zero positions: phi_in = 0 when the driving yoke (cross arm p1 = R_y(phi1) e_z =
(sin phi1, 0, cos phi1)) lies in the bend plane; phi_out = 0 at the same instant,
when the driven yoke arm p2 = R_x(b) R_y(phi2) e_x is normal to the bend plane.
The cross holds p1 . p2 = 0, i.e. sin phi1 cos phi2 - cos phi1 cos b sin phi2 = 0:

    tan(phi_out) = tan(phi_in) / cos(beta)            (seed 002 eq. 10 with delta = 90 deg)

written without branch cuts as phi_out = phi_in + d(phi_in) with the bounded deviation

    d = atan2(sin(phi) cos(phi) (1 - cos b), cos(b) cos^2(phi) + sin^2(phi)),  |d| < pi/2,

so phi_out is continuous over any number of revolutions. Ratio and slope::

    ratio       = cos b / (sin^2 phi + cos^2 b cos^2 phi)        (= cos b/(1 - sin^2 b cos^2 phi))
    ratio_slope = -cos b sin^2 b sin(2 phi) / (sin^2 phi + cos^2 b cos^2 phi)^2

The ratio swings between cos(beta) (phi = pi/2) and 1/cos(beta) (phi = 0); the
deviation amplitude is atan((1 - cos b) / (2 sqrt(cos b))) at tan(phi) = sqrt(cos b).
"""
from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from cvj_ros.errors import GeometryError
from cvj_ros.physics.joints.base import (FloatArray, JointEval, JointSpec, as_angle_array,
                                         check_finite, register)

HOOKE_FIDELITIES = ('ideal', 'exact')


def check_fidelity(fidelity: str, allowed: tuple[str, ...], kind: str) -> str:
    """Return ``fidelity`` if it is one of ``allowed``, else raise :class:`GeometryError`."""
    if fidelity not in allowed:
        raise GeometryError('fidelity', f'{kind} has fidelities {", ".join(allowed)}; got {fidelity!r}')
    return fidelity


def check_bend(name: str, value: float) -> float:
    """Validate a bend angle (rad): 0 <= value < pi/2; the message gives deg and rad."""
    v = check_finite(name, value)
    if not 0.0 <= v < math.pi / 2:
        raise GeometryError(name, f'must be >= 0 and < 90 deg (pi/2 rad), got '
                                  f'{math.degrees(v):.6g} deg ({v:.6g} rad)')
    return v


def hooke_deviation(phi: FloatArray, cos_beta: float) -> FloatArray:
    """phi_out - phi_in (rad) of a Hooke joint, bounded by pi/2; vectorised (seed 002 eq. 10)."""
    s, co = np.sin(phi), np.cos(phi)
    return np.arctan2(s * co * (1.0 - cos_beta), cos_beta * co * co + s * s)


def hooke_stage(phi: FloatArray, cos_beta: float) -> tuple[FloatArray, FloatArray, FloatArray]:
    """(phi_out, ratio, ratio_slope) of tan(phi_out) = tan(phi)/cos_beta, vectorised.

    Units: rad, -, 1/rad. Source: seed 002 eq. 10; derivatives differentiated by hand.
    """
    s, co = np.sin(phi), np.cos(phi)
    den = cos_beta * cos_beta * co * co + s * s
    dev = np.arctan2(s * co * (1.0 - cos_beta), cos_beta * co * co + s * s)
    ratio = cos_beta / den
    slope = -cos_beta * (1.0 - cos_beta * cos_beta) * 2.0 * s * co / (den * den)
    return phi + dev, ratio, slope


def hooke_stage_scalar(phi: float, cos_beta: float) -> tuple[float, float, float]:
    """Float version of :func:`hooke_stage` (rad, -, 1/rad)."""
    s, co = math.sin(phi), math.cos(phi)
    den = cos_beta * cos_beta * co * co + s * s
    dev = math.atan2(s * co * (1.0 - cos_beta), cos_beta * co * co + s * s)
    return (phi + dev, cos_beta / den,
            -cos_beta * (1.0 - cos_beta * cos_beta) * 2.0 * s * co / (den * den))


class Hooke:
    """Single Hooke joint with bend angle ``beta`` (rad), 0 <= beta < pi/2.

    Fidelities: ``exact`` (the cross law above) and ``ideal`` (phi_out = phi_in).
    """

    kind = 'hooke'
    mid_name: str | None = None

    def __init__(self, beta: float, *, fidelity: str = 'exact') -> None:
        self.beta = check_bend('beta', beta)
        self.fidelity = check_fidelity(fidelity, HOOKE_FIDELITIES, self.kind)
        self._c = math.cos(self.beta)
        self._s2 = math.sin(self.beta) ** 2

    def params(self) -> dict[str, float]:
        return {'beta': self.beta}

    def evaluate(self, phi_in: ArrayLike) -> JointEval:
        phi = as_angle_array(phi_in)
        if self.fidelity == 'ideal':
            return JointEval(phi.copy(), np.ones_like(phi), np.zeros_like(phi))
        out, ratio, slope = hooke_stage(phi, self._c)
        return JointEval(out, ratio, slope)

    def scalar(self, phi_in: float) -> tuple[float, float, float]:
        if self.fidelity == 'ideal':
            return phi_in, 1.0, 0.0
        return hooke_stage_scalar(phi_in, self._c)

    def nonuniformity(self) -> float:
        """Amplitude of phi_out - phi_in (rad): atan((1 - cos b) / (2 sqrt(cos b)))."""
        if self.fidelity == 'ideal':
            return 0.0
        c = self._c
        return math.atan((1.0 - c) / (2.0 * math.sqrt(c)))

    def reactions(self, phi_in: float, omega_in: float, torque_in: float) -> dict[str, float]:
        """Quasi-static reaction wrench of a massless, frictionless cross (N m).

        Derivation (virtual work, no seed gives it). The yoke bearings carry no moment
        about their own pin, so the moment M that the input yoke passes through the
        cross to the output yoke is normal to both pins: M = m n, n = p1 x p2 (unit,
        since p1 _|_ p2). Its component along the input axis is the input torque,
        M . a1 = T1, which fixes m. With N = sqrt(cos^2 b cos^2 phi1 + sin^2 phi1),
        cos phi2 = cos b cos phi1 / N, sin phi2 = sin phi1 / N this gives, in the
        housing frame (x, y, z) of the module docstring::

            M = T1 (-tan b sin phi1 cos phi1,  1,  tan b sin^2 phi1)
            T2 = M . a2 = T1 N^2 / cos b = T1 / ratio         (power balance, seed 003 eq. 20 analogue)
            C1 = M - T1 a1 = T1 tan b sin phi1 (-cos phi1, 0, sin phi1),   |C1| = T1 tan b |sin phi1|
            C2 = M - T2 a2 = T1 cos phi1 (-tan b sin phi1, sin^2 b cos phi1, -sin b cos b cos phi1),
                 |C2| = T2 tan b |cos phi2|

        C1, C2 are the secondary couples: the bending moments the cross puts on the
        input and output yokes, reacted by each shaft's support bearings. The cross
        inertia is neglected, so ``omega_in`` (rad/s) does not enter.

        Args:
            phi_in: input angle (rad). omega_in: input speed (rad/s, unused).
            torque_in: torque delivered by the input shaft into the joint (N m).
        Returns:
            ``torque_out`` (N m, about a2, power balance), ``moment_x/y/z`` (M),
            ``secondary_in_x/z`` and ``secondary_in`` (C1 components and magnitude),
            ``secondary_out_x/y/z`` and ``secondary_out`` (C2), all N m, housing frame.
        """
        check_finite('omega_in', omega_in)
        t1 = check_finite('torque_in', torque_in)
        phi = check_finite('phi_in', phi_in)
        if self.fidelity == 'ideal':
            zero = {k: 0.0 for k in ('moment_x', 'moment_z', 'secondary_in_x', 'secondary_in_z',
                                     'secondary_in', 'secondary_out_x', 'secondary_out_y',
                                     'secondary_out_z', 'secondary_out')}
            return {'torque_out': t1, 'moment_y': t1, **zero}
        c, sb = self._c, math.sin(self.beta)
        tb = sb / c
        s1, c1 = math.sin(phi), math.cos(phi)
        n2 = c * c * c1 * c1 + s1 * s1
        t2 = t1 * n2 / c
        mx, my, mz = -t1 * tb * s1 * c1, t1, t1 * tb * s1 * s1
        cin_x, cin_z = mx, mz
        cout = (mx, t1 * sb * sb * c1 * c1, -t1 * sb * c * c1 * c1)
        return {'torque_out': t2, 'moment_x': mx, 'moment_y': my, 'moment_z': mz,
                'secondary_in_x': cin_x, 'secondary_in_z': cin_z,
                'secondary_in': math.hypot(cin_x, cin_z),
                'secondary_out_x': cout[0], 'secondary_out_y': cout[1], 'secondary_out_z': cout[2],
                'secondary_out': math.sqrt(cout[0] ** 2 + cout[1] ** 2 + cout[2] ** 2)}


def hooke_ratio(phi_in: ArrayLike, beta: float) -> np.ndarray:
    """Closed-form velocity ratio cos b / (1 - sin^2 b cos^2 phi) (-) (DESIGN.md section 4)."""
    phi = np.asarray(phi_in, dtype=float)
    return math.cos(beta) / (1.0 - math.sin(beta) ** 2 * np.cos(phi) ** 2)


def _factory(*, fidelity: str = 'exact', beta: float = 0.0, **extra: float) -> Hooke:
    if extra:
        raise GeometryError(sorted(extra)[0], 'unknown parameter for hooke (known: beta)')
    return Hooke(beta, fidelity=fidelity)


register(JointSpec(kind='hooke', factory=_factory, fidelities=HOOKE_FIDELITIES,
                   params={'beta': 'rad, bend angle, 0 <= beta < pi/2, default 0'},
                   source='seed 002 eq. 10 (cross relation); reactions derived in hooke.py'))
