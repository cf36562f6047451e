"""Driveline equations: Lagrange vs closed forms, finite-difference Jacobian, shaft torques."""
from __future__ import annotations

import math

import numpy as np
import pytest

from cvj_ros.errors import SceneError
from cvj_ros.physics.driveline import Driveline, SpringLaw
from cvj_ros.physics.joints.hooke import hooke_ratio
from cvj_ros.physics.scene import parse_scene


def scene(chain: list[dict], *, speed: float = 10.0, **extra: object) -> object:
    d = {'name': 't', 'duration': 1.0, 'engine': {'model': 'linear'},
         'load': {'model': 'constant', 'torque': 10.0}, 'initial': {'speed_rad_s': speed},
         'driveline': chain}
    d.update(extra)
    return parse_scene(d)


def inertia(name: str, J: float) -> dict:
    return {'type': 'inertia', 'name': name, 'J': J}


def spring(name: str, c: float, d: float = 0.0, **kw: object) -> dict:
    return {'type': 'spring', 'name': name, 'stiffness': c, 'damping': d, **kw}


def joint(name: str, kind: str, **params: float) -> dict:
    return {'type': 'joint', 'name': name, 'kind': kind, 'params': params}


MIXED = [inertia('crank', 0.2), joint('box', 'gear', gear_ratio=3.0), inertia('shaft', 0.01),
         spring('mid', 800.0, 2.0, law='progressive', k2=5.0, backlash_deg=2.0),
         joint('h1', 'hooke', beta_deg=25.0), inertia('yoke', 0.02),
         joint('h2', 'hooke', beta_deg=30.0, phase_deg=0.0),
         spring('tyre', 300.0, 1.5), inertia('wheel', 0.9)]


def fd_jacobian(dl: Driveline, x: np.ndarray, te: float, tl: float) -> np.ndarray:
    n = x.size
    jac = np.zeros((n, n))
    for i in range(n):
        h = 1e-6 * max(1.0, abs(x[i]))
        xp, xm = x.copy(), x.copy()
        xp[i] += h
        xm[i] -= h
        jac[:, i] = (dl.rhs(0.0, xp, te, tl) - dl.rhs(0.0, xm, te, tl)) / (2 * h)
    return jac


def test_sections_and_names() -> None:
    dl = Driveline.from_scene(scene(MIXED))
    assert dl.n_dof == 3
    assert dl.state_names == ['crank.angle', 'h1_input.angle', 'wheel.angle',
                              'crank.speed', 'h1_input.speed', 'wheel.speed']
    assert dl.shaft_names == ['crank', 'box_input', 'box_output', 'shaft', 'h1_input', 'h1_output',
                              'yoke', 'h2_input', 'h2_output', 'wheel']


@pytest.mark.parametrize('track', [False, True])
def test_jacobian_matches_finite_differences(track: bool) -> None:
    dl = Driveline.from_scene(scene(MIXED), track_energy=track)
    rng = np.random.default_rng(1)
    for _ in range(5):
        x = dl.x0.copy()
        x[:3] += rng.uniform(-0.05, 0.05, 3) + rng.uniform(0, 6, 1)
        x[3:6] += rng.uniform(-3, 3, 3)
        jac = dl.jacobian(0.0, x, 120.0, 40.0)
        ref = fd_jacobian(dl, x, 120.0, 40.0)
        scale = np.maximum(1.0, np.abs(ref))
        assert np.max(np.abs(jac - ref) / scale) < 1e-5


def test_jacobian_includes_torque_slopes() -> None:
    dl = Driveline.from_scene(scene(MIXED))
    x = dl.x0.copy()
    x[1] += 0.3
    base = dl.jacobian(0.0, x, 100.0, 30.0)
    with_slopes = dl.jacobian(0.0, x, 100.0, 30.0, dTe_domega=-13.0, dTl_domega=2.0)
    m0 = dl.mass(x)[0]
    assert with_slopes[3, 3] - base[3, 3] == pytest.approx(-13.0 / m0)
    assert with_slopes[5, 5] < base[5, 5]


def test_rigid_hooke_generalised_inertia_closed_form() -> None:
    beta = math.radians(35.0)
    dl = Driveline.from_scene(scene([inertia('a', 0.3), joint('h', 'hooke', beta_deg=35.0),
                                     inertia('b', 0.7)]))
    q = np.linspace(0.0, 2 * math.pi, 13)
    r = hooke_ratio(q, beta)
    for qi, ri in zip(q, r):
        x = np.array([qi, 5.0])
        assert dl.mass(x)[0] == pytest.approx(0.3 + 0.7 * ri ** 2, rel=1e-12)
        # free motion conserves M(q) qdot^2 / 2: d/dt(E) = qdot (M qddot + M'/2 qdot^2) = 0
        acc = dl.rhs(0.0, x, 0.0, 0.0)[1]
        h = 1e-6
        dm = (dl.mass(np.array([qi + h, 5.0]))[0] - dl.mass(np.array([qi - h, 5.0]))[0]) / (2 * h)
        assert dl.mass(x)[0] * acc + 0.5 * dm * 25.0 == pytest.approx(0.0, abs=1e-6)


def test_spring_twist_is_bounded_over_many_revolutions() -> None:
    dl = Driveline.from_scene(scene([inertia('a', 0.3), joint('h', 'hooke', beta_deg=30.0),
                                     spring('s', 500.0), inertia('b', 0.7)]))
    for revs in (0, 10, 1000, 100000):
        q = 2 * math.pi * revs + 0.4
        phi_out = dl._section(0, q)[0]
        x = np.array([q, phi_out, 0.0, 0.0])
        assert dl.spring_twists(x)['s'][0] == pytest.approx(0.0, abs=1e-7)
        assert dl.energy(x)['elastic'] == pytest.approx(0.0, abs=1e-9)


def test_shaft_torques_close_on_the_load() -> None:
    """Effort walk: joint output = input / ratio, last inertia carries the load torque."""
    dl = Driveline.from_scene(scene(MIXED))
    x = dl.x0.copy()
    x[:3] += [0.3, 0.1, -0.05]
    x[3:6] += [1.0, -2.0, 0.5]
    names, pos, vel, eff = dl.joint_states(x, 150.0, 42.0)
    i = names.index
    assert eff[i('wheel')] == pytest.approx(42.0, rel=1e-10)
    assert eff[i('box_output')] == pytest.approx(eff[i('box_input')] * 3.0)
    # h1 input carries the spring torque
    assert eff[i('h1_input')] == pytest.approx(dl.spring_twists(x)['mid'][2])
    r = hooke_ratio(pos[i('h1_input')], math.radians(25.0))
    assert vel[i('h1_output')] == pytest.approx(r * vel[i('h1_input')])
    assert vel[i('box_output')] == pytest.approx(vel[i('crank')] / 3.0)


def test_backlash_dead_zone_regularised() -> None:
    law = SpringLaw('s', 1000.0, 0.0, 0.0, math.radians(1.0), 0.1 * math.radians(1.0))
    g = math.radians(1.0)
    assert abs(law.evaluate(0.5 * g, 0.0)[0]) < 1e-3 * 1000.0 * g
    assert law.evaluate(5 * g, 0.0)[0] == pytest.approx(1000.0 * 4 * g, rel=1e-6)
    assert law.evaluate(-5 * g, 0.0)[0] == pytest.approx(-1000.0 * 4 * g, rel=1e-6)
    # torque is dV/dtheta
    h = 1e-7
    for th in (-1.3 * g, -g, 0.2 * g, g, 1.1 * g):
        dv = (law.evaluate(th + h, 0.0)[3] - law.evaluate(th - h, 0.0)[3]) / (2 * h)
        assert law.evaluate(th, 0.0)[0] == pytest.approx(dv, rel=1e-6, abs=1e-9)


def test_progressive_law_torque_is_potential_gradient() -> None:
    law = SpringLaw('s', 700.0, 0.0, 3.0, 0.0, 0.0)
    for th in (-0.4, 0.1, 0.3):
        assert law.evaluate(th, 0.0)[0] == pytest.approx(700.0 * th * (1 + 3.0 * th * th))
        assert law.evaluate(th, 0.0)[3] == pytest.approx(700.0 * (th * th / 2 + 3.0 * th ** 4 / 4))


def test_rigid_spring_merges_sections() -> None:
    dl = Driveline.from_scene(scene(MIXED), fidelity={'mid': 'rigid'})
    assert dl.n_dof == 2
    with pytest.raises(SceneError, match='^fidelity.mdi: no joint or spring'):
        Driveline.from_scene(scene(MIXED), fidelity={'mdi': 'rigid'})
    with pytest.raises(SceneError, match='^fidelity.h1: must be one of'):
        Driveline.from_scene(scene(MIXED), fidelity={'h1': 'closed'})


def test_rhs_sources_equals_rhs_with_evaluated_torques() -> None:
    class Src:
        def __init__(self, k: float) -> None:
            self.k = k

        def torque(self, t: float, omega: float, phi: float = 0.0) -> float:
            return self.k * (1.0 + 0.1 * omega + 0.01 * math.sin(phi) + t)

    dl = Driveline.from_scene(scene(MIXED), track_energy=True)
    x = dl.x0.copy()
    x[:3] += [0.7, 0.1, -0.2]
    x[3:6] += [1.0, -2.0, 0.5]
    eng, load = Src(50.0), Src(7.0)
    phi_l, w_l = dl.load_state(x)
    expected = dl.rhs(0.3, x, eng.torque(0.3, x[3], x[0]), load.torque(0.3, w_l, phi_l))
    assert np.array_equal(dl.rhs_sources(0.3, x, eng, load), expected)


@pytest.mark.parametrize('track', [False, True])
def test_generated_rhs_matches_reference_loop(track: bool) -> None:
    """The straight-line generated rhs and the readable loop (_rhs) agree to rounding."""
    from cvj_ros.physics.scene import load_scene, shipped_scenes
    scenes = [scene(MIXED)] + [sc for sc in map(load_scene, shipped_scenes().values())
                               if not (sc.is_tree or sc.has_modes)]   # modes: physics/hybrid
    rng = np.random.default_rng(7)
    for sc in scenes:
        dl = Driveline(sc, {}, track_energy=track)      # most detailed fidelity of each joint
        n = dl.n_dof
        for _ in range(4):
            x = dl.x0.copy()
            x[:n] += rng.uniform(-0.05, 0.05, n) + rng.uniform(0, 6)
            x[n:2 * n] += rng.uniform(-3, 3, n)
            ref = dl._rhs(0.1, x, 80.0, 20.0, None, None)
            assert np.allclose(dl.rhs(0.1, x, 80.0, 20.0), ref, rtol=1e-13, atol=1e-12), sc.name


def test_reactions_use_the_joint_input_state() -> None:
    """Driveline.reactions passes (phi_in, omega_in, torque_in) of each joint; a lossless
    joint's reported output torque equals the output shaft's effort (T_in / ratio)."""
    dl = Driveline.from_scene(scene(MIXED))
    x = dl.x0.copy()
    x[:3] += [0.4, 0.2, 0.1]
    names, _pos, _vel, eff = dl.joint_states(x, 150.0, 42.0)
    react = dl.reactions(x, 150.0, 42.0)
    for j in ('h1', 'h2'):
        if 'torque_out' not in react.get(j, {}):
            pytest.skip('hooke model gives no torque_out reaction')
        assert react[j]['torque_out'] == pytest.approx(eff[names.index(f'{j}_output')], rel=1e-9)


@pytest.mark.parametrize('revolutions', [0.1, 1e5])
def test_intermediate_member_speed_matches_cage_law_far_out(revolutions: float) -> None:
    """Cage speed of a Rzeppa with a cage error = f'(phi) omega (seed 003 eq. 29 via
    Rzeppa.cage), also after 1e5 revolutions where a plain 1e-6 rad difference loses 1e-4."""
    from cvj_ros.physics.joints.rzeppa import Rzeppa
    chain = [inertia('a', 0.1), joint('rz', 'rzeppa', delta_deg=40.0, alpha_deg=17.0),
             inertia('b', 0.2)]
    dl = Driveline.from_scene(scene(chain))
    x = dl.x0.copy()
    x[0] = 2 * math.pi * revolutions + 0.37
    x[1] = 25.0
    names, pos, vel, _eff = dl.joint_states(x, 0.0, 0.0)
    i_cage = [k for k, n in enumerate(names) if n.startswith('rz_') and n not in ('rz_input', 'rz_output')]
    assert len(i_cage) == 1
    _phi3, f1, _f2 = Rzeppa(math.radians(40.0), alpha=math.radians(17.0)).cage(np.array([x[0]]))
    assert vel[i_cage[0]] == pytest.approx(float(np.asarray(f1).ravel()[0]) * 25.0, rel=1e-6)
