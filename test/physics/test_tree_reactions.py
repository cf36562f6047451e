"""Reaction wrenches of a vehicle scene's joints (TreeDriveline.reactions and the compiled
TreeKernelStateOutputs.wrenches) against an independent construction.

Independent construction: every section of the tree is walked backward as a chain is
(Driveline._walk's torque law, T_before = r (T_after + J qddot) per op) from its end torque
- a wheel's F_x r (the magic formula at the state's relaxed slip), a spring's torque from
its law at the twist between the two shafts, a differential's T_L + T_R at the side gears'
starts (the carrier passes their sum) - with every inertia's acceleration a central
difference of its JointState speed along the equations' flow (x +/- h xdot) and every
ratio r = omega_out/omega_in from the JointState. The joint's reactions are then its
model's ``reactions(phi_in, omega_in, T_in)``. Torque balance closes the walk: the root
section's start torque equals the engine torque, a spring's right section's the spring
torque.

Bounds: reactions vs the construction 1e-8 of max(1, |T_in|): the central difference
with h = 1e-6 s errs by ~h^2 qddddot (1e-12 relative) plus rounding ~1e-16 |omega| / h
(1e-8 rad/s^2 at 100 rad/s), times inertias <= 1 kg m^2 and ratios <= 5; the tripod's
roller forces scale the input torque by 1/r_m ~ 40. Measured: 8.7e-11 at worst (fwd_axle),
the engine-torque balance within 5e-9 N m of 140 N m. Compiled vs Python:
1e-12 relative (the compiled joint state is held to 1e-13 in test_tree_outputs.py, the
compiled reactions to the Python models in test_state_outputs.py).
"""
from __future__ import annotations

import numpy as np
import pytest

from cvj_ros.physics.joints.wrench import wrench_from_reactions
from cvj_ros.physics.scene import load_scene, shipped_scenes
from cvj_ros.physics.state_outputs import (PythonStateOutputs, TreeKernelStateOutputs,
                                           make_state_outputs)
from cvj_ros.physics.tree import TreeDriveline

VEHICLE_SCENES = ('fwd_axle', 'fwd_axle_split_mu', 'awd_4x4', 'rwd_propshaft')
T_ENGINE = 140.0
H = 1e-6


def _driveline(name: str) -> TreeDriveline:
    return TreeDriveline.from_scene(load_scene(shipped_scenes()[name]))


def _state(dl: TreeDriveline, seed: int) -> np.ndarray:
    """x0 with perturbed angles, rates and relaxed slips (springs twisted out of their gap)."""
    rng = np.random.default_rng(seed)
    x = dl.x0.copy()
    n = dl.n_dof
    x[:n] += rng.normal(0.0, 0.05, n)
    x[n:2 * n] += rng.normal(0.0, 3.0, n)
    x[2 * n:2 * n + dl.n_wheel] += rng.normal(0.0, 0.02, dl.n_wheel)
    return x


def _joint_state(dl: TreeDriveline, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    names, pos, vel, eff = dl.joint_states(x, T_ENGINE)
    return pos, vel, eff


def _independent_input_torques(dl: TreeDriveline, x: np.ndarray) -> tuple[dict[str, float], list[float]]:
    """Per joint: the torque entering it (N m) by the backward chain walk of the module
    docstring; and each section's start torque."""
    col = {s: i for i, s in enumerate(dl.shaft_names)}
    pos, vel, _eff = _joint_state(dl, x)
    xdot = dl.rhs(0.0, x, T_ENGINE)
    vel_p = _joint_state(dl, x + H * xdot)[1]
    vel_m = _joint_state(dl, x - H * xdot)[1]
    acc = (vel_p - vel_m) / (2.0 * H)
    wheels = dl.wheel_outputs(x)
    start = [0.0] * len(dl.sections)
    t_in: dict[str, float] = {}

    def first(s: int) -> str:
        name = dl.sections[s].names[0]
        return name if name in col else f'{name}_input'

    def last(s: int) -> str:
        name = dl.sections[s].names[-1]
        return name if name in col else f'{name}_output'

    for s in reversed(range(len(dl.sections))):
        sec = dl.sections[s]
        kind, idx = sec.end
        if kind == 'wheel':
            w = dl.wheels[idx]
            torque = wheels[w.name]['fx'] * w.tyre.radius
        elif kind == 'spring':
            law, left, right = dl.springs[idx]
            th = pos[col[last(left)]] - pos[col[first(right)]]
            thd = vel[col[last(left)]] - vel[col[first(right)]]
            torque = law.evaluate(th, thd)[0]
        elif kind == 'diff':
            d = dl.diffs[idx]
            torque = start[d.left] + start[d.right]
        else:
            torque = 0.0
        for (jv, fn), name in zip(reversed(sec.ops), reversed(sec.names)):
            if fn is None:      # an inertia: its shaft carries the section's name for it
                torque += jv * acc[col[name]]
            else:               # a joint or a differential's ring gear
                i_in, i_out = col[f'{name}_input'], col[f'{name}_output'] if f'{name}_output' in col \
                    else col[f'{name}_carrier']
                torque *= vel[i_out] / vel[i_in]
                t_in[name] = torque
        start[s] = torque
    return t_in, start


@pytest.mark.parametrize('name', VEHICLE_SCENES)
def test_reactions_equal_each_model_at_the_independently_walked_input_torque(name: str) -> None:
    dl = _driveline(name)
    col = {s: i for i, s in enumerate(dl.shaft_names)}
    joints = [j for j, m in dl.joint_models.items() if hasattr(m, 'reactions')]
    assert joints
    for seed in range(3):
        x = _state(dl, seed)
        pos, vel, _eff = _joint_state(dl, x)
        t_in, start = _independent_input_torques(dl, x)
        # torque balance: the root section starts with the engine torque
        assert start[0] == pytest.approx(T_ENGINE, rel=1e-8)
        got = dl.reactions(x, T_ENGINE)
        assert sorted(got) == sorted(joints)
        for j in joints:
            i = col[f'{j}_input']
            want = dl.joint_models[j].reactions(float(pos[i]), float(vel[i]), t_in[j])
            for key, value in want.items():
                assert got[j][key] == pytest.approx(value, rel=1e-8, abs=1e-8 * max(1.0, abs(t_in[j]))), \
                    (seed, j, key)


@pytest.mark.parametrize('name', VEHICLE_SCENES)
def test_spring_right_sections_start_with_the_spring_torque(name: str) -> None:
    """The other closure of the balance: the walk from the wheels reaches each spring with
    the torque the spring law gives (equations of motion consistent with the reactions)."""
    dl = _driveline(name)
    x = _state(dl, 7)
    col = {s: i for i, s in enumerate(dl.shaft_names)}
    pos, vel, _eff = _joint_state(dl, x)
    _t_in, start = _independent_input_torques(dl, x)
    assert dl.springs
    for law, left, right in dl.springs:
        a, b = dl.sections[left], dl.sections[right]
        end = a.names[-1] if a.names[-1] in col else f'{a.names[-1]}_output'
        begin = b.names[0] if b.names[0] in col else f'{b.names[0]}_input'
        spring = law.evaluate(pos[col[end]] - pos[col[begin]], vel[col[end]] - vel[col[begin]])[0]
        assert start[right] == pytest.approx(spring, rel=1e-8, abs=1e-8)


@pytest.mark.parametrize('name', VEHICLE_SCENES)
@pytest.mark.parametrize('outside', [False, True])
def test_compiled_wrenches_equal_the_python_reference(name: str, outside: bool) -> None:
    dl = _driveline(name)
    joints = [j for j, m in dl.joint_models.items() if hasattr(m, 'reactions')]
    if outside:
        dl.set_wheel_torques([30.0 - 20.0 * i for i in range(dl.n_wheel)])
    kernel = make_state_outputs(dl, joints, compiled=True)
    assert isinstance(kernel, TreeKernelStateOutputs)
    ref = PythonStateOutputs(dl, joints)
    for seed in range(4):
        x = _state(dl, seed)
        te = 120.0 * np.cos(seed)
        js = kernel.joint_states(x, te, 0.0)
        got = kernel.wrenches(x, te, 0.0, js)
        want = ref.wrenches(x, te, 0.0, ref.joint_states(x, te, 0.0))
        assert list(got) == list(want) == joints
        for j in joints:
            a, b = np.array(got[j]), np.array(want[j])
            assert np.all(np.abs(a - b) <= 1e-12 * np.maximum(1.0, np.abs(b))), (seed, j)
    dl.set_wheel_torques(None)


def test_every_branch_joint_has_a_housing_wrench_in_the_chain_convention() -> None:
    """fwd_axle: the gearbox and both halfshafts' tripods and Rzeppas answer, each as
    wrench_from_reactions makes a chain joint's."""
    dl = _driveline('fwd_axle')
    x = _state(dl, 3)
    ref = PythonStateOutputs(dl, list(dl.joint_models))
    out = ref.wrenches(x, T_ENGINE, 0.0, ref.joint_states(x, T_ENGINE, 0.0))
    assert set(out) == {'gearbox', 'tripod_left', 'rzeppa_left', 'tripod_right', 'rzeppa_right'}
    react = dl.reactions(x, T_ENGINE)
    for j, w in out.items():
        assert w == wrench_from_reactions(dl.joint_models[j].kind, react[j])
        assert all(np.isfinite(w[0])) and all(np.isfinite(w[1]))
