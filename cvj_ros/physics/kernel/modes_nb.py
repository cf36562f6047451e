"""Compiled modes of a chain with clutch, gearbox and brake (docs/clutch_gearbox.md).

One mode of a :class:`cvj_ros.physics.hybrid.HybridChain` (its rigid groups, the unlocked
boundaries between them, the brake) is data in ``ip``/``fp`` arrays (layout below, built by
``kernel/modes.py``), so one compiled code serves every scene and every mode: a mode change
only rebuilds the arrays. The equations are the oracle's (``HybridChain.evaluate``, same
order of additions): per group M(q) q'' + C(q) q'^2 = Q; Q = (T_e [first] - T_l a_last
- mode T_brake a_last [last]) + T_{link g-1} - T_{link g} a_g, a link being a spring
(``rhs_nb.spring_eval``), a slipping clutch (mode mu_k cgeo fn_max f_n(t)) or neutral (0);
a stuck brake pins the last group (q' = q'' = 0). Work integrals W_engine, W_load, W_damp,
W_friction follow the groups' states.

:func:`mode_segment` integrates one mode from t0 towards t_stop with Dormand-Prince 5(4) or
8(5,3) (the step control and dense output of ``steppers_nb.dopri5_step`` / ``dop853_step``,
whose right-hand side is fixed to the event-free driveline: the steppers bind their rhs as
a module global), checks the mode's
witnesses after every accepted step (a crossing in the witness's direction, scipy's
``find_active_events``), locates the earliest by Brent's method (scipy's ``brentq``, Brent
1973, xtol = rtol = 4 eps) on the dense output and stops there; the discrete transition is
the caller's (``kernel/modes.py``, the oracle's decision code).

ip layout (MH_* header): n groups; op table offset (n+1 op starts, then (code, fp offset)
pairs: layout.OP_* codes and OP_COUPLING fp = [k, offset]: phi_out = k phi_in + offset);
link table offset (n-1 rows of (kind LINK_*, spring fp offset, clutch mode sign)); engine
code and fp offset; load code and fp offset; pinned 0/1; brake mode sign (0: no brake
torque); witness count and table offset (rows (kind W_*, reference, direction));
stuck-slot count and table offset (rows (group, global op index of the clutch coupling));
fp offset of the channel block CH_* (flags, packs, stall speed) and of the three ramps
(throttle, clutch pedal, brake: [m, t_0..t_m-1, v_0..v_m-1], commands.Ramp).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from cvj_ros.physics.kernel.joints_nb import joint_eval
from cvj_ros.physics.kernel.layout import OP_INERTIA
from cvj_ros.physics.kernel.rhs_nb import spring_eval
from cvj_ros.physics.kernel.sources_nb import engine_eval, load_eval
from cvj_ros.physics.kernel.steppers_nb import (BETA, C_DENSE, C_LASTREJ, C_NACC, C_NFEV,
                                                C_NREJ, D8_FAC_MAX, D8_FAC_MIN, D8_ORDER, DP_A,
                                                DP_B, DP_C, DP_E, DP_ORDER, FAC_MAX, FAC_MIN,
                                                FS_ERROLD, FS_H, FS_HLAST, FS_T, FS_TOLD, NCNT,
                                                NFS, SAFETY, ST_NONFINITE, ST_OK, ST_UNDERFLOW,
                                                _proposal, _proposal_nobeta, dopri5_dense)

__all__ = ['M_DOP853', 'M_DOPRI5', 'mode_eval', 'mode_segment', 'witness_values']

M_DOPRI5, M_DOP853 = 0, 1

OP_COUPLING = -1
LINK_SPRING, LINK_CLUTCH, LINK_OPEN = 0, 1, 2
(W_STALL, W_SLIP, W_CLUTCH_FWD, W_CLUTCH_BWD, W_BRAKE_SPEED, W_BRAKE_FWD,
 W_BRAKE_BWD) = range(7)
(MH_N, MH_OPS, MH_LINKS, MH_ENGINE, MH_ENGINE_F, MH_LOAD, MH_LOAD_F, MH_PINNED, MH_BRAKE,
 MH_NWIT, MH_WIT, MH_NSTUCK, MH_STUCK, MH_CHAN_F, MH_RAMP_T, MH_RAMP_C, MH_RAMP_B) = range(17)
N_MHEADER = 17
# channel block: has throttle rows, has clutch, has brake, clutch mu_s, mu_k, cgeo, fn_max,
# brake mu_s, mu_k, cgeo, fn_max, stall speed (rad/s)
(CH_THROTTLE, CH_CLUTCH, CH_BRAKE, CH_CMUS, CH_CMUK, CH_CCGEO, CH_CFN, CH_BMUS, CH_BMUK,
 CH_BCGEO, CH_BFN, CH_STALL) = range(12)
N_CHAN = 12
N_WORK = 4
N_SCRATCH_EXTRA = 6     # sc[n..]: hold torque, omega_last, cs, bs, ck, bk
FS_HUSED = 7            # fs slot: the size of the last accepted attempt (s), for the step log
_EPS = np.finfo(float).eps
_XTOL = 4 * _EPS


@njit(cache=True, inline='always')
def ramp(t, fp, off):
    """commands.Ramp at t: piecewise linear through (t_j, v_j), held outside, 0 without rows;
    k = rows at or before t (bisect_right)."""
    m = int(fp[off])
    if m == 0:
        return 0.0
    ts = off + 1
    vs = ts + m
    lo = 0
    hi = m
    while lo < hi:
        mid = (lo + hi) // 2
        if t < fp[ts + mid]:
            hi = mid
        else:
            lo = mid + 1
    k = lo
    if k == 0:
        return fp[vs]
    if k == m:
        return fp[vs + m - 1]
    t0 = fp[ts + k - 1]
    t1 = fp[ts + k]
    v0 = fp[vs + k - 1]
    v1 = fp[vs + k]
    return v0 + (v1 - v0) * (t - t0) / (t1 - t0)


@njit(cache=True, inline='always')
def capacities(t, ip, fp):
    """(clutch kinetic, clutch static, brake kinetic, brake static) at t (N m):
    mu cgeo fn_max f_n, f_n = clip(1 - pedal) (clutch) or clip(brake) (friction.CoulombPack)."""
    ch = ip[MH_CHAN_F]
    ck = 0.0
    cs = 0.0
    bk = 0.0
    bs = 0.0
    if fp[ch + CH_CLUTCH] != 0.0:
        f = min(1.0, max(0.0, 1.0 - ramp(t, fp, ip[MH_RAMP_C])))
        ck = fp[ch + CH_CMUK] * fp[ch + CH_CCGEO] * fp[ch + CH_CFN] * f
        cs = fp[ch + CH_CMUS] * fp[ch + CH_CCGEO] * fp[ch + CH_CFN] * f
    if fp[ch + CH_BRAKE] != 0.0:
        f = min(1.0, max(0.0, ramp(t, fp, ip[MH_RAMP_B])))
        bk = fp[ch + CH_BMUK] * fp[ch + CH_BCGEO] * fp[ch + CH_BFN] * f
        bs = fp[ch + CH_BMUS] * fp[ch + CH_BCGEO] * fp[ch + CH_BFN] * f
    return ck, cs, bk, bs


@njit(cache=True, inline='always')
def op_eval(code, phi, fp, off):
    """(phi_out, ratio, ratio slope) of one joint or coupling op."""
    if code == OP_COUPLING:
        return fp[off] * phi + fp[off + 1], fp[off], 0.0
    return joint_eval(code, phi, fp, off)


@njit(cache=True, inline='always')
def group_kin(g, q, ip, fp):
    """(phi_end, a_end, b_end, M, C) of group g at angle q (sections.section_kinematics)."""
    tab = ip[MH_OPS]
    n = ip[MH_N]
    ops = tab + n + 1
    phi, a, b, m, c = q, 1.0, 0.0, 0.0, 0.0
    for k in range(ip[tab + g], ip[tab + g + 1]):
        code = ip[ops + 2 * k]
        off = ip[ops + 2 * k + 1]
        if code == OP_INERTIA:
            jv = fp[off]
            m += jv * a * a
            c += jv * a * b
        else:
            po, r, s = op_eval(code, phi, fp, off)
            b = s * a * a + r * b
            a = r * a
            phi = po
    return phi, a, b, m, c


@njit(cache=True)
def mode_eval(t, y, ip, fp, dy, sc, want):
    """dy/dt of the mode state y = [q_g, q'_g, W_engine, W_load, W_damp, W_friction] into dy.
    want: also fill sc (torque entering each group at its first shaft, then hold torque,
    output-shaft speed, cs, bs, ck, bk) for the witnesses. The throttle ramp is written into
    the engine's fp block (engine.set_throttle as the oracle)."""
    n = ip[MH_N]
    ch = ip[MH_CHAN_F]
    ck, cs, bk, bs = capacities(t, ip, fp)
    if fp[ch + CH_THROTTLE] != 0.0:
        fp[ip[MH_ENGINE_F]] = ramp(t, fp, ip[MH_RAMP_T])
    v0 = y[n]
    te = engine_eval(t, v0, y[0], ip, fp, MH_ENGINE, ip[MH_ENGINE_F])[0]
    links = ip[MH_LINKS]
    carry = 0.0
    p_damp = 0.0
    p_cl = 0.0
    p_br = 0.0
    tl = 0.0
    omega_last = 0.0
    hold = 0.0
    for g in range(n):
        phi, a, _b, m, c = group_kin(g, y[g], ip, fp)
        qf = 0.0
        if g == 0:
            qf += te
        if g == n - 1:
            omega_last = a * y[2 * n - 1]
            tl = load_eval(t, omega_last, phi, ip, fp, MH_LOAD, ip[MH_LOAD_F])[0]
            qf -= tl * a
            bm = ip[MH_BRAKE]
            if bm != 0:
                tb = bm * bk
                qf -= tb * a
                p_br += tb * omega_last
        if want:
            sc[g] = te if g == 0 else carry
        if g > 0:
            qf += carry
        if g < n - 1:
            row = links + 3 * g
            kind = ip[row]
            thd = a * y[n + g] - y[n + g + 1]
            if kind == LINK_SPRING:
                ts, _k, _kd, pd = spring_eval(phi - y[g + 1], thd, fp, ip[row + 1])
                p_damp += pd
            elif kind == LINK_CLUTCH:
                ts = ip[row + 2] * ck
                p_cl += ts * thd
            else:
                ts = 0.0
            qf -= ts * a
            carry = ts
        v = y[n + g]
        dy[g] = v
        acc = (qf - c * v * v) / m
        if g == n - 1 and ip[MH_PINNED] != 0:
            hold = qf / a
            acc = 0.0
            dy[g] = 0.0
        dy[n + g] = acc
    dy[2 * n] = te * v0
    dy[2 * n + 1] = tl * omega_last
    dy[2 * n + 2] = p_damp
    dy[2 * n + 3] = p_br + p_cl if ip[MH_BRAKE] != 0 else 0.0 + p_cl
    if want:
        sc[n] = hold
        sc[n + 1] = omega_last
        sc[n + 2] = cs
        sc[n + 3] = bs
        sc[n + 4] = ck
        sc[n + 5] = bk


@njit(cache=True, inline='always')
def stuck_torque(g, target, y, acc, inflow, ip, fp):
    """Shaft torque just before global op ``target`` of group g (N m): walk the group with
    its acceleration, torque -= J (a q'' + b q'^2) per inertia, /= ratio per joint
    (HybridChain._walk_torques)."""
    tab = ip[MH_OPS]
    n = ip[MH_N]
    ops = tab + n + 1
    phi, a, b = y[g], 1.0, 0.0
    v = y[n + g]
    torque = inflow
    for k in range(ip[tab + g], ip[tab + g + 1]):
        if k == target:
            return torque
        code = ip[ops + 2 * k]
        off = ip[ops + 2 * k + 1]
        if code == OP_INERTIA:
            torque -= fp[off] * (a * acc + b * v * v)
        else:
            po, r, s = op_eval(code, phi, fp, off)
            b = s * a * a + r * b
            a = r * a
            phi = po
            torque = torque / r
    return torque


@njit(cache=True)
def witness_values(t, y, ip, fp, dy, sc, wv):
    """Witness values g_i(t, y) of the mode into wv (HybridSimulation._g); dy and sc from
    mode_eval(..., want=True) at the same (t, y)."""
    n = ip[MH_N]
    ch = ip[MH_CHAN_F]
    w0 = ip[MH_WIT]
    cs = sc[n + 2]
    bs = sc[n + 3]
    for i in range(ip[MH_NWIT]):
        kind = ip[w0 + 3 * i]
        ref = ip[w0 + 3 * i + 1]
        if kind == W_STALL:
            wv[i] = y[n] - fp[ch + CH_STALL]
        elif kind == W_SLIP:
            a = group_kin(ref, y[ref], ip, fp)[1]
            wv[i] = a * y[n + ref] - y[n + ref + 1]
        elif kind == W_CLUTCH_FWD or kind == W_CLUTCH_BWD:
            row = ip[MH_STUCK] + 2 * ref
            g = ip[row]
            tst = stuck_torque(g, ip[row + 1], y, dy[n + g], sc[g], ip, fp)
            wv[i] = cs - tst if kind == W_CLUTCH_FWD else cs + tst
        elif kind == W_BRAKE_SPEED:
            wv[i] = sc[n + 1]
        elif kind == W_BRAKE_FWD:
            wv[i] = bs - sc[n]
        else:
            wv[i] = bs + sc[n]


@njit(cache=True)
def _witness_at(t, y, ip, fp, dy, sc, wv):
    mode_eval(t, y, ip, fp, dy, sc, True)
    witness_values(t, y, ip, fp, dy, sc, wv)


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
    mode_eval(t + h0, tmp, ip, fp, f1, sc, False)
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
        mode_eval(t + DP_C[s] * h, arg, ip, fp, K[s], sc, False)
    ynew = work[1]
    for i in range(n):
        ynew[i] = y[i]
    for j in range(6):
        c = h * DP_B[j]
        if c != 0.0:
            kj = K[j]
            for i in range(n):
                ynew[i] += c * kj[i]
    mode_eval(t + h, ynew, ip, fp, K[6], sc, True)      # also the witnesses' scratch
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
            mode_eval(t + C[s] * h, arg, ip, fp, K[s], sc, False)
        for i in range(n):
            acc = 0.0
            for j in range(ns):
                acc += B[j] * K[j, i]
            ynew[i] = y[i] + h * acc
        mode_eval(t + h, ynew, ip, fp, K[ns], sc, True)
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
            mode_eval(t_old + C_EXTRA[r] * h, arg, ip, fp, K[s], sc, False)
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
def mode_segment(method, t0, t_stop, y, ip, fp, rtol, atol, max_step, h_in, t_samp, k0, Y,
                 hlog, out_i, out_f, C8, A8, B8, E5, E3, D8, AX, CX):
    """Integrate the mode from t0 towards t_stop until the earliest witness crossing, with
    method M_DOPRI5 or M_DOP853 (its coefficients C8 .. CX: scipy's DOP853 tableau, as
    steppers_nb.dop853_step takes them; unused by dopri5).

    y: the mode state at t0, overwritten with the state at the end (event or t_stop).
    h_in: first step (s), 0: Hairer's estimate. Samples t_samp[k] (ascending, k >= k0) up to
    the end are written into Y[k] (dense output, the step end exactly). hlog (empty: off)
    receives the size of every accepted attempt (s) while it has room. Returns in
    out_i: status ST_*, witness index of the event (-1: reached t_stop), next sample index,
    accepted steps, rhs evaluations, rejected steps, logged steps; out_f: end time (s), the
    step proposal at the end (s)."""
    ns = y.shape[0]
    n = ip[MH_N]
    nw = ip[MH_NWIT]
    w0 = ip[MH_WIT]
    K = np.zeros((7 if method == M_DOPRI5 else 23, ns))
    fsal = 6 if method == M_DOPRI5 else B8.shape[0]
    work = np.zeros((4, ns))
    y_old = np.zeros(ns)
    yy = np.zeros(ns)
    dy = np.zeros(ns)
    sc = np.zeros(n + N_SCRATCH_EXTRA)
    g_old = np.zeros(max(nw, 1))
    g_new = np.zeros(max(nw, 1))
    wv = np.zeros(max(nw, 1))
    fs = np.zeros(NFS)
    cnt = np.zeros(NCNT, np.int64)
    fs[FS_T] = t0
    fs[FS_ERROLD] = 1e-4        # the PI controller's memory at a start (kernel/stepper.py)
    out_i[0] = ST_OK
    out_i[1] = -1
    mode_eval(t0, y, ip, fp, K[0], sc, False)
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
            witness_values(t_new, y, ip, fp, K[fsal], sc, g_new)
        else:
            _witness_at(t_new, y, ip, fp, dy, sc, g_new)
        best_t = math.inf
        best_i = -1
        for i in range(nw):
            d = ip[w0 + 3 * i + 2]
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
