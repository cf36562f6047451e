"""Compiled driveline right-hand side and analytic Jacobian.

Same equations as the readable oracle ``Driveline._rhs`` / ``Driveline.jacobian``
(see cvj_ros/physics/driveline.py module docstring: M(q) qddot + C(q) qdot^2 = Q per rigid
section, springs on the bounded twist theta = phi_end(q_k) - q_{k+1}), evaluated from the
arrays of ``kernel/layout.py``. Plain loops only (no BLAS, no numpy reductions), cache=True,
no fastmath, so the bytes do not depend on the CPU's BLAS kernel.
"""
from __future__ import annotations

import math

import numpy as np

from numba import njit

from cvj_ros.physics.kernel.borrow_nb import STACK_MAX_DOUBLES, stack_zeros_2d
from cvj_ros.physics.kernel.joints_nb import joint_eval
from cvj_ros.physics.kernel.layout import (
    ENGINE_INPUTS, H_ENERGY, H_ENGINE, H_ENGINE_F, H_IMBALANCE, H_INPUT_F, H_LOAD, H_LOAD_F,
    H_JAC_CONST, H_NDOF, H_SEC, H_SEC_PRE,
    H_SPRING_F, H_TREE, IN_KE, IN_KL, IN_TE, IN_TE_RATE, IN_TK, IN_TL, IN_TL_RATE, IN_WE, IN_WL,
    LOAD_INPUTS, OP_INERTIA, SPRING_STRIDE)
from cvj_ros.physics.kernel.sources_nb import engine_eval, load_eval


@njit(cache=True, inline='always')
def section(g, q, ip, fp):
    """(phi_end rad, a_end -, b_end 1/rad, M kg m^2, C kg m^2/rad, dM/dq, has_joint) of
    section g at angle q: chain rule a <- r a, b <- s a^2 + r b over the section's ops,
    from the end of its constant prefix (layout.section_prefix: phi = q k, a, b = 0, M, the
    same bits as the loop over those ops)."""
    n = ip[H_NDOF]
    tab = ip[H_SEC]
    ops = tab + n + 1
    pre = ip[H_SEC_PRE] + 3 * g
    po = ip[pre + 2]
    phi, a, b, m, c, mp = q * fp[po], fp[po + 1], 0.0, fp[po + 2], 0.0, 0.0
    has_joint = ip[pre + 1] != 0
    for k in range(ip[pre], ip[tab + g + 1]):
        code = ip[ops + 2 * k]
        off = ip[ops + 2 * k + 1]
        if code == OP_INERTIA:
            jv = fp[off]
            m += jv * a * a
            c += jv * a * b
            mp += 2.0 * jv * a * b
        else:
            has_joint = True
            po, r, s = joint_eval(code, phi, fp, off)
            b = s * a * a + r * b
            a = r * a
            phi = po
    return phi, a, b, m, c, mp, has_joint


@njit(cache=True)
def imbalance_force(g, q, ip, fp):
    """(Q N m, dQ/dq N m/rad, V J) of section g's unbalanced inertias at q (table at
    ip[H_IMBALANCE]; sections.section_imbalance): V = sum m g e sin(phi_i + angle)."""
    n = ip[H_NDOF]
    tab = ip[H_SEC]
    ops = tab + n + 1
    it = ip[H_IMBALANCE]
    cnt = ip[it]
    phi, a, b = q, 1.0, 0.0
    qf, dq, v = 0.0, 0.0, 0.0
    for k in range(ip[tab + g], ip[tab + g + 1]):
        code = ip[ops + 2 * k]
        off = ip[ops + 2 * k + 1]
        if code == OP_INERTIA:
            for i in range(cnt):
                if ip[it + 1 + 3 * i + 1] == k:
                    fo = ip[it + 1 + 3 * i + 2]
                    mge = fp[fo]
                    c = math.cos(phi + fp[fo + 1])
                    sn = math.sin(phi + fp[fo + 1])
                    qf -= mge * c * a
                    dq += mge * (sn * a * a - c * b)
                    v += mge * sn
        else:
            po, r, s = joint_eval(code, phi, fp, off)
            b = s * a * a + r * b
            a = r * a
            phi = po
    return qf, dq, v


@njit(cache=True)
def imbalance_torque(k, phi, ip, fp):
    """Resisting weight torque m g e cos(phi + angle) (N m) of op k, 0 if balanced."""
    it = ip[H_IMBALANCE]
    if it == 0:
        return 0.0
    for i in range(ip[it]):
        if ip[it + 1 + 3 * i + 1] == k:
            fo = ip[it + 1 + 3 * i + 2]
            return fp[fo] * math.cos(phi + fp[fo + 1])
    return 0.0


@njit(cache=True, inline='always')
def _sigmoid_of(u, z):
    """_sigmoid(u) given z = exp(-|u|): the same bits (exp(-u) for u >= 0, exp(u) below),
    one exp shared with the softplus instead of two."""
    if u >= 0.0:
        return 1.0 / (1.0 + z)
    return z / (1.0 + z)


#: above it, exp(-u) < 4.3e-18 vanishes in u + log1p(exp(-u)) (half an ulp of u >= 32 is
#: 3.6e-15) and in 1 + exp(-u) (< 2^-54): softplus = w u and sigmoid = 1, exactly
SOFTPLUS_LINEAR_U = 40.0


@njit(cache=True, inline='always')
def _softplus_sigmoid(u, w):
    """(w softplus(u), sigmoid(u)) as sections.SpringLaw.deflection writes them,
    w (max(u, 0) + log1p(exp(-|u|))) and 1/(1 + exp(-u)) (exp(u)/(1 + exp(u)) below 0), with
    exp(-|u|) computed once; for u > SOFTPLUS_LINEAR_U the same bits without exp and log1p
    (a spring preloaded beyond its lash sits there on one side)."""
    if u > SOFTPLUS_LINEAR_U:
        return w * u, 1.0
    z = math.exp(-abs(u))
    return w * (max(u, 0.0) + math.log1p(z)), _sigmoid_of(u, z)


@njit(cache=True, inline='always')
def spring_deflection(th, g, w):
    """(e, de/dtheta, d2e/dtheta2) of the softplus dead zone (driveline.SpringLaw:
    sections.SpringLaw.deflection, the same expressions and bits; per side
    :func:`_softplus_sigmoid`)."""
    if g == 0.0:
        return th, 1.0, 0.0
    u1 = (th - g) / w
    u2 = (-th - g) / w
    sp1, s1 = _softplus_sigmoid(u1, w)
    sp2, s2 = _softplus_sigmoid(u2, w)
    return sp1 - sp2, s1 + s2, (s1 * (1.0 - s1) - s2 * (1.0 - s2)) / w


@njit(cache=True, inline='always')
def deflection_slope(th, g, w):
    """(e, de/dtheta) of :func:`spring_deflection`, the same bits, for the rhs (which needs no
    d2e/dtheta2): beyond the linear cut on one side (u1 or u2 > SOFTPLUS_LINEAR_U) the other
    side has u < -SOFTPLUS_LINEAR_U - 2 g/w, so its softplus w log1p(exp(u)) < 4.3e-18 w is
    below half an ulp of the first side's w u >= 40 w and its sigmoid below 2^-54: e = w u1
    (or -w u2) and de = 1 exactly, without the exp and log1p of that side."""
    if g == 0.0:
        return th, 1.0
    u1 = (th - g) / w
    u2 = (-th - g) / w
    if u1 > SOFTPLUS_LINEAR_U:
        return w * u1, 1.0
    if u2 > SOFTPLUS_LINEAR_U:
        return -(w * u2), 1.0
    sp1, s1 = _softplus_sigmoid(u1, w)
    sp2, s2 = _softplus_sigmoid(u2, w)
    return sp1 - sp2, s1 + s2


@njit(cache=True, inline='always')
def spring_torque(th, thd, fp, off):
    """(torque N m, dissipated power W) of the spring at fp[off:off+5]: the first and last
    values of :func:`spring_eval`, the same bits, from :func:`deflection_slope`."""
    c = fp[off]
    d = fp[off + 1]
    k2 = fp[off + 2]
    e, de = deflection_slope(th, fp[off + 3], fp[off + 4])
    f_el = c * (e + k2 * e * e * e)
    return f_el * de + d * de * thd, d * de * thd * thd


@njit(cache=True, inline='always')
def spring_eval(th, thd, fp, off):
    """(torque N m, dT/dtheta, dT/dthetadot, dissipated power W) of spring at fp[off:off+5]."""
    c = fp[off]
    d = fp[off + 1]
    k2 = fp[off + 2]
    e, de, dde = spring_deflection(th, fp[off + 3], fp[off + 4])
    f_el = c * (e + k2 * e * e * e)
    t = f_el * de + d * de * thd
    k_th = c * (1.0 + 3.0 * k2 * e * e) * de * de + f_el * dde + d * dde * thd
    return t, k_th, d * de, d * de * thd * thd


@njit(cache=True)
def spring_vary_eval(th, thd, phi, fp, off):
    """A spring with circumferentially varying stiffness (SpringLaw.evaluate_varying): the
    potential s(phi) V(theta), s = 1 + sum eps cos(n phi + psi) from the block at
    fp[fp[off + 5]]. Returns (torque on both sides, extra -s' V on the right side, dT/dtheta,
    dT/dthetadot, dT/dphi, dextra/dtheta, dextra/dphi, potential s V, dissipated power)."""
    c = fp[off]
    d = fp[off + 1]
    k2 = fp[off + 2]
    e, de, dde = spring_deflection(th, fp[off + 3], fp[off + 4])
    f_el = c * (e + k2 * e * e * e)
    el = f_el * de
    k_el = c * (1.0 + 3.0 * k2 * e * e) * de * de + f_el * dde
    v0 = c * (0.5 * e * e + 0.25 * k2 * e ** 4)
    vb = int(fp[off + 5])
    s, s1, s2 = 1.0, 0.0, 0.0
    for i in range(int(fp[vb])):
        n = fp[vb + 1 + 3 * i]
        eps = fp[vb + 2 + 3 * i]
        x = n * phi + fp[vb + 3 + 3 * i]
        cx = math.cos(x)
        sx = math.sin(x)
        s += eps * cx
        s1 -= eps * n * sx
        s2 -= eps * n * n * cx
    return (s * el + d * de * thd, -s1 * v0, s * k_el + d * dde * thd, d * de, s1 * el,
            -s1 * el, -s2 * v0, s * v0, d * de * thd * thd)


@njit(cache=True, inline='always')
def engine_torque(t, y, ip, fp):
    """(Te, dTe/domega, dTe/dphi) at the engine shaft (omega = y[n], phi = y[0])."""
    n = ip[H_NDOF]
    inp = ip[H_INPUT_F]
    we = y[n]
    if ip[H_ENGINE] == ENGINE_INPUTS:
        te = fp[inp + IN_TE] + fp[inp + IN_TE_RATE] * (t - fp[inp + IN_TK]) \
            + fp[inp + IN_KE] * (we - fp[inp + IN_WE])
        return te, fp[inp + IN_KE], 0.0
    return engine_eval(t, we, y[0], ip, fp, H_ENGINE, ip[H_ENGINE_F])


@njit(cache=True, inline='always')
def load_torque(t, y, ip, fp, phi_load, a_load):
    """(Tl, dTl/domega, dTl/dphi) at the load shaft (omega = a_load y[2n-1], phi_load)."""
    n = ip[H_NDOF]
    inp = ip[H_INPUT_F]
    wl = a_load * y[2 * n - 1]
    if ip[H_LOAD] == LOAD_INPUTS:
        tl = fp[inp + IN_TL] + fp[inp + IN_TL_RATE] * (t - fp[inp + IN_TK]) \
            + fp[inp + IN_KL] * (wl - fp[inp + IN_WL])
        return tl, fp[inp + IN_KL], 0.0
    return load_eval(t, wl, phi_load, ip, fp, H_LOAD, ip[H_LOAD_F])


@njit(cache=True, inline='always')
def section_accel(t, y, ip, fp, g, phi, a, m, c, te, carry):
    """(acceleration rad/s^2, carry N m, Tl N m, damping power W) of section g given its
    end angle phi, ratio a, reduced inertia M and C (:func:`section`), the engine torque Te
    and the torque carried in from the spring to its left: qddot = (Q - C v^2) / M with
    Q_g = ((0 + Te) - Tl a_load) + T_s,g-1 - T_s,g a_g in the oracle's order of additions.
    carry is the torque the spring to its right carries into section g + 1 (unchanged in
    the last section), Tl is 0.0 except in the last section, the power 0.0 in it.
    The per-section body of :func:`rhs`, written out again for the sample walk
    (outputs_nb) so that rhs keeps its own loop and speed: it must stay equal to rhs bit for
    bit (test/physics/kernel/test_outputs_nb.py compares both on every shipped chain scene
    and joint kind)."""
    n = ip[H_NDOF]
    qf = 0.0
    tl = 0.0
    pd = 0.0
    if g == 0:
        qf += te
    if g == n - 1:
        tl, _dtl, _dtlp = load_torque(t, y, ip, fp, phi, a)
        qf -= tl * a
    if ip[H_IMBALANCE] != 0:
        qf += imbalance_force(g, y[g], ip, fp)[0]
    if g > 0:
        qf += carry
    if g < n - 1:
        off = ip[H_SPRING_F] + SPRING_STRIDE * g
        th = phi - y[g + 1]
        thd = a * y[n + g] - y[n + g + 1]
        extra = 0.0
        if fp[off + 5] != 0.0:      # varying stiffness: extra torque on the right side
            vs = spring_vary_eval(th, thd, y[g + 1], fp, off)
            ts = vs[0]
            extra = vs[1]
            pd = vs[8]
        elif fp[off + 3] == 0.0:
            d = fp[off + 1]
            ts = fp[off] * (th + fp[off + 2] * th * th * th) + d * thd
            pd = d * thd * thd
        else:
            ts, pd = spring_torque(th, thd, fp, off)
        qf -= ts * a
        carry = ts + extra
    v = y[n + g]
    return (qf - c * v * v) / m, carry, tl, pd


@njit(cache=True, _nrt=False)
def rhs(t, y, ip, fp, dy):
    """dy/dt (filled in place, length n_state) of the driveline state y.

    One sweep engine -> load, no allocation: section g's generalised force is complete once
    the spring to its right is evaluated. The additions keep the oracle's order
    (Q_g = ((0 + Te) - Tl a_load) + T_s,g-1 - T_s,g a_g). A vehicle scene (ip[H_TREE] > 0)
    is kernel/tree_nb.py's."""
    if ip[H_TREE] != 0:
        _tree.tree_rhs(t, y, ip, fp, dy)
        return
    n = ip[H_NDOF]
    sp0 = ip[H_SPRING_F]
    te, _dte, _dtep = engine_torque(t, y, ip, fp)
    tl = 0.0
    a_load = 1.0
    carry = 0.0
    p_damp = 0.0
    for g in range(n):
        phi, a, _b, m, c, _mp, _hj = section(g, y[g], ip, fp)
        qf = 0.0
        if g == 0:
            qf += te
        if g == n - 1:
            a_load = a
            tl, _dtl, _dtlp = load_torque(t, y, ip, fp, phi, a)
            qf -= tl * a
        if ip[H_IMBALANCE] != 0:
            qf += imbalance_force(g, y[g], ip, fp)[0]
        if g > 0:
            qf += carry
        if g < n - 1:
            off = sp0 + SPRING_STRIDE * g
            th = phi - y[g + 1]
            thd = a * y[n + g] - y[n + g + 1]
            extra = 0.0
            if fp[off + 5] != 0.0:      # varying stiffness: extra torque on the right side
                vs = spring_vary_eval(th, thd, y[g + 1], fp, off)
                ts = vs[0]
                extra = vs[1]
                p_damp += vs[8]
            elif fp[off + 3] == 0.0:
                d = fp[off + 1]
                ts = fp[off] * (th + fp[off + 2] * th * th * th) + d * thd
                p_damp += d * thd * thd
            else:
                ts, pd = spring_torque(th, thd, fp, off)
                p_damp += pd
            qf -= ts * a
            carry = ts + extra
        v = y[n + g]
        dy[g] = v
        dy[n + g] = (qf - c * v * v) / m
    if ip[H_ENERGY] != 0:
        dy[2 * n] = te * y[n]
        dy[2 * n + 1] = tl * a_load * y[2 * n - 1]
        dy[2 * n + 2] = p_damp


@njit(cache=True)
def jac(t, y, ip, fp, J):
    """Analytic d(rhs)/dy into J (n_state x n_state, overwritten). As the oracle
    Driveline.jacobian, only dC/dq (third derivative of the position functions, not in the
    joint contract) is a central difference of C(q) with h = 1e-6 max(1, |q|). A vehicle
    scene's is kernel/tree_nb.py's (central differences, as its oracle)."""
    if ip[H_TREE] != 0:
        _tree.tree_jac(t, y, ip, fp, J)
        return
    n = ip[H_NDOF]
    n2 = 2 * n
    ns = J.shape[0]
    sp0 = ip[H_SPRING_F]
    energy = ip[H_ENERGY] != 0
    for i in range(n2):     # the work integrals' rows: _energy_rows
        for j in range(ns):
            J[i, j] = 0.0
    # one scratch for all per-section values, indexed by row (each np.empty/np.zeros is an
    # NRT allocation with atomic counters - ten were half of a small jac - and so is every
    # view of it: rows are indexed, not sliced), on the stack unless it is large. Rows:
    # phi_end, a, b, M, C, dM/dq, dC/dq, generalised force (per section), unused, then
    # dQ_g/dy.
    if (9 + n) * n2 <= STACK_MAX_DOUBLES:
        sc = stack_zeros_2d(9 + n, n2)
    else:
        sc = np.zeros((9 + n, n2))
    for g in range(n):
        q = y[g]
        phi, a, b, m, c, mp, hj = section(g, q, ip, fp)
        if hj:
            h = 1e-6 * max(1.0, abs(q))
            cp = (section(g, q + h, ip, fp)[4] - section(g, q - h, ip, fp)[4]) / (2.0 * h)
        else:
            cp = 0.0
        sc[0, g] = phi
        sc[1, g] = a
        sc[2, g] = b
        sc[3, g] = m
        sc[4, g] = c
        sc[5, g] = mp
        sc[6, g] = cp
    al = sc[1, n - 1]
    bl = sc[2, n - 1]
    vl = y[n2 - 1]
    te, dte, dtep = engine_torque(t, y, ip, fp)
    tl, dtl, dtlp = load_torque(t, y, ip, fp, sc[0, n - 1], al)
    sc[7, 0] += te
    sc[9 + 0, n] += dte
    sc[9 + 0, 0] += dtep
    sc[7, n - 1] -= tl * al
    sc[9 + n - 1, n - 1] += -tl * bl - dtl * bl * vl * al - dtlp * al * al
    sc[9 + n - 1, n2 - 1] += -dtl * al * al
    if ip[H_IMBALANCE] != 0:
        for g in range(n):
            qi, dqi, _vi = imbalance_force(g, y[g], ip, fp)
            sc[7, g] += qi
            sc[9 + g, g] += dqi
    for k in range(n - 1):
        off = sp0 + SPRING_STRIDE * k
        a_l = sc[1, k]
        b_l = sc[2, k]
        th = sc[0, k] - y[k + 1]
        thd = a_l * y[n + k] - y[n + k + 1]
        dthd_qk = b_l * y[n + k]
        explicit = 0.0
        if fp[off + 5] != 0.0:      # varying stiffness over phi = q_k+1
            vs = spring_vary_eval(th, thd, y[k + 1], fp, off)
            ts = vs[0]
            k_th = vs[2]
            k_d = vs[3]
            explicit = vs[4]
            sc[7, k + 1] += vs[1]
            sc[9 + k + 1, k] += vs[5] * a_l
            sc[9 + k + 1, k + 1] += vs[6] - vs[5]
        else:
            ts, k_th, k_d, _pd = spring_eval(th, thd, fp, off)
        d_qk = k_th * a_l + k_d * dthd_qk
        d_qk1 = explicit - k_th
        d_vk = k_d * a_l
        d_vk1 = -k_d
        sc[7, k] -= ts * a_l
        sc[7, k + 1] += ts
        sc[9 + k, k] -= d_qk * a_l + ts * b_l
        sc[9 + k, k + 1] -= d_qk1 * a_l
        sc[9 + k, n + k] -= d_vk * a_l
        sc[9 + k, n + k + 1] -= d_vk1 * a_l
        sc[9 + k + 1, k] += d_qk
        sc[9 + k + 1, k + 1] += d_qk1
        sc[9 + k + 1, n + k] += d_vk
        sc[9 + k + 1, n + k + 1] += d_vk1
    for g in range(n):
        J[g, n + g] = 1.0
    for g in range(n):
        v = y[n + g]
        inv = 1.0 / sc[3, g]
        r = n + g
        for j in range(n2):
            J[r, j] = sc[9 + g, j] * inv
        J[r, g] += -sc[6, g] * v * v * inv - (sc[7, g] - sc[4, g] * v * v) * sc[5, g] * inv * inv
        J[r, n + g] += -2.0 * sc[4, g] * v * inv
    if energy:
        _energy_rows(y, ip, fp, J, sc, te, dte, dtep, tl, dtl, dtlp)


@njit(cache=True, inline='always')
def _energy_rows(y, ip, fp, J, sc, te, dte, dtep, tl, dtl, dtlp):
    """Rows 2n, 2n+1, 2n+2 of J (overwritten): d/dy of the work integrals' rates te w_e,
    tl a w_l and the springs' damping power sum d e'(theta)^2 thetadot^2, given every
    section's phi_end, a, b in sc[0..2, g] and the engine's and the load's torque and
    slopes (:func:`jac` and :func:`jac_energy_rows`: one source, the same bits)."""
    n = ip[H_NDOF]
    n2 = 2 * n
    ns = J.shape[0]
    sp0 = ip[H_SPRING_F]
    for i in range(n2, n2 + 3):
        for j in range(ns):
            J[i, j] = 0.0
    for k in range(n - 1):
        off = sp0 + SPRING_STRIDE * k
        d = fp[off + 1]
        if d != 0.0:
            a_l = sc[1, k]
            th = sc[0, k] - y[k + 1]
            thd = a_l * y[n + k] - y[n + k + 1]
            dthd_qk = sc[2, k] * y[n + k]
            _e, de, dde = spring_deflection(th, fp[off + 3], fp[off + 4])
            dp_dth = d * dde * thd * thd
            dp_dthd = 2.0 * d * de * thd
            J[n2 + 2, k] += dp_dth * a_l + dp_dthd * dthd_qk
            J[n2 + 2, k + 1] -= dp_dth
            J[n2 + 2, n + k] += dp_dthd * a_l
            J[n2 + 2, n + k + 1] -= dp_dthd
    al = sc[1, n - 1]
    bl = sc[2, n - 1]
    vl = y[n2 - 1]
    J[n2, n] = te + dte * y[n]
    J[n2, 0] += dtep * y[n]
    J[n2 + 1, n - 1] = tl * bl * vl + dtl * bl * vl * al * vl + dtlp * al * al * vl
    J[n2 + 1, n2 - 1] = tl * al + dtl * al * al * vl


@njit(cache=True)
def jac_energy_rows(t, y, ip, fp, J):
    """:func:`jac`'s rows of the work integrals (2n .. 2n+2) alone, the same bits, the
    other rows of J left as they are; nothing without work integrals. For a model whose
    other rows do not depend on (t, y) (layout.jacobian_block_constant: ip[H_JAC_CONST]),
    J of the step before plus these rows is jac(t, y, ip, fp, J) bit for bit wherever
    f(t, y) is finite (the Rosenbrock steppers keep that block: steppers_nb._ros_jacobian)."""
    if ip[H_ENERGY] == 0:
        return
    n = ip[H_NDOF]
    if 3 * n <= STACK_MAX_DOUBLES:
        sc = stack_zeros_2d(3, n)
    else:
        sc = np.zeros((3, n))
    for g in range(n):
        phi, a, b, _m, _c, _mp, _hj = section(g, y[g], ip, fp)
        sc[0, g] = phi
        sc[1, g] = a
        sc[2, g] = b
    te, dte, dtep = engine_torque(t, y, ip, fp)
    tl, dtl, dtlp = load_torque(t, y, ip, fp, sc[0, n - 1], sc[1, n - 1])
    _energy_rows(y, ip, fp, J, sc, te, dte, dtep, tl, dtl, dtlp)


@njit(cache=True, inline='always')
def jac_keeps_block(ip):
    """1 when the Rosenbrock steppers may keep J's coupled block across steps and refresh
    only :func:`jac_energy_rows` (layout.H_JAC_CONST), else 0."""
    return ip[H_JAC_CONST]


# at the end: tree_nb uses this module's spring and engine functions (either import order works)
from cvj_ros.physics.kernel import tree_nb as _tree  # noqa: E402
