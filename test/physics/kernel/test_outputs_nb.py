"""kernel/outputs_nb.py: the lever hinge's earring angle computed alone (earring_angle) is
bit for bit the exact lever law's phi_out with twist 0 and an identity output stage, which
the intermediate-member fill evaluated before; the fill of a kavz685_lever run gives the
same bytes either way."""
from __future__ import annotations

import math

import numpy as np
import pytest

from cvj_ros.physics.kernel.joints_nb import lever_exact_nb
from cvj_ros.physics.kernel.layout import OP_LEVER_EXACT
from cvj_ros.physics.kernel.outputs_nb import (MID_EARRING, earring_angle, fill_mid_samples,
                                               mid_table)
from cvj_ros.physics.scene import find_scene, load_scene
from cvj_ros.physics.simulate import Simulation


def _bits(x: float) -> int:
    return int(np.array(x, dtype=np.float64).view(np.int64))


@pytest.mark.parametrize('alpha_deg', [0.0, 1e-6, 7.5, 20.0, 45.0, 89.9])
def test_earring_angle_is_the_exact_laws_first_stage_bit_for_bit(alpha_deg):
    a = math.radians(alpha_deg)
    ca, sa2 = math.cos(a), math.sin(a) ** 2
    rng = np.random.default_rng(int(alpha_deg * 1000))
    phis = [0.0, -0.0, 1e-300, -1e-300, math.pi / 2, -math.pi / 2, math.pi, -math.pi,
            2 * math.pi, 1e6, -1e6, *rng.uniform(-100.0, 100.0, 2000).tolist(),
            *rng.uniform(-1e-3, 1e-3, 200).tolist()]
    for phi in phis:
        want = lever_exact_nb(phi, ca, sa2, 0.0, 1.0, 0.0)[0]
        assert _bits(earring_angle(phi, ca)) == _bits(want), (phi, alpha_deg)


def test_fill_of_a_lever_hinge_run_is_unchanged():
    """The earring's angle and speed over a kavz685_lever run (2001 samples), by the
    earring row and by the same row on the exact law (the code the fill used before)."""
    sim = Simulation(load_scene(find_scene('kavz685_lever')))
    tr = sim.run(0.5, sample_dt=0.00025)
    mtab, mfp, python = mid_table(sim.driveline)
    assert mtab.shape[0] == 1 and mtab[0, 2] == MID_EARRING and not python
    old = mtab.copy()
    old[:, 2] = OP_LEVER_EXACT
    pos_a, vel_a = tr.position.copy(), tr.velocity.copy()
    pos_b, vel_b = tr.position.copy(), tr.velocity.copy()
    pos_a[:, mtab[0, 0]] = vel_a[:, mtab[0, 0]] = np.nan
    pos_b[:, mtab[0, 0]] = vel_b[:, mtab[0, 0]] = np.nan
    fill_mid_samples(pos_a, vel_a, mtab, mfp)
    fill_mid_samples(pos_b, vel_b, old, mfp)
    assert np.isfinite(pos_a).all() and np.isfinite(vel_a).all()
    assert pos_a.tobytes() == pos_b.tobytes() and vel_a.tobytes() == vel_b.tobytes()
    assert pos_a.tobytes() == tr.position.tobytes() and vel_a.tobytes() == tr.velocity.tobytes()


def test_walk_energy_residual_uses_the_rhs_sections_inertia_bit_for_bit():
    """sample_outputs sums each section's reduced inertia M = sum J a^2 during its own walk
    over the ops (the lever law evaluated once per sample there, not again by
    rhs_nb.section). Its energy residual over a kavz685_lever run (the driven shaft's inertia
    sits behind the lever hinge, so M varies with the angle) equals bit for bit the residual
    built here from rhs_nb.section's M and phi_end (the rhs's own evaluation) and the linear
    spring's potential c (e^2/2 + k2 e^4/4), in the walk's order of operations."""
    from cvj_ros.physics.kernel.layout import (H_ENERGY, H_IMBALANCE, H_NDOF, H_SPRING_F,
                                               SPRING_STRIDE)
    from cvj_ros.physics.kernel.rhs_nb import section
    sim = Simulation(load_scene(find_scene('kavz685_lever')))
    tr = sim.run(0.5, sample_dt=0.001, reuse_trace=True)
    plan = next(iter(sim._plans.values()))
    X = plan.kept[1][0]
    ip, fp = plan.model.ip, plan.model.fp
    n, sp0 = int(ip[H_NDOF]), int(ip[H_SPRING_F])
    assert ip[H_ENERGY] != 0 and ip[H_IMBALANCE] == 0 and n == 2
    e0 = sim._initial_energy(sim.driveline.x0)
    ms = set()
    for k in range(X.shape[0]):
        y = X[k]
        kin, el = 0.0, 0.0
        for g in range(n):
            phi, _a, _b, m, _c, _mp, _hj = section(g, y[g], ip, fp)
            v = float(y[n + g])
            kin += 0.5 * m * v * v
            ms.add(m)
            if g < n - 1:
                off = sp0 + SPRING_STRIDE * g
                assert fp[off + 3] == 0.0 and fp[off + 5] == 0.0    # linear, no lash
                e = phi - float(y[g + 1])
                el += float(fp[off]) * (0.5 * e * e + 0.25 * float(fp[off + 2]) * e * e * e * e)
        tot = kin + el
        we, wl, wd = (float(y[2 * n + i]) for i in range(3))
        scale = max(abs(tot), abs(e0), abs(we), abs(wl), abs(wd), 1e-12)
        want = (tot - e0 - we + wl + wd) / scale
        assert _bits(tr.energy_residual[k]) == _bits(want), k
    assert len(ms) > 100        # M(q) does vary over the run (the test sees the joint)


def test_sample_outputs_allocates_nothing_per_run():
    """sample_outputs keeps its walk's scratch (dy and the per-op angle, speed and torque) on
    the stack: a compiled loop of 11 calls allocates as much as a loop of one (numba's NRT
    allocation counters, switched on for this test only), and gives the same bytes each
    time. Before, each call allocated its four scratch arrays: all of a stiff run's NRT
    allocations."""
    from numba import njit
    from numba.core.runtime import _nrt_python as nrt

    from cvj_ros.physics.kernel.outputs_nb import sample_outputs

    @njit
    def loop(reps, T, X, ip, fp, tab, e0, pos, vel, eff, te, tl, res):
        bad = 0
        for _ in range(reps):
            bad += sample_outputs(T, X, ip, fp, tab, e0, pos, vel, eff, te, tl, res)
        return bad

    sim = Simulation(load_scene(find_scene('stiff')), method='rodas3', rtol=1e-3, atol=1e-3)
    tr = sim.run(1.0, sample_dt=0.05, sampling='dense', reuse_trace=True)
    plan = next(iter(sim._plans.values()))
    X = plan.kept[1][0]
    m, n_sh = X.shape[0], tr.position.shape[1]
    outs = [np.empty((m, n_sh)) for _ in range(3)] + [np.empty(m) for _ in range(3)]
    args = (plan.times, X, plan.model.ip, plan.model.fp, sim._shaft_table,
            sim._initial_energy(sim.driveline.x0), *outs)
    assert loop(1, *args) == -1
    was_on = nrt.memsys_stats_enabled()
    nrt.memsys_enable_stats()
    try:
        counts = []
        for reps in (1, 11):
            a0 = nrt.memsys_get_stats_alloc()
            loop(reps, *args)
            counts.append(nrt.memsys_get_stats_alloc() - a0)
    finally:
        if not was_on:
            nrt.memsys_disable_stats()
    assert counts[0] == counts[1], counts      # only the arguments' unboxing allocates
    for got, want in zip(outs, (tr.position, tr.velocity, tr.effort, tr.engine_torque,
                                tr.load_torque, tr.energy_residual)):
        assert got.tobytes() == want.tobytes()


def _reference_sample_outputs():
    """The walk as it was with the right-hand side called for the accelerations (each
    joint evaluated twice per sample): rhs_nb.rhs fills dy, the walk reads dy[n + g]. Not
    cached, compiled once per test session."""
    from numba import njit

    from cvj_ros.physics.kernel.joints_nb import joint_eval
    from cvj_ros.physics.kernel.layout import (H_ENERGY, H_IMBALANCE, H_NDOF, H_SEC,
                                               H_SPRING_F, OP_INERTIA, SPRING_STRIDE)
    from cvj_ros.physics.kernel.rhs_nb import (engine_torque, imbalance_force,
                                               imbalance_torque, load_torque, rhs,
                                               spring_deflection, spring_eval,
                                               spring_vary_eval)

    @njit
    def ref(T, X, ip, fp, tab, e0, pos, vel, eff, te, tl, res):
        n = ip[H_NDOF]
        sec = ip[H_SEC]
        ops = sec + n + 1
        sp0 = ip[H_SPRING_F]
        mp = 1
        for g in range(n):
            mp = max(mp, ip[sec + g + 1] - ip[sec + g] + 1)
        dy = np.empty(X.shape[1])
        st_phi = np.empty((n, mp))
        st_om = np.empty((n, mp))
        st_tq = np.empty((n, mp))
        for k in range(T.shape[0]):
            t, y = T[k], X[k]
            rhs(t, y, ip, fp, dy)
            tk_e = engine_torque(t, y, ip, fp)[0]
            phi_l, a_l, kin, el, carry = 0.0, 1.0, 0.0, 0.0, tk_e
            for g in range(n):
                q, v, acc = y[g], y[n + g], dy[n + g]
                phi, a, b, m, torque, p = q, 1.0, 0.0, 0.0, carry, 0
                st_phi[g, 0], st_om[g, 0], st_tq[g, 0] = phi, v, torque
                for kk in range(ip[sec + g], ip[sec + g + 1]):
                    code = ip[ops + 2 * kk]
                    off = ip[ops + 2 * kk + 1]
                    if code == OP_INERTIA:
                        jv = fp[off]
                        m += jv * a * a
                        torque -= jv * (a * acc + b * v * v)
                        if ip[H_IMBALANCE] != 0:
                            torque -= imbalance_torque(kk, phi, ip, fp)
                    else:
                        po, r, s = joint_eval(code, phi, fp, off)
                        b = s * a * a + r * b
                        a = r * a
                        phi = po
                        torque = torque / r
                    p += 1
                    st_phi[g, p], st_om[g, p], st_tq[g, p] = phi, a * v, torque
                kin += 0.5 * m * v * v
                if ip[H_IMBALANCE] != 0:
                    el += imbalance_force(g, q, ip, fp)[2]
                if g < n - 1:
                    off = sp0 + SPRING_STRIDE * g
                    th = phi - y[g + 1]
                    thd = a * v - y[n + g + 1]
                    if fp[off + 5] != 0.0:
                        vs = spring_vary_eval(th, thd, y[g + 1], fp, off)
                        carry = vs[0] + vs[1]
                        el += vs[7]
                    else:
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
    return ref


_REF: list = []

#: every shipped chain scene without a clutch's stick/slip modes (the vehicle scenes walk
#: in tree_outputs_nb, launch_clutch_chain runs on the mode model)
CHAIN_SCENES = ['cardan_truck', 'fwd_halfshaft', 'kavz685_lever', 'stiff', 'tripod_xiu2024']


def _fidelities(scene):
    """None (the scene's own), then every joint at each fidelity its kind takes."""
    from cvj_ros.physics.scene import Joint
    out = [None]
    joints = [el for el in scene.driveline if isinstance(el, Joint)]
    for fid in ('ideal', 'closed', 'exact'):
        over = {}
        for el in joints:
            try:
                Simulation(scene, fidelity={el.name: fid})
            except Exception:       # this kind has no such fidelity
                continue
            over[el.name] = fid
        if over:
            out.append(over)
    return out


def _check_section_accel_is_rhs(T, X, ip, fp):
    """rhs_nb.section_accel, chained over the sections on rhs_nb.section's values, gives
    rhs_nb.rhs's accelerations, load power and damping power bit for bit at every state."""
    from cvj_ros.physics.kernel.layout import H_ENERGY, H_NDOF
    from cvj_ros.physics.kernel.rhs_nb import engine_torque, rhs, section, section_accel
    n = int(ip[H_NDOF])
    dy = np.empty(X.shape[1])
    for k in range(X.shape[0]):
        t, y = float(T[k]), X[k]
        rhs(t, y, ip, fp, dy)
        te = engine_torque(t, y, ip, fp)[0]
        carry, p_damp = 0.0, 0.0
        for g in range(n):
            phi, a, _b, m, c, _mp, _hj = section(g, y[g], ip, fp)
            acc, carry, tl, pd = section_accel(t, y, ip, fp, g, phi, a, m, c, te, carry)
            assert _bits(acc) == _bits(dy[n + g]), (k, g)
            if g < n - 1:
                p_damp += pd
            elif ip[H_ENERGY] != 0:
                assert _bits(tl * a * y[2 * n - 1]) == _bits(dy[2 * n + 1]), k
        if ip[H_ENERGY] != 0:
            assert _bits(p_damp) == _bits(dy[2 * n + 2]), k


@pytest.mark.parametrize('name', CHAIN_SCENES)
def test_walk_with_one_joint_evaluation_equals_the_walk_on_the_rhs_bit_for_bit(name):
    """sample_outputs evaluates each joint once per sample: the accelerations the torques
    need come from rhs_nb.section_accel (rhs_nb.rhs's per-section body written out again)
    on the M, C, phi_end and a of the walk's own pass. section_accel equals rhs bit for bit
    at every state (accelerations, load and damping power), and every output (angles,
    speeds, torques, engine and load torque, energy residual) equals bit for bit a walk
    that calls rhs_nb.rhs for the accelerations, over a run's states of every shipped chain scene, at the scene's own
    fidelity and with every joint at each fidelity its kind takes (Hooke, double cardan,
    tripod, Rzeppa, lever hinge, gear)."""
    if not _REF:
        _REF.append(_reference_sample_outputs())
    ref = _REF[0]
    from cvj_ros.physics.kernel.outputs_nb import sample_outputs
    scene = load_scene(find_scene(name))
    checked = 0
    for fid in _fidelities(scene):
        sim = Simulation(scene, fidelity=fid)
        sim.run(0.3, sample_dt=0.002, reuse_trace=True)
        plan = next(iter(sim._plans.values()))
        T, X = plan.times, plan.kept[1][0]
        ip, fp = plan.model.ip, plan.model.fp
        m, n_sh = X.shape[0], sim._shaft_table.shape[0]
        e0 = sim._initial_energy(sim.driveline.x0)
        got = [np.empty((m, n_sh)) for _ in range(3)] + [np.empty(m) for _ in range(3)]
        want = [np.empty((m, n_sh)) for _ in range(3)] + [np.empty(m) for _ in range(3)]
        assert sample_outputs(T, X, ip, fp, sim._shaft_table, e0, *got) == -1
        ref(T, X, ip, fp, sim._shaft_table, e0, *want)
        for a, b in zip(got, want):
            assert a.tobytes() == b.tobytes(), (name, fid)
        _check_section_accel_is_rhs(T, X, ip, fp)
        assert np.ptp(got[2]) > 0.0         # the torques move over the run
        checked += m
    assert checked > 100


@pytest.mark.parametrize('alpha_deg,delta_deg,twist', [(0.0, 0.0, 0.0), (15.0, 1.72, 0.0),
                                                       (30.0, -3.0, 0.02), (60.0, 20.0, -0.1)])
def test_lever_ratio_alone_is_the_exact_laws_ratio_and_slope_bit_for_bit(alpha_deg, delta_deg,
                                                                         twist):
    """lever_exact_ratio (the lean walk's exact lever law without the output angle) gives
    lever_exact_nb's ratio and slope bit for bit; joint_ratio of every other op is
    joint_eval's."""
    from cvj_ros.physics.kernel.joints_nb import joint_eval
    from cvj_ros.physics.kernel.layout import OP_LEVER_RATIO
    from cvj_ros.physics.kernel.outputs_nb import joint_ratio, lever_exact_ratio
    a, d = math.radians(alpha_deg), math.radians(alpha_deg + delta_deg)
    args = (math.cos(a), math.sin(a) ** 2, twist, math.cos(d), math.sin(d) ** 2)
    rng = np.random.default_rng(int(alpha_deg * 100 + delta_deg * 10))
    phis = [0.0, -0.0, 1e-300, math.pi / 2, -math.pi / 2, math.pi, 1e6,
            *rng.uniform(-100.0, 100.0, 3000).tolist()]
    fp = np.array([0.0, *args])
    for phi in phis:
        _po, r, s = lever_exact_nb(phi, *args)
        got = lever_exact_ratio(phi, *args)
        assert (_bits(got[0]), _bits(got[1])) == (_bits(r), _bits(s)), phi
        got = joint_ratio(OP_LEVER_EXACT, phi, fp, 1)
        assert (_bits(got[0]), _bits(got[1])) == (_bits(r), _bits(s)), phi
        got = joint_ratio(OP_LEVER_RATIO, phi, fp, 1)
        assert (_bits(got[0]), _bits(got[1])) == (_bits(r), _bits(s)), phi
        po, r2, s2 = joint_eval(OP_LEVER_RATIO, phi, fp, 1)      # the rhs's dispatch
        assert math.isnan(po) and (_bits(r2), _bits(s2)) == (_bits(r), _bits(s)), phi


def _lean_flags(sim):
    """unread_angles of a Simulation's model for the sweep's reads: the first shaft's
    angle and the intermediate members' inputs."""
    from cvj_ros.physics.kernel.outputs_nb import unread_angles
    plan = next(iter(sim._plans.values()))
    mtab = sim._mid_table[0]
    return unread_angles(plan.model.ip, sim._shaft_table, sorted({0, *mtab[:, 1].tolist()}))


def _kept_run_with_lean_flags(scene, fid):
    """A kept 0.3 s run of ``scene`` at fidelity ``fid`` (2 ms samples): the Simulation, its
    sample times and states, the model's ip and fp, the shaft table and the sweep's
    unread-angle flags (_lean_flags)."""
    sim = Simulation(scene, fidelity=fid)
    sim.run(0.3, sample_dt=0.002, reuse_trace=True)
    plan = next(iter(sim._plans.values()))
    return (sim, plan.times, plan.kept[1][0], plan.model.ip, plan.model.fp, sim._shaft_table,
            _lean_flags(sim))


@pytest.mark.parametrize('name', CHAIN_SCENES)
def test_lean_walk_gives_the_same_outputs_but_the_unread_angles(name):
    """sample_outputs_lean with unread_angles' flags for the sweep's reads (the first shaft's
    angle, the members' inputs) gives sample_outputs' speeds, torques, engine and load
    torques and energy residual bit for bit, the same angles in every column before a
    flagged joint and NaN after it, on every shipped chain scene at each fidelity. The
    kavz685_lever's exact lever hinge (a joint at the driven end, a random load) is
    flagged."""
    from cvj_ros.physics.kernel.outputs_nb import sample_outputs, sample_outputs_lean
    scene = load_scene(find_scene(name))
    flagged = 0
    for fid in _fidelities(scene):
        sim, T, X, ip, fp, tab, skip = _kept_run_with_lean_flags(scene, fid)
        m, n_sh = X.shape[0], tab.shape[0]
        e0 = sim._initial_energy(sim.driveline.x0)
        got = [np.empty((m, n_sh)) for _ in range(3)] + [np.empty(m) for _ in range(3)]
        want = [np.empty((m, n_sh)) for _ in range(3)] + [np.empty(m) for _ in range(3)]
        assert sample_outputs(T, X, ip, fp, tab, e0, *want) == -1
        assert sample_outputs_lean(T, X, ip, fp, tab, e0, skip, *got) == -1
        for a, b in zip(got[1:], want[1:]):
            assert a.tobytes() == b.tobytes(), (name, fid)
        n = int(ip[0])
        sec = int(ip[9])
        nan_cols = []
        for kk in np.flatnonzero(skip):
            g = n - 1
            nan_cols += [c for c in range(n_sh)
                         if tab[c, 0] == g and tab[c, 1] > kk - ip[sec + g]]
        for c in range(n_sh):
            if c in nan_cols:
                assert np.isnan(got[0][:, c]).all(), (name, fid, c)
            else:
                assert got[0][:, c].tobytes() == want[0][:, c].tobytes(), (name, fid, c)
        flagged += int(skip.sum())
        if name == 'kavz685_lever' and fid is None:
            assert skip.sum() == 1 and nan_cols == [3, 4]
    if name == 'kavz685_lever':
        assert flagged >= 2


@pytest.mark.parametrize('name', CHAIN_SCENES)
def test_ratio_only_ip_gives_the_same_rhs_and_lean_walk_bit_for_bit(name):
    """ratio_only_ip codes the flagged exact lever hinges OP_LEVER_RATIO (their output
    angle not computed) and nothing else; with it rhs_nb.rhs gives the same derivative bit
    for bit at every state of a run and at states between them (the integration's stages
    are not samples), and sample_outputs_lean the same outputs, on every shipped chain scene
    at each fidelity; kavz685_lever's exact lever hinge gets it."""
    from cvj_ros.physics.kernel.layout import H_NDOF, H_SEC, OP_LEVER_RATIO
    from cvj_ros.physics.kernel.outputs_nb import ratio_only_ip, sample_outputs_lean
    from cvj_ros.physics.kernel.rhs_nb import rhs
    scene = load_scene(find_scene(name))
    swapped = 0
    for fid in _fidelities(scene):
        sim, T, X, ip, fp, tab, skip = _kept_run_with_lean_flags(scene, fid)
        lean = ratio_only_ip(ip, skip)
        ops = int(ip[H_SEC]) + int(ip[H_NDOF]) + 1
        levers = [k for k in np.flatnonzero(skip).tolist() if ip[ops + 2 * k] == OP_LEVER_EXACT]
        if lean is None:
            assert not levers, (name, fid)
            continue
        changed = np.flatnonzero(lean != ip).tolist()
        assert changed == [ops + 2 * k for k in levers] and (lean[changed] == OP_LEVER_RATIO).all()
        swapped += len(levers)
        rng = np.random.default_rng(7)
        states = [(float(T[k]), X[k]) for k in range(X.shape[0])]
        states += [(float(T[k]) + 1e-4, X[k] + rng.normal(0.0, 1e-3, X.shape[1]) * (1.0 + abs(X[k])))
                   for k in range(0, X.shape[0], 3)]
        want, got = np.empty(X.shape[1]), np.empty(X.shape[1])
        for t, y in states:
            rhs(t, y, ip, fp, want)
            rhs(t, y, lean, fp, got)
            assert got.tobytes() == want.tobytes(), (name, fid, t)
        m, n_sh = X.shape[0], tab.shape[0]
        e0 = sim._initial_energy(sim.driveline.x0)
        a = [np.empty((m, n_sh)) for _ in range(3)] + [np.empty(m) for _ in range(3)]
        b = [np.empty((m, n_sh)) for _ in range(3)] + [np.empty(m) for _ in range(3)]
        assert sample_outputs_lean(T, X, ip, fp, tab, e0, skip, *a) == -1
        assert sample_outputs_lean(T, X, lean, fp, tab, e0, skip, *b) == -1
        for u, v in zip(a, b):
            assert u.tobytes() == v.tobytes(), (name, fid)
    if name == 'kavz685_lever':
        assert swapped >= 1


def test_unread_angles_keeps_the_angles_something_reads():
    """No joint is flagged when a read shaft sits after it, when the load's torque depends on
    its angle (a Fourier load), with imbalance, or for a joint a spring follows
    (cardan_truck's first joints)."""
    from cvj_ros.physics.kernel.layout import H_IMBALANCE, H_LOAD, LOAD_FOURIER
    from cvj_ros.physics.kernel.outputs_nb import unread_angles
    sim = Simulation(load_scene(find_scene('kavz685_lever')), fidelity={'coupling': 'exact'})
    sim.run(0.01)
    plan = next(iter(sim._plans.values()))
    ip, tab = plan.model.ip, sim._shaft_table
    assert unread_angles(ip, tab, [0, 1]).tolist() == [0, 1, 0]
    assert not unread_angles(ip, tab, [0, 1, 3]).any()      # coupling_output's angle read
    assert not unread_angles(ip, tab, [0, 4]).any()         # driven_shaft's angle read
    for slot, value in ((H_LOAD, LOAD_FOURIER), (H_IMBALANCE, 1)):
        other = ip.copy()
        other[slot] = value
        assert not unread_angles(other, tab, [0, 1]).any()
    sim = Simulation(load_scene(find_scene('cardan_truck')))
    sim.run(0.01)
    plan = next(iter(sim._plans.values()))
    ip = plan.model.ip
    flags = unread_angles(ip, sim._shaft_table, [0])
    n, sec = int(ip[0]), int(ip[9])
    assert not flags[:int(ip[sec + n - 1])].any()       # every section but the last
