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

    tan(phi_out) = tan(phi_in) / cos(beta)            (Bugaru & Vasile 2021, eq. 10 with delta = 90 deg)

written without branch cuts as phi_out = phi_in + d(phi_in) with the bounded deviation

    d = atan2(sin(phi) cos(phi) (1 - cos b), cos(b) cos^2(phi) + sin^2(phi)),  |d| < pi/2,

so phi_out is continuous over any number of revolutions. Ratio and slope::

    ratio       = cos b / (sin^2 phi + cos^2 b cos^2 phi)        (= cos b/(1 - sin^2 b cos^2 phi))
    ratio_slope = -cos b sin^2 b sin(2 phi) / (sin^2 phi + cos^2 b cos^2 phi)^2

The ratio swings between cos(beta) (phi = pi/2) and 1/cos(beta) (phi = 0); the
deviation amplitude is atan((1 - cos b) / (2 sqrt(cos b))) at tan(phi) = sqrt(cos b).

Yoke phase, bend plane and cross angle (``phase`` psi, ``bend_plane`` gamma, ``cross_angle``
delta; defaults 0, 0, pi/2 give exactly the law above). Each shaft carries a body frame:
the input's reference plane is the housing's y-z plane, and the output's is that plane
carried through the bend (rotation by beta about the bend-plane normal). The bend plane
lies at gamma about the input axis from the reference plane; at phi_in = 0 the driving
yoke's arm p1 lies at psi from the reference plane (with gamma = 0: psi is the driving
yoke's angle to the bend plane at zero input angle). The driven yoke's arm sits at
psi + delta in the output's body frame. In the bend-plane frame the arms are at

    theta1 = phi_in + psi - gamma,   theta2 = phi_out + psi - gamma - (pi/2 - delta),

and the cross holds p1 . p2 = cos(delta) (Bugaru & Vasile 2021 eqs. 9-10, with their
angles measured from the bend-plane normal, ours from the bend plane):

    sin(theta1) cos(theta2) - cos(b) cos(theta1) sin(theta2) = cos(delta).

With N = sqrt(sin^2 theta1 + cos^2 b cos^2 theta1) >= cos(b) its unwrapped solution is

    theta2 = H(theta1) - asin(cos(delta) / N),   H = the delta = 90 deg law above,

continuous over revolutions when cos(b) > |cos(delta)| (else the cross locks). Hence

    phi_out     = H(theta1) - asin(cos(delta)/N) + asin(cos(delta)) - psi + gamma
    ratio       = ratio_H(theta1) + k q u / (N^2 E),     k = cos delta, q = sin^2 b,
    ratio_slope = slope_H(theta1) + k q (u' N^2 E - u F') / (N^2 E)^2,
                  u = sin theta1 cos theta1, u' = cos 2 theta1, E = sqrt(N^2 - k^2),
                  F' = 2 q u (3 N^2 - 2 k^2) / (2 E),

so phi_out = phi_in at beta = 0. Two joints on one shaft: the shaft's front (driven) arm
sits at psi1 + delta1 in its body frame, so the second joint's driving yoke is in phase
with it for psi2 = psi1 + delta1 (psi2 = psi1 + 90 deg for a square cross), 90 deg out of
phase for psi2 = psi1; a coplanar Z layout has gamma2 = 180 deg, W gamma2 = 0.
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


def check_cross(name: str, value: float, beta: float) -> float:
    """Validate a cross angle delta (rad): the cross turns only while cos(beta) > |cos(delta)|,
    i.e. beta < delta < pi - beta (Bugaru & Vasile 2021 eq. 10 has no solution otherwise)."""
    v = check_finite(name, value)
    if not beta < v < math.pi - beta:
        raise GeometryError(name, f'must be > beta and < 180 deg - beta ({math.degrees(beta):.6g} '
                                  f'and {180.0 - math.degrees(beta):.6g} deg: the cross locks '
                                  f'otherwise), got {math.degrees(v):.6g} deg ({v:.6g} rad)')
    return v


def hooke_deviation(phi: FloatArray, cos_beta: float) -> FloatArray:
    """phi_out - phi_in (rad) of a Hooke joint, bounded by pi/2; vectorised (Bugaru & Vasile 2021, eq. 10)."""
    s, co = np.sin(phi), np.cos(phi)
    return np.arctan2(s * co * (1.0 - cos_beta), cos_beta * co * co + s * s)


def hooke_stage(phi: FloatArray, cos_beta: float) -> tuple[FloatArray, FloatArray, FloatArray]:
    """(phi_out, ratio, ratio_slope) of tan(phi_out) = tan(phi)/cos_beta, vectorised.

    Units: rad, -, 1/rad. Source: Bugaru & Vasile 2021, eq. 10; derivatives differentiated by hand.
    """
    if cos_beta == 1.0:     # straight (or a homokinetic Rzeppa, K = 1): the identity, exactly
        out = np.array(phi, dtype=float)
        return out, np.ones_like(out), np.zeros_like(out)
    s, co = np.sin(phi), np.cos(phi)
    den = cos_beta * cos_beta * co * co + s * s
    dev = np.arctan2(s * co * (1.0 - cos_beta), cos_beta * co * co + s * s)
    ratio = cos_beta / den
    slope = -cos_beta * (1.0 - cos_beta * cos_beta) * 2.0 * s * co / (den * den)
    return phi + dev, ratio, slope


def hooke_stage_scalar(phi: float, cos_beta: float) -> tuple[float, float, float]:
    """Float version of :func:`hooke_stage` (rad, -, 1/rad). cos_beta = 1 (straight, or a
    homokinetic Rzeppa, K = 1) is the identity, returned as such: the general expressions
    give it only to rounding (ratio 1/(cos^2 + sin^2)) at the price of sin, cos and atan2."""
    if cos_beta == 1.0:
        return phi, 1.0, 0.0
    s, co = math.sin(phi), math.cos(phi)
    den = cos_beta * cos_beta * co * co + s * s
    dev = math.atan2(s * co * (1.0 - cos_beta), cos_beta * co * co + s * s)
    return (phi + dev, cos_beta / den,
            -cos_beta * (1.0 - cos_beta * cos_beta) * 2.0 * s * co / (den * den))


def hooke_phased_scalar(phi: float, cos_beta: float, off: float, cos_cross: float,
                        cross_shift: float) -> tuple[float, float, float]:
    """(phi_out rad, ratio -, ratio_slope 1/rad) of a Hooke joint with yoke offset
    ``off`` = psi - gamma (rad), cos of the cross angle ``cos_cross`` and ``cross_shift`` =
    asin(cos_cross) (module docstring; Bugaru & Vasile 2021 eq. 10). With off = 0 and a
    square cross it is :func:`hooke_stage_scalar` itself (same bits). Plain float function,
    also compiled by cvj_ros/physics/kernel/joints_nb.py."""
    if cos_cross == 0.0:
        if off == 0.0:
            return hooke_stage_scalar(phi, cos_beta)
        v, r, s = hooke_stage_scalar(phi + off, cos_beta)
        return v - off, r, s
    th = phi + off
    v, r, s = hooke_stage_scalar(th, cos_beta)
    sn, co = math.sin(th), math.cos(th)
    q = 1.0 - cos_beta * cos_beta
    n2 = cos_beta * cos_beta * co * co + sn * sn
    e = math.sqrt(n2 - cos_cross * cos_cross)
    u = sn * co
    f = n2 * e
    df = 2.0 * q * u * (3.0 * n2 - 2.0 * cos_cross * cos_cross) / (2.0 * e)
    g = cos_cross * q * u / f
    dg = cos_cross * q * ((co * co - sn * sn) * f - u * df) / (f * f)
    return (v - math.asin(cos_cross / math.sqrt(n2)) + cross_shift - off, r + g, s + dg)


def hooke_phased(phi: FloatArray, cos_beta: float, off: float, cos_cross: float,
                 cross_shift: float) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Vectorised :func:`hooke_phased_scalar` (rad, -, 1/rad)."""
    if cos_cross == 0.0:
        if off == 0.0:
            return hooke_stage(phi, cos_beta)
        v, r, s = hooke_stage(phi + off, cos_beta)
        return v - off, r, s
    th = phi + off
    v, r, s = hooke_stage(th, cos_beta)
    sn, co = np.sin(th), np.cos(th)
    q = 1.0 - cos_beta * cos_beta
    n2 = cos_beta * cos_beta * co * co + sn * sn
    e = np.sqrt(n2 - cos_cross * cos_cross)
    u = sn * co
    f = n2 * e
    df = 2.0 * q * u * (3.0 * n2 - 2.0 * cos_cross * cos_cross) / (2.0 * e)
    g = cos_cross * q * u / f
    dg = cos_cross * q * ((co * co - sn * sn) * f - u * df) / (f * f)
    return v - np.arcsin(cos_cross / np.sqrt(n2)) + cross_shift - off, r + g, s + dg


class Hooke:
    """Single Hooke joint with bend angle ``beta`` (rad), 0 <= beta < pi/2, yoke ``phase``
    psi (rad), ``bend_plane`` gamma (rad) and ``cross_angle`` delta (rad, default pi/2);
    conventions in the module docstring.

    Fidelities: ``exact`` (the cross law above) and ``ideal`` (phi_out = phi_in).
    """

    kind = 'hooke'
    mid_name: str | None = None

    def __init__(self, beta: float, *, phase: float = 0.0, bend_plane: float = 0.0,
                 cross_angle: float = 0.5 * math.pi, fidelity: str = 'exact') -> None:
        self.beta = check_bend('beta', beta)
        self.phase = check_finite('phase', phase)
        self.bend_plane = check_finite('bend_plane', bend_plane)
        self.cross_angle = check_cross('cross_angle', cross_angle, self.beta)
        self.fidelity = check_fidelity(fidelity, HOOKE_FIDELITIES, self.kind)
        self._c = math.cos(self.beta)
        self._s2 = math.sin(self.beta) ** 2
        # driving-yoke angle from the bend plane minus phi_in (rad)
        self._off = self.phase - self.bend_plane
        # cos(delta) and asin(cos delta) = pi/2 - delta; exactly 0 for the square cross
        self._k = 0.0 if self.cross_angle == 0.5 * math.pi else math.cos(self.cross_angle)
        self._shift = math.asin(self._k)

    def params(self) -> dict[str, float]:
        """``beta``, and ``phase``, ``bend_plane``, ``cross_angle`` where not the defaults."""
        out = {'beta': self.beta}
        if self.phase != 0.0:
            out['phase'] = self.phase
        if self.bend_plane != 0.0:
            out['bend_plane'] = self.bend_plane
        if self._k != 0.0:
            out['cross_angle'] = self.cross_angle
        return out

    def kernel_params(self) -> tuple[float, float, float, float]:
        """(cos beta, psi - gamma, cos delta, asin(cos delta)): the arguments of
        :func:`hooke_phased_scalar` after phi."""
        return self._c, self._off, self._k, self._shift

    def evaluate(self, phi_in: ArrayLike) -> JointEval:
        phi = as_angle_array(phi_in)
        if self.fidelity == 'ideal':
            return JointEval(phi.copy(), np.ones_like(phi), np.zeros_like(phi))
        out, ratio, slope = hooke_phased(phi, self._c, self._off, self._k, self._shift)
        return JointEval(out, ratio, slope)

    def scalar(self, phi_in: float) -> tuple[float, float, float]:
        if self.fidelity == 'ideal':
            return phi_in, 1.0, 0.0
        return hooke_phased_scalar(phi_in, self._c, self._off, self._k, self._shift)

    def nonuniformity(self) -> float:
        """Amplitude of phi_out - phi_in (rad): atan((1 - cos b) / (2 sqrt(cos b))) for the
        square cross (any phase: a phase shifts the curve); otherwise half its peak-to-peak
        over a period pi, from 4001 samples with a parabolic refinement at each extremum."""
        if self.fidelity == 'ideal':
            return 0.0
        c = self._c
        if self._k == 0.0:
            return math.atan((1.0 - c) / (2.0 * math.sqrt(c)))
        from cvj_ros.physics.joints.double_cardan import _refined_max
        phi = np.linspace(0.0, math.pi, 4001)
        dev = self.evaluate(phi).phi_out - phi
        return float(0.5 * (_refined_max(phi, dev) + _refined_max(phi, -dev)))

    def pins(self, phi_in: float) -> tuple[float, float]:
        """(theta1, theta2) (rad): the driving and driven arms' angles in the bend-plane
        frame (module docstring), theta1 from the bend plane, theta2 from its normal."""
        th = phi_in + self._off
        if self.fidelity == 'ideal':
            return th, th
        return th, self.scalar(phi_in)[0] + self._off - self._shift

    def reactions(self, phi_in: float, omega_in: float, torque_in: float) -> dict[str, float]:
        """Quasi-static reaction wrench of a massless, frictionless cross (N m).

        Derivation (virtual work, no source gives it). The yoke bearings carry no moment
        about their own pin, so the moment M that the input yoke passes through the
        cross to the output yoke is normal to both pins: M = m n, n = p1 x p2 / |p1 x p2|.
        Its component along the input axis is the input torque, M . a1 = T1, which fixes
        m. For the square cross, with theta1 the driving arm's angle from the bend plane,
        N = sqrt(cos^2 b cos^2 theta1 + sin^2 theta1), cos theta2 = cos b cos theta1 / N,
        sin theta2 = sin theta1 / N, this gives, in the bend-plane frame (x normal to the
        bend plane, y along the input axis, z in the bend plane)::

            M = T1 (-tan b sin th1 cos th1,  1,  tan b sin^2 th1)
            T2 = M . a2 = T1 N^2 / cos b = T1 / ratio         (power balance)
            C1 = M - T1 a1 = T1 tan b sin th1 (-cos th1, 0, sin th1),   |C1| = T1 tan b |sin th1|
            C2 = M - T2 a2 = T1 cos th1 (-tan b sin th1, sin^2 b cos th1, -sin b cos b cos th1),
                 |C2| = T2 tan b |cos theta2|

        (theta1 = phi_in with the default phase and bend plane). Another cross angle uses
        the same vector construction numerically. C1, C2 are the secondary couples: the
        bending moments the cross puts on the input and output yokes, reacted by each
        shaft's support bearings. The cross inertia is neglected, so ``omega_in``
        (rad/s) does not enter.

        Args:
            phi_in: input angle (rad). omega_in: input speed (rad/s, unused).
            torque_in: torque delivered by the input shaft into the joint (N m).
        Returns:
            ``torque_out`` (N m, about a2, power balance), ``moment_x/y/z`` (M),
            ``secondary_in_x/z`` and ``secondary_in`` (C1 components and magnitude),
            ``secondary_out_x/y/z`` and ``secondary_out`` (C2), all N m, bend-plane frame.
        """
        check_finite('omega_in', omega_in)
        t1 = check_finite('torque_in', torque_in)
        phi = check_finite('phi_in', phi_in)
        if self.fidelity == 'ideal':
            zero = {k: 0.0 for k in ('moment_x', 'moment_z', 'secondary_in_x', 'secondary_in_z',
                                     'secondary_in', 'secondary_out_x', 'secondary_out_y',
                                     'secondary_out_z', 'secondary_out')}
            return {'torque_out': t1, 'moment_y': t1, **zero}
        if self._k != 0.0:
            return self._reactions_vector(phi, t1)
        if self._off != 0.0:
            phi = phi + self._off
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

    def _reactions_vector(self, phi: float, t1: float) -> dict[str, float]:
        """:meth:`reactions` of a cross at delta != 90 deg, from the pin vectors."""
        th1, th2 = self.pins(phi)
        cb, sb = self._c, math.sin(self.beta)
        p1 = (math.sin(th1), 0.0, math.cos(th1))
        p2 = (math.cos(th2), sb * math.sin(th2), -cb * math.sin(th2))
        n = (p1[1] * p2[2] - p1[2] * p2[1], p1[2] * p2[0] - p1[0] * p2[2],
             p1[0] * p2[1] - p1[1] * p2[0])
        m = t1 / n[1]                       # M . a1 = T1, a1 = e_y
        mx, my, mz = m * n[0], t1, m * n[2]
        t2 = my * cb + mz * sb              # M . a2, a2 = (0, cos b, sin b)
        cout = (mx, my - t2 * cb, mz - t2 * sb)
        return {'torque_out': t2, 'moment_x': mx, 'moment_y': my, 'moment_z': mz,
                'secondary_in_x': mx, 'secondary_in_z': mz,
                'secondary_in': math.hypot(mx, mz),
                'secondary_out_x': cout[0], 'secondary_out_y': cout[1], 'secondary_out_z': cout[2],
                'secondary_out': math.sqrt(cout[0] ** 2 + cout[1] ** 2 + cout[2] ** 2)}


def hooke_ratio(phi_in: ArrayLike, beta: float) -> np.ndarray:
    """Closed-form velocity ratio cos b / (1 - sin^2 b cos^2 phi) (-)."""
    phi = np.asarray(phi_in, dtype=float)
    return math.cos(beta) / (1.0 - math.sin(beta) ** 2 * np.cos(phi) ** 2)


def _factory(*, fidelity: str = 'exact', beta: float = 0.0, phase: float = 0.0,
             bend_plane: float = 0.0, cross_angle: float = 0.5 * math.pi,
             **extra: float) -> Hooke:
    if extra:
        raise GeometryError(sorted(extra)[0], 'unknown parameter for hooke '
                                              '(known: beta, phase, bend_plane, cross_angle)')
    return Hooke(beta, phase=phase, bend_plane=bend_plane, cross_angle=cross_angle,
                 fidelity=fidelity)


register(JointSpec(kind='hooke', factory=_factory, fidelities=HOOKE_FIDELITIES,
                   params={'beta': 'rad, bend angle, 0 <= beta < pi/2, default 0',
                           'phase': 'rad, driving yoke angle from the reference plane (the bend '
                                    'plane when bend_plane = 0) at phi_in = 0, default 0',
                           'bend_plane': 'rad, bend plane angle from the reference plane, '
                                         'default 0',
                           'cross_angle': 'rad, angle between the cross arms, '
                                          'beta < delta < pi - beta, default pi/2'},
                   source='Bugaru & Vasile 2021, eqs. 9-10 (cross relation, any cross angle); phase, bend '
                          'plane and reactions derived in hooke.py'))
