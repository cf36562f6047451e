"""Hand-written compiled right-hand sides of three scenes, `bench.hooke_2dof_scene`, the
shipped `stiff` scene and the shipped `fwd_halfshaft` scene (the bench's reference for the
price of evaluating a scene from data):
the same equations as kernel/rhs_nb.rhs with the scene's structure written out, no section
walk, no op dispatch.

stiff: the same without the joint, r = 1, s = 0: w1' = (T - Tl) / J1.

hooke_2dof:
State (q0, q1, w0, w1[, E_engine, E_load, E_damp]): engine shaft J0 with the linear engine
Te = x M1 - K1 w0 (Kavzarashvili engine line), a linear spring T = k (q0 - q1) + d (w0 - w1),
then section 1: a Hooke joint (phi, r, s) = hooke_stage(q1, cos beta) driving J1 with the
constant load Tl at its output, so M1 = J1 r^2, C1 = J1 r s and
w1' = (T - Tl r - C1 w1^2) / M1 (driveline.py's M(q) qddot + C(q) qdot^2 = Q).

fwd_halfshaft: three sections - the crank J0 with the map engine (engine.map_engine_eval);
the clutch damper (dead-zone spring, rhs_nb.spring_deflection); input shaft J1, gear k,
differential J2, the exact tripod (its Fourier series, joints/tripod.py) and midshaft J3, so
M1 = J1 + J2 k^2 + J3 (k r)^2, C1 = J3 (k r)(s k^2); the linear midshaft spring on the twist
phi_tripod - q2; the homokinetic Rzeppa (the identity) and the wheel J4 under the road load.

Two timing loops per model. ``time_*_calls`` cycle through the 16 timing states and let
LLVM inline a small rhs into the loop (throughput of independent calls). ``time_*_chain``
time what an integrator's stage pays: the rhs behind a call LLVM may not inline
(:func:`call_not_inlined`, the kernel's steppers call ``rhs`` the same way), arrays
borrowed as the steppers' entry points borrow them, and each call's input the stage
z = y_j + h f(z_previous) of the previous call's output, so calls cannot overlap.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit, types
from numba.core import cgutils
from numba.extending import intrinsic

from cvj_ros.physics.kernel.borrow_nb import borrowed, borrowed_all, stack_zeros_2d
from cvj_ros.physics.kernel.joints_nb import hooke_stage_nb, tripod_series_inline_nb
from cvj_ros.physics.kernel.rhs_nb import rhs, spring_deflection
from cvj_ros.physics.kernel.sources_nb import map_engine_inline_nb

__all__ = ['CHAIN_H', 'call_not_inlined', 'fwd_halfshaft_params', 'fwd_halfshaft_rhs',
           'hooke_2dof_params', 'hooke_2dof_rhs', 'stiff_params', 'stiff_rhs',
           'time_fwd_halfshaft_calls', 'time_fwd_halfshaft_chain', 'time_hooke_2dof_calls',
           'time_hooke_2dof_chain', 'time_kernel_calls', 'time_kernel_chain', 'time_null_chain',
           'time_stiff_calls', 'time_stiff_chain', 'timing_states']


def timing_states(x0: np.ndarray, count: int = 16, seed: int = 0) -> np.ndarray:
    """``count`` states around ``x0`` (rows; angles +-0.5 rad, speeds +-5 %) for the timing
    loops: a loop over one fixed state would let the compiler hoist a hand-written rhs that
    does not read t out of the loop."""
    rng = np.random.default_rng(seed)
    n = (x0.size - 3) // 2 if x0.size % 2 else x0.size // 2
    ys = np.repeat(x0[None, :], count, axis=0).astype(float)
    ys[:, :n] += rng.uniform(-0.5, 0.5, (count, n))
    ys[:, n:2 * n] *= 1.0 + rng.uniform(-0.05, 0.05, (count, n))
    return np.ascontiguousarray(ys)


def hooke_2dof_params(scene: object) -> np.ndarray:
    """(J0, J1, k, d, cos beta, x M1, K1, Tl) of `bench.hooke_2dof_scene` (parsed Scene)."""
    el = {e.name: e for e in scene.driveline}           # type: ignore[attr-defined]
    eng, load = scene.engine, scene.load                 # type: ignore[attr-defined]
    return np.array([el['engine_shaft'].J, el['load_shaft'].J, el['spring'].stiffness,
                     el['spring'].damping, math.cos(el['hooke'].params['beta']),
                     float(eng.get('throttle', 1.0)) * eng['m1'], eng['k1'], load['torque']])


@njit(cache=True)
def hooke_2dof_rhs(t, y, p, dy):
    """dy/dt of the 2-DOF engine-spring-Hooke-load model (module docstring), in place."""
    te = p[5] - p[6] * y[2]
    th = y[0] - y[1]
    thd = y[2] - y[3]
    ts = p[2] * th + p[3] * thd
    phi, r, s = hooke_stage_nb(y[1], p[4])
    m = p[1] * r * r
    c = p[1] * r * s
    dy[0] = y[2]
    dy[1] = y[3]
    dy[2] = (te - ts) / p[0]
    dy[3] = (ts - p[7] * r - c * y[3] * y[3]) / m
    if y.shape[0] > 4:
        dy[4] = te * y[2]
        dy[5] = p[7] * r * y[3]
        dy[6] = p[3] * thd * thd


@njit(cache=True)
def time_hooke_2dof_calls(n, t, ys, p):
    """Call :func:`hooke_2dof_rhs` n times cycling through the states (rows of ``ys``), the
    time advancing by 1 ns a call, summing dy[2] + dy[3] so no call is loop-invariant or
    dead (the same loop as :func:`time_kernel_calls`); returns the sum."""
    dy = np.empty(ys.shape[1])
    m = ys.shape[0]
    acc = 0.0
    for k in range(n):
        hooke_2dof_rhs(t + k * 1e-9, ys[k % m], p, dy)
        acc += dy[2] + dy[3]
    return acc


@njit(cache=True)
def time_kernel_calls(n, t, ys, ip, fp):
    """The kernel's rhs (kernel/rhs_nb.rhs) in the loop of :func:`time_hooke_2dof_calls`."""
    dy = np.empty(ys.shape[1])
    m = ys.shape[0]
    acc = 0.0
    for k in range(n):
        rhs(t + k * 1e-9, ys[k % m], ip, fp, dy)
        acc += dy[2] + dy[3]
    return acc


def stiff_params(scene: object) -> np.ndarray:
    """(J0, J1, k, d, x M1, K1, Tl) of the shipped `stiff` scene (parsed Scene)."""
    el = {e.name: e for e in scene.driveline}           # type: ignore[attr-defined]
    eng, load = scene.engine, scene.load                 # type: ignore[attr-defined]
    return np.array([el['drive'].J, el['driven'].J, el['stiff_spring'].stiffness,
                     el['stiff_spring'].damping, float(eng.get('throttle', 1.0)) * eng['m1'],
                     eng['k1'], load['torque']])


@njit(cache=True)
def stiff_rhs(t, y, p, dy):
    """dy/dt of the stiff scene (two inertias, a linear spring, linear engine, constant load)."""
    te = p[4] - p[5] * y[2]
    th = y[0] - y[1]
    thd = y[2] - y[3]
    ts = p[2] * th + p[3] * thd
    dy[0] = y[2]
    dy[1] = y[3]
    dy[2] = (te - ts) / p[0]
    dy[3] = (ts - p[6]) / p[1]
    if y.shape[0] > 4:
        dy[4] = te * y[2]
        dy[5] = p[6] * y[3]
        dy[6] = p[3] * thd * thd


@njit(cache=True)
def time_stiff_calls(n, t, ys, p):
    """:func:`time_hooke_2dof_calls` for :func:`stiff_rhs`."""
    dy = np.empty(ys.shape[1])
    m = ys.shape[0]
    acc = 0.0
    for k in range(n):
        stiff_rhs(t + k * 1e-9, ys[k % m], p, dy)
        acc += dy[2] + dy[3]
    return acc


def fwd_halfshaft_params(scene: object) -> np.ndarray:
    """(J0..J4, k, clutch c d g w, midshaft c d, road roll aero climb lever vs, throttle, the
    map engine's 13 constants and n, its tables w[n] T[n] d[n], the tripod's nc and b_1..b_nc)
    of the shipped `fwd_halfshaft` scene (parsed Scene; the exact tripod's table and the
    engine's constants from their models)."""
    from cvj_ros.bench import forced_levels
    from cvj_ros.physics.simulate import Simulation
    sim = Simulation(scene, fidelity=forced_levels(scene, 'exact'))
    el = {e.name: e for e in scene.driveline}           # type: ignore[attr-defined]
    tripod = sim.driveline.joint_models['tripod']
    gear = sim.driveline.joint_models['gearbox']
    cl, mid = sim.driveline.springs
    road = sim.load
    w, tq, d, *consts = sim.engine.kernel_params()
    head = [el[n].J for n in ('engine_crank', 'input_shaft', 'differential', 'midshaft', 'wheel')]
    head += [float(gear._k), cl.c, cl.d, cl.gap, cl.width, mid.c, mid.d,
             road._roll, road._aero, road._climb, road._lever, road.vs, float(sim.engine.throttle)]
    return np.array(head + [float(c) for c in consts] + [float(len(w))] + list(w) + list(tq)
                    + list(d) + [float(len(tripod._coeff_list))] + list(tripod._coeff_list))


@njit(cache=True)
def fwd_halfshaft_rhs(t, y, p, dy):
    """dy/dt of the fwd_halfshaft scene (module docstring; state q0..q2, w0..w2, the three
    work integrals), in place."""
    p = borrowed(p)
    n = int(p[31])
    o = 32
    te = map_engine_inline_nb(y[3], y[0], p[17], p[o:o + n], p[o + n:o + 2 * n],
                              p[o + 2 * n:o + 3 * n], p[18], p[19], p[20], p[21], p[22], p[23],
                              p[24], p[25], p[26], p[27], p[28], p[29], p[30])[0]
    # clutch damper: dead zone, no progressive term
    th0 = y[0] - y[1]
    thd0 = y[3] - y[4]
    e, de, _dde = spring_deflection(th0, p[8], p[9])
    ts0 = p[6] * e * de + p[7] * de * thd0
    # section 1: J1, gear k, J2, tripod, J3
    k = p[5]
    nc = int(p[o + 3 * n])
    phi, r, s = tripod_series_inline_nb(y[1] * k, p[o + 3 * n + 1:o + 3 * n + 1 + nc])
    a = r * k
    b = s * k * k
    m1 = p[1] + p[2] * k * k + p[3] * a * a
    c1 = p[3] * a * b
    th1 = phi - y[2]
    thd1 = a * y[4] - y[5]
    ts1 = p[10] * th1 + p[11] * thd1
    # wheel under the road load (Rzeppa K = 1: the identity)
    v = y[5] * p[15]
    tv = math.tanh(v / p[16])
    tl = (p[12] * tv + p[13] * v * abs(v) + p[14]) * p[15]
    dy[0] = y[3]
    dy[1] = y[4]
    dy[2] = y[5]
    dy[3] = (te - ts0) / p[0]
    dy[4] = (ts0 - ts1 * a - c1 * y[4] * y[4]) / m1
    dy[5] = (ts1 - tl) / p[4]
    dy[6] = te * y[3]
    dy[7] = tl * y[5]
    dy[8] = p[7] * de * thd0 * thd0 + p[11] * thd1 * thd1


@njit(cache=True)
def time_fwd_halfshaft_calls(n, t, ys, p):
    """:func:`time_hooke_2dof_calls` for :func:`fwd_halfshaft_rhs`."""
    dy = np.empty(ys.shape[1])
    m = ys.shape[0]
    acc = 0.0
    for k in range(n):
        fwd_halfshaft_rhs(t + k * 1e-9, ys[k % m], p, dy)
        acc += dy[2] + dy[3]
    return acc


@intrinsic
def call_not_inlined(typingctx, fn, args):
    """``fn(*args)`` for the njit function ``fn`` (a global, so the caller stays cacheable) as
    a direct call in numba's calling convention carrying LLVM's ``noinline`` attribute: the
    call boundary an integrator's stage pays for a rhs too large to inline (the kernel's),
    given to a small rhs as well, so that no work moves between calls. An exception raised
    by ``fn`` propagates."""
    if not isinstance(fn, types.Dispatcher) or not isinstance(args, types.BaseTuple):
        return None
    fsig = typingctx.resolve_function_type(fn, tuple(args.types), {})
    if fsig is None:
        return None

    def codegen(context, builder, sig, llargs):
        cres = fn.dispatcher.overloads[fsig.args]
        context.add_linking_libs([cres.library])
        values = [builder.extract_value(llargs[1], i) for i in range(len(args.types))]
        fnty = context.call_conv.get_function_type(fsig.return_type, fsig.args)
        callee = cgutils.get_or_insert_function(builder.module, fnty, cres.fndesc.mangled_name)
        status, res = context.call_conv.call_function(builder, callee, fsig.return_type,
                                                      fsig.args, values, attrs=('noinline',))
        with cgutils.if_unlikely(builder, status.is_error):
            context.call_conv.return_status_propagate(builder, status)
        return res

    return fsig.return_type(fn, args), codegen


#: the stage step (s) of the chained timing loops: z = y_j + CHAIN_H f; with the timing
#: states' largest |f| (stiff: 8e7 rad/s^2) it moves a speed by < 0.1 rad/s
CHAIN_H = 1e-9


@njit(inline='always')
def _stage_chain(fn, n, t, ys, h, extra):
    """n calls fn(t_k, z, *extra, dy), z = ys[k mod m] + h dy (dy of the call before, 0 at
    the start: the same states every time), t_k = t + k ns, z and dy on the stack, ys and
    extra borrowed; returns the sum of dy[2] + dy[3] over the calls."""
    ys = borrowed(ys)
    extra = borrowed_all(extra)
    m = ys.shape[0]
    ns = ys.shape[1]
    sc = stack_zeros_2d(2, ns)
    z = sc[0]
    dy = sc[1]
    acc = 0.0
    j = 0
    for k in range(n):
        for i in range(ns):
            z[i] = ys[j, i] + h * dy[i]
        call_not_inlined(fn, (t + k * 1e-9, z) + extra + (dy,))
        acc += dy[2] + dy[3]
        j += 1
        if j == m:
            j = 0
    return acc


@njit(cache=True)
def time_kernel_chain(n, t, ys, h, ip, fp):
    """The kernel's rhs (kernel/rhs_nb.rhs) in :func:`_stage_chain`; returns its sum."""
    return _stage_chain(rhs, n, t, ys, h, (ip, fp))


@njit(cache=True)
def time_hooke_2dof_chain(n, t, ys, h, p):
    """:func:`hooke_2dof_rhs` in :func:`_stage_chain` (the sum equals
    :func:`time_kernel_chain`'s bit for bit)."""
    return _stage_chain(hooke_2dof_rhs, n, t, ys, h, (p,))


@njit(cache=True)
def time_stiff_chain(n, t, ys, h, p):
    """:func:`stiff_rhs` in :func:`_stage_chain`."""
    return _stage_chain(stiff_rhs, n, t, ys, h, (p,))


@njit(cache=True)
def time_fwd_halfshaft_chain(n, t, ys, h, p):
    """:func:`fwd_halfshaft_rhs` in :func:`_stage_chain`."""
    return _stage_chain(fwd_halfshaft_rhs, n, t, ys, h, (p,))


@njit(cache=True)
def null_rhs(t, y, p, dy):
    """An rhs that computes nothing (dy stays as it is): :func:`time_null_chain`'s callee."""
    return


@njit(cache=True)
def time_null_chain(n, t, ys, h, p):
    """:func:`null_rhs` in :func:`_stage_chain`: the chain's own price per call (the stage
    z = y + h dy and the call), which the other ``*_chain`` loops include."""
    return _stage_chain(null_rhs, n, t, ys, h, (p,))
