"""Offline closed-loop simulation of a scene: engine and load inside the right-hand side.

One persistent stepper (cvj_ros.physics.solvers.make_stepper) integrates the driveline
(cvj_ros.physics.driveline) with the engine torque T_e(t, omega_e, phi_e) on the first
inertia and the load torque T_l(t, omega_l, phi_l) on the last. The stepper lands
exactly on every sample time (``sample_dt``, default the scene's ``sample_step`` or
``exchange_step``), so the samples are solver steps, not interpolants; between samples
it keeps its step-size proposal.

Backends: ``'kernel'`` (default) packs the scene into data (cvj_ros.physics.kernel.layout)
and integrates it with the compiled steppers (kernel/stepper.py) - engine and load are
evaluated inside the compiled right-hand side; ``'python'`` runs the readable reference
right-hand side (Driveline.rhs_sources) with the Python steppers, the test oracle. A scene
element the kernel does not cover falls back to ``'python'`` with one line saying which
(``Simulation.backend_note``); nothing falls back silently.

The state is augmented with the work integrals (engine, load, damping; J), so every run
reports the energy-balance residual (E_kin + E_el - E0 - W_engine + W_load + W_damp) /
max energy scale (cvj_ros.physics.driveline.Driveline.energy_residual).
"""
from __future__ import annotations

import functools
import math
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from cvj_ros.errors import CvjError, SceneError, SolverError
from cvj_ros.physics.driveline import Driveline
from cvj_ros.physics.scene import Scene

FloatArray = NDArray[np.float64]
BACKENDS = ('kernel', 'python')

EXPLICIT_METHODS = ('dopri5', 'dop853', 'tsit5', 'vern6', 'vern7', 'vern8')
# an explicit Runge-Kutta step stays stable for |h lambda| below ~3-6 (Hairer & Wanner 1996,
# IV.2: DOPRI5's stability region reaches ~3.3 on the imaginary axis); 6 bounds every pair here
EXPLICIT_STABILITY = 6.0
# steps an explicit run may need before it is refused up front (~1 h at ~0.3 us a step)
MAX_EXPLICIT_STEPS = 1e10


def element_path(chain: Any, name: str, prefix: str = 'driveline') -> str | None:
    """The scene path of the element ``name`` (``driveline[1]``, a branch's
    ``driveline[4].left[2]``), None when no element has that name."""
    for i, el in enumerate(chain):
        here = f'{prefix}[{i}]'
        if getattr(el, 'name', None) == name:
            return here
        for side in ('left', 'right'):
            branch = getattr(el, side, None)
            if isinstance(branch, tuple):
                found = element_path(branch, name, f'{here}.{side}')
                if found is not None:
                    return found
    return None


def explicit_step_check(scene: Scene, report: Any, method: str, duration: float) -> None:
    """Raise SceneError (naming the spring's stiffness) when an explicit ``method`` would need
    more than :data:`MAX_EXPLICIT_STEPS` steps over ``duration`` (s) just to stay stable on a
    spring mode: omega_n duration / :data:`EXPLICIT_STABILITY`, with omega_n =
    sqrt(c (1/J_l + 1/J_r)) rad/s of each elastic spring (the fidelity report's figure; a
    report without choices, or None, is not checked)."""
    if method not in EXPLICIT_METHODS or report is None:
        return
    for c in getattr(report, 'choices', ()):
        omega = c.candidates.get('elastic', {}).get('omega_n')
        if c.element != 'spring' or c.chosen != 'elastic' or omega is None:
            continue
        steps = omega * duration / EXPLICIT_STABILITY
        if not steps > MAX_EXPLICIT_STEPS:
            continue
        where = element_path(scene.driveline, c.name) or f'driveline[{c.name}]'
        raise SceneError(f'{where}.stiffness',
                         f'spring {c.name!r} and its neighbours\' inertias have a mode at '
                         f'{omega:.3g} rad/s: {method} would need ~{steps:.1e} steps for '
                         f'{duration:g} s just to stay stable (more than {MAX_EXPLICIT_STEPS:.0e});'
                         f' check the value, or use solver rosenbrock or rigid fidelity for it')


def scene_explicit_step_check(scene: Scene, method: str, duration: float, *,
                              overrides: Mapping[str, str] | None = None) -> None:
    """:func:`explicit_step_check` on the scene's own fidelity report (with ``overrides``
    forced), for a run that builds its stepper elsewhere (the coupling node, `cvj-sim run`
    before any process starts). A scene whose report cannot be built is not checked here:
    building its physics names that error."""
    from cvj_ros.physics.fidelity import choose_fidelity
    if method not in EXPLICIT_METHODS:
        return
    try:
        report = choose_fidelity(scene, overrides=overrides or None)
    except CvjError:
        return
    explicit_step_check(scene, report, method, duration)


def kernel_gap(driveline: Driveline, engine: Any, load: Any, horizon: float) -> str | None:
    """Why the compiled kernel cannot run this driveline with these sources (one line
    naming the element), or None when it can."""
    from cvj_ros.physics.kernel.layout import build_model
    try:
        build_model(driveline, engine=engine, load=load, horizon=horizon)
    except NotImplementedError as exc:
        return str(exc).removeprefix('compiled kernel: ')
    return None


@dataclass
class Trace:
    """Sampled run. Arrays are (samples,) or (samples, shafts); units: s, rad, rad/s, N m."""

    t: FloatArray
    names: list[str]
    position: FloatArray
    velocity: FloatArray
    effort: FloatArray
    engine_torque: FloatArray
    load_torque: FloatArray
    energy_residual: FloatArray          # (samples,) relative energy-balance residual
    solver: dict[str, Any] = field(default_factory=dict)
    wall_time: float = 0.0               # s of wall clock, integration + sampling
                                         # (solver['integration_wall_time']: stepping only)
    #: vehicle scenes: (samples,) series 'vehicle_speed' (m/s) and per wheel '<wheel>.slip'
    #: (relaxed slip, -), '<wheel>.fx', '<wheel>.fz' (N), '<wheel>.status' (tyre.TYRE_*)
    channels: dict[str, FloatArray] = field(default_factory=dict)

    @property
    def max_energy_residual(self) -> float:
        if not self.energy_residual.size or np.all(np.isnan(self.energy_residual)):
            return math.nan
        return float(np.nanmax(np.abs(self.energy_residual)))

    def column(self, name: str) -> int:
        """Index of shaft ``name`` in the arrays (KeyError if absent)."""
        try:
            return self.names.index(name)
        except ValueError:
            raise KeyError(name) from None

    def to_csv(self, path: str) -> None:
        """Write t and every shaft's position/velocity/effort as CSV (header names units)."""
        cols = ['t_s'] + [f'{n}_{q}' for n in self.names
                          for q in ('position_rad', 'velocity_rad_s', 'effort_nm')]
        cols += ['engine_torque_nm', 'load_torque_nm', 'energy_residual']
        data = [self.t[:, None]]
        for i in range(len(self.names)):
            data.append(np.stack([self.position[:, i], self.velocity[:, i], self.effort[:, i]], 1))
        data.append(np.stack([self.engine_torque, self.load_torque, self.energy_residual], 1))
        for key, series in self.channels.items():
            cols.append(key)
            data.append(np.asarray(series, dtype=float)[:, None])
        np.savetxt(path, np.hstack(data), delimiter=',', header=','.join(cols), comments='')


_NO_BREAKS = np.empty(0)
#: kernel/steppers_nb.py's ST_OK (a run's status without error), here without importing
#: numba (test_simulate.py checks that they agree)
_ST_OK = 0
_EPS = float(np.finfo(float).eps)
#: a breakpoint within LANDING_TOL max(1, |t|) (s) of a sample or of the breakpoint kept
#: before it is not landed on (``landing_grid`` and its compiled twin)
LANDING_TOL = 1e-9


def landing_grid(times: FloatArray, breaks: FloatArray, *, tol: float = LANDING_TOL
                 ) -> tuple[FloatArray, np.ndarray]:
    """(grid, rows): the ascending sample ``times`` with the breakpoints (s) inside
    (times[0], times[-1]) merged in, and the index in ``grid`` of every sample. A breakpoint
    closer than ``tol`` max(1, |t|) to a sample or to the breakpoint before it is dropped
    (a step that short would only trip the step-size floor)."""
    rows = np.arange(times.size)
    if breaks.size == 0:
        return times, rows
    b = breaks[(breaks > times[0]) & (breaks < times[-1])]
    if b.size > 1 and not (b[1:] > b[:-1]).all():
        b = np.unique(b)   # the loads list them ascending and unique; a user's may not
    near = tol * np.maximum(1.0, np.abs(b))
    i = np.searchsorted(times, b)
    keep = (b - times[np.maximum(i - 1, 0)] > near) & (times[np.minimum(i, times.size - 1)] - b > near)
    if not keep.all():
        b, near = b[keep], near[keep]
    if b.size > 1 and not (b[1:] - b[:-1] > near[1:]).all():
        # a cluster: keep a breakpoint only past tol of the last one kept (sequential)
        bl, nl = b.tolist(), near.tolist()
        kept, last = [bl[0]], bl[0]
        for bj, nj in zip(bl[1:], nl[1:]):
            if bj - last > nj:
                kept.append(bj)
                last = bj
        b = np.array(kept)
    if b.size == 0:
        return times, rows
    grid = np.concatenate((times, b))
    order = np.argsort(grid, kind='stable')
    return grid[order], np.flatnonzero(order < times.size)


def dense_segments(times: FloatArray, breaks: FloatArray) -> list[tuple[int, int, float | None]]:
    """Dense sampling's plan: per breakpoint b (ascending, inside (times[0], times[-1])) the
    sample rows [k, k_end) read before the landing on b - k_end the first sample after b,
    k the previous segment's k_end (1 for the first) -, then the rows after the last one
    (b None). One searchsorted for all (a call per breakpoint was ~0.2 ms of a 2 s
    kavz685_lever sweep variant's plan: 200 knots)."""
    k_ends = [*np.searchsorted(times, breaks, 'right').tolist(), times.size]
    return list(zip([1, *k_ends[:-1]], k_ends, [*breaks.tolist(), None]))


def _below_step_floor(gap: float, t: float) -> bool:
    """True when a step of ``gap`` (s) from ``t`` is below the adaptive steppers' floor
    (``steppers_nb``: h < 10 eps max(|t|, 1e-300) or h <= 1e-300 is a step size underflow)."""
    return gap < 10.0 * _EPS * max(abs(t), 1e-300) or gap <= 1e-300


def dopri5_segments(times: FloatArray, segments: list[tuple[int, int, float | None]],
                    breaks: FloatArray | None = None) -> list[tuple[int, int, float | None]]:
    """Dense sampling's ``segments`` (sample rows [k, k_end), then a landing on breakpoint b)
    for dopri5, whose sampled loop clips its last step at the segment's last sample: t is
    then known exactly at every landing, and where a segment's last sample or a breakpoint
    lies closer to it than the step floor (a load knot k x 10 ms and a sample j x 50 ms
    an ulp apart: 15 x 0.01 = 0.15 < 3 x 0.05) that step would underflow. The landing on
    that breakpoint is dropped instead (the next step crosses it by an ulp; a segment whose
    samples all lie within the floor past it joins the segment before). Only segment lists
    that would fail change. ``breaks``: the segments' breakpoints as an array, when the
    caller has it: both cases need a breakpoint within the floor of a sample but not on
    it, and where none is (checked at once) the list is returned as it is."""
    if breaks is not None:
        if breaks.size == 0:
            return segments
        i = np.minimum(np.searchsorted(times, breaks), times.size - 1)
        d = np.minimum(np.abs(times[i] - breaks), np.abs(times[np.maximum(i - 1, 0)] - breaks))
        if not ((d > 0) & (d < 20.0 * _EPS * np.maximum(np.abs(breaks), 1e-300))).any():
            return segments
    out: list[tuple[int, int, float | None]] = []
    t = float(times[0])
    t_before = t     # t at the start of out[-1]
    for k, k_end, b in segments:
        t_start = t
        if k_end > k:
            last = float(times[k_end - 1])
            if last > t and _below_step_floor(last - t, t) and out and out[-1][2] is not None \
                    and t == out[-1][2]:
                # the previous landing is what left t an ulp short of this segment's samples
                k, t_start = out.pop()[0], t_before
            t = max(t, last)
        if b is not None and b > t:
            if _below_step_floor(b - t, t):
                b = None
            else:
                t = b
        out.append((k, k_end, b))
        t_before = t_start
    return out


@functools.lru_cache(maxsize=None)
def _outputs_kernel() -> tuple[Any, Any, Any]:
    """(entry_point_once, sample_outputs, fill_mid_samples), imported on first use: importing
    outputs_nb loads numba, which commands that do not integrate must not pay for, and an
    import inside every run cost ~1 us."""
    from cvj_ros.physics.kernel import entry_point_once
    from cvj_ros.physics.kernel.outputs_nb import fill_mid_samples, sample_outputs
    return entry_point_once, sample_outputs, fill_mid_samples


@dataclass
class _KernelPlan:
    """A kernel run's options made concrete once (Simulation._kernel_plan)."""

    times: FloatArray                     # sample times (s); a trace gets a copy
    grid: FloatArray | None               # land: the landing grid (s)
    rows: np.ndarray | None               # land: grid row of every sample
    is_sample: np.ndarray | None          # land: grid row is a sample
    segments: list[tuple[int, int, float | None]]   # dense: sample rows, breakpoint after
    stepper: Any                          # reset for every run after the first
    model: Any                            # its ModelData
    run: Any = None                       # KernelStepper.bind_run's one-call run
    XG: FloatArray | None = None          # land: its states at the grid (None: X itself)
    shape: tuple[int, int, int] = (0, 0, 0)   # samples, states, shafts (the run's arrays)
    call: Any = None                      # run's bound entry point, after its first call
    #: run(reuse_trace=True): (its Trace, the call's arrays X, XG, pos, vel, eff, te, tl,
    #: res, the final state's view), made by the first such run and rewritten by the next
    kept: tuple[Trace, tuple[FloatArray, ...], FloatArray] | None = None
    #: call(e0) -> (status, bad) of the run into kept's arrays (bind_run's run.kept), or None
    kept_call: Any = None


@dataclass
class _TreePlan:
    """A vehicle run's options made concrete once (Simulation._tree_plan): the stepper,
    the landing grid and the compiled outputs' tables (kernel/tree_run_nb.py)."""

    times: FloatArray                     # sample times (s); a trace gets a copy
    grid: FloatArray                      # the landing grid (s)
    rows: np.ndarray                      # grid row of every sample (int64)
    stepper: Any                          # reset for every run after the first
    model: Any                            # its ModelData (the engine inside)
    tables: tuple                         # tab, ends, mtab, mfp, wheel_t
    python_members: list                  # members left to the Python fill_mid
    channel_names: list[str]              # Trace.channels' keys, in the rows' order
    call: Any = None                      # tree_run_outputs' entry point


class Simulation:
    """Offline closed loop of ``scene``.

    Args:
        scene: validated scene.
        method, rtol, atol: override the scene's solver settings.
        fidelity: per-element forced levels (joint: ideal|closed|exact, spring:
            elastic|rigid), see cvj_ros.physics.fidelity.
        engine, load: torque sources to use instead of building them from the scene
            specs (anything with ``torque(t, omega, phi)`` and ``slope(...)``).
        track_energy: integrate the work integrals and report the energy residual
            (default); False keeps the state at 2 n_dof (benchmarks) and reports NaN.
        backend: 'kernel' (compiled, default; falls back to 'python' with
            ``backend_note`` set when an element is not compiled) or 'python'
            (the reference right-hand side and Python steppers).
    """

    #: kernel runs without a progress callback: start, integration and outputs in one
    #: compiled call (kernel/run_nb.py); False takes the step-by-step path (the tests' oracle)
    _one_call = True

    def __init__(self, scene: Scene, *, method: str | None = None, rtol: float | None = None,
                 atol: float | None = None, fidelity: Mapping[str, str] | None = None,
                 engine: Any = None, load: Any = None, track_energy: bool = True,
                 backend: str = 'kernel') -> None:
        if backend not in BACKENDS:
            raise SceneError('backend', f'must be one of {", ".join(BACKENDS)}, got {backend!r}')
        self.scene = scene
        self.method = method or scene.solver.method
        self.rtol = float(rtol if rtol is not None else scene.solver.rtol)
        self.atol = float(atol if atol is not None else scene.solver.atol)
        for name, v in (('rtol', self.rtol), ('atol', self.atol)):
            if not (math.isfinite(v) and v > 0):
                raise SceneError(f'solver.{name}', f'must be > 0, got {v}')
        if scene.is_tree:
            # wheels, tyres and the vehicle body are the load (cvj_ros.physics.tree)
            from cvj_ros.physics.tree import TreeDriveline
            self.driveline = TreeDriveline.from_scene(scene, fidelity=fidelity,
                                                      track_energy=track_energy)
        else:
            self.driveline = Driveline.from_scene(scene, fidelity=fidelity, track_energy=track_energy)
        self.fidelity_report = self.driveline.fidelity_report
        if engine is None:
            from cvj_ros.physics.engine import engine_from_spec
            engine = engine_from_spec(scene.engine, field='engine')
        if load is None and not scene.is_tree:
            from cvj_ros.physics.load import load_from_spec
            load = load_from_spec(scene.load, seed=scene.seed, field='load')
        self.engine = engine
        self.load = load
        # no explicit t in the closed loop (joints and springs have none): the Rosenbrock
        # steppers skip f_t, 2 of RODAS3's 5 fev per step (same bytes: f_t is exactly 0)
        self.autonomous = bool(getattr(engine, 'time_invariant', False)
                               and getattr(load, 'time_invariant', False))
        self.last_trace: Trace | None = None
        dl = self.driveline
        n = dl.n_dof
        load_state = getattr(dl, 'load_state', None)      # None: a vehicle scene
        e_torque, l_torque = engine.torque, getattr(load, 'torque', None)

        rhs_sources = dl.rhs_sources

        def fun(t: float, x: FloatArray) -> FloatArray:
            return rhs_sources(t, x, engine, load)

        def jac(t: float, x: FloatArray) -> FloatArray:
            phi_l, w_l = load_state(x)
            w_e, phi_e = float(x[n]), float(x[0])
            # dT/dphi (firing ripple, load over angle) by a central difference: the torque
            # contract gives only dT/domega. Without it Rosenbrock methods lose their order.
            he, hl = 1e-6 * max(1.0, abs(phi_e)), 1e-6 * max(1.0, abs(phi_l))
            return dl.jacobian(t, x, e_torque(t, w_e, phi_e), l_torque(t, w_l, phi_l),
                               dTe_domega=engine.slope(t, w_e, phi_e),
                               dTl_domega=load.slope(t, w_l, phi_l),
                               dTe_dphi=(e_torque(t, w_e, phi_e + he) - e_torque(t, w_e, phi_e - he)) / (2 * he),
                               dTl_dphi=(l_torque(t, w_l, phi_l + hl) - l_torque(t, w_l, phi_l - hl)) / (2 * hl))

        if scene.is_tree:
            def jac(t: float, x: FloatArray) -> FloatArray:   # noqa: F811
                return dl.jacobian_fd(t, x, engine)

        self.fun = fun
        self.jac = jac
        self.backend = backend
        self.backend_note: str | None = None
        self.compile_seconds: float | None = None
        self._packed: dict[float, Any] = {}
        self._plans: dict[tuple, _KernelPlan] = {}
        self._tree_plans: dict[tuple, tuple[Any, Any, Any]] = {}   # vehicle: stepper, samples, mids
        self._tree_runs: dict[tuple, _TreePlan | None] = {}   # vehicle, compiled outputs
        self._shaft_table: NDArray[np.int64] | None = None
        self._mid_table: tuple[Any, Any, list[tuple[int, int]]] | None = None   # with it
        self._e0: tuple[bytes | None, float] = (None, 0.0)   # (x0 bytes, its energy)
        # (run's own arguments with method, rtol, atol; the plan) of the latest one-call
        # run: the same arguments again skip the checks and the plan's lookup (run)
        self._fast: tuple[tuple, _KernelPlan] | None = None
        if backend == 'kernel':
            # packing the scene is also the test whether the kernel covers it (kernel_gap):
            # over a zero horizon (a random load's few edge knots); a run packs its own (_model)
            from cvj_ros.physics.kernel.layout import build_model
            horizon = 0.0
            try:
                self._packed = {horizon: build_model(dl, engine=engine, load=load,
                                                     horizon=horizon)}
            except NotImplementedError as exc:
                reason = str(exc).removeprefix('compiled kernel: ')
                self.backend = 'python'
                self.backend_note = f'compiled kernel: {reason}; running the Python reference'

    def _model(self, horizon: float):
        """The scene as kernel data for runs up to ``horizon`` (s): a seeded random load's
        knots over [0, horizon] only (each knot is a function of its index, so a shorter
        horizon packs a prefix of the same values). Packed once per horizon and kept; each
        run gets fresh copies of the arrays, so a run never sees another run's input block."""
        from cvj_ros.physics.kernel.layout import ModelData, build_model
        h = float(horizon)
        cached = self._packed.get(h)
        if cached is None:
            cached = build_model(self.driveline, engine=self.engine, load=self.load, horizon=h)
            self._packed = {h: cached}
        return ModelData(ip=cached.ip.copy(), fp=cached.fp.copy(), n_dof=cached.n_dof,
                         n_state=cached.n_state, track_energy=cached.track_energy, x0=cached.x0)

    def _output_tables(self) -> None:
        """The shaft and intermediate-member tables of the compiled outputs, made once."""
        if self._shaft_table is None:
            from cvj_ros.physics.kernel.outputs_nb import mid_table, shaft_table
            self._shaft_table = shaft_table(self.driveline)
            self._mid_table = mid_table(self.driveline)

    def _kernel_outputs(self, times: FloatArray, X: FloatArray, e0: float, pos: FloatArray,
                        vel: FloatArray, eff: FloatArray, te: FloatArray, tl: FloatArray,
                        res: FloatArray) -> None:
        """Joint states, torques and energy residual of every sample, compiled
        (kernel/outputs_nb.py); the same quantities the Python ``record`` computes."""
        # every array here is allocated by run() (C-contiguous float64/int64): one type each
        self._output_tables()
        args = (times, X, self.model.ip, self.model.fp, self._shaft_table, float(e0), pos, vel,
                eff, te, tl, res)
        entry_point_once, sample_outputs, _fill = _outputs_kernel()
        self._check_outputs(times, entry_point_once(sample_outputs, args)(*args), pos, vel)

    def _check_outputs(self, times: FloatArray, bad: int, pos: FloatArray,
                       vel: FloatArray, *, compiled_mids: bool = False) -> None:
        """SolverError when sample ``bad`` (>= 0) was not finite; else the intermediate
        members' angles and speeds (compiled where the kernel has them - already filled by
        the one-call run when ``compiled_mids`` - else Python)."""
        if bad >= 0:
            raise SolverError(f'state became non-finite at t = {float(times[bad]):g} s')
        mtab, mfp, python_members = self._mid_table
        if mtab.shape[0] and not compiled_mids:
            entry_point_once, _outputs, fill_mid_samples = _outputs_kernel()
            args = (pos, vel, mtab, mfp)
            entry_point_once(fill_mid_samples, args)(*args)
        if python_members:
            self.driveline.fill_mid(pos, vel, members=python_members)

    @staticmethod
    def _landing_grid(times: FloatArray, breaks: FloatArray) -> tuple[FloatArray, np.ndarray]:
        """:func:`landing_grid` compiled (kernel/grid_nb.py, same grid; tested against it)."""
        if breaks.size == 0:
            return times, np.arange(times.size)
        from cvj_ros.physics.kernel import entry_point_once
        from cvj_ros.physics.kernel.grid_nb import landing_grid as landing_grid_nb
        breaks = np.ascontiguousarray(breaks, dtype=np.float64)
        grid = np.empty(times.size + breaks.size)
        rows = np.empty(times.size, np.int64)
        args = (times, breaks, LANDING_TOL, grid, rows)
        m = entry_point_once(landing_grid_nb, args)(*args)
        return grid[:m], rows

    def _initial_energy(self, x0: FloatArray) -> float:
        """Kinetic + elastic energy (J) of x0, the energy residual's reference; kept per x0."""
        key = x0.tobytes()
        if self._e0[0] != key:
            e = self.driveline.energy(x0)
            self._e0 = (key, e['kinetic'] + e['elastic'])
        return self._e0[1]

    def breakpoints(self, horizon: float) -> FloatArray:
        """Times in (0, horizon) (s, ascending) where the load torque is not smooth in t
        (``Load.breakpoints``: random-load knots, time-series samples, brake-step ramp ends;
        the engine models are smooth in t). ``run`` lands a step on each, so the step
        controller never steps across a kink: on kavz685_lever's random load (knots every
        10 ms) dop853 at tol 1e-6 ends 1.3e-9 from the reference instead of 3.6e-6
        (docs/solvers.md "Breakpoints")."""
        listed = getattr(self.load, 'breakpoints', None)   # a user's own load may lack it
        return _NO_BREAKS if listed is None else np.asarray(listed(0.0, horizon), dtype=float)

    def make_stepper(self, x0: FloatArray, horizon: float, **kwargs: Any) -> Any:
        """A persistent stepper of this scene's closed loop from t = 0 (backend-dependent);
        ``horizon`` (s) bounds pre-generated source sequences (seeded random load)."""
        if self.backend == 'python':
            from cvj_ros.physics.solvers import make_stepper
            if self.method in ('rosenbrock', 'ros2'):
                kwargs['jac'] = self.jac
            return make_stepper(self.method, self.fun, 0.0, x0, autonomous=self.autonomous,
                                **kwargs)
        from cvj_ros.physics.kernel import rhs_nb
        from cvj_ros.physics.kernel.stepper import KernelStepper
        model = self._model(horizon)
        self.model = model
        stepper = KernelStepper(self.method, rhs_nb.rhs, model.ip, model.fp, 0.0, x0,
                                jac=rhs_nb.jac, autonomous=self.autonomous, **kwargs)
        return stepper

    def torques(self, t: float, x: FloatArray) -> tuple[float, float]:
        """(engine torque, load torque) in N m at state x; a vehicle scene's load torque is its
        tyres' sum F_x r."""
        n = self.driveline.n_dof
        if self.scene.is_tree:
            dl = self.driveline
            return (float(self.engine.torque(t, dl.engine_omega(x), dl.engine_phi(x))),
                    float(dl.tyre_torque(x)))
        phi_l, w_l = self.driveline.load_state(x)
        return (float(self.engine.torque(t, float(x[n]), float(x[0]))),
                float(self.load.torque(t, w_l, phi_l)))

    def run(self, duration: float | None = None, *, sample_dt: float | None = None,
            sampling: str = 'land', progress: Callable[[float], None] | None = None,
            breakpoints: bool = True, reuse_trace: bool = False) -> Trace:
        """Integrate from t = 0 over ``duration`` (s, default the scene's), sampling every
        ``sample_dt`` (s). ``sampling='land'`` steps exactly onto every sample time (samples
        are solver points; dense sampling then bounds the step); ``'dense'`` lets the
        controller choose its steps and reads samples from the method's dense output
        (interpolant of the method's dense order; cheaper when samples are denser than
        steps). ``progress``, if given, is called with the simulated time (s) of every sample
        (e.g. :meth:`cvj_ros.progress.Progress.update`). ``breakpoints`` (default on): a step
        lands on every time where the load is not smooth in t (:meth:`breakpoints`); off, the
        controller steps across them (cheaper only at loose tolerances).

        ``reuse_trace=True`` (repeated runs of the same options: a benchmark, a loop over
        initial states) returns this Simulation's own Trace for these options, its arrays
        and ``final_state`` rewritten in place by every later run with ``reuse_trace=True``
        and the same arguments: the results alias one buffer, so copy what you keep. Such a
        run allocates nothing (its arrays and solver dict are the first such run's). It
        applies where the run is one compiled call (the kernel backend of a chain scene,
        no ``progress``); elsewhere the Trace is a new one as without it.

        Raises SolverError if the state becomes non-finite."""
        fast = self._fast
        if fast is not None and progress is None and fast[0] == (
                duration, sample_dt, sampling, breakpoints, self.method, self.rtol, self.atol):
            # the latest one-call run's arguments again: they were checked and made into
            # this plan then (the scene is frozen), so only the call is left
            plan = fast[1]
            self.model = plan.model
            if reuse_trace and plan.kept is not None:
                return self._run_kept(plan, self.driveline.x0, plan.kept)
            return self._run_one_call(plan, self.driveline.x0, reuse_trace)
        if sampling not in ('land', 'dense'):
            raise SceneError('sampling', f"must be 'land' or 'dense', got {sampling!r}")
        sc = self.scene
        dur = float(sc.duration if duration is None else duration)
        if not (math.isfinite(dur) and dur > 0):
            raise SceneError('duration', f'must be > 0, got {duration}')
        dt = float(sample_dt or sc.sample_step or sc.exchange_step)
        if not (math.isfinite(dt) and dt > 0):
            raise SceneError('sample_dt', f'must be > 0, got {sample_dt}')
        explicit_step_check(sc, self.fidelity_report, self.method, dur)
        if self.backend == 'kernel' and not self.scene.is_tree:
            trace = self._run_kernel(dur, dt, sampling, progress, breakpoints, reuse_trace)
            plan = next(iter(self._plans.values()))
            self._fast = None if progress is not None or plan.run is None else (
                (duration, sample_dt, sampling, breakpoints, self.method, self.rtol,
                 self.atol), plan)
            return trace
        if (self.backend == 'kernel' and progress is None and sampling == 'land'
                and self.scene.is_tree):
            trace = self._run_tree(dur, dt, breakpoints)
            if trace is not None:
                return trace
        return self._run_python(dur, dt, sampling, progress, breakpoints)

    def _tree_plan(self, dur: float, dt: float, breakpoints: bool) -> _TreePlan | None:
        """A vehicle run's plan (:class:`_TreePlan`), or None when the compiled outputs do
        not cover this driveline (tree_outputs_nb.tree_tables: a subclass such as the
        mode-aware tree, a joint of several kernel stages)."""
        from cvj_ros.physics.kernel.outputs_nb import mid_table
        from cvj_ros.physics.kernel.tree_outputs_nb import tree_tables
        dl = self.driveline
        try:
            tab, ends = tree_tables(dl)
        except NotImplementedError:
            return None
        times = self._sample_times(dur, dt)
        breaks = self.breakpoints(float(times[-1])) if breakpoints else _NO_BREAKS
        grid, rows = landing_grid(times, breaks)
        stepper = self.make_stepper(dl.x0.copy(), dur, **self._stepper_options(dt))
        mtab, mfp, python_members = mid_table(dl)
        names = ['vehicle_speed'] + [f'{w.name}.{q}' for w in dl.wheels
                                     for q in ('slip', 'fx', 'fz', 'status')]
        return _TreePlan(times=times, grid=np.ascontiguousarray(grid, dtype=np.float64),
                         rows=np.ascontiguousarray(rows, dtype=np.int64), stepper=stepper,
                         model=self.model,
                         tables=(tab, ends, np.ascontiguousarray(mtab, dtype=np.int64), mfp,
                                 np.zeros(max(dl.n_wheel, 1))),
                         python_members=python_members, channel_names=names)

    def _run_tree(self, dur: float, dt: float, breakpoints: bool) -> Trace | None:
        """A vehicle run on the kernel in two compiled calls: every landing
        (KernelStepper._land, the same steps as the advance_to loop) and every sample's
        outputs with the intermediate members (kernel/tree_run_nb.tree_run_outputs). The
        plan (stepper, grid, tables) is kept per options; a later run resets the stepper.
        None when the compiled outputs do not cover the driveline (``_run_python`` then)."""
        key = (dur, dt, breakpoints, self.method, self.rtol, self.atol)
        fresh = key not in self._tree_runs
        if fresh:
            self._tree_runs = {key: self._tree_plan(dur, dt, breakpoints)}   # latest only
        plan = self._tree_runs[key]
        if plan is None:
            return None
        self.model = plan.model
        dl = self.driveline
        x0 = dl.x0
        stepper = plan.stepper
        times, grid = plan.times, plan.grid
        m = times.size
        n_sh = len(dl.shaft_names)
        empty = np.empty
        XG = empty((grid.size, x0.size))
        pos, vel, eff = empty((m, n_sh)), empty((m, n_sh)), empty((m, n_sh))
        te, tl, res = empty(m), empty(m), empty(m)
        ch = empty((len(plan.channel_names), m))
        e0 = self._initial_energy(x0)
        clock = time.perf_counter
        wall0 = clock()
        if not fresh:
            stepper.reset(0.0, x0)
        XG[0] = x0
        stepper._land(grid, XG)   # grid and XG built by the plan: checked by construction
        integ = clock() - wall0
        tab, ends, mtab, mfp, wheel_t = plan.tables
        args = (times, XG, plan.rows, plan.model.ip, plan.model.fp, tab, ends, float(e0), pos,
                vel, eff, te, tl, res, ch, mtab, mfp, wheel_t)
        call = plan.call
        if call is None:   # every argument of the types above: one entry point per process
            from cvj_ros.physics.kernel import entry_point_once
            from cvj_ros.physics.kernel.tree_run_nb import tree_run_outputs
            call = plan.call = entry_point_once(tree_run_outputs, args)
        bad = call(*args)
        if bad >= 0:
            raise SolverError(f'state became non-finite at t = {float(times[bad]):g} s')
        if plan.python_members:
            dl.fill_mid(pos, vel, members=plan.python_members)
        trace = self._finish(stepper, times.copy(), pos, vel, eff, te, tl, res, XG[-1].copy(),
                             integ, clock() - wall0)
        trace.channels = dict(zip(plan.channel_names, ch))
        return trace

    def _stepper_options(self, dt: float) -> dict[str, Any]:
        """Keyword options of this run's stepper: tolerances, h (the scene's, or for the
        fixed-step methods a tenth of the smaller of sample and exchange step), max_step."""
        sc = self.scene
        h = sc.solver.h
        if self.method in ('rk4', 'ros2') and h is None:
            h = min(dt, sc.exchange_step) / 10.0
        kwargs: dict[str, Any] = dict(rtol=self.rtol, atol=self.atol, h=h)
        if sc.solver.max_step is not None:
            kwargs['max_step'] = sc.solver.max_step
        return kwargs

    def _sample_times(self, dur: float, dt: float) -> FloatArray:
        """0, dt, 2 dt, ... and ``dur`` itself (s)."""
        n_samples = int(math.floor(dur / dt + 1e-9)) + 1
        times = np.arange(n_samples) * dt
        if times[-1] < dur - 1e-12:
            times = np.append(times, dur)
        return times

    def _kernel_plan(self, dur: float, dt: float, sampling: str, breakpoints: bool) -> _KernelPlan:
        """What a kernel run of these options computes before integrating: the sample times,
        the landing grid (land) or the breakpoints (dense), the stepper. Kept per options
        (:meth:`_run_kernel`): none of it depends on x0 or on an earlier run."""
        times = self._sample_times(dur, dt)
        breaks = self.breakpoints(float(times[-1])) if breakpoints else _NO_BREAKS
        grid = rows = None
        is_sample = None
        if sampling == 'land':
            # the steps land on grid; row j of it is a sample where is_sample[j]
            grid, rows = self._landing_grid(times, breaks)
            is_sample = np.zeros(grid.size, dtype=bool)
            is_sample[rows] = True
            breaks = _NO_BREAKS
        elif breaks.size:
            # dense: samples are not landings, so a breakpoint on a sample is kept too;
            # merged with the two end times only, then the ends taken out again
            g, r = landing_grid(times[[0, -1]], breaks)
            breaks = np.delete(g, r)
        # dense: (first sample, end) row slices between the breakpoints, the landing after
        segments = []
        if sampling == 'dense':
            segments = dense_segments(times, breaks)
            if self.method in ('dopri5', 'tsit5', 'vern6', 'vern7', 'vern8'):   # their sampled loops clip alike
                segments = dopri5_segments(times, segments, breaks)
        kwargs = self._stepper_options(dt)
        stepper = self.make_stepper(self.driveline.x0.copy(), dur, **kwargs)
        plan = _KernelPlan(times=times, grid=grid, rows=rows, is_sample=is_sample,
                           segments=segments, stepper=stepper, model=self.model,
                           shape=(times.size, self.driveline.x0.size,
                                  len(self.driveline.shaft_names)))
        if self._one_call:
            # the same plan as arrays for the one-call run (kernel/run_nb.py); the unused
            # mode's arrays are empty, of the types every call passes
            n = self.driveline.x0.size
            if sampling == 'land':
                # every landing a sample: the landings' states are X itself, rows not needed
                gather = grid.size != times.size
                if gather:
                    plan.XG = np.empty((grid.size, n))
                arrays = (grid, rows.astype(np.int64) if gather else np.zeros(0, np.int64),
                          np.zeros((0, 2), np.int64), np.zeros(0))
            else:
                arrays = (np.zeros(0), np.zeros(0, np.int64),
                          np.array([(k, k_end) for k, k_end, _b in segments], dtype=np.int64),
                          np.array([math.nan if b is None else b for _k, _ke, b in segments]))
            self._output_tables()
            mtab, mfp, _python_members = self._mid_table
            plan.run = stepper.bind_run(self.driveline.x0, times,
                                        (*arrays, np.zeros(2), np.zeros((2, n))),
                                        self._shaft_table, (mtab, mfp))
        return plan

    def _run_kernel(self, dur: float, dt: float, sampling: str,
                    progress: Callable[[float], None] | None, breakpoints: bool,
                    reuse_trace: bool = False) -> Trace:
        """:meth:`run` on the compiled kernel. The plan of these options (sample times, grid,
        stepper) is made once per Simulation and options; a later run resets the plan's
        stepper (the same steps and bytes as a new one) and spends its Python on little more
        than one compiled call (costs in docs/solvers.md, "Short runs")."""
        key = (dur, dt, sampling, breakpoints, self.method, self.rtol, self.atol)
        plan = self._plans.get(key)
        x0 = self.driveline.x0
        fresh = plan is None
        if fresh:
            plan = self._kernel_plan(dur, dt, sampling, breakpoints)
            self._plans = {key: plan}   # the latest options only
        self.model = plan.model
        if progress is None and plan.run is not None:
            return self._run_one_call(plan, x0, reuse_trace)
        stepper = plan.stepper
        times = plan.times
        m, n, n_sh = plan.shape
        pos = np.empty((m, n_sh))
        vel = np.empty((m, n_sh))
        eff = np.empty((m, n_sh))
        te = np.empty(m)
        tl = np.empty(m)
        res = np.empty(m)
        e0 = self._initial_energy(x0)
        clock = time.perf_counter
        wall0 = clock()
        X = np.empty((m, n))
        if not fresh:
            stepper.reset(0.0, x0)
        X[0] = x0
        if sampling == 'dense':
            # dense output between the breakpoints, a landing on each
            for k, k_end, b in plan.segments:
                if k_end > k:   # contiguous slices of arrays built here: unchecked
                    stepper._sample_into(times[k:k_end], X[k:k_end])
                if b is not None and b > stepper.t:
                    stepper.advance_to(b)
                if progress is not None:
                    for tk in times[k:k_end].tolist():
                        progress(tk)
            integ = clock() - wall0
        elif progress is None:
            grid = plan.grid
            XG = X if grid.size == m else np.empty((grid.size, x0.size))
            XG[0] = x0
            stepper._land(grid, XG)   # grid and XG built by the plan: checked by construction
            integ = clock() - wall0
            if XG is not X:
                X[:] = XG[plan.rows]
        else:
            integ = 0.0
            k = 1
            grid, is_sample = plan.grid, plan.is_sample
            for j in range(1, grid.size):
                c0 = clock()
                xj = stepper.advance_to(float(grid[j]))
                integ += clock() - c0
                if is_sample[j]:
                    X[k] = xj
                    progress(float(grid[j]))
                    k += 1
        self._kernel_outputs(times, X, e0, pos, vel, eff, te, tl, res)
        return self._finish(stepper, times.copy(), pos, vel, eff, te, tl, res, X[-1],
                            integ, clock() - wall0)

    def _run_one_call(self, plan: _KernelPlan, x0: FloatArray, reuse: bool = False) -> Trace:
        """Start, integration and outputs in one compiled call (kernel/run_nb.py), and the
        Trace. The Python around the call is what a short run pays beyond its compiled time
        (stiff at tol 1e-3: ~15 us compiled; docs/solvers.md "Short runs"), so it allocates
        the run's arrays, makes the call and hands the rest to :meth:`_finish`; with
        ``reuse`` (``run(reuse_trace=True)``) the plan's kept arrays and Trace are written
        again instead (:meth:`_run_kept`)."""
        kept = plan.kept if reuse else None
        if kept is not None:
            return self._run_kept(plan, x0, kept)
        m, n, n_sh = plan.shape
        empty = np.empty
        X = empty((m, n))
        pos = empty((m, n_sh))
        vel = empty((m, n_sh))
        eff = empty((m, n_sh))
        te = empty(m)
        tl = empty(m)
        res = empty(m)
        e0 = self._initial_energy(x0)
        XG = plan.XG
        clock = time.perf_counter
        wall0 = clock()
        call = plan.call   # the bound entry point after the first run (bind_run)
        if call is None:
            bad = plan.run(e0, X, X if XG is None else XG, pos, vel, eff, te, tl, res)
            plan.call = plan.run.bound()
        else:
            st, bad = call(e0, X, X if XG is None else XG, pos, vel, eff, te, tl, res)
            if st != _ST_OK:
                plan.run.check(st)   # raises
        wall = clock() - wall0
        times = plan.times
        if bad >= 0 or self._mid_table[2]:   # a non-finite sample, or members in Python
            self._check_outputs(times, bad, pos, vel, compiled_mids=True)
        trace = self._finish(plan.stepper, times.copy(), pos, vel, eff, te, tl, res, X[-1],
                             wall, wall)
        if reuse:
            arrays = (X, X if XG is None else XG, pos, vel, eff, te, tl, res)
            plan.kept = (trace, arrays, self.final_state)
            plan.kept_call = plan.run.kept(arrays)
        return trace

    def _run_kept(self, plan: _KernelPlan, x0: FloatArray,
                  kept: tuple[Trace, tuple[FloatArray, ...], FloatArray]) -> Trace:
        """:meth:`_run_one_call` into the arrays of the plan's kept Trace: the same call and
        checks, then the Trace's counters, proposal and wall times refreshed in place
        (``KernelStepper.stats_into``); nothing is allocated. The first kept run's made
        the Trace, so the call's bound entry point exists; a Rosenbrock run's call takes
        its arrays by address instead (``plan.kept_call``, kernel/kept_nb.py)."""
        trace, arrays, final = kept
        e0 = self._initial_energy(x0)
        call = plan.kept_call   # the Rosenbrock run's arrays by address (KernelStepper.bind_run)
        clock = time.perf_counter
        wall0 = clock()
        st, bad = plan.call(e0, *arrays) if call is None else call(e0)
        if st != _ST_OK:
            plan.run.check(st)   # raises
        wall = clock() - wall0
        if bad >= 0 or self._mid_table[2]:   # a non-finite sample, or members in Python
            self._check_outputs(plan.times, bad, arrays[2], arrays[3], compiled_mids=True)
        solver = trace.solver
        plan.stepper.stats_into(solver)
        solver['integration_wall_time'] = wall
        trace.wall_time = wall
        self.last_trace = trace
        self.final_state = final
        return trace

    def _finish(self, stepper: Any, times: FloatArray, pos: FloatArray, vel: FloatArray,
                eff: FloatArray, te: FloatArray, tl: FloatArray, res: FloatArray,
                x: FloatArray, integ: float, wall: float) -> Trace:
        """The run's Trace with the stepper's counters; kept as ``last_trace``."""
        self.compile_seconds = getattr(stepper, 'compile_seconds', None)
        self.cache_path = getattr(stepper, 'cache_path', None)
        # item by item and a positional Trace: this is on every short run's path
        # (_run_one_call), and a dict merge or update cost ~0.3 us more (of ~17)
        stats = stepper.stats()   # its 'method' is self.method
        stats['rtol'] = self.rtol
        stats['atol'] = self.atol
        stats['integration_wall_time'] = integ
        stats['backend'] = self.backend
        stats['backend_fallback'] = self.backend_note
        trace = Trace(times, list(self.driveline.shaft_names), pos, vel, eff, te, tl, res,
                      stats, wall)
        self.last_trace = trace
        self.final_state = x
        return trace

    def _run_python(self, dur: float, dt: float, sampling: str,
                    progress: Callable[[float], None] | None, breakpoints: bool) -> Trace:
        """:meth:`run` step by step with the outputs computed in Python: the Python
        reference's run, and a vehicle scene's on the kernel (compiled stepper and right-hand
        side, kernel/tree_nb.py, kept per options and landing on all samples in one call
        without a progress callback; the joint states and wheel channels from the compiled
        walk of kernel/tree_samples.py, the intermediate members compiled, the energy
        residual from the reference's Python). A vehicle run with landing sampling and no
        progress callback takes :meth:`_run_tree` instead where the compiled outputs cover
        its driveline."""
        dl = self.driveline
        x0 = dl.x0.copy()
        times = self._sample_times(dur, dt)
        kept = None
        if self.scene.is_tree and self.backend == 'kernel':
            # a vehicle scene on the kernel keeps its stepper and compiled sample walk per
            # options, as a chain keeps its plan (_run_kernel): a later run resets the
            # stepper (the same steps and bytes as a new one)
            key = (dur, dt, sampling, breakpoints, self.method, self.rtol, self.atol)
            kept = self._tree_plans.get(key)
        if kept is None:
            stepper = self.make_stepper(x0, dur, **self._stepper_options(dt))
        else:
            stepper = kept[0]
            stepper.reset(0.0, x0)
        n_sh = len(dl.shaft_names)
        pos = np.empty((times.size, n_sh))
        vel = np.empty_like(pos)
        eff = np.empty_like(pos)
        te = np.empty(times.size)
        tl = np.empty(times.size)
        res = np.empty(times.size)
        e0 = self._initial_energy(x0)
        wall0 = time.perf_counter()
        integ = 0.0
        clock = time.perf_counter
        x = x0

        channels: dict[str, FloatArray] = {}
        if self.scene.is_tree:
            channels['vehicle_speed'] = np.empty(times.size)
            for w in dl.wheels:
                for q in ('slip', 'fx', 'fz', 'status'):
                    channels[f'{w.name}.{q}'] = np.empty(times.size)

        wheel_cols = [[channels[f'{w.name}.{q}'] for q in ('slip', 'fx', 'fz', 'status')]
                      for w in dl.wheels] if channels else []
        e_torque = self.engine.torque
        samples = None
        if kept is not None:
            samples = kept[1]
        elif channels and self.backend == 'kernel':   # the compiled walk, same numbers
            from cvj_ros.physics.kernel.tree_samples import TreeKernelSamples
            try:
                samples = TreeKernelSamples(dl)
            except NotImplementedError:
                pass
        mids = None
        if kept is not None:
            mids = kept[2]
        elif self.scene.is_tree and self.backend == 'kernel':
            # the intermediate members compiled (outputs_nb.fill_mid_samples: the same bytes
            # as the Python fill_mid on the vehicle scenes), the rest left to Python
            from cvj_ros.physics.kernel.outputs_nb import mid_table
            mids = mid_table(dl)
            self._tree_plans = {key: (stepper, samples, mids)}   # the latest options only

        def record(k: int, x: FloatArray) -> None:
            tk = float(times[k])
            if not np.all(np.isfinite(x)):
                raise SolverError(f'state became non-finite at t = {tk:g} s')
            if samples is not None:
                te[k], tl[k], res[k], wheels = samples(tk, x, e_torque, e0, pos[k], vel[k], eff[k])
                channels['vehicle_speed'][k] = dl.vehicle_speed(x)
                for cols, values in zip(wheel_cols, wheels):
                    for col, value in zip(cols, values):
                        col[k] = value
                if progress is not None:
                    progress(tk)
                return
            if channels:    # a vehicle scene: one kinematics and force pass per sample
                te[k], tl[k], pos[k], vel[k], eff[k], res[k], wheels = dl.sample_outputs(
                    tk, x, e_torque, e0)
                channels['vehicle_speed'][k] = dl.vehicle_speed(x)
                for cols, values in zip(wheel_cols, wheels):
                    for col, value in zip(cols, values):
                        col[k] = value
                if progress is not None:
                    progress(tk)
                return
            te[k], tl[k] = self.torques(tk, x)
            pos[k], vel[k], eff[k] = dl.joint_states_fast(x, te[k], tl[k])
            res[k] = dl.energy_residual(x, e0) if dl.track_energy else math.nan
            if progress is not None:
                progress(tk)

        breaks = self.breakpoints(float(times[-1])) if breakpoints else _NO_BREAKS
        record(0, x)
        if sampling == 'land':
            # the steps land on grid; row j of it is a sample where is_sample[j]
            grid, rows = landing_grid(times, breaks)
            is_sample = np.zeros(grid.size, dtype=bool)
            is_sample[rows] = True
            if progress is None and self.backend == 'kernel':
                # every landing in one compiled call (KernelStepper._land: the same steps
                # and bytes as the advance_to loop below), then the samples' outputs
                XG = np.empty((grid.size, x0.size))
                XG[0] = x0
                c0 = clock()
                stepper._land(np.ascontiguousarray(grid, dtype=np.float64), XG)
                integ = clock() - c0
                for k in range(1, times.size):
                    record(k, XG[rows[k]])
                x = stepper.y
            else:
                k = 1
                for j in range(1, grid.size):
                    c0 = clock()
                    x = stepper.advance_to(float(grid[j]))
                    integ += clock() - c0
                    if is_sample[j]:
                        record(k, x)
                        k += 1
        else:
            if breaks.size:
                # samples are not landings, so a breakpoint on a sample is kept too;
                # merged with the two end times only, then the ends taken out again
                grid, rows = landing_grid(times[[0, -1]], breaks)
                breaks = np.delete(grid, rows)
            k = 1
            t_end = float(times[-1])
            bounds = [float(b) for b in breaks] + [t_end]
            i_b = 0
            while k < times.size:
                while i_b < len(bounds) - 1 and stepper.t >= bounds[i_b]:
                    i_b += 1
                c0 = clock()
                t_new = stepper.step(bounds[i_b])
                integ += clock() - c0
                while k < times.size and times[k] <= t_new:
                    x = stepper.y if times[k] == t_new else stepper.dense(float(times[k]))
                    record(k, np.asarray(x, dtype=float))
                    k += 1
            x = stepper.y
        if mids is None:
            dl.fill_mid(pos, vel)
        else:
            mtab, mfp, python_members = mids
            if mtab.shape[0]:
                entry_point_once, _outputs, fill_mid_samples = _outputs_kernel()
                args = (pos, vel, mtab, mfp)
                entry_point_once(fill_mid_samples, args)(*args)
            if python_members:
                dl.fill_mid(pos, vel, members=python_members)
        trace = self._finish(stepper, times, pos, vel, eff, te, tl, res, x, integ,
                             time.perf_counter() - wall0)
        trace.channels = channels
        return trace

    def summary(self, *, transient: float | None = None) -> dict[str, Any]:
        """Summary of the last run (runs the scene first if needed): the steady window
        (cvj_ros.physics.steady; ``transient`` s sets its start), per-shaft metrics over it
        (cvj_ros.physics.metrics), energy residual, solver stats, wall time per simulated
        second, fidelity report."""
        from cvj_ros.physics.metrics import steady_window, summarize
        tr = self.last_trace or self.run()
        sim_time = float(tr.t[-1] - tr.t[0]) or 1.0
        window = steady_window(tr.t, tr.names, tr.velocity, tr.effort, transient=transient)
        out = {'scene': self.scene.name, 'duration': float(tr.t[-1]),
                'window': window.to_dict(), 'window_text': window.describe(),
                'shafts': summarize(tr, window=window),
                'energy_residual': tr.max_energy_residual,
                'solver': dict(tr.solver), 'wall_time': tr.wall_time,
                'wall_per_sim_second': tr.wall_time / sim_time,
                'fidelity': self.fidelity_report.to_dict()}
        if tr.channels:
            out['vehicle'] = vehicle_summary(tr)
        return out


def vehicle_summary(tr: Trace) -> dict[str, Any]:
    """A vehicle run's body and tyres: speed at start and end (km/h) and per wheel the final
    relaxed slip, the mean F_x and F_z (N) over the record and how many samples had the
    tyre status NO_LOAD (F_z <= 0)."""
    ch = tr.channels
    v = ch['vehicle_speed']
    wheels = {}
    for key in ch:
        if key.endswith('.slip'):
            w = key[:-5]
            wheels[w] = {'slip_end': float(ch[key][-1]), 'fx_mean': float(np.mean(ch[f'{w}.fx'])),
                         'fz_mean': float(np.mean(ch[f'{w}.fz'])),
                         'no_load_samples': int(np.count_nonzero(ch[f'{w}.status']))}
    return {'speed_start_kmh': float(v[0]) * 3.6, 'speed_end_kmh': float(v[-1]) * 3.6,
            'wheels': wheels}
