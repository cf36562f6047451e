"""The lockstep mode model on the compiled kernel (KernelHybridLockstep) against the Python
reference (HybridLockstep), both driven as the coupling node drives them: launch_clutch_chain's
sampled command schedule, the engine and road load evaluated on each backend's own joint
states at t_k and held over [t_k, t_(k+1)].

Each backend runs its own mesh (the kernel's step controller differs from the reference's
in the last bits, test_modes_kernel.py), so the bounds are the free-running ones of
test_modes_kernel.py: the same events, event times to 1e-8 s; shaft speeds relative to the
shaft's largest speed to 1e-6 (100 rtol; measured 1.5e-8 over these 6 s); energy residuals
at solver tolerance on both."""
from __future__ import annotations

import numpy as np
import pytest

from cvj_ros.errors import CvjError
from cvj_ros.nodes.command_plan import CommandPlan
from cvj_ros.physics.engine import engine_from_spec
from cvj_ros.physics.hybrid.lockstep import HybridLockstep, hybrid_lockstep
from cvj_ros.physics.load import load_from_spec
from cvj_ros.physics.scene import find_scene, load_scene

pytest.importorskip('numba')
from cvj_ros.physics.kernel.modes_lockstep import KernelHybridLockstep  # noqa: E402

H = 1e-3


def drive(hybrid: HybridLockstep, scene, duration: float) -> np.ndarray:
    """Joint-state speeds at t_0 .. t_(N-1) of ``hybrid`` driven as the loop drives it."""
    n = int(round(duration / H))
    plan = CommandPlan.from_scene(scene, 1_000_000, n)
    from cvj_ros.nodes.common import scene_dict
    spec = scene_dict(scene)
    engine = engine_from_spec(dict(spec['engine']))
    load = load_from_spec(spec['load'], seed=scene.seed)
    out = []
    for k in range(n):
        row = dict(plan.at(k))
        if 'throttle' in row:
            engine.set_throttle(row['throttle'])
        hybrid.set_commands(clutch=row.get('clutch'), brake=row.get('brake'),
                            gear=None if 'gear' not in row else int(row['gear']))
        pos, vel, _eff = hybrid.joint_states()
        out.append(vel.copy())
        t = k * H
        hybrid.advance((k + 1) * H, engine.torque(t, vel[0], pos[0]),
                       load.torque(t, vel[-1], pos[-1]))
    return np.array(out)


def test_launch_clutch_chain_in_lockstep_matches_the_reference() -> None:
    scene = load_scene(find_scene('launch_clutch_chain'))
    ref = hybrid_lockstep(scene, backend='python')
    ker = hybrid_lockstep(scene, backend='kernel')
    assert type(ref) is HybridLockstep and type(ker) is KernelHybridLockstep
    assert ker.backend == 'kernel' and ref.backend == 'python'
    vp = drive(ref, scene, 6.0)
    vk = drive(ker, scene, 6.0)
    assert len(ref.events) == len(ker.events) == 7   # brake hold, release, clutch lock, slip, shift 1-0-2, lock
    for a, b in zip(ref.events, ker.events):
        assert (a.element, a.before, a.after) == (b.element, b.before, b.after)
        assert abs(a.t - b.t) < 1e-8, (a, b)
    assert ref.mode_names() == ker.mode_names() and ref.gear() == ker.gear() == 2   # 2nd at 4.65 s
    scale = np.maximum(np.abs(vp).max(axis=0), 1.0)
    assert np.max(np.abs(vp - vk) / scale) < 1e-6
    assert abs(ker.energy_residual()) < 1e-7 and abs(ref.energy_residual()) < 1e-7


def test_backend_choice() -> None:
    scene = load_scene(find_scene('launch_clutch_chain'))
    auto = hybrid_lockstep(scene, backend='auto')
    assert type(auto) is KernelHybridLockstep and auto.backend_fallback is None
    # every method with dense output runs mode scenes compiled
    for method in ('rodas3', 'rodas4', 'rosenbrock'):
        ros = hybrid_lockstep(scene, method=method, backend='auto')
        assert type(ros) is KernelHybridLockstep and ros.backend_fallback is None
    with pytest.raises(CvjError, match='^backend: must be one of'):
        hybrid_lockstep(scene, backend='fast')


def _random_chain(seed: int):
    """test_modes_kernel's random chain and command schedule (structure, packs, grade)."""
    import importlib.util
    from pathlib import Path
    spec = importlib.util.spec_from_file_location(
        'modes_kernel_cases', Path(__file__).with_name('test_modes_kernel.py'))
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod._random_chain_sim(seed)()


@pytest.mark.parametrize('seed', range(12))
def test_random_chains_and_schedules_in_lockstep_match_the_reference(seed: int) -> None:
    """Fuzz: a random chain under 20 random command rows (refused gears, stalls included),
    2 s of 1 ms exchanges, the map engine and road load held per interval on each backend's
    own states: the same events and statuses, event times to 1e-8 s (the free-running bound
    above; measured 0-10 events per seed, times within 3.1e-9 s)."""
    from cvj_ros.physics.hybrid.lockstep import Commands
    sim = _random_chain(seed)
    sched = sim.schedule
    n = 2000
    plan = CommandPlan.from_schedule(sched, 1_000_000, n)
    c0 = Commands(sched.value('clutch', 0.0), sched.value('brake', 0.0), sched.gear(0.0))
    runs = []
    for cls in (HybridLockstep, KernelHybridLockstep):
        sim = _random_chain(seed)
        hl = cls(sim.chain, commands=c0, initial_speed=sim.initial_speed,
                 stall_speed=sim.stall_speed, method=sim.method, rtol=sim.rtol, atol=sim.atol)
        engine, load = sim.engine, sim.load
        for k in range(n):
            row = dict(plan.at(k))
            if 'throttle' in row:
                engine.set_throttle(row['throttle'])
            hl.set_commands(clutch=row.get('clutch'), brake=row.get('brake'),
                            gear=None if 'gear' not in row else int(row['gear']))
            pos, vel, _eff = hl.joint_states()
            t = k * H
            hl.advance((k + 1) * H, engine.torque(t, vel[0], pos[0]),
                       load.torque(t, vel[-1], pos[-1]))
            if hl.stall is not None:
                break
        runs.append(hl)
    ref, ker = runs
    assert [(e.element, e.before, e.after) for e in ref.events] == \
           [(e.element, e.before, e.after) for e in ker.events]
    dt = max((abs(a.t - b.t) for a, b in zip(ref.events, ker.events)), default=0.0)
    assert dt < 1e-8
    assert [s.split(' at t=')[0] for s in ref.statuses] == [s.split(' at t=')[0] for s in ker.statuses]
    assert (ref.stall is None) == (ker.stall is None)


@pytest.mark.parametrize('method', ['tsit5', 'vern6'])
def test_launch_clutch_chain_in_lockstep_on_tsit5_vern6(method: str) -> None:
    """The explicit pairs with interpolants run the lockstep model compiled too (no fallback
    to the reference): launch_clutch_chain's 6 s on both backends with ``method``, the bounds
    of the dopri5 case above (each backend its own mesh)."""
    scene = load_scene(find_scene('launch_clutch_chain'))
    ref = hybrid_lockstep(scene, method=method, backend='python')
    ker = hybrid_lockstep(scene, method=method, backend='auto')
    assert type(ker) is KernelHybridLockstep and ker.backend_fallback is None
    vp = drive(ref, scene, 6.0)
    vk = drive(ker, scene, 6.0)
    assert len(ref.events) == len(ker.events) == 7
    for a, b in zip(ref.events, ker.events):
        assert (a.element, a.before, a.after) == (b.element, b.before, b.after)
        assert abs(a.t - b.t) < 1e-8, (a, b)
    assert ref.mode_names() == ker.mode_names() and ref.gear() == ker.gear() == 2
    scale = np.maximum(np.abs(vp).max(axis=0), 1.0)
    assert np.max(np.abs(vp - vk) / scale) < 1e-6
    assert abs(ker.energy_residual()) < 1e-7 and abs(ref.energy_residual()) < 1e-7
