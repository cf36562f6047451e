"""Branching vehicle driveline (cvj_ros.physics.tree): differential relations in closed form,
independent constructions (a symmetric or locked axle equals one equivalent chain), the
Lagrange solve against a Newton-Euler backward walk, energy balance with every dissipation,
split-mu spin-up, start from rest, a lifted wheel's status."""
from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from cvj_ros.physics.engine import engine_from_spec
from cvj_ros.physics.scene import parse_scene
from cvj_ros.physics.simulate import Simulation
from cvj_ros.physics.tree import TreeDriveline
from cvj_ros.physics.tyre import TYRE_NO_LOAD

ENGINE = {'model': 'linear', 'm1': 200.0, 'k1': 0.5}


def wheel(name: str, mu: float = 0.9, **kw: Any) -> dict[str, Any]:
    return {'type': 'wheel', 'name': name, 'J': 1.0, 'radius': 0.3, 'mu': mu, 'load_share': 0.3, **kw}


def axle_scene(*, kind: str = 'open', mu_l: float = 0.9, mu_r: float = 0.9, j_spider: float = 0.001,
               left: list[dict] | None = None, right: list[dict] | None = None,
               vehicle: dict | None = None, **diff: Any) -> dict[str, Any]:
    d = {'type': 'differential', 'name': 'diff', 'kind': kind, 'ratio': 4.0, 'J_carrier': 0.02,
         'J_side': 0.005, 'J_spider': j_spider, 'spider_ratio': 1.6,
         'left': left if left is not None else [wheel('wheel_left', mu_l)],
         'right': right if right is not None else [wheel('wheel_right', mu_r)], **diff}
    return {'name': 'axle', 'duration': 1.0, 'engine': dict(ENGINE),
            'vehicle': vehicle or {'mass': 1500, 'initial_speed_kmh': 20},
            'driveline': [{'type': 'inertia', 'name': 'crank', 'J': 0.2},
                          {'type': 'joint', 'name': 'gearbox', 'kind': 'gear',
                           'params': {'gear_ratio': 3.5}}, d]}


def halfshafts(side: str, stiffness: float = 8000.0, beta: float = 6.0, mu: float = 0.9) -> list[dict]:
    return [{'type': 'spring', 'name': f'hs_{side}', 'stiffness': stiffness, 'damping': 2.0},
            {'type': 'joint', 'name': f'tri_{side}', 'kind': 'tripod', 'params': {'beta_deg': beta}},
            {'type': 'joint', 'name': f'rz_{side}', 'kind': 'rzeppa', 'params': {'delta_deg': 2 * beta}},
            wheel(f'wheel_{side}', mu)]


def integrate(dl: TreeDriveline, t_end: float, n: int = 11, rtol: float = 1e-10) -> Any:
    eng = engine_from_spec(dl.scene.engine, field='engine')
    return solve_ivp(lambda t, x: dl.rhs_sources(t, x, eng), (0, t_end), dl.x0, method='DOP853',
                     rtol=rtol, atol=1e-10, t_eval=np.linspace(0, t_end, n)), eng


def test_differential_speed_relations_along_a_run() -> None:
    sc = parse_scene(axle_scene(left=halfshafts('left', mu=0.1), right=halfshafts('right', 9000, 3)))
    tr = Simulation(sc, backend='python').run(0.5, sample_dt=0.05)
    col = {n: i for i, n in enumerate(tr.names)}
    w = tr.velocity
    wl, wr, wc, win = (w[:, col['diff_left']], w[:, col['diff_right']], w[:, col['diff_carrier']],
                       w[:, col['diff_input']])
    assert wc == pytest.approx(0.5 * (wl + wr), rel=1e-12, abs=1e-12)
    assert win == pytest.approx(4.0 * wc, rel=1e-12)
    assert np.max(np.abs(wl - wr)) > 1.0       # the branches do differ (split mu)


@pytest.mark.parametrize('j_spider', [0.0, 0.004])
def test_open_differential_torques_newton_euler_against_lagrange(j_spider: float) -> None:
    """The generalised accelerations (Lagrange, group solve) fed to a backward Newton-Euler
    walk of every section must give: the engine torque at the crank, each spring's torque at
    its right section, and side-gear torques T_L - T_R = -P delta_ddot (equal without spider
    inertia: the open differential passes equal torque)."""
    sc = parse_scene(axle_scene(j_spider=j_spider, left=halfshafts('left', mu=0.1),
                                right=halfshafts('right', 9000, 3)))
    dl = TreeDriveline.from_scene(sc)
    sol, eng = integrate(dl, 0.4, n=5)
    for x in sol.y.T:
        te = eng.torque(0, dl.engine_omega(x), dl.engine_phi(x))
        start = dl.section_start_torques(x, te)
        assert start[0] == pytest.approx(te, rel=1e-11)
        kin = dl._kinematics(x)
        fo = dl._forces(0.0, x, kin, None, te)
        for (law, _l, right), ts in zip(dl.springs, fo.spring_t):
            assert start[right] == pytest.approx(ts, rel=1e-10, abs=1e-9)
        d = dl.diffs[0]
        acc = dl._accelerations(kin, fo)
        p = d.model.spider_inertia
        assert start[d.left] - start[d.right] == pytest.approx(-p * acc[d.coord], abs=1e-9)
        if j_spider == 0.0:
            assert start[d.left] == pytest.approx(start[d.right], rel=1e-12)


def _equivalent_chain(mu: float) -> dict[str, Any]:
    """One wheel carrying both wheels' inertia and load share behind a rigid final drive:
    what a locked (or symmetric open) axle must reduce to."""
    return {'name': 'equiv', 'duration': 1.0, 'engine': dict(ENGINE),
            'vehicle': {'mass': 1500, 'initial_speed_kmh': 20},
            'driveline': [{'type': 'inertia', 'name': 'crank', 'J': 0.2},
                          {'type': 'joint', 'name': 'gearbox', 'kind': 'gear', 'params': {'gear_ratio': 3.5}},
                          {'type': 'joint', 'name': 'final', 'kind': 'gear', 'params': {'gear_ratio': 4.0}},
                          {'type': 'inertia', 'name': 'carrier', 'J': 0.02 + 2 * 0.005},
                          {'type': 'wheel', 'name': 'both', 'J': 2.0, 'radius': 0.3, 'mu': mu,
                           'load_share': 0.6}]}


@pytest.mark.parametrize('kind', ['locked', 'open', 'viscous'])
def test_symmetric_axle_equals_one_equivalent_wheel(kind: str) -> None:
    """Independent construction: equal wheels on equal road make delta stay 0 (open, viscous)
    or do not have it (locked); the axle then is one rigid body with the carrier, both side
    gears and both wheels, i.e. the single-wheel chain with J, share summed."""
    extra = {'viscous': 5.0} if kind == 'viscous' else {}
    tree = TreeDriveline.from_scene(parse_scene(axle_scene(kind=kind, **extra)))
    chain = TreeDriveline.from_scene(parse_scene(_equivalent_chain(0.9)))
    st, _ = integrate(tree, 0.6, n=7)
    sc_, _ = integrate(chain, 0.6, n=7)
    n_t, n_c = tree.n_dof, chain.n_dof
    crank_t = st.y[n_t]                      # crank speed
    crank_c = sc_.y[n_c]
    assert crank_t == pytest.approx(crank_c, rel=1e-8)
    assert st.y[tree._iv] == pytest.approx(sc_.y[chain._iv], rel=1e-8)
    if kind != 'locked':
        assert np.max(np.abs(st.y[n_t + 1])) < 1e-9       # delta rate stays 0 by symmetry


def test_energy_balance_with_every_dissipation() -> None:
    """Springs with damping, a viscous coupling, tyre slip on split mu, rolling, drag, a grade:
    E_kin + E_el - E0 - W_engine + W_damp + W_slip + W_road stays at solver tolerance."""
    veh = {'mass': 1500, 'initial_speed_kmh': 20, 'grade_percent': 4, 'cg_height': 0.55,
           'wheelbase': 2.6, 'front_share': 0.62}
    left, right = halfshafts('left', mu=0.2), halfshafts('right', 9000, 3)
    left[-1]['axle'] = right[-1]['axle'] = 'front'
    sc = parse_scene(axle_scene(kind='viscous', viscous=3.0, left=left, right=right,
                                vehicle=veh))
    dl = TreeDriveline.from_scene(sc, track_energy=True)
    sol, _ = integrate(dl, 1.0, n=11, rtol=1e-11)
    e0 = sum(dl.energy(dl.x0).values())
    res = [abs(dl.energy_residual(x, e0)) for x in sol.y.T]
    assert max(res) < 1e-9
    we, wd, ws, wr = sol.y[dl._iv + 1:, -1]
    assert we > 0 and wd > 0 and ws > 0 and wr > 0    # every term is exercised


def test_split_mu_low_mu_wheel_spins_open_passes_equal_torque() -> None:
    sc = parse_scene(axle_scene(mu_l=0.1, mu_r=0.9, j_spider=0.0))
    sim = Simulation(sc, backend='python')
    tr = sim.run(1.0, sample_dt=0.01)
    col = {n: i for i, n in enumerate(tr.names)}
    wl, wr = tr.velocity[:, col['wheel_left']], tr.velocity[:, col['wheel_right']]
    assert wl[-1] > 1.4 * wr[-1]
    # the ice wheel's force is capped by mu F_z; the open differential gives the other
    # wheel the same side torque, so both forces are about the ice wheel's
    fz = tr.channels['wheel_left.fz'][-1]
    assert tr.channels['wheel_left.fx'][-1] <= 0.1 * fz * (1 + 1e-12)
    # torque the gears pass to the side gears (the side sections' start torques)
    dl = sim.driveline
    x = sim.final_state
    start = dl.section_start_torques(x, sim.torques(1.0, x)[0])
    d = dl.diffs[0]
    assert start[d.left] == pytest.approx(start[d.right], rel=1e-12)
    assert start[d.left] > 50.0
    # locked: both wheels turn together and the car gains more speed
    locked = Simulation(parse_scene(axle_scene(kind='locked', mu_l=0.1, mu_r=0.9)),
                        backend='python').run(1.0, sample_dt=0.01)
    cl = {n: i for i, n in enumerate(locked.names)}
    assert locked.velocity[:, cl['wheel_left']] == pytest.approx(locked.velocity[:, cl['wheel_right']],
                                                                 rel=1e-12)
    assert locked.channels['vehicle_speed'][-1] > tr.channels['vehicle_speed'][-1]


def test_viscous_coupling_reduces_the_spin() -> None:
    runs = {}
    for kind, extra in (('open', {}), ('viscous', {'viscous': 20.0})):
        sc = parse_scene(axle_scene(kind=kind, mu_l=0.1, **extra))
        tr = Simulation(sc, backend='python').run(1.0, sample_dt=0.05)
        col = {n: i for i, n in enumerate(tr.names)}
        runs[kind] = tr.velocity[-1, col['wheel_left']] - tr.velocity[-1, col['wheel_right']]
    assert 0 < runs['viscous'] < 0.8 * runs['open']


def test_start_from_rest_without_blow_up() -> None:
    """v = 0, engine at rest: the slip ratio is singular there; the relaxed slip is not."""
    raw = axle_scene(vehicle={'mass': 1500, 'initial_speed_kmh': 0}, left=halfshafts('left'),
                     right=halfshafts('right', 9000, 3))
    tr = Simulation(parse_scene(raw), backend='python').run(1.0, sample_dt=0.01)
    v = tr.channels['vehicle_speed']
    assert v[0] == 0.0 and np.all(np.isfinite(tr.velocity))
    assert 0.5 < v[-1] < 20.0
    assert np.all(np.diff(v[5:]) > 0)           # accelerating once the tyres have built force
    assert np.max(np.abs(tr.channels['wheel_left.slip'])) < 1.0
    assert tr.max_energy_residual < 1e-5


def test_lifted_wheel_has_no_load_status_not_nan() -> None:
    """A 4x4 with a CG as high as the wheelbase, front wheels on high grip: hard acceleration
    unloads the front axle completely; its tyres report NO_LOAD with F_x = 0."""
    veh = {'mass': 1500, 'initial_speed_kmh': 10, 'cg_height': 2.6, 'wheelbase': 2.6,
           'front_share': 0.5}
    fl, fr = wheel('front_left', axle='front'), wheel('front_right', axle='front')
    rl, rr = wheel('rear_left', axle='rear', load_share=0.2), wheel('rear_right', axle='rear', load_share=0.2)
    fl['load_share'] = fr['load_share'] = 0.25
    rl['load_share'] = rr['load_share'] = 0.25
    axle = {'type': 'differential', 'name': 'front_diff', 'kind': 'open', 'ratio': 1.0,
            'J_carrier': 0.01, 'J_side': 0.005, 'left': [fl], 'right': [fr]}
    rear = dict(axle, name='rear_diff', left=[rl], right=[rr])
    raw = axle_scene(left=[axle], right=[rear], vehicle=veh)
    dl = TreeDriveline.from_scene(parse_scene(raw))
    x = dl.x0.copy()
    n = dl.n_dof
    names = [w.name for w in dl.wheels]
    x[2 * n + names.index('rear_left')] = x[2 * n + names.index('rear_right')] = 0.18  # peak grip
    out = dl.wheel_outputs(x)
    assert out['front_left']['status'] == out['front_right']['status'] == TYRE_NO_LOAD
    assert out['front_left']['fx'] == 0.0 and out['front_left']['fz'] == 0.0
    assert np.all(np.isfinite(dl.rhs_sources(0.0, x, engine_from_spec(ENGINE, field='engine'))))
    assert out['rear_left']['fz'] + out['rear_right']['fz'] == pytest.approx(dl.body.weight_normal)


def test_energy_matches_members_kinetic_energy() -> None:
    """TreeDriveline.energy against cvj_ros.physics.differential's member-by-member sum."""
    from cvj_ros.physics.differential import Differential
    sc = parse_scene(axle_scene(mu_l=0.1))
    dl = TreeDriveline.from_scene(sc)
    x = dl.x0.copy()
    n = dl.n_dof
    x[n + 1] = 7.0                               # delta rate
    wl, wr = x[n] / 3.5 / 4.0 + 7.0, x[n] / 3.5 / 4.0 - 7.0
    d = Differential(ratio=4.0, J_carrier=0.02, J_spider=0.001, spider_ratio=1.6)
    ke_diff = d.kinetic_energy(wl, wr, 0.005 + 1.0, 0.005 + 1.0)   # side gear + wheel each
    v = x[dl._iv]
    expect = 0.5 * 0.2 * x[n] ** 2 + ke_diff + 0.5 * 1500 * v * v
    assert dl.energy(x)['kinetic'] == pytest.approx(expect, rel=1e-13)


def test_sample_outputs_equal_the_separate_methods() -> None:
    """One kinematics and force pass per sample gives the numbers of engine.torque,
    tyre_torque, joint_states_fast, energy_residual and wheel_outputs, bit for bit (the
    kernel and the reference runs both record through it)."""
    from cvj_ros.physics.scene import load_scene, shipped_scenes
    sc = load_scene(shipped_scenes()['fwd_axle_split_mu'])
    dl = TreeDriveline.from_scene(sc, track_energy=True)
    eng = engine_from_spec(sc.engine, field='engine')
    rng = np.random.default_rng(3)
    x = dl.x0.copy()
    m = 2 * dl.n_dof + dl.n_wheel + 1
    x[:m] += rng.normal(0.0, 0.3, m)
    x[m:] = rng.normal(0.0, 50.0, x.size - m)     # work integrals
    e0 = 123.0
    te, tl, pos, vel, eff, res, wheels = dl.sample_outputs(0.2, x, eng.torque, e0)
    assert te == eng.torque(0.2, dl.engine_omega(x), dl.engine_phi(x))
    assert tl == dl.tyre_torque(x)
    for got, ref in zip((pos, vel, eff), dl.joint_states_fast(x, te)):
        assert np.array_equal(got, ref)
    assert res == dl.energy_residual(x, e0)
    ref_w = dl.wheel_outputs(x)
    assert wheels == [(o['slip'], o['fx'], o['fz'], o['status']) for o in ref_w.values()]
