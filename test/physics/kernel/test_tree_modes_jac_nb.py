"""The analytic Jacobian of a vehicle tree mode (kernel/tree_modes_jac_nb.py,
hybrid/tree_jac.py) against central differences of the mode's right-hand side, and the two
backends against each other, at the start of every mode of launch_clutch (brakes pinned and
slipping, clutch slipping and stuck, gears, neutral, shifts), fwd_axle_manual (a shift
under load) and a clutch-pack differential on split mu (stuck, then slipping with its
torque-sensing bias), and at states with random angles, slip speeds, tyre slips and vehicle speed
around each; the torque-sensing pack's central-difference fallback (|m k B| >= 1) too.

Bound: a fourth-order central difference of increment h (1e-5 rad on the angles, 1e-5
max(1, |y_j|) on the rest) errs by h^4 |f^(5)| / 30 (truncation; the sharpest feature is
the lash's dead zone, w = 4.4e-4 rad: (h / w)^4 / 30 ~ 1e-8) plus ~eps |y| |f| / h
(rounding; twists are differences of angles up to ~1e3 rad: ~2e-8); both are below 1e-6 of
the column's scale max(max_i |J_ij|, max_i |f_i| / max(1, |y_j|)), so an entry off by a
missing term (relative 1) fails (measured: 6.5e-9 launch_clutch, 1.3e-8 fwd_axle_manual,
5.6e-9 the torque-sensing pack). The two backends' Jacobians are the same formula term by
term: bound 1e-12 of the column's scale max(max_i |J_ij|, 1) (measured: 5.8e-18, 1.6e-18,
0.0).
"""
from __future__ import annotations

import numpy as np
import pytest
import yaml

import cvj_ros.physics.hybrid.tree_sim as ts
from cvj_ros.physics.hybrid.from_scene import hybrid_simulation
from cvj_ros.physics.scene import load_scene, parse_scene, shipped_scenes

pytest.importorskip('numba')
from cvj_ros.physics.kernel.tree_modes import tree_mode_arrays  # noqa: E402
from cvj_ros.physics.kernel.tree_modes_jac_nb import tm_jac  # noqa: E402
from cvj_ros.physics.kernel.tree_modes_nb import MB_NWIT, tm_eval  # noqa: E402

FD_TOL = 1e-6
TWIN_TOL = 1e-12


def _central(f, t, y, n_dof):
    """Fourth-order central differences (-f(2h) + 8 f(h) - 8 f(-h) + f(-2h)) / 12h,
    increment h = 1e-5 on the angles (absolute: a clutch damper's lash is a dead zone
    softened over w = 4.4e-4 rad, which an increment relative to a shaft's turned angle,
    1e-6 x 1000 rad, would straddle), 1e-5 max(1, |y_j|) on the rest."""
    n = y.size
    J = np.empty((n, n))
    for j in range(n):
        h = 1e-5 if j < n_dof else 1e-5 * max(1.0, abs(y[j]))
        cols = []
        for m in (2.0, 1.0, -1.0, -2.0):
            yy = y.copy()
            yy[j] += m * h
            cols.append(f(t, yy))
        J[:, j] = (-cols[0] + 8.0 * cols[1] - 8.0 * cols[2] + cols[3]) / (12.0 * h)
    return J


def _fd_error(J, J_fd, f0, y, mt) -> float:
    """Largest |J - J_fd| over the column's scale. The relaxed slips' rate carries |v|: at a
    vehicle speed inside the difference's increment (a car just released, v ~ 1e-9 m/s)
    the central difference straddles the kink and sees its mean, so those entries (the
    slip rows' v column) are left out there."""
    scale = np.maximum(np.max(np.abs(J), axis=0), np.max(np.abs(f0)) / np.maximum(1.0, np.abs(y)))
    err = np.abs(J - J_fd) / np.maximum(scale, 1e-300)
    n, nw = mt.n_dof, mt.n_wheel
    iv = 2 * n + nw
    if abs(y[iv]) < 2e-5 * max(1.0, abs(y[iv])):        # the stencil reaches 2h
        err[2 * n:iv, iv] = 0.0
    return float(np.max(err))


def _states(mt, y0, rng):
    """y0 and two states around it: angles +-0.5 rad, speeds +-30 rad/s (slips of either
    sign), relaxed slips +-0.05, vehicle speed +-1 m/s; pinned coordinates stay at rest."""
    n, nw = mt.n_dof, mt.n_wheel
    out = [y0]
    for _ in range(2):
        y = y0.copy()
        y[:n] += rng.uniform(-0.5, 0.5, n)
        y[n:2 * n] += rng.uniform(-30.0, 30.0, n)
        y[2 * n:2 * n + nw] += rng.uniform(-0.05, 0.05, nw)
        y[2 * n + nw] += rng.uniform(-1.0, 1.0)
        for c in mt._pinned_coords:
            y[n + c] = 0.0
        out.append(y)
    return out


def _check_run(name: str | dict, duration: float, seed: int) -> dict:
    """Spy on every mode segment of a dopri5 run of the Python reference: the kernel's and
    the reference's Jacobians at its start and around it, against central differences and
    each other (the kernel's arrays of that mode: ``tree_mode_arrays``)."""
    scene = parse_scene(name) if isinstance(name, dict) else load_scene(shipped_scenes()[name])
    sim = hybrid_simulation(scene, duration=duration)
    rng = np.random.default_rng(seed)
    got = {'fd': 0.0, 'twin': 0.0, 'modes': set(), 'pinned': 0, 'slipping_clutch': 0}
    plain_tree, plain_stepper = sim.tree, ts.make_stepper
    now = {}

    def tree(mode):
        now['mt'] = plain_tree(mode)
        return now['mt']

    def spy(method, fun, t, y0, **kw):
        mt = now['mt']
        mode = mt.mode
        ip, fp = tree_mode_arrays(sim, mt, mode)
        mb = ip[-1]
        ns = y0.size
        wv = np.zeros(max(ip[mb + MB_NWIT], 1))

        def f_kernel(tt, yy):
            dy = np.zeros(ns)
            tm_eval(tt, yy, ip, fp, dy, wv, False)
            return dy

        got['modes'].add((tuple(sorted(mode.clutch.items())), tuple(sorted(mode.gear.items())),
                          tuple(sorted(mode.brakes.items())), tuple(sorted(mode.packs.items()))))
        got['pinned'] += bool(mt.pinned)
        got['slipping_clutch'] += any(m != 0 for m in mode.clutch.values())
        for y in _states(mt, np.array(y0, dtype=float), rng):
            Jk = np.zeros((ns, ns))
            tm_jac(t, y, ip, fp, Jk)
            Jp = sim._jac(mt, t, y)
            f0 = fun(t, y)
            got['fd'] = max(got['fd'], _fd_error(Jk, _central(f_kernel, t, y, mt.n_dof), f0, y, mt),
                            _fd_error(Jp, _central(fun, t, y, mt.n_dof), f0, y, mt))
            scale = np.maximum(np.max(np.abs(Jp), axis=0), 1.0)
            got['twin'] = max(got['twin'], float(np.max(np.abs(Jk - Jp) / scale)))
            for c in mt._pinned_coords:
                assert not Jk[mt.n_dof + c].any() and not Jp[mt.n_dof + c].any()
        return plain_stepper(method, fun, t, y0, **kw)

    sim.tree = tree
    ts.make_stepper = spy
    try:
        sim.run()
    finally:
        ts.make_stepper = plain_stepper
    assert got['fd'] <= FD_TOL, got
    assert got['twin'] <= TWIN_TOL, got
    assert got['fd'] > 0.0
    return got


def test_launch_clutch_mode_jacobians() -> None:
    """Brake hold (pinned wheels), release (slipping brakes), clutch engagement (slipping,
    stuck), the scheduled shift 1 -> 2 (neutral, gears): open differential, tripod and
    Rzeppa joints (position-dependent rows and masses), tyres with load transfer."""
    got = _check_run('launch_clutch', 4.5, 11)
    assert len(got['modes']) >= 5 and got['pinned'] and got['slipping_clutch'], got


def test_fwd_axle_manual_mode_jacobians() -> None:
    """The commanded shift under load (lash in the clutch damper: the softplus dead zone)."""
    got = _check_run('fwd_axle_manual', 2.0, 12)
    assert len(got['modes']) >= 3, got


def _split_mu_pack(bias: float) -> dict:
    """fwd_axle_split_mu (left wheel on ice) at full throttle with a clutch-pack differential
    (preload 100 N m, torque_bias ``bias``)."""
    with open(shipped_scenes()['fwd_axle_split_mu'], encoding='utf-8') as f:
        d = yaml.safe_load(f)
    d['engine'] = {'model': 'map', 'throttle': 1.0}
    d['driveline'][4] = dict(d['driveline'][4], kind='clutch_pack', preload_nm=100.0,
                             torque_bias=bias)
    return d


@pytest.mark.parametrize('bias', [0.0, 0.2])
def test_clutch_pack_mode_jacobians(bias: float) -> None:
    """A clutch-pack differential on split mu (0.3 s): stuck (the locked pack's offset),
    then slipping with its preload (torque_bias 0) or with torque sensing (0.2: the bias's
    analytic derivative through the two backward walks; the random states around the slip
    mode's start give carrier torques of both signs, s = +1 and -1). Measured (0.2): 5.6e-9
    against central differences, the backends' Jacobians equal (0.0)."""
    got = _check_run(_split_mu_pack(bias), 0.3, 13)
    assert {m[3] for m in got['modes']} >= {(('differential', 0),), (('differential', 1),)}, got


def _pack_slip_start(monkeypatch) -> tuple:
    """(sim, mode tree, mode rhs, t, y) at the first start of a stepper with the split-mu pack
    slipping (torque_bias 0.2, 0.3 s): the make_stepper calls of a run, spied."""
    sim = hybrid_simulation(parse_scene(_split_mu_pack(0.2)), duration=0.3)
    starts = []
    plain_tree, plain_stepper = sim.tree, ts.make_stepper
    now = {}

    def tree(mode):
        now['mt'] = plain_tree(mode)
        return now['mt']

    def spy(method, fun, t, y0, **kw):
        starts.append((now['mt'], fun, t, np.array(y0, dtype=float)))
        return plain_stepper(method, fun, t, y0, **kw)

    sim.tree = tree
    monkeypatch.setattr(ts, 'make_stepper', spy)
    sim.run()
    slipping = [s for s in starts if s[0].mode.packs['differential'] != 0]
    assert slipping
    return (sim, *slipping[0])


def _count_evaluations(monkeypatch) -> list:
    """A list that gets one entry per ModeTree.evaluate call from now on."""
    from cvj_ros.physics.hybrid.tree import ModeTree
    calls = []
    plain_eval = ModeTree.evaluate

    def evaluate(self, *args, **kw):
        calls.append(1)
        return plain_eval(self, *args, **kw)

    monkeypatch.setattr(ModeTree, 'evaluate', evaluate)
    return calls


def test_torque_sensing_pack_jacobian_is_analytic(monkeypatch) -> None:
    """The reference's Jacobian of the slipping torque-sensing pack's mode evaluates the
    mode rhs once (the analytic path; central differences of the whole rhs took two per
    state component, 36 here), and equals the kernel's there."""
    sim, mt, _fun, t, y = _pack_slip_start(monkeypatch)
    calls = _count_evaluations(monkeypatch)
    Jp = sim._jac(mt, t, y)
    assert len(calls) == 1
    ip, fp = tree_mode_arrays(sim, mt, mt.mode)
    Jk = np.zeros_like(Jp)
    tm_jac(t, y, ip, fp, Jk)
    scale = np.maximum(np.max(np.abs(Jp), axis=0), 1.0)
    assert float(np.max(np.abs(Jk - Jp) / scale)) <= TWIN_TOL


def test_torque_sensing_pack_fallback_matches_central_differences(monkeypatch) -> None:
    """Where |m k B| >= 1 (the bias's implicit derivative has no consistent sign) both
    backends fall back to second-order central differences of the mode rhs (increment 1e-6
    max(1, |y_j|)). Reached here at the split-mu pack's slip start, where |B| = 0.28
    (measured: the analytic path holds up to k = 3.53), with the pack's torque_bias set to
    20 in the built mode tree (|m k B| = 5.7; the scene check caps torque_bias at 0.9, which
    needs |B| > 1.1 to get there), at that state and two random ones around it. The kernel
    took the branch when its Jacobian is bit for bit its ``_central``, the reference when it
    evaluated the rhs once per difference (2 per state component + 1, not once). Against the
    fourth-order differences of the module docstring, bound FD_TOL (the fallback's own
    truncation h^2 |f'''| / 6 and rounding eps |f| / h, h = 1e-6: ~1e-10 of the column's
    scale; measured 2.2e-10 .. 5.1e-10); the two backends' fallbacks equal within TWIN_TOL
    (measured 0.0)."""
    import dataclasses

    from cvj_ros.physics.kernel.tree_modes_jac_nb import _central as kernel_central
    sim, mt, fun, t, y0 = _pack_slip_start(monkeypatch)
    el, d = mt.packs['differential']
    monkeypatch.setitem(mt.packs, 'differential', (dataclasses.replace(el, torque_bias=20.0), d))
    ip, fp = tree_mode_arrays(sim, mt, mt.mode)
    ns = y0.size
    wv = np.zeros(max(ip[ip[-1] + MB_NWIT], 1))

    def f_kernel(tt, yy):
        dy = np.zeros(ns)
        tm_eval(tt, yy, ip, fp, dy, wv, False)
        return dy

    calls = _count_evaluations(monkeypatch)
    for y in _states(mt, y0, np.random.default_rng(14)):
        Jk = np.zeros((ns, ns))
        tm_jac(t, y, ip, fp, Jk)
        Jc = np.zeros((ns, ns))
        kernel_central(t, y, ip, fp, Jc)
        assert np.array_equal(Jk, Jc)                       # the kernel's fallback branch
        calls.clear()
        Jp = sim._jac(mt, t, y)
        assert len(calls) == 2 * ns + 1                     # the reference's fallback branch
        f0 = f_kernel(t, y)
        assert _fd_error(Jk, _central(f_kernel, t, y, mt.n_dof), f0, y, mt) <= FD_TOL
        assert _fd_error(Jp, _central(fun, t, y, mt.n_dof), f0, y, mt) <= FD_TOL
        scale = np.maximum(np.max(np.abs(Jp), axis=0), 1.0)
        assert float(np.max(np.abs(Jk - Jp) / scale)) <= TWIN_TOL
