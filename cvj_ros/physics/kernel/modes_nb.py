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

:func:`cvj_ros.physics.kernel.segment_nb.mode_segment` integrates one mode on this
right-hand side (dopri5, dop853 or a RODAS method), checks its witnesses
(:func:`witness_values`) after every step and locates the earliest crossing on the dense
output; the discrete transition is the caller's (``kernel/modes.py``, the oracle's
decision code).

ip layout (MH_* header): n groups; op table offset (n+1 op starts, then (code, fp offset)
pairs: layout.OP_* codes and OP_COUPLING fp = [k, offset]: phi_out = k phi_in + offset);
link table offset (n-1 rows of (kind LINK_*, spring fp offset, clutch mode sign)); engine
code and fp offset; load code and fp offset; pinned 0/1; brake mode sign (0: no brake
torque); witness count and table offset (rows (kind W_*, reference, direction));
stuck-slot count and table offset (rows (group, global op index of the clutch coupling));
fp offset of the channel block CH_* (flags, packs, stall speed) and of the three ramps
(throttle, clutch pedal, brake: [m, t_0..t_m-1, v_0..v_m-1, t_end], commands.Ramp; t_end:
the integrated segment's end, where a jump is seen from the left, inf outside a segment).
"""
from __future__ import annotations

from numba import njit

from cvj_ros.physics.kernel.joints_nb import joint_eval
from cvj_ros.physics.kernel.layout import OP_INERTIA
from cvj_ros.physics.kernel.rhs_nb import spring_eval
from cvj_ros.physics.kernel.sources_nb import engine_eval, load_eval

__all__ = ['M_DOP853', 'M_DOPRI5', 'mode_eval', 'witness_values']

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


@njit(cache=True, inline='always')
def ramp(t, fp, off):
    """commands.Ramp.at(t, t_end): piecewise linear through (t_j, v_j), held outside, 0
    without rows; k = rows at or before t (bisect_right). Block [m, t_0.., v_0.., t_end]:
    at or beyond t_end (the integrated segment's end, :func:`set_ramp_end`) a jump there (two
    rows at t_end) is seen from the left, the value of its first row."""
    m = int(fp[off])
    if m == 0:
        return 0.0
    ts = off + 1
    vs = ts + m
    te = fp[vs + m]
    if t >= te:
        lo = 0
        hi = m
        while lo < hi:               # rows before t_end (bisect_left)
            mid = (lo + hi) // 2
            if fp[ts + mid] < te:
                lo = mid + 1
            else:
                hi = mid
        if lo + 1 < m and fp[ts + lo] == te and fp[ts + lo + 1] == te:
            return fp[vs + lo]
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


@njit(cache=True)
def set_ramp_end(fp, off, t_end):
    """Write the segment end t_end (s) into the ramp block at fp[off] (:func:`ramp`)."""
    m = int(fp[off])
    fp[off + 1 + 2 * m] = t_end


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
