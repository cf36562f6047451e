"""Compiled right-hand side of a vehicle scene's branching driveline.

The equations of the readable oracle ``TreeDriveline._rhs`` (cvj_ros/physics/tree.py module
docstring), evaluated from the tree tables of ``kernel/layout.py`` (``H_TREE``): per section
the chain rule over its ops (rhs_nb.section's loop), its group-local row r_s and bias
acceleration k_s = a_end k_parent + b_end qdot_parent^2; generalised forces from the engine,
springs (rhs_nb.spring_torque), viscous couplings and tyres (magic formula on the relaxed slip,
normal loads with load transfer in closed form, cvj_ros.physics.vehicle); per group the SPD
system [sum_s M_s r_s r_s^T + sum_d P_d e_d e_d^T] uddot = sum_s r_s (Q_s - C_s qdot_s^2 - M_s k_s)
solved by a plain-loop Cholesky, in the oracle's order of operations (same bytes). No
allocation (scratch on the stack: rhs_nb.rhs is compiled without NRT), no BLAS.
Reached through rhs_nb.rhs / rhs_nb.jac, which dispatch on ``ip[H_TREE]``.
"""
from __future__ import annotations

import math

from numba import njit

from cvj_ros.physics.kernel import rhs_nb as _rhs
from cvj_ros.physics.kernel.borrow_nb import stack_zeros_2d
from cvj_ros.physics.kernel.joints_nb import joint_eval
from cvj_ros.physics.kernel.layout import (
    H_ENERGY, H_NDOF, H_SPRING_F, H_TREE, OP_INERTIA, SEC_STRIDE, SPRING_STRIDE, TB_BODY_F,
    TB_DIFF, TB_GRP, TB_KMAX, TB_ND, TB_NG, TB_NS, TB_NSPR, TB_NW, TB_OPS, TB_SEC, TB_SPR,
    TB_WHEEL)

# scratch rows (stack_zeros_2d), each of width max(sections, wheels, kmax)
R_Q, R_QD, R_BIAS, R_QF, R_PHI, R_A, R_B, R_M, R_C, R_FZ, R_GRIP, R_FF, R_YY, R_XX = range(14)
N_ROWS = 14     # then the sections' rows r_s (ns), the group matrix (kmax), its factor (kmax)


@njit(cache=True, _nrt=False)
def tree_rhs(t, y, ip, fp, dy):
    """dy/dt (in place) of a vehicle scene's state y (tree.py: [u, udot, kappa', v, work])."""
    n = ip[H_NDOF]
    tb = ip[H_TREE]
    ns = ip[tb + TB_NS]
    nw = ip[tb + TB_NW]
    kmax = ip[tb + TB_KMAX]
    sec = ip[tb + TB_SEC]
    ops = ip[tb + TB_OPS]
    sc = stack_zeros_2d(N_ROWS + ns + 2 * kmax, max(ns, max(nw, kmax)))
    r0 = N_ROWS               # row of section s's r_s: r0 + s
    m0 = N_ROWS + ns          # group matrix rows
    l0 = m0 + kmax            # Cholesky factor rows
    # kinematics in tree order (a parent precedes its children)
    for s in range(ns):
        o = sec + SEC_STRIDE * s
        parent = ip[o + 2]
        if parent < 0:
            c = ip[o + 5]
            sc[R_Q, s] = y[c]
            sc[R_QD, s] = y[n + c]
            sc[r0 + s, 0] = 1.0
        else:
            ap = sc[R_A, parent]
            for i in range(kmax):
                sc[r0 + s, i] = ap * sc[r0 + parent, i]
            sc[R_Q, s] = sc[R_PHI, parent]
            sc[R_QD, s] = ap * sc[R_QD, parent]
            loc = ip[o + 4]
            if loc >= 0:
                sign = ip[o + 3]
                cd = ip[o + 6]
                sc[R_Q, s] += sign * y[cd]
                sc[R_QD, s] += sign * y[n + cd]
                sc[r0 + s, loc] += sign
            qdp = sc[R_QD, parent]
            sc[R_BIAS, s] = ap * sc[R_BIAS, parent] + sc[R_B, parent] * qdp * qdp
        phi, a, b, m, cc = sc[R_Q, s], 1.0, 0.0, 0.0, 0.0
        for k in range(ip[o], ip[o + 1]):
            code = ip[ops + 2 * k]
            off = ip[ops + 2 * k + 1]
            if code == OP_INERTIA:
                jv = fp[off]
                m += jv * a * a
                cc += jv * a * b
            else:
                po, r, sl = joint_eval(code, phi, fp, off)
                b = sl * a * a + r * b
                a = r * a
                phi = po
        sc[R_PHI, s] = phi
        sc[R_A, s] = a
        sc[R_B, s] = b
        sc[R_M, s] = m
        sc[R_C, s] = cc
    # generalised forces
    te, _dte, _dtep = _rhs.engine_torque(t, y, ip, fp)
    sc[R_QF, 0] += te
    p_damp = 0.0
    spr = ip[tb + TB_SPR]
    sp0 = ip[H_SPRING_F]
    for k in range(ip[tb + TB_NSPR]):
        left = ip[spr + 2 * k]
        right = ip[spr + 2 * k + 1]
        a_l = sc[R_A, left]
        th = sc[R_PHI, left] - sc[R_Q, right]
        thd = a_l * sc[R_QD, left] - sc[R_QD, right]
        ts, pd = _rhs.spring_torque(th, thd, fp, sp0 + SPRING_STRIDE * k)
        p_damp += pd
        sc[R_QF, left] -= ts * a_l
        sc[R_QF, right] += ts
    dif = ip[tb + TB_DIFF]
    for k in range(ip[tb + TB_ND]):
        left = ip[dif + 3 * k]
        right = ip[dif + 3 * k + 1]
        slip = sc[R_QD, left] - sc[R_QD, right]
        tbias = fp[ip[dif + 3 * k + 2]] * slip
        if tbias != 0.0:
            sc[R_QF, left] -= tbias
            sc[R_QF, right] += tbias
            p_damp += tbias * slip
    # tyres and body (vehicle.VehicleBody.normal_loads, tyre.Tyre)
    iv = 2 * n + nw
    v = y[iv]
    whl = ip[tb + TB_WHEEL]
    bf = ip[tb + TB_BODY_F]
    w_n = fp[bf + 1]
    roll = w_n * fp[bf + 2] * math.tanh(v / fp[bf + 5])
    for i in range(nw):
        wf = ip[whl + 2 * i + 1]
        bk = fp[wf + 2] * y[2 * n + i]
        x = bk - fp[wf + 4] * (bk - math.atan(bk))
        sc[R_GRIP, i] = fp[wf] * math.sin(fp[wf + 3] * math.atan(x))
    if fp[bf + 6] == 0.0:
        for i in range(nw):
            sc[R_FZ, i] = fp[ip[whl + 2 * i + 1] + 6] * w_n
    else:
        sf = fp[bf + 7]
        sr = 1.0 - sf
        gf = 0.0
        gr = 0.0
        for i in range(nw):
            wf = ip[whl + 2 * i + 1]
            if fp[wf + 7] > 0.0:
                gf += fp[wf + 6] * sc[R_GRIP, i]
        for i in range(nw):
            wf = ip[whl + 2 * i + 1]
            if fp[wf + 7] < 0.0:
                gr += fp[wf + 6] * sc[R_GRIP, i]
        gf = gf / sf if sf > 0.0 else 0.0
        gr = gr / sr if sr > 0.0 else 0.0
        h = fp[bf + 8]
        el = fp[bf + 9]
        fzf = (w_n * sf * el - h * (w_n * gr - roll)) / (el + h * (gf - gr))
        fzf = min(max(fzf, 0.0), w_n)
        fzr = w_n - fzf
        for i in range(nw):
            wf = ip[whl + 2 * i + 1]
            sc[R_FZ, i] = fzf * fp[wf + 6] / sf if fp[wf + 7] > 0.0 else fzr * fp[wf + 6] / sr
    sum_fx = 0.0
    p_slip = 0.0
    for i in range(nw):
        s = ip[whl + 2 * i]
        wf = ip[whl + 2 * i + 1]
        kap = y[2 * n + i]
        fz = sc[R_FZ, i]
        f = 0.0
        if fz > 0.0:
            bk = fp[wf + 2] * kap
            x = bk - fp[wf + 4] * (bk - math.atan(bk))
            f = fp[wf] * fz * math.sin(fp[wf + 3] * math.atan(x))
        a_w = sc[R_A, s]
        om = a_w * sc[R_QD, s]
        r = fp[wf + 1]
        sc[R_QF, s] -= f * r * a_w
        p_slip += f * (om * r - v)
        sum_fx += f
        dy[2 * n + i] = (om * r - v - abs(v) * kap) / fp[wf + 5]
    # accelerations, group by group
    p = ip[tb + TB_GRP]
    for _g in range(ip[tb + TB_NG]):
        k = ip[p]
        nsec = ip[p + 1]
        nsp = ip[p + 2]
        cs = p + 3
        ss = cs + k
        spd = ss + nsec
        p = spd + 2 * nsp
        if k == 1:
            mg = 0.0
            fg = 0.0
            for j in range(nsec):
                s = ip[ss + j]
                ms = sc[R_M, s]
                r = sc[r0 + s, 0]
                qd = sc[R_QD, s]
                mg += ms * r * r
                fg += r * (sc[R_QF, s] - sc[R_C, s] * qd * qd - ms * sc[R_BIAS, s])
            dy[n + ip[cs]] = fg / mg
            continue
        for i in range(k):
            sc[R_FF, i] = 0.0
            for j in range(k):
                sc[m0 + i, j] = 0.0
        for j in range(nsec):
            s = ip[ss + j]
            ms = sc[R_M, s]
            qd = sc[R_QD, s]
            gen = sc[R_QF, s] - sc[R_C, s] * qd * qd - ms * sc[R_BIAS, s]
            for i in range(k):
                ri = sc[r0 + s, i]
                if ri == 0.0:
                    continue
                sc[R_FF, i] += ri * gen
                for jj in range(i + 1):        # the lower triangle (all Cholesky reads)
                    sc[m0 + i, jj] += ms * ri * sc[r0 + s, jj]
        for j in range(nsp):
            i = ip[spd + 2 * j]
            sc[m0 + i, i] += fp[ip[spd + 2 * j + 1]]
        for i in range(k):                      # tree._cholesky_solve
            for j in range(i + 1):
                acc = sc[m0 + i, j]
                for kk in range(j):
                    acc -= sc[l0 + i, kk] * sc[l0 + j, kk]
                sc[l0 + i, j] = math.sqrt(acc) if i == j else acc / sc[l0 + j, j]
        for i in range(k):
            acc = sc[R_FF, i]
            for kk in range(i):
                acc -= sc[l0 + i, kk] * sc[R_YY, kk]
            sc[R_YY, i] = acc / sc[l0 + i, i]
        for i in range(k - 1, -1, -1):
            acc = sc[R_YY, i]
            for kk in range(i + 1, k):
                acc -= sc[l0 + kk, i] * sc[R_XX, kk]
            sc[R_XX, i] = acc / sc[l0 + i, i]
        for i in range(k):
            dy[n + ip[cs + i]] = sc[R_XX, i]
    for i in range(n):
        dy[i] = y[n + i]
    res = roll + fp[bf + 3] + fp[bf + 4] * v * abs(v)
    dy[iv] = (sum_fx - res) / fp[bf]
    if ip[H_ENERGY] != 0:
        dy[iv + 1] = te * y[n]
        dy[iv + 2] = p_damp
        dy[iv + 3] = p_slip
        dy[iv + 4] = res * v


@njit(cache=True, _nrt=False)
def tree_jac(t, y, ip, fp, J):
    """d(rhs)/dy into J by central differences, h = 1e-6 max(1, |y_j|): the oracle's
    TreeDriveline.jacobian_fd (the analytic Jacobian of the tree is not written)."""
    ns = y.shape[0]
    w = stack_zeros_2d(4, ns)        # y + h e_j, y - h e_j, f(+), f(-)
    for i in range(ns):
        w[0, i] = y[i]
        w[1, i] = y[i]
    for j in range(ns):
        h = 1e-6 * max(1.0, abs(y[j]))
        w[0, j] = y[j] + h
        w[1, j] = y[j] - h
        tree_rhs(t, w[0], ip, fp, w[2])
        tree_rhs(t, w[1], ip, fp, w[3])
        for i in range(ns):
            J[i, j] = (w[2, i] - w[3, i]) / (2.0 * h)
        w[0, j] = y[j]
        w[1, j] = y[j]
