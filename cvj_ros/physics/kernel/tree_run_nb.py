"""Compiled outputs of a whole offline vehicle run, every sample in one call.

``tree_run_outputs`` gives per sample what ``TreeDriveline.sample_outputs`` and the
vehicle speed give (cvj_ros/physics/tree.py), from the landing states of one compiled
landing call: the engine torque of the model's in-kernel engine (``rhs_nb.engine_torque``,
as the compiled rhs evaluates it), the joint states and tyre forces of the compiled walk
(``tree_outputs_nb._walk``), sum F_x r, the wheel channels, and the energy residual

    (E_kin + E_el - E0 - W_engine + W_damp + W_slip + W_road) / max(|terms|, 1e-12),
    E_kin = sum_s M_s qdot_s^2 / 2 + sum_d P_d delta_dot_d^2 / 2 + m v^2 / 2,
    E_el = sum c (e^2/2 + k2 e^4/4)   (sections.SpringLaw.evaluate's potential)

(``TreeDriveline.energy``, ``energy_residual``: M_s = sum J a^2 over the section's
inertias, the spiders' P from the group table), then the intermediate members
(``outputs_nb.fill_mid_samples``). A new module so the kernel files' numba caches stay
valid.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from cvj_ros.physics.kernel.borrow_nb import borrowed_all
from cvj_ros.physics.kernel.layout import (
    H_ENERGY, H_NDOF, H_SPRING_F, H_TREE, OP_INERTIA, SEC_STRIDE, SPRING_STRIDE, TB_BODY_F,
    TB_GRP, TB_NG, TB_NS, TB_NSPR, TB_NW, TB_OPS, TB_SEC, TB_SPR, TB_WHEEL)
from cvj_ros.physics.kernel.outputs_nb import fill_mid_samples
from cvj_ros.physics.kernel.rhs_nb import engine_torque, spring_deflection
from cvj_ros.physics.kernel.tree_outputs_nb import _walk

__all__ = ['tree_energy', 'tree_run_outputs', 'warm', 'CH_SPEED', 'CH_PER_WHEEL']

#: rows of the channel array: the vehicle speed, then per wheel i rows
#: 1 + CH_PER_WHEEL i + (0 relaxed slip, 1 F_x, 2 F_z, 3 status)
CH_SPEED, CH_PER_WHEEL = 0, 4


@njit(cache=True)
def tree_energy(y, ip, fp, q, qd, sphi, sa):
    """(kinetic, elastic) energy (J) of state y from its walk's section angles ``q``,
    speeds ``qd`` and per position angle ``sphi`` and ratio ``sa`` (TreeDriveline.energy,
    its order of additions)."""
    n = ip[H_NDOF]
    tb = ip[H_TREE]
    sec = ip[tb + TB_SEC]
    ops = ip[tb + TB_OPS]
    ke = 0.0
    for s in range(ip[tb + TB_NS]):
        o = sec + SEC_STRIDE * s
        m = 0.0
        p = 0
        for k in range(ip[o], ip[o + 1]):
            if ip[ops + 2 * k] == OP_INERTIA:
                a = sa[s, p]
                m += fp[ip[ops + 2 * k + 1]] * a * a
            p += 1
        ke += 0.5 * m * qd[s] * qd[s]
    # the spiders (group table: local index, fp offset of P per spider)
    p = ip[tb + TB_GRP]
    for _g in range(ip[tb + TB_NG]):
        k = ip[p]
        nsec = ip[p + 1]
        nsp = ip[p + 2]
        cs = p + 3
        spd = cs + k + nsec
        for j in range(nsp):
            dd = y[n + ip[cs + ip[spd + 2 * j]]]
            ke += 0.5 * fp[ip[spd + 2 * j + 1]] * dd * dd
        p = spd + 2 * nsp
    v = y[2 * n + ip[tb + TB_NW]]
    ke += 0.5 * fp[ip[tb + TB_BODY_F]] * v * v
    el = 0.0
    spr = ip[tb + TB_SPR]
    sp0 = ip[H_SPRING_F]
    for k in range(ip[tb + TB_NSPR]):
        left = ip[spr + 2 * k]
        right = ip[spr + 2 * k + 1]
        pe = ip[sec + SEC_STRIDE * left + 1] - ip[sec + SEC_STRIDE * left]
        off = sp0 + SPRING_STRIDE * k
        e = spring_deflection(sphi[left, pe] - q[right], fp[off + 3], fp[off + 4])[0]
        el += fp[off] * (0.5 * e * e + 0.25 * fp[off + 2] * e ** 4)
    return ke, el


@njit(cache=True)
def tree_run_outputs(times, XG, rows, ip, fp, tab, ends, e0, pos, vel, eff, te, tl, res, ch,
                     mtab, mfp, wheel_t):
    """For every sample k (time times[k], state XG[rows[k]]): shaft positions, speeds and
    torques (pos/vel/eff[k], rows of ``tab``, ``ends``: tree_outputs_nb.tree_tables), the
    engine torque and sum F_x r (te/tl[k], N m), the energy residual (res[k]; NaN without
    work integrals) and the channels ch[:, k] (CH_*: vehicle speed m/s, per wheel relaxed
    slip, F_x N, F_z N, status 0 ok / 1 no load); then, every sample finite, the
    intermediate members of ``mtab``/``mfp`` (outputs_nb.mid_table). ``wheel_t``: scratch
    of max(wheels, 1). Returns the first sample whose state is not finite, or -1."""
    (times, XG, rows, ip, fp, tab, ends, pos, vel, eff, te, tl, res, ch, mtab, mfp,
     wheel_t) = borrowed_all((times, XG, rows, ip, fp, tab, ends, pos, vel, eff, te, tl, res,
                              ch, mtab, mfp, wheel_t))
    n = ip[H_NDOF]
    tb = ip[H_TREE]
    nw = ip[tb + TB_NW]
    whl = ip[tb + TB_WHEEL]
    iv = 2 * n + nw
    ns = XG.shape[1]
    for k in range(times.shape[0]):
        y = XG[rows[k]]
        for i in range(ns):
            if not np.isfinite(y[i]):
                return k
        tk_e = engine_torque(times[k], y, ip, fp)[0]
        fx, fz, q, qd, sphi, sa = _walk(y, ip, fp, tk_e, 0, wheel_t, tab, ends, pos[k],
                                        vel[k], eff[k])
        te[k] = tk_e
        t_l = 0.0
        for i in range(nw):
            t_l += fx[i] * fp[ip[whl + 2 * i + 1] + 1]
            r = 1 + CH_PER_WHEEL * i
            ch[r, k] = y[2 * n + i]
            ch[r + 1, k] = fx[i]
            ch[r + 2, k] = fz[i]
            ch[r + 3, k] = 0.0 if fz[i] > 0.0 else 1.0
        tl[k] = t_l
        ch[CH_SPEED, k] = y[iv]
        if ip[H_ENERGY] != 0:
            ke, el = tree_energy(y, ip, fp, q, qd, sphi, sa)
            tot = ke + el
            we, wd, ws, wr = y[iv + 1], y[iv + 2], y[iv + 3], y[iv + 4]
            scale = max(abs(tot), abs(e0), abs(we), abs(wd), abs(ws), abs(wr), 1e-12)
            res[k] = (tot - e0 - we + wd + ws + wr) / scale
        else:
            res[k] = np.nan
    if mtab.shape[0] > 0:
        fill_mid_samples(pos, vel, mtab, mfp)
    return -1


def warm(driveline) -> None:
    """Compile or load :func:`tree_run_outputs` (``make kernel``) on a TreeDriveline's x0,
    with the argument types ``Simulation.run`` passes."""
    from cvj_ros.physics.kernel.layout import build_model
    from cvj_ros.physics.kernel.outputs_nb import mid_table
    from cvj_ros.physics.kernel.tree_outputs_nb import tree_tables
    model = build_model(driveline)
    tab, ends = tree_tables(driveline)
    mtab, mfp, _python = mid_table(driveline)
    m, ns = 2, len(driveline.shaft_names)
    tree_run_outputs(np.array([0.0, 1e-3]), np.tile(model.x0, (m, 1)), np.arange(m), model.ip,
                     model.fp, tab, ends, 0.0, np.empty((m, ns)), np.empty((m, ns)),
                     np.empty((m, ns)), np.empty(m), np.empty(m), np.empty(m),
                     np.empty((1 + CH_PER_WHEEL * driveline.n_wheel, m)),
                     np.ascontiguousarray(mtab, dtype=np.int64), mfp,
                     np.zeros(max(driveline.n_wheel, 1)))
