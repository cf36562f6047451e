"""A vehicle run's compiled outputs (kernel/tree_run_nb.py through Simulation.run) against
the Python per-sample path, the compiled energy against TreeDriveline.energy, and the runs'
determinism.

Reference: the same run stepped by ``advance_to`` (a progress callback: the same steps and
states, test_simulate.py) with every sample's outputs from ``TreeDriveline.sample_outputs``
(the compiled sample walk refused): engine torque from the Python engine, the walk, the
energy residual from ``TreeDriveline.energy_residual``. Bound: 1e-13 relative (floor 1) per
entry, test_tree_outputs.py's: the compiled walk and energy are ports in the oracle's order
of operations and the in-kernel engine is the compiled rhs's; a libm call rounding
differently from numpy's moves an entry by a few ulp (~1e-15 relative), the member speeds'
central difference (h = 1e-3 rad) amplifies that by ~1/h, and the residual divides
differences of energies ~1e4 J by a scale of the same size.
"""
from __future__ import annotations

import hashlib
import importlib.util
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from cvj_ros.physics.scene import load_scene, parse_scene, shipped_scenes
from cvj_ros.physics.simulate import Simulation, Trace
from cvj_ros.physics.tree import TreeDriveline

VEHICLE_SCENES = ('fwd_axle', 'fwd_axle_split_mu', 'awd_4x4', 'rwd_propshaft')
TOL = 1e-13


def _fuzz_module() -> Any:
    path = Path(__file__).resolve().parents[1] / 'test_tree_fuzz.py'
    spec = importlib.util.spec_from_file_location('_tree_fuzz_scenes_run', path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _python_samples(sim: Simulation, monkeypatch: Any, *args: Any, **kwargs: Any) -> Trace:
    """sim.run stepped from Python with every sample's outputs from the Python reference."""
    from cvj_ros.physics.kernel import tree_samples

    def refuse(_dl: Any) -> None:
        raise NotImplementedError('the Python samples')
    monkeypatch.setattr(tree_samples, 'TreeKernelSamples', refuse)
    try:
        return sim.run(*args, progress=lambda _t: None, **kwargs)
    finally:
        monkeypatch.undo()


def _arrays(tr: Trace) -> list[tuple[str, np.ndarray]]:
    return [('position', tr.position), ('velocity', tr.velocity), ('effort', tr.effort),
            ('engine', tr.engine_torque), ('load', tr.load_torque),
            ('residual', tr.energy_residual), *tr.channels.items()]


@pytest.mark.parametrize('name', VEHICLE_SCENES)
def test_every_output_of_a_vehicle_run_matches_the_python_samples(name: str, monkeypatch) -> None:
    sc = load_scene(shipped_scenes()[name])
    got = Simulation(sc).run(0.1, sample_dt=2e-3)
    assert Simulation(sc)._tree_plan(0.1, 2e-3, True) is not None   # the compiled path ran
    want = _python_samples(Simulation(sc), monkeypatch, 0.1, sample_dt=2e-3)
    assert got.solver['nfev'] == want.solver['nfev'] and list(got.channels) == list(want.channels)
    assert got.t.tobytes() == want.t.tobytes()
    for key, a in _arrays(got):
        b = dict(_arrays(want))[key]
        np.testing.assert_array_equal(np.isnan(a), np.isnan(b))
        ok = ~np.isnan(b)
        err = np.abs(a[ok] - b[ok]) / np.maximum(1.0, np.abs(b[ok]))
        assert err.size == 0 or float(np.max(err)) <= TOL, (key, float(np.max(err)))
    assert np.all(np.isfinite(got.energy_residual))          # the scenes track the work


@pytest.mark.parametrize('method', ['vern6', 'rodas3'])
def test_other_methods_and_no_energy_tracking_match_the_python_samples(method: str,
                                                                     monkeypatch) -> None:
    """Another method's landings, and a driveline without work integrals (NaN residuals,
    as the reference)."""
    sc = load_scene(shipped_scenes()['fwd_axle'])
    for track in (True, False):
        kw = dict(method=method, rtol=1e-5, atol=1e-7, track_energy=track)
        got = Simulation(sc, **kw).run(0.05, sample_dt=5e-3)
        want = _python_samples(Simulation(sc, **kw), monkeypatch, 0.05, sample_dt=5e-3)
        assert np.isnan(got.energy_residual).all() == (not track)
        for key, a in _arrays(got):
            b = dict(_arrays(want))[key]
            np.testing.assert_array_equal(np.isnan(a), np.isnan(b))
            ok = ~np.isnan(b)
            err = np.abs(a[ok] - b[ok]) / np.maximum(1.0, np.abs(b[ok]))
            assert err.size == 0 or float(np.max(err)) <= TOL, (key, track)


def _states(dl: TreeDriveline, count: int, seed: int) -> list[np.ndarray]:
    """x0 and perturbations of it (angles, rates, slips, speed, work integrals)."""
    rng = np.random.default_rng(seed)
    out = [dl.x0.copy()]
    for _ in range(count - 1):
        x = dl.x0 + rng.normal(0.0, 1.0, dl.x0.size) * np.r_[
            np.full(dl.n_dof, 0.5), np.full(dl.n_dof, 5.0), np.full(dl.n_wheel, 0.05),
            np.full(dl.x0.size - 2 * dl.n_dof - dl.n_wheel, 3.0)]
        out.append(x)
    return out


def _energy_check(dl: TreeDriveline, states: list[np.ndarray]) -> None:
    from cvj_ros.physics.kernel.layout import build_model
    from cvj_ros.physics.kernel.tree_outputs_nb import _walk, tree_tables
    from cvj_ros.physics.kernel.tree_run_nb import tree_energy
    model = build_model(dl)
    tab, ends = tree_tables(dl)
    m = len(dl.shaft_names)
    for x in states:
        _fx, _fz, q, qd, sphi, sa = _walk(x, model.ip, model.fp, 50.0, 0,
                                          np.zeros(max(dl.n_wheel, 1)), tab, ends,
                                          np.empty(m), np.empty(m), np.empty(m))
        ke, el = tree_energy(x, model.ip, model.fp, q, qd, sphi, sa)
        want = dl.energy(x)
        assert ke == pytest.approx(want['kinetic'], rel=TOL, abs=TOL)
        assert el == pytest.approx(want['elastic'], rel=TOL, abs=TOL)


@pytest.mark.parametrize('name', VEHICLE_SCENES)
def test_compiled_energy_matches_the_reference(name: str) -> None:
    """Kinetic (sections, spiders, body) and elastic energy at x0 and perturbed states."""
    dl = TreeDriveline.from_scene(load_scene(shipped_scenes()[name]), track_energy=True)
    _energy_check(dl, _states(dl, 8, 3))


@pytest.mark.parametrize('seed', range(8))
def test_compiled_energy_of_fuzzed_trees_matches_the_reference(seed: int) -> None:
    """The seeded random trees of test_tree_fuzz.py (locked and open differentials, spiders,
    springs with dead zones, several groups)."""
    dl = TreeDriveline.from_scene(parse_scene(_fuzz_module().random_scene(seed)),
                                  track_energy=True)
    _energy_check(dl, _states(dl, 4, seed))


def test_a_non_finite_landing_state_is_the_first_bad_sample_and_fills_nothing_after() -> None:
    from cvj_ros.physics.kernel.outputs_nb import mid_table
    from cvj_ros.physics.kernel.tree_outputs_nb import tree_tables
    from cvj_ros.physics.kernel.tree_run_nb import tree_run_outputs
    sim = Simulation(load_scene(shipped_scenes()['fwd_axle']))
    dl = sim.driveline
    model = sim._model(1.0)
    tab, ends = tree_tables(dl)
    mtab, mfp, _py = mid_table(dl)
    XG = np.tile(dl.x0, (4, 1))
    XG[2, 3] = np.nan
    m, ns = 3, len(dl.shaft_names)
    pos = np.full((m, ns), -7.0)
    vel = pos.copy()
    out = [np.full((m, ns), -7.0), *(np.full(m, -7.0) for _ in range(3)),
           np.full((1 + 4 * dl.n_wheel, m), -7.0)]
    bad = tree_run_outputs(np.array([0.0, 0.1, 0.2]), XG, np.array([0, 1, 2], np.int64),
                           model.ip, model.fp, tab, ends, 1.0, pos, vel, *out,
                           np.ascontiguousarray(mtab, np.int64), mfp, np.zeros(dl.n_wheel))
    assert bad == 2
    assert (pos[2] == -7.0).all() and out[1][2] == -7.0        # sample 2 untouched
    assert (pos[:2] != -7.0).all() and (out[1][:2] != -7.0).all()   # the first two filled


_RUN = '''
import hashlib, numpy as np
from cvj_ros.physics.scene import load_scene, shipped_scenes
from cvj_ros.physics.simulate import Simulation
tr = Simulation(load_scene(shipped_scenes()['fwd_axle'])).run(0.2, sample_dt=0.01)
h = hashlib.sha256()
for a in (tr.t, tr.position, tr.velocity, tr.effort, tr.engine_torque, tr.load_torque,
          tr.energy_residual, *tr.channels.values()):
    h.update(np.ascontiguousarray(a).tobytes())
print(h.hexdigest())
'''


def test_a_vehicle_run_gives_the_same_bytes_in_another_simulation_and_process() -> None:
    """Same scene and seed, the same bytes: two Simulations here and one in a fresh
    interpreter (other hash seed, other memory layout)."""
    digests = []
    for _ in range(2):
        tr = Simulation(load_scene(shipped_scenes()['fwd_axle'])).run(0.2, sample_dt=0.01)
        h = hashlib.sha256()
        for a in (tr.t, tr.position, tr.velocity, tr.effort, tr.engine_torque, tr.load_torque,
                  tr.energy_residual, *tr.channels.values()):
            h.update(np.ascontiguousarray(a).tobytes())
        digests.append(h.hexdigest())
    env = dict(os.environ, PYTHONHASHSEED='123')
    done = subprocess.run([sys.executable, '-c', _RUN], capture_output=True, text=True,
                          timeout=600, env=env)
    assert done.returncode == 0, done.stderr[-2000:]
    assert digests[0] == digests[1] == done.stdout.split()[-1]
