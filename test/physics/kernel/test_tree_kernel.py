"""The compiled vehicle-scene kernel (kernel/tree_nb.py through rhs_nb.rhs / rhs_nb.jac)
against its oracle, cvj_ros.physics.tree.TreeDriveline: right-hand side and Jacobian on the
shipped vehicle scenes and on the seeded random trees of test_tree_fuzz.py (nested open,
locked and viscous differentials, springs, joints, load transfer), at the initial state,
at perturbed states and along a trajectory; whole runs kernel against Python reference."""
from __future__ import annotations

import importlib.util
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from cvj_ros.physics.engine import engine_from_spec
from cvj_ros.physics.kernel import rhs_nb
from cvj_ros.physics.kernel.layout import H_TREE, build_model
from cvj_ros.physics.scene import load_scene, parse_scene, shipped_scenes
from cvj_ros.physics.simulate import Simulation
from cvj_ros.physics.tree import TreeDriveline

VEHICLE_SCENES = ('fwd_axle', 'fwd_axle_split_mu', 'awd_4x4', 'rwd_propshaft')
# The kernel evaluates the oracle's formulas in the oracle's order: measured bit-identical
# (0.0) on every state below; the bound is the 1e-12 (relative, floor 1).
TOL = 1e-12


def _fuzz_module() -> Any:
    path = Path(__file__).resolve().parents[1] / 'test_tree_fuzz.py'
    spec = importlib.util.spec_from_file_location('_tree_fuzz_scenes', path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


FUZZ = _fuzz_module()


def _rel(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.max(np.abs(a - b) / np.maximum(1.0, np.abs(b))))


def _states(dl: TreeDriveline, count: int, seed: int) -> list[np.ndarray]:
    """x0 and ``count - 1`` perturbations of it (angles, rates, relaxed slips, speed)."""
    rng = np.random.default_rng(seed)
    m = 2 * dl.n_dof + dl.n_wheel + 1
    scale = np.r_[np.full(dl.n_dof, 0.5), np.full(dl.n_dof, 5.0), np.full(dl.n_wheel, 0.05), [1.0]]
    out = [dl.x0.copy()]
    for _ in range(count - 1):
        x = dl.x0.copy()
        x[:m] += rng.normal(0.0, 1.0, m) * scale
        out.append(x)
    return out


def _check_rhs_and_jac(dl: TreeDriveline, engine: Any, states: list[np.ndarray], n_jac: int) -> None:
    md = build_model(dl, engine=engine)
    assert md.ip[H_TREE] > 0 and md.n_state == dl.x0.size
    for i, x in enumerate(states):
        t = 0.01 * i
        ref = dl.rhs_sources(t, x, engine)
        dy = np.full_like(ref, np.nan)
        rhs_nb.rhs(t, x, md.ip, md.fp, dy)
        assert _rel(dy, ref) <= TOL, i
        if i < n_jac:
            jac = np.full((x.size, x.size), np.nan)
            rhs_nb.jac(t, x, md.ip, md.fp, jac)
            assert _rel(jac, dl.jacobian_fd(t, x, engine)) <= TOL, i


@pytest.mark.parametrize('name', VEHICLE_SCENES)
def test_shipped_vehicle_scene_rhs_and_jac_match_the_oracle(name: str) -> None:
    sc = load_scene(shipped_scenes()[name])
    dl = TreeDriveline.from_scene(sc, track_energy=True)
    engine = engine_from_spec(sc.engine, field='engine')
    _check_rhs_and_jac(dl, engine, _states(dl, 40, 0), 4)


@pytest.mark.parametrize('seed', range(24))
def test_fuzzed_tree_rhs_and_jac_match_the_oracle(seed: int) -> None:
    sc = parse_scene(FUZZ.random_scene(seed))
    engine = engine_from_spec(FUZZ.ENGINE, field='engine')
    for energy in (True, False):
        dl = TreeDriveline.from_scene(sc, track_energy=energy)
        _check_rhs_and_jac(dl, engine, _states(dl, 12, seed), 2)


def test_rhs_matches_along_a_trajectory() -> None:
    """The states a run visits (spun-up wheel on ice, wound-up springs), not only
    perturbations of the start."""
    sc = load_scene(shipped_scenes()['fwd_axle_split_mu'])
    sim = Simulation(sc, backend='python')
    sim.run(0.3, sample_dt=0.05)
    dl = sim.driveline
    _check_rhs_and_jac(dl, sim.engine, [dl.x0, sim.final_state], 2)


@pytest.mark.parametrize('name,method', [('fwd_axle', 'dopri5'), ('rwd_propshaft', 'dopri5'),
                                         ('fwd_axle_split_mu', 'rodas3')])
def test_simulation_runs_vehicle_scenes_on_the_kernel(name: str, method: str) -> None:
    """Simulation picks the kernel for vehicle scenes. The compiled and the Python steppers
    differ in summation order (the chain scenes' REL = 1e-9 in test_backends.py), so the
    samples agree to the steppers' rounding: dopri5 takes the reference's steps (same
    counters; measured 1e-10..2e-9 relative on the velocities); rodas3 factors the
    finite-difference Jacobian by its own LU (numpy's LAPACK in the reference), which moves
    a step-size decision by one step in ~700 (measured 629 vs 628 accepted, velocities 5e-9
    relative, tyre channels 6e-7 relative: the force is steep in the slip). Bounds 10x the
    measured."""
    sc = load_scene(shipped_scenes()[name])
    kern = Simulation(sc, method=method)
    assert kern.backend == 'kernel' and kern.backend_note is None
    a = kern.run(0.1)
    b = Simulation(sc, method=method, backend='python').run(0.1)
    assert a.solver['backend'] == 'kernel'
    assert a.names == b.names and sorted(a.channels) == sorted(b.channels)
    if method == 'dopri5':
        for c in ('naccept', 'nreject', 'nfev'):
            assert a.solver[c] == b.solver[c], c
        assert _rel(a.velocity, b.velocity) < 2e-8 and _rel(a.position, b.position) < 2e-8
        chan = 2e-8
    else:
        assert abs(a.solver['naccept'] - b.solver['naccept']) <= 0.01 * b.solver['naccept']
        assert _rel(a.velocity, b.velocity) < 5e-8 and _rel(a.position, b.position) < 5e-8
        chan = 6e-6
    for key, ref in b.channels.items():
        assert _rel(a.channels[key], ref) < chan, key
    assert np.all(np.abs(a.energy_residual) < 1e-8)


def test_fuzzed_tree_runs_on_the_kernel() -> None:
    """Three random trees through Simulation (kernel): same steps as the reference."""
    for seed in (1, 5, 9):
        sc = parse_scene(FUZZ.random_scene(seed))
        a = Simulation(sc).run(0.03, sample_dt=0.01)
        b = Simulation(sc, backend='python').run(0.03, sample_dt=0.01)
        assert a.solver['backend'] == 'kernel' and b.solver['backend'] == 'python'
        assert a.solver['nfev'] == b.solver['nfev'], seed
        assert _rel(a.velocity, b.velocity) < 1e-8, seed


def test_an_engine_the_kernel_does_not_cover_falls_back_with_one_line() -> None:
    """A vehicle scene with a user's Python engine runs on the reference, saying why."""
    sc = load_scene(shipped_scenes()['fwd_axle'])

    class OwnEngine:
        time_invariant = True

        def torque(self, t: float, omega: float, phi: float) -> float:
            return 120.0 - 0.1 * omega

        def slope(self, t: float, omega: float, phi: float) -> float:
            return -0.1

    sim = Simulation(sc, engine=OwnEngine())
    assert sim.backend == 'python'
    assert sim.backend_note == ('compiled kernel: engine model OwnEngine is not covered yet; '
                                'running the Python reference')
    assert sim.run(0.01).solver['backend'] == 'python'
