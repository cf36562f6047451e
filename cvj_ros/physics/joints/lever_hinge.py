"""Lever-hinge (articulated-lever) coupling with elastic elements (Davidbaev et al. 2023, chapter 3).

Link geometry (Davidbaev et al. 2023, sections 2.1 and 3.1, figs. 2.1, 3.1, 3.5)
------------------------------------------------------------------
Each shaft carries a fork; an earring (shackle) is pivoted in the fork on the fork's
pin axis p; the earring's second hinge axis q (normal to p) carries the connecting
rods (levers). The rods of both halves join the two earrings, so the earrings' rod
hinge axes stay parallel to each other and normal to the line O1-O2 through the fork
centres: the earrings and rods form the intermediate member, turning about O1-O2
(angle c, the earring angle, ``phi_mid``). Each half is kinematically a Hooke joint
with bend angle alpha between its shaft and O1-O2. Its two rocking angles
(:func:`rocking_angles`): the earring turns in the fork about the fork pin by
atan(tan(alpha) sin(phi)), and the rods turn on the earring about its rod hinge by
asin(sin(alpha) cos(phi)) - the angle xi of Davidbaev et al. 2023 eq. 3.2, which with
phi = 0 at the fork pin in the bend plane is this earring-rod angle, not the
fork-earring one.

Frame (m, rad): x along O1-O2, bend plane x-y. Input shaft axis a1 = (cos a, sin a, 0),
fork pin p1 = cos(phi_in) b1 + sin(phi_in) z with b1 = (-sin a, cos a, 0) (phi_in = 0:
pin in the bend plane). Earring rod-hinge axis q(c) = (0, -sin c, cos c). The output
half is built the same way with its own angle a2 and angle phi_out. Closure p . q = 0:

    tan(c) = tan(phi_in) / cos(alpha)                    (input half, Bugaru & Vasile 2021, eq. 10)
    tan(phi_out) = cos(alpha2) tan(c + twist)            (output half)

* Rigid (Davidbaev et al. 2023, ch. 3 opening): alpha2 = alpha, twist = 0 gives phi_out = phi_in
  exactly: the coupling is synchronous.
* Elastic support of the driven shaft (bushing deflection D2' at shaft length l2)
  tilts the driven shaft: alpha2 = alpha + delta_alpha, delta_alpha = asin(D2'/l2)
  (Davidbaev et al. 2023, eq. 3.13).
* Elastic bushing in the hinge earring-rod of the driven half (deflection D2 at
  earring length l_c2) turns the driven earring against the rods by
  twist = asin(D2/l_c2) (Davidbaev et al. 2023, eq. 3.13). This deformation grows with the
  transmitted torque (twist ~ T/c_y): it *is* the series torsional spring c_y, b_y
  of the machine unit (Davidbaev et al. 2023, eqs. 3.17-3.22). A driveline that models that spring
  as its own element must leave ``twist = 0`` here (else it counts twice); a purely
  kinematic use may pass the static twist for a torque via :func:`twist_for_torque`.

Small-deformation transfer function (derived here; Davidbaev et al. 2023, eqs. 3.14/3.16 are garbled,
README "Errors in the source documents"). Write phi_out = G(c + twist, alpha + delta_alpha) with
G(c, a) = atan(cos a tan c) and c = H(phi_in) its inverse at a = alpha. To first order:

    dG/dc  = 1 / H'(phi_in) = (1 - sin^2(alpha) cos^2(phi_in)) / cos(alpha)
    dG/da  = -sin(a) tan(c) / (1 + cos^2(a) tan^2(c)) = -tan(alpha) sin(phi_in) cos(phi_in)

    phi_out ~ phi_in + twist (1 - sin^2(alpha) cos^2(phi_in)) / cos(alpha)
                     - (delta_alpha / 2) tan(alpha) sin(2 phi_in)          [+ O(d^2)]

so the earring twist shifts the output by twist/cos(alpha) on average with a second
harmonic of relative size sin^2(alpha)/2, and the support tilt adds a second harmonic
of amplitude (delta_alpha/2) tan(alpha). Ratio and slope are its derivatives:
ratio = 1 + twist sin^2(a) sin(2 phi)/cos(a) - delta_alpha tan(a) cos(2 phi),
slope = 2 twist sin^2(a) cos(2 phi)/cos(a) + 2 delta_alpha tan(a) sin(2 phi).
The neglected terms are O(twist^2, twist delta_alpha, delta_alpha^2);
test_lever_hinge.py checks this against an independent vector closure.

Fidelities: ``ideal`` (synchronous), ``closed`` (the formula above), ``exact`` (the two
Hooke relations composed without approximation, branch-free; verified against a
numerical solution of the vector closure p2 . q2 = 0).
"""
from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cvj_ros.errors import GeometryError
from cvj_ros.physics.joints.base import (JointEval, JointSpec, as_angle_array, check_finite,
                                         check_range, register)

FloatArray = NDArray[np.float64]

# KAVZ-685 machine unit (Davidbaev et al. 2023, section 3.3, parameter list)
KAVZ685_ALPHA = math.radians(15.0)      # rad, shaft divergence angle of the reference scene
KAVZ685_C_Y = 715.4                     # N m/rad, torsional stiffness of the elastic elements
KAVZ685_B_Y = 6.35                      # N m s/rad, their damping
KAVZ685_I1 = 0.128                      # kg m^2, driving shaft
KAVZ685_I2 = 0.161                      # kg m^2, driven shaft
RECOMMENDED_ALPHA = (math.radians(10.0), math.radians(25.0))   # Davidbaev et al. 2023, section 3.3 conclusion
_FIDELITIES = ('ideal', 'closed', 'exact')


def deformation_angles(*, support_deflection: float = 0.0, shaft_length: float = 1.0,
                       hinge_deflection: float = 0.0, earring_length: float = 1.0) -> tuple[float, float]:
    """(delta_alpha, twist) in rad from bushing deflections (m) and lengths (m):
    delta_alpha = asin(D2'/l2), twist = asin(D2/l_c2) (Davidbaev et al. 2023, eq. 3.13)."""
    l2 = check_range('shaft_length', shaft_length, lo=0.0, lo_open=True, hi=None, unit=' m')
    lc = check_range('earring_length', earring_length, lo=0.0, lo_open=True, hi=None, unit=' m')
    d_s = check_range('support_deflection', support_deflection, lo=-l2, hi=l2, hi_open=True, unit=' m')
    d_h = check_range('hinge_deflection', hinge_deflection, lo=-lc, hi=lc, hi_open=True, unit=' m')
    return math.asin(d_s / l2), math.asin(d_h / lc)


def twist_for_torque(torque: float, *, stiffness: float = KAVZ685_C_Y) -> float:
    """Static earring twist (rad) under a transmitted torque (N m) for a bushing torsional
    stiffness (N m/rad): torque / stiffness (linear bushing, Davidbaev et al. 2023, eq. 3.19 spring)."""
    t = check_finite('torque', torque)
    c = check_range('stiffness', stiffness, lo=0.0, lo_open=True, hi=None, unit=' N m/rad')
    return t / c


def rocking_angles(phi_in: ArrayLike, alpha: float) -> tuple[FloatArray, FloatArray]:
    """(fork-earring, earring-rod) rocking angles (rad) of one half at fork angle ``phi_in``
    (rad, 0 = fork pin in the bend plane) and bend angle ``alpha`` (rad).

    With the module frame's fork pin p1, earring rod-hinge axis q (p1 . q = 0) and shaft
    axis a1: the earring turns about p1 out of the plane normal to a1 by
    asin(-q . a1) = atan(tan(alpha) sin(phi)); the rods (along O1-O2 = x) see p1 turned out
    of the plane normal to x by asin(-p1 . x) = asin(sin(alpha) cos(phi)).
    """
    phi = as_angle_array(phi_in)
    return (np.arctan(math.tan(alpha) * np.sin(phi)),
            np.arcsin(math.sin(alpha) * np.cos(phi)))


def _hooke_dev(phi: FloatArray, cos_a: float) -> FloatArray:
    """Branch-free H(phi) - phi for tan(H) = tan(phi)/cos a (rad)."""
    s, c = np.sin(phi), np.cos(phi)
    return np.arctan2(s * c * (1.0 - cos_a), cos_a * c * c + s * s)


def _inverse_dev(c_ang: FloatArray, cos_a: float) -> FloatArray:
    """Branch-free G(c) - c for tan(G) = cos a tan(c) (rad)."""
    s, c = np.sin(c_ang), np.cos(c_ang)
    return np.arctan2((cos_a - 1.0) * s * c, c * c + cos_a * s * s)


def lever_hinge_closed_scalar(phi_in: float, ca: float, sa2: float, ta: float, tw: float,
                              da: float) -> tuple[float, float, float]:
    """'closed' fidelity (phi_out rad, ratio -, ratio_slope 1/rad): first order in twist and
    delta_alpha, see the module docstring. ca = cos alpha, sa2 = sin^2 alpha, ta = tan alpha,
    tw = twist (rad), da = delta_alpha (rad). Plain float function, also compiled by
    cvj_ros/physics/kernel/joints_nb.py (one source for both)."""
    s2, c2, c1 = math.sin(2.0 * phi_in), math.cos(2.0 * phi_in), math.cos(phi_in)
    return (phi_in + tw * (1.0 - sa2 * c1 * c1) / ca - 0.5 * da * ta * s2,
            1.0 + tw * sa2 * s2 / ca - da * ta * c2,
            2.0 * tw * sa2 * c2 / ca + 2.0 * da * ta * s2)


def lever_hinge_exact_scalar(phi_in: float, ca: float, sa2: float, twist: float, ca2: float,
                             sa22: float) -> tuple[float, float, float]:
    """'exact' fidelity (phi_out rad, ratio -, ratio_slope 1/rad): two cross stages in series
    (module docstring). ca, sa2: cos alpha, sin^2 alpha; ca2, sa22: the same of
    alpha + delta_alpha; twist (rad). Also compiled by kernel/joints_nb.py."""
    s, c = math.sin(phi_in), math.cos(phi_in)
    den1 = 1.0 - sa2 * c * c
    h1 = ca / den1
    h2 = -ca * sa2 * 2.0 * s * c / (den1 * den1)
    c2 = phi_in + math.atan2(s * c * (1.0 - ca), ca * c * c + s * s) + twist
    s_, c_ = math.sin(c2), math.cos(c2)
    den2 = 1.0 - sa22 * s_ * s_
    g1 = ca2 / den2
    g2 = ca2 * sa22 * 2.0 * s_ * c_ / (den2 * den2)
    out = c2 + math.atan2((ca2 - 1.0) * s_ * c_, c_ * c_ + ca2 * s_ * s_)
    return out, g1 * h1, g2 * h1 * h1 + g1 * h2


class LeverHinge:
    """Lever-hinge coupling, shaft divergence ``alpha`` (rad), driven-shaft support tilt
    ``delta_alpha`` (rad) and driven earring twist ``twist`` (rad); see the module docstring."""

    kind = 'lever_hinge'
    mid_name = 'earring'

    def __init__(self, alpha: float = KAVZ685_ALPHA, *, fidelity: str = 'exact',
                 delta_alpha: float = 0.0, twist: float = 0.0) -> None:
        if fidelity not in _FIDELITIES:
            raise GeometryError('fidelity', f'lever_hinge has fidelities {", ".join(_FIDELITIES)}; '
                                            f'got {fidelity!r}')
        self.fidelity = fidelity
        self.alpha = check_range('alpha', alpha, lo=0.0, hi=math.pi / 2, hi_open=True, unit=' rad')
        self.delta_alpha = check_finite('delta_alpha', delta_alpha)
        if not 0.0 <= self.alpha + self.delta_alpha < math.pi / 2:
            # the sum is out of range: name it with both terms (in degrees, as scenes give them)
            a, d = math.degrees(self.alpha), math.degrees(self.delta_alpha)
            raise GeometryError('alpha' if abs(a) >= abs(d) else 'delta_alpha',
                                f'the sum alpha + delta_alpha must be in [0, 90) deg, got '
                                f'{a:.6g} + {d:.6g} = {a + d:.6g} deg')
        self.twist = check_range('twist', twist, lo=-math.pi / 2, lo_open=True, hi=math.pi / 2,
                                 unit=' rad')
        self._ca = math.cos(self.alpha)
        self._sa2 = math.sin(self.alpha) ** 2
        self._ta = math.tan(self.alpha)
        self._ca2 = math.cos(self.alpha + self.delta_alpha)
        self._sa22 = math.sin(self.alpha + self.delta_alpha) ** 2

    def params(self) -> dict[str, float]:
        return {'alpha': self.alpha, 'delta_alpha': self.delta_alpha, 'twist': self.twist}

    def nonuniformity(self) -> float:
        """Max |phi_out - phi_in| (rad) over a revolution (period pi)."""
        phi = np.linspace(0.0, math.pi, 2001)
        return float(np.max(np.abs(self.evaluate(phi).phi_out - phi)))

    def evaluate(self, phi_in: ArrayLike) -> JointEval:
        """phi_out (rad), ratio (-), ratio_slope (1/rad), phi_mid = driving earring angle c (rad)."""
        phi = as_angle_array(phi_in)
        c = phi + _hooke_dev(phi, self._ca)
        if self.fidelity == 'ideal':
            return JointEval(phi.copy(), np.ones_like(phi), np.zeros_like(phi), c)
        if self.fidelity == 'closed':
            out, ratio, slope = self._closed(phi)
            return JointEval(out, ratio, slope, c)
        ca, sa2 = self._ca, self._sa2
        den1 = 1.0 - sa2 * np.cos(phi) ** 2
        h1 = ca / den1                                        # dc/dphi_in
        h2 = -ca * sa2 * np.sin(2.0 * phi) / den1 ** 2        # d2c/dphi_in2
        c2 = c + self.twist
        ca2, sa22 = self._ca2, self._sa22
        den2 = 1.0 - sa22 * np.sin(c2) ** 2
        g1 = ca2 / den2                                       # dphi_out/dc2
        g2 = ca2 * sa22 * np.sin(2.0 * c2) / den2 ** 2        # d2phi_out/dc2^2
        out = c2 + _inverse_dev(c2, ca2)
        return JointEval(out, g1 * h1, g2 * h1 * h1 + g1 * h2, c)

    def mid_angle(self, phi_in: ArrayLike) -> FloatArray:
        """phi_mid (rad) alone: the same numbers as ``evaluate(phi_in).phi_mid`` (the same
        expression on the same array), without phi_out, ratio and slope; used by
        :meth:`cvj_ros.physics.driveline.Driveline.fill_mid` on every sample of a run."""
        phi = as_angle_array(phi_in)
        return phi + _hooke_dev(phi, self._ca)

    def _closed(self, phi: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        ca, sa2, ta, tw, da = self._ca, self._sa2, self._ta, self.twist, self.delta_alpha
        s2, c2 = np.sin(2.0 * phi), np.cos(2.0 * phi)
        out = phi + tw * (1.0 - sa2 * np.cos(phi) ** 2) / ca - 0.5 * da * ta * s2
        ratio = 1.0 + tw * sa2 * s2 / ca - da * ta * c2
        slope = 2.0 * tw * sa2 * c2 / ca + 2.0 * da * ta * s2
        return out, ratio, slope

    def scalar(self, phi_in: float) -> tuple[float, float, float]:
        """(phi_out, ratio, ratio_slope) for one float ``phi_in`` (rad)."""
        if self.fidelity == 'ideal':
            return phi_in, 1.0, 0.0
        if self.fidelity == 'closed':
            return lever_hinge_closed_scalar(phi_in, self._ca, self._sa2, self._ta, self.twist,
                                             self.delta_alpha)
        return lever_hinge_exact_scalar(phi_in, self._ca, self._sa2, self.twist, self._ca2,
                                        self._sa22)

    def reactions(self, phi_in: float, omega_in: float, torque_in: float) -> dict[str, float]:
        """Output torque (N m) from the power balance of the rigid linkage (no losses):
        torque_out = torque_in / ratio. omega_in (rad/s) is not needed (massless links)."""
        check_finite('omega_in', omega_in)
        t = check_finite('torque_in', torque_in)
        return {'torque_out': t / self.scalar(check_finite('phi_in', phi_in))[1]}


def _factory(*, fidelity: str = 'exact', alpha: float = KAVZ685_ALPHA, delta_alpha: float = 0.0,
             twist: float = 0.0, **_ignored: float) -> LeverHinge:
    return LeverHinge(alpha, fidelity=fidelity, delta_alpha=delta_alpha, twist=twist)


register(JointSpec(
    kind='lever_hinge', factory=_factory, fidelities=_FIDELITIES,
    params={'alpha': 'rad, shaft divergence angle, 0 <= alpha < pi/2 (recommended 10-25 deg), '
                     'default 15 deg (KAVZ-685, Davidbaev et al. 2023, section 3.3)',
            'delta_alpha': 'rad, driven-shaft tilt from the support bushing, asin(D2\'/l2) '
                           '(Davidbaev et al. 2023, eq. 3.13), default 0',
            'twist': 'rad, driven earring twist from the hinge bushing, asin(D2/l_c2) (Davidbaev et al. 2023 '
                     'eq. 3.13) = T/c_y; leave 0 when the series spring c_y is modelled, default 0'},
    source='Davidbaev et al. 2023, ch. 3 (eqs. 3.2, 3.13; geometry figs. 2.1, 3.1, 3.5); transfer function '
           'derived in lever_hinge.py (eqs. 3.14/3.16 garbled, see README "Errors in the source documents")'))
