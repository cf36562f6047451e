"""Tripod (tulip-tripode) plunging joint: ideal, closed-form and exact kinematics, reactions.

Geometry and conventions (all lengths m, angles rad)
----------------------------------------------------
Fixed frame: z along the housing (tulip, input shaft) axis, the joint opening towards
+z; the bend plane is x-z. The output shaft (the shaft that carries the spider,
e.g. a half-shaft) is held at a fixed point P at distance ``l`` from the spider
centre S (the centre of the other joint or of a self-aligning bearing, Xiu et al. 2024
section 2): ``P = l n0``, ``n0 = (sin beta, 0, cos beta)``; beta is the bend angle.

* Housing tracks: three lines parallel to z at radius ``r``, at angles
  ``psi_j = phi_in + 2 pi j/3`` (j = 0, 1, 2) (Xiu et al. 2024, eq. 1).
* Spider: three trunnion axes ``e_j`` through S, perpendicular to the output shaft axis
  ``n = (P - S)/l`` and 120 deg apart, at angles ``phi_out + 2 pi j/3`` in the shaft
  frame (u, v, n). The roller centre R_j = S + h_j e_j slides along its trunnion
  (h_j ~ r varies) and along its track: R_j lies on track j.
* Output-shaft frame (Xiu et al. 2024, eqs. 6-8: O''Y'' always perpendicular to ox):
  ``v = n x u0 / |n x u0|``, ``u = v x n`` with ``u0 = (cos beta, 0, -sin beta)``.
  This is a convention for the angle of a shaft whose axis wobbles (by ~rho/l); its
  own twist makes d phi_out/dt differ from the spin Omega . n by O((rho/l)^2)
  (``spin_ratio`` in :meth:`Tripod.solve`), the same order as the closed form's error.
* Zero: at phi_in = 0 track 0 (groove m1) lies in the bend plane (x > 0); phi_out = 0
  when trunnion 0 lies in the plane spanned by n and u0. By mirror symmetry
  (y -> -y) the deviation phi_out - phi_in is then odd in phi_in: a sine series.

Unknowns (given phi_in): the spider-centre offset (s_u, s_v) in the plane spanned by
(u0, v0 = y) and phi_out. The spider centre is
``S = s_u u0 + s_v v0 + (l - w) n0`` with ``w = sqrt(l^2 - s_u^2 - s_v^2)``, so
|S - P| = l exactly. Roller j on track j means the xy-projection of ``e_j`` is parallel
to the track point minus S:  ``(r cos psi_j - S_x) e_jy - (r sin psi_j - S_y) e_jx = 0``
(three equations; h_j then follows). Assumptions: rigid parts, no clearance, point
roller centres, tracks exactly axial, the fixed point P does not move; the plunge
(axial sliding) S_z and the spider orbit (s_u, s_v) are outputs, not inputs.
This is the tripode geometry behind Bugaru & Vasile 2021, eq. 19 (after Duditza-Diaconescu) and
Xiu et al. 2024, eqs. 1-17 (where the rod-to-ball distance h_i also varies, Xiu et al. 2024, eq. 21).
With a fixed arm length the system would be overdetermined (9 conditions, 6 unknowns).

Fidelities
----------
* ``ideal``: phi_out = phi_in.
* ``closed`` (Bugaru & Vasile 2021, eq. 19; Xiu et al. 2024, eq. 18, corrected: README "Errors in the source documents"):
  ``phi_out = phi_in - A sin(3 phi_in)``, ``A = (r / 2 l) tan(beta) tan^2(beta/2)``;
  ratio ``1 - 3 A cos(3 phi_in)``, slope ``9 A sin(3 phi_in)`` (differentiated here;
  Xiu et al. 2024, eq. 19 is wrong). The sign (lag at small positive phi_in) is that of the
  exact model in this convention (test_tripod.py checks it).
* ``exact``: the three constraint equations solved by Newton (warm-started from
  Fourier tables of the solution, themselves built from a continuation in beta and
  then along the rotation) to |residual| <=
  1e-13 r (about 1e-13 rad; at angles reduced modulo 2 pi/3, so precision holds at
  any number of revolutions);
  ratio and ratio_slope by implicit differentiation of the constraints (second-order
  Taylor arithmetic along the solution, no finite differences). ``scalar()`` uses a
  Fourier sine series in phi_in (period 2 pi/3) of the exact deviation, built at
  construction and converged to <= 1e-12 rad against Newton.

Working angle: Xiu et al. 2024 recommends beta <= 25 deg (:data:`RECOMMENDED_MAX_BETA`).
The exact model needs beta < 90 deg; it is built and verified up to
:data:`PRACTICAL_MAX_BETA` = 70 deg (the orbit radius r (1/cos beta - 1)/2 grows
without bound as beta -> 90 deg, 41 Fourier terms at 70 deg; at 80 deg and r/l = 0.1
the continuation fails).
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cvj_ros.errors import GeometryError, SolverError
from cvj_ros.physics.fixed_order import dot, matvec, solve, solve_batched
from cvj_ros.physics.joints.base import (JointEval, JointSpec, as_angle_array, check_finite,
                                         check_range, register)

FloatArray = NDArray[np.float64]

RECOMMENDED_MAX_BETA = math.radians(25.0)   # Xiu et al. 2024 abstract and conclusion (4)
PRACTICAL_MAX_BETA = math.radians(70.0)     # limit of the exact model's verified range
SEED000_ROLLER_MASS = 0.2                   # kg, Xiu et al. 2024, section 4 example
NEWTON_TOL = 1e-12                          # residual tolerance / r (~ rad) of the exact model
TWO_PI_3 = 2.0 * math.pi / 3.0
_FIDELITIES = ('ideal', 'closed', 'exact')


def closed_form_amplitude(beta: float, r: float, l: float) -> float:
    """Deviation amplitude (rad) (r / 2 l) tan(beta) tan^2(beta/2): Bugaru & Vasile 2021, eq. 19,
    Xiu et al. 2024, eq. 18 ((1 - cos b)/(1 + cos b) = tan^2(b/2)). beta in rad, r and l in m."""
    return r / (2.0 * l) * math.tan(beta) * math.tan(beta / 2.0) ** 2


# --- second-order Taylor arithmetic ("jets") ------------------------------------------
# A jet is a list [c0, c1, c2] (or [c0, c1]) of arrays/floats: x(t) = c0 + c1 t + c2 t^2.

Jet = list


def _jadd(a: Jet, b: Jet) -> Jet:
    return [x + y for x, y in zip(a, b)]


def _jsub(a: Jet, b: Jet) -> Jet:
    return [x - y for x, y in zip(a, b)]


def _jscale(a: Jet, k: Any) -> Jet:
    return [x * k for x in a]


def _jmul(a: Jet, b: Jet) -> Jet:
    if len(a) == 2:
        return [a[0] * b[0], a[0] * b[1] + a[1] * b[0]]
    return [a[0] * b[0], a[0] * b[1] + a[1] * b[0], a[0] * b[2] + a[1] * b[1] + a[2] * b[0]]


def _jcompose(a: Jet, f0: Any, f1: Any, f2: Any) -> Jet:
    """f(a(t)) given f(a0), f'(a0), f''(a0)."""
    if len(a) == 2:
        return [f0, f1 * a[1]]
    return [f0, f1 * a[1], f1 * a[2] + 0.5 * f2 * a[1] * a[1]]


def _jsin(a: Jet) -> Jet:
    s, c = np.sin(a[0]), np.cos(a[0])
    return _jcompose(a, s, c, -s)


def _jcos(a: Jet) -> Jet:
    s, c = np.sin(a[0]), np.cos(a[0])
    return _jcompose(a, c, -s, -c)


def _jsqrt(a: Jet) -> Jet:
    q = np.sqrt(a[0])
    return _jcompose(a, q, 0.5 / q, -0.25 / (q * a[0]))


def _jrecip(a: Jet) -> Jet:
    inv = 1.0 / a[0]
    return _jcompose(a, inv, -inv * inv, 2.0 * inv * inv * inv)


def _jconst(value: Any, order: int) -> Jet:
    """Constant jet; pass ``value`` already broadcast to the shape of the other jets."""
    z = value * 0.0
    return [value] + [z] * order


# The exact model's Fourier table depends only on the geometry (beta, r, l); building it
# (continuation + Newton + FFT) costs 0.15-1 s, and a scene builds the same joint for
# validation, fidelity choice and the driveline. Tables are read-only once built.
_SPECTRAL_FIELDS = ('_sine_coeffs', '_coeff_list', '_orbit_spec', '_table_phi', '_table_q',
                    'spectral_error')
_SPECTRAL_CACHE: dict[tuple[float, float, float], dict[str, Any]] = {}


def tripod_closed_scalar(phi_in: float, a: float) -> tuple[float, float, float]:
    """'closed' fidelity (phi_out rad, ratio -, ratio_slope 1/rad): phi_out = phi_in - a sin 3phi_in
    with a = closed_form_amplitude (module docstring). Plain float function, also compiled by
    cvj_ros/physics/kernel/joints_nb.py (one source for both)."""
    x = 3.0 * phi_in
    s3, c3 = math.sin(x), math.cos(x)
    return phi_in - a * s3, 1.0 - 3.0 * a * c3, 9.0 * a * s3


def tripod_series_scalar(phi_in: float, coeffs: Any) -> tuple[float, float, float]:
    """'exact' fidelity from its Fourier table: phi_out = phi_in + sum_k b_k sin(3 k phi_in)
    (sequence ``coeffs`` = b_1, b_2, ...), derivatives by the angle-addition recurrence. Also
    compiled by kernel/joints_nb.py (coeffs then a float64 array view)."""
    return tripod_series_reduced(phi_in, math.fmod(phi_in, TWO_PI_3), coeffs)


def tripod_series_reduced(phi_in: float, red: float, coeffs: Any) -> tuple[float, float, float]:
    """:func:`tripod_series_scalar` given ``red`` = fmod(phi_in, TWO_PI_3) (the series has period
    2 pi/3): the compiled kernel passes its own exact reduction (kernel/joints_nb.py)."""
    x = 3.0 * red
    s1, c1 = math.sin(x), math.cos(x)
    sk, ck = s1, c1
    dev = d1 = d2 = 0.0
    k = 1
    for b in coeffs:
        dev += b * sk
        d1 += b * k * ck
        d2 -= b * k * k * sk
        sk, ck = sk * c1 + ck * s1, ck * c1 - sk * s1
        k += 1
    return phi_in + dev, 1.0 + 3.0 * d1, 9.0 * d2


class Tripod:
    """Tripod joint with bend angle ``beta`` (rad), track radius ``r`` (m) and shaft
    length ``l`` (m) from the spider centre to the output shaft's fixed point.

    ``roller_mass`` (kg) is the axially sliding mass per track (Xiu et al. 2024: plunger,
    0.2 kg); ``spider_mass`` (kg) the spider with the part of its shaft lumped at the
    spider centre (orbiting at three times the shaft speed; Xiu et al. 2024 neglects it,
    default 0). Both are used by :meth:`reactions` only. See the module docstring for the model.
    """

    kind = 'tripod'
    mid_name = 'spider'

    def __init__(self, beta: float, r: float, l: float, *, fidelity: str = 'exact',
                 roller_mass: float = SEED000_ROLLER_MASS, spider_mass: float = 0.0) -> None:
        if fidelity not in _FIDELITIES:
            raise GeometryError('fidelity', f'tripod has fidelities {", ".join(_FIDELITIES)}; '
                                            f'got {fidelity!r}')
        self.fidelity = fidelity
        self.r = check_range('r', r, lo=0.0, lo_open=True, hi=None, unit=' m')
        self.l = check_range('l', l, lo=0.0, lo_open=True, hi=None, unit=' m')
        if not self.r < self.l:
            raise GeometryError('r', f'must be < l (track radius below shaft length), '
                                     f'got r = {self.r} m >= l = {self.l} m')
        self.beta = check_range('beta', beta, lo=0.0, hi=math.pi / 2, hi_open=True, unit=' rad')
        self.roller_mass = check_range('roller_mass', roller_mass, lo=0.0, hi=None, unit=' kg')
        self.spider_mass = check_range('spider_mass', spider_mass, lo=0.0, hi=None, unit=' kg')
        self.amplitude_closed = closed_form_amplitude(self.beta, self.r, self.l)
        sb, cb = math.sin(self.beta), math.cos(self.beta)
        self._n0 = np.array([sb, 0.0, cb])
        self._u0 = np.array([cb, 0.0, -sb])
        self._sine_coeffs: FloatArray | None = None   # b_k of sin(3 k phi), k = 1..K
        self._table_phi: FloatArray | None = None
        self._table_q: FloatArray | None = None
        self._orbit_spec: list[NDArray[np.complex128]] | None = None
        if fidelity == 'exact':
            if self.beta > PRACTICAL_MAX_BETA:
                raise GeometryError('beta', f'exact tripod model is verified up to '
                                            f'{math.degrees(PRACTICAL_MAX_BETA):g} deg, got '
                                            f'{math.degrees(self.beta):.6g} deg')
            key = (self.beta, self.r, self.l)
            cached = _SPECTRAL_CACHE.get(key)
            if cached is None:
                try:
                    with np.errstate(invalid='ignore', over='ignore', divide='ignore'):
                        self._build_spectral()
                except SolverError as exc:   # degenerate geometry (e.g. r/l ~ 1e-300)
                    raise GeometryError('l', f'exact tripod geometry cannot be solved for r = '
                                             f'{self.r:g} m, l = {self.l:g} m ({exc})') from None
                _SPECTRAL_CACHE[key] = cached = {k: getattr(self, k) for k in _SPECTRAL_FIELDS}
            else:
                for k, v in cached.items():
                    setattr(self, k, v)

    # --- contract ----------------------------------------------------------------------

    def params(self) -> dict[str, float]:
        return {'beta': self.beta, 'r': self.r, 'l': self.l, 'roller_mass': self.roller_mass,
                'spider_mass': self.spider_mass}

    def nonuniformity(self) -> float:
        """Amplitude (rad) of phi_out - phi_in: max |deviation| over a period."""
        if self.fidelity == 'ideal':
            return 0.0
        if self.fidelity == 'closed':
            return self.amplitude_closed
        # grid maximum of |deviation| refined by Newton on d(deviation)/dphi = 0
        phi = np.linspace(0.0, TWO_PI_3, 721)
        dev = np.abs(self._series(phi)[0])
        x = phi[np.argsort(dev)[-4:]]
        for _ in range(8):
            _, d1, d2 = self._series(x)
            x = x - d1 / np.where(d2 == 0.0, 1.0, d2)
        return float(max(np.max(dev), np.max(np.abs(self._series(x)[0]))))

    def evaluate(self, phi_in: ArrayLike, *, method: str = 'table') -> JointEval:
        """phi_out (rad), ratio (-), ratio_slope (1/rad), phi_mid = spider angle (rad).

        The spider is rigid on the output shaft, so phi_mid = phi_out. Exact fidelity:
        ``method='table'`` (default) evaluates the Fourier sine table of the exact
        deviation (verified against Newton to <= 1e-12 rad at construction; a few us per
        call); ``method='newton'`` solves the constraints by Newton with implicit
        differentiation (about 3 ms per call; used to verify the table)."""
        phi = as_angle_array(phi_in)
        if method not in ('table', 'newton'):
            raise GeometryError('method', f"must be 'table' or 'newton', got {method!r}")
        if self.fidelity == 'ideal':
            return JointEval(phi.copy(), np.ones_like(phi), np.zeros_like(phi), phi.copy())
        if self.fidelity == 'closed':
            a = self.amplitude_closed
            s3, c3 = np.sin(3.0 * phi), np.cos(3.0 * phi)
            out = phi - a * s3
            return JointEval(out, 1.0 - 3.0 * a * c3, 9.0 * a * s3, out.copy())
        if method == 'table':
            dev, d1, d2 = self._series(np.fmod(phi, TWO_PI_3))
            out = phi + dev
            return JointEval(out, 1.0 + d1, d2, out.copy())
        sol = self.solve(phi)
        out = np.asarray(phi + sol['deviation'])
        return JointEval(out, sol['ratio'], sol['ratio_slope'], out.copy())

    def scalar(self, phi_in: float) -> tuple[float, float, float]:
        """(phi_out, ratio, ratio_slope) for one float (rad); exact uses the Fourier table."""
        if self.fidelity == 'ideal':
            return phi_in, 1.0, 0.0
        if self.fidelity == 'closed':
            return tripod_closed_scalar(phi_in, self.amplitude_closed)
        return tripod_series_scalar(phi_in, self._coeff_list)

    # --- exact model -------------------------------------------------------------------

    def _geometry_jets(self, su: Jet, sv: Jet, ph2: Jet, ph1: Jet) -> dict[str, Any]:
        """Spider centre, frame, trunnions, constraint residuals (m), arm lengths h_j (m)
        and roller-centre axial positions z_j (m) as jets; see the module docstring."""
        order = len(su) - 1
        l, r = self.l, self.r
        n0, u0 = self._n0, self._u0
        w = _jsqrt(_jsub(_jconst(l * l + 0.0 * su[0], order), _jadd(_jmul(su, su), _jmul(sv, sv))))
        # S = su u0 + sv y + (l - w) n0 ;  n = (-su u0 - sv y + w n0)/l
        lw = _jsub(_jconst(l + 0.0 * su[0], order), w)
        S = [_jadd(_jscale(su, u0[i]), _jscale(lw, n0[i])) for i in range(3)]
        S[1] = _jadd(S[1], sv)
        n = [_jscale(_jadd(_jscale(su, -u0[i]), _jscale(w, n0[i])), 1.0 / l) for i in range(3)]
        n[1] = _jadd(n[1], _jscale(sv, -1.0 / l))
        # v = n x u0 / |n x u0| ; u = v x n
        vx = _jscale(n[1], u0[2])
        vy = _jsub(_jscale(n[2], u0[0]), _jscale(n[0], u0[2]))
        vz = _jscale(n[1], -u0[0])
        inv = _jrecip(_jsqrt(_jadd(_jadd(_jmul(vx, vx), _jmul(vy, vy)), _jmul(vz, vz))))
        v = [_jmul(vx, inv), _jmul(vy, inv), _jmul(vz, inv)]
        u = [_jsub(_jmul(v[1], n[2]), _jmul(v[2], n[1])),
             _jsub(_jmul(v[2], n[0]), _jmul(v[0], n[2])),
             _jsub(_jmul(v[0], n[1]), _jmul(v[1], n[0]))]
        res, h, zr, arms = [], [], [], []
        for j in range(3):
            aj = _jadd(ph2, _jconst(j * TWO_PI_3 + 0.0 * su[0], order))
            ca, sa = _jcos(aj), _jsin(aj)
            e = [_jadd(_jmul(ca, u[i]), _jmul(sa, v[i])) for i in range(3)]
            pj = _jadd(ph1, _jconst(j * TWO_PI_3 + 0.0 * su[0], order))
            tx = _jsub(_jscale(_jcos(pj), r), S[0])
            ty = _jsub(_jscale(_jsin(pj), r), S[1])
            res.append(_jsub(_jmul(tx, e[1]), _jmul(ty, e[0])))
            exy2 = _jadd(_jmul(e[0], e[0]), _jmul(e[1], e[1]))
            hj = _jmul(_jadd(_jmul(tx, e[0]), _jmul(ty, e[1])), _jrecip(exy2))
            h.append(hj)
            zr.append(_jadd(S[2], _jmul(hj, e[2])))
            arms.append(e)
        return {'S': S, 'n': n, 'u': u, 'v': v, 'e': arms, 'res': res, 'h': h, 'z': zr}

    def _residual_and_jacobian(self, q: FloatArray, ph1: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Residual (3, N) in m and Jacobian (N, 3, 3) w.r.t. (s_u, s_v, phi_out)."""
        zero = np.zeros_like(ph1)
        jac = np.empty(ph1.shape + (3, 3))
        res = None
        for k in range(3):
            seeds = [[q[i], zero + (1.0 if i == k else 0.0)] for i in range(3)]
            g = self._geometry_jets(seeds[0], seeds[1], seeds[2], [ph1, zero])
            if res is None:
                res = np.array([g['res'][i][0] for i in range(3)])
            for i in range(3):
                jac[..., i, k] = g['res'][i][1]
        return res, jac

    def _newton(self, q: FloatArray, ph1: FloatArray, *, max_iter: int = 40) -> FloatArray:
        return self._newton_jac(q, ph1, max_iter=max_iter)[0]

    def _newton_jac(self, q: FloatArray, ph1: FloatArray, *,
                    max_iter: int = 40) -> tuple[FloatArray, FloatArray | None]:
        """Newton on the three constraints from the start ``q`` (3, N).

        Converged when every residual is <= 1e-13 r (m), i.e. an angle error of about
        1e-13 rad; fails (SolverError) above NEWTON_TOL r."""
        q = q.copy()
        target = 1e-13 * self.r
        err = math.inf
        for _ in range(max_iter):
            res, jac = self._residual_and_jacobian(q, ph1)
            err = float(np.max(np.abs(res)))
            if err <= target:
                return q, jac
            q += solve_batched(jac, -res.T).T
        if err <= NEWTON_TOL * self.r:
            return q, None
        raise SolverError(f'tripod: Newton did not converge (max residual {err / self.r:.3g} r)')

    def _start(self, ph1: FloatArray) -> FloatArray:
        """Warm start (3, N) from the continuation table (periodic interpolation)."""
        assert self._table_phi is not None and self._table_q is not None
        red = np.mod(ph1, TWO_PI_3)
        q = np.empty((3,) + ph1.shape)
        if self._orbit_spec is not None and self._sine_coeffs is not None:
            # Fourier tables: start within ~1e-15 of the solution
            k = np.arange(len(self._orbit_spec[0]))
            x = 3.0 * np.multiply.outer(red, k)
            w = np.where(k == 0, 1.0, 2.0)
            cx, sx = np.cos(x), np.sin(x)
            for i in range(2):   # Re(sum_k w_k c_k e^{i x_k}), real arithmetic, fixed order
                c = w * self._orbit_spec[i]
                q[i] = matvec(cx, c.real) - matvec(sx, c.imag)
            q[2] = ph1 + self._series(red)[0]
            return q
        for i in range(3):
            q[i] = np.interp(red, self._table_phi, self._table_q[i])
        q[2] += ph1 - red
        return q

    def solve(self, phi_in: ArrayLike) -> dict[str, FloatArray]:
        """Exact geometry at ``phi_in`` (rad), by Newton and implicit differentiation.

        Returns arrays: ``deviation`` phi_out - phi_in (rad), ``ratio`` (-), ``ratio_slope``
        (1/rad), ``orbit_u``, ``orbit_v`` spider-centre offset (m) along u0 (bend plane)
        and y, ``orbit_radius`` (m), ``orbit_angle`` (rad), ``plunge`` axial position of
        the spider centre S_z (m), ``arm_length`` (3, N) roller centre to spider centre
        (m), ``roller_z`` (3, N) roller-centre axial positions (m) and their first and
        second derivatives over phi_in ``roller_dz``, ``roller_d2z`` (m/rad, m/rad^2),
        ``spider_d``, ``spider_d2`` (3, N) first and second derivatives of the spider
        centre position (m/rad, m/rad^2),
        ``spin_ratio`` (-): the spider's spin rate about its own axis n per unit input
        rate, Omega . n / omega_in. It differs from ``ratio`` by O((rho/l)^2) (the frame
        convention's own twist while n wobbles); power balances use it.
        """
        ph1 = np.atleast_1d(as_angle_array(phi_in)).astype(float)
        shape = np.shape(np.asarray(phi_in))
        if self._table_phi is None:
            raise SolverError('tripod: exact geometry needs fidelity="exact"')
        # The geometry is periodic in phi_in with period 2 pi/3 (tracks permute): solve at
        # the reduced angle so that sin/cos keep full precision at large angles.
        turns = np.round(ph1 / TWO_PI_3)
        red = ph1 - turns * TWO_PI_3
        q, jac = self._newton_jac(self._start(red), red)
        out = self._derivatives(q, red, jac)
        out['deviation'] = out['deviation'] + (ph1 - red - turns * TWO_PI_3)
        # per-roller arrays: reduced index (j + turns) mod 3 is the original roller j
        idx = (np.arange(3)[:, None] + turns[None, :].astype(int)) % 3
        for key in ('arm_length', 'roller_z', 'roller_dz', 'roller_d2z', 'residual'):
            out[key] = np.take_along_axis(out[key], idx, axis=0)
        return {k: (v.reshape(v.shape[:-1] + shape) if v.ndim > 1 else v.reshape(shape))
                for k, v in out.items()}

    def _derivatives(self, q: FloatArray, ph1: FloatArray,
                     jac: FloatArray | None = None) -> dict[str, FloatArray]:
        """Implicit differentiation: q(t) = q0 + q1 t + q2 t^2 along phi_in = ph1 + t;
        ``jac`` is the constraint Jacobian at q if already known."""
        zero = np.zeros_like(ph1)
        one = zero + 1.0
        if jac is None:
            _, jac = self._residual_and_jacobian(q, ph1)
        g = self._geometry_jets(*[[q[i], zero] for i in range(3)], [ph1, one])
        r1 = np.array([g['res'][i][1] for i in range(3)])
        q1 = solve_batched(jac, -r1.T).T
        g = self._geometry_jets(*[[q[i], q1[i], zero] for i in range(3)], [ph1, one, zero])
        r2 = np.array([g['res'][i][2] for i in range(3)])
        q2 = solve_batched(jac, -r2.T).T
        g = self._geometry_jets(*[[q[i], q1[i], q2[i]] for i in range(3)], [ph1, one, zero])
        su, sv = q[0], q[1]
        # spin of the spider about its own axis per unit phi_in: (de0/dphi) . (n x e0)
        e0 = [g['e'][0][i] for i in range(3)]
        nn = [g['n'][i][0] for i in range(3)]
        ne = np.cross(np.array(nn).T, np.array([c[0] for c in e0]).T).T
        spin = sum(e0[i][1] * ne[i] for i in range(3))
        return {
            'spin_ratio': spin,
            'deviation': q[2] - ph1,
            'ratio': q1[2],
            'ratio_slope': 2.0 * q2[2],
            'orbit_u': su, 'orbit_v': sv,
            'orbit_radius': np.hypot(su, sv),
            'orbit_angle': np.arctan2(sv, su),
            'plunge': g['S'][2][0],
            'arm_length': np.array([g['h'][j][0] for j in range(3)]),
            'roller_z': np.array([g['z'][j][0] for j in range(3)]),
            'roller_dz': np.array([g['z'][j][1] for j in range(3)]),
            'roller_d2z': np.array([2.0 * g['z'][j][2] for j in range(3)]),
            'spider_d': np.array([g['S'][i][1] for i in range(3)]),
            'spider_d2': np.array([2.0 * g['S'][i][2] for i in range(3)]),
            'residual': np.array([g['res'][j][0] for j in range(3)]),
        }

    def positions(self, phi_in: float) -> dict[str, FloatArray]:
        """Points and axes of the exact geometry at one ``phi_in`` (rad), for independent
        checks and plots: ``S``, ``P``, ``n``, ``arms`` (3x3 unit trunnion axes), ``rollers``
        (3x3 roller centres, m)."""
        phi = check_finite('phi_in', phi_in)
        turns = round(phi / TWO_PI_3)
        red = np.array([phi - turns * TWO_PI_3])
        q = self._newton(self._start(red), red)
        z = np.zeros(1)
        g = self._geometry_jets(*[[q[i], z] for i in range(3)], [red, z])
        S = np.array([g['S'][i][0][0] for i in range(3)])
        # reduced index (j + turns) mod 3 is the original track/trunnion j
        arms = np.roll(np.array([[g['e'][j][i][0][0] for i in range(3)] for j in range(3)]),
                       -turns, axis=0)
        h = np.roll(np.array([g['h'][j][0][0] for j in range(3)]), -turns)
        return {'S': S, 'P': self.l * self._n0, 'n': np.array([g['n'][i][0][0] for i in range(3)]),
                'arms': arms, 'rollers': S + h[:, None] * arms,
                'phi_out': float(q[2][0]) + turns * TWO_PI_3}

    def _build_spectral(self) -> None:
        """Continuation along phi_in over one period, then a Fourier sine table."""
        # Start at phi_in = 0 (symmetric: s_v = 0, phi_out = 0) by continuation in beta.
        q = np.zeros((3, 1))
        ph0 = np.zeros(1)
        beta_target = self.beta
        nb = max(1, int(math.ceil(beta_target / math.radians(5.0))))
        for b in np.linspace(beta_target / nb, beta_target, nb):
            self._set_beta(float(b))
            q = self._newton(q, ph0)
        self._set_beta(beta_target)
        # March along one period; table for warm starts.
        m = 18
        phis = np.linspace(0.0, TWO_PI_3, m + 1)
        qs = np.empty((3, m + 1))
        qs[:, 0] = q[:, 0]
        for i in range(1, m + 1):
            qi = self._newton(qs[:, i - 1:i].copy(), phis[i:i + 1])
            qs[:, i] = qi[:, 0]
        self._table_phi = phis
        self._table_q = qs   # (s_u, s_v, phi_out); phi_out - phi_in is periodic
        # Fourier sine series of the deviation on N equispaced points (odd by symmetry).
        coeffs = None
        for n_pts in (64, 128, 256, 512, 1024):
            x = np.arange(n_pts) * (TWO_PI_3 / n_pts)
            q_pts = self._newton(self._start(x), x)
            dev = q_pts[2] - x
            spec = np.fft.rfft(dev) / n_pts
            b = -2.0 * spec.imag[1:n_pts // 2]
            a = 2.0 * spec.real[1:n_pts // 2]
            if max(abs(spec.real[0]), np.max(np.abs(a))) > 1e-12:
                raise SolverError('tripod: deviation is not odd; convention broken')
            tail = np.max(np.abs(b[-(len(b) // 4):]))
            if tail < 1e-16:
                keep = np.nonzero(np.abs(b) > 1e-16)[0]
                coeffs = b[:keep[-1] + 1] if keep.size else b[:1]
                # orbit offsets too, as warm starts for Newton in evaluate()
                n_keep = len(coeffs) + 8
                self._orbit_spec = [np.fft.rfft(q_pts[i])[:n_keep] / n_pts for i in range(2)]
                break
        if coeffs is None:
            raise SolverError('tripod: Fourier series of the exact deviation did not converge')
        self._sine_coeffs = coeffs
        self._coeff_list = [float(c) for c in coeffs]
        # Verify against Newton between the sample points.
        xm = (np.arange(97) + 0.37) * (TWO_PI_3 / 97)
        err = np.max(np.abs(self._series(xm)[0] - (self._newton(self._start(xm), xm)[2] - xm)))
        if not err <= 1e-12:   # also catches NaN from a degenerate geometry
            raise SolverError(f'tripod: Fourier table error {err:.3g} rad > 1e-12')
        self.spectral_error = float(err)

    def _set_beta(self, beta: float) -> None:
        sb, cb = math.sin(beta), math.cos(beta)
        self._n0 = np.array([sb, 0.0, cb])
        self._u0 = np.array([cb, 0.0, -sb])

    def _series(self, phi: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Deviation (rad), d/dphi (-), d2/dphi2 (1/rad) of the Fourier sine table."""
        assert self._sine_coeffs is not None
        k = np.arange(1, len(self._sine_coeffs) + 1)
        x = 3.0 * np.multiply.outer(np.asarray(phi), k)
        b = self._sine_coeffs
        sx, cx = np.sin(x), np.cos(x)
        return (matvec(sx, b), matvec(cx, 3.0 * k * b), -matvec(sx, 9.0 * k * k * b))

    # --- reactions ---------------------------------------------------------------------

    def reactions(self, phi_in: float, omega_in: float, torque_in: float) -> dict[str, float]:
        """Quasi-static reactions at constant speed (Xiu et al. 2024, section 4, from this model).

        Inputs: phi_in (rad), omega_in (rad/s), torque_in (N m, delivered by the housing).
        Frictionless contacts: the track pushes a roller only across its track (no axial
        component), the trunnion only across its axis. Each roller/plunger of mass
        ``roller_mass`` m (kg) slides axially with a_j = omega^2 d2z_j/dphi^2 (m/s^2, z_j
        from the exact geometry by Taylor arithmetic), so the spider's force on roller j,
        F_j (N), satisfies F_j . z = m a_j and F_j . e_j = 0; the housing torque gives
        sum (R_j x F_j) . z = -torque_in; the spider with its shaft pivots freely about P:
        sum (R_j - P) x (-F_j) + T n = (S - P) x m_s a_S. A 10 x 10 linear system.
        Checked by virtual work and by the energy balance (test_tripod.py).

        Returns (N, N m, m/s^2): ``axial_force`` generated axial force on the output
        shaft at P along n (Xiu et al. 2024 R_z''); ``output_force_x/y/z`` bearing force at P on
        the output shaft (fixed frame); ``input_force_x/y`` and ``input_moment_x/y``
        reaction force and moment (about the joint centre O) the housing's bearing must
        supply, -sum F_j and -sum R_j x F_j plus (exact fidelity) the rate of the plungers'
        angular momentum, also given alone as ``plunger_moment_x/y`` (1.4 % of the moment
        at 25 deg, 1.8 % at 30 deg in the example below without load torque);
        ``roller_force_0..2`` (N) and ``roller_arm_0..2`` (m): per-roller trunnion force
        and arm (:meth:`_solve_reactions`); ``torque_out`` (N m) torque about the output
        axis n (power torque_out * Omega . n, see ``spin_ratio`` in :meth:`solve`);
        ``roller_accel_0..2``, ``roller_accel_sum`` (m/s^2, Xiu et al. 2024, eq. 20).

        Xiu et al. 2024 example (m = 0.2 kg, 2000 rpm, r = 26 mm, l = 700 mm, beta = 25 deg): the
        peak generated axial force is 3.5 N, each plunger needs m a_j ~ 109 N, the input
        bearing about 8 N and 5 N m; not "8000 kilonewtons" (eq. 30). The exact sum of
        the plunger accelerations is second order in rho/l (0.03 m/s^2 there), not
        -6 omega^2 rho sin(beta) cos(3 phi) (eq. 20, 150 m/s^2): with the spider centre
        held at distance l from P, n . S = -|S|^2 / (2 l), so sum z_j = 3 n . S / n_z.
        Closed/ideal fidelity: first-order geometry without the orbit (:meth:`_reactions_small`).
        """
        phi = check_finite('phi_in', phi_in)
        omega = check_finite('omega_in', omega_in)
        torque = check_finite('torque_in', torque_in)
        m = self.roller_mass
        if self.fidelity == 'exact':
            g = self.positions(phi)
            sol = self.solve(np.array([phi]))
            acc = omega * omega * sol['roller_d2z'][:, 0]
            acc_spider = omega * omega * sol['spider_d2'][:, 0]
            P, n, arms, rollers = g['P'], g['n'], g['arms'], g['rollers']
        else:
            return self._reactions_small(phi, omega, torque)
        return self._solve_reactions(P, n, arms, rollers, acc, torque, m,
                                     spider=g['S'], acc_spider=acc_spider,
                                     spider_mass=self.spider_mass, omega=omega)

    def _reactions_small(self, phi: float, omega: float, torque: float) -> dict[str, float]:
        """Closed/ideal fidelity: first-order geometry without the orbit (S = 0, n = n0).
        Roller j sits on its track in the spider plane n0 . R = 0:
        R_j = (r cos psi_j, r sin psi_j, -r tan(beta) cos psi_j), so
        a_j = omega^2 r tan(beta) cos(psi_j) (m/s^2) and sum a_j = 0."""
        sb, cb = math.sin(self.beta), math.cos(self.beta)
        n = np.array([sb, 0.0, cb])
        tb = sb / cb
        rollers = np.empty((3, 3))
        acc = np.empty(3)
        for j in range(3):
            c, s = math.cos(phi + j * TWO_PI_3), math.sin(phi + j * TWO_PI_3)
            rollers[j] = (self.r * c, self.r * s, -self.r * tb * c)
            acc[j] = omega * omega * self.r * tb * c
        arms = rollers / np.sqrt(rollers[:, 0] ** 2 + rollers[:, 1] ** 2 + rollers[:, 2] ** 2)[:, None]
        return self._solve_reactions(self.l * n, n, arms, rollers, acc, torque, self.roller_mass)

    @staticmethod
    def _solve_reactions(P: FloatArray, n: FloatArray, arms: FloatArray, rollers: FloatArray,
                         acc: FloatArray, torque: float, m: float, *,
                         spider: FloatArray | None = None, acc_spider: FloatArray | None = None,
                         spider_mass: float = 0.0, omega: float | None = None
                         ) -> dict[str, float]:
        """Solve the 10 x 10 system of :meth:`reactions` (F_j in N, output torque in N m).
        A spider point mass at S (kg) with acceleration acc_spider (m/s^2) adds its
        moment (S - P) x m_s a_S about P and its inertia force to the bearing force.

        Per roller (Xiu et al. 2024 eqs. 22-24, from this model): ``roller_force_j`` (N) =
        -F_j . (n x e_j), the force roller j puts on its trunnion across it in the spider
        plane (the one that carries the torque), and ``roller_arm_j`` (m) = |R_j - S|;
        sum_j roller_arm_j roller_force_j = torque_out (the moment balance about n). The
        three forces differ, and the arms sum to 3 r + 3 rho (rho the spider's orbit
        radius, up to ~rho^2/r), not 3 r - 3 rho (their eqs. 21, 24).

        With ``omega`` (rad/s, exact geometry) the housing bearing also supplies the rate of
        the plungers' angular momentum about O, dL/dt = sum_j m R_j x A_j with
        A_j = (-omega^2 x_j, -omega^2 y_j, a_j) (centripetal on the track radius, axial
        a_j; the housing turns at constant omega): the input moment is
        -sum R_j x F_j + dL/dt (x, y). For the first-order geometry (``omega`` None)
        dL/dt is exactly 0 (the rollers stay in the fixed spider plane n0 . R = 0)."""
        inertia = np.zeros(3) if spider is None or acc_spider is None else spider_mass * acc_spider
        A = np.zeros((10, 10))
        rhs = np.zeros(10)
        for j in range(3):
            A[j, 3 * j:3 * j + 3] = arms[j]                   # F_j . e_j = 0
            A[3 + j, 3 * j + 2] = 1.0                         # F_j . z = m a_j
            rhs[3 + j] = m * acc[j]
            A[6, 3 * j] = -rollers[j, 1]                      # sum (R_j x F_j) . z = -T_in
            A[6, 3 * j + 1] = rollers[j, 0]
            d = rollers[j] - P                                # sum d_j x (-F_j) + T n = 0
            A[7:10, 3 * j:3 * j + 3] = -np.array([[0.0, -d[2], d[1]], [d[2], 0.0, -d[0]],
                                                  [-d[1], d[0], 0.0]])
        A[7:10, 9] = n
        rhs[6] = -torque
        if spider is not None:
            rhs[7:10] = np.cross(spider - P, inertia)
        x = solve(A, rhs)
        F = x[:9].reshape(3, 3)
        on_rollers = F.sum(axis=0)              # the housing carries -on_rollers (x, y)
        total = on_rollers + inertia            # bearing force at P on the output shaft
        moment = np.cross(rollers, F).sum(axis=0)
        out = {
            'axial_force': dot(total, n),
            'output_force_x': float(total[0]), 'output_force_y': float(total[1]),
            'output_force_z': float(total[2]),
            'input_force_x': float(-on_rollers[0]), 'input_force_y': float(-on_rollers[1]),
            'input_moment_x': float(-moment[0]), 'input_moment_y': float(-moment[1]),
            'torque_out': float(-x[9]),
            'roller_accel_sum': float(acc.sum()),
        }
        for j in range(3):
            out[f'roller_accel_{j}'] = float(acc[j])
        centre = np.zeros(3) if spider is None else spider
        for j in range(3):
            out[f'roller_force_{j}'] = -dot(F[j], np.cross(n, arms[j]))
            out[f'roller_arm_{j}'] = float(np.linalg.norm(rollers[j] - centre))
        if omega is not None:
            w2 = omega * omega
            dlx, dly = 0.0, 0.0
            for j in range(3):
                x, y, z = float(rollers[j, 0]), float(rollers[j, 1]), float(rollers[j, 2])
                ax, ay, az = -w2 * x, -w2 * y, float(acc[j])
                dlx += m * (y * az - z * ay)
                dly += m * (z * ax - x * az)
            out['input_moment_x'] += dlx
            out['input_moment_y'] += dly
            out['plunger_moment_x'], out['plunger_moment_y'] = dlx, dly
        return out


def _factory(*, fidelity: str = 'exact', beta: float = 0.0, r: float = 0.026, l: float = 0.7,
             roller_mass: float = SEED000_ROLLER_MASS, spider_mass: float = 0.0,
             **_ignored: float) -> Tripod:
    return Tripod(beta, r, l, fidelity=fidelity, roller_mass=roller_mass, spider_mass=spider_mass)


register(JointSpec(
    kind='tripod', factory=_factory, fidelities=_FIDELITIES,
    params={'beta': 'rad, bend angle, 0 <= beta < pi/2 (exact: <= 70 deg; recommended <= 25 deg), default 0',
            'r': 'm, track radius (tulip radius), 0 < r < l, default 0.026 (Xiu et al. 2024)',
            'l': 'm, spider centre to the output shaft fixed point, default 0.7 (Xiu et al. 2024)',
            'roller_mass': 'kg, axially sliding mass per track (reactions), default 0.2 (Xiu et al. 2024)',
            'spider_mass': 'kg, spider (+ lumped shaft) mass orbiting at 3x speed (reactions, exact '
                           'fidelity), default 0 (Xiu et al. 2024 neglects it)'},
    source='Bugaru & Vasile 2021, eq. 19; Xiu et al. 2024, eqs. 1-18, 20-34 (with the errata listed in README "Errors in the source documents"); exact: own geometry'))
