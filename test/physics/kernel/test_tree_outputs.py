"""The compiled joint state of a vehicle scene (kernel/tree_outputs_nb.py through
state_outputs.TreeKernelStateOutputs) against the Python reference
(TreeDriveline.joint_states_fast + fill_mid): every shaft's angle, speed and torque on the
shipped vehicle scenes and the seeded random trees of test_tree_fuzz.py, at the start,
at perturbed states and with outside wheel torques.

Bound: 1e-13 relative (floor 1) per entry. Where it comes from: the compiled walk is a
port of TreeDriveline._walk in the same order of operations and its joint ops are the
kernel's (test_tree_kernel: kernel rhs = oracle bit for bit); a libm call rounding
differently from numpy moves an entry by a few ulp (~1e-15), the member speeds' central
difference (h = 1e-3 rad) amplifies that by ~1/h. Measured on this machine: bit-identical
on fwd_axle, fwd_axle_split_mu and awd_4x4; rwd_propshaft within 4.3e-16 relative (its
Hooke stages).
"""
from __future__ import annotations

import importlib.util
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from cvj_ros.physics.scene import load_scene, parse_scene, shipped_scenes
from cvj_ros.physics.state_outputs import (PythonStateOutputs, TreeKernelStateOutputs,
                                           make_state_outputs)
from cvj_ros.physics.tree import TreeDriveline

VEHICLE_SCENES = ('fwd_axle', 'fwd_axle_split_mu', 'awd_4x4', 'rwd_propshaft')
TOL = 1e-13


def _fuzz_module() -> Any:
    path = Path(__file__).resolve().parents[1] / 'test_tree_fuzz.py'
    spec = importlib.util.spec_from_file_location('_tree_fuzz_scenes_outputs', path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


FUZZ = _fuzz_module()


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


def _check(dl: TreeDriveline, states: list[np.ndarray], wheel_torques: list[float] | None) -> None:
    kernel = TreeKernelStateOutputs(dl, [])
    dl.set_wheel_torques(wheel_torques)
    ref = PythonStateOutputs(dl, [])
    for i, x in enumerate(states):
        te = 120.0 * np.cos(i)          # both signs of the engine torque
        got = kernel.joint_states(x, te, 0.0)
        want = ref.joint_states(x, te, 0.0)
        for name, a, b in zip(('position', 'velocity', 'effort'), got, want):
            err = np.abs(a - b) / np.maximum(1.0, np.abs(b))
            assert float(np.max(err)) <= TOL, (i, name, dl.shaft_names[int(np.argmax(err))])
    dl.set_wheel_torques(None)


@pytest.mark.parametrize('name', VEHICLE_SCENES)
def test_shipped_vehicle_scene_joint_state_matches_the_reference(name: str) -> None:
    dl = TreeDriveline.from_scene(load_scene(shipped_scenes()[name]))
    _check(dl, _states(dl, 12, 1), None)


@pytest.mark.parametrize('name', VEHICLE_SCENES)
def test_outside_wheel_torques_replace_the_tyres_as_in_the_reference(name: str) -> None:
    dl = TreeDriveline.from_scene(load_scene(shipped_scenes()[name]))
    torques = [40.0 - 25.0 * i for i in range(dl.n_wheel)]     # one wheel driving back
    _check(dl, _states(dl, 6, 2), torques)
    # and they act: the wheel shafts' efforts are the torques themselves (F_x r, F_x = T / r)
    kernel = TreeKernelStateOutputs(dl, [])
    dl.set_wheel_torques(torques)
    _pos, _vel, eff = kernel.joint_states(dl.x0, 50.0, 0.0)
    for w, t in zip(dl.wheel_names, torques):
        assert eff[dl.shaft_names.index(w)] == pytest.approx(t, rel=1e-15)


@pytest.mark.parametrize('seed', range(12))
def test_fuzzed_tree_joint_state_matches_the_reference(seed: int) -> None:
    dl = TreeDriveline.from_scene(parse_scene(FUZZ.random_scene(seed)))
    _check(dl, _states(dl, 6, seed), None)


def test_make_state_outputs_compiles_trees_and_keeps_the_python_path_on_request() -> None:
    dl = TreeDriveline.from_scene(load_scene(shipped_scenes()['fwd_axle']))
    assert isinstance(make_state_outputs(dl, [], compiled=True), TreeKernelStateOutputs)
    assert isinstance(make_state_outputs(dl, [], compiled=False), PythonStateOutputs)
    out = make_state_outputs(dl, [], compiled=True)
    assert out.wrenches(dl.x0, 0.0, 0.0, out.joint_states(dl.x0, 0.0, 0.0)) == {}   # no joints asked


def test_a_non_finite_state_gives_the_reference_nan() -> None:
    dl = TreeDriveline.from_scene(load_scene(shipped_scenes()['fwd_axle']))
    x = dl.x0.copy()
    x[dl.n_dof] = np.nan
    pos, vel, eff = TreeKernelStateOutputs(dl, []).joint_states(x, 10.0, 0.0)
    want = PythonStateOutputs(dl, []).joint_states(x, 10.0, 0.0)
    for a, b in zip((pos, vel, eff), want):
        np.testing.assert_array_equal(np.isnan(a), np.isnan(b))


# --- outside wheel loads on the compiled right-hand side (kernel/tree_wheel_rhs.py) -----------

def _check_rhs(dl: TreeDriveline, states: list[np.ndarray]) -> None:
    from cvj_ros.physics.kernel.tree_wheel_rhs import CompiledWheelLoadRhs
    compiled = CompiledWheelLoadRhs(dl)
    for i, x in enumerate(states):
        dl.set_wheel_torques([60.0 * np.sin(i + w) for w in range(dl.n_wheel)])
        got = compiled.rhs(0.01 * i, x, 150.0 * np.cos(i), 0.0)
        want = dl.rhs(0.01 * i, x, 150.0 * np.cos(i), 0.0)
        err = np.abs(got - want) / np.maximum(1.0, np.abs(want))
        assert float(np.max(err)) <= TOL, (i, dl.state_names[int(np.argmax(err))])
    dl.set_wheel_torques(None)     # no outside torques: the tyres, i.e. the driveline's rhs
    np.testing.assert_array_equal(compiled.rhs(0.0, states[-1], 80.0), dl.rhs(0.0, states[-1], 80.0))


@pytest.mark.parametrize('name', VEHICLE_SCENES)
def test_compiled_wheel_load_rhs_matches_the_reference(name: str) -> None:
    for energy in (False, True):
        dl = TreeDriveline.from_scene(load_scene(shipped_scenes()[name]), track_energy=energy)
        _check_rhs(dl, _states(dl, 8, 3))


@pytest.mark.parametrize('seed', range(12))
def test_fuzzed_tree_compiled_wheel_load_rhs_matches_the_reference(seed: int) -> None:
    dl = TreeDriveline.from_scene(parse_scene(FUZZ.random_scene(seed)), track_energy=True)
    _check_rhs(dl, _states(dl, 4, seed))


def test_coupled_stepper_on_the_compiled_wheel_load_rhs_steps_as_the_reference() -> None:
    """The coupling node's stepper (Python dopri5 on the wrapper) against the same stepper on
    the plain TreeDriveline, answers changing every step: the same states (measured
    bit-identical; bound as above)."""
    from cvj_ros.physics.cosim import CoupledStepper
    from cvj_ros.physics.kernel.tree_wheel_rhs import CompiledWheelLoadRhs
    sc = load_scene(shipped_scenes()['fwd_axle'])
    dl = TreeDriveline.from_scene(sc)
    dl.set_wheel_torques([0.0, 0.0])
    kw = dict(method=sc.solver.method, rtol=sc.solver.rtol, atol=sc.solver.atol, h=sc.solver.h)
    a = CoupledStepper(CompiledWheelLoadRhs(dl), **kw)
    b = CoupledStepper(dl, **kw)
    assert a.backend == b.backend == 'python'
    for k in range(40):
        dl.set_wheel_torques([30.0 + 0.5 * k, -10.0 + k])
        xa = np.asarray(a.advance((k + 1) * 1e-3, 140.0, 0.0))
        xb = np.asarray(b.advance((k + 1) * 1e-3, 140.0, 0.0))
        err = np.abs(xa - xb) / np.maximum(1.0, np.abs(xb))
        assert float(np.max(err)) <= TOL, k


# --- offline samples (kernel/tree_samples.py through Simulation.run) -------------------------

def _trace(name: str, compiled: bool, monkeypatch: Any) -> Any:
    from cvj_ros.physics.kernel import tree_samples
    from cvj_ros.physics.simulate import Simulation
    if not compiled:
        def refuse(_dl: Any) -> None:
            raise NotImplementedError('the Python samples')
        monkeypatch.setattr(tree_samples, 'TreeKernelSamples', refuse)
    sim = Simulation(load_scene(shipped_scenes()[name]))
    assert sim.backend == 'kernel'
    trace = sim.run(0.05, sample_dt=1e-3, progress=lambda _t: None)   # the per-sample path
    monkeypatch.undo()
    return trace


@pytest.mark.parametrize('name', VEHICLE_SCENES)
def test_compiled_samples_of_a_vehicle_run_equal_the_python_samples(name: str, monkeypatch) -> None:
    """Simulation.run on the kernel stepped from Python (a progress callback): every
    sampled array and wheel channel from the compiled walk against the same run sampled by
    TreeDriveline.sample_outputs (bound as above; NaN residuals where no work integrals are
    kept). Without a callback the run's outputs are kernel/tree_run_nb.py's
    (test_tree_run_nb.py)."""
    from cvj_ros.physics.kernel.tree_samples import TreeKernelSamples
    TreeKernelSamples(TreeDriveline.from_scene(load_scene(shipped_scenes()[name])))  # covered
    got = _trace(name, True, monkeypatch)
    want = _trace(name, False, monkeypatch)
    pairs = [('position', got.position, want.position), ('velocity', got.velocity, want.velocity),
             ('effort', got.effort, want.effort), ('engine', got.engine_torque, want.engine_torque),
             ('load', got.load_torque, want.load_torque),
             ('residual', got.energy_residual, want.energy_residual)]
    assert sorted(got.channels) == sorted(want.channels)
    pairs += [(k, got.channels[k], want.channels[k]) for k in want.channels]
    for key, a, b in pairs:
        np.testing.assert_array_equal(np.isnan(a), np.isnan(b))
        ok = ~np.isnan(b)
        err = np.abs(a[ok] - b[ok]) / np.maximum(1.0, np.abs(b[ok]))
        assert err.size == 0 or float(np.max(err)) <= TOL, key


def test_a_tree_subclass_such_as_the_mode_aware_tree_stays_on_the_python_path() -> None:
    """The compiled walk has no mode links or stuck packs: a subclass of TreeDriveline (the
    mode-aware tree is one) is refused by every compiled tree path, and the node's outputs
    fall back to the Python reference."""
    from cvj_ros.physics.kernel.tree_samples import TreeKernelSamples
    from cvj_ros.physics.kernel.tree_wheel_rhs import CompiledWheelLoadRhs

    class Sub(TreeDriveline):
        pass
    dl = Sub.from_scene(load_scene(shipped_scenes()['fwd_axle']))
    for build in (lambda: TreeKernelStateOutputs(dl, []), lambda: TreeKernelSamples(dl),
                  lambda: CompiledWheelLoadRhs(dl)):
        with pytest.raises(NotImplementedError):
            build()
    assert isinstance(make_state_outputs(dl, [], compiled=True), PythonStateOutputs)
