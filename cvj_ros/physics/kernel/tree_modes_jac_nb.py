"""Analytic Jacobian of a vehicle tree mode's right-hand side (``tree_modes_nb.tm_eval``).

d(mode rhs)/dy for y = [u, udot, kappa', v, W_engine, W_damp, W_slip, W_road, W_friction],
the chain rule through the tree's equations (cvj_ros.physics.tree module docstring):

* kinematics: a section's angle moves with its group's coordinates along its row,
  dq_s/du = r_s (q_s = phi_end(parent) + sign u_delta, r_s = a_p r_p + sign e_delta), so
  dr_s/du_j = b_p r_p[j] r_p + a_p dr_p/du_j, dqdot_s/dy = (dr_s/du) udot, r_s; the bias
  k_s = a_p k_p + b_p qdot_p^2 differentiated the same way; dM_s/dq = sum 2 J a b;
* forces: engine slopes (``sources_nb``), springs by ``rhs_nb.spring_eval``'s slopes, the
  viscous couplings, the tyres (magic formula slope, normal loads with load transfer
  differentiated in closed form, zero where clamped), the body; the mode's slipping clutch
  (-ts b_l dq_l), slipping brakes (-T_b b_w dq_w), a pack's bias; friction power;
* per group M uddot = f: d uddot/dy = M^-1 sum_s [dr_s/dy (G_s - M_s r_s.uddot)
  + r_s (dG_s/dy - dM_s/dq dq_s/dy r_s.uddot - M_s (dr_s/dy).uddot)], G_s = Q_s - C_s
  qdot_s^2 - M_s k_s, solved with the group's Cholesky factor; a pinned coordinate's rows 0;
* a slipping torque-sensing pack: T_b = m (T_p + k s T_c), s = sign T_c, T_c = T_L + T_R the
  backward walk's carrier torque = sum_s w_s (M_s qddot_s + C_s qdot_s^2 + a_s T_end,s) over
  both sides and the sections hung on them rigidly (w = 1 on a side, w_s = w_p a_p below),
  affine in T_b (T_c = T_c0 + B T_b, ``ModeTree._pack_bias``). Implicitly differentiated:
  dT_b/dy = m k s (dT_c/dy) / (1 - m k s B) with dT_c/dy at fixed T_b (the chain rule above,
  the acceleration rows at fixed T_b) and B = sum_s w_s M_s r_s.g, g = d uddot/dT_b (one
  more column in the group solve); then d uddot/dy += g dT_b/dy, dW_friction'/dy +=
  (omega_L - omega_R) dT_b/dy.

Difference quotients, as in the chain's ``modes_jac_nb.mode_jac``: db_end/dq and dC_s/dq need
a joint's third derivative (not in the joint contract): central differences of the section's
end kinematics, increment 1e-6 max(1, |q_s|). Where |m k B| >= 1 (no consistent sign:
:func:`tm_eval`'s fallback) or with two sensing packs, the whole Jacobian by central
differences of :func:`tm_eval` (increment 1e-6 max(1, |y_j|), ``tree_nb.tree_jac``).
The Python reference's twin is ``hybrid/tree_jac.tree_mode_jacobian`` (the same formula, term
by term).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from cvj_ros.physics.kernel import rhs_nb as _rhs
from cvj_ros.physics.kernel.layout import (
    H_NDOF, H_SPRING_F, H_TREE, OP_INERTIA, SEC_STRIDE, SPRING_STRIDE, TB_BODY_F, TB_DIFF,
    TB_GRP, TB_KMAX, TB_ND, TB_NG, TB_NS, TB_NSPR, TB_NW, TB_OPS, TB_SEC, TB_SPR, TB_WHEEL)
from cvj_ros.physics.kernel.modes_nb import op_eval
from cvj_ros.physics.kernel.tree_modes_nb import (BRAKE_STRIDE, LINK_STRIDE, MB_BRAKE,
                                                  MB_LINK, MB_NBRAKE, MB_NLINK, MB_NPACK,
                                                  MB_NWIT, MB_PACK, MB_SECX, PACK_STRIDE,
                                                  SECX_STRIDE, commands, tm_eval)

__all__ = ['tm_jac']


@njit(cache=True, inline='always')
def _section_end(ip, fp, ops, o, q):
    """(phi, a, b, M, C, dM/dq, has a joint op) at the end of the section with table row o
    at angle q (sections.section_kinematics; dM/dq = sum 2 J a b)."""
    phi, a, b, m, c, dm = q, 1.0, 0.0, 0.0, 0.0, 0.0
    hj = False
    for k in range(ip[o], ip[o + 1]):
        code = ip[ops + 2 * k]
        off = ip[ops + 2 * k + 1]
        if code == OP_INERTIA:
            jv = fp[off]
            m += jv * a * a
            c += jv * a * b
            dm += 2.0 * jv * a * b
        else:
            po, r, sl = op_eval(code, phi, fp, off)
            hj = True
            b = sl * a * a + r * b
            a = r * a
            phi = po
    return phi, a, b, m, c, dm, hj


@njit(cache=True)
def _central(t, y, ip, fp, J):
    """J by central differences of tm_eval, increment 1e-6 max(1, |y_j|)."""
    ns = y.shape[0]
    mb = ip[ip.shape[0] - 1]
    wv = np.empty(max(ip[mb + MB_NWIT], 1))
    yp = y.copy()
    fpl = np.empty(ns)
    fmi = np.empty(ns)
    for j in range(ns):
        h = 1e-6 * max(1.0, abs(y[j]))
        yp[j] = y[j] + h
        tm_eval(t, yp, ip, fp, fpl, wv, False)
        yp[j] = y[j] - h
        tm_eval(t, yp, ip, fp, fmi, wv, False)
        yp[j] = y[j]
        for i in range(ns):
            J[i, j] = (fpl[i] - fmi[i]) / (2.0 * h)


@njit(cache=True, inline='always')
def _add_dq(row, coef, s, R, CL, K, ip):
    """row += coef dq_s/dy (dq_s/du = r_s)."""
    cl = CL[s]
    for i in range(K[s]):
        row[ip[cl + i]] += coef * R[s, i]


@njit(cache=True, inline='always')
def _add_dqd(row, coef, s, R, DQD, CL, K, ip, n):
    """row += coef dqdot_s/dy ((dr_s/du) udot on u, r_s on udot)."""
    cl = CL[s]
    for i in range(K[s]):
        c = ip[cl + i]
        row[c] += coef * DQD[s, i]
        row[n + c] += coef * R[s, i]


@njit(cache=True)
def tm_jac(t, y, ip, fp, J):
    """d(tm_eval)/dy at (t, y) into J (n_state x n_state, overwritten); module docstring."""
    n = ip[H_NDOF]
    tb = ip[H_TREE]
    ns = ip[tb + TB_NS]
    nw = ip[tb + TB_NW]
    kmax = ip[tb + TB_KMAX]
    sec = ip[tb + TB_SEC]
    ops = ip[tb + TB_OPS]
    mb = ip[ip.shape[0] - 1]
    sx = ip[mb + MB_SECX]
    nst = y.shape[0]
    for i in range(nst):
        for j in range(nst):
            J[i, j] = 0.0
    prow = -1                                  # the slipping torque-sensing pack's row
    for pi in range(ip[mb + MB_NPACK]):
        row = ip[mb + MB_PACK] + PACK_STRIDE * pi
        if ip[row + 2] == 0 and fp[ip[row + 4] + 1] != 0.0:
            if prow >= 0:
                _central(t, y, ip, fp, J)
                return
            prow = row
    dy = np.empty(nst)
    wv = np.empty(max(ip[mb + MB_NWIT], 1))
    tm_eval(t, y, ip, fp, dy, wv, False)        # uddot; sets the throttle
    ck, _cs, fb = commands(t, ip, fp)
    # per section: q, qdot, bias, phi, a, b, M, C, dM/dq, db/dq, dC/dq, Q
    S = np.zeros((12, ns))
    R = np.zeros((ns, max(kmax, 1)))
    D = np.zeros((ns, max(kmax, 1), max(kmax, 1)))
    DQD = np.zeros((ns, max(kmax, 1)))
    DKU = np.zeros((ns, max(kmax, 1)))
    DKW = np.zeros((ns, max(kmax, 1)))
    CL = np.zeros(ns, dtype=np.int64)
    K = np.zeros(ns, dtype=np.int64)
    DQ = np.zeros((ns, nst))
    TE = np.zeros(ns)                          # torque at a section's end (the walk's t_end)
    DTE = np.zeros((ns, nst))
    for s in range(ns):
        o = sec + SEC_STRIDE * s
        x = sx + SECX_STRIDE * s
        k = ip[x + 2]
        cl = ip[x + 3]
        K[s] = k
        CL[s] = cl
        parent = ip[o + 2]
        if parent < 0:
            c = ip[o + 5]
            S[0, s] = y[c]
            S[1, s] = y[n + c]
            R[s, 0] = 1.0
        else:
            ap = S[4, parent]
            bp = S[5, parent]
            qdp = S[1, parent]
            for i in range(k):
                R[s, i] = ap * R[parent, i]
            S[0, s] = S[3, parent]
            S[1, s] = ap * qdp
            loc = ip[o + 4]
            if loc >= 0:
                sign = ip[o + 3]
                cd = ip[o + 6]
                S[0, s] += sign * y[cd]
                S[1, s] += sign * y[n + cd]
                R[s, loc] += sign
            else:
                qo = ip[x + 4]
                if qo >= 0:
                    S[0, s] += fp[qo]
            S[2, s] = ap * S[2, parent] + bp * qdp * qdp
            dbp = S[9, parent]
            for j in range(k):
                rpj = R[parent, j]
                for i in range(k):
                    D[s, i, j] = bp * rpj * R[parent, i] + ap * D[parent, i, j]
                DKU[s, j] = (bp * rpj * S[2, parent] + ap * DKU[parent, j]
                             + dbp * rpj * qdp * qdp + 2.0 * bp * qdp * DQD[parent, j])
                DKW[s, j] = ap * DKW[parent, j] + 2.0 * bp * qdp * R[parent, j]
        for j in range(k):
            acc = 0.0
            for i in range(k):
                acc += D[s, i, j] * y[n + ip[cl + i]]
            DQD[s, j] = acc
        q = S[0, s]
        phi, a, b, m, c, dm, hj = _section_end(ip, fp, ops, o, q)
        S[3, s] = phi
        S[4, s] = a
        S[5, s] = b
        S[6, s] = m
        S[7, s] = c
        S[8, s] = dm
        if hj:
            h = 1e-6 * max(1.0, abs(q))
            _p1, _a1, b1, _m1, c1, _d1, _h1 = _section_end(ip, fp, ops, o, q + h)
            _p2, _a2, b2, _m2, c2, _d2, _h2 = _section_end(ip, fp, ops, o, q - h)
            S[9, s] = (b1 - b2) / (2.0 * h)
            S[10, s] = (c1 - c2) / (2.0 * h)
    # forces: values into S[11], derivatives into DQ; power derivatives
    dpd = np.zeros(nst)
    dps = np.zeros(nst)
    dpf = np.zeros(nst)
    d1 = np.zeros(nst)
    d2 = np.zeros(nst)
    te, dte, dtep = _rhs.engine_torque(t, y, ip, fp)
    S[11, 0] += te
    DQ[0, n] += dte
    DQ[0, 0] += dtep
    spr = ip[tb + TB_SPR]
    sp0 = ip[H_SPRING_F]
    for k in range(ip[tb + TB_NSPR]):
        left = ip[spr + 2 * k]
        right = ip[spr + 2 * k + 1]
        a_l = S[4, left]
        b_l = S[5, left]
        qd_l = S[1, left]
        th = S[3, left] - S[0, right]
        thd = a_l * qd_l - S[1, right]
        off = sp0 + SPRING_STRIDE * k
        ts, k_th, k_d, _pd = _rhs.spring_eval(th, thd, fp, off)
        for i in range(nst):
            d1[i] = 0.0
            d2[i] = 0.0
        _add_dq(d1, a_l, left, R, CL, K, ip)                 # dtheta/dy
        _add_dq(d1, -1.0, right, R, CL, K, ip)
        _add_dq(d2, b_l * qd_l, left, R, CL, K, ip)          # dthetadot/dy
        _add_dqd(d2, a_l, left, R, DQD, CL, K, ip, n)
        _add_dqd(d2, -1.0, right, R, DQD, CL, K, ip, n)
        S[11, left] -= ts * a_l
        S[11, right] += ts
        _add_dq(DQ[left], -ts * b_l, left, R, CL, K, ip)
        TE[left] = ts
        for i in range(nst):
            dts = k_th * d1[i] + k_d * d2[i]
            DQ[left, i] -= a_l * dts
            DQ[right, i] += dts
            DTE[left, i] = dts
        dd = fp[off + 1]
        if dd != 0.0:
            _e, de, dde = _rhs.spring_deflection(th, fp[off + 3], fp[off + 4])
            p_th = dd * dde * thd * thd
            p_thd = 2.0 * dd * de * thd
            for i in range(nst):
                dpd[i] += p_th * d1[i] + p_thd * d2[i]
    dif = ip[tb + TB_DIFF]
    for k in range(ip[tb + TB_ND]):
        left = ip[dif + 3 * k]
        right = ip[dif + 3 * k + 1]
        cv = fp[ip[dif + 3 * k + 2]]
        if cv == 0.0:
            continue
        slip = S[1, left] - S[1, right]
        tbias = cv * slip
        S[11, left] -= tbias
        S[11, right] += tbias
        for i in range(nst):
            d1[i] = 0.0
        _add_dqd(d1, 1.0, left, R, DQD, CL, K, ip, n)
        _add_dqd(d1, -1.0, right, R, DQD, CL, K, ip, n)
        for i in range(nst):
            DQ[left, i] -= cv * d1[i]
            DQ[right, i] += cv * d1[i]
            dpd[i] += 2.0 * cv * slip * d1[i]
    # tyres and body
    iv = 2 * n + nw
    v = y[iv]
    whl = ip[tb + TB_WHEEL]
    bf = ip[tb + TB_BODY_F]
    w_n = fp[bf + 1]
    th_v = math.tanh(v / fp[bf + 5])
    roll = w_n * fp[bf + 2] * th_v
    droll = w_n * fp[bf + 2] * (1.0 - th_v * th_v) / fp[bf + 5]
    grip = np.zeros(max(nw, 1))
    dgrip = np.zeros(max(nw, 1))
    for i in range(nw):
        wf = ip[whl + 2 * i + 1]
        bb = fp[wf + 2]
        ee = fp[wf + 4]
        bk = bb * y[2 * n + i]
        x = bk - ee * (bk - math.atan(bk))
        dx = bb * (1.0 - ee) + ee * bb / (1.0 + bk * bk)
        cc = fp[wf + 3]
        grip[i] = fp[wf] * math.sin(cc * math.atan(x))
        dgrip[i] = fp[wf] * (math.cos(cc * math.atan(x)) * cc * dx / (1.0 + x * x))
    fz = np.zeros(max(nw, 1))
    dfz = np.zeros((max(nw, 1), nst))
    if fp[bf + 6] == 0.0:
        for i in range(nw):
            fz[i] = fp[ip[whl + 2 * i + 1] + 6] * w_n
    else:
        sf = fp[bf + 7]
        sr = 1.0 - sf
        gf = 0.0
        gr = 0.0
        for i in range(nw):
            wf = ip[whl + 2 * i + 1]
            if fp[wf + 7] > 0.0:
                gf += fp[wf + 6] * grip[i]
        for i in range(nw):
            wf = ip[whl + 2 * i + 1]
            if fp[wf + 7] < 0.0:
                gr += fp[wf + 6] * grip[i]
        gf = gf / sf if sf > 0.0 else 0.0
        gr = gr / sr if sr > 0.0 else 0.0
        h = fp[bf + 8]
        el = fp[bf + 9]
        den = el + h * (gf - gr)
        raw = (w_n * sf * el - h * (w_n * gr - roll)) / den
        fzf = min(max(raw, 0.0), w_n)
        inside = 0.0 <= raw <= w_n
        for i in range(nst):
            d1[i] = 0.0                                      # dfz_front/dy
        if inside:
            for i in range(nw):
                wf = ip[whl + 2 * i + 1]
                if fp[wf + 7] > 0.0 and sf > 0.0:
                    dgf = fp[wf + 6] * dgrip[i] / sf
                    d1[2 * n + i] += -fzf * h * dgf / den
                elif fp[wf + 7] < 0.0 and sr > 0.0:
                    dgr = fp[wf + 6] * dgrip[i] / sr
                    d1[2 * n + i] += (-h * w_n * dgr + fzf * h * dgr) / den
            d1[iv] += h * droll / den
        fzr = w_n - fzf
        for i in range(nw):
            wf = ip[whl + 2 * i + 1]
            if fp[wf + 7] > 0.0:
                fz[i] = fzf * fp[wf + 6] / sf
                for j in range(nst):
                    dfz[i, j] = d1[j] * fp[wf + 6] / sf
            else:
                fz[i] = fzr * fp[wf + 6] / sr
                for j in range(nst):
                    dfz[i, j] = -d1[j] * fp[wf + 6] / sr
    dsum = np.zeros(nst)
    for i in range(nw):
        s = ip[whl + 2 * i]
        wf = ip[whl + 2 * i + 1]
        kap = y[2 * n + i]
        r = fp[wf + 1]
        f = 0.0
        for j in range(nst):
            d1[j] = 0.0                                      # dF_x/dy
            d2[j] = 0.0                                      # domega/dy
        if fz[i] > 0.0:
            bk = fp[wf + 2] * kap
            x = bk - fp[wf + 4] * (bk - math.atan(bk))
            f = fp[wf] * fz[i] * math.sin(fp[wf + 3] * math.atan(x))
            for j in range(nst):
                d1[j] = grip[i] * dfz[i, j]
            d1[2 * n + i] += fz[i] * dgrip[i]
        a_w = S[4, s]
        b_w = S[5, s]
        qd = S[1, s]
        om = a_w * qd
        _add_dq(d2, b_w * qd, s, R, CL, K, ip)
        _add_dqd(d2, a_w, s, R, DQD, CL, K, ip, n)
        S[11, s] -= f * r * a_w
        _add_dq(DQ[s], -f * r * b_w, s, R, CL, K, ip)
        TE[s] = f * r
        for j in range(nst):
            DQ[s, j] -= r * a_w * d1[j]
            DTE[s, j] = r * d1[j]
            dps[j] += d1[j] * (om * r - v) + f * r * d2[j]
            dsum[j] += d1[j]
            J[2 * n + i, j] = r * d2[j] / fp[wf + 5]
        dps[iv] -= f
        sv = 1.0 if v > 0.0 else (-1.0 if v < 0.0 else 0.0)
        J[2 * n + i, iv] += (-1.0 - sv * kap) / fp[wf + 5]
        J[2 * n + i, 2 * n + i] += -abs(v) / fp[wf + 5]
    # mode forces (ModeTree.evaluate)
    for i in range(ip[mb + MB_NLINK]):
        row = ip[mb + MB_LINK] + LINK_STRIDE * i
        if ip[row + 2] != 0:
            continue
        left = ip[row]
        right = ip[row + 1]
        a_l = S[4, left]
        ts = 0.0
        if ip[row + 3] != 0:
            ts = ip[row + 4] * ck
            _add_dq(dpf, ts * S[5, left] * S[1, left], left, R, CL, K, ip)
            _add_dqd(dpf, ts * a_l, left, R, DQD, CL, K, ip, n)
            _add_dqd(dpf, -ts, right, R, DQD, CL, K, ip, n)
        S[11, left] -= ts * a_l
        S[11, right] += ts
        _add_dq(DQ[left], -ts * S[5, left], left, R, CL, K, ip)
        TE[left] = ts
    for bi in range(ip[mb + MB_NBRAKE]):
        row = ip[mb + MB_BRAKE] + BRAKE_STRIDE * bi
        if ip[row + 2] != 0:
            continue
        s = ip[row + 1]
        pk = ip[row + 4]
        tq = ip[row + 3] * (fp[pk + 1] * fp[pk + 2] * fp[pk + 3] * fb)
        TE[s] += tq
        S[11, s] -= tq * S[4, s]
        _add_dq(DQ[s], -tq * S[5, s], s, R, CL, K, ip)
        _add_dq(dpf, tq * S[5, s] * S[1, s], s, R, CL, K, ip)
        _add_dqd(dpf, tq * S[4, s], s, R, DQD, CL, K, ip, n)
    # a torque-sensing pack's carrier torque T_c = sum_s w_s X_s (the backward walk), its
    # bias T_b = m (T_p + k |T_c|) (tree_modes_nb.tm_eval's consistent sign s = sign T_c)
    WC = np.zeros(ns)
    DW = np.zeros((ns, nst))
    INS = np.zeros(ns, dtype=np.bool_)
    tb_sense = 0.0
    s_c = 1.0
    if prow >= 0:
        pl = ip[prow]
        pr = ip[prow + 1]
        tc = 0.0
        for s in range(ns):
            parent = ip[sec + SEC_STRIDE * s + 2]
            if s == pl or s == pr:
                WC[s] = 1.0
            elif parent >= 0 and INS[parent]:
                WC[s] = WC[parent] * S[4, parent]
                for j in range(nst):
                    DW[s, j] = S[4, parent] * DW[parent, j]
                _add_dq(DW[s], WC[parent] * S[5, parent], parent, R, CL, K, ip)
            else:
                continue
            INS[s] = True
            a_s = 0.0
            for i in range(K[s]):
                a_s += R[s, i] * dy[n + ip[CL[s] + i]]
            a_s += S[2, s]
            tc += WC[s] * (S[6, s] * a_s + S[7, s] * S[1, s] * S[1, s] + S[4, s] * TE[s])
        tb_sense = ip[prow + 3] * (fp[ip[prow + 4]] + fp[ip[prow + 4] + 1] * abs(tc))
        s_c = 1.0 if tc >= 0.0 else -1.0
    for pi in range(ip[mb + MB_NPACK]):
        row = ip[mb + MB_PACK] + PACK_STRIDE * pi
        if ip[row + 2] != 0:
            continue
        left = ip[row]
        right = ip[row + 1]
        tbp = ip[row + 3] * fp[ip[row + 4]] if fp[ip[row + 4] + 1] == 0.0 else tb_sense
        S[11, left] -= tbp
        S[11, right] += tbp
        _add_dqd(dpf, tbp, left, R, DQD, CL, K, ip, n)
        _add_dqd(dpf, -tbp, right, R, DQD, CL, K, ip, n)
    # accelerations, group by group
    kk = max(kmax, 1)
    Rm = np.zeros((kk, nst + 1))               # last column: d/dT_b (unit bias)
    Mg = np.zeros((kk, kk))
    L = np.zeros((kk, kk))
    Z = np.zeros((kk, nst + 1))
    G = np.zeros(n)                            # d uddot / d T_b
    p = ip[tb + TB_GRP]
    for _g in range(ip[tb + TB_NG]):
        k = ip[p]
        nsec = ip[p + 1]
        nsp = ip[p + 2]
        cs = p + 3
        ss = cs + k
        spd = ss + nsec
        p = spd + 2 * nsp
        for i in range(k):
            for j in range(nst + 1):
                Rm[i, j] = 0.0
            for j in range(k):
                Mg[i, j] = 0.0
        for jj in range(nsec):
            s = ip[ss + jj]
            ms = S[6, s]
            qd = S[1, s]
            a_s = 0.0
            for i in range(k):
                a_s += R[s, i] * dy[n + ip[cs + i]]
            gen = S[11, s] - S[7, s] * qd * qd - ms * S[2, s]
            e_s = gen - ms * a_s
            for j in range(nst):
                d1[j] = DQ[s, j]                             # H_s
            _add_dq(d1, -(S[10, s] * qd * qd + S[8, s] * S[2, s] + S[8, s] * a_s), s, R, CL, K, ip)
            _add_dqd(d1, -2.0 * S[7, s] * qd, s, R, DQD, CL, K, ip, n)
            for j in range(k):
                c = ip[cs + j]
                da = 0.0
                for i in range(k):
                    da += D[s, i, j] * dy[n + ip[cs + i]]
                d1[c] -= ms * (DKU[s, j] + da)
                d1[n + c] -= ms * DKW[s, j]
            for i in range(k):
                ri = R[s, i]
                for j in range(nst):
                    Rm[i, j] += ri * d1[j]
                if prow >= 0 and s == ip[prow]:
                    Rm[i, nst] += -1.0 * ri
                elif prow >= 0 and s == ip[prow + 1]:
                    Rm[i, nst] += 1.0 * ri
                for j in range(k):
                    Rm[i, ip[cs + j]] += D[s, i, j] * e_s
                    Mg[i, j] += ms * ri * R[s, j]
        for jj in range(nsp):
            i = ip[spd + 2 * jj]
            Mg[i, i] += fp[ip[spd + 2 * jj + 1]]
        for i in range(k):                                   # Cholesky M = L L^T
            for j in range(i + 1):
                a = Mg[i, j]
                for m in range(j):
                    a -= L[i, m] * L[j, m]
                L[i, j] = math.sqrt(a) if i == j else a / L[j, j]
        for c in range(nst + 1):
            for i in range(k):
                a = Rm[i, c]
                for m in range(i):
                    a -= L[i, m] * Z[m, c]
                Z[i, c] = a / L[i, i]
            for i in range(k - 1, -1, -1):
                a = Z[i, c]
                for m in range(i + 1, k):
                    a -= L[m, i] * Z[m, c]
                Z[i, c] = a / L[i, i]
        for i in range(k):
            for c in range(nst):
                J[n + ip[cs + i], c] = Z[i, c]
            G[ip[cs + i]] = Z[i, nst]
    if prow >= 0:
        # dT_b/dy = m k s (dT_c/dy at fixed T_b) / (1 - m k s B), B = dT_c/dT_b
        bb = 0.0
        dtc = np.zeros(nst)
        for s in range(ns):
            if not INS[s]:
                continue
            cl = CL[s]
            k = K[s]
            ms = S[6, s]
            qd = S[1, s]
            a_s = 0.0
            for i in range(k):
                a_s += R[s, i] * dy[n + ip[cl + i]]
            a_s += S[2, s]
            xs = ms * a_s + S[7, s] * qd * qd + S[4, s] * TE[s]
            gs = 0.0
            for i in range(k):
                gs += R[s, i] * G[ip[cl + i]]
            bb += WC[s] * ms * gs
            for j in range(nst):
                d1[j] = S[4, s] * DTE[s, j]
            _add_dq(d1, S[8, s] * a_s + S[10, s] * qd * qd + S[5, s] * TE[s], s, R, CL, K, ip)
            _add_dqd(d1, 2.0 * S[7, s] * qd, s, R, DQD, CL, K, ip, n)
            for i in range(k):
                ci = n + ip[cl + i]
                for j in range(nst):
                    d1[j] += (ms * R[s, i]) * J[ci, j]
            for j in range(k):
                c = ip[cl + j]
                da = 0.0
                for i in range(k):
                    da += D[s, i, j] * dy[n + ip[cl + i]]
                d1[c] += ms * (DKU[s, j] + da)
                d1[n + c] += ms * DKW[s, j]
            for j in range(nst):
                dtc[j] += WC[s] * d1[j] + xs * DW[s, j]
        mk = ip[prow + 3] * fp[ip[prow + 4] + 1] * s_c
        if abs(mk * bb) >= 1.0:                # no consistent sign: tm_eval's fallback
            _central(t, y, ip, fp, J)
            return
        f = mk / (1.0 - mk * bb)
        for c in range(n):
            if G[c] != 0.0:
                for j in range(nst):
                    J[n + c, j] += G[c] * (f * dtc[j])
        s_lr = S[1, ip[prow]] - S[1, ip[prow + 1]]
        for j in range(nst):
            dpf[j] += s_lr * (f * dtc[j])
    for bi in range(ip[mb + MB_NBRAKE]):
        row = ip[mb + MB_BRAKE] + BRAKE_STRIDE * bi
        if ip[row + 2] != 0:
            c = ip[sec + SEC_STRIDE * ip[row + 1] + 5]
            for j in range(nst):
                J[n + c, j] = 0.0
    for i in range(n):
        J[i, n + i] = 1.0
    res = roll + fp[bf + 3] + fp[bf + 4] * v * abs(v)
    dres = droll + 2.0 * fp[bf + 4] * abs(v)
    for j in range(nst):
        J[iv, j] = dsum[j] / fp[bf]
        J[iv + 2, j] = dpd[j]
        J[iv + 3, j] = dps[j]
        J[iv + 5, j] = dpf[j]
    J[iv, iv] -= dres / fp[bf]
    c0 = ip[sec + 5]
    w_e = y[n + c0]
    J[iv + 1, n] += dte * w_e
    J[iv + 1, 0] += dtep * w_e
    J[iv + 1, n + c0] += te
    J[iv + 4, iv] = dres * v + res
