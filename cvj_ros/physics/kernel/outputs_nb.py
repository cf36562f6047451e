"""Compiled sampling outputs (issue 9): joint states, torques and energy residual of many
states at once, so an offline run does not spend ~0.15 ms of Python per sample.

``shaft_table(driveline)`` (pure Python) maps every named shaft to (section g, position p)
in the kernel's op list of that section: position 0 is the section's start, position k+1
the state after op k (a chain joint is several kernel ops: its input shaft is the position
before its first stage, its output the position after its last). ``sample_outputs`` walks
each section like ``Driveline._walk``: inertia ops take the torque J (a acc + b v^2) out of
the shaft torque, a joint op maps (phi, a, b) by the chain rule and divides the torque by
its ratio. Intermediate members ('mid') are filled afterwards by ``Driveline.fill_mid`` (as
on the Python path). Energy: E_kin = sum M_g v_g^2 / 2, E_el = sum c (e^2/2 + k2 e^4/4)
with the spring's deflection e (driveline.SpringLaw.evaluate's potential), residual as
``Driveline.energy_residual``.
"""
from __future__ import annotations

from typing import Any

import numpy as np
from numba import njit

from cvj_ros.physics.kernel.joints_nb import joint_eval
from cvj_ros.physics.kernel.layout import (H_ENERGY, H_NDOF, H_SEC, H_SPRING_F, OP_INERTIA,
                                          SPRING_STRIDE)
from cvj_ros.physics.kernel.rhs_nb import (engine_torque, load_torque, rhs, section,
                                          spring_deflection, spring_eval)


def shaft_table(driveline: Any) -> np.ndarray:
    """(n_shafts, 3) int64: section, position in that section's kernel ops, 1 = 'mid'."""
    from cvj_ros.physics.scene import Joint
    by_name = {el.name: el for el in driveline.scene.driveline}
    first: list[list[int]] = []     # per section: first kernel op of each element
    last: list[list[int]] = []      # per section: one past its last kernel op
    for names in driveline._section_names:
        f, l_, k = [], [], 0
        for name in names:
            el = by_name[name]
            count = 1
            if isinstance(el, Joint):
                model = driveline.joint_models[name]
                count = len(model.joints) if model.kind == 'chain' else 1
            f.append(k)
            k += count
            l_.append(k)
        first.append(f)
        last.append(l_)
    rows = []
    for sh in driveline.shafts:
        g, j = sh.section, sh.op_index
        before = sh.role in ('input', 'mid')
        rows.append((g, first[g][j] if before else last[g][j], 1 if sh.role == 'mid' else 0))
    return np.asarray(rows, dtype=np.int64).reshape(-1, 3)


@njit(cache=True)
def sample_outputs(T, X, ip, fp, tab, e0, pos, vel, eff, te, tl, res):
    """For every sample k (time T[k], state X[k]): shaft positions, speeds and torques
    (pos/vel/eff[k], per row of ``tab``), engine and load torque (te/tl[k], N m) and the
    relative energy residual (res[k]; NaN without work integrals). Returns the index of the
    first non-finite state, or -1."""
    n = ip[H_NDOF]
    sec = ip[H_SEC]
    ops = sec + n + 1
    sp0 = ip[H_SPRING_F]
    ns = X.shape[1]
    dy = np.empty(ns)
    max_pos = 1
    for g in range(n):
        max_pos = max(max_pos, ip[sec + g + 1] - ip[sec + g] + 1)
    st_phi = np.empty((n, max_pos))
    st_om = np.empty((n, max_pos))
    st_tq = np.empty((n, max_pos))
    for k in range(T.shape[0]):
        y = X[k]
        for i in range(ns):
            if not np.isfinite(y[i]):
                return k
        t = T[k]
        rhs(t, y, ip, fp, dy)
        tk_e = engine_torque(t, y, ip, fp)[0]
        phi_l, a_l = 0.0, 1.0
        kin = 0.0
        el = 0.0
        carry = tk_e
        for g in range(n):
            q, v, acc = y[g], y[n + g], dy[n + g]
            phi, a, b = q, 1.0, 0.0
            torque = carry
            p = 0
            st_phi[g, 0], st_om[g, 0], st_tq[g, 0] = phi, v, torque
            for kk in range(ip[sec + g], ip[sec + g + 1]):
                code = ip[ops + 2 * kk]
                off = ip[ops + 2 * kk + 1]
                if code == OP_INERTIA:
                    torque -= fp[off] * (a * acc + b * v * v)
                else:
                    po, r, s = joint_eval(code, phi, fp, off)
                    b = s * a * a + r * b
                    a = r * a
                    phi = po
                    torque = torque / r
                p += 1
                st_phi[g, p], st_om[g, p], st_tq[g, p] = phi, a * v, torque
            m = section(g, q, ip, fp)[3]
            kin += 0.5 * m * v * v
            if g < n - 1:       # the spring to the right carries the next section's torque
                off = sp0 + SPRING_STRIDE * g
                th = phi - y[g + 1]
                thd = a * v - y[n + g + 1]
                carry = spring_eval(th, thd, fp, off)[0]
                e = spring_deflection(th, fp[off + 3], fp[off + 4])[0]
                el += fp[off] * (0.5 * e * e + 0.25 * fp[off + 2] * e * e * e * e)
            else:
                phi_l, a_l = phi, a
        te[k] = tk_e
        tl[k] = load_torque(t, y, ip, fp, phi_l, a_l)[0]
        for i in range(tab.shape[0]):
            g, p = tab[i, 0], tab[i, 1]
            pos[k, i] = st_phi[g, p]
            vel[k, i] = st_om[g, p]
            eff[k, i] = 0.0 if tab[i, 2] == 1 else st_tq[g, p]
        if ip[H_ENERGY] != 0:
            tot = kin + el
            we, wl, wd = y[2 * n], y[2 * n + 1], y[2 * n + 2]
            scale = max(abs(tot), abs(e0), abs(we), abs(wl), abs(wd), 1e-12)
            res[k] = (tot - e0 - we + wl + wd) / scale
        else:
            res[k] = np.nan
    return -1


@njit(cache=True)
def time_rhs_calls(n, t, y, ip, fp):
    """Call the compiled rhs n times (the benchmark's ns-per-call figure); returns a checksum
    so the calls cannot be optimised away."""
    dy = np.empty(y.shape[0])
    acc = 0.0
    for k in range(n):
        rhs(t + k * 1e-9, y, ip, fp, dy)
        acc += dy[0]
    return acc
