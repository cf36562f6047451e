"""The Rosenbrock steppers keep the Jacobian's coupled block of a model whose block does not
depend on (t, y) (layout.jacobian_block_constant, ip[H_JAC_CONST]) and refresh only the work
integrals' rows (rhs_nb.jac_energy_rows): the flag's conditions, the refreshed J against
rhs_nb.jac bit for bit, and whole runs with and without the kept block bit for bit."""
from __future__ import annotations

import math

import numpy as np
import pytest

from cvj_ros.physics.driveline import Driveline
from cvj_ros.physics.engine import engine_from_spec
from cvj_ros.physics.kernel import layout
from cvj_ros.physics.kernel.layout import H_JAC_CONST, build_model, jacobian_block_constant
from cvj_ros.physics.kernel.rhs_nb import jac, jac_energy_rows, rhs
from cvj_ros.physics.load import load_from_spec
from cvj_ros.physics.scene import parse_scene

LINEAR = {'model': 'linear', 'm1': 200.0, 'k1': 1.5}
CONSTANT = {'model': 'constant', 'torque': 40.0}
HOOKE = {'type': 'joint', 'name': 'h1', 'kind': 'hooke', 'fidelity': 'exact',
         'params': {'beta_deg': 25.0}}
A = {'type': 'inertia', 'name': 'a', 'J': 0.3}
B = {'type': 'inertia', 'name': 'b', 'J': 0.05}
C = {'type': 'inertia', 'name': 'c', 'J': 0.4}
SPRING = {'type': 'spring', 'name': 's', 'stiffness': 3000.0, 'damping': 2.0}
SPRING2 = {'type': 'spring', 'name': 's2', 'stiffness': 1.0e6, 'damping': 0.0}
GEAR = {'type': 'joint', 'name': 'g', 'kind': 'gear', 'params': {'gear_ratio': -2.5}}

#: label: (driveline, engine spec (None: the input block), load spec, flag expected)
MODELS = {
    'linear_two_springs': ([A, SPRING, B, SPRING2, C], LINEAR, CONSTANT, True),
    'gear_and_ideal_cv_in_prefix': (
        [A, SPRING, B, GEAR, {'type': 'joint', 'name': 'cv', 'kind': 'ideal_cv'}, C],
        LINEAR, CONSTANT, True),
    'hooke_ideal': ([A, dict(HOOKE, fidelity='ideal'), B, SPRING, C], LINEAR, CONSTANT, True),
    'lash_spring': ([A, dict(SPRING, backlash_deg=2.0), C], LINEAR, CONSTANT, False),
    'cubic_spring': ([A, dict(SPRING, law='progressive', k2=30.0), C], LINEAR, CONSTANT,
                     False),
    'map_engine': ([A, SPRING, C], {'model': 'map'}, CONSTANT, False),
    'hooke_exact': ([A, HOOKE, B, SPRING, C], LINEAR, CONSTANT, False),
    'road_load': ([A, SPRING, C], LINEAR,
                  {'model': 'road', 'mass': 1300.0, 'wheel_radius': 0.3,
                   'grade_percent': 4.0, 'speed_scale': 2.0}, False),
    'constant_load_with_sign': ([A, SPRING, C], LINEAR, dict(CONSTANT, speed_scale=5.0),
                                False),
    'input_block_engine': ([A, SPRING, C], None, CONSTANT, False),
}


def _scene(driveline, engine, load):
    return parse_scene({
        'name': 'jac_keep', 'seed': 3, 'duration': 1.0, 'exchange_step': 0.001,
        'engine': engine or LINEAR, 'load': load, 'initial': {'speed_rad_s': 60.0},
        'driveline': driveline})


def _model(label, energy=True):
    driveline, engine, load, _flag = MODELS[label]
    sc = _scene(driveline, engine, load)
    dl = Driveline.from_scene(sc, track_energy=energy)
    return dl, build_model(dl, engine=None if engine is None else engine_from_spec(engine),
                           load=load_from_spec(load, seed=sc.seed), horizon=1.0)


@pytest.mark.parametrize('label', sorted(MODELS))
def test_flag_only_where_the_coupled_block_is_constant(label):
    """Set for chains of inertias, identity joints, gears and linear springs with the linear
    engine and a constant load; not for a lash or progressive spring, a map engine, an exact
    Hooke joint, a road load, a load with a speed sign, or torques from the input block."""
    _dl, model = _model(label)
    assert bool(model.ip[H_JAC_CONST]) is MODELS[label][3]
    assert jacobian_block_constant(model.ip, model.fp) is MODELS[label][3]


def _states(dl, rng):
    """Start state, zeros of either sign, and random states with speeds of both signs up to
    1e3 rad/s and twists up to 1e2 rad (f finite at all of them)."""
    n = dl.n_dof
    x0 = np.array(dl.x0, dtype=float)
    out = [x0, np.zeros_like(x0), -np.zeros_like(x0)]
    for scale in (1e-3, 1.0, 1e2):
        for _ in range(12):
            x = x0.copy()
            x[:n] += rng.uniform(-scale, scale, n)
            x[n:2 * n] = rng.uniform(-10 * scale, 10 * scale, n)
            x[2 * n:] = rng.uniform(-5.0, 5.0, x.size - 2 * n)
            out.append(x)
    return out


@pytest.mark.parametrize('label', [k for k, v in MODELS.items() if v[3]])
def test_kept_block_plus_energy_rows_is_jac_bit_for_bit(label):
    """J evaluated at one state, then only jac_energy_rows at another: the bytes of jac there
    (signed zeros included), for every pair of the states, at t = 0 and t = 0.7 s."""
    dl, model = _model(label)
    ip, fp = model.ip, model.fp
    states = _states(dl, np.random.default_rng(7))
    ns = states[0].size
    assert ns == 2 * dl.n_dof + 3
    ref = np.zeros((ns, ns))
    dy = np.zeros(ns)
    for t in (0.0, 0.7):
        for k, y in enumerate(states):
            rhs(t, y, ip, fp, dy)
            assert np.isfinite(dy).all()
            jac(t, y, ip, fp, ref)
            kept = np.full((ns, ns), np.nan)
            jac(t, states[(k + 5) % len(states)], ip, fp, kept)
            jac_energy_rows(t, y, ip, fp, kept)
            assert kept.tobytes() == ref.tobytes(), (label, t, k)


def test_the_flag_matters_the_block_varies_without_it():
    """The check above has teeth: for a lash spring the coupled block differs between two
    states, so keeping it would change results."""
    dl, model = _model('lash_spring')
    states = _states(dl, np.random.default_rng(7))
    ns = states[0].size
    m = 2 * dl.n_dof
    J1, J2 = np.zeros((ns, ns)), np.zeros((ns, ns))
    jac(0.0, states[3], model.ip, model.fp, J1)
    jac(0.0, states[-1], model.ip, model.fp, J2)
    assert J1[:m, :m].tobytes() != J2[:m, :m].tobytes()


def test_energy_rows_leave_the_other_rows_and_do_nothing_without_work_integrals():
    """jac_energy_rows writes rows 2n..2n+2 only; a model without work integrals has none."""
    dl, model = _model('linear_two_springs')
    ns = 2 * dl.n_dof + 3
    J = np.full((ns, ns), 7.0)
    jac_energy_rows(0.0, np.array(dl.x0, dtype=float), model.ip, model.fp, J)
    assert (J[:2 * dl.n_dof] == 7.0).all() and not (J[2 * dl.n_dof:] == 7.0).all()
    dl2, m2 = _model('linear_two_springs', energy=False)
    assert m2.ip[H_JAC_CONST] == 1 and not m2.track_energy
    J2 = np.full((2 * dl2.n_dof,) * 2, 7.0)
    jac_energy_rows(0.0, np.array(dl2.x0, dtype=float), m2.ip, m2.fp, J2)
    assert (J2 == 7.0).all()


def _trace_bytes(tr, final):
    return b''.join(np.ascontiguousarray(getattr(tr, f)).tobytes() for f in (
        't', 'position', 'velocity', 'effort', 'engine_torque', 'load_torque',
        'energy_residual')) + np.ascontiguousarray(final).tobytes()


def _runs(scene, monkeypatch, keep, **kw):
    from cvj_ros.physics.simulate import Simulation
    with monkeypatch.context() as mp:
        if not keep:
            mp.setattr(layout, 'jacobian_block_constant', lambda ip, fp: False)
        out = []
        for method, tol, sampling in (('rodas3', 1e-3, 'dense'), ('rodas3', 1e-6, 'land'),
                                      ('rosenbrock', 1e-6, 'dense'), ('rodas4', 1e-4, 'land')):
            sim = Simulation(scene, method=method, rtol=tol, atol=tol, **kw)
            tr = sim.run(0.5, sample_dt=0.01, sampling=sampling)
            assert int(sim.model.ip[H_JAC_CONST]) == int(keep)
            out.append((_trace_bytes(tr, sim.final_state),
                        {k: tr.solver[k] for k in ('nfev', 'njev', 'nlu', 'naccept',
                                                   'nreject', 't', 'h')}))
        return out


@pytest.mark.parametrize('which', ['stiff', 'gear_and_ideal_cv_in_prefix'])
def test_runs_with_the_kept_block_are_the_runs_without_it(which, monkeypatch):
    """Simulation.run (the compiled run: run_nb) with the kept block and with the flag forced
    off (every step a whole jac): the same trace, final state and counters, bit for bit (njev
    counts the refreshes), for rodas3, RODAS5P and rodas4, land and dense."""
    from cvj_ros import bench
    if which == 'stiff':
        scene = bench.resolve_scene('stiff')
    else:
        driveline, engine, load, _ = MODELS[which]
        scene = _scene(driveline, engine, load)
    assert _runs(scene, monkeypatch, True) == _runs(scene, monkeypatch, False)


def test_stepper_keeps_the_block_and_restart_drops_it():
    """KernelStepper (ros2 and rodas3, advance_to per exchange step): C_JKEPT is set after
    the first Jacobian of a flagged model, the states equal those of a stepper on the same
    model with the flag cleared bit for bit, and restart() clears it."""
    from cvj_ros.physics.kernel import steppers_nb as nb
    from cvj_ros.physics.kernel.stepper import KernelStepper
    dl, model = _model('linear_two_springs')
    ip_off = model.ip.copy()
    ip_off[H_JAC_CONST] = 0
    x0 = np.array(dl.x0, dtype=float)
    for method, h in (('rodas3', None), ('ros2', 2e-4)):
        st = [KernelStepper(method, rhs, ip, model.fp, 0.0, x0, rtol=1e-5, atol=1e-7, h=h,
                            jac=jac) for ip in (model.ip, ip_off)]
        for k in range(1, 21):
            ys = [s.advance_to(0.001 * k) for s in st]
            assert ys[0].tobytes() == ys[1].tobytes(), (method, k)
        assert st[0]._cnt[nb.C_JKEPT] == 1 and st[1]._cnt[nb.C_JKEPT] == 0
        assert st[0].njev == st[1].njev > 1
        st[0].restart()
        assert st[0]._cnt[nb.C_JKEPT] == 0
        assert math.isfinite(st[0].advance_to(0.03)[0])
