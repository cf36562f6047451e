"""Compiled modes of a vehicle tree with clutch, gearbox, wheel brakes and a clutch-pack
limited-slip differential (docs/clutch_gearbox.md).

One mode of :class:`cvj_ros.physics.hybrid.tree.ModeTree` is data: the event-free tree
tables of ``kernel/layout.py`` (``H_TREE``; a locked clutch or engaged gear is the coupling
op phi_out = k phi_in + offset, ``modes_nb.OP_COUPLING``, ending its input section) plus a
mode block (layout below, built by ``kernel/tree_modes.py``), so one compiled code serves
every vehicle scene and every mode. :func:`tm_eval` is ``ModeTree.evaluate`` in its order of
operations: the tree's kinematics, forces, tyres and body (``kernel/tree_nb.tree_rhs``'s
loops), then per unlocked link the slipping clutch's mode mu_k cgeo fn f_n(t) (-ts a_l on
the input section, +ts on the output), per slipping brake -mode mu_k cgeo fn f_b(t) on its
wheel, per stuck brake the hold torque Q_s / a_w of its pinned section, per slipping
clutch pack the torque-sensing bias T_b = m (T_p + k s T_c0) / (1 - m k s B) (two backward
walks, ``ModeTree._pack_bias``); per group the SPD solve, pinned coordinates at rest; the
work integrals W_engine, W_damp, W_slip, W_road, W_friction. The stuck clutch's and stuck
pack's torques come from the backward walk (``TreeDriveline._walk``: an inertia adds
J (a qddot + b qdot^2), a joint multiplies by its ratio). The AutoShift envelope (clutch
pedal p + (1 - p) e, throttle x (1 - e); cvj_ros.physics.hybrid.shift) is evaluated here.

:func:`tree_mode_segment` integrates one mode from t0 towards t_stop with Dormand-Prince
5(4) or 8(5,3), checks the witnesses after every accepted step and locates the earliest
crossing by Brent's method on the dense output: ``modes_nb.mode_segment``'s loop, step
control, dense output and root finder line for line on :func:`tm_eval` (numba binds a
callee at compile time and does not cache a function taking a function argument -
measured with numba 0.68: a cache miss in every process - so the loop is repeated here for
the tree's right-hand side instead of passed it).

Mode block at ip[ip[-1]] (MB_* header): links (left, right, locked, clutch 1 / gearbox 0,
clutch mode sign), brakes (wheel, section, pinned, mode sign, fp pack block [mu_s, mu_k,
cgeo, fn_max]), packs (left, right, stuck, mode sign, fp [preload, torque_bias,
static_ratio]), witnesses (kind TW_*, element index, direction, fp offset), per section
its end (END_* of tree_outputs_nb or END_LINK, index), its group's size and coordinate list
offset (the tree block's group table) and fp offset of its angle offset (a stuck pack's
delta; -1: none); fp offsets of the channel block (TC_*) and of the three ramps (throttle,
clutch pedal, brake; modes_nb.ramp).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from cvj_ros.physics.kernel import rhs_nb as _rhs
from cvj_ros.physics.kernel.layout import (
    H_ENGINE_F, H_NDOF, H_SPRING_F, H_TREE, OP_INERTIA, SEC_STRIDE, SPRING_STRIDE, TB_BODY_F,
    TB_DIFF, TB_GRP, TB_KMAX, TB_ND, TB_NG, TB_NS, TB_NSPR, TB_NW, TB_OPS, TB_SEC, TB_SPR,
    TB_WHEEL)
from cvj_ros.physics.kernel.modes_nb import FS_HUSED, M_DOP853, M_DOPRI5, op_eval, ramp
from cvj_ros.physics.kernel.steppers_nb import (BETA, C_DENSE, C_LASTREJ, C_NACC, C_NFEV,
                                                C_NREJ, D8_FAC_MAX, D8_FAC_MIN, D8_ORDER, DP_A,
                                                DP_B, DP_C, DP_E, DP_ORDER, FAC_MAX, FAC_MIN,
                                                FS_ERROLD, FS_H, FS_HLAST, FS_T, FS_TOLD, NCNT,
                                                NFS, SAFETY, ST_NONFINITE, ST_OK, ST_UNDERFLOW,
                                                _proposal, _proposal_nobeta, dopri5_dense)

__all__ = ['M_DOP853', 'M_DOPRI5', 'tm_eval', 'tree_mode_segment']

_EPS = np.finfo(float).eps
_XTOL = 4 * _EPS

(MB_NLINK, MB_LINK, MB_NBRAKE, MB_BRAKE, MB_NPACK, MB_PACK, MB_NWIT, MB_WIT, MB_SECX,
 MB_CHAN_F, MB_RAMP_T, MB_RAMP_C, MB_RAMP_B) = range(13)
N_MB = 13
LINK_STRIDE, BRAKE_STRIDE, PACK_STRIDE, WIT_STRIDE, SECX_STRIDE = 5, 5, 5, 4, 5
END_NONE, END_WHEEL, END_SPRING, END_DIFF, END_LINK = 0, 1, 2, 3, 4
(TW_STALL, TW_SLIP, TW_CLUTCH_FWD, TW_CLUTCH_BWD, TW_BRAKE_SPEED, TW_BRAKE_FWD, TW_BRAKE_BWD,
 TW_PACK_SLIP, TW_PACK_FWD, TW_PACK_BWD, TW_SHIFT) = range(11)
# channel block: has throttle, has clutch, clutch mu_s, mu_k, cgeo, fn_max, stall speed,
# shift sequence on, its start, open, neutral, close time, duration (s)
(TC_THROTTLE, TC_CLUTCH, TC_CMUS, TC_CMUK, TC_CCGEO, TC_CFN, TC_STALL, TC_SEQ, TC_T0, TC_OPEN,
 TC_NEUTRAL, TC_CLOSE, TC_DUR) = range(13)
N_TC = 13
# scratch rows (per section unless noted)
(R_Q, R_QD, R_BIAS, R_QF, R_PHI, R_A, R_B, R_M, R_C, R_FZ, R_GRIP, R_FX, R_EXTRA, R_ACC, R_ST,
 R_LINKT, R_FF, R_YY, R_XX, R_SPRT) = range(20)
N_ROWS = 20


@njit(cache=True, inline='always')
def envelope(t, fp, ch):
    """AutoShift._envelope at t: 0 outside a sequence, rising over open, 1 in neutral,
    falling over close."""
    if fp[ch + TC_SEQ] == 0.0:
        return 0.0
    tau = t - fp[ch + TC_T0]
    if tau <= 0.0 or tau >= fp[ch + TC_DUR]:
        return 0.0
    if tau < fp[ch + TC_OPEN]:
        return tau / fp[ch + TC_OPEN]
    if tau <= fp[ch + TC_OPEN] + fp[ch + TC_NEUTRAL]:
        return 1.0
    return 1.0 - (tau - fp[ch + TC_OPEN] - fp[ch + TC_NEUTRAL]) / fp[ch + TC_CLOSE]


@njit(cache=True)
def _accelerations(ip, fp, W, r0, m0, l0, qrow, acc):
    """Per group uddot from the generalised forces in W[qrow] (TreeDriveline._accelerations,
    tree_nb.tree_rhs's loop) into acc[coordinate]; a stuck brake's pinned coordinate at rest."""
    tb = ip[H_TREE]
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
                ms = W[R_M, s]
                r = W[r0 + s, 0]
                qd = W[R_QD, s]
                mg += ms * r * r
                fg += r * (W[qrow, s] - W[R_C, s] * qd * qd - ms * W[R_BIAS, s])
            acc[ip[cs]] = fg / mg
            continue
        for i in range(k):
            W[R_FF, i] = 0.0
            for j in range(k):
                W[m0 + i, j] = 0.0
        for j in range(nsec):
            s = ip[ss + j]
            ms = W[R_M, s]
            qd = W[R_QD, s]
            gen = W[qrow, s] - W[R_C, s] * qd * qd - ms * W[R_BIAS, s]
            for i in range(k):
                ri = W[r0 + s, i]
                if ri == 0.0:
                    continue
                W[R_FF, i] += ri * gen
                for jj in range(i + 1):
                    W[m0 + i, jj] += ms * ri * W[r0 + s, jj]
        for j in range(nsp):
            i = ip[spd + 2 * j]
            W[m0 + i, i] += fp[ip[spd + 2 * j + 1]]
        for i in range(k):
            for j in range(i + 1):
                a = W[m0 + i, j]
                for kk in range(j):
                    a -= W[l0 + i, kk] * W[l0 + j, kk]
                W[l0 + i, j] = math.sqrt(a) if i == j else a / W[l0 + j, j]
        for i in range(k):
            a = W[R_FF, i]
            for kk in range(i):
                a -= W[l0 + i, kk] * W[R_YY, kk]
            W[R_YY, i] = a / W[l0 + i, i]
        for i in range(k - 1, -1, -1):
            a = W[R_YY, i]
            for kk in range(i + 1, k):
                a -= W[l0 + kk, i] * W[R_XX, kk]
            W[R_XX, i] = a / W[l0 + i, i]
        for i in range(k):
            acc[ip[cs + i]] = W[R_XX, i]
    mb = ip[ip.shape[0] - 1]
    for b in range(ip[mb + MB_NBRAKE]):
        row = ip[mb + MB_BRAKE] + BRAKE_STRIDE * b
        if ip[row + 2] != 0:
            sec = ip[row + 1]
            o = ip[H_TREE]
            c = ip[ip[o + TB_SEC] + SEC_STRIDE * sec + 5]
            acc[c] = 0.0


@njit(cache=True)
def _walk(ip, fp, W, r0, m0, l0, qrow, acc, st):
    """Start torque of every section into st (TreeDriveline._walk's backward walk, deepest
    first) for the generalised forces in W[qrow]; acc receives uddot."""
    n = ip[H_NDOF]
    tb = ip[H_TREE]
    ns = ip[tb + TB_NS]
    sec = ip[tb + TB_SEC]
    ops = ip[tb + TB_OPS]
    whl = ip[tb + TB_WHEEL]
    mb = ip[ip.shape[0] - 1]
    sx = ip[mb + MB_SECX]
    _accelerations(ip, fp, W, r0, m0, l0, qrow, acc)
    a_op = np.empty(64)
    b_op = np.empty(64)
    r_op = np.empty(64)
    for s in range(ns - 1, -1, -1):
        o = sec + SEC_STRIDE * s
        x = sx + SECX_STRIDE * s
        k = ip[x + 2]
        cl = ip[x + 3]
        qdd = 0.0
        for i in range(k):
            qdd += W[r0 + s, i] * acc[ip[cl + i]]
        qdd += W[R_BIAS, s]
        kind = ip[x]
        idx = ip[x + 1]
        if kind == END_WHEEL:
            wf = ip[whl + 2 * idx + 1]
            t_end = W[R_FX, idx] * fp[wf + 1]
            t_end += W[R_EXTRA, idx]
        elif kind == END_LINK:
            lrow = ip[mb + MB_LINK] + LINK_STRIDE * idx
            t_end = st[ip[lrow + 1]] if ip[lrow + 2] != 0 else W[R_LINKT, idx]
        elif kind == END_SPRING:
            t_end = W[R_SPRT, idx]
        elif kind == END_DIFF:
            dif = ip[tb + TB_DIFF]
            t_end = st[ip[dif + 3 * idx]] + st[ip[dif + 3 * idx + 1]]
        else:
            t_end = 0.0
        phi, a, b = W[R_Q, s], 1.0, 0.0
        j = 0
        for kk in range(ip[o], ip[o + 1]):
            code = ip[ops + 2 * kk]
            off = ip[ops + 2 * kk + 1]
            if code != OP_INERTIA:
                po, r, sl = op_eval(code, phi, fp, off)
                b = sl * a * a + r * b
                a = r * a
                phi = po
                r_op[j] = r
            a_op[j] = a
            b_op[j] = b
            j += 1
        torque = t_end
        qd = W[R_QD, s]
        j = ip[o + 1] - ip[o]
        for kk in range(ip[o + 1] - 1, ip[o] - 1, -1):
            j -= 1
            if ip[ops + 2 * kk] == OP_INERTIA:
                torque += fp[ip[ops + 2 * kk + 1]] * (a_op[j] * qdd + b_op[j] * qd ** 2)
            else:
                torque *= r_op[j]
        st[s] = torque
    return n


@njit(cache=True)
def tm_eval(t, y, ip, fp, dy, wv, want):
    """dy/dt of the mode state y = [u, udot, kappa', v, W_engine, W_damp, W_slip, W_road,
    W_friction] into dy (module docstring); want: also the witness values into wv."""
    n = ip[H_NDOF]
    tb = ip[H_TREE]
    ns = ip[tb + TB_NS]
    nw = ip[tb + TB_NW]
    kmax = ip[tb + TB_KMAX]
    sec = ip[tb + TB_SEC]
    ops = ip[tb + TB_OPS]
    mb = ip[ip.shape[0] - 1]
    ch = ip[mb + MB_CHAN_F]
    sx = ip[mb + MB_SECX]
    width = max(max(ns, nw), max(kmax, max(ip[mb + MB_NLINK], 1)))
    width = max(width, max(ip[tb + TB_NSPR], n))
    W = np.zeros((N_ROWS + ns + 2 * kmax, width))
    r0 = N_ROWS
    m0 = N_ROWS + ns
    l0 = m0 + kmax
    acc = np.zeros(n)
    st = np.zeros(ns)
    # commands (HybridTreeSimulation._eval, _capacities; AutoShift.value)
    e = envelope(t, fp, ch)
    if fp[ch + TC_THROTTLE] != 0.0:
        x = ramp(t, fp, ip[mb + MB_RAMP_T])
        fp[ip[H_ENGINE_F]] = x * (1.0 - e) if fp[ch + TC_SEQ] != 0.0 else x
    ck = 0.0
    cs = 0.0
    if fp[ch + TC_CLUTCH] != 0.0:
        pv = ramp(t, fp, ip[mb + MB_RAMP_C])
        if fp[ch + TC_SEQ] != 0.0:
            pv = pv + (1.0 - pv) * e
        f = min(1.0, max(0.0, 1.0 - pv))
        ck = fp[ch + TC_CMUK] * fp[ch + TC_CCGEO] * fp[ch + TC_CFN] * f
        cs = fp[ch + TC_CMUS] * fp[ch + TC_CCGEO] * fp[ch + TC_CFN] * f
    fb = min(1.0, max(0.0, ramp(t, fp, ip[mb + MB_RAMP_B])))
    # kinematics in tree order (TreeDriveline._kinematics)
    for s in range(ns):
        o = sec + SEC_STRIDE * s
        parent = ip[o + 2]
        if parent < 0:
            c = ip[o + 5]
            W[R_Q, s] = y[c]
            W[R_QD, s] = y[n + c]
            W[r0 + s, 0] = 1.0
        else:
            ap = W[R_A, parent]
            for i in range(kmax):
                W[r0 + s, i] = ap * W[r0 + parent, i]
            W[R_Q, s] = W[R_PHI, parent]
            W[R_QD, s] = ap * W[R_QD, parent]
            loc = ip[o + 4]
            if loc >= 0:
                sign = ip[o + 3]
                cd = ip[o + 6]
                W[R_Q, s] += sign * y[cd]
                W[R_QD, s] += sign * y[n + cd]
                W[r0 + s, loc] += sign
            else:
                qo = ip[sx + SECX_STRIDE * s + 4]
                if qo >= 0:
                    W[R_Q, s] += fp[qo]
            qdp = W[R_QD, parent]
            W[R_BIAS, s] = ap * W[R_BIAS, parent] + W[R_B, parent] * qdp * qdp
        phi, a, b, m, cc = W[R_Q, s], 1.0, 0.0, 0.0, 0.0
        for k in range(ip[o], ip[o + 1]):
            code = ip[ops + 2 * k]
            off = ip[ops + 2 * k + 1]
            if code == OP_INERTIA:
                jv = fp[off]
                m += jv * a * a
                cc += jv * a * b
            else:
                po, r, sl = op_eval(code, phi, fp, off)
                b = sl * a * a + r * b
                a = r * a
                phi = po
        W[R_PHI, s] = phi
        W[R_A, s] = a
        W[R_B, s] = b
        W[R_M, s] = m
        W[R_C, s] = cc
    # forces (TreeDriveline._forces)
    te, _dte, _dtep = _rhs.engine_torque(t, y, ip, fp)
    W[R_QF, 0] += te
    p_damp = 0.0
    spr = ip[tb + TB_SPR]
    sp0 = ip[H_SPRING_F]
    for k in range(ip[tb + TB_NSPR]):
        left = ip[spr + 2 * k]
        right = ip[spr + 2 * k + 1]
        a_l = W[R_A, left]
        th = W[R_PHI, left] - W[R_Q, right]
        thd = a_l * W[R_QD, left] - W[R_QD, right]
        ts, _k, _kd, pd = _rhs.spring_eval(th, thd, fp, sp0 + SPRING_STRIDE * k)
        p_damp += pd
        W[R_SPRT, k] = ts
        W[R_QF, left] -= ts * a_l
        W[R_QF, right] += ts
    dif = ip[tb + TB_DIFF]
    for k in range(ip[tb + TB_ND]):
        left = ip[dif + 3 * k]
        right = ip[dif + 3 * k + 1]
        slip = W[R_QD, left] - W[R_QD, right]
        tbias = fp[ip[dif + 3 * k + 2]] * slip
        if tbias != 0.0:
            W[R_QF, left] -= tbias
            W[R_QF, right] += tbias
            p_damp += tbias * slip
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
        W[R_GRIP, i] = fp[wf] * math.sin(fp[wf + 3] * math.atan(x))
    if fp[bf + 6] == 0.0:
        for i in range(nw):
            W[R_FZ, i] = fp[ip[whl + 2 * i + 1] + 6] * w_n
    else:
        sf = fp[bf + 7]
        sr = 1.0 - sf
        gf = 0.0
        gr = 0.0
        for i in range(nw):
            wf = ip[whl + 2 * i + 1]
            if fp[wf + 7] > 0.0:
                gf += fp[wf + 6] * W[R_GRIP, i]
        for i in range(nw):
            wf = ip[whl + 2 * i + 1]
            if fp[wf + 7] < 0.0:
                gr += fp[wf + 6] * W[R_GRIP, i]
        gf = gf / sf if sf > 0.0 else 0.0
        gr = gr / sr if sr > 0.0 else 0.0
        h = fp[bf + 8]
        el = fp[bf + 9]
        fzf = (w_n * sf * el - h * (w_n * gr - roll)) / (el + h * (gf - gr))
        fzf = min(max(fzf, 0.0), w_n)
        fzr = w_n - fzf
        for i in range(nw):
            wf = ip[whl + 2 * i + 1]
            W[R_FZ, i] = fzf * fp[wf + 6] / sf if fp[wf + 7] > 0.0 else fzr * fp[wf + 6] / sr
    sum_fx = 0.0
    p_slip = 0.0
    for i in range(nw):
        s = ip[whl + 2 * i]
        wf = ip[whl + 2 * i + 1]
        kap = y[2 * n + i]
        fz = W[R_FZ, i]
        f = 0.0
        if fz > 0.0:
            bk = fp[wf + 2] * kap
            x = bk - fp[wf + 4] * (bk - math.atan(bk))
            f = fp[wf] * fz * math.sin(fp[wf + 3] * math.atan(x))
        a_w = W[R_A, s]
        om = a_w * W[R_QD, s]
        r = fp[wf + 1]
        W[R_FX, i] = f
        W[R_QF, s] -= f * r * a_w
        p_slip += f * (om * r - v)
        sum_fx += f
        dy[2 * n + i] = (om * r - v - abs(v) * kap) / fp[wf + 5]
    # mode forces (ModeTree.evaluate)
    p_fric = 0.0
    for i in range(ip[mb + MB_NLINK]):
        row = ip[mb + MB_LINK] + LINK_STRIDE * i
        if ip[row + 2] != 0:
            continue
        left = ip[row]
        right = ip[row + 1]
        a_l = W[R_A, left]
        sl = a_l * W[R_QD, left] - W[R_QD, right]
        ts = 0.0
        if ip[row + 3] != 0:
            ts = ip[row + 4] * ck
            p_fric += ts * sl
        W[R_LINKT, i] = ts
        W[R_QF, left] -= ts * a_l
        W[R_QF, right] += ts
    for bi in range(ip[mb + MB_NBRAKE]):
        row = ip[mb + MB_BRAKE] + BRAKE_STRIDE * bi
        if ip[row + 2] != 0:
            continue
        w = ip[row]
        s = ip[row + 1]
        pk = ip[row + 4]
        a_w = W[R_A, s]
        om = a_w * W[R_QD, s]
        tq = ip[row + 3] * (fp[pk + 1] * fp[pk + 2] * fp[pk + 3] * fb)
        W[R_QF, s] -= tq * a_w
        W[R_EXTRA, w] += tq
        p_fric += tq * om
    for bi in range(ip[mb + MB_NBRAKE]):
        row = ip[mb + MB_BRAKE] + BRAKE_STRIDE * bi
        if ip[row + 2] == 0:
            continue
        w = ip[row]
        s = ip[row + 1]
        W[R_EXTRA, w] += W[R_QF, s] / W[R_A, s]
    for pi in range(ip[mb + MB_NPACK]):
        row = ip[mb + MB_PACK] + PACK_STRIDE * pi
        if ip[row + 2] != 0:
            continue
        left = ip[row]
        right = ip[row + 1]
        pf = ip[row + 4]
        mm = ip[row + 3]
        s_lr = W[R_QD, left] - W[R_QD, right]
        tp = fp[pf]
        kb = fp[pf + 1]
        if kb == 0.0:
            tbp = mm * tp
        else:
            q_l = W[R_QF, left]
            q_r = W[R_QF, right]
            _walk(ip, fp, W, r0, m0, l0, R_QF, acc, st)
            tc0 = st[left] + st[right]
            W[R_QF, left] = q_l - 1.0
            W[R_QF, right] = q_r + 1.0
            _walk(ip, fp, W, r0, m0, l0, R_QF, acc, st)
            W[R_QF, left] = q_l
            W[R_QF, right] = q_r
            bb = st[left] + st[right] - tc0
            first = 1.0 if tc0 >= 0.0 else -1.0
            tbp = mm * (tp + kb * abs(tc0))
            for sgn in (first, -first):
                cand = mm * (tp + kb * sgn * tc0) / (1.0 - mm * kb * sgn * bb)
                if sgn * (tc0 + bb * cand) >= 0.0:
                    tbp = cand
                    break
        W[R_QF, left] -= tbp
        W[R_QF, right] += tbp
        p_fric += tbp * s_lr
    _accelerations(ip, fp, W, r0, m0, l0, R_QF, acc)
    for i in range(n):
        dy[i] = y[n + i]
        dy[n + i] = acc[i]
    res = roll + fp[bf + 3] + fp[bf + 4] * v * abs(v)
    dy[iv] = (sum_fx - res) / fp[bf]
    c0 = ip[sec + 5]
    dy[iv + 1] = te * y[n + c0]
    dy[iv + 2] = p_damp
    dy[iv + 3] = p_slip
    dy[iv + 4] = res * v
    dy[iv + 5] = p_fric
    if not want:
        return
    walked = False
    w0 = ip[mb + MB_WIT]
    for i in range(ip[mb + MB_NWIT]):
        row = w0 + WIT_STRIDE * i
        kind = ip[row]
        ref = ip[row + 1]
        wf = ip[row + 3]
        if kind == TW_STALL:
            wv[i] = y[n + c0] - fp[ch + TC_STALL]
        elif kind == TW_SLIP:
            lrow = ip[mb + MB_LINK] + LINK_STRIDE * ref
            wv[i] = W[R_A, ip[lrow]] * W[R_QD, ip[lrow]] - W[R_QD, ip[lrow + 1]]
        elif kind == TW_BRAKE_SPEED:
            brow = ip[mb + MB_BRAKE] + BRAKE_STRIDE * ref
            s = ip[brow + 1]
            wv[i] = W[R_A, s] * W[R_QD, s]
        elif kind == TW_BRAKE_FWD or kind == TW_BRAKE_BWD:
            brow = ip[mb + MB_BRAKE] + BRAKE_STRIDE * ref
            s = ip[brow + 1]
            pk = ip[brow + 4]
            bs = fp[pk] * fp[pk + 2] * fp[pk + 3] * fb
            th = W[R_QF, s] / W[R_A, s]
            wv[i] = bs - th if kind == TW_BRAKE_FWD else bs + th
        elif kind == TW_PACK_SLIP:
            prow = ip[mb + MB_PACK] + PACK_STRIDE * ref
            wv[i] = W[R_QD, ip[prow]] - W[R_QD, ip[prow + 1]]
        elif kind == TW_SHIFT:
            lrow = ip[mb + MB_LINK] + LINK_STRIDE * ref
            wv[i] = fp[wf] * W[R_QD, ip[lrow + 1]] - fp[wf + 1]
        else:
            if not walked:
                _walk(ip, fp, W, r0, m0, l0, R_QF, acc, st)
                walked = True
            if kind == TW_CLUTCH_FWD or kind == TW_CLUTCH_BWD:
                lrow = ip[mb + MB_LINK] + LINK_STRIDE * ref
                tst = st[ip[lrow + 1]]
                wv[i] = cs - tst if kind == TW_CLUTCH_FWD else cs + tst
            else:
                prow = ip[mb + MB_PACK] + PACK_STRIDE * ref
                t_l = st[ip[prow]]
                t_r = st[ip[prow + 1]]
                pf = ip[prow + 4]
                tst = 0.5 * (t_r - t_l)
                cap = fp[pf + 2] * (fp[pf] + fp[pf + 1] * abs(t_l + t_r))
                wv[i] = cap - tst if kind == TW_PACK_FWD else cap + tst


@njit(cache=True)
def _witness_at(t, y, ip, fp, dy, sc, wv):
    """The mode's witness values at (t, y) into wv."""
    tm_eval(t, y, ip, fp, dy, sc, True)
    for i in range(wv.shape[0]):
        wv[i] = sc[i] if i < sc.shape[0] else 0.0


@njit(cache=True)
def _dense(method, tau, y, y_old, ip, fp, fs, cnt, K, sc, D8, AX, CX, out):
    """The method's dense output at tau inside the last accepted step."""
    if method == M_DOPRI5:
        dopri5_dense(tau, y_old, fs, K, out)
    else:
        _d8_dense(tau, y, y_old, ip, fp, fs, cnt, D8, AX, CX, K, out, sc)


@njit(cache=True)
def _dense_witness(method, tau, i, y, y_old, fs, cnt, K, ip, fp, yy, dy, sc, wv, D8, AX, CX):
    """Witness i on the dense output at tau."""
    _dense(method, tau, y, y_old, ip, fp, fs, cnt, K, sc, D8, AX, CX, yy)
    _witness_at(tau, yy, ip, fp, dy, sc, wv)
    return wv[i]


@njit(cache=True)
def brent_root(xa, xb, fa, fb, i, method, y, y_old, fs, cnt, K, ip, fp, yy, dy, sc, wv, D8,
               AX, CX):
    """Zero of witness i on the dense output in [xa, xb]: scipy's brentq (zeros.c, Brent
    1973, "Algorithms for minimization without derivatives", ch. 4) with xtol = rtol =
    4 eps, maxiter 100; fa, fb: the witness at the ends (opposite signs)."""
    xpre = xa
    xcur = xb
    fpre = fa
    fcur = fb
    xblk = 0.0
    fblk = 0.0
    spre = 0.0
    scur = 0.0
    if fpre == 0.0:
        return xpre
    if fcur == 0.0:
        return xcur
    for _it in range(100):
        if fpre != 0.0 and fcur != 0.0 and (math.copysign(1.0, fpre) != math.copysign(1.0, fcur)):
            xblk = xpre
            fblk = fpre
            spre = xcur - xpre
            scur = spre
        if abs(fblk) < abs(fcur):
            xpre = xcur
            xcur = xblk
            xblk = xpre
            fpre = fcur
            fcur = fblk
            fblk = fpre
        delta = (_XTOL + _XTOL * abs(xcur)) / 2
        sbis = (xblk - xcur) / 2
        if fcur == 0.0 or abs(sbis) < delta:
            return xcur
        if abs(spre) > delta and abs(fcur) < abs(fpre):
            if xpre == xblk:
                stry = -fcur * (xcur - xpre) / (fcur - fpre)
            else:
                dpre = (fpre - fcur) / (xpre - xcur)
                dblk = (fblk - fcur) / (xblk - xcur)
                stry = -fcur * (fblk * dblk - fpre * dpre) / (dblk * dpre * (fblk - fpre))
            if 2 * abs(stry) < min(abs(spre), 3 * abs(sbis) - delta):
                spre = scur
                scur = stry
            else:
                spre = sbis
                scur = sbis
        else:
            spre = sbis
            scur = sbis
        xpre = xcur
        fpre = fcur
        if abs(scur) > delta:
            xcur += scur
        else:
            xcur += delta if sbis > 0 else -delta
        fcur = _dense_witness(method, xcur, i, y, y_old, fs, cnt, K, ip, fp, yy, dy, sc, wv,
                              D8, AX, CX)
    return xcur


@njit(cache=True)
def _initial_step(y, f0, t, ip, fp, sc, rtol, atol, max_step, order, tmp, f1):
    """Hairer's HINIT (steppers_nb._initial_step) on the mode's rhs; h0 (s) or -1.0."""
    n = y.shape[0]
    s0 = 0.0
    s1 = 0.0
    for i in range(n):
        scl = abs(y[i]) * rtol + atol[i]
        s0 += (y[i] / scl) ** 2
        s1 += (f0[i] / scl) ** 2
    d0 = math.sqrt(s0 / n)
    d1 = math.sqrt(s1 / n)
    if not (math.isfinite(d0) and math.isfinite(d1)):
        return -1.0
    h0 = 1e-6 if (d0 < 1e-5 or d1 < 1e-5) else 0.01 * d0 / d1
    h0 = min(h0, max_step)
    for i in range(n):
        tmp[i] = y[i] + h0 * f0[i]
    tm_eval(t + h0, tmp, ip, fp, f1, sc, False)
    s2 = 0.0
    for i in range(n):
        scl = abs(y[i]) * rtol + atol[i]
        s2 += ((f1[i] - f0[i]) / scl) ** 2
    d2 = math.sqrt(s2 / n) / h0
    if not math.isfinite(d2):
        return -1.0
    dmax = max(d1, d2)
    if dmax <= 1e-15:
        h1 = max(1e-6, h0 * 1e-3)
    else:
        h1 = (0.01 / dmax) ** (1.0 / (order + 1))
    return min(100 * h0, h1, max_step)


@njit(cache=True)
def _attempt(h, y, ip, fp, fs, cnt, rtol, atol, K, work, sc):
    """One DOPRI5 attempt (steppers_nb._dopri5_attempt on the mode's rhs)."""
    n = y.shape[0]
    t = fs[FS_T]
    arg = work[0]
    for s in range(1, 6):
        for i in range(n):
            arg[i] = y[i]
        for j in range(s):
            c = h * DP_A[s, j]
            if c != 0.0:
                kj = K[j]
                for i in range(n):
                    arg[i] += c * kj[i]
        tm_eval(t + DP_C[s] * h, arg, ip, fp, K[s], sc, False)
    ynew = work[1]
    for i in range(n):
        ynew[i] = y[i]
    for j in range(6):
        c = h * DP_B[j]
        if c != 0.0:
            kj = K[j]
            for i in range(n):
                ynew[i] += c * kj[i]
    tm_eval(t + h, ynew, ip, fp, K[6], sc, True)      # also the witnesses' scratch
    cnt[C_NFEV] += 6
    ss = 0.0
    for i in range(n):
        e = 0.0
        for j in range(7):
            e += DP_E[j] * K[j, i]
        scl = max(abs(y[i]), abs(ynew[i])) * rtol + atol[i]
        ss += (e / scl) ** 2
    return abs(h) * math.sqrt(ss / n)


@njit(cache=True)
def _step(t_bound, y, y_old, ip, fp, fs, cnt, rtol, atol, max_step, K, work, sc):
    """One accepted DOPRI5 step clipped to land on t_bound within 1 %
    (steppers_nb.dopri5_step); K[0] = f(t, y) on entry. Returns ST_*."""
    n = y.shape[0]
    expo = 1.0 / (DP_ORDER + 1) - 0.75 * BETA
    t = fs[FS_T]
    h_prop = fs[FS_H]
    remaining = t_bound - t
    clipped = h_prop * 1.01 >= remaining
    h = remaining if clipped else h_prop
    while True:
        if h < 10 * _EPS * max(abs(t), 1e-300) or h <= 1e-300:
            return ST_UNDERFLOW
        err = _attempt(h, y, ip, fp, fs, cnt, rtol, atol, K, work, sc)
        if err <= 1.0:
            h_new = _proposal(h, err, fs, expo, FAC_MAX)
            if cnt[C_LASTREJ] == 1:
                h_new = min(h_new, h)
            cnt[C_LASTREJ] = 0
            cnt[C_NACC] += 1
            t_new = t_bound if clipped else t + h
            ynew = work[1]
            for i in range(n):
                y_old[i] = y[i]
                y[i] = ynew[i]
            fs[FS_TOLD] = t
            fs[FS_T] = t_new
            fs[FS_HLAST] = t_new - t
            fs[FS_HUSED] = h
            fs[FS_H] = min(max(h_new, h_prop) if clipped else h_new, max_step)
            return ST_OK
        cnt[C_NREJ] += 1
        cnt[C_LASTREJ] = 1
        clipped = False
        if not math.isfinite(err):
            return ST_NONFINITE
        h = h / min(1.0 / FAC_MIN, err ** expo / SAFETY)


@njit(cache=True)
def _d8_step(t_bound, y, y_old, ip, fp, fs, cnt, rtol, atol, max_step, C, A, B, E5, E3, K,
             work, sc):
    """One accepted DOP853 step (steppers_nb.dop853_step on the mode's rhs); K[0] =
    f(t, y) on entry. Returns ST_*."""
    n = y.shape[0]
    ns = B.shape[0]
    expo = 1.0 / (D8_ORDER + 1)
    t = fs[FS_T]
    h_prop = fs[FS_H]
    remaining = t_bound - t
    clipped = h_prop * 1.01 >= remaining
    h = remaining if clipped else h_prop
    arg = work[0]
    ynew = work[1]
    while True:
        if h < 10 * _EPS * max(abs(t), 1e-300) or h <= 1e-300:
            return ST_UNDERFLOW
        for s in range(1, ns):
            for i in range(n):
                acc = 0.0
                for j in range(s):
                    acc += A[s, j] * K[j, i]
                arg[i] = y[i] + h * acc
            tm_eval(t + C[s] * h, arg, ip, fp, K[s], sc, False)
        for i in range(n):
            acc = 0.0
            for j in range(ns):
                acc += B[j] * K[j, i]
            ynew[i] = y[i] + h * acc
        tm_eval(t + h, ynew, ip, fp, K[ns], sc, True)
        cnt[C_NFEV] += ns
        e5n = 0.0
        e3n = 0.0
        for i in range(n):
            e5 = 0.0
            e3 = 0.0
            for j in range(ns + 1):
                e5 += E5[j] * K[j, i]
                e3 += E3[j] * K[j, i]
            scl = max(abs(y[i]), abs(ynew[i])) * rtol + atol[i]
            e5n += (e5 / scl) ** 2
            e3n += (e3 / scl) ** 2
        if e5n == 0.0 and e3n == 0.0:
            err = 0.0
        else:
            err = abs(h) * e5n / math.sqrt((e5n + 0.01 * e3n) * n)
        if err <= 1.0:
            h_new = _proposal_nobeta(h, err, D8_FAC_MIN, D8_FAC_MAX, expo)
            fs[FS_ERROLD] = max(err, 1e-4)
            if cnt[C_LASTREJ] == 1:
                h_new = min(h_new, h)
            cnt[C_LASTREJ] = 0
            cnt[C_NACC] += 1
            t_new = t_bound if clipped else t + h
            for i in range(n):
                y_old[i] = y[i]
                y[i] = ynew[i]
            fs[FS_TOLD] = t
            fs[FS_T] = t_new
            fs[FS_HLAST] = t_new - t
            fs[FS_HUSED] = h
            fs[FS_H] = min(max(h_new, h_prop) if clipped else h_new, max_step)
            cnt[C_DENSE] = 0
            return ST_OK
        cnt[C_NREJ] += 1
        cnt[C_LASTREJ] = 1
        clipped = False
        if not math.isfinite(err):
            return ST_NONFINITE
        h = h / min(1.0 / D8_FAC_MIN, err ** expo / SAFETY)


@njit(cache=True)
def _d8_dense(t, y, y_old, ip, fp, fs, cnt, D, A_EXTRA, C_EXTRA, K, out, sc):
    """7th-order dense output of DOP853 (steppers_nb.dop853_dense on the mode's rhs): the
    three extra stages and the coefficients once per step."""
    n = y.shape[0]
    h = fs[FS_HLAST]
    t_old = fs[FS_TOLD]
    if h == 0.0:
        for i in range(n):
            out[i] = y_old[i]
        return
    if cnt[C_DENSE] == 0:
        arg = np.empty(n)
        for r in range(3):
            s = 13 + r
            for i in range(n):
                acc = 0.0
                for j in range(s):
                    acc += A_EXTRA[r, j] * K[j, i]
                arg[i] = y_old[i] + h * acc
            tm_eval(t_old + C_EXTRA[r] * h, arg, ip, fp, K[s], sc, False)
        cnt[C_NFEV] += 3
        for i in range(n):
            dy = y[i] - y_old[i]
            K[16, i] = dy
            K[17, i] = h * K[0, i] - dy
            K[18, i] = 2 * dy - h * (K[12, i] + K[0, i])
            for r in range(4):
                acc = 0.0
                for j in range(16):
                    acc += D[r, j] * K[j, i]
                K[19 + r, i] = h * acc
        cnt[C_DENSE] = 1
    x = (t - t_old) / h
    for i in range(n):
        acc = 0.0
        for q in range(7):
            acc += K[22 - q, i]
            acc *= x if q % 2 == 0 else 1.0 - x
        out[i] = acc + y_old[i]


@njit(cache=True)
def tree_mode_segment(method, t0, t_stop, y, ip, fp, rtol, atol, max_step, h_in, t_samp, k0, Y,
                 hlog, out_i, out_f, C8, A8, B8, E5, E3, D8, AX, CX):
    """Integrate the tree mode from t0 towards t_stop until the earliest witness crossing, with
    method M_DOPRI5 or M_DOP853 (its coefficients C8 .. CX: scipy's DOP853 tableau, as
    steppers_nb.dop853_step takes them; unused by dopri5).

    y: the mode state at t0, overwritten with the state at the end (event or t_stop).
    h_in: first step (s), 0: Hairer's estimate. Samples t_samp[k] (ascending, k >= k0) up to
    the end are written into Y[k] (dense output, the step end exactly). hlog (empty: off)
    receives the size of every accepted attempt (s) while it has room. Returns in
    out_i: status ST_*, witness index of the event (-1: reached t_stop), next sample index,
    accepted steps, rhs evaluations, rejected steps, logged steps; out_f: end time (s), the
    step proposal at the end (s) and, given a third slot, the last accepted step's length
    (s)."""
    ns = y.shape[0]
    mb = ip[ip.shape[0] - 1]
    nw = ip[mb + MB_NWIT]
    w0 = ip[mb + MB_WIT]
    K = np.zeros((7 if method == M_DOPRI5 else 23, ns))
    fsal = 6 if method == M_DOPRI5 else B8.shape[0]
    work = np.zeros((4, ns))
    y_old = np.zeros(ns)
    yy = np.zeros(ns)
    dy = np.zeros(ns)
    sc = np.zeros(max(nw, 1))
    g_old = np.zeros(max(nw, 1))
    g_new = np.zeros(max(nw, 1))
    wv = np.zeros(max(nw, 1))
    fs = np.zeros(NFS)
    cnt = np.zeros(NCNT, np.int64)
    fs[FS_T] = t0
    fs[FS_ERROLD] = 1e-4        # the PI controller's memory at a start (kernel/stepper.py)
    out_i[0] = ST_OK
    out_i[1] = -1
    tm_eval(t0, y, ip, fp, K[0], sc, False)
    cnt[C_NFEV] += 1
    if h_in > 0.0:
        fs[FS_H] = min(h_in, max_step)
    else:
        h0 = _initial_step(y, K[0], t0, ip, fp, sc, rtol, atol, max_step,
                           DP_ORDER if method == M_DOPRI5 else D8_ORDER, work[0], work[2])
        cnt[C_NFEV] += 1
        if h0 < 0.0:
            out_i[0] = ST_NONFINITE
            return
        fs[FS_H] = h0
    _witness_at(t0, y, ip, fp, dy, sc, g_old)
    k = k0
    m = t_samp.shape[0]
    steps = 0
    while True:
        t_old = fs[FS_T]
        if method == M_DOPRI5:
            st = _step(t_stop, y, y_old, ip, fp, fs, cnt, rtol, atol, max_step, K, work, sc)
        else:
            st = _d8_step(t_stop, y, y_old, ip, fp, fs, cnt, rtol, atol, max_step, C8, A8, B8,
                          E5, E3, K, work, sc)
        if st != ST_OK:
            out_i[0] = st
            break
        if steps < hlog.shape[0]:
            hlog[steps] = fs[FS_HUSED]
        steps += 1
        t_new = fs[FS_T]
        if t_new == fs[FS_TOLD] + fs[FS_HUSED]:
            # the step's FSAL evaluation was at (t_new, y): its derivative and scratch
            for i in range(nw):
                g_new[i] = sc[i]
        else:
            _witness_at(t_new, y, ip, fp, dy, sc, g_new)
        best_t = math.inf
        best_i = -1
        for i in range(nw):
            d = ip[w0 + WIT_STRIDE * i + 2]
            if d < 0:
                hit = g_old[i] > 0.0 and g_new[i] <= 0.0
            else:
                hit = g_old[i] < 0.0 and g_new[i] >= 0.0
            if hit:
                if g_new[i] == 0.0:
                    t_i = t_new
                else:
                    # as scipy's brentq: both ends from the function (the dense output)
                    f_a = _dense_witness(method, t_old, i, y, y_old, fs, cnt, K, ip, fp, yy,
                                         dy, sc, wv, D8, AX, CX)
                    f_b = _dense_witness(method, t_new, i, y, y_old, fs, cnt, K, ip, fp, yy,
                                         dy, sc, wv, D8, AX, CX)
                    t_i = brent_root(t_old, t_new, f_a, f_b, i, method, y, y_old, fs, cnt, K,
                                     ip, fp, yy, dy, sc, wv, D8, AX, CX)
                if t_i < best_t:
                    best_t = t_i
                    best_i = i
        t_end = best_t if best_i >= 0 else t_new
        while k < m and t_samp[k] <= t_end:
            ts = t_samp[k]
            if ts == t_new:
                for j in range(ns):
                    Y[k, j] = y[j]
            else:
                _dense(method, max(ts, t_old), y, y_old, ip, fp, fs, cnt, K, sc, D8, AX, CX,
                       Y[k])
            k += 1
        if best_i >= 0:
            if best_t != t_new:
                _dense(method, best_t, y, y_old, ip, fp, fs, cnt, K, sc, D8, AX, CX, yy)
                for j in range(ns):
                    y[j] = yy[j]
            out_i[1] = best_i
            out_f[0] = best_t
            break
        for i in range(nw):
            g_old[i] = g_new[i]
        if t_new >= t_stop:
            out_f[0] = t_stop
            break
        for j in range(ns):        # FSAL
            K[0, j] = K[fsal, j]
    out_i[2] = k
    out_i[3] = steps
    out_i[4] = cnt[C_NFEV]
    out_i[5] = cnt[C_NREJ]
    out_i[6] = min(steps, hlog.shape[0])
    out_f[1] = fs[FS_H]
    if out_f.shape[0] > 2:
        out_f[2] = fs[FS_HLAST]
