"""Work-precision benchmark (`cvj-sim bench`).

For each reference scene, each project solver (cvj_ros.physics.solvers via
cvj_ros.physics.simulate.Simulation: dopri5, dop853, rosenbrock adaptive over tolerances;
rk4 over fixed steps) and each joint fidelity (ideal / closed / exact forced on every joint
with springs elastic, 'auto' = the fidelity chooser's pick from the scene's accuracy
target, 'rigid' = exact joints with every spring rigid), with and without the work
integrals (``energy`` on / off), it measures

* wall seconds per simulated second (min of ``repeats`` runs, spread over ``passes`` passes
  of each scene's configurations; spread (max - min)/min),
* right-hand-side evaluations (and Jacobian evaluations),
* max relative error of the output (load) shaft speed, max |error| of its angle (rad),

against a reference: exact fidelity, elastic springs, dop853 at rtol = atol =
``reference_tol`` (100x tighter than the tightest tolerance benchmarked, at most 1e-10). In the same run the
*same equations* (``Simulation.fun``: the same Driveline rhs closed with the same engine and
load, exact fidelity) are solved by plain ``scipy.integrate.solve_ivp`` (RK45, LSODA, Radau;
default usage: one call over the horizon with ``t_eval`` = the sample grid, no Jacobian) as
the baseline, so every figure is a ratio measured side by side on the same machine.
Tolerances: rtol = atol = tol for both (states are rad and rad/s, and J for the work
integrals). Errors are measured on the same sample grid for every run. Simulation.run lands
exactly on every sample (solve_ivp interpolates), so the grid is kept coarse (``samples``
points per horizon, default 20 over 2 s) to keep landing from capping the step size.

A run that needs more than ``max_rhs_evals`` right-hand-side evaluations (an explicit method
on a stiff scene at a loose tolerance) or fails is recorded with ``ok = False`` and no error.

The lockstep study runs :class:`cvj_ros.physics.cosim.CoupledStepper` offline (no ROS) over
exchange steps and coupling schemes against the closed-loop reference, and compares the
loop's overhead per exchange with the measured rclpy round trips, in one process
(:func:`cvj_ros.nodes.roundtrip.measure_round_trip`) and across processes
(:func:`cvj_ros.nodes.roundtrip.measure_round_trip_ipc`), ratios side by side.
"""
from __future__ import annotations

import contextlib
import csv
import dataclasses
import itertools
import math
import os
import platform
import subprocess
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from cvj_ros.errors import CvjError, SceneError

REFERENCE_SCENES = ('kavz685_lever', 'fwd_halfshaft', 'cardan_truck', 'tripod_xiu2024', 'stiff',
                    'fwd_axle')
ADAPTIVE_SOLVERS = ('dopri5', 'dop853', 'rosenbrock', 'rodas4', 'rodas3', 'tsit5', 'vern6',
                    'vern7', 'vern8')
BASELINES = ('RK45', 'LSODA', 'Radau')
FIDELITY_MODES = ('ideal', 'closed', 'exact', 'auto', 'rigid')
ENERGY_MODES = ('on', 'off')   # project runs with / without the work integrals (track_energy)
COUPLING_SCHEMES = ('zoh', 'extrapolate', 'linear_implicit')
ERROR_LEVELS = (1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8)


@dataclass
class BenchConfig:
    """What to run. Times in s. ``scenes`` are shipped scene names, paths, or parsed
    :class:`cvj_ros.physics.scene.Scene` objects."""

    scenes: Sequence[Any] = REFERENCE_SCENES
    solvers: Sequence[str] = ADAPTIVE_SOLVERS + ('rk4',)
    tolerances: Sequence[float] = (1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9, 1e-10)
    rk4_steps: Sequence[float] = (1e-3, 3e-4, 1e-4, 3e-5)
    fidelities: Sequence[str] = FIDELITY_MODES
    energy: Sequence[str] = ENERGY_MODES  # 'off': every project configuration once more without
                                         # the work integrals (Simulation(track_energy=False))
    baselines: Sequence[str] = BASELINES
    horizon: float | None = 1.0          # s simulated per run (None: the scene's duration)
    samples: int = 20                    # sample points on the horizon (error grid)
    repeats: int = 5                     # at most; stop repeating once a config used repeat_budget_s
    repeat_budget_s: float = 3.0
    min_timed_s: float = 0.02            # short runs: repeat until their walls fill this (timeit's
    max_repeats: int = 200               # autorange), up to max_repeats; split over the passes
    passes: int = 2                      # the repeats of a scene's configs, spread over this many passes
    max_rhs_evals: int = 1_000_000
    exchange_steps: Sequence[float] = (1e-4, 2.5e-4, 1e-3, 2e-3, 5e-3, 1e-2)   # divide the horizon
    schemes: Sequence[str] = COUPLING_SCHEMES
    lockstep_scenes: Sequence[str] | None = ('kavz685_lever', 'fwd_halfshaft')   # None: first scene
    round_trip_n: int = 1000             # 0: skip the rclpy round-trip measurement
    real_lockstep: bool = False          # also time real `cvj-sim run` lockstep runs
    real_lockstep_runs: int = 2          # per scene and mode, alternating (the VM's minute moves them)
    studies: bool = False                # run `pytest -m slow` and append its summary
    startup: bool = False                # time the kernel's cold compile and a warm simulate
    compiled_baselines: bool = True      # also solve_ivp over the compiled rhs (expert baseline)
    mode_scenes: Sequence[str] = ()      # clutch/gearbox/brake scenes (cvj_ros.bench_modes:
                                         # kernel vs solve_ivp + events; `cvj-sim bench` sets them)
    expert_methods: Sequence[str] = ('lsoda', 'dop853')   # numbalsoda on the compiled rhs ('baseline_expert';
                                         # skipped with one line when numbalsoda is not installed)

    @classmethod
    def quick(cls) -> BenchConfig:
        """Reduced set that finishes in under two minutes on a 2-core machine."""
        return cls(scenes=('kavz685_lever', 'fwd_halfshaft'), solvers=('dopri5', 'dop853', 'rosenbrock', 'rk4'),
                   tolerances=(1e-3, 1e-5, 1e-7), rk4_steps=(1e-3, 2.5e-4),
                   fidelities=('exact', 'auto'), horizon=0.5, samples=10, repeats=3, repeat_budget_s=1.0,
                   max_rhs_evals=100_000, exchange_steps=(2.5e-4, 1e-3, 5e-3),
                   lockstep_scenes=('kavz685_lever',), round_trip_n=300)


@dataclass
class SceneProblem:
    """One scene prepared for benchmarking: the sample grid and the exact reference."""

    scene: Any
    horizon: float
    t_eval: np.ndarray
    ref_speed: np.ndarray
    ref_angle: np.ndarray
    ref_wall: float
    levels: dict[str, str] = field(default_factory=dict)      # fidelity mode -> 'name=level ...'
    aliases: dict[str, str] = field(default_factory=dict)     # mode -> earlier mode, same levels
    rhs_cost: dict[str, Any] = field(default_factory=dict)    # see rhs_cost()
    has_breakpoints: bool = False   # the load has breakpoints: adaptive runs also step across


class _BudgetExceeded(Exception):
    pass


def _counted(fun: Callable[[float, np.ndarray], np.ndarray], budget: int) -> Callable[..., np.ndarray]:
    """``fun`` that raises _BudgetExceeded after ``budget`` calls (same wrapper for every run)."""
    count = [0]

    def wrapped(t: float, x: np.ndarray) -> np.ndarray:
        count[0] += 1
        if count[0] > budget:
            raise _BudgetExceeded
        return fun(t, x)
    wrapped.count = count  # type: ignore[attr-defined]
    return wrapped


def resolve_scene(spec: Any) -> Any:
    """A Scene from a Scene object, a shipped scene name or a path (SceneError otherwise)."""
    from cvj_ros.physics.scene import Scene, find_scene, load_scene
    if isinstance(spec, Scene):
        return spec
    return load_scene(find_scene(str(spec)))


def forced_levels(scene: Any, mode: str) -> dict[str, str] | None:
    """Per-element overrides for fidelity ``mode``: every joint at ``mode`` where the joint
    has it (else its nearest richer level), every spring elastic; None for 'auto'. 'rigid':
    every joint at its richest level (as 'exact') and every spring rigid (its two sections
    one inertia, cvj_ros.physics.fidelity), a model without the drivetrain's torsional
    modes."""
    from cvj_ros.physics.joints import JOINTS
    from cvj_ros.physics.scene import Joint, Spring, iter_elements
    if mode == 'auto':
        return None
    order = ('ideal', 'closed', 'exact')
    joint_mode = 'exact' if mode == 'rigid' else mode
    out: dict[str, str] = {}
    for el in iter_elements(scene.driveline):     # a vehicle scene's branches too
        if isinstance(el, Joint):
            have = JOINTS[el.kind].fidelities
            level = next((lv for lv in order[order.index(joint_mode):] if lv in have), have[-1])
            out[el.name] = level
        elif isinstance(el, Spring):
            out[el.name] = 'rigid' if mode == 'rigid' else 'elastic'
    return out


def _levels_key(scene: Any, mode: str) -> str | None:
    """The per-element levels fidelity ``mode`` resolves to, as 'name=level ...' (None on error)."""
    from cvj_ros.physics.fidelity import choose_fidelity
    try:
        levels = choose_fidelity(scene, overrides=forced_levels(scene, mode)).levels
    except CvjError:
        return None
    return ' '.join(f'{k}={v}' for k, v in levels.items())


def _scene_for(scene: Any, *, h: float | None = None) -> Any:
    if h is None:
        return scene
    return dataclasses.replace(scene, solver=dataclasses.replace(scene.solver, h=h))


def _output(trace: Any) -> tuple[np.ndarray, np.ndarray]:
    """Output (last) shaft speed (rad/s) and angle (rad) of a Trace."""
    return trace.velocity[:, -1].copy(), trace.position[:, -1].copy()


def _errors(prob: SceneProblem, speed: np.ndarray, angle: np.ndarray) -> tuple[float, float]:
    scale = float(np.max(np.abs(prob.ref_speed))) or 1.0
    return (float(np.max(np.abs(speed - prob.ref_speed))) / scale,
            float(np.max(np.abs(angle - prob.ref_angle))))


def prepare(scene: Any, cfg: BenchConfig, *, reference_tol: float) -> SceneProblem:
    """Sample grid and the reference solution of ``scene`` (exact, elastic, dop853)."""
    from cvj_ros.physics.simulate import Simulation
    horizon = float(min(cfg.horizon, scene.duration) if cfg.horizon else scene.duration)
    sim = Simulation(scene, method='dop853', rtol=reference_tol, atol=reference_tol,
                     fidelity=forced_levels(scene, 'exact'))
    t0 = time.perf_counter()
    tr = sim.run(horizon, sample_dt=horizon / cfg.samples)
    wall = time.perf_counter() - t0
    speed, angle = _output(tr)
    return SceneProblem(scene=scene, horizon=horizon, t_eval=tr.t.copy(), ref_speed=speed,
                        ref_angle=angle, ref_wall=wall,
                        has_breakpoints=bool(sim.breakpoints(horizon).size))


def _time_runs(run_once: Callable[[], tuple[Any, int, int]], repeats: int,
               budget_s: float = math.inf, *, min_total_s: float = 0.0,
               max_repeats: int = 0) -> dict[str, Any]:
    """Call ``run_once`` up to ``repeats`` times (fewer once ``budget_s`` of wall time is
    used, at least once), then on while the walls sum to less than ``min_total_s``, up to
    ``max_repeats`` calls in all (timeit's autorange: a 0.1 ms run's minimum over 5 calls
    still carries the first calls' cold caches - measured 117-209 us against 100-175 us over
    30 for kavz685_lever; a 4 ms baseline run fills the time with its 5); wall time = min,
    spread = (max - min)/min."""
    walls: list[float] = []
    result: Any = None
    nfev = njev = 0
    while True:
        t0 = time.perf_counter()
        result, nfev, njev = run_once()
        walls.append(time.perf_counter() - t0)
        total = sum(walls)
        if total > budget_s:
            break
        if len(walls) >= repeats and (total >= min_total_s or len(walls) >= max_repeats):
            break
    w = min(walls)
    return {'result': result, 'wall_s': w, 'wall_spread': (max(walls) - w) / w if w > 0 else 0.0,
            'repeats': len(walls), 'nfev': nfev, 'njev': njev, 'walls': walls}


def _autorange(cfg: BenchConfig) -> dict[str, Any]:
    """Per pass: its share of ``cfg.min_timed_s`` and of ``cfg.max_repeats``."""
    passes = max(1, cfg.passes)
    return {'min_total_s': cfg.min_timed_s / passes,
            'max_repeats': max(1, math.ceil(cfg.max_repeats / passes))}


def _first_pass_repeats(cfg: BenchConfig) -> int:
    """Repeats in a configuration's first pass: ``cfg.repeats`` split over ``cfg.passes``."""
    return max(1, math.ceil(cfg.repeats / max(1, cfg.passes)))


def retime_passes(rows: list[dict[str, Any]], cfg: BenchConfig, *,
                  horizon: float) -> None:
    """Time every configuration of ``rows`` (one scene's, ok, with a kept ``_once``) again
    in ``cfg.passes - 1`` more passes over all of them, up to ``cfg.repeats`` runs each in
    all (more for a run shorter than ``cfg.min_timed_s`` over them, see :func:`_time_runs`);
    wall_s = the min, wall_spread over all runs. A configuration is thus timed at
    moments spread over the scene's whole run rather than within one second: this machine's
    speed drifts by up to 1.5x over minutes (docs/benchmark.md), and the ratios compare
    configurations timed at different moments. A failure in a later pass keeps the first
    pass's figures (the same run just succeeded)."""
    first = _first_pass_repeats(cfg)
    left = cfg.repeats - first
    for p in range(cfg.passes - 1):
        n = math.ceil(left / (cfg.passes - 1 - p)) if left > 0 else 0
        left -= n
        if n <= 0:
            break
        for r in rows:
            once = r.get('_once')
            if not r.get('ok') or once is None:
                continue
            try:
                extra = _time_runs(once, n, cfg.repeat_budget_s, **_autorange(cfg))
            except (_BudgetExceeded, CvjError, ArithmeticError, np.linalg.LinAlgError, ValueError):
                continue
            walls = r['_walls'] + extra['walls']
            w = min(walls)
            r.update(_walls=walls, wall_s=w, repeats=len(walls),
                     wall_spread=(max(walls) - w) / w if w > 0 else 0.0,
                     wall_per_sim_s=w / horizon)
    for r in rows:
        r.pop('_once', None)
        r.pop('_walls', None)


def run_project(prob: SceneProblem, *, solver: str, tol: float | None, h: float | None,
                fidelity: str, cfg: BenchConfig, breakpoints: bool = True,
                sampling: str = 'land', energy: bool = True) -> dict[str, Any]:
    """Time one project configuration: ``Simulation.run`` (the project's own path: persistent
    stepper landing on every sample - or with ``sampling='dense'`` reading the samples from
    the method's dense output, as solve_ivp's ``t_eval`` does - and, with ``breakpoints``, on
    every load breakpoint; joint states and energy residual per sample). Building the
    Simulation (fidelity choice, joint set-up) is not timed, for project and baseline alike;
    the runs after the first reuse its plan (``Simulation._run_kernel``: sample times,
    stepper) and write one Trace in place (``run(reuse_trace=True)``: the result of the last
    run is the one measured), as a user's repeated runs of one Simulation do. ``energy``
    False: the run without the work integrals (``Simulation(track_energy=False)``: 2 n_dof
    states, energy residual NaN; label suffix ' no-energy', CSV column energy = 'off')."""
    from cvj_ros.physics.simulate import Simulation
    scene = _scene_for(prob.scene, h=h)
    row: dict[str, Any] = {'scene': prob.scene.name, 'family': 'project', 'solver': solver,
                           'fidelity': fidelity, 'tol': tol, 'h': h, 'breakpoints': breakpoints,
                           'sampling': sampling, 'energy': 'on' if energy else 'off'}
    row['label'] = f'{solver} {fidelity}{_run_kind(row)}'
    tol_ = tol if tol is not None else 1e-6
    try:
        sim = Simulation(scene, method=solver, rtol=tol_, atol=tol_, fidelity=forced_levels(scene, fidelity),
                         track_energy=energy)
    except CvjError as exc:
        return {**row, 'ok': False, 'note': str(exc).splitlines()[0][:160]}
    row['levels'] = ' '.join(f'{k}={v}' for k, v in sim.fidelity_report.levels.items())
    plain_fun = sim.fun
    # the rhs budget: the Python backend calls sim.fun, counted; the kernel counts its own
    # evaluations (tr.solver['nfev'], checked after the run) and never calls sim.fun, so a
    # counting wrapper there would only add its set-up (~0.3 us) to a 17 us run's timing
    python_rhs = sim.backend == 'python'

    def once() -> tuple[Any, int, int]:
        if python_rhs:
            sim.fun = _counted(plain_fun, cfg.max_rhs_evals)
        tr = sim.run(prob.horizon, sample_dt=prob.horizon / cfg.samples, breakpoints=breakpoints,
                     sampling=sampling, reuse_trace=True)
        nfev = int(tr.solver['nfev'])
        if nfev > cfg.max_rhs_evals:    # the compiled path is not stopped midway: checked after
            raise _BudgetExceeded
        return tr, nfev, int(tr.solver.get('njev', 0))
    return _finish(row, prob, once, cfg)


def compiled_rhs_function(sim: Any, horizon: float) -> Callable[[float, np.ndarray], np.ndarray]:
    """What an expert writes for solve_ivp: the compiled driveline rhs (kernel/rhs_nb.py,
    engine and load inside, packed over ``horizon`` s as a run of that duration) behind a
    thin Python function ``f(t, y) -> dy``."""
    from cvj_ros.physics.kernel import rhs_nb
    from cvj_ros.physics.kernel.layout import build_model
    model = build_model(sim.driveline, engine=sim.engine, load=sim.load, horizon=horizon)
    rhs, ip, fp = rhs_nb.rhs, model.ip, model.fp
    rhs(0.0, model.x0.copy(), ip, fp, np.empty(model.n_state))   # compile / load outside the timing

    def fun(t: float, y: np.ndarray) -> np.ndarray:
        dy = np.empty(y.shape[0])
        rhs(t, y, ip, fp, dy)
        return dy
    return fun


def hooke_2dof_scene() -> Any:
    """The model of the hand-written reference rhs figure (25 ns): a 2-DOF engine-spring-Hooke-
    load driveline - linear engine, linear spring with damping, exact Hooke joint at 20 deg,
    constant load."""
    from cvj_ros.physics.scene import parse_scene
    return parse_scene({
        'name': 'hooke_2dof', 'duration': 1.0, 'exchange_step': 0.001,
        'engine': {'model': 'linear', 'm1': 100.0, 'k1': 0.5},
        'load': {'model': 'constant', 'torque': 20.0}, 'initial': {'speed_rad_s': 100.0},
        'driveline': [{'type': 'inertia', 'name': 'engine_shaft', 'J': 0.1},
                      {'type': 'spring', 'name': 'spring', 'stiffness': 1000.0, 'damping': 1.0},
                      {'type': 'joint', 'name': 'hooke', 'kind': 'hooke', 'fidelity': 'exact',
                       'params': {'beta_deg': 20.0}},
                      {'type': 'inertia', 'name': 'load_shaft', 'J': 0.2}]})


def rhs_cost(scene: Any, *, calls: int = 200_000) -> dict[str, float]:
    """Cost of one right-hand side (exact fidelity, engine and load inside): ns per call of
    the compiled rhs called from a compiled loop, us per call of the same rhs from Python
    (the solve_ivp wrapper) and of the Python reference rhs. Best of 3."""
    from cvj_ros.physics.kernel.outputs_nb import time_rhs_calls
    from cvj_ros.physics.simulate import Simulation
    sim = Simulation(scene, fidelity=forced_levels(scene, 'exact'))
    from cvj_ros.physics.kernel.layout import build_model
    model = build_model(sim.driveline, engine=sim.engine, load=sim.load)
    y = model.x0.copy()
    time_rhs_calls(10, 0.0, y, model.ip, model.fp)
    best = math.inf
    for _ in range(3):
        t0 = time.perf_counter()
        time_rhs_calls(calls, 0.001, y, model.ip, model.fp)
        best = min(best, (time.perf_counter() - t0) / calls)
    out = {'compiled_ns': best * 1e9}
    for key, fun, n in (('compiled_from_python_us', compiled_rhs_function(sim, 1.0), 20_000),
                        ('python_us', sim.fun, 2_000)):
        b = math.inf
        for _ in range(3):
            t0 = time.perf_counter()
            for _k in range(n):
                fun(0.001, y)
            b = min(b, (time.perf_counter() - t0) / n)
        out[key] = b * 1e6
    return out


HAND_WRITTEN = ('hooke_2dof', 'stiff', 'fwd_halfshaft')


def hand_written_rhs_cost(model_name: str = 'hooke_2dof', *, calls: int = 200_000,
                          rounds: int = 5, loop: str = 'chain', clock: str = 'cpu') -> dict[str, Any]:
    """ns per call of the kernel's rhs on ``model_name`` (:data:`HAND_WRITTEN`:
    :func:`hooke_2dof_scene`, the shipped stiff or fwd_halfshaft scene) and of the same equations
    written by hand (:mod:`cvj_ros.bench_handrhs`), timed in alternating rounds (each round's
    pair shares its moment); medians, min and max over the rounds, the median of the per-round
    ratios, and ``floor_ns``: the chain's own price (:func:`cvj_ros.bench_handrhs.time_null_chain`,
    included in both).

    ``loop`` 'chain' (what an integrator's stage pays: each rhs behind a call LLVM does not
    inline, the input z = y + h f of the call before; ``time_*_chain``) or 'cycle' (the
    16 states cycled, a small rhs inlined into the loop; ``time_*_calls``). ``clock`` 'cpu'
    (the timing thread's CPU time: a time slice lost to another process is not counted) or
    'wall' (perf_counter)."""
    from cvj_ros import bench_handrhs as hw
    from cvj_ros.physics.kernel.layout import build_model
    from cvj_ros.physics.simulate import Simulation
    models = {'hooke_2dof': (hw.hooke_2dof_params, hw.time_hooke_2dof_calls, hw.time_hooke_2dof_chain),
              'stiff': (hw.stiff_params, hw.time_stiff_calls, hw.time_stiff_chain),
              'fwd_halfshaft': (hw.fwd_halfshaft_params, hw.time_fwd_halfshaft_calls,
                                hw.time_fwd_halfshaft_chain)}
    if model_name not in models:
        raise ValueError(f'no hand-written rhs for {model_name!r} (have {", ".join(HAND_WRITTEN)})')
    if loop not in ('chain', 'cycle') or clock not in ('cpu', 'wall'):
        raise ValueError(f"loop must be 'chain' or 'cycle' and clock 'cpu' or 'wall', "
                         f"not {loop!r}, {clock!r}")
    scene = hooke_2dof_scene() if model_name == 'hooke_2dof' else resolve_scene(model_name)
    params, cycle_timer, chain_timer = models[model_name]
    sim = Simulation(scene, fidelity=forced_levels(scene, 'exact'))
    model = build_model(sim.driveline, engine=sim.engine, load=sim.load)
    ys = hw.timing_states(model.x0)
    p = params(scene)
    if loop == 'chain':
        def kernel(n: int) -> float:
            return hw.time_kernel_chain(n, 0.001, ys, hw.CHAIN_H, model.ip, model.fp)

        def hand(n: int) -> float:
            return chain_timer(n, 0.001, ys, hw.CHAIN_H, p)
    else:
        def kernel(n: int) -> float:
            return hw.time_kernel_calls(n, 0.001, ys, model.ip, model.fp)

        def hand(n: int) -> float:
            return cycle_timer(n, 0.001, ys, p)
    now = time.thread_time if clock == 'cpu' else time.perf_counter

    def per_call(fun: Any) -> float:
        t0 = now()
        fun(calls)
        return (now() - t0) / calls * 1e9

    def null(n: int) -> float:
        return hw.time_null_chain(n, 0.001, ys, hw.CHAIN_H, p)

    for fun in (kernel, hand, null):
        fun(10)
    kern, hnd, floor = [], [], []
    for _ in range(max(1, rounds)):
        kern.append(per_call(kernel))
        hnd.append(per_call(hand))
        if loop == 'chain':
            floor.append(per_call(null))
    out = {'kernel_ns': float(np.median(kern)), 'kernel_ns_min': min(kern), 'kernel_ns_max': max(kern),
           'hand_ns': float(np.median(hnd)), 'hand_ns_min': min(hnd), 'hand_ns_max': max(hnd),
           'ratio': float(np.median(np.array(kern) / np.array(hnd))), 'rounds': len(kern),
           'loop': loop, 'clock': clock}
    if floor:
        out['floor_ns'] = float(np.median(floor))
    return out


def _rhs_cost_or_note(scene: Any) -> dict[str, Any]:
    """:func:`rhs_cost`, or ``{'note': why}`` when the kernel cannot build the scene."""
    try:
        return rhs_cost(scene)
    except (CvjError, NotImplementedError) as exc:
        return {'note': str(exc).splitlines()[0][:160]}


def _rhs_cost_text(rc: dict[str, Any]) -> str:
    """The three per-call costs of :func:`rhs_cost` as report text."""
    return (f'compiled {rc["compiled_ns"]:.0f} ns per call from a compiled loop; '
            f'{rc["compiled_from_python_us"]:.2f} us per call from Python (the solve_ivp wrapper); '
            f'Python reference {rc["python_us"]:.1f} us per call.')


def run_baseline(prob: SceneProblem, *, method: str, tol: float, cfg: BenchConfig,
                 compiled: bool = False) -> dict[str, Any]:
    """Time plain solve_ivp on the same closed-loop equations (exact fidelity): one call over
    the horizon with ``t_eval``, no Jacobian (its default usage). ``compiled``: the rhs is the
    compiled kernel behind a thin Python function (family 'baseline_compiled'), else the
    Python reference ``Simulation.fun`` (family 'baseline', what a user writes)."""
    from scipy.integrate import solve_ivp

    from cvj_ros.physics.simulate import Simulation
    row: dict[str, Any] = {'scene': prob.scene.name,
                           'family': 'baseline_compiled' if compiled else 'baseline',
                           'solver': method, 'fidelity': 'exact', 'tol': tol, 'h': None,
                           'label': f'solve_ivp {method}' + (' + compiled rhs' if compiled else '')}
    try:
        sim = Simulation(prob.scene, fidelity=forced_levels(prob.scene, 'exact'))
        rhs_fun = compiled_rhs_function(sim, prob.horizon) if compiled else sim.fun
    except (CvjError, NotImplementedError) as exc:
        return {**row, 'ok': False, 'note': str(exc).splitlines()[0][:160]}
    dl = sim.driveline

    def once() -> tuple[Any, int, int]:
        fun = _counted(rhs_fun, cfg.max_rhs_evals)
        sol = solve_ivp(fun, (0.0, prob.horizon), dl.x0.copy(), method=method,
                        t_eval=prob.t_eval, rtol=tol, atol=tol)
        if not sol.success:
            raise CvjError(f'solve_ivp {method}: {sol.message}')
        return sol, int(sol.nfev), int(sol.njev)
    row = _finish(row, prob, once, cfg, output=lambda sol: _last_shaft(dl, sol.y.T))
    return row


def _last_shaft(dl: Any, states: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Speed (rad/s) and angle (rad) of the last JointState shaft (the Trace's last column,
    :func:`_output`) at each state: a chain's load shaft, a vehicle scene's last wheel."""
    if getattr(dl, 'is_tree', False):
        walked = [dl.joint_states_fast(x, 0.0) for x in states]
        return np.array([w[1][-1] for w in walked]), np.array([w[0][-1] for w in walked])
    return np.array([dl.load_state(x)[1] for x in states]), np.array([dl.load_state(x)[0] for x in states])


def run_expert(prob: SceneProblem, *, method: str, tol: float, cfg: BenchConfig,
               restart: bool = False) -> dict[str, Any]:
    """Time the expert baseline (family 'baseline_expert', :mod:`cvj_ros.bench_expert`):
    numbalsoda ``method`` ('lsoda' or 'dop853') on the compiled rhs (kernel/rhs_nb.rhs,
    engine and load inside, exact fidelity) through one cfunc, one call over the horizon
    with ``t_eval`` = the sample grid, rtol = atol = tol; ``restart``: one call per segment
    between the load's breakpoints (what an expert does at a piecewise load's knots)."""
    from cvj_ros import bench_expert as ex
    from cvj_ros.physics.kernel.layout import build_model
    from cvj_ros.physics.simulate import Simulation
    row: dict[str, Any] = {'scene': prob.scene.name, 'family': 'baseline_expert', 'solver': method,
                           'fidelity': 'exact', 'tol': tol, 'h': None, 'breakpoints': restart,
                           'label': f'numbalsoda {method}' + (' restart-at-breaks' if restart else '')}
    try:
        sim = Simulation(prob.scene, fidelity=forced_levels(prob.scene, 'exact'))
        dl = sim.driveline
        model = build_model(dl, engine=sim.engine, load=sim.load, horizon=prob.horizon)
        address = ex.expert_cfunc().address   # compiled or loaded outside the timing
        x0 = np.ascontiguousarray(dl.x0, dtype=float)
        data = ex.expert_data(model.ip, model.fp, x0.size)
        breaks = np.asarray(sim.breakpoints(prob.horizon), dtype=float) if restart else None
        ex.solve_expert(method, address, x0, np.array([0.0, 1e-6]), data, rtol=tol, atol=tol,
                        breaks=breaks)   # numbalsoda and the segment loop compiled outside the timing
    except (CvjError, NotImplementedError, ValueError) as exc:
        return {**row, 'ok': False, 'note': str(exc).splitlines()[0][:160]}
    ip, fp = model.ip, model.fp   # kept alive: data holds their addresses
    t_eval = np.ascontiguousarray(prob.t_eval, dtype=float)
    max_steps = max(1, cfg.max_rhs_evals // (12 if method == 'dop853' else 2))

    def once() -> tuple[Any, int, int]:
        _alive = (ip, fp)   # noqa: F841
        sol, nfev, ok = ex.solve_expert(method, address, x0, t_eval, data, rtol=tol, atol=tol,
                                        breaks=breaks, max_steps=max_steps)
        if nfev > cfg.max_rhs_evals:
            raise _BudgetExceeded
        if not ok:
            raise CvjError(f'numbalsoda {method}: integration failed (step limit or step size)')
        return sol, nfev, 0
    return _finish(row, prob, once, cfg, output=lambda sol: _last_shaft(dl, sol))


def _finish(row: dict[str, Any], prob: SceneProblem, once: Callable[[], tuple[Any, int, int]],
            cfg: BenchConfig, *, output: Callable[[Any], tuple[np.ndarray, np.ndarray]] = None) -> dict[str, Any]:
    try:
        timed = _time_runs(once, _first_pass_repeats(cfg), cfg.repeat_budget_s, **_autorange(cfg))
    except _BudgetExceeded:
        return {**row, 'ok': False, 'note': f'more than {cfg.max_rhs_evals} rhs evaluations'}
    except (CvjError, ArithmeticError, np.linalg.LinAlgError, ValueError) as exc:
        return {**row, 'ok': False, 'note': str(exc).splitlines()[0][:160]}
    res = timed.pop('result')
    walls = timed.pop('walls')
    speed, angle = (output or _output)(res)
    if not (np.all(np.isfinite(speed)) and np.all(np.isfinite(angle))):
        return {**row, 'ok': False, 'note': 'non-finite output'}
    e_speed, e_angle = _errors(prob, speed, angle)
    return {**row, **timed, 'ok': True, 'note': '',
            'wall_per_sim_s': timed['wall_s'] / prob.horizon,
            'err_speed_rel': e_speed, 'err_angle_rad': e_angle,
            '_once': once, '_walls': walls}   # for retime_passes, dropped there


# ---------------------------------------------------------------------------- Pareto


def pareto_front(rows: Sequence[dict[str, Any]], *, error_key: str = 'err_speed_rel',
                 cost_key: str = 'wall_per_sim_s') -> list[dict[str, Any]]:
    """Rows not dominated in (error, cost) (both lower is better), sorted by error."""
    ok = sorted((r for r in rows if r.get('ok')), key=lambda r: (r[error_key], r[cost_key]))
    front, best_cost = [], math.inf
    for r in ok:
        if r[cost_key] < best_cost:
            front.append(r)
            best_cost = r[cost_key]
    return front


def best_at_levels(rows: Sequence[dict[str, Any]], *, levels: Sequence[float] = ERROR_LEVELS,
                   error_key: str = 'err_speed_rel') -> list[dict[str, Any]]:
    """Per error level: the cheapest project row and the cheapest row of each baseline
    family reaching it, and the speedups (baseline cost / project cost)."""
    out = []
    for lv in levels:
        entry: dict[str, Any] = {'level': lv}
        for fam in ('project', 'baseline', 'baseline_compiled', 'baseline_expert'):
            cand = [r for r in rows if r.get('ok') and r['family'] == fam and r[error_key] <= lv]
            entry[fam] = min(cand, key=lambda r: r['wall_per_sim_s']) if cand else None
        p, b, bc = entry['project'], entry['baseline'], entry['baseline_compiled']
        entry['speedup'] = b['wall_per_sim_s'] / p['wall_per_sim_s'] if p and b else None
        entry['speedup_compiled'] = bc['wall_per_sim_s'] / p['wall_per_sim_s'] if p and bc else None
        be = entry['baseline_expert']
        entry['speedup_expert'] = be['wall_per_sim_s'] / p['wall_per_sim_s'] if p and be else None
        out.append(entry)
    return out


# ---------------------------------------------------------------------------- lockstep


def lockstep_study(prob: SceneProblem, cfg: BenchConfig) -> list[dict[str, Any]]:
    """Exchange step vs error and real-time factor per coupling scheme (offline, no ROS).

    The loop is the coupling node's: at each exchange t_k the engine and load torques (and
    slopes) are evaluated at the state x(t_k), then the CoupledStepper advances to t_k + H.
    Error: max relative output-speed error at the exchange points on the sample grid
    against the closed-loop reference. ``rtf`` = simulated time / wall time;
    ``us_per_exchange`` = wall time of one exchange (the loop's own compute).
    """
    try:
        from cvj_ros.physics.cosim import CoupledStepper
    except ImportError:
        return []
    from cvj_ros.physics.driveline import Driveline
    from cvj_ros.physics.engine import engine_from_spec
    from cvj_ros.physics.load import load_from_spec
    scene = prob.scene
    rows = []
    for H in cfg.exchange_steps:
        n_ex = int(round(prob.horizon / H))
        if n_ex < 1 or abs(n_ex * H - prob.horizon) > 1e-9 * prob.horizon:
            continue
        for scheme in cfg.schemes:
            row: dict[str, Any] = {'scene': scene.name, 'scheme': scheme, 'exchange_step': H}
            try:
                dl = Driveline.from_scene(scene, fidelity=forced_levels(scene, 'exact'))
                eng = engine_from_spec(scene.engine, field='engine')
                lod = load_from_spec(scene.load, seed=scene.seed, field='load')
                cs = CoupledStepper(dl, scheme=scheme, method=scene.solver.method,
                                    rtol=scene.solver.rtol, atol=scene.solver.atol, h=scene.solver.h)
                n = dl.n_dof
                x = dl.x0.copy()
                speeds = np.empty(n_ex + 1)
                angles = np.empty(n_ex + 1)
                phi_l, w_l = dl.load_state(x)
                speeds[0], angles[0] = w_l, phi_l
                t0 = time.perf_counter()
                for k in range(n_ex):
                    t = k * H
                    w_e, phi_e = float(x[n]), float(x[0])
                    te, se = eng.torque(t, w_e, phi_e), eng.slope(t, w_e, phi_e)
                    tl, sl = lod.torque(t, w_l, phi_l), lod.slope(t, w_l, phi_l)
                    x = np.asarray(cs.advance((k + 1) * H, te, tl, slope_engine=se, slope_load=sl))
                    phi_l, w_l = dl.load_state(x)
                    speeds[k + 1], angles[k + 1] = w_l, phi_l
                wall = time.perf_counter() - t0
            except (CvjError, ArithmeticError, ValueError) as exc:
                rows.append({**row, 'ok': False, 'note': str(exc).splitlines()[0][:160]})
                continue
            t_ex = np.arange(n_ex + 1) * H
            ref_w = np.interp(t_ex, prob.t_eval, prob.ref_speed)
            on_grid = np.isclose(np.mod(t_ex + 1e-12, prob.t_eval[1]), 0.0, atol=1e-9) | (t_ex == t_ex[-1])
            on_grid = on_grid if np.count_nonzero(on_grid) >= 2 else np.ones_like(on_grid)
            err = np.abs(speeds - ref_w)[on_grid]
            finite = bool(np.all(np.isfinite(speeds)))
            rows.append({**row, 'ok': finite,
                         'err_speed_rel': float(np.max(err)) / (float(np.max(np.abs(prob.ref_speed))) or 1.0)
                         if finite else None,
                         'rtf': prob.horizon / wall, 'us_per_exchange': 1e6 * wall / n_ex,
                         'note': '' if finite else 'non-finite state (unstable coupling)'})
    return rows


ROUND_TRIP_LABELS = {
    'events': 'in-process, events executor',
    'events2': 'in-process, 2 answering nodes (= engine + load pattern), events executor',
    'single': 'in-process, single-threaded executor',
    'events_ipc': 'inter-process (1 echo process), events executor',
    'events_ipc2': 'inter-process (2 echo processes = engine + load pattern), events executor',
}


def measure_rclpy_round_trip(n: int) -> dict[str, Any]:
    """rclpy publish/subscribe round trip (us): in one process with both executors
    (``events``, ``single``) and across processes with the events executor and one or two
    echo processes (``events_ipc``, ``events_ipc2``), or a note why not."""
    out: dict[str, Any] = {}
    if n <= 0:
        return {'note': 'skipped'}
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    try:
        from cvj_ros.nodes.roundtrip import (measure_round_trip, measure_round_trip_ipc,
                                             measure_round_trip_peers, run_dds_settings)
    except ImportError as exc:
        return {'note': f'unavailable: {exc}'}
    # every side of every round trip with the DDS settings of the run's node processes
    # (the Fast DDS profile applies only to a process's first participant)
    run_dds_settings()
    runs: dict[str, Callable[[], dict[str, Any]]] = {
        'events': lambda: measure_round_trip(n, 'events'),
        'events2': lambda: measure_round_trip_peers(n, 2),
        'single': lambda: measure_round_trip(n, 'single'),
        'events_ipc': lambda: measure_round_trip_ipc(n, 'events', echoes=1),
        'events_ipc2': lambda: measure_round_trip_ipc(n, 'events', echoes=2),
    }
    for key, run in runs.items():
        try:
            out[key] = run()
        except Exception as exc:  # rclpy set-up problems must not kill the benchmark
            out[key] = {'note': f'{type(exc).__name__}: {str(exc)[:120]}'}
    return out


def overhead_ratios(real: dict[str, Any], rt: dict[str, Any]) -> dict[str, float]:
    """Lockstep overhead per exchange (us) divided by each measured round trip's mean (us):
    ``{'events': ..., 'events_ipc2': ...}`` for the round trips that were measured."""
    out: dict[str, float] = {}
    over = real.get('overhead_us_mean')
    if not isinstance(over, (int, float)):
        return out
    for key, v in rt.items():
        if isinstance(v, dict) and isinstance(v.get('us_mean'), (int, float)) and v['us_mean'] > 0:
            out[key] = float(over) / float(v['us_mean'])
    return out


#: the round trip of the same topology per loop mode (overhead ratio)
MODE_ROUND_TRIP = {'separate': 'events_ipc2', 'composed': 'events2'}


def real_lockstep_run(scene_name: str, *, duration: float, timeout: float = 300.0,
                      composed: bool = False) -> dict[str, Any]:
    """Loop figures of a real ROS lockstep run (`cvj-sim run`: one process per loop node, or
    ``composed``: every node and the recorder in one process, ``--composed``).

    Reads the run's ``report.json``: the per-exchange wall time, lockstep wait, integration,
    state evaluation + publication and overhead = exchange wall - integration (us) of its
    ``loop_timing`` (the coupling node's last loop diagnostics), and the real-time factor the
    run's report prints (simulated time over the recorded loop's wall span), so the bench and
    `cvj-sim run` give the same figure. Returns ``{'note': ...}`` when the run is not
    possible here.
    """
    import json
    import tempfile
    exe = Path(sys.executable).with_name('cvj-sim')
    env = dict(os.environ)
    env.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    with tempfile.TemporaryDirectory() as tmp:
        cmd = [str(exe), 'run', scene_name, '--duration', str(duration), '--out', str(Path(tmp) / 'run')]
        if composed:
            cmd.append('--composed')
        t0 = time.perf_counter()
        try:
            r = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, env=env)
        except (OSError, subprocess.TimeoutExpired) as exc:
            return {'note': f'cvj-sim run failed: {exc}'}
        wall = time.perf_counter() - t0
        if r.returncode != 0:
            return {'note': f'cvj-sim run exited {r.returncode}: {(r.stderr or r.stdout).strip()[-200:]}'}
        try:
            rep = json.loads((Path(tmp) / 'run' / 'report.json').read_text())
        except (OSError, ValueError) as exc:
            return {'note': f'report.json unreadable: {exc}'}
    states = int((rep.get('counts') or {}).get('/driveline/joint_states', 1))
    out: dict[str, Any] = {'scene': scene_name, 'exchanges': max(1, states - 1),
                           'process_wall_s': wall, 'mode': 'composed' if composed else 'separate'}
    timing = (rep.get('metrics') or {}).get('loop_timing') or {}
    if 'overhead_us_mean' in timing:
        out.update({key: float(v) for key, v in timing.items()})
        out['real_time_factor'] = float(rep.get('real_time_factor') or 'nan')
    else:
        out['note'] = 'no coupling-node loop diagnostics in the run report'
    return out


def real_lockstep_runs(scenes: Sequence[str], *, runs: int = 2, duration: float = 5.0,
                       log: Callable[[str], None] = print) -> list[dict[str, Any]]:
    """:func:`real_lockstep_run` of every scene in both modes (separate, then composed),
    ``runs`` rounds, a round running every scene and mode once: pairs of one round ran in
    the same minute of a shared machine, whose speed moves real-time factors by ~1.4x
    (docs/nodes.md). Each result carries its ``round`` (1-based)."""
    out: list[dict[str, Any]] = []
    for r in range(1, max(1, int(runs)) + 1):
        for name in scenes:
            for mode in ('separate', 'composed'):
                log(f'[bench] real lockstep run {r}/{runs}: {name}, {mode}')
                res = real_lockstep_run(name, duration=duration, composed=mode == 'composed')
                res.setdefault('scene', name)
                res['mode'] = mode
                res['round'] = r
                out.append(res)
    return out


def real_lockstep_medians(real: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per (scene, mode), in first-seen order: runs, median and range of the real-time
    factor and median overhead per exchange (us) of the runs that finished."""
    groups: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for run in real:
        groups.setdefault((str(run.get('scene')), str(run.get('mode'))), []).append(run)
    out = []
    for (scene, mode), group in groups.items():
        ok = [g for g in group if isinstance(g.get('real_time_factor'), float)]
        rtf = sorted(g['real_time_factor'] for g in ok)
        over = [g['overhead_us_mean'] for g in ok if isinstance(g.get('overhead_us_mean'), float)]
        out.append({'scene': scene, 'mode': mode, 'runs': len(group), 'finished': len(ok),
                    'rtf_median': float(np.median(rtf)) if rtf else math.nan,
                    'rtf_min': rtf[0] if rtf else math.nan, 'rtf_max': rtf[-1] if rtf else math.nan,
                    'overhead_us_median': float(np.median(over)) if over else math.nan})
    return out


# ---------------------------------------------------------------------------- machine


def machine_description() -> dict[str, str]:
    """CPU model, cores, OS, Python, numpy and scipy versions."""
    import scipy
    cpu = platform.processor() or ''
    try:
        for line in Path('/proc/cpuinfo').read_text().splitlines():
            if line.startswith('model name'):
                cpu = line.split(':', 1)[1].strip()
                break
    except OSError:
        pass
    return {'cpu': cpu or 'unknown', 'cores': str(os.cpu_count()), 'os': platform.platform(),
            'python': platform.python_version(), 'numpy': np.__version__, 'scipy': scipy.__version__}


# ---------------------------------------------------------------------------- driver


CSV_FIELDS = ('scene', 'family', 'solver', 'fidelity', 'tol', 'h', 'label', 'ok', 'wall_s',
              'wall_spread', 'repeats', 'wall_per_sim_s', 'nfev', 'njev', 'err_speed_rel', 'err_angle_rad',
              'levels', 'breakpoints', 'sampling', 'note', 'energy')
LOCKSTEP_FIELDS = ('scene', 'scheme', 'exchange_step', 'ok', 'err_speed_rel', 'rtf', 'us_per_exchange', 'note')


def planned_runs(cfg: BenchConfig) -> int:
    """Upper bound of the solver runs :func:`run_bench` makes (fidelity modes that turn out
    to be the same model as an earlier one are skipped, so fewer may be made)."""
    fixed = sum(len(cfg.rk4_steps) for s in cfg.solvers if s in ('rk4', 'ros2'))
    adaptive = sum(len(cfg.tolerances) for s in cfg.solvers if s not in ('rk4', 'ros2'))
    families = 2 if cfg.compiled_baselines else 1
    experts = len(expert_methods_run(cfg))
    total = 0
    for scene in cfg.scenes:
        # adaptive runs: landing on the samples (and, on a load with breakpoints, once more
        # stepping across them) and dense sampling
        variants = 3 if _may_have_breakpoints(scene) else 2
        total += (len(cfg.fidelities) * len(cfg.energy) * (fixed + variants * adaptive)
                  + families * len(cfg.baselines) * len(cfg.tolerances)
                  + experts * (variants - 1) * len(cfg.tolerances))
    return total


def expert_methods_run(cfg: BenchConfig) -> tuple[str, ...]:
    """The numbalsoda methods the run times: ``cfg.expert_methods``, or none when numbalsoda
    is not importable (:func:`cvj_ros.bench_expert.unavailable_reason`)."""
    if not cfg.expert_methods:
        return ()
    from cvj_ros.bench_expert import unavailable_reason
    return () if unavailable_reason() else tuple(cfg.expert_methods)


def _quiet_if(on: bool) -> Any:
    """:func:`cvj_ros.bench_expert.quiet_stdout` when ``on`` (numbalsoda runs), else a no-op."""
    if not on:
        return contextlib.nullcontext()
    from cvj_ros.bench_expert import quiet_stdout
    return quiet_stdout()


def _may_have_breakpoints(scene: Any) -> bool:
    """Whether the scene's load spec names a model that lists breakpoints (its class
    overrides ``Load.breakpoints``; a list is a sum), read from the spec without building
    the loads."""
    try:
        from cvj_ros.physics.load import LOAD_MODELS, Load
        from cvj_ros.physics.scene import find_scene, load_scene
        sc = scene if hasattr(scene, 'load') else load_scene(find_scene(scene))
        specs = sc.load if isinstance(sc.load, list) else [sc.load]
        return any(LOAD_MODELS[sp['model']].breakpoints is not Load.breakpoints
                   for sp in specs if isinstance(sp, Mapping) and sp.get('model') in LOAD_MODELS)
    except Exception:    # an unreadable scene fails later, with its own message
        return True


def run_bench(cfg: BenchConfig, out_dir: str | Path, *, log: Callable[[str], None] = print,
              progress: Callable[[float], None] | None = None) -> dict[str, Any]:
    """Run the benchmark and write ``bench.csv``, ``lockstep.csv``, ``rhs.csv``, ``bench.md``
    and one ``wp_<scene>.png`` per scene to ``out_dir``. Returns the results (rows, tables, paths).
    ``progress``, if given, is called with the number of solver runs done (of
    :func:`planned_runs`) after each one."""
    from cvj_ros.plots import work_precision_plot
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    t_start = time.perf_counter()
    ref_tol = max(1e-13, min(min(cfg.tolerances) * 1e-2, 1e-10))
    rows: list[dict[str, Any]] = []
    lock_rows: list[dict[str, Any]] = []
    problems: dict[str, SceneProblem] = {}
    experts = expert_methods_run(cfg)
    if cfg.expert_methods and not experts:
        from cvj_ros.bench_expert import skip_line, unavailable_reason
        log(skip_line(unavailable_reason() or ''))
    if experts:
        from cvj_ros.bench_expert import expert_cfunc, skip_line
        try:
            expert_cfunc()
        except Exception as exc:   # an optional baseline never stops the bench (numba/numbalsoda mismatch)
            first = str(exc).splitlines()[0][:120] if str(exc) else type(exc).__name__
            log(skip_line(f'numbalsoda is installed but its cfunc did not compile ({first})',
                          install_hint=False))
            experts = ()
    # loop figures first (seconds), so partial reports of a long run carry them
    rt = measure_rclpy_round_trip(cfg.round_trip_n)
    lock_names = list(cfg.lockstep_scenes) if cfg.lockstep_scenes is not None else []
    lock_spec: str | None = lock_names[0] if lock_names else None   # what `cvj-sim run` is given
    if cfg.lockstep_scenes is None and cfg.scenes and isinstance(cfg.scenes[0], (str, os.PathLike)):
        lock_spec = str(cfg.scenes[0])
    real_specs = ([str(n) for n in cfg.lockstep_scenes] if cfg.lockstep_scenes is not None
                  else [lock_spec] if lock_spec else [])
    real = (real_lockstep_runs(real_specs, runs=cfg.real_lockstep_runs, log=log)
            if cfg.real_lockstep and real_specs else None)
    for i, spec in enumerate(cfg.scenes):
        scene = resolve_scene(spec)
        if cfg.lockstep_scenes is None and i == 0:
            lock_names.append(scene.name)
        log(f'[bench] {scene.name}: reference (dop853, rtol={ref_tol:g}, exact)')
        prob = prepare(scene, cfg, reference_tol=ref_tol)
        problems[scene.name] = prob
        seen_levels: dict[str, str] = {}
        for fid in cfg.fidelities:
            key = _levels_key(scene, fid)
            prob.levels[fid] = key or '?'
            if key is not None and key in seen_levels:   # same model as an earlier mode: not rerun
                prob.aliases[fid] = seen_levels[key]
                log(f'[bench] {scene.name}: fidelity {fid} = {seen_levels[key]} ({key}), not rerun')
                continue
            if key is not None:
                seen_levels[key] = fid
            for solver in cfg.solvers:
                grid = [(None, h) for h in cfg.rk4_steps] if solver in ('rk4', 'ros2') else \
                       [(tol, None) for tol in cfg.tolerances]
                for tol, h in grid:
                    # (breakpoints, sampling): landing on samples and breakpoints; stepping
                    # across the breakpoints; dense sampling (adaptive methods only)
                    variants = [(True, 'land')]
                    if tol is not None:
                        variants += [(False, 'land')] if prob.has_breakpoints else []
                        variants += [(True, 'dense')]
                    for (breaks, sampling), energy in itertools.product(variants, cfg.energy):
                        rows.append(run_project(prob, solver=solver, tol=tol, h=h, fidelity=fid,
                                                cfg=cfg, breakpoints=breaks, sampling=sampling,
                                                energy=energy == 'on'))
                        if progress is not None:
                            progress(len(rows))
        for compiled in ((False, True) if cfg.compiled_baselines else (False,)):
            for method in cfg.baselines:
                for tol in cfg.tolerances:
                    rows.append(run_baseline(prob, method=method, tol=tol, cfg=cfg, compiled=compiled))
                    if progress is not None:
                        progress(len(rows))
        with _quiet_if(bool(experts)):
            for method in experts:
                for tol in cfg.tolerances:
                    for restart in ((False, True) if prob.has_breakpoints else (False,)):
                        rows.append(run_expert(prob, method=method, tol=tol, cfg=cfg, restart=restart))
                        if progress is not None:
                            progress(len(rows))
            retime_passes([r for r in rows if r['scene'] == scene.name], cfg, horizon=prob.horizon)
        prob.rhs_cost = _rhs_cost_or_note(scene)
        log(f'[bench] {scene.name}: {sum(1 for r in rows if r["scene"] == scene.name)} runs')
        if scene.name in lock_names and not scene.is_tree:   # the lockstep loop carries chains
            lock_rows += lockstep_study(prob, cfg)
        # partial report after every scene: an interrupted long run keeps what it measured
        _write_outputs(out, cfg, rows, lock_rows, problems, rt, real, None,
                       time.perf_counter() - t_start, ref_tol, work_precision_plot, partial=True)
    modes: list[dict[str, Any]] = []
    if cfg.mode_scenes:
        from cvj_ros.bench_modes import KERNEL_METHODS, mode_study, write_mode_outputs
        for name in cfg.mode_scenes:
            mode_experts = tuple(cfg.expert_methods)
            modes.append(mode_study(name, tolerances=tuple(cfg.tolerances) + (1e-11,),
                                    samples=cfg.samples, log=log, kernel_methods=KERNEL_METHODS,
                                    expert_methods=mode_experts + tuple(m + '-bisect' for m in mode_experts)))
            for e in modes[-1]['levels']:
                sp = f"{e['speedup']:.1f}x" if e['speedup'] else 'not reached by both'
                ex = (f"; vs numbalsoda (oracle events) {e['speedup_expert']:.2f}x"
                      if e.get('speedup_expert') else '')
                log(f"[bench] {name}: error level {e['level']:g}: kernel vs solve_ivp + events {sp}{ex}")
        mode_paths = write_mode_outputs(modes, out)
    rhs_reference = _rhs_cost_or_note(hooke_2dof_scene())
    if 'compiled_ns' in rhs_reference:
        rhs_reference['hand'] = {name: hand_written_rhs_cost(name) for name in HAND_WRITTEN}
    studies = run_studies() if cfg.studies else None
    startup = kernel_startup() if cfg.startup else None
    duration = time.perf_counter() - t_start
    paths = _write_outputs(out, cfg, rows, lock_rows, problems, rt, real, studies, duration, ref_tol,
                           work_precision_plot, startup=startup, rhs_reference=rhs_reference,
                           modes=modes)
    if modes:
        paths = [*mode_paths, *paths]     # the report (bench.md) stays last
    log(f'[bench] done in {duration:.1f} s; wrote {", ".join(str(p) for p in paths)}')
    return {'modes': modes, 'rows': rows, 'lockstep': lock_rows, 'round_trip': rt, 'real_lockstep': real,
            'startup': startup, 'rhs_reference': rhs_reference, 'duration_s': duration, 'paths': paths, 'reference_tol': ref_tol,
            'tables': {name: best_at_levels([r for r in rows if r['scene'] == name]) for name in problems}}


def kernel_startup(*, warm_runs: int = 3, timeout: float = 1800.0) -> dict[str, Any]:
    """The kernel's start-up in fresh interpreters: the cold compile of every
    method and the outputs (``python -m cvj_ros.physics.kernel.warmup`` with an empty
    NUMBA_CACHE_DIR; what the first ``make`` pays), and the whole command
    ``cvj-sim simulate kavz685_lever --duration 2`` on the warm cache (target <= 1.5 s),
    median and min of ``warm_runs``. Wall seconds; ``{'note': ...}`` when not possible."""
    import tempfile
    exe = Path(sys.executable).with_name('cvj-sim')
    out: dict[str, Any] = {}
    with tempfile.TemporaryDirectory() as tmp:
        env = dict(os.environ, NUMBA_CACHE_DIR=str(Path(tmp) / 'numba'))
        t0 = time.perf_counter()
        try:
            r = subprocess.run([sys.executable, '-m', 'cvj_ros.physics.kernel.warmup'], env=env,
                               capture_output=True, text=True, timeout=timeout)
        except (OSError, subprocess.TimeoutExpired) as exc:
            return {'note': f'cold compile failed: {exc}'}
        if r.returncode != 0:
            return {'note': f'cold compile exited {r.returncode}: {(r.stderr or r.stdout).strip()[-200:]}'}
        out['cold_compile_s'] = time.perf_counter() - t0
        ready = [ln for ln in (r.stdout or '').splitlines() if ln.startswith('kernel ready')]
        if ready and '(' in ready[-1]:
            out['cold_compile_how'] = ready[-1].rsplit('(', 1)[1].rstrip(')')   # 'two processes'
        walls = []
        for _ in range(max(1, warm_runs)):   # the same (now warm) cache directory
            t0 = time.perf_counter()
            try:
                r = subprocess.run([str(exe), 'simulate', 'kavz685_lever', '--duration', '2'],
                                   env=env, capture_output=True, text=True, timeout=timeout)
            except (OSError, subprocess.TimeoutExpired) as exc:
                return {**out, 'note': f'warm simulate failed: {exc}'}
            if r.returncode != 0:
                return {**out, 'note': f'warm simulate exited {r.returncode}'}
            walls.append(time.perf_counter() - t0)
    out.update(warm_simulate_s_median=float(np.median(walls)), warm_simulate_s_min=min(walls),
               warm_runs=len(walls))
    return out


def run_studies(timeout: float = 3600.0) -> dict[str, Any]:
    """Run the repository's slow studies (`pytest -m slow`) and keep the summary line."""
    root = Path(__file__).resolve().parents[1]
    try:
        r = subprocess.run([sys.executable, '-m', 'pytest', '-m', 'slow', '-q', 'test'], cwd=root,
                           capture_output=True, text=True, timeout=timeout)
    except (OSError, subprocess.TimeoutExpired) as exc:
        return {'summary': f'failed to run: {exc}'}
    lines = [ln for ln in r.stdout.strip().splitlines() if ln.strip()]
    return {'returncode': r.returncode, 'summary': lines[-1] if lines else '(no output)'}


def _g(x: Any, fmt: str = '.3g') -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return '-'
    return format(x, fmt)


def _config_label(r: dict[str, Any] | None) -> str:
    if r is None:
        return '-'
    knob = f'h={_g(r["h"])}' if r.get('h') else f'tol={_g(r["tol"], ".0e")}'
    if r['family'] == 'baseline_expert':
        restart = r.get('breakpoints') in (True, 'True')
        return f'numbalsoda {r["solver"]} {knob}' + (' restart-at-breaks' if restart else '')
    if r['family'] != 'project':
        return f'{r["solver"]} {knob}'
    return f'{r["solver"]} {r["fidelity"]} {knob}{_run_kind(r)}'


def _run_kind(r: dict[str, Any]) -> str:
    """A project row's label suffix: ' across-breaks' (stepping across the load's
    breakpoints), ' dense' (dense sampling), or '' (landing on samples and breakpoints), then
    ' no-energy' for a run without the work integrals; rows read back from the CSV hold the
    flags as strings (a CSV from before the energy column: all 'on')."""
    across = '' if r.get('breakpoints', True) in (True, 'True', '') else ' across-breaks'
    return (across + (' dense' if r.get('sampling') == 'dense' else '')
            + (' no-energy' if r.get('energy') == 'off' else ''))


def _real_lockstep_lines(real: Sequence[dict[str, Any]], rt: dict[str, Any]) -> list[str]:
    """bench.md lines of the real `cvj-sim run` lockstep runs: one table row per run (wall,
    integration, wait, state, overhead per exchange, the overhead over the round trip of
    the same topology, real-time factor against its target), then the median per scene
    and mode."""
    if not real:
        return []
    from cvj_ros.orchestrate.report import REAL_TIME_TARGETS   # the loop's real-time targets
    md = ['', 'Real lockstep runs (`cvj-sim run SCENE --duration 5`, 1 ms exchange step; separate = '
          'one process per loop node, the monitor beside the recorder; composed = `--composed`, one '
          'process). Overhead = exchange wall - integration; its ratio is to the round trip of the '
          'same topology measured above (separate: inter-process 2-peer, composed: in-process '
          '2-peer; aim <= 1.5x). Targets: separate >= 2x, composed >= 10x real time.', '',
          '| round | scene | mode | us/exchange | integration us | lockstep wait us | state us | '
          'overhead us | overhead / round trip | real-time factor (target) |',
          '| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |']
    for run in real:
        mode = str(run.get('mode'))
        head = f'| {run.get("round", 1)} | {run.get("scene", "?")} | {mode} |'
        if 'overhead_us_mean' not in run:
            md.append(f'{head} {run.get("note", "no loop figures")} | | | | | | |')
            continue
        key = MODE_ROUND_TRIP.get(mode, '')
        ratio = overhead_ratios(run, {key: rt[key]} if key in rt else {}).get(key)
        ratio_text = (f'{ratio:.2f}x ({rt[key]["us_mean"]:.0f} us)' if ratio is not None
                      else 'n/a (round trip not measured)')
        target = REAL_TIME_TARGETS.get(mode, math.nan)
        md.append(f'{head} {run.get("exchange_wall_us_mean", math.nan):.0f} | '
                  f'{run.get("integration_us_mean", math.nan):.0f} | '
                  f'{run.get("lockstep_wait_us_mean", math.nan):.0f} | '
                  f'{run.get("state_us_mean", math.nan):.0f} | {run["overhead_us_mean"]:.0f} | '
                  f'{ratio_text} | {run.get("real_time_factor", math.nan):.3g} (>= {target:g}) |')
    md.append('')
    for m in real_lockstep_medians(real):
        target = REAL_TIME_TARGETS.get(m['mode'], math.nan)
        if not m['finished']:
            md.append(f'- {m["scene"]}, {m["mode"]}: no run finished ({m["runs"]} tried)')
            continue
        met = 'met' if m['rtf_min'] >= target else ('median met' if m['rtf_median'] >= target
                                                      else 'not met')
        md.append(f'- {m["scene"]}, {m["mode"]}: real-time factor median {m["rtf_median"]:.3g} '
                  f'(range {m["rtf_min"]:.3g}-{m["rtf_max"]:.3g} over {m["finished"]} runs), target '
                  f'>= {target:g}: {met}; overhead median {m["overhead_us_median"]:.0f} us per exchange')
    return md


def _write_outputs(out: Path, cfg: BenchConfig, rows: list[dict[str, Any]], lock_rows: list[dict[str, Any]],
                   problems: dict[str, SceneProblem], rt: dict[str, Any],
                   real: list[dict[str, Any]] | None,
                   studies: dict[str, Any] | None, duration: float, ref_tol: float,
                   plot: Callable[..., Path], *, partial: bool = False,
                   startup: dict[str, Any] | None = None,
                   rhs_reference: dict[str, Any] | None = None,
                   modes: Sequence[dict[str, Any]] = ()) -> list[Path]:
    paths = []
    p = out / 'bench.csv'
    with p.open('w', newline='') as fh:
        w = csv.DictWriter(fh, fieldnames=CSV_FIELDS, extrasaction='ignore')
        w.writeheader()
        for r in rows:
            w.writerow({k: r.get(k, '') for k in CSV_FIELDS})
    paths.append(p)
    p = out / 'lockstep.csv'
    with p.open('w', newline='') as fh:
        w = csv.DictWriter(fh, fieldnames=LOCKSTEP_FIELDS, extrasaction='ignore')
        w.writeheader()
        for r in lock_rows:
            w.writerow({k: r.get(k, '') for k in LOCKSTEP_FIELDS})
    paths.append(p)
    for name in problems:
        paths.append(plot([r for r in rows if r['scene'] == name], scene=name, path=out / f'wp_{name}.png'))
    if lock_rows:
        from cvj_ros.plots import lockstep_plot
        paths.append(lockstep_plot(lock_rows, path=out / 'lockstep.png'))
    md = ['# cvj_ros work-precision benchmark', '',
          ('PARTIAL REPORT (run still going or interrupted): ' if partial else '')
          + f'Run: {time.strftime("%Y-%m-%d %H:%M:%S")}, total {duration:.1f} s wall; '
          f'horizon {cfg.horizon if cfg.horizon else "scene duration"} s, {cfg.samples} samples, '
          f'{cfg.repeats} repeat(s) over {cfg.passes} pass(es) of each scene (min taken), reference dop853 rtol = atol = {ref_tol:g}, exact fidelity.', '',
          '## Machine', '']
    md += [f'- {k}: {v}' for k, v in machine_description().items()]
    if cfg.expert_methods and not expert_methods_run(cfg):
        from cvj_ros.bench_expert import skip_line, unavailable_reason
        md += ['', skip_line(unavailable_reason() or '').removeprefix('[bench] ')]
    from cvj_ros.bench_report import summary_lines, write_rhs_csv
    rhs = {name: prob.rhs_cost for name, prob in problems.items() if prob.rhs_cost}
    paths.append(write_rhs_csv(out / 'rhs.csv', rhs))
    md += ['', '## Speedups per error level against each baseline family', '',
           'Best project configuration against the best of each family reaching the level '
           '(`cvj-sim bench --report DIR` rebuilds this from DIR/bench.csv).', '']
    md += summary_lines(rows, {k: v['compiled_ns'] for k, v in rhs.items() if 'compiled_ns' in v})
    for name, prob in problems.items():
        srows = [r for r in rows if r['scene'] == name]
        md += ['', f'## {name}', '',
               f'Horizon {prob.horizon:g} s; reference took {prob.ref_wall:.2f} s. '
               f'Error = max relative error of the output-shaft speed; cost = wall s per simulated s.', '',
               '| error level | best project config | cost | best solve_ivp (Python rhs) | cost | speedup '
               '| best solve_ivp (compiled rhs) | cost | speedup | best numbalsoda (compiled rhs) | cost '
               '| speedup |',
               '| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |']
        for e in best_at_levels(srows):
            pr, bl, bc, be = e['project'], e['baseline'], e['baseline_compiled'], e['baseline_expert']
            md.append(f'| {e["level"]:.0e} | {_config_label(pr)} | {_g(pr and pr["wall_per_sim_s"])} | '
                      f'{_config_label(bl)} | {_g(bl and bl["wall_per_sim_s"])} | '
                      f'{_g(e["speedup"], ".2f") + "x" if e["speedup"] else "-"} | '
                      f'{_config_label(bc)} | {_g(bc and bc["wall_per_sim_s"])} | '
                      f'{_g(e["speedup_compiled"], ".2f") + "x" if e["speedup_compiled"] else "-"} | '
                      f'{_config_label(be)} | {_g(be and be["wall_per_sim_s"])} | '
                      f'{_g(e["speedup_expert"], ".2f") + "x" if e["speedup_expert"] else "-"} |')
        rc = getattr(prob, 'rhs_cost', None) or {}
        if 'compiled_ns' in rc:
            md += ['', 'Right-hand side (exact fidelity, engine and load inside): ' + _rhs_cost_text(rc)]
        elif rc:
            md += ['', f'Right-hand side cost: not measured ({rc.get("note", "")}).']
        front = pareto_front(srows)
        md += ['', 'Pareto front (error vs cost, all configurations):', '',
               '| config | error (speed, rel) | error (angle, rad) | cost s/s | timing spread | rhs evals |',
               '| --- | --- | --- | --- | --- | --- |']
        md += [f'| {_config_label(r)} | {_g(r["err_speed_rel"], ".2e")} | {_g(r["err_angle_rad"], ".2e")} | '
               f'{_g(r["wall_per_sim_s"])} | {100 * r["wall_spread"]:.0f} % | {r["nfev"]} |' for r in front]
        if prob.aliases:
            md += ['', 'Same model, not rerun: ' + ', '.join(f'{k} = {v}' for k, v in prob.aliases.items())
                   + '.']
        if 'auto' in prob.levels:
            same = prob.aliases.get('auto', 'auto')
            auto = [r for r in srows if r['family'] == 'project' and r['fidelity'] == same and r.get('ok')]
            on = [r for r in auto if r in front]
            md += ['', f'Fidelity chooser\'s pick ({prob.levels["auto"]}'
                   + (f', the same model as {same}' if same != 'auto' else '') + '): '
                   f'{len(on)} of {len(auto)} of its runs on the Pareto front'
                   + (f' ({", ".join(_config_label(r) for r in on)}).' if on else '.')]
        failed = [r for r in srows if not r.get('ok')]
        if failed:
            md += ['', f'{len(failed)} runs failed or exceeded the budget: '
                   + '; '.join(f'{_config_label(r)}: {r.get("note", "")}' for r in failed[:8])
                   + (' ...' if len(failed) > 8 else '')]
    md += ['', '## Lockstep loop (offline CoupledStepper vs closed-loop reference)', '']
    if lock_rows:
        md += ['| scene | scheme | exchange step s | error (speed, rel) | real-time factor | us/exchange |',
               '| --- | --- | --- | --- | --- | --- |']
        md += [f'| {r["scene"]} | {r["scheme"]} | {r["exchange_step"]:g} | {_g(r.get("err_speed_rel"), ".2e")} | '
               f'{_g(r.get("rtf"))} | {_g(r.get("us_per_exchange"))} |' for r in lock_rows]
    else:
        md.append('Not run (cvj_ros.physics.cosim.CoupledStepper not available, or no lockstep scene).')
    md += ['', '## Loop overhead vs rclpy round trip', '']
    for ex, v in rt.items():
        if ex == 'note':
            md.append(f'- rclpy round trip: {v}')
            continue
        label = ROUND_TRIP_LABELS.get(ex, ex)
        md.append(f'- rclpy round trip, {label}: '
                  + (f'{v["us_mean"]:.0f} us mean, {v.get("us_p50", math.nan):.0f} us median, '
                     f'{v.get("us_p95", math.nan):.0f} us p95' if isinstance(v, dict) and 'us_mean' in v else str(v)))
    md += _real_lockstep_lines(real or [], rt)
    if studies:
        md.append(f'- slow studies (`pytest -m slow`): {studies["summary"]}')
    if rhs_reference:
        md += ['', "## Right-hand side of a hand-written 2-DOF model", '']
        if 'compiled_ns' in rhs_reference:
            md.append('2-DOF engine-spring-Hooke(exact)-load (`bench.hooke_2dof_scene`; the '
                      'reference: a hand-written compiled rhs at 25 ns, aim within 2x): '
                      + _rhs_cost_text(rhs_reference))
            for name, hand in (rhs_reference.get('hand') or {}).items():
                md.append(f'- {name}, the same equations written by hand (`cvj_ros.bench_handrhs`, no '
                          f'section walk): {hand["hand_ns"]:.1f} ns per call against the kernel '
                          f'rhs\'s {hand["kernel_ns"]:.1f} ns (CPU time per integrator-like call: '
                          f'not inlined, each input from the output before, the chain\'s own '
                          f'{hand.get("floor_ns", math.nan):.1f} ns included; medians of '
                          f'{hand["rounds"]} alternating rounds, ranges '
                          f'{hand["hand_ns_min"]:.1f}-{hand["hand_ns_max"]:.1f} and '
                          f'{hand["kernel_ns_min"]:.1f}-{hand["kernel_ns_max"]:.1f} ns): the kernel '
                          f'is {hand["ratio"]:.2f}x the hand-written rhs (aim within 1.5x).')
        else:
            md.append(f'Not measured ({rhs_reference.get("note", "")}).')
    if startup is not None:
        md += ['', '## Kernel start-up', '']
        if 'cold_compile_s' in startup:
            md.append(f'- cold compile (`python -m cvj_ros.physics.kernel.warmup`, empty cache, every '
                      f'method and the outputs; what the first `make test` or `make bench` pays, the first `make demo` compiles only the entry points its run calls, docs/solvers.md "First run"): {startup["cold_compile_s"]:.1f} s'
                      + (f' ({startup["cold_compile_how"]})' if startup.get('cold_compile_how') else ''))
        if 'warm_simulate_s_median' in startup:
            md.append(f'- warm start, whole command `cvj-sim simulate kavz685_lever --duration 2`: '
                      f'{startup["warm_simulate_s_median"]:.2f} s median, {startup["warm_simulate_s_min"]:.2f} s '
                      f'min of {startup["warm_runs"]} (target <= 1.5 s)')
        if 'note' in startup:
            md.append(f'- {startup["note"]}')
    expert_modes = [m for m in modes if m.get('expert_skipped') or
                    any(r['family'] == 'baseline_expert' for r in m['rows'])]
    if expert_modes:
        from cvj_ros.bench_modes import expert_verdict
        md += ['', '## Mode scenes against baseline_expert (oracle events)', '',
               'Kernel against numbalsoda on the same compiled mode rhs, each mode segment ending at '
               'the oracle run\'s event (a lower bound on the expert\'s cost); tables in modes.md.', '']
        for m in expert_modes:
            md.append(f"- {m['scene']}: " + (f"baseline_expert skipped: {m['expert_skipped']}"
                                             if m.get('expert_skipped') else expert_verdict(m)))
            if any(r['family'] == 'baseline_expert_bisect' for r in m['rows']):
                md.append(f"- {m['scene']} (numbalsoda with its own witness bisection): "
                          + expert_verdict(m, 'baseline_expert_bisect'))
    p = out / 'bench.md'
    p.write_text('\n'.join(md) + '\n')
    paths.append(p)
    return paths


def check_config(cfg: BenchConfig) -> None:
    """Validate a configuration; raises SceneError naming the option."""
    for t in cfg.tolerances:
        if not (math.isfinite(t) and 0 < t < 1):
            raise SceneError('--tolerances', f'must be in (0, 1), got {t}')
    for s in cfg.solvers:
        if s not in ADAPTIVE_SOLVERS + ('rk4', 'ros2'):
            raise SceneError('--solvers', f'unknown solver {s!r}')
    for f in cfg.fidelities:
        if f not in FIDELITY_MODES:
            raise SceneError('--fidelities', f'unknown fidelity {f!r}; one of {", ".join(FIDELITY_MODES)}')
    if not cfg.energy:
        raise SceneError('--energy', 'give on, off or both')
    for e in cfg.energy:
        if e not in ENERGY_MODES:
            raise SceneError('--energy', f'unknown value {e!r}; one of {", ".join(ENERGY_MODES)}')
    if cfg.repeats < 1:
        raise SceneError('--repeats', f'must be >= 1, got {cfg.repeats}')
    if cfg.passes < 1:
        raise SceneError('--passes', f'must be >= 1, got {cfg.passes}')
    if cfg.horizon is not None and not (math.isfinite(cfg.horizon) and cfg.horizon > 0):
        raise SceneError('--horizon', f'must be > 0, got {cfg.horizon}')


def sweep_rates(variants: int = 400, workers: Sequence[int] = (1, 2), *,
                scene: str = 'kavz685_lever', out_dir: str | Path | None = None) -> list[dict[str, Any]]:
    """Sweep throughput (`cvj-sim bench --sweep N`): ``variants`` variants of ``scene`` (its
    own duration; hinge angle x bushing stiffness for kavz685_lever, else initial speed),
    once per worker count. Per row: workers, steady variants/s (after the first finished
    chunk: workers started, kernel loaded), that start-up (s), wall s of the whole sweep, and
    the scaling efficiency rate_n / (n rate_1). On a shared machine the figures move
    with the other load: the line names the load average."""
    import tempfile

    from cvj_ros.commands.sweep import load_scene_data
    from cvj_ros.physics.scene import find_scene
    from cvj_ros.sweep.run import RunOptions, execute, make_executor
    from cvj_ros.sweep.spec import build_sweep
    path = find_scene(scene)
    base = load_scene_data(path)
    if scene == 'kavz685_lever':
        n_a = max(1, variants // 10)
        sets = [f'driveline[coupling].params.alpha_deg=0:30:{n_a}',
                f'driveline[bushings].stiffness=300:3000:{max(1, variants // n_a)}:log']
    else:
        sets = [f'initial.speed_rad_s=10:100:{variants}']
    sweep = build_sweep(base, sets)
    rows: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory() as tmp:
        for n in workers:
            t0 = time.perf_counter()
            rep = execute(sweep, RunOptions(), Path(out_dir or tmp) / f'w{n}',
                          executor=make_executor(n), fresh=True, scene_source=str(path), started=t0)
            rows.append({'scene': scene, 'variants': rep.total, 'workers': n, 'rate': rep.steady_rate,
                         'startup_s': rep.first_wall, 'run_wall_s': rep.run_wall,
                         'total_wall_s': rep.total_wall})
    for r in rows:
        r['efficiency'] = r['rate'] / (r['workers'] * rows[0]['rate']) if rows[0]['rate'] else math.nan
    return rows


def format_sweep_rates(rows: Sequence[dict[str, Any]]) -> str:
    """One line per worker count, plus the 10 000-variant extrapolation of the fastest."""
    lines = [f"sweep {r['scene']}: {r['variants']} variants, {r['workers']} worker"
             f"{'s' if r['workers'] > 1 else ''}: {r['rate']:.1f} variants/s after "
             f"{r['startup_s']:.1f} s start-up ({r['total_wall_s']:.1f} s wall), scaling efficiency "
             f"{100 * r['efficiency']:.0f} %" for r in rows]
    best = max(rows, key=lambda r: r['rate'])
    if best['rate'] > 0:
        lines.append(f"sweep: 10 000 variants would take ~{best['startup_s'] + 10_000 / best['rate']:.0f} s with "
                     f"{best['workers']} worker{'s' if best['workers'] > 1 else ''} "
                     f"(target <= 60 s); {os.cpu_count()} cores, load average "
                     f"{os.getloadavg()[0]:.1f} at the end")
    return '\n'.join(lines)
