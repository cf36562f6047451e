"""Where a vehicle-scene run's time goes (docs/benchmark.md, fwd_axle section).

Times the bench's own call (``bench.run_project``: ``Simulation.run(1.0, sample_dt=0.05)`` on
one Simulation) on a vehicle scene for a method and tolerance, and splits it into pieces
timed the same way (CPU time of this thread, min over CALLS calls, median of ROUNDS rounds):

- ``whole``: ``Simulation.run`` as the bench calls it (one landing call, then every
  sample's outputs in one compiled call);
- ``whole_py``: the same run with the outputs from Python per sample
  (``Simulation._run_python``: one landing call, then ``record`` below per sample), the
  path vehicle runs took before the compiled outputs;
- ``stepper``: making the run's stepper (``Simulation.make_stepper``, the model packed and
  copied);
- ``samples_build``: building the compiled sample walk (``TreeKernelSamples``);
- ``integ_loop``: the stepper reset and stepped to every landing by ``advance_to`` from
  Python (the run's integration);
- ``integ_land``: the same landings in one compiled call (``KernelStepper._land``);
- ``rhs``: the run's evaluations x the compiled rhs's ns per call in a compiled loop;
- ``record``: the per-sample outputs from Python (``TreeKernelSamples`` call,
  ``vehicle_speed``, the wheel channels: the path a run with a progress callback takes), of
  which ``energy``: ``TreeDriveline.energy_residual`` (Python);
- ``outputs``: every sample's outputs and the intermediate members in one compiled call
  (``kernel/tree_run_nb.tree_run_outputs``, what ``Simulation.run`` calls after the landing);
- ``expert``: numbalsoda ``dop853`` at the same tolerance on the same compiled rhs
  (``bench_expert.solve_expert``, 21 samples), and its evaluations.

    PYTHONPATH=. python scripts/tree_profile.py fwd_axle dopri5 1e-3 [ROUNDS]
"""
from __future__ import annotations

import sys

import numpy as np

from cvj_ros import bench, bench_expert
from cvj_ros.physics.kernel import entry_point
from cvj_ros.physics.kernel.layout import build_model
from cvj_ros.physics.kernel.tree_run_nb import tree_run_outputs
from cvj_ros.physics.kernel.tree_samples import TreeKernelSamples
from cvj_ros.physics.simulate import Simulation, landing_grid
from run_profile import _min_cpu, _rhs_loop   # scripts/ is on the path when run as a script


def profile(scene_name: str, solver: str, tol: float, rounds: int = 5,
            calls: int = 20) -> dict[str, float]:
    scene = bench.resolve_scene(scene_name)
    sim = Simulation(scene, method=solver, rtol=tol, atol=tol,
                     fidelity=bench.forced_levels(scene, 'exact'))
    horizon, dt = 1.0, 0.05
    tr = sim.run(horizon, sample_dt=dt)
    dl = sim.driveline
    x0 = dl.x0.copy()
    opts = sim._stepper_options(dt)
    times = sim._sample_times(horizon, dt)
    grid, rows = landing_grid(times, sim.breakpoints(float(times[-1])))
    stepper = sim.make_stepper(x0, horizon, **opts)
    samples = TreeKernelSamples(dl)
    XG = np.empty((grid.size, x0.size))
    XG[0] = x0
    stepper._land(grid, XG)
    X = XG[rows]
    m, n_sh = times.size, len(dl.shaft_names)
    pos, vel, eff = np.empty((m, n_sh)), np.empty((m, n_sh)), np.empty((m, n_sh))
    e0 = sim._initial_energy(x0)
    e_torque = sim.engine.torque

    def loop() -> None:
        stepper.reset(0.0, x0)
        for t in grid[1:].tolist():
            stepper.advance_to(t)

    def land() -> None:
        stepper.reset(0.0, x0)
        stepper._land(grid, XG)

    def record() -> None:
        for k in range(m):
            samples(float(times[k]), X[k], e_torque, e0, pos[k], vel[k], eff[k])
            dl.vehicle_speed(X[k])

    def energy() -> None:
        for k in range(m):
            dl.energy_residual(X[k], e0)

    plan = sim._tree_plan(horizon, dt, True)
    ch = np.empty((len(plan.channel_names), m))
    te, tl, res = np.empty(m), np.empty(m), np.empty(m)
    out_args = (times, XG, plan.rows, plan.model.ip, plan.model.fp, *plan.tables[:2], e0, pos,
                vel, eff, te, tl, res, ch, *plan.tables[2:])
    out_call = entry_point(tree_run_outputs, out_args)

    def outputs() -> None:
        out_call(*out_args)

    model = build_model(dl, engine=sim.engine, horizon=max(1.0, scene.duration))
    addr = bench_expert.expert_cfunc().address
    data = bench_expert.expert_data(model.ip, model.fp, x0.size)
    t_eval = np.linspace(0.0, 1.0, 21)

    def expert() -> None:
        bench_expert.solve_expert('dop853', addr, x0, t_eval, data, rtol=tol, atol=tol)

    expert()
    nfev_expert = int(bench_expert.solve_expert('dop853', addr, x0, t_eval, data, rtol=tol,
                                                atol=tol)[1])
    dy = np.empty(x0.size)
    ip, fp = sim.model.ip, sim.model.fp
    _rhs_loop(1, X, ip, fp, times, dy)
    nfev = int(tr.solver['nfev'])
    pieces = {'whole': lambda: sim.run(horizon, sample_dt=dt),
              'whole_py': lambda: sim._run_python(horizon, dt, 'land', None, True),
              'stepper': lambda: sim.make_stepper(x0, horizon, **opts),
              'samples_build': lambda: TreeKernelSamples(dl),
              'integ_loop': loop, 'integ_land': land, 'record': record, 'energy': energy,
              'outputs': outputs,
              'expert': expert}
    out: dict[str, list[float]] = {k: [] for k in (*pieces, 'rhs')}
    for _ in range(rounds):
        for k, fn in pieces.items():
            out[k].append(_min_cpu(fn, calls))
        out['rhs'].append(_min_cpu(lambda: _rhs_loop(20_000, X, ip, fp, times, dy), 5)
                          / 20_000 * nfev)
    med: dict[str, float] = {k: float(np.median(v)) * 1e6 for k, v in out.items()}
    med['nfev'] = nfev
    med['nfev_expert'] = nfev_expert
    med['rhs_ns'] = med['rhs'] * 1e3 / nfev
    return med


def main() -> None:
    scene, solver, tol = sys.argv[1], sys.argv[2], float(sys.argv[3])
    rounds = int(sys.argv[4]) if len(sys.argv) > 4 else 5
    med = profile(scene, solver, tol, rounds)
    print(f'{scene} {solver} tol={tol:g} (us): ' + ', '.join(
        f'{k} {v:.0f}' if isinstance(v, float) else f'{k} {v}' for k, v in med.items()))


if __name__ == '__main__':
    main()
