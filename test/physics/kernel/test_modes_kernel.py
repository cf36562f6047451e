"""Clutch, gearbox and brake modes on the compiled kernel against the Python reference.

Every hard case of test/hard_cases/test_clutch_brake_modes.py (engagement at large slip,
judder with and without damping, brake hold and release on a grade, stall, shift under load,
refused gears, command rows at the exchange step, random command schedules) and the shipped
launch_clutch_chain run on both backends.

On the same mesh (the reference replays the kernel's accepted step sizes: an adaptive step
controller turns rounding differences of the error norm, numpy/BLAS sums in the reference,
fixed loops in the kernel, into different accept/reject decisions after a few hundred
steps, hence different meshes and tolerance-sized differences) the compiled run must
reproduce the reference's event sequence, every event time to 1e-12 relative
(|t_k - t_p| <= 1e-12 max(1 s, t_p)), every sampled
shaft speed relative to that shaft's largest speed over the run
(|w_k - w_p| / max(max |w_p|, 1 rad/s)) and the final section angles, speeds and work
integrals relative (floor 1) to TOL_STATE. Free-running (each
backend its own mesh) the two find the same events.
"""
from __future__ import annotations

import importlib.util
import math
from pathlib import Path

import numpy as np
import pytest

import cvj_ros.physics.hybrid.simulate as hs
from cvj_ros.physics.hybrid import HybridResult, HybridSimulation
from cvj_ros.physics.hybrid.from_scene import hybrid_simulation
from cvj_ros.physics.scene import load_scene, shipped_scenes

pytest.importorskip('numba')
from cvj_ros.physics.kernel.modes import KernelHybridSimulation  # noqa: E402

TOL = 1e-12          # event times
# sampled speeds and final states: the reference adds in the kernel's order
# (solvers._ordered_rows); measured dop853 0.0, dopri5 0.0 (DOPRI5_EXACT below; before,
# <= 7.1e-12). With numpy/BLAS dot products the stability-bound stretches
# amplified their last bits (launch_clutch_chain's slipping disc, 2.0-2.5 s: 2.8e-11; the
# undamped judder's final angles after 135 events: 6.3e-12); docs/clutch_gearbox.md
TOL_STATE = 1e-10
# dopri5 on the kernel's mesh: the same bits. The kernel's dense output returns y at a step's
# end as the reference's Dopri5Stepper.dense does (segment_nb._dense; the interpolant there
# differs from y in the last bits and moved Brent's bracket: launch_clutch_chain 3.2e-14 /
# 5.2e-12 / 4.9e-13 before), so every event time, sample and final state is equal: measured
# 0.0 on launch_clutch_chain, every hard case, the 12 random chains and fuzzed launches 0-15
DOPRI5_EXACT = (0.0, 0.0)


def assert_same_run(rp, rk, tol_t: float = TOL, tol_x: float = TOL_STATE) -> dict[str, float]:
    """Kernel result rk equals reference result rp (module docstring's measure); returns
    the largest relative differences found."""
    assert [(e.element, e.before, e.after, e.cause) for e in rk.events] == \
        [(e.element, e.before, e.after, e.cause) for e in rp.events]
    assert [s.split(':', 1)[1] for s in rk.statuses] == [s.split(':', 1)[1] for s in rp.statuses]
    assert (rk.stall is None) == (rp.stall is None)
    dt = max([abs(a.t - b.t) / max(1.0, abs(b.t)) for a, b in zip(rk.events, rp.events)],
             default=0.0)
    assert dt <= tol_t, dt
    assert abs(rk.t_end - rp.t_end) <= tol_t * max(1.0, rp.t_end)
    assert rk.speed.shape == rp.speed.shape
    assert np.array_equal(rk.gear, rp.gear)
    scale = np.maximum(np.nanmax(np.abs(rp.speed), axis=0, initial=0.0), 1.0)
    ds = float(np.nanmax(np.abs(rk.speed - rp.speed) / scale, initial=0.0))
    assert ds <= tol_x, ds
    fin = 0.0
    for a, b in ((rk.final.q, rp.final.q), (rk.final.v, rp.final.v), (rk.final.work, rp.final.work)):
        fin = max(fin, float(np.max(np.abs(a - b) / np.maximum(np.abs(b), 1.0))))
    assert fin <= tol_x, fin
    return {'event_t': dt, 'speed': ds, 'final': fin}


def replay_on_mesh(module, run, sim, log: list[np.ndarray], monkeypatch):
    """``run(sim)`` (a reference run) on the kernel's mesh: the stepper that
    ``module.make_stepper`` gives its k-th integrated mode segment takes the k-th logged step
    sizes, each accepted (the kernel accepted it). Chains: ``hybrid.simulate``; vehicle
    trees: ``hybrid.tree_sim`` (test_tree_modes_kernel.py). A segment takes its sizes at its
    first step: the reference makes a stepper before it checks for a scheduled shift due at
    the segment's start (a clutch locking with the synchronous speed already past a shift
    speed), the kernel checks before it integrates, and that segment takes no step."""
    segments = iter(log)
    plain = module.make_stepper

    def make(*args, **kwargs):
        st = plain(*args, **kwargs)
        sizes: list = []
        attempt, step = st._attempt, st.step

        def forced_attempt(h):
            err, y_new = attempt(h)
            return min(err, 1.0), y_new

        def forced_step(t_bound):
            if not sizes:
                sizes.append(iter(next(segments)))
            st.h = next(sizes[0])
            return step(t_bound)
        st._attempt, st.step = forced_attempt, forced_step
        return st
    with monkeypatch.context() as m:
        m.setattr(module, 'make_stepper', make)
        return run(sim)


def replay(sim: HybridSimulation, log: list[np.ndarray], monkeypatch) -> HybridResult:
    """The chain reference ``sim`` on the kernel's mesh (:func:`replay_on_mesh`)."""
    return replay_on_mesh(hs, PLAIN_RUN, sim, log, monkeypatch)


PLAIN_RUN = HybridSimulation.run


def _patch_twin(monkeypatch, method: str | None = None) -> list[dict[str, float]]:
    """Every HybridSimulation.run also runs its kernel twin (with ``method`` when given, on
    both) and compares it with the reference replayed on the kernel's mesh; the test sees
    the free-running reference."""
    seen: list[dict[str, float]] = []

    def run(self):
        if method is not None:
            self.method = method
        k = KernelHybridSimulation.from_reference(self, step_log=True)
        free = KernelHybridSimulation.from_reference(self)
        rk = k.run()
        rp = replay(self, k.step_log, monkeypatch)
        seen.append(assert_same_run(rp, rk, *(DOPRI5_EXACT if self.method == 'dopri5'
                                              else (TOL, TOL_STATE))))
        self.events.clear()
        self.statuses.clear()
        self._gear_seen = None
        free_r = PLAIN_RUN(self)
        rf = free.run()
        assert [(e.element, e.after) for e in rf.events] == [(e.element, e.after) for e in free_r.events]
        return free_r
    monkeypatch.setattr(HybridSimulation, 'run', run)
    return seen


@pytest.fixture
def twin(monkeypatch):
    return _patch_twin(monkeypatch)


@pytest.fixture
def twin853(monkeypatch):
    return _patch_twin(monkeypatch, 'dop853')


def test_launch_clutch_chain_matches_the_reference(monkeypatch) -> None:
    scene = load_scene(shipped_scenes()['launch_clutch_chain'])
    k = KernelHybridSimulation.from_reference(hybrid_simulation(scene), step_log=True)
    rk = k.run()
    rp = replay(hybrid_simulation(scene), k.step_log, monkeypatch)
    assert len(rp.events) >= 9
    # the reference's dopri5 adds in the kernel's order (solvers._ordered_rows) and both
    # return y at a step's end: equal (DOPRI5_EXACT; with numpy/BLAS dot products 0.7-2.1e-12
    # at the lock at 2.96 s, varying between processes)
    assert_same_run(rp, rk, *DOPRI5_EXACT)
    assert rk.max_energy_residual < 1e-7
    # free-running: each its own mesh (rtol 1e-8): the same events, times to ~1e-10 s
    rf = hybrid_simulation(scene).run()
    assert [(e.element, e.after) for e in rf.events] == [(e.element, e.after) for e in rk.events]
    assert max(abs(a.t - b.t) for a, b in zip(rf.events, rk.events)) < 1e-8


def _hard_cases():
    # the cases themselves, one definition: test/hard_cases/test_clutch_brake_modes.py
    spec = importlib.util.spec_from_file_location(
        '_clutch_hard_cases', Path(__file__).resolve().parents[2] / 'hard_cases'
        / 'test_clutch_brake_modes.py')
    hc = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(hc)
    out = []
    for name in sorted(vars(hc)):
        fn = getattr(hc, name)
        if name.startswith('test_') and callable(fn):
            marks = getattr(fn, 'pytestmark', [])
            seeds = [m.args[1] for m in marks if m.name == 'parametrize']
            if seeds:      # the reference's seeds and as many more random schedules
                # (the extra seeds n..2n-1 under -m slow: make test runs the n seeds the
                # hard case itself runs on the reference)
                n = len(list(seeds[0]))
                out += [pytest.param(fn, {'seed': s}, id=f'{name}[{s}]',
                                     marks=(pytest.mark.slow,) if s >= n else ())
                        for s in range(2 * n)]
            else:
                out.append(pytest.param(fn, {}, id=name))
    return out


@pytest.mark.parametrize(('case', 'kwargs'), _hard_cases())
def test_hard_case_matches_the_reference(twin, case, kwargs) -> None:
    case(**kwargs)          # the case's own assertions on the reference, plus the twin's
    assert twin, 'the case ran no simulation'


_DOP853_CASES = ('test_engagement_at_large_speed_difference_locks_at_the_closed_form_time',
                 'test_judder_with_low_damping_locates_every_transition',
                 'test_shift_under_load_matches_the_closed_form',
                 'test_stall_is_reported_at_the_closed_form_time',
                 'test_brake_release_on_a_grade_rolls_back_when_the_ramp_crosses_the_hold_torque',
                 'test_random_command_schedules_keep_the_invariants[0]',
                 'test_random_command_schedules_keep_the_invariants[1]')


@pytest.mark.parametrize(('case', 'kwargs'),
                         [p for p in _hard_cases() if p.id in _DOP853_CASES])
def test_hard_case_on_dop853_matches_the_reference(twin853, case, kwargs) -> None:
    case(**kwargs)
    assert twin853, 'the case ran no simulation'


def test_launch_clutch_chain_on_dop853_matches_the_reference(monkeypatch) -> None:
    scene = load_scene(shipped_scenes()['launch_clutch_chain'])
    k = KernelHybridSimulation.from_reference(hybrid_simulation(scene, method='dop853'),
                                              step_log=True)
    rk = k.run()
    rp = replay(hybrid_simulation(scene, method='dop853'), k.step_log, monkeypatch)
    # the reference's dop853 adds its stage sums, error estimates and dense output in the
    # kernel's order (solvers._ordered_rows): measured 0.0 in event times, speeds and final
    # states (with numpy/BLAS dot products 3.7e-10, 5.3e-7, 6.5e-10: dop853's 4x longer
    # steps at the stability edge of the slipping stretch, 2.0-2.5 s, amplified the last
    # bits); the hard cases' bounds
    assert_same_run(rp, rk)
    assert rk.max_energy_residual < 1e-7


def fuzzed_rows(rng: np.random.Generator, h: float, gears: bool, duration: float = 1.5,
                n: int = 14) -> list[dict]:
    """A random command schedule: a row at 0 (brake and clutch pedal 0 or 1, throttle
    0.3..0.6, with ``gears`` a gear -1..2) and ``n`` rows over ``duration`` whose times are
    uniform, on the exchange-step grid (``h``), one exchange step after another row or at
    the same time as one; each may set throttle (0.3..1), the clutch pedal (0, 1 or
    uniform: steps and ramps), the brake (releases, full, partial) and with ``gears`` a
    gear -1..4 (refused ones included). Shared by the chain and vehicle fuzz."""
    times: list[float] = []
    for _ in range(n):
        kind = rng.integers(4)
        if kind == 0 or not times:
            times.append(float(rng.uniform(0.0, duration)))
        elif kind == 1:
            times.append(int(rng.integers(1, int(duration / h))) * h)
        elif kind == 2:
            times.append(min(duration, times[int(rng.integers(len(times)))] + h))
        else:
            times.append(times[int(rng.integers(len(times)))])
    rows = [{'t': 0.0, 'brake': float(rng.choice([0.0, 1.0])), 'clutch': float(rng.choice([0.0, 1.0])),
             'throttle': float(rng.uniform(0.3, 0.6))}]
    if gears:
        rows[0]['gear'] = int(rng.integers(-1, 3))
    for t in sorted(times):
        row: dict = {'t': float(t)}
        if rng.random() < 0.5:
            row['throttle'] = float(rng.uniform(0.3, 1.0))
        if rng.random() < 0.5:
            row['clutch'] = float(rng.choice([0.0, 1.0, rng.uniform()]))
        if rng.random() < 0.4:
            row['brake'] = float(rng.choice([0.0, 0.0, 1.0, rng.uniform(0.0, 0.5)]))
        if gears and rng.random() < 0.3:
            row['gear'] = int(rng.integers(-1, 5))
        rows.append(row)
    return rows


def _random_chain_sim(seed: int):
    """A random chain (inertias, packs, ratios, optional damper, Hooke joint and brake, map
    engine, road load on a random grade) under 20 random command rows over 3 s; returns a
    maker of fresh simulations of it."""
    from cvj_ros.physics.engine import engine_from_spec
    from cvj_ros.physics.hybrid import Brake, Clutch, CommandSchedule, CoulombPack, Gearbox, HybridChain
    from cvj_ros.physics.load import RoadLoad
    from cvj_ros.physics.scene import Inertia, Joint, Spring
    rng = np.random.default_rng(1000 + seed)
    els = [Inertia('engine_crank', rng.uniform(0.1, 0.3)),
           Clutch('clutch', rng.uniform(0.02, 0.1), rng.uniform(0.005, 0.03),
                  CoulombPack(mu_s=0.4, mu_k=rng.uniform(0.2, 0.4), cgeo=0.2,
                              fn_max=rng.uniform(2000, 6000)))]
    if rng.uniform() < 0.5:
        els += [Spring('damper', rng.uniform(500, 3000), rng.uniform(0.0, 3.0)),
                Inertia('input_shaft', rng.uniform(0.005, 0.02))]
    els.append(Gearbox('gearbox', 0.01, 0.02, tuple(sorted(rng.uniform(4, 15, 3))[::-1]), -12.0,
                       max_input_speed=650.0))
    if rng.uniform() < 0.5:
        els += [Joint('cardan', 'hooke', {'beta_deg': float(rng.uniform(5, 25))}),
                Inertia('shaft', 0.05)]
    els += [Spring('halfshaft', rng.uniform(3000, 9000), rng.uniform(2, 20)),
            Inertia('wheel', rng.uniform(100, 150))]
    if rng.uniform() < 0.8:
        els.append(Brake('brake', CoulombPack(mu_s=0.5, mu_k=0.4, cgeo=0.25, fn_max=40000.0)))
    chain = HybridChain(els)
    rows = [(0.0, {'clutch': 1.0, 'gear': 1, 'throttle': 0.0,
                   **({'brake': 1.0} if chain.brake else {})})]
    for t in np.sort(rng.uniform(0.05, 3.0, 20)):
        ch = rng.choice(['clutch', 'throttle', 'gear'] + (['brake'] if chain.brake else []))
        rows.append((float(t), {ch: int(rng.integers(-1, 4)) if ch == 'gear'
                                else float(rng.choice([0.0, 1.0, rng.uniform()]))}))
    grade = float(rng.uniform(-5, 10))
    return lambda: HybridSimulation(
        chain, engine=engine_from_spec({'model': 'map', 'throttle': 0.0, 'stall_rpm': 400.0}),
        load=RoadLoad(mass=1500.0, wheel_radius=0.3, final_drive_ratio=4.0, grade_percent=grade),
        schedule=CommandSchedule(rows), duration=3.0, sample_dt=0.01, initial_speed=85.0,
        stall_speed=400 * math.pi / 30, rtol=1e-8, atol=1e-10)


@pytest.mark.parametrize('seed', range(12))
def test_random_chains_and_schedules_match_the_reference(seed: int, monkeypatch) -> None:
    """Fuzz over structure and commands, dopri5: equal (DOPRI5_EXACT; before the kernel
    returned y at a step's end, 0.0 in 8 of 12 and event times <= 2.5e-13, speeds <= 7.1e-12,
    final states <= 3.8e-13 in the others)."""
    mk = _random_chain_sim(seed)
    k = KernelHybridSimulation.from_reference(mk(), step_log=True)
    rk = k.run()
    rp = replay(mk(), k.step_log, monkeypatch)
    assert_same_run(rp, rk, *DOPRI5_EXACT)


def _fuzzed_launch_chain(seed: int) -> dict:
    """launch_clutch_chain on a random grade (-15 .. 15 %) with a random mass (0.6 .. 1.8 x,
    the wheel shaft's m r^2 with it) under a random 14-row schedule over 1.5 s
    (:func:`fuzzed_rows`, gears -1..4 commanded)."""
    import yaml
    rng = np.random.default_rng(9000 + seed)
    d = yaml.safe_load(Path(shipped_scenes()['launch_clutch_chain']).read_text())
    rows = fuzzed_rows(rng, float(d['exchange_step']), gears=True)
    load = d['load']
    mass = float(load['mass'] * rng.uniform(0.6, 1.8))
    wheel = next(e for e in d['driveline'] if e.get('name') == 'wheel')
    wheel['J'] = float(wheel['J'] - load['mass'] * load['wheel_radius'] ** 2
                       + mass * load['wheel_radius'] ** 2)
    d['load'] = dict(load, mass=mass, grade_percent=float(rng.uniform(-15.0, 15.0)))
    d.update(duration=1.5, commands=rows)
    return d


def chain_fuzz_case(seed: int, method: str, monkeypatch, tol_t: float = TOL,
                    tol_x: float = TOL_STATE) -> dict[str, float]:
    """Kernel = reference on :func:`_fuzzed_launch_chain` with ``method``, the reference
    replayed on the kernel's mesh (:func:`replay_on_mesh`); returns the differences and
    the event count."""
    from cvj_ros.physics.scene import parse_scene
    mk = lambda: hybrid_simulation(parse_scene(_fuzzed_launch_chain(seed)), method=method)  # noqa: E731
    k = KernelHybridSimulation.from_reference(mk(), step_log=True)
    rk = k.run()
    rp = replay(mk(), k.step_log, monkeypatch)
    got = assert_same_run(rp, rk, tol_t=tol_t, tol_x=tol_x)
    # the energy residual: the same on both (dop853 seed 0 reaches 1.1e-7 on both, its
    # stall at 0.31 s; a property of the method at rtol 1e-8, not of the backend), within
    # the states' bound (the residual is a function of the states over the energy scale)
    assert abs(rk.max_energy_residual - rp.max_energy_residual) <= tol_x
    got['events'] = len(rk.events)
    return got


# bounds per method: dopri5 equal (DOPRI5_EXACT), dop853 the hard cases' (TOL, TOL_STATE),
# the reference adding in the kernel's order (solvers._ordered_rows; test_fuzzed_launch_chain)
_CHAIN_FUZZ_TOL = {'dopri5': DOPRI5_EXACT, 'dop853': (TOL, TOL_STATE)}


@pytest.mark.parametrize('method', ['dopri5', 'dop853'])
@pytest.mark.parametrize('seed', range(4))
def test_fuzzed_launch_chain(seed: int, method: str, monkeypatch) -> None:
    """Kernel = reference on fuzzed launch_clutch_chain scenes (random grade, mass and
    14-row schedule, rows on the exchange-step grid and at the same time), on both methods
    that the kernel runs with an explicit stepper; more seeds under ``-m slow``. Measured
    (seeds 0..15, 1-11 events each, 72 in all, 10 runs stalling, the same on both), the
    reference adding in the kernel's order: dop853 0.0 everywhere; dopri5 0.0 in seeds 0-15
    since the kernel returns y at a step's end (before: 0.0 in 11 of 16, event times <= 7.2e-15,
    samples <= 8.9e-14, final states <= 2.1e-12 in the others; with numpy/BLAS dot products:
    dopri5 7.8e-14, 3.8e-10, 1.6e-12; dop853 4.7e-11, 5.5e-7, 8.9e-10)."""
    chain_fuzz_case(seed, method, monkeypatch, *_CHAIN_FUZZ_TOL[method])


@pytest.mark.slow
@pytest.mark.parametrize('method', ['dopri5', 'dop853'])
@pytest.mark.parametrize('seed', range(4, 16))
def test_fuzzed_launch_chain_more(seed: int, method: str, monkeypatch) -> None:
    """Seeds 4..15 on both methods (:func:`test_fuzzed_launch_chain`)."""
    chain_fuzz_case(seed, method, monkeypatch, *_CHAIN_FUZZ_TOL[method])


def test_unsupported_method_is_refused_in_one_line() -> None:
    """A method without dense output: refused by the scene (one line naming the field) and,
    given to the kernel class directly, by it (one line naming the methods it runs)."""
    from cvj_ros.errors import SceneError
    scene = load_scene(shipped_scenes()['launch_clutch_chain'])
    with pytest.raises(SceneError, match='solver.method'):
        hybrid_simulation(scene, method='ros2')
    sim = hybrid_simulation(scene)
    sim.method = 'rk4'
    with pytest.raises(NotImplementedError, match='dopri5, dop853, rodas3, rodas4, rosenbrock') as exc:
        KernelHybridSimulation.from_reference(sim)
    assert '\n' not in str(exc.value)


# --- the Rosenbrock methods (rodas3, rodas4, RODAS5P 'rosenbrock') --------------------------

ROSENBROCK = ('rodas3', 'rodas4', 'rosenbrock')


def _patch_ros_twin(monkeypatch, method: str) -> list[dict[str, float]]:
    """Every HybridSimulation.run also runs its simulation with ``method`` on the kernel and
    on the reference replayed on the kernel's mesh and compares them; the case's own
    assertions (tuned to its dopri5 tolerances) see the plain reference with its method."""
    seen: list[dict[str, float]] = []

    def run(self):
        plain = self.method
        self.method = method
        k = KernelHybridSimulation.from_reference(self, step_log=True)
        rk = k.run()
        rp = replay(self, k.step_log, monkeypatch)
        seen.append(assert_same_run(rp, rk, tol_t=ROS_TOL_T, tol_x=ROS_TOL_X))
        assert rk.stats['steps'] == sum(len(h) for h in k.step_log)
        self.method = plain
        self.events.clear()
        self.statuses.clear()
        self._gear_seen = None
        return PLAIN_RUN(self)
    monkeypatch.setattr(HybridSimulation, 'run', run)
    return seen


# The Rosenbrock methods use the mode's analytic Jacobian in both backends
# (kernel/modes_jac_nb.py, hybrid/chain_jac.py; a forward-difference Jacobian divided the
# backends' last-bit differences by its increment ~1e-8 and gave ~1e-9 in states), so they
# agree as dopri5 does: measured on the hard cases below event and end times <= 2.8e-15
# relative, sampled speeds <= 1.1e-12, final states <= 4.1e-12 (the undamped judder on
# RODAS5P after its transitions, as dopri5's 6.3e-12 there); the bounds are dopri5's.
ROS_TOL_T, ROS_TOL_X = TOL, TOL_STATE
# cheap in CI; the rest (the reference's RODAS steps in Python at the cases' rtol 1e-10: 30 s
# to 260 s each on the shared machine) under -m slow
_ROS_CASES = {
    'test_engagement_at_large_speed_difference_locks_at_the_closed_form_time': ROSENBROCK,
    'test_judder_locates_every_transition': ('rosenbrock',),
    'test_brake_holds_on_a_grade_for_10_s_with_speed_exactly_zero': ROSENBROCK,
    'test_brake_release_on_a_grade_rolls_back_when_the_ramp_crosses_the_hold_torque': ROSENBROCK,
    'test_shift_under_load_matches_the_closed_form': ROSENBROCK,
    'test_random_command_schedules_keep_the_invariants[0]': ('rodas4', 'rosenbrock'),
    # the clutch pedal jumps at 0.1 s (two rows at one time): the segment's commands are
    # one-sided at its end (commands.Ramp.at; the Rosenbrock stages there also on the left
    # limit, segment_nb._ros_stages): the reference reaches the row in 16 (rodas3, rodas4)
    # and 17 (RODAS5P) steps with no rejection; before, rodas4 127 / RODAS5P 125 steps crept
    # to it and rodas3 ended in a step-size underflow 1.5e-16 s before it in both backends
    'test_stall_is_reported_at_the_closed_form_time': ROSENBROCK}
_ROS_SLOW = {'test_judder_locates_every_transition': ('rodas3', 'rodas4'),
             'test_random_command_schedules_keep_the_invariants[0]': ('rodas3',)}


def _ros_params():
    out = []
    for p in _hard_cases():
        for table, marks in ((_ROS_CASES, ()), (_ROS_SLOW, (pytest.mark.slow,))):
            for method in table.get(p.id, ()):
                out.append(pytest.param(*p.values, method, marks=marks, id=f'{p.id}-{method}'))
    return out


@pytest.mark.parametrize(('case', 'kwargs', 'method'), _ros_params())
def test_hard_case_on_rosenbrock_matches_the_reference(monkeypatch, case, kwargs, method) -> None:
    """The kernel's Rosenbrock steps on the mode's rhs against the reference's, on the
    kernel's mesh: the same events, times and states to the bounds above."""
    seen = _patch_ros_twin(monkeypatch, method)
    case(**kwargs)
    assert seen, 'the case ran no simulation'


@pytest.mark.parametrize('method', [pytest.param('rodas3', marks=pytest.mark.slow),
                                    pytest.param('rodas4', marks=pytest.mark.slow),
                                    'rosenbrock'])
def test_launch_clutch_chain_on_rosenbrock_matches_the_reference(monkeypatch, method) -> None:
    """Every event, sample and the final state of the shipped launch on the kernel's mesh,
    and the energy residual at the tolerance through every transition (rtol 1e-8).
    Measured (rosenbrock, rodas4; analytic Jacobian): event times 1.6e-14, 1.0e-13
    relative; sampled speeds 4.6e-12, 2.5e-12 (the disc on its damper while the clutch
    slips, 2.0-2.5 s, amplifies the last bits as with dopri5); final states 5.6e-13,
    7.2e-13; energy residual 2.7e-10, 8.5e-10. Bounds: dopri5's (TOL, TOL_STATE)."""
    scene = load_scene(shipped_scenes()['launch_clutch_chain'])
    k = KernelHybridSimulation.from_reference(hybrid_simulation(scene, method=method),
                                              step_log=True)
    rk = k.run()
    rp = replay(hybrid_simulation(scene, method=method), k.step_log, monkeypatch)
    assert len(rk.events) >= 9
    assert_same_run(rp, rk, tol_t=TOL, tol_x=TOL_STATE)
    assert rk.max_energy_residual < 1e-7
    assert np.isfinite(rk.energy_residual).all()


def test_every_method_shares_one_compiled_segment() -> None:
    """segment_nb.mode_segment takes the method (and chain or tree) as a run-time flag and
    every method's coefficients with the same numba types, so one compiled code - one cache
    entry, one cold compile - serves dopri5, dop853 and the RODAS methods."""
    from numba import typeof

    from cvj_ros.physics.kernel.modes import KERNEL_MODE_METHODS, _coefficients
    from cvj_ros.physics.kernel.tree_modes import KERNEL_TREE_MODE_METHODS
    assert set(KERNEL_TREE_MODE_METHODS) == set(KERNEL_MODE_METHODS)
    types = {tuple(typeof(a) for a in _coefficients(m)) for m in KERNEL_MODE_METHODS}
    assert len(types) == 1


def test_kernel_ramp_sees_a_step_at_the_segment_end_as_the_reference() -> None:
    """modes_nb.ramp (its Python body: the same arithmetic) equals commands.Ramp.at bit for
    bit at random times, row times and a rounding either side of them, for segment ends on a
    step (two rows at one time), on a plain row and beyond the last row; the block's t_end
    slot is what mode_segment writes (modes_nb.set_ramp_end)."""
    from cvj_ros.physics.hybrid.commands import CommandSchedule
    from cvj_ros.physics.kernel.modes_nb import ramp, set_ramp_end
    s = CommandSchedule([(0.0, {'clutch': 1.0}), (0.1, {'clutch': 1.0}), (0.1, {'clutch': 0.0}),
                         (0.7, {'clutch': 0.3}), (0.7, {'clutch': 0.3}), (1.3, {'clutch': 0.9})])
    r = s.channels['clutch']
    fp = np.array([float(len(r.times)), *r.times, *r.values, math.inf])
    rng = np.random.default_rng(5)
    ts = [*rng.uniform(-0.5, 2.0, 200), *r.times]
    ts += [math.nextafter(t, d) for t in r.times for d in (-1.0, 2.0)]
    for t_end in (math.inf, 0.1, 0.7, 1.3, 0.4, 2.0):
        set_ramp_end.py_func(fp, 0, t_end)
        for t in ts:
            assert ramp.py_func(t, fp, 0) == r.at(t, t_end), (t, t_end)
    set_ramp_end.py_func(fp, 0, 0.1)
    assert (ramp.py_func(0.1, fp, 0), r(0.1)) == (1.0, 0.0)


def _stiff_damper_scene(stiffness: float, damping: float):
    """launch_clutch_chain with a stiffer, damped clutch damper (the disc, 0.01 kg m^2, on
    ``stiffness`` N m/rad and ``damping`` N m s/rad)."""
    import yaml

    from cvj_ros.physics.scene import parse_scene
    data = yaml.safe_load(Path(shipped_scenes()['launch_clutch_chain']).read_text())
    for el in data['driveline']:
        if el.get('name') == 'clutch_damper':
            el['stiffness'], el['damping'] = stiffness, damping
    return parse_scene(data)


def test_stiff_clutch_damper_takes_far_fewer_steps_on_rodas() -> None:
    """A clutch damper of 1e6 N m/rad, 100 N m s/rad on the 0.01 kg m^2 disc (eigenvalues
    ~ -5000 +- 8700i 1/s: stiff against the launch's seconds) at rtol 1e-6: dopri5 is held
    at its stability limit (measured 25858 steps), the L-stable RODAS methods follow the
    accuracy (rodas3 3799, rodas4 1287, RODAS5P 612). Deterministic counts of the kernel's
    step control; the bound (4x) is far below the measured 6.8x of the weakest."""
    scene = _stiff_damper_scene(1e6, 100.0)
    runs = {m: KernelHybridSimulation.from_reference(
        hybrid_simulation(scene, method=m, rtol=1e-6, atol=1e-8)).run()
        for m in ('dopri5', 'rodas3', 'rodas4', 'rosenbrock')}
    ref = runs.pop('dopri5')
    for m, r in runs.items():
        assert [(e.element, e.after) for e in r.events] == [(e.element, e.after) for e in ref.events], m
        # event times agree to the tolerance's order (measured <= 1.2e-5 s apart)
        assert max(abs(a.t - b.t) for a, b in zip(r.events, ref.events)) < 1e-4, m
        assert r.stats['steps'] * 4 < ref.stats['steps'], (m, r.stats, ref.stats)
        assert r.max_energy_residual < 1e-5, m


def test_carried_step_finds_the_same_events() -> None:
    """carry_step (each mode starts with the previous mode's last step proposal instead of
    Hairer's estimate) is an option: the same events, times to the tolerance's order. It saves
    no steps here (docs/clutch_gearbox.md: launch_clutch_chain 2288 against 2290, the undamped
    judder 8606 against 8496: the step after an event is limited by the new mode's dynamics)."""
    scene = load_scene(shipped_scenes()['launch_clutch_chain'])
    rk = KernelHybridSimulation.from_reference(hybrid_simulation(scene, duration=5.0)).run()
    rc = KernelHybridSimulation.from_reference(hybrid_simulation(scene, duration=5.0),
                                               carry_step=True).run()
    assert [(e.element, e.after) for e in rc.events] == [(e.element, e.after) for e in rk.events]
    assert max(abs(a.t - b.t) for a, b in zip(rc.events, rk.events)) < 1e-6
    assert rc.stats['steps'] != rk.stats['steps'] or rc.stats['nfev'] != rk.stats['nfev']
    assert rc.max_energy_residual < 1e-7


# --- the explicit pairs with interpolants (tsit5, vern6, vern7, vern8) ----------------------

ERK = ('tsit5', 'vern6', 'vern7', 'vern8')
# vern7 / vern8: the cases whose reference run (Python, replayed and free-running) takes more
# than a few seconds are under -m slow (the judders, the 10 s brake hold and the random
# schedule: 17-46 s each on the loaded 2-core machine, as tsit5's and vern6's)
_ERK_SLOW = ('test_judder_locates_every_transition',
             'test_judder_with_low_damping_locates_every_transition',
             'test_brake_holds_on_a_grade_for_10_s_with_speed_exactly_zero',
             'test_random_command_schedules_keep_the_invariants[0]')


def _erk_marks(method: str, slow: bool = True) -> tuple:
    return (pytest.mark.slow,) if slow and method in ('vern7', 'vern8') else ()
_ERK_CASES = ('test_engagement_at_large_speed_difference_locks_at_the_closed_form_time',
              'test_judder_locates_every_transition',
              'test_judder_with_low_damping_locates_every_transition',
              'test_brake_holds_on_a_grade_for_10_s_with_speed_exactly_zero',
              'test_random_command_schedules_keep_the_invariants[0]',
              'test_stall_is_reported_at_the_closed_form_time',
              'test_shift_under_load_matches_the_closed_form')
# the stall case's clutch pedal jumps at 0.1 s and the shift's at 0.5 s (two rows at one
# time), each the end of a segment: the segment's last stage and witnesses see the pedal
# before the jump (commands.Ramp.at, modes_nb.ramp), so the explicit pairs step onto the row
# (before, the FSAL stage at t + h = 0.1 s saw the closed clutch and the error estimate
# rejected every step towards it: 57 rejections down to h = 7e-16 s in the tsit5 reference,
# a step-size underflow in the kernel)


def _patch_erk_twin(monkeypatch, method: str) -> list[dict[str, float]]:
    """Every HybridSimulation.run also runs its simulation with ``method`` on the kernel and on
    the reference replayed on the kernel's mesh (the bounds of the dopri5 hard cases, TOL and
    TOL_STATE), and both free-running (the same events); the case's own assertions (tuned to
    its dopri5 tolerances) see the plain reference with its method."""
    seen: list[dict[str, float]] = []

    def run(self):
        plain = self.method
        self.method = method
        k = KernelHybridSimulation.from_reference(self, step_log=True)
        free = KernelHybridSimulation.from_reference(self)
        rk = k.run()
        rp = replay(self, k.step_log, monkeypatch)
        seen.append(assert_same_run(rp, rk))
        assert rk.stats['steps'] == sum(len(h) for h in k.step_log)
        self.events.clear()
        self.statuses.clear()
        self._gear_seen = None
        free_r = PLAIN_RUN(self)
        rf = free.run()
        assert [(e.element, e.after) for e in rf.events] == \
            [(e.element, e.after) for e in free_r.events]
        self.method = plain
        self.events.clear()
        self.statuses.clear()
        self._gear_seen = None
        return PLAIN_RUN(self)
    monkeypatch.setattr(HybridSimulation, 'run', run)
    return seen


@pytest.mark.parametrize(('case', 'kwargs', 'method'),
                         [pytest.param(*p.values, m, id=f'{p.id}-{m}',
                                       marks=_erk_marks(m, p.id in _ERK_SLOW))
                          for p in _hard_cases() if p.id in _ERK_CASES for m in ERK])
def test_hard_case_on_tsit5_vern6_matches_the_reference(monkeypatch, case, kwargs,
                                                        method) -> None:
    """The kernel's tsit5 / vern6 / vern7 / vern8 steps, interpolants and Brent on them
    against the reference's (solvers._ErkStepper) on the kernel's mesh: the same events,
    times to 1e-12 relative, states to TOL_STATE."""
    seen = _patch_erk_twin(monkeypatch, method)
    case(**kwargs)
    assert seen, 'the case ran no simulation'


# launch_clutch_chain on the kernel's mesh (rtol 1e-8): the reference's stage sums, error
# norm and interpolant add in the kernel's order (solvers._ErkStepper._ordered), so the two
# agree bit for bit, measured 0.0 in event times, sampled speeds and final states (with
# numpy/BLAS dot products they differed by 2.0e-13 / 2.4e-9 in event times, 6.0e-11 / 5.9e-8
# in speeds for tsit5 / vern6: the slipping stretch at 2.0-2.5 s amplified the last bits).
# Bounds: the hard cases' (TOL, TOL_STATE), the issue's 1e-12 for event times.
ERK_CHAIN_TOL = {m: (TOL, TOL_STATE) for m in ERK}


@pytest.mark.parametrize('method', [pytest.param(m, marks=_erk_marks(m)) for m in ERK])
def test_launch_clutch_chain_on_tsit5_vern6_matches_the_reference(monkeypatch, method) -> None:
    """Every event, sample and the final state of the shipped launch on the kernel's mesh,
    and the energy residual at the tolerance through every transition (rtol 1e-8)."""
    scene = load_scene(shipped_scenes()['launch_clutch_chain'])
    k = KernelHybridSimulation.from_reference(hybrid_simulation(scene, method=method),
                                              step_log=True)
    rk = k.run()
    rp = replay(hybrid_simulation(scene, method=method), k.step_log, monkeypatch)
    assert len(rk.events) >= 9
    tol_t, tol_x = ERK_CHAIN_TOL[method]
    assert_same_run(rp, rk, tol_t=tol_t, tol_x=tol_x)
    assert rk.max_energy_residual < 1e-7
    assert np.isfinite(rk.energy_residual).all()
    # against dopri5 on the kernel (each its own mesh, rtol 1e-8): the same events
    r5 = KernelHybridSimulation.from_reference(hybrid_simulation(scene)).run()
    assert [(e.element, e.after) for e in r5.events] == [(e.element, e.after) for e in rk.events]
    assert max(abs(a.t - b.t) for a, b in zip(r5.events, rk.events)) < 1e-6


@pytest.mark.parametrize('method', ERK)
@pytest.mark.parametrize('seed', range(4))
def test_random_chains_and_schedules_on_tsit5_vern6_match_the_reference(seed: int, method: str,
                                                                         monkeypatch) -> None:
    """The fuzz of test_random_chains_and_schedules_match_the_reference (random structure and
    20 random command rows) on the four pairs: event times to TOL, samples and final states to
    TOL_STATE (both backends add in one order, ERK_CHAIN_TOL's comment; measured 0.0)."""
    mk = _random_chain_sim(seed)

    def sim():
        s = mk()
        s.method = method
        return s
    k = KernelHybridSimulation.from_reference(sim(), step_log=True)
    rk = k.run()
    rp = replay(sim(), k.step_log, monkeypatch)
    assert_same_run(rp, rk, tol_t=TOL, tol_x=TOL_STATE)
