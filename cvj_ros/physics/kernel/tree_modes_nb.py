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

:func:`cvj_ros.physics.kernel.segment_nb.mode_segment` (kind KIND_TREE) integrates one
mode on :func:`tm_eval` with dopri5, dop853 or a RODAS method, checks the witnesses after
every accepted step and locates the earliest crossing by Brent's method on the dense
output; the chains' loop, one compiled code for both.

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
from cvj_ros.physics.kernel.borrow_nb import STACK_MAX_DOUBLES, stack_zeros_2d
from cvj_ros.physics.kernel.layout import (
    H_ENGINE_F, H_NDOF, H_SPRING_F, H_TREE, OP_INERTIA, SEC_STRIDE, SPRING_STRIDE, TB_BODY_F,
    TB_DIFF, TB_GRP, TB_KMAX, TB_ND, TB_NG, TB_NS, TB_NSPR, TB_NW, TB_OPS, TB_SEC, TB_SPR,
    TB_WHEEL)
from cvj_ros.physics.kernel.modes_nb import op_eval, ramp

__all__ = ['commands', 'tm_eval']

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
MAX_SEC_OPS = 64        # ops of one section (the backward walk's per-op rows)


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


@njit(cache=True, inline='always')
def commands(t, ip, fp):
    """(clutch kinetic, clutch static capacity N m, brake fraction 0..1) at t; sets the
    engine's throttle in fp (HybridTreeSimulation._eval, _capacities; AutoShift.value)."""
    mb = ip[ip.shape[0] - 1]
    ch = ip[mb + MB_CHAN_F]
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
    return ck, cs, fb


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
    ops3 = stack_zeros_2d(3, MAX_SEC_OPS)        # per op: a, b, ratio (no heap allocation)
    a_op = ops3[0]
    b_op = ops3[1]
    r_op = ops3[2]
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
    W_friction] into dy (module docstring); want: also the witness values into wv. The
    scratch rows are zeroed in this call's stack frame (``borrow_nb.stack_zeros_2d``, as
    ``tree_nb.tree_rhs``): no heap allocation per call."""
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
    rows = N_ROWS + ns + 2 * kmax
    # the scratch rows, then acc (uddot) and st (the walk's section torques): zeroed in this
    # call's stack frame, no heap allocation per call (a larger tree: np.zeros)
    if (rows + 2) * width <= STACK_MAX_DOUBLES:
        W = stack_zeros_2d(rows + 2, width)
    else:
        W = np.zeros((rows + 2, width))
    r0 = N_ROWS
    m0 = N_ROWS + ns
    l0 = m0 + kmax
    acc = W[rows]
    st = W[rows + 1]
    ck, cs, fb = commands(t, ip, fp)
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
