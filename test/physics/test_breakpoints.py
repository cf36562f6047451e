"""Load breakpoints (Load.breakpoints) and Simulation.run landing on them: the models list
the right times, the landing grid keeps every sample, and landing buys accuracy the step
controller cannot (a dopri5 step across a C1 knot loses its order)."""
from __future__ import annotations

import numpy as np
import pytest

from cvj_ros.physics.load import (BrakeStepsLoad, ConstantLoad, RandomLoad, SumLoad,
                                  TimeSeriesLoad)
from cvj_ros.physics.scene import find_scene, load_scene
from cvj_ros.physics.simulate import Simulation, dense_segments, dopri5_segments, landing_grid


def test_random_load_breakpoints_are_its_knots():
    load = RandomLoad(seed=1, sample_interval=0.01)
    b = load.breakpoints(0.0, 0.05)
    np.testing.assert_allclose(b, [0.01, 0.02, 0.03, 0.04], rtol=0, atol=1e-15)
    assert load.breakpoints(0.013, 0.021).tolist() == pytest.approx([0.02])
    # between two knots the interpolant is one cubic: its third difference is constant
    t = np.linspace(0.0205, 0.0295, 10)
    v = np.array([load.torque(x, 0.0) for x in t])
    d3 = np.diff(v, 3)
    assert np.ptp(d3) < 1e-9 * max(1.0, np.max(np.abs(d3)))


def test_time_series_brake_steps_sum_and_smooth_models():
    ts = TimeSeriesLoad([0.0, 0.1, 0.25, 0.4], [1.0, 2.0, 0.0, 1.0])
    assert ts.breakpoints(0.0, 0.3).tolist() == [0.1, 0.25]
    brake = BrakeStepsLoad(times=[0.2, 0.5], torques=[10.0, 0.0], ramp_time=0.05)
    assert brake.breakpoints(0.0, 1.0).tolist() == pytest.approx([0.2, 0.25, 0.5, 0.55])
    assert BrakeStepsLoad(times=[0.2], torques=[5.0], ramp_time=0.0).breakpoints(0.0, 1.0).tolist() == [0.2]
    both = SumLoad([ts, brake, ConstantLoad(torque=3.0)])
    assert both.breakpoints(0.0, 0.3).tolist() == pytest.approx([0.1, 0.2, 0.25])
    assert ConstantLoad(torque=3.0).breakpoints(0.0, 10.0).size == 0


def test_landing_grid_keeps_samples_and_drops_near_duplicates():
    times = np.arange(6) * 0.05
    breaks = np.array([0.0, 0.01, 0.05 + 1e-13, 0.07, 0.07 + 1e-12, 0.25, 0.3])
    grid, rows = landing_grid(times, breaks)
    np.testing.assert_array_equal(grid[rows], times)
    assert sorted(set(grid) - set(times)) == [0.01, 0.07]
    assert np.all(np.diff(grid) > 0)
    g0, r0 = landing_grid(times, np.empty(0))
    assert g0 is times and r0.tolist() == list(range(6))


def _landing_grid_plain(times, breaks, tol=1e-9):
    """The definition, one breakpoint at a time: sorted unique breakpoints inside the
    span, none within tol max(1, |t|) of a sample or of the last breakpoint kept."""
    kept = []
    for b in sorted(set(float(x) for x in breaks)):
        near = tol * max(1.0, abs(b))
        if not (times[0] < b < times[-1]) or np.min(np.abs(times - b)) <= near:
            continue
        if kept and b - kept[-1] <= near:
            continue
        kept.append(b)
    return np.sort(np.concatenate((times, kept)))


@pytest.mark.parametrize('seed', range(40))
def test_landing_grid_matches_its_definition_on_fuzzed_breakpoints(seed):
    """Unsorted, repeated, clustered (gaps below tol) and out-of-span breakpoints."""
    rng = np.random.default_rng(seed)
    times = np.arange(int(rng.integers(2, 30))) * 0.05
    base = rng.uniform(-0.1, times[-1] + 0.1, int(rng.integers(0, 40)))
    clusters = np.repeat(base[:5], 3) + rng.choice([0.0, 3e-10, 2e-9], 15)[:3 * base[:5].size]
    on_samples = times[rng.integers(0, times.size, 3)] + rng.choice([0.0, 5e-10, 1e-6], 3)
    breaks = np.concatenate((base, clusters, on_samples, base[:3]))
    rng.shuffle(breaks)
    grid, rows = landing_grid(times, breaks)
    np.testing.assert_array_equal(grid, _landing_grid_plain(times, breaks))
    np.testing.assert_array_equal(grid[rows], times)


def _kavz(**kw):
    return Simulation(load_scene(find_scene('kavz685_lever')), **kw)


def test_landing_on_knots_buys_accuracy_at_equal_tolerance():
    """kavz685_lever's random load has knots every 10 ms. Reference: dop853 at 1e-12,
    landing on them. dopri5 at tol 1e-6 landing on them must be >= 10x closer than the same
    solver stepping across (measured 8e-8 against 1e-5 on 1 s; 10x leaves two decades)."""
    ref = _kavz(method='dop853', rtol=1e-12, atol=1e-12).run(0.5, sample_dt=0.05)
    w_ref = ref.velocity[:, -1]
    scale = np.max(np.abs(w_ref))
    errs = {}
    for breaks in (True, False):
        tr = _kavz(method='dopri5', rtol=1e-6, atol=1e-6).run(0.5, sample_dt=0.05, breakpoints=breaks)
        np.testing.assert_array_equal(tr.t, ref.t)
        errs[breaks] = float(np.max(np.abs(tr.velocity[:, -1] - w_ref)) / scale)
    assert errs[True] * 10 < errs[False], errs
    assert errs[True] < 1e-6


@pytest.mark.parametrize('backend', ['kernel', 'python'])
def test_dense_sampling_lands_on_breakpoints_too(backend):
    """Dense sampling (natural steps, interpolated samples) stops at each knot as well, also
    where a knot falls on a sample. Measured on 0.2 s, dopri5 at 1e-8, samples every 2 ms:
    9.9e-9 landing, 3.7e-7 across (both backends); bounds at 10x and a decade below."""
    ref = _kavz(method='dop853', rtol=1e-12, atol=1e-12).run(0.2, sample_dt=0.002)
    scale = np.max(np.abs(ref.velocity))
    sim = _kavz(method='dopri5', rtol=1e-8, atol=1e-8, backend=backend)
    err = {}
    for breaks in (True, False):
        tr = sim.run(0.2, sample_dt=0.002, sampling='dense', breakpoints=breaks)
        err[breaks] = float(np.max(np.abs(tr.velocity - ref.velocity)) / scale)
    assert err[True] < 1e-7 and err[True] * 10 < err[False], err


@pytest.mark.parametrize('seed', range(40))
def test_compiled_landing_grid_is_the_numpy_one(seed):
    """kernel/grid_nb.py (what a kernel run uses) against landing_grid on the fuzzed
    breakpoints of the test above: the same grid and rows, bit for bit."""
    rng = np.random.default_rng(1000 + seed)
    times = np.arange(int(rng.integers(2, 30))) * 0.05
    base = rng.uniform(-0.1, times[-1] + 0.1, int(rng.integers(0, 40)))
    near = np.repeat(base[:5], 3) + rng.choice([0.0, 3e-10, 2e-9], 3 * base[:5].size)
    on_samples = times[rng.integers(0, times.size, 3)] + rng.choice([0.0, 5e-10, 1e-6], 3)
    breaks = np.concatenate((base, near, on_samples, [np.nan]))
    rng.shuffle(breaks)
    grid, rows = Simulation._landing_grid(times, breaks)
    g_ref, r_ref = landing_grid(times, breaks)
    np.testing.assert_array_equal(grid, g_ref)
    np.testing.assert_array_equal(rows, r_ref)


def test_dopri5_dense_survives_a_knot_an_ulp_from_a_sample():
    """A random-load knot an ulp before a sample (15 x 0.01 = 0.15 < 3 x 0.05): dense
    dopri5 landed on the knot, then clipped its next step at that sample, an ulp ahead, and
    failed with a step size underflow at t = 0.15 s. Samples every 50 ms land on every
    knot-aligned sample, so the dense run is the landing run, bit for bit."""
    sim = _kavz(method='dopri5', rtol=1e-3, atol=1e-3)
    assert 15 * 0.01 < 3 * 0.05      # the premise: the knot precedes the sample by an ulp
    dense = sim.run(1.0, sample_dt=0.05, sampling='dense')
    land = sim.run(1.0, sample_dt=0.05, sampling='land')
    np.testing.assert_array_equal(dense.velocity, land.velocity)
    assert int(dense.solver['nfev']) == int(land.solver['nfev'])


def test_dopri5_segments_drop_only_the_landings_that_would_underflow():
    """A landing an ulp before a segment of samples is dropped (the segment joins the one
    before it), as is one an ulp after a segment's last sample; every other list is kept
    as it is - the kavz685_lever sweep's 1 ms samples (every knot on a sample) run as
    before."""
    times = np.arange(5) * 0.05       # 0.15000000000000002
    segs = [(1, 3, 0.15), (3, 4, 0.16), (4, 5, None)]
    assert dopri5_segments(times, segs) == [(1, 4, 0.16), (4, 5, None)]
    times2 = np.array([0.0, 0.3, 0.6])
    b = 0.1 + 0.2                     # 0.30000000000000004: an ulp after sample 0.3
    assert dopri5_segments(times2, [(1, 2, b), (2, 3, None)]) == [(1, 2, None), (2, 3, None)]
    sim = _kavz(method='dopri5')
    plan = sim._kernel_plan(2.0, 0.001, 'dense', True)
    assert len(plan.segments) == 200
    raw = [(k, k_end, b) for k, k_end, b in plan.segments]
    assert dopri5_segments(plan.times, raw) == raw


@pytest.mark.parametrize('seed', range(20))
def test_dense_segments_match_their_definition(seed):
    """dense_segments (one searchsorted) against the loop it replaced, one breakpoint at a
    time: the same rows and breakpoints, so dense runs keep their steps and bytes."""
    rng = np.random.default_rng(2000 + seed)
    times = np.arange(int(rng.integers(2, 60))) * rng.choice([0.001, 0.05, 0.1])
    cand = np.concatenate((rng.uniform(0.0, times[-1] * 1.1, int(rng.integers(0, 30))),
                           times[rng.integers(0, times.size, 3)]))   # some on samples
    g, r = landing_grid(times[[0, -1]], cand)
    breaks = np.delete(g, r)
    expected, k = [], 1
    for b in (*breaks.tolist(), None):
        k_end = times.size if b is None else int(np.searchsorted(times, b, 'right'))
        expected.append((k, k_end, b))
        k = max(k, k_end)
    assert dense_segments(times, breaks) == expected
