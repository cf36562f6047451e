"""Rzeppa / Birfield fixed ball joint (Dziopa).

Geometry and conventions (Dziopa section 2, checked against a rotation-matrix
construction in the tests). Frame 0x1y1z1: y1 along the input shaft [1], z1 in the
input fork (groove) plane at phi1 = 0, bend plane = y1-z1. The output shaft [2] axis
is R_x(delta) e_y = (0, cos d, sin d); shaft k turns right-handed about its own axis
(R_y(phi1); R_x(delta) R_y(phi2)), so both turn in the same sense. Groove planes
pi_1: cos(phi1) x - sin(phi1) z = 0 (eq. 4) and pi_2 (eq. 5) both contain the bend
plane at zero. The cage plane pi has normal R_x(alpha) e_y = (0, cos a, sin a)
(eq. 9); the ball centre A lies on the line pi_1 & pi_2 & pi (eqs. 7-8).

Position function (Dziopa eq. 10, re-derived: r3 = r1 x r2 in pi gives it)::

    tan(phi2) = tan(phi1) / K,   K = tan(a) sin(d) + cos(d) = cos(d - a) / cos(a) > 0

homokinetic for alpha = delta/2 (eq. 12, K = 1). The same law as a Hooke joint with
cos(beta) -> K, so the bounded-deviation form of :mod:`hooke` keeps phi_out
continuous over any number of turns.

Cage / ball angle phi3 = phi_mid (rad): the ball direction R_x(a) R_y(phi3) e_z must
lie in pi_1, so tan(phi3) = cos(a) tan(phi1), which is Dziopa eq. 25 for
a = d/2; transmission f' = cos(a) / (1 - sin^2(a) sin^2 phi1) (eq. 29) and second
position function f'' = cos(a) sin^2(a) sin(2 phi1) / (1 - sin^2(a) sin^2 phi1)^2
(eq. 34). Torque relation: M_s2 = K cos^2(phi1)/cos^2(phi2) M_s1 = M_s1 / ratio
(eq. 20, virtual work).

Fidelities: ``exact`` (above, any cage angle alpha) and ``ideal`` (phi_out = phi_mid
= phi_in).
"""
from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from cvj_ros.errors import GeometryError
from cvj_ros.physics.joints.base import (FloatArray, JointEval, JointSpec, as_angle_array,
                                         check_finite, check_range, register)
from cvj_ros.physics.joints.hooke import check_bend, check_fidelity, hooke_stage, hooke_stage_scalar

RZEPPA_FIDELITIES = ('ideal', 'exact')


class Rzeppa:
    """Fixed ball joint with bend angle ``delta`` (rad, [0, pi/2)), cage-plane angle
    ``alpha`` (rad, default delta/2 = homokinetic) and ball pitch radius ``r`` (m, only
    for :meth:`ball_point`). ``phi_mid`` is the cage/ball angle phi3; ``mid_name`` 'cage'."""

    kind = 'rzeppa'
    mid_name = 'cage'

    def __init__(self, delta: float, *, alpha: float | None = None, r: float = 0.0,
                 fidelity: str = 'exact') -> None:
        self.delta = check_bend('delta', delta)
        a = 0.5 * self.delta if alpha is None else check_finite('alpha', alpha)
        if not abs(a) < 0.5 * math.pi:
            raise GeometryError('alpha', f'must satisfy |alpha| < pi/2 rad, got {a} rad')
        if not abs(self.delta - a) < 0.5 * math.pi:
            raise GeometryError('alpha', f'cage plane must satisfy |delta - alpha| < pi/2 rad, '
                                         f'got alpha = {a} rad, delta = {self.delta} rad')
        self.alpha = a
        self.r = check_range('r', r, lo=0.0, hi=None, unit=' m')
        self.fidelity = check_fidelity(fidelity, RZEPPA_FIDELITIES, self.kind)
        # K = tan(a) sin(d) + cos(d) (eq. 10); exactly 1.0 on the homokinetic plane
        self.k = 1.0 if alpha is None else math.cos(self.delta - a) / math.cos(a)
        self._cage_c = 1.0 / math.cos(a)   # tan(phi3) = tan(phi1) / (1/cos a)

    def params(self) -> dict[str, float]:
        return {'delta': self.delta, 'alpha': self.alpha, 'r': self.r}

    def evaluate(self, phi_in: ArrayLike) -> JointEval:
        phi = as_angle_array(phi_in)
        if self.fidelity == 'ideal':
            return JointEval(phi.copy(), np.ones_like(phi), np.zeros_like(phi), phi.copy())
        out, ratio, slope = hooke_stage(phi, self.k)
        return JointEval(out, ratio, slope, hooke_stage(phi, self._cage_c)[0])

    def scalar(self, phi_in: float) -> tuple[float, float, float]:
        if self.fidelity == 'ideal':
            return phi_in, 1.0, 0.0
        return hooke_stage_scalar(phi_in, self.k)

    def cage(self, phi_in: ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Cage/ball angle phi3 (rad), transmission f' (-) and second position function
        f'' (1/rad) against phi1 (Dziopa eqs. 26, 29, 34 with delta/2 -> alpha)."""
        phi = as_angle_array(phi_in)
        if self.fidelity == 'ideal':
            return phi.copy(), np.ones_like(phi), np.zeros_like(phi)
        return hooke_stage(phi, self._cage_c)

    def ball_point(self, phi_in: ArrayLike, omega_in: ArrayLike, domega_in: ArrayLike = 0.0, *,
                   radius: float | None = None) -> dict[str, FloatArray]:
        """Position, velocity and accelerations of ball centre A (Dziopa eqs. 35-41).

        Frame 0x1y1z1 (fixed, input shaft at zero). The ball turns with the cage about
        the fixed cage axis n = (0, cos a, sin a) at phi3' = f' omega, phi3'' = f'' omega^2
        + f' domega (eq. 30), so with e(phi3) = R_x(a) (sin phi3, 0, cos phi3)::

            r_A = R e,  v_A = phi3' R de/dphi3 (eq. 37),  a_t = phi3'' R de/dphi3 (eq. 39),
            a_n = -phi3'^2 R e (eq. 41)

        For a = d/2 these are the paper's expressions, except that Dziopa eq. 37 prints
        V_Az with a + sign; d(r_Az)/dt = -omega R cos^3(d/2) sin(phi1)/(...)^(3/2) < 0 for
        small phi1 > 0 (checked numerically in the tests).

        Args: phi_in (rad), omega_in (rad/s), domega_in (rad/s^2), radius R (m,
        default the joint's ``r``; must be > 0).
        Returns: dict of arrays with a trailing axis of 3 (x1, y1, z1): ``position`` (m),
        ``velocity`` (m/s), ``accel_tangential``, ``accel_normal``, ``acceleration`` (m/s^2).
        """
        rad = self.r if radius is None else check_finite('radius', radius)
        if not rad > 0.0:
            raise GeometryError('r', f'ball pitch radius must be > 0 m for ball kinematics, got {rad} m')
        phi = as_angle_array(phi_in)
        om = np.asarray(omega_in, dtype=float)
        dom = np.asarray(domega_in, dtype=float)
        phi3, f1, f2 = hooke_stage(phi, self._cage_c)
        w3 = f1 * om
        a3 = f2 * om * om + f1 * dom
        ca, sa = math.cos(self.alpha), math.sin(self.alpha)
        s3, c3 = np.sin(phi3), np.cos(phi3)
        e = np.stack([s3, -sa * c3, ca * c3], axis=-1)
        de = np.stack([c3, sa * s3, -ca * s3], axis=-1)
        pos = rad * e
        vel = rad * w3[..., None] * de
        at = rad * a3[..., None] * de
        an = -rad * (w3 * w3)[..., None] * e
        return {'position': pos, 'velocity': vel, 'accel_tangential': at, 'accel_normal': an,
                'acceleration': at + an}

    def nonuniformity(self) -> float:
        """Amplitude of phi_out - phi_in (rad): atan(|1 - K| / (2 sqrt(K))); 0 at alpha = delta/2."""
        if self.fidelity == 'ideal':
            return 0.0
        return math.atan(abs(1.0 - self.k) / (2.0 * math.sqrt(self.k)))

    def reactions(self, phi_in: float, omega_in: float, torque_in: float) -> dict[str, float]:
        """Output torque (N m) by Dziopa eq. 20, M_s2 = M_s1 / ratio, written through the
        ratio so it stays finite where cos(phi2) = 0. ``omega_in`` (rad/s) does not enter."""
        check_finite('omega_in', omega_in)
        t1 = check_finite('torque_in', torque_in)
        ratio = self.scalar(check_finite('phi_in', phi_in))[1]
        return {'torque_out': t1 / ratio}


def _factory(*, fidelity: str = 'exact', delta: float | None = None, alpha: float | None = None,
             r: float = 0.0, beta: float | None = None, **extra: float) -> Rzeppa:
    if extra:
        raise GeometryError(sorted(extra)[0], 'unknown parameter for rzeppa (known: delta, alpha, r)')
    if delta is None:
        delta = 0.0 if beta is None else beta    # beta accepted as an alias of delta
    return Rzeppa(delta, alpha=alpha, r=r, fidelity=fidelity)


register(JointSpec(
    kind='rzeppa', factory=_factory, fidelities=RZEPPA_FIDELITIES,
    params={'delta': 'rad, bend angle, [0, pi/2), default 0 (alias beta)',
            'alpha': 'rad, cage-plane angle, default delta/2 (homokinetic)',
            'r': 'm, ball pitch radius (ball_point only), default 0'},
    source='Dziopa eqs. 10, 20, 25-41 (eq. 37 V_Az sign corrected)'))
