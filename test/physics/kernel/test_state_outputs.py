"""Compiled per-exchange outputs (issue 10, cvj_ros/physics/state_outputs.py) against the
Python reference: joint states (angles, speeds, torques, intermediate members) and the
reaction wrenches, on every shipped scene, at its own fidelities and with every joint
forced to each of its other fidelities, at several states (small and large angles, both
torque signs).

Bound: 1e-12 relative to the largest magnitude of the compared vector (positions,
velocities, efforts, one joint's wrench). Where it comes from: the compiled functions are
line-by-line ports in the same operation order, so the two paths differ only where a libm
call (sin, cos, atan2, sqrt) rounds differently from numpy's, a few ulp (~1e-15 relative);
the member speeds take a central difference with h = 1e-3 rad, which amplifies that by
~1/h to ~1e-13 - still 10x inside the bound. Measured on this machine: bit-identical
(difference 0) on every case.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from cvj_ros.physics.driveline import Driveline
from cvj_ros.physics.joints import JOINTS
from cvj_ros.physics.scene import Joint, find_scene, load_scene
from cvj_ros.physics.state_outputs import (KernelStateOutputs, PythonStateOutputs,
                                           make_state_outputs)

SCENES = ('kavz685_lever', 'fwd_halfshaft', 'cardan_truck', 'tripod_xiu2024', 'stiff')
REL = 1e-12


def _variants(scene):
    """The scene's own levels, then every joint at each of its kind's fidelities."""
    yield 'scene', None
    joints = [el for el in scene.driveline if isinstance(el, Joint)]
    levels = set()
    for el in joints:
        levels.update(JOINTS[el.kind].fidelities)
    for level in sorted(levels):
        forced = {el.name: level for el in joints if level in JOINTS[el.kind].fidelities}
        if forced:
            yield level, forced


def _states(dl: Driveline, rng: np.random.Generator):
    """(x, T_engine, T_load): x0, then perturbed states, one at large angles (1e3 rad)."""
    n = dl.n_dof
    yield np.array(dl.x0, dtype=float), 150.0, 80.0
    for k in range(4):
        x = np.array(dl.x0, dtype=float)
        x[:n] += rng.uniform(-3.0, 3.0, n) + (1e3 if k == 3 else 0.0)
        x[n:2 * n] = x[n:2 * n] * rng.uniform(0.5, 1.5) + rng.uniform(-2.0, 2.0, n)
        yield x, float(rng.uniform(-300.0, 500.0)), float(rng.uniform(-200.0, 300.0))


def _rel(a, b) -> float:
    a, b = np.asarray(a, dtype=float).ravel(), np.asarray(b, dtype=float).ravel()
    return float(np.max(np.abs(a - b)) / max(float(np.max(np.abs(b))), 1e-300))


@pytest.mark.parametrize('name', SCENES)
def test_compiled_outputs_equal_python_on_every_scene_and_fidelity(name):
    scene = load_scene(find_scene(name))
    rng = np.random.default_rng(10)
    checked = 0
    for label, forced in _variants(scene):
        dl = Driveline.from_scene(scene, fidelity=forced, track_energy=True)
        joints = [j for j, m in dl.joint_models.items() if hasattr(m, 'reactions')]
        comp = KernelStateOutputs(dl, joints)
        ref = PythonStateOutputs(dl, joints)
        # every member and joint of the shipped scenes has its compiled form
        assert comp._mid_python == [] and comp._react_python == [], (label, comp._mid_python)
        for x, te, tl in _states(dl, rng):
            got = comp.joint_states(x, te, tl)
            want = ref.joint_states(x, te, tl)
            for what, g, w in zip(('position', 'velocity', 'effort'), got, want):
                assert _rel(g, w) <= REL, (label, what, g, w)
            wg = comp.wrenches(x, te, tl, got)
            ww = ref.wrenches(x, te, tl, want)
            assert list(wg) == list(ww) == joints, label
            for j in joints:
                assert all(math.isfinite(v) for v in np.ravel(wg[j]))
                assert _rel(wg[j], ww[j]) <= REL, (label, j, wg[j], ww[j])
            checked += 1
    assert checked >= 5


def test_exact_tripod_reactions_at_many_angles():
    """The compiled Newton + implicit derivatives + 10 x 10 balance of the exact tripod
    (fwd_halfshaft's, beta 15 deg, and seed 000's) over a revolution and at 1e4 rad, where the
    angle reduction modulo 2 pi/3 renumbers the rollers."""
    for name in ('fwd_halfshaft', 'tripod_xiu2024'):
        dl = Driveline.from_scene(load_scene(find_scene(name)))
        joint = next(j for j, m in dl.joint_models.items() if m.kind == 'tripod')
        comp = KernelStateOutputs(dl, [joint])
        model = dl.joint_models[joint]
        col = dl.shaft_names.index(f'{joint}_input')
        n = len(dl.shaft_names)
        for phi in list(np.linspace(-math.pi, math.pi, 13)) + [1e4 + 0.3, -2e4 - 1.1]:
            pos, vel, eff = np.zeros(n), np.zeros(n), np.zeros(n)
            pos[col], vel[col], eff[col] = phi, 209.4, 312.0
            got = comp.wrenches(None, 0.0, 0.0, (pos, vel, eff))[joint]
            r = model.reactions(phi, 209.4, 312.0)
            want = ((r['input_force_x'], r['input_force_y'], r['axial_force']),
                    (r['input_moment_x'], r['input_moment_y'], r['torque_out']))
            assert _rel(got, want) <= REL, (name, phi, got, want)


def test_python_fallback_when_not_compiled():
    """compiled=False gives the Python reference; a joint without a compiled reaction
    (here: its code forced to 'python') is answered by its model, in the joints' order."""
    dl = Driveline.from_scene(load_scene(find_scene('fwd_halfshaft')))
    joints = ['gearbox', 'tripod', 'rzeppa']
    assert make_state_outputs(dl, joints, compiled=False).backend == 'python'
    comp = make_state_outputs(dl, joints, compiled=True)
    assert comp.backend == 'kernel'
    comp._react_python = [1]                     # tripod through Python
    keep = comp._rtab[:, 1] >= 0
    keep[1] = False
    comp._rtab_c = comp._rtab[keep]
    comp._row_joint = ['gearbox', 'rzeppa']
    comp._ws = np.empty((2, 6))
    x = np.array(dl.x0, dtype=float)
    js = comp.joint_states(x, 120.0, 60.0)
    got = comp.wrenches(x, 120.0, 60.0, js)
    want = PythonStateOutputs(dl, joints).wrenches(x, 120.0, 60.0, js)
    assert list(got) == joints
    for j in joints:
        assert _rel(got[j], want[j]) <= REL


def test_non_finite_input_goes_to_the_python_model():
    """A non-finite joint state is not answered by the compiled reactions: the Python model
    gets it and raises its own error, as the Python path does."""
    from cvj_ros.errors import CvjError
    dl = Driveline.from_scene(load_scene(find_scene('kavz685_lever')))
    comp = KernelStateOutputs(dl, ['coupling'])
    x = np.array(dl.x0, dtype=float)
    pos, vel, eff = comp.joint_states(x, 100.0, 50.0)
    eff = eff.copy()
    eff[dl.shaft_names.index('coupling_input')] = math.nan
    with pytest.raises(CvjError):               # what the Python path raises
        dl.joint_models['coupling'].reactions(float(pos[1]), float(vel[1]), math.nan)
    with pytest.raises(CvjError):
        comp.wrenches(x, 100.0, 50.0, (pos, vel, eff))


def test_phased_hooke_reactions_compiled_and_cross_angle_on_python():
    """A Hooke pair with yoke phases and bend planes: the compiled joint states and
    reaction wrenches equal the Python reference (REL); a Hooke with a non-square cross has
    no compiled reaction and is answered by its model (the states stay compiled)."""
    from cvj_ros.physics.scene import parse_scene
    sc = parse_scene({
        'name': 'phased', 'duration': 1.0, 'engine': {'model': 'linear'},
        'load': {'model': 'constant', 'torque': 40.0}, 'initial': {'speed_rad_s': 50.0},
        'driveline': [
            {'type': 'inertia', 'name': 'a', 'J': 0.3},
            {'type': 'joint', 'name': 'front', 'kind': 'hooke', 'fidelity': 'exact',
             'params': {'beta_deg': 12.0, 'phase_deg': 30.0, 'bend_plane_deg': 15.0}},
            {'type': 'inertia', 'name': 'centre', 'J': 0.03},
            {'type': 'spring', 'name': 'tube', 'stiffness': 2e4, 'damping': 3.0},
            {'type': 'inertia', 'name': 'centre_rear', 'J': 0.03},
            {'type': 'joint', 'name': 'rear', 'kind': 'hooke', 'fidelity': 'exact',
             'params': {'beta_deg': 12.0, 'phase_deg': 120.0, 'bend_plane_deg': 180.0,
                        'cross_angle_deg': 84.0}},
            {'type': 'inertia', 'name': 'b', 'J': 0.4}]})
    dl = Driveline.from_scene(sc, track_energy=True)
    comp = KernelStateOutputs(dl, ['front', 'rear'])
    ref = PythonStateOutputs(dl, ['front', 'rear'])
    assert comp._react_python == [1]
    rng = np.random.default_rng(33)
    for x, te, tl in _states(dl, rng):
        got, want = comp.joint_states(x, te, tl), ref.joint_states(x, te, tl)
        for g, w in zip(got, want):
            assert _rel(g, w) <= REL
        wg, ww = comp.wrenches(x, te, tl, got), ref.wrenches(x, te, tl, want)
        for j in ('front', 'rear'):
            assert _rel(wg[j], ww[j]) <= REL, (j, wg[j], ww[j])
