"""Analytic Jacobian of a chain mode's right-hand side (``modes_nb.mode_eval``).

d(mode rhs)/dy for y = [q_g, q'_g, W_engine, W_load, W_damp, W_friction], the same terms as
the event-free kernel's ``rhs_nb.jac`` (M(q) q'' + C(q) q'^2 = Q per group, the chain rule
through the joints, springs by ``rhs_nb.spring_eval``'s slopes, engine and load by
``sources_nb``'s analytic slopes) on the mode's merged groups, plus the mode's own terms:

* a slipping clutch link carries the constant (in y) torque T = s mu_k cgeo fn_max f_n(t):
  dQ_g/dq_g = -T b_g, dQ_g+1 = 0; its friction power T thetadot adds T d(thetadot)/dy;
* the brake torque T_b a_last on the last group: dQ/dq_last = -T_b b_last, friction power
  T_b omega_last;
* a stuck brake pins the last group: its q' and q'' rows are zero.

As in ``rhs_nb.jac`` only dC/dq (the joints' third derivative, not in the joint contract) is
a central difference of C(q), increment 1e-6 max(1, |q|). The Python reference's twin is
``hybrid/chain_jac.mode_jacobian`` (the same formula, term by term).
"""
from __future__ import annotations

import numpy as np
from numba import njit

from cvj_ros.physics.kernel.layout import OP_INERTIA
from cvj_ros.physics.kernel.modes_nb import (CH_THROTTLE, LINK_CLUTCH, LINK_SPRING, MH_BRAKE,
                                             MH_ENGINE, MH_ENGINE_F, MH_LINKS, MH_LOAD,
                                             MH_LOAD_F, MH_N, MH_OPS, MH_PINNED, MH_CHAN_F,
                                             MH_RAMP_T, capacities, group_kin, op_eval, ramp)
from cvj_ros.physics.kernel.rhs_nb import spring_deflection, spring_eval
from cvj_ros.physics.kernel.sources_nb import engine_eval, load_eval

__all__ = ['mode_jac']


@njit(cache=True, inline='always')
def _group_dm(g, q, ip, fp):
    """(dM/dq, has a joint or coupling op) of group g at q: dM/dq = sum 2 J a b (a' = b)."""
    tab = ip[MH_OPS]
    n = ip[MH_N]
    ops = tab + n + 1
    phi, a, b, mp = q, 1.0, 0.0, 0.0
    hj = False
    for k in range(ip[tab + g], ip[tab + g + 1]):
        code = ip[ops + 2 * k]
        off = ip[ops + 2 * k + 1]
        if code == OP_INERTIA:
            mp += 2.0 * fp[off] * a * b
        else:
            po, r, s = op_eval(code, phi, fp, off)
            hj = True
            b = s * a * a + r * b
            a = r * a
            phi = po
    return mp, hj


@njit(cache=True)
def mode_jac(t, y, ip, fp, J):
    """d(mode_eval)/dy at (t, y) into J (n_state x n_state, overwritten)."""
    n = ip[MH_N]
    n2 = 2 * n
    ns = J.shape[0]
    for i in range(ns):
        for j in range(ns):
            J[i, j] = 0.0
    ch = ip[MH_CHAN_F]
    ck, _cs, bk, _bs = capacities(t, ip, fp)
    if fp[ch + CH_THROTTLE] != 0.0:
        fp[ip[MH_ENGINE_F]] = ramp(t, fp, ip[MH_RAMP_T])
    # per group: phi_end, a, b, M, C, dM/dq, dC/dq, Q; then dQ_g/dy (n x 2n), dP_damp/dy,
    # dP_friction/dy
    sc = np.zeros((8, n))
    dq = np.zeros((n, n2))
    dpd = np.zeros(n2)
    dpf = np.zeros(n2)
    for g in range(n):
        q = y[g]
        phi, a, b, m, c = group_kin(g, q, ip, fp)
        mp, hj = _group_dm(g, q, ip, fp)
        if hj:
            h = 1e-6 * max(1.0, abs(q))
            cp = (group_kin(g, q + h, ip, fp)[4] - group_kin(g, q - h, ip, fp)[4]) / (2.0 * h)
        else:
            cp = 0.0
        sc[0, g] = phi
        sc[1, g] = a
        sc[2, g] = b
        sc[3, g] = m
        sc[4, g] = c
        sc[5, g] = mp
        sc[6, g] = cp
    v0 = y[n]
    te, dte, dtep = engine_eval(t, v0, y[0], ip, fp, MH_ENGINE, ip[MH_ENGINE_F])
    al = sc[1, n - 1]
    bl = sc[2, n - 1]
    vl = y[n2 - 1]
    omega_last = al * vl
    tl, dtl, dtlp = load_eval(t, omega_last, sc[0, n - 1], ip, fp, MH_LOAD, ip[MH_LOAD_F])
    sc[7, 0] += te
    dq[0, n] += dte
    dq[0, 0] += dtep
    sc[7, n - 1] -= tl * al
    dq[n - 1, n - 1] += -tl * bl - dtl * bl * vl * al - dtlp * al * al
    dq[n - 1, n2 - 1] += -dtl * al * al
    bm = ip[MH_BRAKE]
    if bm != 0:
        tb = bm * bk
        sc[7, n - 1] -= tb * al
        dq[n - 1, n - 1] -= tb * bl
        dpf[n - 1] += tb * bl * vl
        dpf[n2 - 1] += tb * al
    links = ip[MH_LINKS]
    for k in range(n - 1):
        row = links + 3 * k
        kind = ip[row]
        a_l = sc[1, k]
        b_l = sc[2, k]
        thd = a_l * y[n + k] - y[n + k + 1]
        dthd_qk = b_l * y[n + k]
        if kind == LINK_SPRING:
            off = ip[row + 1]
            th = sc[0, k] - y[k + 1]
            ts, k_th, k_d, _pd = spring_eval(th, thd, fp, off)
            d_qk = k_th * a_l + k_d * dthd_qk
            d_qk1 = -k_th
            d_vk = k_d * a_l
            d_vk1 = -k_d
            sc[7, k] -= ts * a_l
            sc[7, k + 1] += ts
            dq[k, k] -= d_qk * a_l + ts * b_l
            dq[k, k + 1] -= d_qk1 * a_l
            dq[k, n + k] -= d_vk * a_l
            dq[k, n + k + 1] -= d_vk1 * a_l
            dq[k + 1, k] += d_qk
            dq[k + 1, k + 1] += d_qk1
            dq[k + 1, n + k] += d_vk
            dq[k + 1, n + k + 1] += d_vk1
            d = fp[off + 1]
            if d != 0.0:
                _e, de, dde = spring_deflection(th, fp[off + 3], fp[off + 4])
                dp_dth = d * dde * thd * thd
                dp_dthd = 2.0 * d * de * thd
                dpd[k] += dp_dth * a_l + dp_dthd * dthd_qk
                dpd[k + 1] -= dp_dth
                dpd[n + k] += dp_dthd * a_l
                dpd[n + k + 1] -= dp_dthd
        elif kind == LINK_CLUTCH:
            ts = ip[row + 2] * ck
            sc[7, k] -= ts * a_l
            sc[7, k + 1] += ts
            dq[k, k] -= ts * b_l
            dpf[k] += ts * dthd_qk
            dpf[n + k] += ts * a_l
            dpf[n + k + 1] -= ts
    pinned = ip[MH_PINNED] != 0
    for g in range(n):
        if pinned and g == n - 1:
            continue
        J[g, n + g] = 1.0
        v = y[n + g]
        inv = 1.0 / sc[3, g]
        r = n + g
        for j in range(n2):
            J[r, j] = dq[g, j] * inv
        J[r, g] += -sc[6, g] * v * v * inv - (sc[7, g] - sc[4, g] * v * v) * sc[5, g] * inv * inv
        J[r, n + g] += -2.0 * sc[4, g] * v * inv
    J[n2, n] = te + dte * v0
    J[n2, 0] += dtep * v0
    J[n2 + 1, n - 1] = tl * bl * vl + dtl * bl * vl * al * vl + dtlp * al * al * vl
    J[n2 + 1, n2 - 1] = tl * al + dtl * al * al * vl
    for j in range(n2):
        J[n2 + 2, j] = dpd[j]
        J[n2 + 3, j] = dpf[j]
