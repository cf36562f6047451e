"""Seeded random branching vehicle drivelines (nested differentials of every kind, springs,
joints, wheels, load transfer): the group solve (Lagrange) against a Newton-Euler backward
walk of every section, and the energy balance of a short run."""
from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from cvj_ros.physics.engine import engine_from_spec
from cvj_ros.physics.scene import Wheel, iter_elements, parse_scene
from cvj_ros.physics.tree import TreeDriveline

ENGINE = {'model': 'linear', 'm1': 150.0, 'k1': 0.3}


def _chain(rng: np.random.Generator, depth: int, counter: list[int], wheels: list[dict]) -> list[dict]:
    """A random chain ending in a wheel or (above depth 2) a differential with two chains."""
    out: list[dict] = []
    has_inertia = True       # a branch starts at a side gear (an inertia)

    def name(prefix: str) -> str:
        counter[0] += 1
        return f'{prefix}{counter[0]}'

    for _ in range(int(rng.integers(0, 4))):
        kind = rng.choice(['inertia', 'joint', 'spring'])
        if kind == 'spring' and has_inertia:
            out.append({'type': 'spring', 'name': name('s'), 'stiffness': float(rng.uniform(2e3, 2e4)),
                        'damping': float(rng.choice([0.0, rng.uniform(0.1, 5.0)]))})
            has_inertia = False
        elif kind == 'joint':
            jk = rng.choice(['gear', 'tripod', 'rzeppa', 'ideal_cv'])
            params = {'gear': {'gear_ratio': float(rng.uniform(0.5, 3.0))},
                      'tripod': {'beta_deg': float(rng.uniform(0, 12))},
                      'rzeppa': {'delta_deg': float(rng.uniform(0, 20))},
                      'ideal_cv': {}}[str(jk)]
            if jk == 'rzeppa':
                params['alpha_deg'] = params['delta_deg'] * float(rng.uniform(0.4, 0.6))
            out.append({'type': 'joint', 'name': name('j'), 'kind': str(jk), 'params': params})
        else:
            out.append({'type': 'inertia', 'name': name('i'), 'J': float(rng.uniform(0.002, 0.05))})
            has_inertia = True
    if depth < 2 and rng.random() < 0.6:
        kind = str(rng.choice(['open', 'locked', 'viscous']))
        d = {'type': 'differential', 'name': name('d'), 'kind': kind,
             'ratio': float(rng.uniform(0.8, 4.5)), 'J_carrier': float(rng.uniform(0.01, 0.06)),
             'J_side': float(rng.uniform(0.001, 0.005)), 'J_spider': float(rng.uniform(0.0, 0.002)),
             'spider_ratio': float(rng.uniform(1.2, 2.0)),
             'left': _chain(rng, depth + 1, counter, wheels),
             'right': _chain(rng, depth + 1, counter, wheels)}
        if kind == 'viscous':
            d['viscous'] = float(rng.uniform(1.0, 30.0))
        out.append(d)
    else:
        w = {'type': 'wheel', 'name': name('w'), 'J': float(rng.uniform(0.5, 1.5)), 'radius': 0.3,
             'mu': float(rng.uniform(0.1, 1.0)), 'load_share': 0.1,
             'tyre': {'B': float(rng.uniform(4, 12)), 'C': float(rng.uniform(1.4, 2.0)),
                      'E': float(rng.uniform(0.5, 1.0)), 'relaxation_length': float(rng.uniform(0.1, 0.4))}}
        wheels.append(w)
        out.append(w)
    return out


def random_scene(seed: int) -> dict[str, Any]:
    rng = np.random.default_rng(seed)
    wheels: list[dict] = []
    counter = [0]
    body = _chain(rng, 0 if rng.random() < 0.85 else 2, counter, wheels)
    for w in wheels:
        w['load_share'] = 0.9 / len(wheels)
    vehicle: dict[str, Any] = {'mass': float(rng.uniform(900, 2500)),
                               'initial_speed_m_s': float(rng.uniform(2, 20)),
                               'grade_percent': float(rng.uniform(-5, 5))}
    if rng.random() < 0.5 and len(wheels) > 1:
        for i, w in enumerate(wheels):
            w['axle'] = 'front' if i % 2 == 0 else 'rear'
        front = sum(w['load_share'] for w in wheels if w['axle'] == 'front')
        vehicle.update(cg_height=0.6, wheelbase=2.7, front_share=front + 0.05)
    return {'name': f'fuzz{seed}', 'duration': 1.0, 'engine': dict(ENGINE), 'vehicle': vehicle,
            'driveline': [{'type': 'inertia', 'name': 'crank', 'J': 0.2}] + body}


@pytest.mark.parametrize('seed', range(24))
def test_random_tree_newton_euler_and_energy(seed: int) -> None:
    sc = parse_scene(random_scene(seed))
    assert parse_scene(sc.to_dict()) == sc
    assert any(isinstance(el, Wheel) for el in iter_elements(sc.driveline))
    dl = TreeDriveline.from_scene(sc, track_energy=True)
    eng = engine_from_spec(ENGINE, field='engine')
    sol = solve_ivp(lambda t, x: dl.rhs_sources(t, x, eng), (0, 0.05), dl.x0, method='DOP853',
                    rtol=1e-10, atol=1e-10, t_eval=[0.0, 0.02, 0.05])
    assert sol.success
    e0 = sum(dl.energy(dl.x0).values())
    assert abs(dl.energy_residual(sol.y[:, -1], e0)) < 1e-8
    for x in sol.y.T:
        te = eng.torque(0, dl.engine_omega(x), dl.engine_phi(x))
        start = dl.section_start_torques(x, te)
        scale = max(1.0, abs(te))
        assert start[0] == pytest.approx(te, rel=1e-9, abs=1e-9 * scale)
        kin = dl._kinematics(x)
        fo = dl._forces(0.0, x, kin, None, te)
        acc = dl._accelerations(kin, fo)
        for (_law, _l, right), ts in zip(dl.springs, fo.spring_t):
            assert start[right] == pytest.approx(ts, rel=1e-8, abs=1e-8 * max(1.0, abs(ts)))
        for d, tb in zip(dl.diffs, fo.bias_t):
            if d.coord < 0:
                continue
            # spiders: T_spider_L - T_spider_R = -P delta_ddot; the walk's start torques
            # also carry the coupling's -T_b (left) and +T_b (right)
            expect = -d.model.spider_inertia * acc[d.coord] - 2.0 * tb
            big = max(1.0, abs(start[d.left]), abs(start[d.right]))
            assert start[d.left] - start[d.right] == pytest.approx(expect, abs=1e-9 * big)


def test_fuzz_covers_the_cases() -> None:
    """The seeds above hold nested differentials of each kind, multi-coordinate groups and
    load transfer (so the checks are not vacuous)."""
    kinds, max_group, transfer = set(), 0, 0
    for seed in range(24):
        sc = parse_scene(random_scene(seed))
        dl = TreeDriveline(sc, {})
        kinds |= {d.model.kind for d in dl.diffs}
        max_group = max(max_group, max(len(c) for c, _s in dl._groups))
        transfer += sc.vehicle.cg_height is not None
    assert kinds == {'open', 'locked', 'viscous'}
    assert max_group >= 3 and transfer >= 3
