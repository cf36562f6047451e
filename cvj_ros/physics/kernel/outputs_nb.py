"""Compiled sampling outputs: joint states, torques and energy residual of many
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

import math
from typing import Any

import numpy as np
from numba import njit

from cvj_ros.physics.kernel.borrow_nb import STACK_MAX_DOUBLES, borrowed_all, stack_zeros_2d
from cvj_ros.physics.kernel.joints_nb import joint_eval, lever_exact_ratio
from cvj_ros.physics.kernel.reactions_nb import joint_wrench
from cvj_ros.physics.kernel.layout import (H_ENERGY, H_IMBALANCE, H_LOAD, H_NDOF, H_SEC,
                                          H_SPRING_F, H_TREE, LOAD_BRAKE_STEPS, LOAD_CONSTANT,
                                          LOAD_INPUTS, LOAD_RANDOM, LOAD_ROAD, LOAD_TIME_SERIES,
                                          OP_HOOKE, OP_INERTIA, OP_JOINT_IDENTITY, OP_LEVER_EXACT,
                                          OP_LEVER_RATIO, SPRING_STRIDE)
from cvj_ros.physics.kernel.rhs_nb import (engine_torque, rhs, section_accel,
                                          spring_deflection, spring_eval,
                                          spring_vary_eval, imbalance_force,
                                          imbalance_torque)


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


#: mid-table code of the lever hinge's earring (not a kernel op: fill_mid_one only)
MID_EARRING = -1


@njit(cache=True, inline='always')
def earring_angle(phi, ca):
    """The lever hinge's earring angle c (rad) at input angle phi: phi_out of
    ``lever_hinge_exact_scalar(phi, ca, sa2, 0, 1, 0)`` (twist 0, identity output stage), the
    same operations without the ratio, the slope and the output stage, whose atan2 term is
    +-0 there: (phi + atan2(s c (1 - cos a), cos a c^2 + s^2)) + 0.0, the first stage's
    tan(c) = tan(phi) / cos a (``lever_hinge._hooke_dev``). Bit-identical to it
    (test/physics/kernel/test_outputs_nb.py): the ``+ 0.0`` is the twist's, and adding the
    output stage's +-0 to a value that is never -0.0 changes no bit. Half its transcendental
    calls."""
    s, c = math.sin(phi), math.cos(phi)
    return phi + math.atan2(s * c * (1.0 - ca), ca * c * c + s * s) + 0.0


@njit(cache=True, inline='always')
def _mid_angle(code, phi, mfp, off):
    """phi_mid of a mid-table row: joint_eval(code, phi)[0], or the earring angle."""
    if code == MID_EARRING:
        return earring_angle(phi, mfp[off])
    return joint_eval(code, phi, mfp, off)[0]


def _mid_op(model: Any, mfp: list[float]) -> tuple[int, int]:
    """(op code, mfp offset) whose joint_eval phi_out is ``model.evaluate(phi).phi_mid``;
    NotImplementedError when the member has no compiled form (it stays on the Python path)."""
    from cvj_ros.physics.kernel.layout import _joint_op
    kind, fid = model.kind, getattr(model, 'fidelity', None)
    if kind == 'lever_hinge':       # earring c = tan^-1(tan(phi) / cos a): the exact law's
        off = len(mfp)              # first stage (twist 0, output stage cos = 1 -> identity)
        mfp.extend([model._ca, model._sa2, 0.0, 1.0, 0.0])
        return MID_EARRING, off     # that law's phi_out, computed alone (earring_angle)
    if kind in ('rzeppa', 'double_cardan') and fid == 'ideal':
        return OP_JOINT_IDENTITY, 0
    if kind == 'rzeppa':            # cage: tan(phi3) = cos(alpha) tan(phi1)
        mfp.append(float(model._cage_c))
        return OP_HOOKE, len(mfp) - 1
    if kind == 'double_cardan':     # intermediate shaft: the first Hooke stage
        mfp.append(float(model._c1))
        return OP_HOOKE, len(mfp) - 1
    if kind == 'tripod':            # the spider turns with the output shaft
        return _joint_op(kind, model, mfp)
    if kind == 'chain':             # after the first stage, or the single stage's member
        first = model.joints[0]
        if len(model.joints) == 1:
            return _mid_op(first, mfp)
        return _joint_op(kind, first, mfp)
    raise NotImplementedError(f'compiled outputs: intermediate member of {kind!r}')


def mid_table(driveline: Any) -> tuple[np.ndarray, np.ndarray, list[tuple[int, int]]]:
    """Intermediate members for :func:`fill_mid_one`: (rows (n, 4) int64 = mid column,
    input column, op code, mfp offset; mfp float64; [(mid column, input column)] left to
    the Python ``Driveline.fill_mid`` formula)."""
    mfp: list[float] = [0.0]
    rows: list[tuple[int, int, int, int]] = []
    python: list[tuple[int, int]] = []
    for i_mid, i_in in driveline._mid_index:
        model = driveline.shafts[i_mid].joint
        try:
            code, off = _mid_op(model, mfp)
        except NotImplementedError:
            python.append((i_mid, i_in))
            continue
        rows.append((i_mid, i_in, code, off))
    return (np.asarray(rows, dtype=np.int64).reshape(-1, 4), np.asarray(mfp, dtype=np.float64),
            python)


def _reaction_code(model: Any, rfp: list[float]) -> tuple[int, int]:
    """(reaction code, rfp offset) of reactions_nb.joint_wrench for one joint model;
    NotImplementedError when it has no compiled form."""
    from cvj_ros.physics.kernel import reactions_nb as R
    from cvj_ros.physics.kernel.layout import _joint_op
    kind, fid = model.kind, getattr(model, 'fidelity', None)
    if kind == 'ideal_cv' or (kind in ('rzeppa', 'double_cardan', 'lever_hinge')
                              and fid == 'ideal'):
        return R.R_TORQUE_IDENTITY, 0
    if kind == 'gear':
        rfp.append(float(model.gear_ratio))
        return R.R_TORQUE_GEAR, len(rfp) - 1
    if kind in ('rzeppa', 'double_cardan', 'lever_hinge'):   # torque_out = T_in / ratio
        off = len(rfp)
        rfp.extend([0.0, 0.0])
        code, op_off = _joint_op(kind, model, rfp)
        rfp[off], rfp[off + 1] = float(code), float(op_off)
        return R.R_TORQUE_RATIO, off
    if kind == 'hooke':
        if fid == 'ideal':
            return R.R_HOOKE_IDEAL, 0
        if model._k != 0.0:         # cross angle != 90 deg: Hooke._reactions_vector
            raise NotImplementedError('compiled outputs: reactions of a Hooke cross at '
                                      f'{math.degrees(model.cross_angle):g} deg')
        off = len(rfp)
        rfp.extend([float(model._c), math.sin(model.beta), float(model._off)])
        return R.R_HOOKE_EXACT, off
    if kind == 'tripod' and fid in ('ideal', 'closed'):
        off = len(rfp)
        rfp.extend([model.r, model.l, math.sin(model.beta), math.cos(model.beta),
                    model.roller_mass])
        return R.R_TRIPOD_SMALL, off
    if kind == 'tripod' and fid == 'exact' and model._orbit_spec is not None:
        off = len(rfp)
        spec = model._orbit_spec
        nor = len(spec[0])
        block = [model.r, model.l, *(float(v) for v in model._n0), *(float(v) for v in model._u0),
                 model.roller_mass, model.spider_mass, float(nor), float(len(model._sine_coeffs))]
        for i in range(2):
            block.extend(float(v) for v in np.real(spec[i]))
            block.extend(float(v) for v in np.imag(spec[i]))
        block.extend(float(v) for v in model._sine_coeffs)
        assert len(block) == R.TE_DATA + 4 * nor + len(model._sine_coeffs)
        rfp.extend(block)
        return R.R_TRIPOD_EXACT, off
    raise NotImplementedError(f'compiled outputs: reactions of {kind!r} ({fid})')


def reaction_table(driveline: Any, joints: list[str]
                   ) -> tuple[np.ndarray, np.ndarray, list[int]]:
    """Reaction wrenches for :func:`wrenches_one`, one row per name in ``joints`` (rows
    (n, 3) int64 = input column, reaction code, rfp offset; rfp float64; indices of the
    ``joints`` left to the Python model's ``reactions``, their rows code -1)."""
    rfp: list[float] = [0.0]
    rows: list[tuple[int, int, int]] = []
    python: list[int] = []
    names = driveline.shaft_names
    for k, name in enumerate(joints):
        col = names.index(f'{name}_input')
        try:
            code, off = _reaction_code(driveline.joint_models[name], rfp)
        except NotImplementedError:
            python.append(k)
            code, off = -1, 0
        rows.append((col, code, off))
    return (np.asarray(rows, dtype=np.int64).reshape(-1, 3), np.asarray(rfp, dtype=np.float64),
            python)


@njit(cache=True, inline='always')
def joint_ratio(code, phi, fp, off):
    """(ratio, ratio_slope) of ``joint_eval(code, phi, fp, off)``, the same floats; the exact
    lever hinge without its output angle (``joints_nb.lever_exact_ratio``; also for its
    OP_LEVER_RATIO, :func:`ratio_only_ip`)."""
    if code == OP_LEVER_EXACT or code == OP_LEVER_RATIO:
        return lever_exact_ratio(phi, fp[off], fp[off + 1], fp[off + 2], fp[off + 3],
                                 fp[off + 4])
    _po, r, s = joint_eval(code, phi, fp, off)
    return r, s


#: load codes whose torque does not depend on the load shaft's angle (sources_nb.load_eval)
_LOADS_WITHOUT_ANGLE = (LOAD_INPUTS, LOAD_CONSTANT, LOAD_ROAD, LOAD_RANDOM, LOAD_BRAKE_STEPS,
                        LOAD_TIME_SERIES)


def unread_angles(ip: np.ndarray, tab: np.ndarray, read: list[int]) -> np.ndarray:
    """Per kernel op (int64, the length of the op list): 1 at a joint whose output angle
    nothing reads when only the shaft columns ``read`` (rows of ``tab``, :func:`shaft_table`)
    are read for their angle: a joint of the last section with no joint after it, no shaft
    of ``read`` after it, no imbalance, and a load whose torque does not depend on its
    angle; else 0. A chain layout only (all zeros for a vehicle scene)."""
    n = int(ip[H_NDOF])
    sec = int(ip[H_SEC])
    ops = sec + n + 1
    flags = np.zeros(int(ip[sec + n]), np.int64)
    if ip[H_TREE] != 0 or ip[H_IMBALANCE] != 0 or int(ip[H_LOAD]) not in _LOADS_WITHOUT_ANGLE:
        return flags
    g = n - 1
    k0, k1 = int(ip[sec + g]), int(ip[sec + g + 1])
    joints = [kk for kk in range(k0, k1) if ip[ops + 2 * kk] != OP_INERTIA]
    if not joints:
        return flags
    kk = joints[-1]     # position after it: kk - k0 + 1; a read shaft there or later needs it
    if any(int(tab[c, 0]) == g and int(tab[c, 1]) > kk - k0 for c in read):
        return flags
    flags[kk] = 1
    return flags


def ratio_only_ip(ip: np.ndarray, skip: np.ndarray) -> np.ndarray | None:
    """A copy of ``ip`` with every exact lever hinge that ``skip`` (:func:`unread_angles`)
    flags coded OP_LEVER_RATIO: the right-hand side then takes its ratio and slope without
    the output angle, which nothing reads (the last section's end angle; the load's torque
    does not depend on it), so the same accelerations bit for bit. None when no flagged
    joint is an exact lever hinge."""
    ops = int(ip[H_SEC]) + int(ip[H_NDOF]) + 1
    ks = [k for k in np.flatnonzero(skip).tolist() if int(ip[ops + 2 * k]) == OP_LEVER_EXACT]
    if not ks:
        return None
    out = np.array(ip, dtype=np.int64)
    for k in ks:
        out[ops + 2 * k] = OP_LEVER_RATIO
    return out


@njit(cache=True, inline='always')
def _walk_sample(t, y, ip, fp, wk, st_phi, st_om, st_tq, skip):
    """One state y at time t: shaft angle, speed and torque before/after every kernel op
    into st_phi/st_om/st_tq[g, position] (the walk of ``Driveline._walk``). Returns (engine
    torque N m, kinetic energy J, elastic energy J, load torque N m). ``skip`` (int per
    kernel op, :func:`unread_angles`, or empty): a joint flagged 1 gives its ratio and slope
    alone (:func:`joint_ratio`) and the angles after it are NaN.
    Each joint is evaluated once per sample: a first pass over a section's ops maps
    (phi, a, b) by the chain rule and sums M = sum J a^2 and C = sum J a b over the same ops
    with the same a, b in the same order as ``rhs_nb.section`` (so the same floats), keeping
    a, b at each inertia and the ratio r of each joint in wk (3, positions); the section's
    acceleration is ``rhs_nb.section_accel``'s, the formula ``rhs_nb.rhs`` uses; a second
    pass takes the torque J (a acc + b v^2) out at each inertia and divides by r at each
    joint."""
    n = ip[H_NDOF]
    sec = ip[H_SEC]
    ops = sec + n + 1
    sp0 = ip[H_SPRING_F]
    tk_e = engine_torque(t, y, ip, fp)[0]
    tl = 0.0
    kin = 0.0
    el = 0.0
    carry = tk_e        # the walk's torque into the section's first shaft
    carry_q = 0.0       # the right-hand side's spring torque carried into the section
    for g in range(n):
        q, v = y[g], y[n + g]
        phi, a, b = q, 1.0, 0.0
        m, c = 0.0, 0.0
        p = 0
        st_phi[g, 0], st_om[g, 0] = phi, v
        for kk in range(ip[sec + g], ip[sec + g + 1]):
            code = ip[ops + 2 * kk]
            off = ip[ops + 2 * kk + 1]
            if code == OP_INERTIA:
                jv = fp[off]
                wk[0, p] = a
                wk[1, p] = b
                m += jv * a * a         # rhs_nb.section's M and C, term by term
                c += jv * a * b
            elif skip.shape[0] != 0 and skip[kk] != 0:
                r, s = joint_ratio(code, phi, fp, off)
                wk[2, p] = r
                b = s * a * a + r * b
                a = r * a
                phi = math.nan
            else:
                po, r, s = joint_eval(code, phi, fp, off)
                wk[2, p] = r
                b = s * a * a + r * b
                a = r * a
                phi = po
            p += 1
            st_phi[g, p], st_om[g, p] = phi, a * v
        acc, carry_q, tl_g, _pd = section_accel(t, y, ip, fp, g, phi, a, m, c, tk_e, carry_q)
        torque = carry
        st_tq[g, 0] = torque
        p = 0
        for kk in range(ip[sec + g], ip[sec + g + 1]):
            code = ip[ops + 2 * kk]
            if code == OP_INERTIA:
                torque -= fp[ip[ops + 2 * kk + 1]] * (wk[0, p] * acc + wk[1, p] * v * v)
                if ip[H_IMBALANCE] != 0:    # else imbalance_torque is 0.0: x - 0.0 is x
                    torque -= imbalance_torque(kk, st_phi[g, p], ip, fp)
            else:
                torque = torque / wk[2, p]
            p += 1
            st_tq[g, p] = torque
        kin += 0.5 * m * v * v
        if ip[H_IMBALANCE] != 0:
            el += imbalance_force(g, q, ip, fp)[2]
        if g < n - 1:       # the spring to the right carries the next section's torque
            off = sp0 + SPRING_STRIDE * g
            th = phi - y[g + 1]
            thd = a * v - y[n + g + 1]
            if fp[off + 5] != 0.0:      # varying stiffness: the right side's torque and s V
                vs = spring_vary_eval(th, thd, y[g + 1], fp, off)
                carry = vs[0] + vs[1]
                el += vs[7]
            else:
                carry = spring_eval(th, thd, fp, off)[0]
                e = spring_deflection(th, fp[off + 3], fp[off + 4])[0]
                el += fp[off] * (0.5 * e * e + 0.25 * fp[off + 2] * e * e * e * e)
        else:
            tl = tl_g
    return tk_e, kin, el, tl


@njit(cache=True, inline='always')
def _max_positions(ip):
    """Most positions of any section's walk (its kernel ops + 1)."""
    n = ip[H_NDOF]
    sec = ip[H_SEC]
    max_pos = 1
    for g in range(n):
        max_pos = max(max_pos, ip[sec + g + 1] - ip[sec + g] + 1)
    return max_pos


@njit(cache=True)
def _walk_buffers(ip):
    """Scratch arrays of :func:`_walk_sample`: wk (3, max positions) for the per-op a, b and
    ratio, and (n, max positions) for the per-op angle, speed and torque."""
    n = ip[H_NDOF]
    max_pos = _max_positions(ip)
    return (np.empty((3, max_pos)), np.empty((n, max_pos)), np.empty((n, max_pos)),
            np.empty((n, max_pos)))


#: no joint angle skipped (:func:`_walk_sample`)
_NO_SKIP = np.zeros(0, np.int64)


@njit(cache=True)
def sample_outputs(T, X, ip, fp, tab, e0, pos, vel, eff, te, tl, res):
    """For every sample k (time T[k], state X[k]): shaft positions, speeds and torques
    (pos/vel/eff[k], per row of ``tab``), engine and load torque (te/tl[k], N m) and the
    relative energy residual (res[k]; NaN without work integrals). Returns the index of the
    first non-finite state, or -1."""
    T, X, ip, fp, tab, pos, vel, eff, te, tl, res = borrowed_all((
        T, X, ip, fp, tab, pos, vel, eff, te, tl, res))
    return _sample_rows(T, X, ip, fp, tab, e0, _NO_SKIP, pos, vel, eff, te, tl, res)


@njit(cache=True)
def sample_outputs_lean(T, X, ip, fp, tab, e0, skip, pos, vel, eff, te, tl, res):
    """:func:`sample_outputs` with the joints flagged in ``skip`` (:func:`unread_angles`)
    giving their ratio and slope alone: the same speeds, torques, engine and load torques
    and energy residual bit for bit, NaN angles after those joints."""
    T, X, ip, fp, tab, skip, pos, vel, eff, te, tl, res = borrowed_all((
        T, X, ip, fp, tab, skip, pos, vel, eff, te, tl, res))
    return _sample_rows(T, X, ip, fp, tab, e0, skip, pos, vel, eff, te, tl, res)


@njit(cache=True, inline='always')
def _sample_rows(T, X, ip, fp, tab, e0, skip, pos, vel, eff, te, tl, res):
    """The body of :func:`sample_outputs` (and of :func:`sample_outputs_lean`)."""
    n = ip[H_NDOF]
    ns = X.shape[1]
    max_pos = _max_positions(ip)
    if 3 * max_pos + 3 * n * max_pos <= STACK_MAX_DOUBLES:
        # on the stack: no NRT allocation and no reference counts (the heap arrays' were 4
        # allocations per run); every entry read is written first, as with np.empty
        wk = stack_zeros_2d(3, max_pos)
        st_phi = stack_zeros_2d(n, max_pos)
        st_om = stack_zeros_2d(n, max_pos)
        st_tq = stack_zeros_2d(n, max_pos)
    else:
        wk, st_phi, st_om, st_tq = _walk_buffers(ip)
    for k in range(T.shape[0]):
        y = X[k]
        for i in range(ns):
            if not np.isfinite(y[i]):
                return k
        t = T[k]
        tk_e, kin, el, tk_l = _walk_sample(t, y, ip, fp, wk, st_phi, st_om, st_tq, skip)
        te[k] = tk_e
        tl[k] = tk_l
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
def joint_state_one(y, ip, fp, tab, mtab, mfp, pos, vel, eff):
    """The coupling node's per-exchange joint state: shaft positions (rad),
    speeds (rad/s) and torques (N m) of one state y into pos/vel/eff (rows of ``tab``), with
    the torques of the model's input block (``layout.set_torque_inputs``, t = 0), and the
    intermediate members of ``mtab`` filled as ``Driveline.fill_mid`` does. Returns False
    (outputs untouched) when y is not finite."""
    ns = y.shape[0]
    for i in range(ns):
        if not np.isfinite(y[i]):
            return False
    wk, st_phi, st_om, st_tq = _walk_buffers(ip)
    _walk_sample(0.0, y, ip, fp, wk, st_phi, st_om, st_tq, _NO_SKIP)
    for i in range(tab.shape[0]):
        g, p = tab[i, 0], tab[i, 1]
        pos[i] = st_phi[g, p]
        vel[i] = st_om[g, p]
        eff[i] = 0.0 if tab[i, 2] == 1 else st_tq[g, p]
    fill_mid_one(pos, vel, mtab, mfp)
    return True


@njit(cache=True)
def fill_mid_samples(pos, vel, mtab, mfp):
    """:func:`fill_mid_one` for every row k of (samples, shafts) arrays pos/vel: the
    compiled ``Driveline.fill_mid`` of an offline trace."""
    for k in range(pos.shape[0]):
        fill_mid_one(pos[k], vel[k], mtab, mfp)


@njit(cache=True)
def fill_mid_one(pos, vel, mtab, mfp):
    """``Driveline.fill_mid`` for one sample: per row (mid column, input column, op code,
    mfp offset) the member angle phi_mid = _mid_angle(op, phi_in) and its speed by the
    same Richardson-extrapolated central difference (h = 1e-3 rad) times omega_in."""
    h = 1e-3
    for i in range(mtab.shape[0]):
        i_mid, i_in, code, off = mtab[i, 0], mtab[i, 1], mtab[i, 2], mtab[i, 3]
        phi = pos[i_in]
        m0 = _mid_angle(code, phi, mfp, off)
        mp = _mid_angle(code, phi + h, mfp, off)
        mm = _mid_angle(code, phi - h, mfp, off)
        mp2 = _mid_angle(code, phi + h / 2, mfp, off)
        mm2 = _mid_angle(code, phi - h / 2, mfp, off)
        d_h = (mp - mm) / (2 * h)
        d_h2 = (mp2 - mm2) / h
        pos[i_mid] = m0
        vel[i_mid] = (4.0 * d_h2 - d_h) / 3.0 * vel[i_in]


@njit(cache=True)
def wrenches_one(pos, vel, eff, rtab, rfp, out):
    """Reaction wrenches (housing frame, reactions_nb.joint_wrench) of the joints of
    ``rtab`` (rows: input column, reaction code, rfp offset) from the joint state
    pos/vel/eff: out[i, 0:6] = force xyz (N), torque xyz (N m). Returns the number of rows
    the compiled models did not answer (their out rows are NaN; the caller asks the Python
    model): a non-finite input (which the Python model rejects with its own error) or a
    Newton that did not converge."""
    failed = 0
    w = np.empty(6)
    for i in range(rtab.shape[0]):
        c = rtab[i, 0]
        if not (np.isfinite(pos[c]) and np.isfinite(vel[c]) and np.isfinite(eff[c])) or \
                joint_wrench(rtab[i, 1], pos[c], vel[c], eff[c], rfp, rtab[i, 2], w) != 0:
            failed += 1
            for k in range(6):
                out[i, k] = np.nan
            continue
        for k in range(6):
            out[i, k] = w[k]
    return failed


@njit(cache=True)
def time_rhs_calls(n, t, y, ip, fp):
    """Call the compiled rhs n times (the benchmark's ns-per-call figure); returns a checksum
    so the calls cannot be optimised away."""
    return _time_rhs_loop(n, t, y, ip, fp, np.empty(y.shape[0]))


@njit(cache=True)
def _time_rhs_loop(n, t, y, ip, fp, dy):
    y, ip, fp, dy = borrowed_all((y, ip, fp, dy))
    acc = 0.0
    for k in range(n):
        rhs(t + k * 1e-9, y, ip, fp, dy)
        acc += dy[0]
    return acc
