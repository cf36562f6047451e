"""Analytic Jacobian of a chain mode's right-hand side (``HybridChain.evaluate``).

d(ydot)/dy for the mode state y = [q_g, q'_g, W_engine, W_load, W_damp, W_friction]: the
terms of the event-free ``Driveline.jacobian`` (M(q) q'' + C(q) q'^2 = Q per rigid group,
the chain rule through the joints and couplings, spring slopes) on the mode's groups, plus
a slipping clutch's torque T = s mu_k cgeo fn (constant in y: dQ_g/dq_g = -T b_g, its
friction power T thetadot), the slipping brake's T_b a_last on the last group and a stuck
brake's pinned group (zero rows). Only dC/dq (the joints' third derivative, not in the
joint contract) is a central difference of C(q), increment 1e-6 max(1, |q|), as in
``Driveline.jacobian``. The compiled twin is ``kernel/modes_jac_nb.mode_jac`` (the same
formula, term by term).
"""
from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from cvj_ros.physics.engine import MapEngine, map_engine_eval
from cvj_ros.physics.hybrid.chain import Assembly, HybridChain, Mode
from cvj_ros.physics.sections import section_kinematics, section_slopes

__all__ = ['mode_jacobian', 'torque_slopes']

FloatArray = NDArray[np.float64]


def torque_slopes(src: Any, t: float, omega: float, phi: float) -> tuple[float, float, float]:
    """(T, dT/domega, dT/dphi) of an engine or load: the map engine's analytic formula
    (``map_engine_eval``, also the kernel's); otherwise ``torque``, ``slope`` and dT/dphi by a
    central difference of increment 1e-6 max(1, |phi|) (exactly 0 for a torque without
    angle dependence)."""
    if isinstance(src, MapEngine):
        return map_engine_eval(omega, phi, src.throttle, *src.kernel_params())
    h = 1e-6 * max(1.0, abs(phi))
    dphi = (src.torque(t, omega, phi + h) - src.torque(t, omega, phi - h)) / (2.0 * h)
    return src.torque(t, omega, phi), src.slope(t, omega, phi), dphi


def mode_jacobian(chain: HybridChain, asm: Assembly, mode: Mode, t: float, y: FloatArray, *,
                  engine: Any, load: Any, clutch_kinetic: float,
                  brake_kinetic: float) -> FloatArray:
    """d(ydot)/dy of ``chain.evaluate`` at (t, y) (the engine's throttle already set)."""
    groups = asm.groups
    n = len(groups)
    n2 = 2 * n
    yl = y.tolist()
    ns = len(yl)
    sec = []
    for g, grp in enumerate(groups):
        q = yl[g]
        phi, a, b, m, c, mp, hj = section_slopes(grp.ops, q)
        if hj:
            h = 1e-6 * max(1.0, abs(q))
            cp = (section_kinematics(grp.ops, q + h)[4]
                  - section_kinematics(grp.ops, q - h)[4]) / (2.0 * h)
        else:
            cp = 0.0
        sec.append((phi, a, b, m, c, mp, cp))
    qf = [0.0] * n
    dq = [[0.0] * n2 for _ in range(n)]
    dpd = [0.0] * n2
    dpf = [0.0] * n2
    v0 = yl[n]
    te, dte, dtep = torque_slopes(engine, t, v0, yl[0])
    al, bl = sec[-1][1], sec[-1][2]
    vl = yl[n2 - 1]
    omega_last = al * vl
    tl, dtl, dtlp = torque_slopes(load, t, omega_last, sec[-1][0])
    qf[0] += te
    dq[0][n] += dte
    dq[0][0] += dtep
    qf[-1] -= tl * al
    dq[n - 1][n - 1] += -tl * bl - dtl * bl * vl * al - dtlp * al * al
    dq[n - 1][n2 - 1] += -dtl * al * al
    if chain.brake is not None and not asm.pinned and mode.brake:
        tb = mode.brake * brake_kinetic
        qf[-1] -= tb * al
        dq[n - 1][n - 1] -= tb * bl
        dpf[n - 1] += tb * bl * vl
        dpf[n2 - 1] += tb * al
    for k, b in enumerate(asm.links):
        bd = chain.boundaries[b]
        phi_l, a_l, b_l = sec[k][0], sec[k][1], sec[k][2]
        thd = a_l * yl[n + k] - yl[n + k + 1]
        dthd_qk = b_l * yl[n + k]
        rk, rk1 = dq[k], dq[k + 1]
        if bd.kind == 'spring':
            sp = bd.spring
            th = phi_l - yl[k + 1]
            ts, k_th, k_d, _v, _pd = sp.evaluate(th, thd)
            d_qk = k_th * a_l + k_d * dthd_qk
            d_vk = k_d * a_l
            qf[k] -= ts * a_l
            qf[k + 1] += ts
            rk[k] -= d_qk * a_l + ts * b_l
            rk[k + 1] -= -k_th * a_l
            rk[n + k] -= d_vk * a_l
            rk[n + k + 1] -= -k_d * a_l
            rk1[k] += d_qk
            rk1[k + 1] += -k_th
            rk1[n + k] += d_vk
            rk1[n + k + 1] += -k_d
            if sp.d != 0.0:
                _e, de, dde = sp.deflection(th)
                dp_dth = sp.d * dde * thd * thd
                dp_dthd = 2.0 * sp.d * de * thd
                dpd[k] += dp_dth * a_l + dp_dthd * dthd_qk
                dpd[k + 1] -= dp_dth
                dpd[n + k] += dp_dthd * a_l
                dpd[n + k + 1] -= dp_dthd
        elif bd.kind == 'clutch':
            ts = mode.clutch[bd.name] * clutch_kinetic
            qf[k] -= ts * a_l
            qf[k + 1] += ts
            rk[k] -= ts * b_l
            dpf[k] += ts * dthd_qk
            dpf[n + k] += ts * a_l
            dpf[n + k + 1] -= ts
    J = np.zeros((ns, ns))
    for g in range(n):
        if asm.pinned and g == n - 1:
            continue
        _phi, _a, _b, m, c, mp, cp = sec[g]
        v = yl[n + g]
        inv = 1.0 / m
        J[g, n + g] = 1.0
        row = [d * inv for d in dq[g]]
        row[g] += -cp * v * v * inv - (qf[g] - c * v * v) * mp * inv * inv
        row[n + g] += -2.0 * c * v * inv
        J[n + g, :n2] = row
    J[n2, n] = te + dte * v0
    J[n2, 0] += dtep * v0
    J[n2 + 1, n - 1] = tl * bl * vl + dtl * bl * vl * al * vl + dtlp * al * al * vl
    J[n2 + 1, n2 - 1] = tl * al + dtl * al * al * vl
    J[n2 + 2, :n2] = dpd
    J[n2 + 3, :n2] = dpf
    return J
