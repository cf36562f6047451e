"""The compiled reduction (kernel/reduce_nb.py, through cvj_ros.sweep.reduce) gives the
floats of the numpy path bit for bit: numpy's pairwise sum on every length and offset, and
the steady window, shaft metrics and energy residual of synthetic records (steady and never
steady, uniform and non-uniform time steps, windows of every start) and of a real run, also
when the speeds but the first are filled only from the row before the window on."""
from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from cvj_ros.physics import steady
from cvj_ros.physics.kernel.reduce_nb import series_sum
from cvj_ros.physics.metrics import steady_window, summarize
from cvj_ros.sweep.reduce import MAX_SAMPLES, compiled_reduction
from cvj_ros.sweep.run import RunOptions


def test_pairwise_sum_is_numpys() -> None:
    """np.add.reduce of a column slice (contiguous copy or strided view: the same sum) for
    lengths across the 8-term and 128-term block boundaries and the halving above them."""
    rng = np.random.default_rng(7)
    a = rng.standard_normal((3000, 3)) * 10.0 ** rng.integers(-3, 4, (3000, 3))
    for n in [*range(1, 40), 127, 128, 129, 255, 256, 257, 1000, 2001, 2999]:
        for start in sorted({0, min(1, 3000 - n), min(3, 3000 - n), 3000 - n}):
            for col in (0, 2):
                ref = np.add.reduce(np.ascontiguousarray(a[start:start + n, col]))
                assert series_sum(a, start, n, col) == ref, (n, start, col)
                assert np.mean(a[start:start + n, col]) == series_sum(a, start, n, col) / n


def _trace(t: np.ndarray, vel: np.ndarray, eff: np.ndarray, res: np.ndarray) -> SimpleNamespace:
    names = [f's{i}' for i in range(vel.shape[1])]
    return SimpleNamespace(t=t, names=names, velocity=vel, effort=eff, energy_residual=res,
                           solver={'nfev': 1},
                           max_energy_residual=(math.nan if np.all(np.isnan(res))
                                                else float(np.nanmax(np.abs(res)))))


def _numpy_summary(tr: SimpleNamespace) -> dict:
    w = steady_window(tr.t, tr.names, tr.velocity, tr.effort)
    return {'window': {'steady': w.steady, 'start_s': w.start_s},
            'energy_residual': tr.max_energy_residual, 'solver': tr.solver,
            'shafts': summarize(tr, window=w)}


def _records(seed: int):
    """Shaft speeds: a mean with a decaying transient (steady or not by its time constant)
    and ripple; torques likewise; times uniform (arange * 0.5) or not (linspace)."""
    rng = np.random.default_rng(seed)
    for k in range(60):
        m = int(rng.integers(40, 2500))
        t = (np.arange(m) * 0.5 if k % 3 == 0 else np.linspace(0.0, rng.uniform(0.5, 5), m))
        n_sh = int(rng.integers(1, 5))
        tau = rng.uniform(0.01, 3.0) * t[-1]
        x = t[:, None] / t[-1]
        vel = (rng.uniform(-50, 300, n_sh) * (1 + rng.uniform(0, 0.5) * np.exp(-t[:, None] / tau))
               + rng.uniform(0, 2, n_sh) * np.sin(2 * np.pi * rng.uniform(5, 40) * x
                                                   + rng.uniform(0, 6, n_sh)))
        eff = (rng.uniform(-100, 100, n_sh) + rng.uniform(0, 20, n_sh)
               * np.cos(2 * np.pi * rng.uniform(5, 40) * x) * (1 + np.exp(-t[:, None] / tau)))
        if k % 7 == 0:
            eff[:, -1] = 0.0                       # a free end: the torque floor
        res = rng.standard_normal(m) * 1e-9
        if k % 5 == 0:
            res[::3] = np.nan
        if k % 11 == 0:
            res[:] = np.nan
        yield _trace(t, vel, eff, res)


def test_synthetic_records_bit_for_bit() -> None:
    verdicts = set()
    for tr in _records(3):
        got = compiled_reduction(tr, RunOptions())
        assert got is not None
        ref = _numpy_summary(tr)
        assert repr(got[1]) == repr(ref)
        verdicts.add(ref['window']['steady'])
        win = got[0]
        assert np.array_equal(win.mask(tr.t), steady_window(tr.t, tr.names, tr.velocity,
                                                            tr.effort).mask(tr.t))
    assert verdicts == {True, False}               # both branches of the criterion


def test_speeds_filled_from_the_window_on() -> None:
    """A record whose speeds (but the first) are NaN until ``fill`` completes them from the
    row it is given: the same summary as the complete record, and the row is the one
    before the window (or 0)."""
    for tr in _records(11):
        full = tr.velocity.copy()
        tr.velocity[:, 1:] = np.nan
        rows = []

        def fill(i: int, tr=tr, full=full, rows=rows) -> None:
            rows.append(i)
            tr.velocity[i:, 1:] = full[i:, 1:]
        got = compiled_reduction(tr, RunOptions(), fill=fill)
        tr.velocity[:] = full
        ref = _numpy_summary(tr)
        assert got is not None and repr(got[1]) == repr(ref)
        i0 = int(np.flatnonzero(steady_window(tr.t, tr.names, tr.velocity,
                                              tr.effort).mask(tr.t))[0])
        assert rows == [max(0, i0 - 1)]


def test_records_it_does_not_cover_return_none() -> None:
    tr = next(iter(_records(5)))
    assert compiled_reduction(tr, RunOptions(transient=0.1)) is None
    bad = _trace(tr.t.copy(), tr.velocity.copy(), tr.effort, tr.energy_residual)
    bad.velocity[5, 0] = np.nan
    assert compiled_reduction(bad, RunOptions()) is None
    back = _trace(tr.t[::-1].copy(), tr.velocity, tr.effort, tr.energy_residual)
    assert compiled_reduction(back, RunOptions()) is None
    m = MAX_SAMPLES + 1
    long = _trace(np.linspace(0, 1, m), np.ones((m, 1)), np.ones((m, 1)), np.zeros(m))
    assert compiled_reduction(long, RunOptions()) is None
    assert steady.FALLBACK_FRACTION == 0.5 and steady.MIN_SLICES == 3   # what the docs state


@pytest.mark.parametrize('scene', ['kavz685_lever', 'cardan_truck'])
def test_a_run_bit_for_bit(scene: str) -> None:
    from cvj_ros.commands.sweep import load_scene_data
    from cvj_ros.physics.scene import find_scene, parse_scene
    from cvj_ros.physics.simulate import Simulation
    data = load_scene_data(find_scene(scene))
    data['duration'] = 0.5
    tr = Simulation(parse_scene(data)).run(sampling='dense')
    got = compiled_reduction(tr, RunOptions())
    assert got is not None
    assert repr(got[1]) == repr(_numpy_summary(tr))


def test_slices_kept_per_times() -> None:
    """The slice bounds kept for the last times serve only records with those times: two
    records of one length and other times (uniform, then stretched) each get their own."""
    from cvj_ros.physics.steady import slice_bounds
    from cvj_ros.sweep.reduce import _slices
    from cvj_ros.physics.kernel.reduce_nb import gradient_table
    for t in (np.arange(500) * 0.5, np.linspace(0.0, 1.0, 500) ** 2, np.arange(500) * 0.5):
        lo, hi, gco, gx0 = _slices(t)
        _e, lo_ref, hi_ref = slice_bounds(t)
        assert np.array_equal(lo, lo_ref) and np.array_equal(hi, hi_ref)
        co_ref, x0_ref = gradient_table(t)
        assert gco.tobytes() == co_ref.tobytes() and np.array_equal(gx0, x0_ref)


def test_member_speeds_alone_are_fill_mid_samples_speeds() -> None:
    """reduce_nb.fill_mid_speeds (the members' speeds without their angles) writes the speeds
    outputs_nb.fill_mid_samples writes, bit for bit, from the row it is given on, and no
    member angle; members chained (one's input another's member) are filled in full (angles
    too), as fill_mid_samples does. Members: the lever hinge's earring and the compiled
    joint ops of the other kinds (Hooke stage, identity) on a real run's angles and speeds."""
    from cvj_ros.commands.sweep import load_scene_data
    from cvj_ros.physics.kernel.layout import OP_HOOKE, OP_JOINT_IDENTITY
    from cvj_ros.physics.kernel.outputs_nb import MID_EARRING, fill_mid_samples
    from cvj_ros.physics.kernel.reduce_nb import fill_mid_speeds
    from cvj_ros.physics.scene import find_scene, parse_scene
    from cvj_ros.physics.simulate import Simulation
    data = load_scene_data(find_scene('kavz685_lever'))
    data['duration'] = 0.3
    tr = Simulation(parse_scene(data)).run(sampling='dense')
    rng = np.random.default_rng(3)
    m = tr.t.size
    base_pos = np.ascontiguousarray(tr.position)
    base_vel = np.ascontiguousarray(tr.velocity)
    n_sh = base_pos.shape[1]
    pos0 = np.concatenate([base_pos, rng.uniform(-9, 9, (m, 2))], axis=1)
    vel0 = np.concatenate([base_vel, rng.uniform(-9, 9, (m, 2))], axis=1)
    mfp = np.array([math.cos(math.radians(25.0)), 0.0, 0.0, 1.0, 0.0, 0.93])
    tables = {'earring': [(n_sh, 1, MID_EARRING, 0)],
              'hooke and identity': [(n_sh, 0, OP_HOOKE, 5), (n_sh + 1, 1, OP_JOINT_IDENTITY, 0)],
              'earring and hooke': [(n_sh, 0, MID_EARRING, 0), (n_sh + 1, 2, OP_HOOKE, 5)],
              'chained': [(n_sh, 0, MID_EARRING, 0), (n_sh + 1, n_sh, OP_HOOKE, 5)]}
    for label, rows in tables.items():
        mtab = np.array(rows, dtype=np.int64)
        members = mtab[:, 0]
        for i0 in (0, 1, m // 3, m - 1, m):
            pos_a, vel_a = pos0.copy(), vel0.copy()
            fill_mid_samples(pos_a[i0:], vel_a[i0:], mtab, mfp)
            pos_b, vel_b = pos0.copy(), vel0.copy()
            fill_mid_speeds(pos_b, vel_b, i0, mtab, mfp)
            assert vel_b.tobytes() == vel_a.tobytes(), (label, i0)
            if label == 'chained':
                assert pos_b.tobytes() == pos_a.tobytes(), (label, i0)
            else:
                assert pos_b.tobytes() == pos0.tobytes(), (label, i0)
                assert not np.array_equal(pos_a[i0:, members], pos0[i0:, members]) or i0 == m


def test_one_call_reduction_with_members_equals_the_fill_path() -> None:
    """compiled_reduction with a fill that names its members (one compiled call: window,
    speeds, metrics) gives the summary and window of the two-call path with the full fill
    and of the numpy path on the complete record; the speeds are filled from the row before
    the window on and the summary's earring speeds are the full run's."""
    from cvj_ros.commands.sweep import load_scene_data
    from cvj_ros.physics.scene import find_scene, parse_scene
    from cvj_ros.physics.simulate import Simulation
    from cvj_ros.sweep.batch import bind_lean, lean_run
    for alpha, dur in ((30.0, 0.4), (5.0, 0.3), (20.0, 2.0)):
        data = load_scene_data(find_scene('kavz685_lever'))
        data['duration'] = dur
        data['driveline'][2]['params']['alpha_deg'] = alpha
        sim = Simulation(parse_scene(data))
        full = sim.run(sampling='dense')
        plan = next(iter(sim._plans.values()))
        lean = bind_lean(sim, plan, 'dense')
        assert lean is not None
        ref = _numpy_summary(full)
        trace_a, fill_a = lean_run(sim, plan, lean, speeds_only=True)
        assert fill_a.members is not None
        got_a = compiled_reduction(trace_a, RunOptions(), fill=fill_a)
        trace_b, fill_b = lean_run(sim, plan, lean)
        assert fill_b.members is None
        got_b = compiled_reduction(trace_b, RunOptions(), fill=fill_b)
        assert got_a is not None and got_b is not None
        def metrics(summary: dict) -> str:     # the solver's counters hold the run's wall
            return repr({k: v for k, v in summary.items() if k != 'solver'})
        assert metrics(got_a[1]) == metrics(got_b[1]) == metrics(ref), alpha
        assert got_a[0].start_s == got_b[0].start_s
        i0 = max(0, int(np.flatnonzero(got_a[0].mask(full.t))[0]) - 1)
        assert fill_b.done == i0 and fill_a.done == full.t.size      # angles not filled
        assert trace_a.velocity[i0:].tobytes() == full.velocity[i0:].tobytes()


def test_gradient_coefficients_give_gradient_at() -> None:
    """window_metrics' per-row coefficients (reduce_nb._gradient_coefs, once for all
    shafts) give reduce_nb._gradient_at's value (numpy's np.gradient arithmetic) bit for
    bit in every row, uniform and non-uniform spacing, and np.gradient's own."""
    from cvj_ros.physics.kernel.reduce_nb import _gradient_at, _gradient_coefs, gradient_table
    rng = np.random.default_rng(5)
    for t in (np.arange(40) * 0.001, np.linspace(0.0, 2.0, 2001),
              np.cumsum(rng.uniform(0.1, 2, 30)), np.arange(3) * 0.5):
        d = np.diff(t)
        uniform = bool(np.all(d == d[0]))
        f = rng.standard_normal((t.size, 3)) * 10.0 ** rng.integers(-3, 4, (t.size, 3))
        co = np.empty(4)
        table, x0s = gradient_table(t)      # what window_metrics reads: every row's
        for r in range(t.size):
            x0 = _gradient_coefs(t, r, uniform, co)
            assert x0 == x0s[r]
            assert (co[3] if x0 < 0 else co[:3]).tobytes() == \
                (table[r, 3] if x0 < 0 else table[r, :3]).tobytes()
            for j in range(3):
                if x0 < 0:
                    g = (f[r + 1, j] - f[r - 1, j]) / co[3]
                else:
                    g = co[0] * f[x0, j] + co[1] * f[x0 + 1, j] + co[2] * f[x0 + 2, j]
                assert g == _gradient_at(t, f, j, r, uniform), (t.size, r, j)
                assert g == np.gradient(f[:, j], t, edge_order=2)[r]


def test_extrema_keep_the_first_of_equal_values() -> None:
    """window_metrics takes the window's extrema in one pass over the rows (steady_start
    its slices' likewise): a value replaces the max (min) only when greater (less), as the
    column-by-column _max / _min they replace: the same half ranges with torques of +0.0
    and -0.0 in either order."""
    from cvj_ros.physics.kernel.reduce_nb import _max, _min, gradient_table, window_metrics
    m = 300
    t = np.linspace(0.0, 1.0, m)
    vel = np.ones((m, 2)) + np.sin(np.arange(m))[:, None]
    for first, then in ((-0.0, 0.0), (0.0, -0.0)):
        eff = np.full((m, 2), then)
        eff[:, 1] = np.cos(np.arange(m))
        eff[: m // 2, 0] = first
        out = np.empty(3 + 6 * 2)
        out[1] = 0.0
        gco, gx0 = gradient_table(t)
        assert window_metrics(t, vel, eff, np.zeros(m), gco, gx0, out) == 0
        for j in range(2):
            want = 0.5 * (_max(eff, 0, m, j) - _min(eff, 0, m, j))
            assert repr(float(out[3 + 6 * j + 5])) == repr(float(want)), (first, j)
            span = _max(vel, 0, m, j) - _min(vel, 0, m, j)
            assert repr(float(out[3 + 6 * j + 2])) == repr(float(0.5 * span))
