"""Compiled joint reactions and intermediate members: the coupling node's
reaction wrenches without Python, one sample at a time.

Every function here is a line-by-line port of the readable Python in
``cvj_ros/physics/joints`` (the oracle; test/physics/kernel/test_state_outputs.py compares
the two on every shipped scene): the same formulas in the same operation order, so the
results differ only where a libm function (sin, cos, atan2, sqrt) rounds differently from
numpy's.

* :func:`solve_fixed`: ``fixed_order.solve`` (Gaussian elimination with partial pivoting,
  ties to the lower row, the same elimination order; no BLAS).
* Tripod, exact fidelity (``Tripod.reactions`` -> ``positions``, ``solve``,
  ``_solve_reactions``): second-order jets ``(c0, c1, c2)`` as float tuples (the Python jets'
  order-1 uses are the first two coefficients of these: c0 and c1 never depend on c2),
  the three constraint residuals and their Jacobian by three directional seeds, Newton from
  the Fourier warm start (``_start``) to 1e-13 r, implicit derivatives of second order,
  then the 10 x 10 system of the frictionless quasi-static balance.
* Tripod closed/ideal (``_reactions_small``), Hooke (``Hooke.reactions``) and every joint
  whose reaction wrench is only its output torque (gear: i T_in; Rzeppa, lever hinge,
  double cardan: T_in / ratio; ideal CV: T_in).

Wrench layout (``cvj_ros/physics/joints/wrench.py``, housing frame): force x, y, z (N),
torque x, y, z (N m).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from cvj_ros.physics.kernel.joints_nb import joint_eval

TWO_PI_3 = 2.0 * math.pi / 3.0       # = joints/tripod.py TWO_PI_3

# reaction codes (rtab column 1); parameters at rfp[off:]
R_TORQUE_IDENTITY = 0   # ideal CV: torque_out = T_in
R_TORQUE_GEAR = 1       # rfp = [gear_ratio]: torque_out = gear_ratio T_in
R_TORQUE_RATIO = 2      # rfp = [op code, op fp offset into rfp]: torque_out = T_in / ratio(phi)
R_HOOKE_EXACT = 3       # rfp = [cos b, sin b, psi - gamma]
R_HOOKE_IDEAL = 4
R_TRIPOD_SMALL = 5      # rfp = [r, l, sin b, cos b, roller_mass]
R_TRIPOD_EXACT = 6      # rfp: see tripod_exact_params

# tripod_exact parameter block offsets (relative to the block start)
TE_R, TE_L, TE_N0, TE_U0, TE_M, TE_MS, TE_NORB, TE_NB, TE_DATA = 0, 1, 2, 5, 8, 9, 10, 11, 12


# --- second-order jets --------------------------------------------------------------------

@njit(cache=True, inline='always')
def _jadd(a, b):
    return (a[0] + b[0], a[1] + b[1], a[2] + b[2])


@njit(cache=True, inline='always')
def _jsub(a, b):
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


@njit(cache=True, inline='always')
def _jscale(a, k):
    return (a[0] * k, a[1] * k, a[2] * k)


@njit(cache=True, inline='always')
def _jmul(a, b):
    return (a[0] * b[0], a[0] * b[1] + a[1] * b[0], a[0] * b[2] + a[1] * b[1] + a[2] * b[0])


@njit(cache=True, inline='always')
def _jcompose(a, f0, f1, f2):
    return (f0, f1 * a[1], f1 * a[2] + 0.5 * f2 * a[1] * a[1])


@njit(cache=True, inline='always')
def _jsin(a):
    s, c = math.sin(a[0]), math.cos(a[0])
    return _jcompose(a, s, c, -s)


@njit(cache=True, inline='always')
def _jcos(a):
    s, c = math.sin(a[0]), math.cos(a[0])
    return _jcompose(a, c, -s, -c)


@njit(cache=True, inline='always')
def _jsqrt(a):
    q = math.sqrt(a[0])
    return _jcompose(a, q, 0.5 / q, -0.25 / (q * a[0]))


@njit(cache=True, inline='always')
def _jrecip(a):
    inv = 1.0 / a[0]
    return _jcompose(a, inv, -inv * inv, 2.0 * inv * inv * inv)


@njit(cache=True)
def _round_half_even(x):
    """np.round / Python round of a float to the nearest integer, ties to even (float)."""
    f = math.floor(x)
    d = x - f
    if d > 0.5 or (d == 0.5 and f % 2.0 != 0.0):
        return f + 1.0
    return f


# --- fixed-order linear solve -------------------------------------------------------------

@njit(cache=True)
def solve_fixed(A, b):
    """x with A x = b (n x n), in place on copies: ``fixed_order.solve``'s elimination
    (partial pivoting, first of equal |pivots|, same loop order). Singular -> inf/NaN."""
    n = A.shape[0]
    M = A.copy()
    x = b.copy()
    for k in range(n):
        p = k
        best = abs(M[k, k])
        for i in range(k + 1, n):
            v = abs(M[i, k])
            if v > best:
                best = v
                p = i
        if p != k:
            for j in range(n):
                M[k, j], M[p, j] = M[p, j], M[k, j]
            x[k], x[p] = x[p], x[k]
        piv = M[k, k]
        for i in range(k + 1, n):
            f = M[i, k] / piv
            for j in range(k, n):
                M[i, j] = M[i, j] - f * M[k, j]
            x[i] = x[i] - f * x[k]
    for k in range(n - 1, -1, -1):
        s = x[k]
        for j in range(k + 1, n):
            s = s - M[k, j] * x[j]
        x[k] = s / M[k, k]
    return x


# --- exact tripod geometry (joints/tripod.py Tripod._geometry_jets) -----------------------

@njit(cache=True)
def _tripod_geometry(su, sv, ph2, ph1, rfp, o, G):
    """Jets of the exact tripod geometry into G (24, 3): rows 0-2 spider centre S (m),
    3-5 shaft axis n, 6-14 trunnion axes e_j (j major), 15-17 constraint residuals (m),
    18-20 arm lengths h_j (m), 21-23 roller axial positions z_j (m)."""
    r, l = rfp[o + TE_R], rfp[o + TE_L]
    n00, n01, n02 = rfp[o + TE_N0], rfp[o + TE_N0 + 1], rfp[o + TE_N0 + 2]
    u00, u01, u02 = rfp[o + TE_U0], rfp[o + TE_U0 + 1], rfp[o + TE_U0 + 2]
    zs = 0.0 * su[0]
    w = _jsqrt(_jsub((l * l + zs, 0.0, 0.0), _jadd(_jmul(su, su), _jmul(sv, sv))))
    lw = _jsub((l + zs, 0.0, 0.0), w)
    S0 = _jadd(_jscale(su, u00), _jscale(lw, n00))
    S1 = _jadd(_jadd(_jscale(su, u01), _jscale(lw, n01)), sv)
    S2 = _jadd(_jscale(su, u02), _jscale(lw, n02))
    il = 1.0 / l
    m_il = -1.0 / l
    N0 = _jscale(_jadd(_jscale(su, -u00), _jscale(w, n00)), il)
    N1 = _jadd(_jscale(_jadd(_jscale(su, -u01), _jscale(w, n01)), il), _jscale(sv, m_il))
    N2 = _jscale(_jadd(_jscale(su, -u02), _jscale(w, n02)), il)
    vx = _jscale(N1, u02)
    vy = _jsub(_jscale(N2, u00), _jscale(N0, u02))
    vz = _jscale(N1, -u00)
    inv = _jrecip(_jsqrt(_jadd(_jadd(_jmul(vx, vx), _jmul(vy, vy)), _jmul(vz, vz))))
    V0, V1, V2 = _jmul(vx, inv), _jmul(vy, inv), _jmul(vz, inv)
    U0 = _jsub(_jmul(V1, N2), _jmul(V2, N1))
    U1 = _jsub(_jmul(V2, N0), _jmul(V0, N2))
    U2 = _jsub(_jmul(V0, N1), _jmul(V1, N0))
    for i in range(3):
        G[0, i], G[1, i], G[2, i] = S0[i], S1[i], S2[i]
        G[3, i], G[4, i], G[5, i] = N0[i], N1[i], N2[i]
    for j in range(3):
        aj = _jadd(ph2, (j * TWO_PI_3 + zs, 0.0, 0.0))
        ca, sa = _jcos(aj), _jsin(aj)
        e0 = _jadd(_jmul(ca, U0), _jmul(sa, V0))
        e1 = _jadd(_jmul(ca, U1), _jmul(sa, V1))
        e2 = _jadd(_jmul(ca, U2), _jmul(sa, V2))
        pj = _jadd(ph1, (j * TWO_PI_3 + zs, 0.0, 0.0))
        tx = _jsub(_jscale(_jcos(pj), r), S0)
        ty = _jsub(_jscale(_jsin(pj), r), S1)
        res = _jsub(_jmul(tx, e1), _jmul(ty, e0))
        exy2 = _jadd(_jmul(e0, e0), _jmul(e1, e1))
        hj = _jmul(_jadd(_jmul(tx, e0), _jmul(ty, e1)), _jrecip(exy2))
        zj = _jadd(S2, _jmul(hj, e2))
        for i in range(3):
            G[6 + 3 * j, i], G[7 + 3 * j, i], G[8 + 3 * j, i] = e0[i], e1[i], e2[i]
            G[15 + j, i] = res[i]
            G[18 + j, i] = hj[i]
            G[21 + j, i] = zj[i]


@njit(cache=True)
def _tripod_res_jac(q, red, rfp, o, G, res, jac):
    """Residual (3, m) and Jacobian d res / d (s_u, s_v, phi_out) at q (Tripod._residual_and_jacobian)."""
    for k in range(3):
        _tripod_geometry((q[0], 1.0 if k == 0 else 0.0, 0.0), (q[1], 1.0 if k == 1 else 0.0, 0.0),
                         (q[2], 1.0 if k == 2 else 0.0, 0.0), (red, 0.0, 0.0), rfp, o, G)
        for i in range(3):
            if k == 0:
                res[i] = G[15 + i, 0]
            jac[i, k] = G[15 + i, 1]


@njit(cache=True)
def _tripod_start(red, rfp, o, q):
    """Warm start from the Fourier tables of the orbit and the deviation (Tripod._start)."""
    nor = int(rfp[o + TE_NORB])
    nb = int(rfp[o + TE_NB])
    d = o + TE_DATA
    redm = red % TWO_PI_3          # np.mod: result with the sign of the divisor
    for i in range(2):
        acc_c = 0.0
        acc_s = 0.0
        for k in range(nor):
            x = 3.0 * (redm * k)
            wk = 1.0 if k == 0 else 2.0
            acc_c = acc_c + math.cos(x) * (wk * rfp[d + 2 * i * nor + k])
            acc_s = acc_s + math.sin(x) * (wk * rfp[d + (2 * i + 1) * nor + k])
        q[i] = acc_c - acc_s
    b0 = d + 4 * nor
    dev = 0.0
    for k in range(nb):
        dev = dev + math.sin(3.0 * (redm * (k + 1))) * rfp[b0 + k]
    q[2] = red + dev


@njit(cache=True)
def tripod_exact_reactions(phi, omega, torque, rfp, o, out):
    """Tripod.reactions at exact fidelity into out[0:6] (housing wrench: input_force_x/y,
    axial_force, input_moment_x/y, torque_out). Returns 0, or 1 when Newton did not reach
    NEWTON_TOL r (the caller then asks the Python model, which raises its SolverError)."""
    r = rfp[o + TE_R]
    turns = _round_half_even(phi / TWO_PI_3)
    red = phi - turns * TWO_PI_3
    q = np.empty(3)
    _tripod_start(red, rfp, o, q)
    G = np.empty((24, 3))
    res = np.empty(3)
    jac = np.empty((3, 3))
    target = 1e-13 * r
    err = np.inf
    have_jac = False
    for _ in range(40):
        _tripod_res_jac(q, red, rfp, o, G, res, jac)
        err = max(abs(res[0]), abs(res[1]), abs(res[2]))
        if err <= target:
            have_jac = True
            break
        dq = solve_fixed(jac, -res)
        for i in range(3):
            q[i] += dq[i]
    if not have_jac:
        if not err <= 1e-12 * r:          # tripod.NEWTON_TOL
            return 1
        _tripod_res_jac(q, red, rfp, o, G, res, jac)
    # implicit derivatives along phi_in = red + t (Tripod._derivatives)
    _tripod_geometry((q[0], 0.0, 0.0), (q[1], 0.0, 0.0), (q[2], 0.0, 0.0), (red, 1.0, 0.0),
                     rfp, o, G)
    r1 = np.empty(3)
    for i in range(3):
        r1[i] = -G[15 + i, 1]
    q1 = solve_fixed(jac, r1)
    _tripod_geometry((q[0], q1[0], 0.0), (q[1], q1[1], 0.0), (q[2], q1[2], 0.0), (red, 1.0, 0.0),
                     rfp, o, G)
    for i in range(3):
        r1[i] = -G[15 + i, 2]
    q2 = solve_fixed(jac, r1)
    _tripod_geometry((q[0], q1[0], q2[0]), (q[1], q1[1], q2[1]), (q[2], q1[2], q2[2]),
                     (red, 1.0, 0.0), rfp, o, G)
    # roller j of the original numbering is reduced roller (j + turns) mod 3
    it = int(turns)
    m = rfp[o + TE_M]
    ms = rfp[o + TE_MS]
    P = np.empty(3)
    n = np.empty(3)
    S = np.empty(3)
    inertia = np.empty(3)
    arms = np.empty((3, 3))
    rollers = np.empty((3, 3))
    acc = np.empty(3)
    for i in range(3):
        P[i] = rfp[o + TE_L] * rfp[o + TE_N0 + i]
        n[i] = G[3 + i, 0]
        S[i] = G[i, 0]
        inertia[i] = ms * (omega * omega * (2.0 * G[i, 2]))
    for j in range(3):
        jr = (j + it) % 3
        acc[j] = omega * omega * (2.0 * G[21 + jr, 2])
        h = G[18 + jr, 0]
        for i in range(3):
            arms[j, i] = G[6 + 3 * jr + i, 0]
            rollers[j, i] = S[i] + h * arms[j, i]
    _solve_tripod_balance(P, n, arms, rollers, acc, torque, m, S, inertia, out)
    # the plungers' angular momentum rate about O (Tripod._solve_reactions with omega)
    w2 = omega * omega
    dlx, dly = 0.0, 0.0
    for j in range(3):
        x, y, z = rollers[j, 0], rollers[j, 1], rollers[j, 2]
        ax, ay, az = -w2 * x, -w2 * y, acc[j]
        dlx += m * (y * az - z * ay)
        dly += m * (z * ax - x * az)
    out[3] += dlx
    out[4] += dly
    return 0


@njit(cache=True)
def _solve_tripod_balance(P, n, arms, rollers, acc, torque, m, S, inertia, out):
    """Tripod._solve_reactions: the 10 x 10 balance, wrench into out[0:6]."""
    A = np.zeros((10, 10))
    rhs = np.zeros(10)
    for j in range(3):
        for i in range(3):
            A[j, 3 * j + i] = arms[j, i]
        A[3 + j, 3 * j + 2] = 1.0
        rhs[3 + j] = m * acc[j]
        A[6, 3 * j] = -rollers[j, 1]
        A[6, 3 * j + 1] = rollers[j, 0]
        d0, d1, d2 = rollers[j, 0] - P[0], rollers[j, 1] - P[1], rollers[j, 2] - P[2]
        c = 3 * j
        A[7, c], A[7, c + 1], A[7, c + 2] = -0.0, -(-d2), -d1
        A[8, c], A[8, c + 1], A[8, c + 2] = -d2, -0.0, -(-d0)
        A[9, c], A[9, c + 1], A[9, c + 2] = -(-d1), -d0, -0.0
    A[7, 9], A[8, 9], A[9, 9] = n[0], n[1], n[2]
    rhs[6] = -torque
    sp0, sp1, sp2 = S[0] - P[0], S[1] - P[1], S[2] - P[2]
    rhs[7] = sp1 * inertia[2] - sp2 * inertia[1]
    rhs[8] = sp2 * inertia[0] - sp0 * inertia[2]
    rhs[9] = sp0 * inertia[1] - sp1 * inertia[0]
    x = solve_fixed(A, rhs)
    on = np.empty(3)
    mom = np.empty(3)
    for i in range(3):
        on[i] = (x[i] + x[3 + i]) + x[6 + i]
    for i in range(3):
        a, b = (i + 1) % 3, (i + 2) % 3
        c0 = rollers[0, a] * x[b] - rollers[0, b] * x[a]
        c1 = rollers[1, a] * x[3 + b] - rollers[1, b] * x[3 + a]
        c2 = rollers[2, a] * x[6 + b] - rollers[2, b] * x[6 + a]
        mom[i] = (c0 + c1) + c2
    t0, t1, t2 = on[0] + inertia[0], on[1] + inertia[1], on[2] + inertia[2]
    out[0] = -on[0]
    out[1] = -on[1]
    out[2] = ((0.0 + t0 * n[0]) + t1 * n[1]) + t2 * n[2]
    out[3] = -mom[0]
    out[4] = -mom[1]
    out[5] = -x[9]


@njit(cache=True)
def tripod_small_reactions(phi, omega, torque, rfp, o, out):
    """Tripod._reactions_small (closed/ideal fidelity: S = 0, n = n0) into out[0:6]."""
    r, l, sb, cb, m = rfp[o], rfp[o + 1], rfp[o + 2], rfp[o + 3], rfp[o + 4]
    tb = sb / cb
    n = np.empty(3)
    n[0], n[1], n[2] = sb, 0.0, cb
    P = np.empty(3)
    for i in range(3):
        P[i] = l * n[i]
    rollers = np.empty((3, 3))
    arms = np.empty((3, 3))
    acc = np.empty(3)
    for j in range(3):
        c, s = math.cos(phi + j * TWO_PI_3), math.sin(phi + j * TWO_PI_3)
        rollers[j, 0], rollers[j, 1], rollers[j, 2] = r * c, r * s, -r * tb * c
        acc[j] = omega * omega * r * tb * c
        norm = math.sqrt(rollers[j, 0] * rollers[j, 0] + rollers[j, 1] * rollers[j, 1]
                         + rollers[j, 2] * rollers[j, 2])
        for i in range(3):
            arms[j, i] = rollers[j, i] / norm
    zero = np.zeros(3)
    _solve_tripod_balance(P, n, arms, rollers, acc, torque, m, zero, zero, out)


@njit(cache=True)
def joint_wrench(code, phi, omega, torque, rfp, off, out):
    """Housing-frame wrench (joints/wrench.py) of one joint with input angle phi (rad),
    speed omega (rad/s) and input torque (N m) into out[0:6]; returns 0, or 1 when the
    compiled model could not answer (Newton failure): the caller falls back to Python."""
    for i in range(5):
        out[i] = 0.0
    if code == R_TORQUE_IDENTITY:
        out[5] = torque
    elif code == R_TORQUE_GEAR:
        out[5] = rfp[off] * torque
    elif code == R_TORQUE_RATIO:
        ratio = joint_eval(int(rfp[off]), phi, rfp, int(rfp[off + 1]))[1]
        out[5] = torque / ratio
    elif code == R_HOOKE_EXACT:
        c, sb, yoke = rfp[off], rfp[off + 1], rfp[off + 2]
        tb = sb / c
        th = phi + yoke if yoke != 0.0 else phi     # driving arm from the bend plane
        s1, c1 = math.sin(th), math.cos(th)
        n2 = c * c * c1 * c1 + s1 * s1
        out[3] = -torque * tb * s1 * c1
        out[4] = -(torque * tb * s1 * s1)
        out[5] = torque * n2 / c
    elif code == R_HOOKE_IDEAL:
        out[4] = -0.0
        out[5] = torque
    elif code == R_TRIPOD_SMALL:
        tripod_small_reactions(phi, omega, torque, rfp, off, out)
    elif code == R_TRIPOD_EXACT:
        return tripod_exact_reactions(phi, omega, torque, rfp, off, out)
    else:
        return 1
    return 0
