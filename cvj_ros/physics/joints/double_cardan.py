"""Double cardan shaft: two Hooke joints joined by an intermediate shaft.

Geometry (housing frame of :mod:`hooke`: y along the input axis, bend plane 1 = y-z).
Joint 1 bends the intermediate shaft by ``beta1`` about x. Joint 2 bends the output
shaft by ``beta2`` relative to the intermediate shaft, in a plane turned by
``bend_plane`` (gamma) about the intermediate axis from bend plane 1 (0 = coplanar).
Layout, for coplanar bends:

* ``Z``: the second bend is opposite to the first: with beta1 = beta2 the output
  shaft is parallel to the input shaft, offset sideways (the usual propeller shaft).
  Angle between input and output axes |beta1 - beta2|.
* ``W``: both bends have the same sense: input and output axes intersect on the far
  side of the intermediate shaft ("W"/"M" arrangement), angle beta1 + beta2.

The intermediate yokes carry a phase ``phase`` (psi, rad): 0 = in phase, both fork
planes of the intermediate shaft coincide (the correct assembly).

Kinematics. Each joint obeys the Hooke law tan(theta_out) = tan(theta)/cos(beta)
(Bugaru & Vasile 2021, eq. 10) with theta the driving-yoke angle from *its own* bend plane.
Joint 1: phi_mid = H(phi_in; beta1), phi_mid = intermediate shaft angle (rad). At
joint 2 the driving yoke (on the intermediate shaft) is normal to bend plane 1 at
phi_mid = 0, so its angle from bend plane 2 is u = phi_mid + psi - gamma + pi/2;
the output angle is phi_out = H(u; beta2) - pi/2 - psi + gamma, zero positions
chosen so that phi_out = phi_in when both angles vanish. With psi = gamma = 0 this
is tan(phi_out) = cos(beta2) tan(phi_mid) = cos(beta2)/cos(beta1) tan(phi_in):
homokinetic exactly when beta1 = beta2, a Hooke-like nonuniformity otherwise.

How the layout enters: Z is a bend by -beta2 in bend plane gamma, i.e. +beta2 in
plane gamma + pi. Shifting gamma by pi shifts u and H(u) by pi and leaves phi_out
unchanged (H(u + pi) = H(u) + pi), so Z and W have the same position function; the
layout only sets the output axis direction (:meth:`DoubleCardan.output_axis_angle`).
The tests check this against a rotation-matrix construction of both layouts.

Ratio and slope by the chain rule: ratio = r2(u) r1(phi_in),
slope = s2(u) r1^2 + r2(u) s1 (1/rad), r_k, s_k of :func:`hooke.hooke_stage`.
"""
from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from cvj_ros.errors import GeometryError
from cvj_ros.physics.joints.base import JointEval, JointSpec, as_angle_array, check_finite, register
from cvj_ros.physics.joints.hooke import (HOOKE_FIDELITIES, check_bend, check_fidelity, hooke_stage,
                                          hooke_stage_scalar)

LAYOUTS = ('Z', 'W')
_HALF_PI = 0.5 * math.pi


def double_cardan_scalar(phi_in: float, c1: float, c2: float, off: float
                         ) -> tuple[float, float, float]:
    """(phi_out rad, ratio -, ratio_slope 1/rad) of two Hooke stages in series (cos beta1 = c1,
    cos beta2 = c2, yoke phase offset ``off`` rad; see the module docstring). Plain float
    function, also compiled by cvj_ros/physics/kernel/joints_nb.py (one source for both)."""
    mid, r1, s1 = hooke_stage_scalar(phi_in, c1)
    v, r2, s2 = hooke_stage_scalar(mid + off, c2)
    return v - off, r2 * r1, s2 * r1 * r1 + r2 * s1


class DoubleCardan:
    """Two Hooke joints with angles ``beta1``, ``beta2`` (rad, each in [0, pi/2)),
    intermediate-yoke ``phase`` (rad), ``layout`` 'Z' | 'W' and ``bend_plane`` (rad).

    ``phi_mid`` is the intermediate shaft angle (rad); ``mid_name`` = 'yoke'.
    Fidelities: ``exact`` (two Hooke laws), ``ideal`` (phi_out = phi_mid = phi_in).
    """

    kind = 'double_cardan'
    mid_name = 'yoke'

    def __init__(self, beta1: float, beta2: float, *, phase: float = 0.0, layout: str = 'Z',
                 bend_plane: float = 0.0, fidelity: str = 'exact') -> None:
        self.beta1 = check_bend('beta1', beta1)
        self.beta2 = check_bend('beta2', beta2)
        self.phase = check_finite('phase', phase)
        self.bend_plane = check_finite('bend_plane', bend_plane)
        lay = str(layout).upper()
        if lay not in LAYOUTS:
            raise GeometryError('layout', f"must be 'Z' or 'W', got {layout!r}")
        self.layout = lay
        self.fidelity = check_fidelity(fidelity, HOOKE_FIDELITIES, self.kind)
        self._c1, self._c2 = math.cos(self.beta1), math.cos(self.beta2)
        # offset from the intermediate angle to joint 2's driving-yoke angle (rad)
        self._off = self.phase - self.bend_plane + _HALF_PI

    def params(self) -> dict[str, float]:
        return {'beta1': self.beta1, 'beta2': self.beta2, 'phase': self.phase,
                'bend_plane': self.bend_plane, 'layout': self.layout}  # type: ignore[dict-item]

    def output_axis_angle(self) -> float:
        """Angle between input and output shaft axes (rad), from the layout and bend plane."""
        s2 = -1.0 if self.layout == 'Z' else 1.0
        b1, b2, g = self.beta1, s2 * self.beta2, self.bend_plane
        # output axis = R_x(b1) R_y(g) R_x(b2) e_y, dotted with e_y
        cos_out = math.cos(b1) * math.cos(b2) - math.sin(b1) * math.sin(b2) * math.cos(g)
        return math.acos(max(-1.0, min(1.0, cos_out)))

    def evaluate(self, phi_in: ArrayLike) -> JointEval:
        phi = as_angle_array(phi_in)
        if self.fidelity == 'ideal':
            return JointEval(phi.copy(), np.ones_like(phi), np.zeros_like(phi), phi.copy())
        mid, r1, s1 = hooke_stage(phi, self._c1)
        v, r2, s2 = hooke_stage(mid + self._off, self._c2)
        return JointEval(v - self._off, r2 * r1, s2 * r1 * r1 + r2 * s1, mid)

    def scalar(self, phi_in: float) -> tuple[float, float, float]:
        if self.fidelity == 'ideal':
            return phi_in, 1.0, 0.0
        return double_cardan_scalar(phi_in, self._c1, self._c2, self._off)

    def nonuniformity(self) -> float:
        """Amplitude (rad): half the peak-to-peak of phi_out - phi_in over its period pi,
        from 4001 samples with a parabolic refinement at each extremum."""
        if self.fidelity == 'ideal':
            return 0.0
        phi = np.linspace(0.0, math.pi, 4001)
        dev = self.evaluate(phi).phi_out - phi
        return float(0.5 * (_refined_max(phi, dev) + _refined_max(phi, -dev)))

    def reactions(self, phi_in: float, omega_in: float, torque_in: float) -> dict[str, float]:
        """Quasi-static torques and secondary-couple magnitudes (N m), massless crosses.

        ``torque_mid`` = T1/r1 and ``torque_out`` = T1/ratio (power balance, Dziopa
        eq. 20 analogue); secondary couples per yoke from :meth:`hooke.Hooke.reactions`:
        ``secondary_in`` = T1 tan b1 |sin phi_in|, ``secondary_mid1`` = T_mid tan b1 |cos phi_mid|,
        ``secondary_mid2`` = T_mid tan b2 |sin u|, ``secondary_out`` = T_out tan b2 |cos H(u)|.
        ``omega_in`` (rad/s) does not enter.
        """
        check_finite('omega_in', omega_in)
        t1 = check_finite('torque_in', torque_in)
        phi = check_finite('phi_in', phi_in)
        if self.fidelity == 'ideal':
            return {'torque_out': t1, 'torque_mid': t1, 'secondary_in': 0.0, 'secondary_mid1': 0.0,
                    'secondary_mid2': 0.0, 'secondary_out': 0.0}
        mid, r1, _ = hooke_stage_scalar(phi, self._c1)
        u = mid + self._off
        v, r2, _ = hooke_stage_scalar(u, self._c2)
        tm, to = t1 / r1, t1 / (r1 * r2)
        tb1, tb2 = math.tan(self.beta1), math.tan(self.beta2)
        return {'torque_out': to, 'torque_mid': tm,
                'secondary_in': abs(t1 * tb1 * math.sin(phi)),
                'secondary_mid1': abs(tm * tb1 * math.cos(mid)),
                'secondary_mid2': abs(tm * tb2 * math.sin(u)),
                'secondary_out': abs(to * tb2 * math.cos(v))}


def _refined_max(x: np.ndarray, y: np.ndarray) -> float:
    """Maximum of samples y(x) (uniform x) refined by a parabola through the peak and neighbours."""
    k = int(np.argmax(y))
    if k == 0 or k == y.size - 1:
        return float(y[k])
    ym, y0, yp = y[k - 1], y[k], y[k + 1]
    den = ym - 2.0 * y0 + yp
    return float(y0 - 0.125 * (yp - ym) ** 2 / den) if den < 0.0 else float(y0)


def _factory(*, fidelity: str = 'exact', beta1: float = 0.0, beta2: float | None = None,
             phase: float = 0.0, layout: str = 'Z', bend_plane: float = 0.0,
             beta: float | None = None, **extra: float) -> DoubleCardan:
    if extra:
        raise GeometryError(sorted(extra)[0], 'unknown parameter for double_cardan '
                                              '(known: beta1, beta2, phase, layout, bend_plane)')
    if beta is not None:              # CLI --beta alias of beta1
        beta1 = beta
    return DoubleCardan(beta1, beta1 if beta2 is None else beta2, phase=phase, layout=layout,
                        bend_plane=bend_plane, fidelity=fidelity)


register(JointSpec(
    kind='double_cardan', factory=_factory, fidelities=HOOKE_FIDELITIES,
    params={'beta1': 'rad, bend angle of joint 1, [0, pi/2), default 0 (alias beta)',
            'beta2': 'rad, bend angle of joint 2, [0, pi/2), default beta1',
            'phase': 'rad, intermediate-yoke phase, 0 = in phase, default 0',
            'layout': "Z (output parallel to input) or W (axes intersect), default Z",
            'bend_plane': 'rad, angle between the two bend planes, default 0 (coplanar)'},
    source='Bugaru & Vasile 2021, eq. 10 applied twice; layouts and phase in double_cardan.py'))
