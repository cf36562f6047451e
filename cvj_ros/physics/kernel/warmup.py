"""Compile (or load) every compiled stepper of the driveline kernel once: ``python -m
cvj_ros.physics.kernel.warmup``.

Run by ``make test`` and ``make bench`` (which use every method), so no test node pays a
cold compile while its peers wait. ``make demo`` does not: a run compiles only the entry
points it calls, on first use (docs/solvers.md "First run"). With a warm cache it only loads.
Prints one line per method with the wall time and whether it compiled or loaded. The
clutch/gearbox/brake mode segment (kernel/segment_nb.py, chains and trees, every method) is
warmed after the outputs.

On a machine with two or more cores the cold compile runs in two processes sharing the
cache: this one compiles dopri5, dop853, rk4 and the mode segment, a child (``--methods``) the
Rosenbrock family, the four explicit pairs and the outputs (:data:`CHILD_METHODS`), about
equal halves of the compile time. numba writes every cache file
through a temporary file and a rename, so a file is never half written; what two processes
can race on is a function's index when both add a signature to it within the same
milliseconds (here only ``rhs``, compiled by both with the same signature at the start, and
``hermite_dense``, ~10 s apart). A lost index entry costs a recompile at that function's
first call from Python, never a wrong result: numba loads an entry only for its exact
signature. ``CVJ_WARMUP_SERIAL=1`` keeps it in one process.
"""
from __future__ import annotations

import os
import subprocess
import sys
import time

from cvj_ros.physics.kernel.stepper import KERNEL_METHODS

#: what the child process compiles when the warm-up runs in two processes (rodas3: rodas4's
#: functions, vern6-8: tsit5's, loaded; 'outputs': :func:`warm_outputs`)
CHILD_METHODS = ('ros2', 'rosenbrock', 'rodas4', 'rodas3', 'tsit5', 'vern6', 'vern7', 'vern8',
                 'outputs')
#: what ``--methods`` accepts beside the kernel's methods
PARTS = ('outputs',)


def tiny_scene():
    """A two-inertia driveline (engine inertia, spring, load inertia)."""
    from cvj_ros.physics.scene import parse_scene
    return parse_scene({
        'name': 'warmup', 'duration': 0.01, 'exchange_step': 0.001,
        'driveline': [{'type': 'inertia', 'name': 'a', 'J': 0.1},
                      {'type': 'spring', 'name': 's', 'stiffness': 1000.0, 'damping': 1.0},
                      {'type': 'inertia', 'name': 'b', 'J': 0.2}],
        'engine': {'model': 'linear', 'm1': 10.0, 'k1': 0.1},
        'load': {'model': 'constant', 'torque': 5.0}})


def tiny_model():
    """:func:`tiny_scene` as kernel data."""
    from cvj_ros.physics.driveline import Driveline
    from cvj_ros.physics.kernel.layout import build_model
    return build_model(Driveline.from_scene(tiny_scene()))


def warm(methods: tuple[str, ...] = KERNEL_METHODS, *, out=sys.stdout) -> float:
    """Compile or load each method's entry points (advance, step, dense, sample, land, the
    whole offline run of kernel/run_nb.py and, for the Rosenbrock methods, its kept call of
    kernel/kept_nb.py); returns the total wall time (s)."""
    import numpy as np

    from cvj_ros.physics.kernel import rhs_nb
    from cvj_ros.physics.kernel.layout import set_torque_inputs
    from cvj_ros.physics.kernel.stepper import KernelStepper
    from cvj_ros.physics.simulate import Simulation
    scene = tiny_scene()
    model = tiny_model()
    set_torque_inputs(model, t_k=0.0, Te=1.0, Tl=0.5)
    total = 0.0
    for method in methods:
        t0 = time.perf_counter()
        st = KernelStepper(method, rhs_nb.rhs, model.ip, model.fp.copy(), 0.0, model.x0,
                           rtol=1e-6, atol=1e-9, h=1e-4 if method in ('rk4', 'ros2') else None,
                           jac=rhs_nb.jac)
        st.advance_to(1e-3)
        st.step(2e-3)
        st.dense(0.5 * (st.t_old + st.t))
        st.sample(np.array([st.t, st.t + 1e-3]))
        st.land(np.array([st.t, st.t + 1e-3, st.t + 2e-3]), np.empty((3, model.x0.size)))
        sim = Simulation(scene, method=method)
        sim.run(0.002, sample_dt=0.001)   # the whole offline run (run_nb)
        sim.run(0.002, sample_dt=0.001, reuse_trace=True)   # kept: kept_nb (Rosenbrock)
        compile_s = st.compile_seconds + (sim.compile_seconds or 0.0)
        dt = time.perf_counter() - t0
        total += dt
        how = f'compiled in {compile_s:.1f} s' if compile_s else 'loaded'
        print(f'kernel {method}: {how} ({dt:.2f} s)', file=out)
    return total


def warm_outputs(*, out=sys.stdout) -> float:
    """Compile or load the outputs (kernel/outputs_nb.py): the coupling node's per-exchange
    joint_state_one and wrenches_one with every joint's reactions, a vehicle scene's
    (kernel/tree_outputs_nb.py: joint state, offline samples, right-hand side under
    outside wheel loads; kernel/tree_run_nb.py: an offline run's outputs), the offline trace's
    sample_outputs, fill_mid_samples and landing grid, the batched sweep's reduction, the
    monitor's window statistics and
    the engine node's map engine torque;
    returns the
    wall time (s)."""
    from cvj_ros.physics.driveline import Driveline
    from cvj_ros.physics.scene import parse_scene
    from cvj_ros.physics.state_outputs import KernelStateOutputs
    t0 = time.perf_counter()
    scene = parse_scene({
        'name': 'warmup_outputs', 'duration': 0.01, 'exchange_step': 0.001,
        'driveline': [{'type': 'inertia', 'name': 'a', 'J': 0.1},
                      {'type': 'joint', 'name': 'g', 'kind': 'gear', 'params': {'gear_ratio': 2.0}},
                      {'type': 'inertia', 'name': 'b', 'J': 0.2}],
        'engine': {'model': 'linear', 'm1': 10.0, 'k1': 0.1},
        'load': {'model': 'constant', 'torque': 5.0}})
    KernelStateOutputs(Driveline.from_scene(scene), ['g'])
    import numpy as np

    from cvj_ros.physics.kernel.outputs_nb import fill_mid_samples
    from cvj_ros.physics.simulate import Simulation
    Simulation(scene, method='dopri5').run(0.002, sample_dt=0.001)   # sample_outputs
    fill_mid_samples(np.zeros((1, 2)), np.zeros((1, 2)), np.zeros((0, 4), np.int64),
                     np.zeros(1))   # the offline trace's intermediate members
    from cvj_ros.physics.kernel import window_nb
    window_nb.warm()                  # the monitor's windows and bulk reading
    from cvj_ros.physics.kernel import grid_nb
    grid_nb.warm()                    # an offline run's landing grid
    from cvj_ros.physics.kernel import reduce_nb
    reduce_nb.warm()                  # the batched sweep's window and metrics
    from cvj_ros.physics.engine import engine_from_spec
    from cvj_ros.physics.kernel.sources_nb import CompiledMapEngineTorque
    CompiledMapEngineTorque(engine_from_spec({'model': 'map'}))   # engine_node's answers
    # a vehicle scene's joint state and its right-hand side under outside wheel loads
    from cvj_ros.physics.kernel.tree_wheel_rhs import CompiledWheelLoadRhs
    from cvj_ros.physics.scene import load_scene, shipped_scenes
    from cvj_ros.physics.state_outputs import TreeKernelStateOutputs
    from cvj_ros.physics.tree import TreeDriveline
    from cvj_ros.physics.kernel.tree_samples import TreeKernelSamples
    tree = TreeDriveline.from_scene(load_scene(shipped_scenes()['fwd_axle']))
    TreeKernelStateOutputs(tree, [])
    TreeKernelSamples(tree)         # an offline vehicle run's samples
    from cvj_ros.physics.kernel import tree_run_nb
    tree_run_nb.warm(tree)          # an offline vehicle run's outputs in one call
    tree.set_wheel_torques([0.0] * tree.n_wheel)
    CompiledWheelLoadRhs(tree).rhs(0.0, tree.x0, 0.0)
    dt = time.perf_counter() - t0
    print(f'kernel outputs: {dt:.2f} s', file=out)
    return dt


def warm_modes(*, out=sys.stdout) -> float:
    """Compile or load the clutch/gearbox/brake mode segments by 0.05 s runs of the shipped
    launch_clutch_chain (kernel/modes_nb.py) and launch_clutch (the vehicle tree,
    kernel/tree_modes_nb.py): one compiled segment (kernel/segment_nb.py) for both and for
    every method (the method is a run-time flag), with the modes' analytic Jacobians
    (modes_jac_nb, tree_modes_jac_nb) it calls; returns the wall time (s)."""
    from cvj_ros.physics.hybrid.from_scene import hybrid_simulation
    from cvj_ros.physics.kernel.modes import KernelHybridSimulation
    from cvj_ros.physics.kernel.tree_modes import KernelHybridTreeSimulation
    from cvj_ros.physics.scene import load_scene, shipped_scenes
    t0 = time.perf_counter()
    scene = load_scene(shipped_scenes()['launch_clutch_chain'])
    KernelHybridSimulation.from_reference(hybrid_simulation(scene, duration=0.05)).run()
    scene = load_scene(shipped_scenes()['launch_clutch'])
    KernelHybridTreeSimulation.from_reference(hybrid_simulation(scene, duration=0.05)).run()
    dt = time.perf_counter() - t0
    print(f'kernel modes: {dt:.2f} s', file=out)
    return dt


def main(argv: list[str] | None = None) -> int:
    """``warmup`` (everything; two processes on >= 2 cores) or ``warmup --methods a,b``
    (those methods, and the outputs when ``outputs`` is named: the child of the two-process
    warm-up). Exit status 1 when the
    child failed (its own output says why)."""
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ['--methods'] and len(argv) == 2:
        methods = tuple(m for m in argv[1].split(',') if m)
        unknown = [m for m in methods if m not in KERNEL_METHODS + PARTS]
        if unknown:
            print(f'warmup: --methods: unknown {", ".join(unknown)} (compiled: '
                  f'{", ".join(KERNEL_METHODS + PARTS)})', file=sys.stderr)
            return 2
        warm(tuple(m for m in methods if m in KERNEL_METHODS))
        if 'outputs' in methods:
            warm_outputs()
        return 0
    if argv:
        print('usage: python -m cvj_ros.physics.kernel.warmup [--methods M1,M2,..]',
              file=sys.stderr)
        return 2
    t0 = time.perf_counter()
    child = None
    if (os.cpu_count() or 1) >= 2 and os.environ.get('CVJ_WARMUP_SERIAL', '') != '1':
        # the cache's staleness check ran at this process's import (kernel/__init__), so the
        # child finds the stamp current and deletes nothing this process writes
        child = subprocess.Popen([sys.executable, '-m', 'cvj_ros.physics.kernel.warmup',
                                  '--methods', ','.join(CHILD_METHODS)])
        mine = tuple(m for m in KERNEL_METHODS if m not in CHILD_METHODS)
    else:
        mine = KERNEL_METHODS
    warm(mine)
    if child is None:
        warm_outputs()
    warm_modes()
    status = 0 if child is None else child.wait()
    how = 'one process' if child is None else 'two processes'
    if status != 0:
        print(f'kernel warm-up: the child compiling {", ".join(CHILD_METHODS)} exited {status}',
              file=sys.stderr)
        return 1
    print(f'kernel ready: {time.perf_counter() - t0:.1f} s ({how})', file=sys.stdout)
    return 0


if __name__ == '__main__':
    sys.exit(main())
