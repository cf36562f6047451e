"""Compiled per-exchange joint state of a vehicle scene's branching driveline.

``tree_joint_state`` is ``TreeDriveline._walk`` (cvj_ros/physics/tree.py) on the kernel's
tree tables (``kernel/layout.py``, ``H_TREE``), in the oracle's order of operations:
kinematics in tree order (per section the chain rule over its ops, rows r_s and bias
k_s = a_end k_parent + b_end qdot_parent^2, as ``kernel/tree_nb.tree_rhs``, here keeping
every op's (phi, a, b, ratio)); generalised forces (engine, springs, viscous couplings,
tyres or outside wheel torques F_x = T_w / r); per group the SPD solve for uddot; then the
backward walk of every section, deepest first, from its end torque (a wheel's F_x r, a
spring's torque, a differential's side start torques summed): an inertia adds
J (a qddot_s + b qdot_s^2), a joint multiplies by its ratio. Intermediate members are
filled by ``outputs_nb.fill_mid_one`` (Driveline.fill_mid's formula). A new module so the
kernel files' numba caches stay valid.
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np
from numba import njit

from cvj_ros.physics.kernel import rhs_nb as _rhs
from cvj_ros.physics.kernel.joints_nb import joint_eval
from cvj_ros.physics.kernel.layout import (
    H_ENERGY, H_NDOF, H_SPRING_F, H_TREE, OP_INERTIA, SEC_STRIDE, SPRING_STRIDE, TB_BODY_F, TB_DIFF,
    TB_GRP, TB_KMAX, TB_ND, TB_NG, TB_NS, TB_NSPR, TB_NW, TB_OPS, TB_SEC, TB_SPR, TB_WHEEL)
from cvj_ros.physics.kernel.outputs_nb import fill_mid_one

__all__ = ['END_NONE', 'END_WHEEL', 'END_SPRING', 'END_DIFF', 'tree_tables', 'tree_joint_state',
           'tree_rhs_wheels', 'tree_sample']

END_NONE, END_WHEEL, END_SPRING, END_DIFF = 0, 1, 2, 3


def tree_tables(dl: Any) -> tuple[np.ndarray, np.ndarray]:
    """(shaft table (n_shafts, 3) int64: section, position in the section's kernel ops
    (0 = start, k + 1 = after op k), 1 = 'mid'; section ends (n_sections, 2) int64: END_*
    code, index of the wheel / spring / differential). NotImplementedError for what the walk
    does not cover (the mode-aware tree's links and stuck packs, a joint of several kernel
    stages)."""
    from cvj_ros.physics.tree import TreeDriveline
    if type(dl) is not TreeDriveline:
        raise NotImplementedError(f'compiled tree outputs: {type(dl).__name__}')
    rows = []
    for sh in dl.shafts:
        sec = dl.sections[sh.section]
        name = sec.names[sh.op_index]
        model = dl.joint_models.get(name)
        if model is not None and model.kind == 'chain' and len(model.joints) != 1:
            raise NotImplementedError(f'compiled tree outputs: joint chain {name!r}')
        before = sh.role in ('input', 'mid')
        rows.append((sh.section, sh.op_index if before else sh.op_index + 1,
                     1 if sh.role == 'mid' else 0))
    ends = []
    codes = {'wheel': END_WHEEL, 'spring': END_SPRING, 'diff': END_DIFF}
    for sec in dl.sections:
        end = getattr(sec, 'end', None)
        if not end:
            ends.append((END_NONE, 0))
            continue
        kind, idx = end
        if kind not in codes:
            raise NotImplementedError(f'compiled tree outputs: section end {kind!r}')
        ends.append((codes[kind], idx))
    return (np.asarray(rows, dtype=np.int64).reshape(-1, 3),
            np.asarray(ends, dtype=np.int64).reshape(-1, 2))


@njit(cache=True)
def sa_width(ip):
    """Positions of the longest section: its kernel ops + 1."""
    tb = ip[H_TREE]
    sec = ip[tb + TB_SEC]
    maxp = 1
    for s in range(ip[tb + TB_NS]):
        o = sec + SEC_STRIDE * s
        maxp = max(maxp, ip[o + 1] - ip[o] + 1)
    return maxp


@njit(cache=True)
def _tree_dynamics(y, ip, fp, te, ext, wheel_t):
    """Kinematics (per section q, qdot, rows r_s, bias k_s, M_s, C_s; per position phi, a,
    b; per op its ratio), forces (spring torques, F_x per wheel, damping and slip power) and
    the accelerations uddot of state y at engine torque ``te`` (TreeDriveline._kinematics,
    _forces, _accelerations; ``ext`` != 0: F_x = wheel_t[i] / r)."""
    n = ip[H_NDOF]
    tb = ip[H_TREE]
    ns = ip[tb + TB_NS]
    nw = ip[tb + TB_NW]
    kmax = ip[tb + TB_KMAX]
    sec = ip[tb + TB_SEC]
    ops = ip[tb + TB_OPS]
    maxp = sa_width(ip)
    q = np.zeros(ns)
    qd = np.zeros(ns)
    bias = np.zeros(ns)
    qf = np.zeros(ns)
    m_s = np.zeros(ns)
    c_s = np.zeros(ns)
    rows = np.zeros((ns, kmax))
    sphi = np.zeros((ns, maxp))       # per position: angle, a, b; per op: its ratio
    sa = np.zeros((ns, maxp))
    sb = np.zeros((ns, maxp))
    sr = np.ones((ns, maxp))
    # kinematics in tree order (a parent precedes its children)
    for s in range(ns):
        o = sec + SEC_STRIDE * s
        parent = ip[o + 2]
        if parent < 0:
            c = ip[o + 5]
            q[s] = y[c]
            qd[s] = y[n + c]
            rows[s, 0] = 1.0
        else:
            pe = ip[sec + SEC_STRIDE * parent + 1] - ip[sec + SEC_STRIDE * parent]
            ap = sa[parent, pe]
            for i in range(kmax):
                rows[s, i] = ap * rows[parent, i]
            q[s] = sphi[parent, pe]
            qd[s] = ap * qd[parent]
            loc = ip[o + 4]
            if loc >= 0:
                sign = ip[o + 3]
                cd = ip[o + 6]
                q[s] += sign * y[cd]
                qd[s] += sign * y[n + cd]
                rows[s, loc] += sign
            qdp = qd[parent]
            bias[s] = ap * bias[parent] + sb[parent, pe] * qdp * qdp
        phi, a, b, m, cc = q[s], 1.0, 0.0, 0.0, 0.0
        p = 0
        sphi[s, 0], sa[s, 0], sb[s, 0] = phi, a, b
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
                sr[s, p] = r
            p += 1
            sphi[s, p], sa[s, p], sb[s, p] = phi, a, b
        m_s[s] = m
        c_s[s] = cc
    # generalised forces (tree.TreeDriveline._forces)
    qf[0] += te
    p_damp = 0.0
    spr = ip[tb + TB_SPR]
    sp0 = ip[H_SPRING_F]
    nspr = ip[tb + TB_NSPR]
    spring_t = np.zeros(max(nspr, 1))
    for k in range(nspr):
        left = ip[spr + 2 * k]
        right = ip[spr + 2 * k + 1]
        pe = ip[sec + SEC_STRIDE * left + 1] - ip[sec + SEC_STRIDE * left]
        a_l = sa[left, pe]
        th = sphi[left, pe] - q[right]
        thd = a_l * qd[left] - qd[right]
        ts, _k, _kd, pd = _rhs.spring_eval(th, thd, fp, sp0 + SPRING_STRIDE * k)
        p_damp += pd
        spring_t[k] = ts
        qf[left] -= ts * a_l
        qf[right] += ts
    dif = ip[tb + TB_DIFF]
    nd = ip[tb + TB_ND]
    for k in range(nd):
        left = ip[dif + 3 * k]
        right = ip[dif + 3 * k + 1]
        slip = qd[left] - qd[right]
        tbias = fp[ip[dif + 3 * k + 2]] * slip
        if tbias != 0.0:
            qf[left] -= tbias
            qf[right] += tbias
            p_damp += tbias * slip
    v = y[2 * n + nw]
    whl = ip[tb + TB_WHEEL]
    bf = ip[tb + TB_BODY_F]
    w_n = fp[bf + 1]
    roll = w_n * fp[bf + 2] * math.tanh(v / fp[bf + 5])
    grip = np.zeros(max(nw, 1))
    fz = np.zeros(max(nw, 1))
    fx = np.zeros(max(nw, 1))
    for i in range(nw):
        wf = ip[whl + 2 * i + 1]
        bk = fp[wf + 2] * y[2 * n + i]
        x = bk - fp[wf + 4] * (bk - math.atan(bk))
        grip[i] = fp[wf] * math.sin(fp[wf + 3] * math.atan(x))
    if fp[bf + 6] == 0.0:
        for i in range(nw):
            fz[i] = fp[ip[whl + 2 * i + 1] + 6] * w_n
    else:
        sf = fp[bf + 7]
        sr_ = 1.0 - sf
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
        gr = gr / sr_ if sr_ > 0.0 else 0.0
        h = fp[bf + 8]
        el = fp[bf + 9]
        fzf = (w_n * sf * el - h * (w_n * gr - roll)) / (el + h * (gf - gr))
        fzf = min(max(fzf, 0.0), w_n)
        fzr = w_n - fzf
        for i in range(nw):
            wf = ip[whl + 2 * i + 1]
            fz[i] = fzf * fp[wf + 6] / sf if fp[wf + 7] > 0.0 else fzr * fp[wf + 6] / sr_
    sum_fx = 0.0
    p_slip = 0.0
    for i in range(nw):
        s = ip[whl + 2 * i]
        wf = ip[whl + 2 * i + 1]
        r = fp[wf + 1]
        f = 0.0
        if ext != 0:
            f = wheel_t[i] / r
        elif fz[i] > 0.0:
            bk = fp[wf + 2] * y[2 * n + i]
            x = bk - fp[wf + 4] * (bk - math.atan(bk))
            f = fp[wf] * fz[i] * math.sin(fp[wf + 3] * math.atan(x))
        fx[i] = f
        pe = ip[sec + SEC_STRIDE * s + 1] - ip[sec + SEC_STRIDE * s]
        a_w = sa[s, pe]
        qf[s] -= f * r * a_w
        p_slip += f * (a_w * qd[s] * r - v)
        sum_fx += f
    # accelerations, group by group (tree._accelerations); each section's group columns
    acc = np.zeros(max(n, 1))
    g_cs = np.zeros(ns, dtype=np.int64)
    g_k = np.zeros(ns, dtype=np.int64)
    ff = np.zeros(kmax)
    mm = np.zeros((kmax, kmax))
    ll = np.zeros((kmax, kmax))
    yy = np.zeros(kmax)
    xx = np.zeros(kmax)
    p = ip[tb + TB_GRP]
    for _g in range(ip[tb + TB_NG]):
        k = ip[p]
        nsec = ip[p + 1]
        nsp = ip[p + 2]
        cs = p + 3
        ss = cs + k
        spd = ss + nsec
        p = spd + 2 * nsp
        for j in range(nsec):
            g_cs[ip[ss + j]] = cs
            g_k[ip[ss + j]] = k
        if k == 1:
            mg = 0.0
            fg = 0.0
            for j in range(nsec):
                s = ip[ss + j]
                ms = m_s[s]
                r = rows[s, 0]
                fg_qd = qd[s]
                mg += ms * r * r
                fg += r * (qf[s] - c_s[s] * fg_qd * fg_qd - ms * bias[s])
            acc[ip[cs]] = fg / mg
            continue
        for i in range(k):
            ff[i] = 0.0
            for j in range(k):
                mm[i, j] = 0.0
        for j in range(nsec):
            s = ip[ss + j]
            ms = m_s[s]
            qs = qd[s]
            gen = qf[s] - c_s[s] * qs * qs - ms * bias[s]
            for i in range(k):
                ri = rows[s, i]
                if ri == 0.0:
                    continue
                ff[i] += ri * gen
                for jj in range(i + 1):
                    mm[i, jj] += ms * ri * rows[s, jj]
        for j in range(nsp):
            i = ip[spd + 2 * j]
            mm[i, i] += fp[ip[spd + 2 * j + 1]]
        for i in range(k):
            for j in range(i + 1):
                a_ = mm[i, j]
                for kk in range(j):
                    a_ -= ll[i, kk] * ll[j, kk]
                ll[i, j] = math.sqrt(a_) if i == j else a_ / ll[j, j]
        for i in range(k):
            a_ = ff[i]
            for kk in range(i):
                a_ -= ll[i, kk] * yy[kk]
            yy[i] = a_ / ll[i, i]
        for i in range(k - 1, -1, -1):
            a_ = yy[i]
            for kk in range(i + 1, k):
                a_ -= ll[kk, i] * xx[kk]
            xx[i] = a_ / ll[i, i]
        for i in range(k):
            acc[ip[cs + i]] = xx[i]
    res = roll + fp[bf + 3] + fp[bf + 4] * v * abs(v)
    return (q, qd, rows, bias, sphi, sa, sb, sr, acc, g_cs, g_k, spring_t, fx, p_damp, p_slip,
            sum_fx, res, fz)


@njit(cache=True)
def tree_rhs_wheels(t, y, ip, fp, te, wheel_t, dy):
    """dy/dt (in place) of a vehicle scene's state y (tree.py: [u, udot, kappa', v, work])
    with engine torque ``te`` and every tyre replaced by its outside resisting torque
    wheel_t[i] (N m): TreeDriveline.rhs under set_wheel_torques, in its order of operations
    (kernel/tree_nb.tree_rhs with F_x = T_w / r)."""
    n = ip[H_NDOF]
    tb = ip[H_TREE]
    nw = ip[tb + TB_NW]
    sec = ip[tb + TB_SEC]
    (_q, qd, _rows, _bias, _sphi, sa, _sb, _sr, acc, _gcs, _gk, _spt, _fx, p_damp, p_slip,
     sum_fx, res, _fz) = _tree_dynamics(y, ip, fp, te, 1, wheel_t)
    for i in range(n):
        dy[i] = y[n + i]
        dy[n + i] = acc[i]
    iv = 2 * n + nw
    v = y[iv]
    whl = ip[tb + TB_WHEEL]
    for i in range(nw):
        s = ip[whl + 2 * i]
        wf = ip[whl + 2 * i + 1]
        pe = ip[sec + SEC_STRIDE * s + 1] - ip[sec + SEC_STRIDE * s]
        om = sa[s, pe] * qd[s]
        kap = y[2 * n + i]
        dy[2 * n + i] = (om * fp[wf + 1] - v - abs(v) * kap) / fp[wf + 5]
    bf = ip[tb + TB_BODY_F]
    dy[iv] = (sum_fx - res) / fp[bf]
    if ip[H_ENERGY] != 0:
        dy[iv + 1] = te * y[n + ip[sec + 5]]
        dy[iv + 2] = p_damp
        dy[iv + 3] = p_slip
        dy[iv + 4] = res * v


@njit(cache=True)
def _walk(y, ip, fp, te, ext, wheel_t, tab, ends, pos, vel, eff):
    """The backward walk into pos/vel/eff (members left as their joint's input); returns
    _tree_dynamics' F_x and F_z per wheel and, for the energy (kernel/tree_run_nb.py), the
    section angles q, speeds qdot and per position angle and ratio a."""
    tb = ip[H_TREE]
    ns = ip[tb + TB_NS]
    sec = ip[tb + TB_SEC]
    ops = ip[tb + TB_OPS]
    dif = ip[tb + TB_DIFF]
    whl = ip[tb + TB_WHEEL]
    maxp = sa_width(ip)
    (q, qd, rows, bias, sphi, sa, sb, sr, acc, g_cs, g_k, spring_t, fx, _pd, _ps,
     _sfx, _res, fz) = _tree_dynamics(y, ip, fp, te, ext, wheel_t)
    # backward walk, deepest section first, from each section's end torque
    start_t = np.zeros(ns)
    st_tq = np.zeros((ns, maxp))
    for s in range(ns - 1, -1, -1):
        o = sec + SEC_STRIDE * s
        cs = g_cs[s]
        qdd = 0.0
        for i in range(g_k[s]):
            qdd += rows[s, i] * acc[ip[cs + i]]
        qdd += bias[s]
        kind = ends[s, 0]
        idx = ends[s, 1]
        if kind == END_WHEEL:
            t_end = fx[idx] * fp[ip[whl + 2 * idx + 1] + 1]
        elif kind == END_SPRING:
            t_end = spring_t[idx]
        elif kind == END_DIFF:
            t_end = start_t[ip[dif + 3 * idx]] + start_t[ip[dif + 3 * idx + 1]]
        else:
            t_end = 0.0
        nop = ip[o + 1] - ip[o]
        torque = t_end
        st_tq[s, nop] = torque
        qs = qd[s]
        for kk in range(nop - 1, -1, -1):
            if ip[ops + 2 * (ip[o] + kk)] == OP_INERTIA:
                jv = fp[ip[ops + 2 * (ip[o] + kk) + 1]]
                torque += jv * (sa[s, kk + 1] * qdd + sb[s, kk + 1] * qs * qs)
            else:
                torque *= sr[s, kk]
            st_tq[s, kk] = torque
        start_t[s] = torque
    for i in range(tab.shape[0]):
        s, pp = tab[i, 0], tab[i, 1]
        pos[i] = sphi[s, pp]
        vel[i] = sa[s, pp] * qd[s]
        eff[i] = 0.0 if tab[i, 2] == 1 else st_tq[s, pp]
    return fx, fz, q, qd, sphi, sa


@njit(cache=True)
def tree_joint_state(y, ip, fp, te, ext, wheel_t, tab, ends, mtab, mfp, pos, vel, eff):
    """Shaft positions (rad), speeds (rad/s) and torques (N m) of state y into pos/vel/eff
    (rows of ``tab``) for engine torque ``te`` (N m); ``ext`` != 0: wheel i's tyre is
    replaced by the resisting torque wheel_t[i] (N m). Intermediate members of ``mtab``
    filled. Returns False (outputs untouched) when y is not finite."""
    for i in range(y.shape[0]):
        if not np.isfinite(y[i]):
            return False
    _walk(y, ip, fp, te, ext, wheel_t, tab, ends, pos, vel, eff)
    fill_mid_one(pos, vel, mtab, mfp)
    return True


@njit(cache=True)
def tree_sample(y, ip, fp, te, wheel_t, tab, ends, pos, vel, eff, wheels):
    """One offline sample of a vehicle scene (TreeDriveline.sample_outputs with the tyres):
    pos/vel/eff as :func:`tree_joint_state` with members left as their joint's input, per
    wheel i ``wheels[i]`` = (relaxed slip, F_x N, F_z N, status: 0 ok, 1 no load F_z <= 0);
    returns sum F_x r (N m). ``y`` must be finite (the caller checks)."""
    fx, fz, _q, _qd, _sphi, _sa = _walk(y, ip, fp, te, 0, wheel_t, tab, ends, pos, vel, eff)
    tb = ip[H_TREE]
    n = ip[H_NDOF]
    whl = ip[tb + TB_WHEEL]
    tl = 0.0
    for i in range(ip[tb + TB_NW]):
        tl += fx[i] * fp[ip[whl + 2 * i + 1] + 1]
        wheels[i, 0] = y[2 * n + i]
        wheels[i, 1] = fx[i]
        wheels[i, 2] = fz[i]
        wheels[i, 3] = 0.0 if fz[i] > 0.0 else 1.0
    return tl
