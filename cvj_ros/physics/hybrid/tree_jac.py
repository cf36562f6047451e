"""Analytic Jacobian of a vehicle tree mode's right-hand side (``ModeTree.evaluate``).

d(xdot)/dx for x = [u, udot, kappa', v, W_engine, W_damp, W_slip, W_road, W_friction] by the
chain rule through the tree's equations: a section's angle moves along its row (dq_s/du =
r_s, dr_s/du_j = b_p r_p[j] r_p + a_p dr_p/du_j, the bias k_s likewise), forces by their
slopes (engine: ``chain_jac.torque_slopes``; springs: ``SpringLaw.evaluate``; viscous
couplings; tyres: ``MagicFormula.slope`` with the normal loads' load transfer differentiated
in closed form, zero where clamped; body), the mode's slipping clutch, slipping brakes and a
pack's bias; per group d uddot/dy = M^-1 sum_s [dr_s/dy (G_s - M_s r_s.uddot)
+ r_s (dG_s/dy - dM_s/dq dq_s/dy r_s.uddot - M_s (dr_s/dy).uddot)] with G_s = Q_s - C_s
qdot_s^2 - M_s k_s; a pinned coordinate's rows 0.

A slipping torque-sensing pack's bias T_b = m (T_p + k s T_c), s = sign T_c
(``ModeTree._pack_bias``), by implicit differentiation of its two backward walks: the
carrier torque T_c = T_L + T_R = sum_s w_s (M_s qddot_s + C_s qdot_s^2 + a_s T_end,s) over
both sides and the sections hung on them rigidly (w = 1 on a side, w_s = w_p a_p below),
affine in T_b (T_c = T_c0 + B T_b); dT_c/dy at fixed T_b by the chain rule above (with the
acceleration rows at fixed T_b), B = sum_s w_s M_s r_s.g, g = d uddot/dT_b (the group solve
of the unit bias), so dT_b/dy = m k s (dT_c/dy) / (1 - m k s B), added as g dT_b/dy to the
accelerations and (omega_L - omega_R) dT_b/dy to the friction power.

Difference quotients: db_end/dq and dC_s/dq (a joint's third derivative), central
differences of the section's end kinematics (increment 1e-6 max(1, |q_s|)), as in
``chain_jac``; where |m k B| >= 1 (no consistent sign: the rhs's fallback) or with two
sensing packs, the whole Jacobian by central differences of the mode rhs (increment 1e-6
max(1, |x_j|)). The compiled twin is ``kernel/tree_modes_jac_nb.tm_jac`` (the same formula,
term by term).
"""
from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np
from numpy.typing import NDArray

from cvj_ros.physics.hybrid.chain_jac import torque_slopes
from cvj_ros.physics.hybrid.elements import Clutch
from cvj_ros.physics.hybrid.tree import ModeTree
from cvj_ros.physics.sections import section_kinematics, section_slopes

__all__ = ['tree_mode_jacobian']

FloatArray = NDArray[np.float64]


def _carrier_weights(mt: ModeTree, di: Any, end: list[tuple[float, ...]],
                     coords: list[list[int]], dq_row: Any
                     ) -> tuple[list[float], FloatArray, list[int]]:
    """Weights w_s of the sections a pack's carrier torque T_c = T_L + T_R sums in the
    backward walk (both sides and everything hung on them rigidly: w = 1 on a side, w_s =
    w_p a_p below), their derivatives dw_s/dy = a_p dw_p/dy + w_p b_p dq_p/dy, and those
    sections in tree order."""
    ns = len(mt.sections)
    nst = mt._n_state
    w = [0.0] * ns
    dw = np.zeros((ns, nst))
    inside = [False] * ns
    out = []
    for s, sec in enumerate(mt.sections):
        if s in (di.left, di.right):
            w[s] = 1.0
        elif sec.parent >= 0 and inside[sec.parent]:
            p = sec.parent
            w[s] = w[p] * end[p][1]
            dw[s] = end[p][1] * dw[p]
            dq_row(p, w[p] * end[p][2], dw[s])
        else:
            continue
        inside[s] = True
        out.append(s)
    return w, dw, out


def tree_mode_jacobian(mt: ModeTree, t: float, x: FloatArray, engine: Any, clutch_kinetic: float,
                       brake_kinetic: Mapping[str, float]) -> FloatArray:
    """d(xdot)/dx of ``mt.evaluate(t, x, engine, clutch_kinetic, brake_kinetic)`` (the
    engine's throttle already set), module docstring."""
    n = mt.n_dof
    nw = mt.n_wheel
    x = np.asarray(x, dtype=float)
    nst = x.size
    xl = x.tolist()

    def rhs(xx: FloatArray) -> FloatArray:
        return mt.evaluate(t, xx, engine, clutch_kinetic, brake_kinetic, torques=False).ydot

    def central() -> FloatArray:
        jac = np.empty((nst, nst))
        for j in range(nst):
            h = 1e-6 * max(1.0, abs(xl[j]))
            xp, xm = x.copy(), x.copy()
            xp[j] += h
            xm[j] -= h
            jac[:, j] = (rhs(xp) - rhs(xm)) / (2.0 * h)
        return jac

    sensing = [(el, mt.diffs[d], mt.mode.packs[name]) for name, (el, d) in mt.packs.items()
               if mt.diffs[d].coord >= 0 and el.torque_bias != 0.0]
    acc = rhs(x)[n:2 * n].tolist()
    J = np.zeros((nst, nst))
    ns = len(mt.sections)
    coords = [mt._groups[mt._group_of[s]][0] for s in range(ns)]
    q = [0.0] * ns
    qd = [0.0] * ns
    bias = [0.0] * ns
    R: list[list[float]] = [[]] * ns
    D: list[list[list[float]]] = [[]] * ns
    dqd: list[list[float]] = [[]] * ns
    dku: list[list[float]] = [[]] * ns
    dkw: list[list[float]] = [[]] * ns
    end: list[tuple[float, ...]] = [()] * ns
    dbq = [0.0] * ns
    dcq = [0.0] * ns
    for s, sec in enumerate(mt.sections):
        k = len(coords[s])
        if sec.parent < 0:
            c = sec.coord
            q[s], qd[s] = xl[c], xl[n + c]
            row = [0.0] * k
            row[0] = 1.0
            dd = [[0.0] * k for _ in range(k)]
            ku = [0.0] * k
            kw = [0.0] * k
        else:
            p = sec.parent
            ap, bp, qdp = end[p][1], end[p][2], qd[p]
            rp = R[p]
            row = [ap * r for r in rp]
            q[s], qd[s] = end[p][0], ap * qdp
            i = mt._sec_local[s]
            if i >= 0:
                c = mt.diffs[sec.diff].coord
                q[s] += sec.sign * xl[c]
                qd[s] += sec.sign * xl[n + c]
                row[i] += sec.sign
            elif mt._lock_delta and sec.diff in mt._lock_delta:
                q[s] += sec.sign * mt._lock_delta[sec.diff]
            bias[s] = ap * bias[p] + bp * qdp * qdp
            dd = [[bp * rp[j] * rp[i] + ap * D[p][i][j] for j in range(k)] for i in range(k)]
            ku = [bp * rp[j] * bias[p] + ap * dku[p][j] + dbq[p] * rp[j] * qdp * qdp
                  + 2.0 * bp * qdp * dqd[p][j] for j in range(k)]
            kw = [ap * dkw[p][j] + 2.0 * bp * qdp * rp[j] for j in range(k)]
        R[s], D[s], dku[s], dkw[s] = row, dd, ku, kw
        dqd[s] = [sum(dd[i][j] * xl[n + coords[s][i]] for i in range(k)) for j in range(k)]
        e = section_slopes(mt._sec_ops[s], q[s])
        end[s] = e
        if e[6]:
            h = 1e-6 * max(1.0, abs(q[s]))
            ep = section_kinematics(mt._sec_ops[s], q[s] + h)
            em = section_kinematics(mt._sec_ops[s], q[s] - h)
            dbq[s] = (ep[2] - em[2]) / (2.0 * h)
            dcq[s] = (ep[4] - em[4]) / (2.0 * h)

    def dq_row(s: int, coef: float, out: FloatArray) -> None:
        for i, c in enumerate(coords[s]):
            out[c] += coef * R[s][i]

    def dqd_row(s: int, coef: float, out: FloatArray) -> None:
        for i, c in enumerate(coords[s]):
            out[c] += coef * dqd[s][i]
            out[n + c] += coef * R[s][i]

    qf = [0.0] * ns
    DQ = np.zeros((ns, nst))
    t_end = [0.0] * ns                  # torque at a section's end (the walk's t_end)
    dt_end = np.zeros((ns, nst))
    dpd = np.zeros(nst)
    dps = np.zeros(nst)
    dpf = np.zeros(nst)
    te, dte, dtep = torque_slopes(engine, t, xl[n], xl[0])
    qf[0] += te
    DQ[0, n] += dte
    DQ[0, 0] += dtep
    for law, left, right in mt.springs:
        a_l, b_l = end[left][1], end[left][2]
        th = end[left][0] - q[right]
        thd = a_l * qd[left] - qd[right]
        ts, k_th, k_d, _v, _pd = law.evaluate(th, thd)
        d1 = np.zeros(nst)
        d2 = np.zeros(nst)
        dq_row(left, a_l, d1)
        dq_row(right, -1.0, d1)
        dq_row(left, b_l * qd[left], d2)
        dqd_row(left, a_l, d2)
        dqd_row(right, -1.0, d2)
        qf[left] -= ts * a_l
        qf[right] += ts
        dq_row(left, -ts * b_l, DQ[left])
        dts = k_th * d1 + k_d * d2
        t_end[left] = ts
        dt_end[left] = dts
        DQ[left] -= a_l * dts
        DQ[right] += dts
        if law.d != 0.0:
            _e, de, dde = law.deflection(th)
            dpd += (law.d * dde * thd * thd) * d1 + (2.0 * law.d * de * thd) * d2
    for di in mt.diffs:
        cv = di.model.viscous if di.model.kind == 'viscous' else 0.0
        if cv == 0.0:
            continue
        slip = qd[di.left] - qd[di.right]
        tbias = cv * slip
        qf[di.left] -= tbias
        qf[di.right] += tbias
        d1 = np.zeros(nst)
        dqd_row(di.left, 1.0, d1)
        dqd_row(di.right, -1.0, d1)
        DQ[di.left] -= cv * d1
        DQ[di.right] += cv * d1
        dpd += (2.0 * cv * slip) * d1
    # tyres and body
    iv = mt._iv
    v = xl[iv]
    body = mt.body
    roll = body.rolling(v)
    th_v = math.tanh(v / body.speed_scale)
    droll = body.weight_normal * body.rolling_coeff * (1.0 - th_v * th_v) / body.speed_scale
    kap = xl[2 * n:2 * n + nw]
    grip = [w.tyre.mu * w.tyre.mf.shape(k) for w, k in zip(mt.wheels, kap)]
    dgrip = [w.tyre.mu * w.tyre.mf.slope(k) for w, k in zip(mt.wheels, kap)]
    shares = [w.share for w in mt.wheels]
    axles = [w.axle for w in mt.wheels]
    fz = body.normal_loads(shares, axles, grip, v)
    dfz = np.zeros((nw, nst))
    if body.cg_height is not None and body.wheelbase is not None and body.front_share is not None:
        w_n = body.weight_normal
        sf = body.front_share
        sr = 1.0 - sf
        gf = sum(s * y for s, y, a in zip(shares, grip, axles) if a > 0) / sf if sf > 0 else 0.0
        gr = sum(s * y for s, y, a in zip(shares, grip, axles) if a < 0) / sr if sr > 0 else 0.0
        h, el = body.cg_height, body.wheelbase
        den = el + h * (gf - gr)
        raw = (w_n * sf * el - h * (w_n * gr - roll)) / den
        fzf = min(max(raw, 0.0), w_n)
        d1 = np.zeros(nst)
        if 0.0 <= raw <= w_n:
            for i, (s, a) in enumerate(zip(shares, axles)):
                if a > 0 and sf > 0.0:
                    d1[2 * n + i] += -fzf * h * (s * dgrip[i] / sf) / den
                elif a < 0 and sr > 0.0:
                    dgr = s * dgrip[i] / sr
                    d1[2 * n + i] += (-h * w_n * dgr + fzf * h * dgr) / den
            d1[iv] += h * droll / den
        for i, (s, a) in enumerate(zip(shares, axles)):
            dfz[i] = d1 * (s / sf) if a > 0 else -d1 * (s / sr)
    dsum = np.zeros(nst)
    for i, w in enumerate(mt.wheels):
        s = w.section
        r = w.tyre.radius
        f, _st = w.tyre.force(kap[i], fz[i])
        d1 = np.zeros(nst)
        d2 = np.zeros(nst)
        if fz[i] > 0.0:
            d1 = grip[i] * dfz[i]
            d1[2 * n + i] += fz[i] * dgrip[i]
        a_w, b_w = end[s][1], end[s][2]
        om = a_w * qd[s]
        dq_row(s, b_w * qd[s], d2)
        dqd_row(s, a_w, d2)
        qf[s] -= f * r * a_w
        dq_row(s, -f * r * b_w, DQ[s])
        DQ[s] -= (r * a_w) * d1
        t_end[s] = f * r
        dt_end[s] = r * d1
        dps += d1 * (om * r - v) + (f * r) * d2
        dsum += d1
        J[2 * n + i] = (r / w.tyre.sigma) * d2
        dps[iv] -= f
        sv = 1.0 if v > 0.0 else (-1.0 if v < 0.0 else 0.0)
        J[2 * n + i, iv] += (-1.0 - sv * kap[i]) / w.tyre.sigma
        J[2 * n + i, 2 * n + i] += -abs(v) / w.tyre.sigma
    # mode forces
    for lk in mt.links:
        if lk.locked:
            continue
        left, right = lk.left, lk.right
        a_l, b_l = end[left][1], end[left][2]
        ts = 0.0
        if isinstance(lk.element, Clutch):
            ts = mt.mode.clutch[lk.element.name] * clutch_kinetic
            dq_row(left, ts * b_l * qd[left], dpf)
            dqd_row(left, ts * a_l, dpf)
            dqd_row(right, -ts, dpf)
        qf[left] -= ts * a_l
        qf[right] += ts
        dq_row(left, -ts * b_l, DQ[left])
        t_end[left] = ts
    for name, (_br, w) in mt.brakes.items():
        if name in mt.pinned:
            continue
        s = mt.wheels[w].section
        tq = mt.mode.brakes[name] * brake_kinetic[name]
        t_end[s] += tq
        qf[s] -= tq * end[s][1]
        dq_row(s, -tq * end[s][2], DQ[s])
        dq_row(s, tq * end[s][2] * qd[s], dpf)
        dqd_row(s, tq * end[s][1], dpf)
    if len(sensing) > 1:
        return central()
    if sensing:
        el, di, m_p = sensing[0]
        w_c, dw_c, x_c = _carrier_weights(mt, di, end, coords, dq_row)
        tc = 0.0
        for s in x_c:
            a_s = sum(R[s][i] * acc[c] for i, c in enumerate(coords[s])) + bias[s]
            tc += w_c[s] * (end[s][3] * a_s + end[s][4] * qd[s] * qd[s] + end[s][1] * t_end[s])
        tb_sense = m_p * (el.preload + el.torque_bias * abs(tc))
        s_c = 1.0 if tc >= 0.0 else -1.0
    for name, (el, d) in mt.packs.items():
        di = mt.diffs[d]
        if di.coord < 0:
            continue
        tbp = mt.mode.packs[name] * el.preload if el.torque_bias == 0.0 else tb_sense
        qf[di.left] -= tbp
        qf[di.right] += tbp
        dqd_row(di.left, tbp, dpf)
        dqd_row(di.right, -tbp, dpf)
    # accelerations, group by group
    g_b = [0.0] * n                     # d uddot / d T_b of a torque-sensing pack
    side: dict[int, float] = {}
    if sensing:
        side = {sensing[0][1].left: -1.0, sensing[0][1].right: 1.0}
    for (gc, secs), spiders in zip(mt._groups, mt._group_spiders):
        k = len(gc)
        rm = np.zeros((k, nst + 1))
        mg = [[0.0] * k for _ in range(k)]
        for s in secs:
            ms, cs_, dm = end[s][3], end[s][4], end[s][5]
            a_s = sum(R[s][i] * acc[gc[i]] for i in range(k))
            gen = qf[s] - cs_ * qd[s] * qd[s] - ms * bias[s]
            e_s = gen - ms * a_s
            hs = DQ[s].copy()
            dq_row(s, -(dcq[s] * qd[s] * qd[s] + dm * bias[s] + dm * a_s), hs)
            dqd_row(s, -2.0 * cs_ * qd[s], hs)
            for j in range(k):
                da = sum(D[s][i][j] * acc[gc[i]] for i in range(k))
                hs[gc[j]] -= ms * (dku[s][j] + da)
                hs[n + gc[j]] -= ms * dkw[s][j]
            for i in range(k):
                rm[i, :nst] += R[s][i] * hs
                if s in side:
                    rm[i, nst] += side[s] * R[s][i]
                for j in range(k):
                    rm[i, gc[j]] += D[s][i][j] * e_s
                    mg[i][j] += ms * R[s][i] * R[s][j]
        for i, p in spiders:
            mg[i][i] += p
        lo = [[0.0] * k for _ in range(k)]
        for i in range(k):                                   # Cholesky M = L L^T
            for j in range(i + 1):
                a = mg[i][j]
                for m in range(j):
                    a -= lo[i][m] * lo[j][m]
                lo[i][j] = math.sqrt(a) if i == j else a / lo[j][j]
        z = np.zeros((k, nst + 1))
        for i in range(k):
            a_v = rm[i].copy()
            for m in range(i):
                a_v -= lo[i][m] * z[m]
            z[i] = a_v / lo[i][i]
        for i in range(k - 1, -1, -1):
            a_v = z[i].copy()
            for m in range(i + 1, k):
                a_v -= lo[m][i] * z[m]
            z[i] = a_v / lo[i][i]
        for i in range(k):
            J[n + gc[i]] = z[i, :nst]
            g_b[gc[i]] = z[i, nst]
    if sensing:
        el, di, m_p = sensing[0]
        bb = 0.0
        dtc = np.zeros(nst)
        for s in x_c:
            gc = coords[s]
            k = len(gc)
            ms, cs_, dm = end[s][3], end[s][4], end[s][5]
            a_s = sum(R[s][i] * acc[gc[i]] for i in range(k)) + bias[s]
            xs = ms * a_s + cs_ * qd[s] * qd[s] + end[s][1] * t_end[s]
            bb += w_c[s] * ms * sum(R[s][i] * g_b[gc[i]] for i in range(k))
            dx = end[s][1] * dt_end[s]
            dq_row(s, dm * a_s + dcq[s] * qd[s] * qd[s] + end[s][2] * t_end[s], dx)
            dqd_row(s, 2.0 * cs_ * qd[s], dx)
            for i in range(k):
                dx += (ms * R[s][i]) * J[n + gc[i]]
            for j in range(k):
                da = sum(D[s][i][j] * acc[gc[i]] for i in range(k))
                dx[gc[j]] += ms * (dku[s][j] + da)
                dx[n + gc[j]] += ms * dkw[s][j]
            dtc += w_c[s] * dx + xs * dw_c[s]
        mk = m_p * el.torque_bias * s_c
        if abs(mk * bb) >= 1.0:            # no consistent sign: tm_eval's fallback branch
            return central()
        dtb = (mk / (1.0 - mk * bb)) * dtc
        for c in range(n):
            if g_b[c] != 0.0:
                J[n + c] += g_b[c] * dtb
        dpf += (qd[di.left] - qd[di.right]) * dtb
    for c in mt._pinned_coords:
        J[n + c] = 0.0
    for i in range(n):
        J[i, n + i] = 1.0
    res = body.resistance(v)
    dres = droll + body.air_density * body.drag_area * abs(v)
    J[iv] = dsum / body.mass
    J[iv, iv] -= dres / body.mass
    J[iv + 2] = dpd
    J[iv + 3] = dps
    J[iv + 5] = dpf
    c0 = mt.sections[0].coord
    w_e = xl[n + c0]
    J[iv + 1, n] += dte * w_e
    J[iv + 1, 0] += dtep * w_e
    J[iv + 1, n + c0] += te
    J[iv + 4, iv] = dres * v + res
    return J
