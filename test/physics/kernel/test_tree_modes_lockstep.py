"""The vehicle lockstep mode model on the compiled kernel (KernelHybridTreeLockstep) against
the Python reference (HybridTreeLockstep), both driven as the coupling node drives them:
launch_clutch's sampled command schedule (brake hold and release, clutch engagement, the
shift schedule's 1 -> 2 shift), the engine map evaluated on each backend's own joint states
at t_k and held over [t_k, t_(k+1)].

Each backend runs its own mesh, so the bounds are the free-running ones of
test_modes_lockstep.py: the same events, event times to 1e-8 s, shaft speeds relative to
the shaft's largest speed to 1e-6 (100 rtol), wheels exactly still while braked on both,
energy residuals at solver tolerance."""
from __future__ import annotations

import numpy as np
import pytest

from cvj_ros.nodes.command_plan import CommandPlan
from cvj_ros.physics.engine import engine_from_spec
from cvj_ros.physics.hybrid.lockstep import hybrid_lockstep
from cvj_ros.physics.hybrid.tree_lockstep import HybridTreeLockstep
from cvj_ros.physics.hybrid.tree_sim import HybridTreeSimulation
from cvj_ros.physics.scene import find_scene, load_scene

pytest.importorskip('numba')
from cvj_ros.physics.kernel.tree_modes_lockstep import KernelHybridTreeLockstep  # noqa: E402

H = 1e-3


def drive(hybrid, scene, duration: float) -> np.ndarray:
    """Joint-state speeds at t_0 .. t_(N-1) of ``hybrid`` driven as the loop drives it."""
    n = int(round(duration / H))
    plan = CommandPlan.from_scene(scene, 1_000_000, n)
    from cvj_ros.nodes.common import scene_dict
    engine = engine_from_spec(dict(scene_dict(scene)['engine']))
    out = []
    for k in range(n):
        row = dict(plan.at(k))
        if 'throttle' in row:
            engine.set_throttle(row['throttle'])
        hybrid.set_commands(clutch=row.get('clutch'), brake=row.get('brake'),
                            gear=None if 'gear' not in row else int(row['gear']))
        pos, vel, _eff = hybrid.joint_states()
        out.append(vel.copy())
        hybrid.advance((k + 1) * H, engine.torque(k * H, vel[0], pos[0]), 0.0)
    return np.array(out)


def _compare(duration: float, min_events: int, gear: int) -> None:
    scene = load_scene(find_scene('launch_clutch'))
    ref = hybrid_lockstep(scene, backend='python')
    ker = hybrid_lockstep(scene, backend='kernel')
    assert type(ref) is HybridTreeLockstep and type(ker) is KernelHybridTreeLockstep
    assert ker.backend == 'kernel'
    vp = drive(ref, scene, duration)
    vk = drive(ker, scene, duration)
    assert len(ref.events) == len(ker.events) >= min_events
    for a, b in zip(ref.events, ker.events):
        assert (a.element, a.before, a.after) == (b.element, b.before, b.after)
        assert abs(a.t - b.t) < 1e-8, (a, b)
    assert ref.mode_names() == ker.mode_names() and ker.gear() == gear
    scale = np.maximum(np.abs(vp).max(axis=0), 1.0)
    assert np.max(np.abs(vp - vk) / scale) < 1e-6
    wheel = ker.shaft_names.index('wheel_left')
    assert np.array_equal(vk[:, wheel] == 0.0, vp[:, wheel] == 0.0)
    assert abs(ker.energy_residual()) < 1e-7 and abs(ref.energy_residual()) < 1e-7


def test_brake_hold_and_release_in_lockstep() -> None:
    """2 s: both brakes stick at 0, are released, stick again and are released (8 events;
    in the loop the engine torque is held per exchange)."""
    _compare(2.0, 4, 1)


@pytest.mark.slow
def test_launch_clutch_in_lockstep_matches_the_reference() -> None:
    """4.5 s (~8 min under load, the reference's share): the clutch locks, the 1 -> 2 shift."""
    _compare(4.5, 9, 2)


def test_backend_choice() -> None:
    scene = load_scene(find_scene('launch_clutch'))
    auto = hybrid_lockstep(scene, backend='auto')
    assert type(auto) is KernelHybridTreeLockstep and auto.backend_fallback is None
    # every method with dense output runs mode scenes compiled
    for method in ('rodas3', 'rodas4', 'rosenbrock'):
        ros = hybrid_lockstep(scene, method=method, backend='auto')
        assert type(ros) is KernelHybridTreeLockstep and ros.backend_fallback is None


class _NoReuse(KernelHybridTreeLockstep):
    """The kernel lockstep with the reference's exchange path: no kept kinematics, walk or
    evaluation, ModeTree.from_state for every mode state, the Python fill_mid."""

    tree = HybridTreeSimulation.tree
    _eval = HybridTreeSimulation._eval
    _apply = HybridTreeSimulation._apply
    _now = HybridTreeLockstep._now
    joint_states = HybridTreeLockstep.joint_states


def _as_hybrid_lockstep(cls, scene):
    """``cls`` built as hybrid_lockstep builds the vehicle lockstep."""
    from cvj_ros.physics.hybrid.from_scene import hybrid_simulation
    from cvj_ros.physics.hybrid.lockstep import Commands
    sim = hybrid_simulation(scene)
    s = getattr(sim.schedule, 'base', sim.schedule)
    c0 = Commands(s.value('clutch', 0.0), s.value('brake', 0.0), s.gear(0.0))
    return cls(scene, sim.levels, commands=c0, shift=scene.shift_schedule,
               stall_speed=sim.stall_speed, method=sim.method, rtol=sim.rtol, atol=sim.atol,
               max_step=sim.max_step)


def _exchange_loop(hybrid, scene, n: int, on_step=None) -> list[bytes]:
    """The bytes of every joint state (position, velocity, effort) of ``drive``'s loop."""
    plan = CommandPlan.from_scene(scene, 1_000_000, n)
    from cvj_ros.nodes.common import scene_dict
    engine = engine_from_spec(dict(scene_dict(scene)['engine']))
    out = []
    for k in range(n):
        row = dict(plan.at(k))
        if 'throttle' in row:
            engine.set_throttle(row['throttle'])
        hybrid.set_commands(clutch=row.get('clutch'), brake=row.get('brake'))
        pos, vel, eff = hybrid.joint_states()
        out.append(pos.tobytes() + vel.tobytes() + eff.tobytes())
        if on_step is not None:
            on_step(k)
        hybrid.advance((k + 1) * H, engine.torque(k * H, vel[0], pos[0]), 0.0)
    return out


def test_reuse_gives_the_reference_exchange_path_bit_for_bit() -> None:
    """3 s of launch_clutch's loop (brakes held, released, the clutch ramped in and locked at
    ~2.69 s: the kept walk serves a stuck clutch): every joint state, event and the final
    mode state are the bytes of the same stepper without the reuse."""
    scene = load_scene(find_scene('launch_clutch'))
    fast = hybrid_lockstep(scene, backend='kernel')
    ref = _as_hybrid_lockstep(_NoReuse, scene)
    n = 3000
    a, b = _exchange_loop(fast, scene, n), _exchange_loop(ref, scene, n)
    assert fast.mode_names()['clutch'] == 'stuck' and len(fast.events) >= 5
    assert [e for e in fast.events] == [e for e in ref.events]
    assert a == b
    assert fast.state_vector().tobytes() == ref.state_vector().tobytes()
    assert fast.energy_residual() == ref.energy_residual()


def test_one_evaluation_per_exchange_while_the_commands_hold() -> None:
    """With the commands unchanged (the first second: brakes holding, clutch open), the joint
    state of t_(k+1) takes the settle's evaluation at t_(k+1): one ModeTree.evaluate per
    exchange, against two on the reference's path."""
    from cvj_ros.physics.hybrid.tree import ModeTree
    scene = load_scene(find_scene('launch_clutch'))
    fast = hybrid_lockstep(scene, backend='kernel')
    calls = [0]
    real = ModeTree.evaluate

    def counted(self, *args, **kwargs):
        calls[0] += 1
        return real(self, *args, **kwargs)

    counts = []
    ModeTree.evaluate = counted
    try:
        _exchange_loop(fast, scene, 300, on_step=lambda k: counts.append(calls[0]))
    finally:
        ModeTree.evaluate = real
    steady = np.diff(counts[100:])
    assert np.all(steady == 1), steady


@pytest.mark.parametrize('method', ['tsit5', 'vern6'])
def test_brake_hold_and_release_in_lockstep_on_tsit5_vern6(method: str) -> None:
    """launch_clutch's first 2 s in lockstep with tsit5 / vern6 on both backends (compiled,
    no fallback): the bounds of test_brake_hold_and_release_in_lockstep."""
    scene = load_scene(find_scene('launch_clutch'))
    ref = hybrid_lockstep(scene, method=method, backend='python')
    ker = hybrid_lockstep(scene, method=method, backend='auto')
    assert type(ker) is KernelHybridTreeLockstep and ker.backend_fallback is None
    vp = drive(ref, scene, 2.0)
    vk = drive(ker, scene, 2.0)
    assert len(ref.events) == len(ker.events) >= 4
    for a, b in zip(ref.events, ker.events):
        assert (a.element, a.before, a.after) == (b.element, b.before, b.after)
        assert abs(a.t - b.t) < 1e-8, (a, b)
    assert ref.mode_names() == ker.mode_names() and ker.gear() == 1
    scale = np.maximum(np.abs(vp).max(axis=0), 1.0)
    assert np.max(np.abs(vp - vk) / scale) < 1e-6
    wheel = ker.shaft_names.index('wheel_left')
    assert np.array_equal(vk[:, wheel] == 0.0, vp[:, wheel] == 0.0)
    assert abs(ker.energy_residual()) < 1e-7 and abs(ref.energy_residual()) < 1e-7
