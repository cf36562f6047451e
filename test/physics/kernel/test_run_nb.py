"""kernel/run_nb.py: a whole offline run in one compiled call gives the same bytes and
counters as the step-by-step path it replaces (reset, land / sample, sample_outputs), for
every method, both samplings, with and without breakpoints, on a first and a reused plan."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cvj_ros.errors import SolverError
from cvj_ros.physics.kernel.stepper import KERNEL_METHODS
from cvj_ros.physics.scene import load_scene
from cvj_ros.physics.simulate import Simulation

SCENES = Path(__file__).resolve().parents[3] / 'config' / 'scenes'
FIELDS = ('t', 'position', 'velocity', 'effort', 'engine_torque', 'load_torque',
          'energy_residual')
COUNTERS = ('nfev', 'njev', 'nlu', 'naccept', 'nreject', 't', 'h')


def _runs(scene, method: str, *, one_call: bool, **kw):
    sim = Simulation(scene, method=method, rtol=1e-5, atol=1e-7)
    sim._one_call = one_call
    first = sim.run(0.25, sample_dt=0.007, **kw)
    again = sim.run(0.25, sample_dt=0.007, **kw)   # the plan's stepper reused
    return sim, first, again


def _same(a, b) -> None:
    for f in FIELDS:
        assert np.array_equal(getattr(a, f), getattr(b, f), equal_nan=True), f
    assert {k: a.solver[k] for k in COUNTERS} == {k: b.solver[k] for k in COUNTERS}


# kavz685_lever: random load (breakpoints every 10 ms, between the 7 ms samples), a lever
# hinge; cardan_truck: double cardan with an intermediate shaft (the members' fill after
# the call); stiff: the Rosenbrock scene
@pytest.mark.parametrize('scene_name', ['kavz685_lever', 'cardan_truck', 'stiff'])
@pytest.mark.parametrize('method', KERNEL_METHODS)
@pytest.mark.parametrize('sampling,breakpoints', [('land', True), ('dense', True),
                                                  ('dense', False)])
def test_one_call_run_matches_the_step_by_step_path(scene_name, method, sampling, breakpoints):
    scene = load_scene(SCENES / f'{scene_name}.yaml')
    sim, one, one_again = _runs(scene, method, one_call=True, sampling=sampling,
                                breakpoints=breakpoints)
    assert next(iter(sim._plans.values())).run is not None   # the one call ran
    _sim, steps, steps_again = _runs(scene, method, one_call=False, sampling=sampling,
                                     breakpoints=breakpoints)
    _same(one, steps)
    _same(one_again, steps_again)
    _same(one, one_again)


def test_breakpoints_between_samples_are_landed_on():
    """Dense sampling with the random load's knots: the step count differs from stepping
    across them, and the one call lands on them as advance_to did (compared above)."""
    scene = load_scene(SCENES / 'kavz685_lever.yaml')
    _s, with_bp, _a = _runs(scene, 'dopri5', one_call=True, sampling='dense', breakpoints=True)
    _s, across, _a = _runs(scene, 'dopri5', one_call=True, sampling='dense', breakpoints=False)
    assert with_bp.solver['naccept'] > across.solver['naccept']


@pytest.mark.parametrize('method', ['dopri5', 'rodas4'])
def test_a_run_that_fails_raises_the_same_error_on_both_paths(method):
    scene = load_scene(SCENES / 'stiff.yaml')
    messages = []
    for one_call in (True, False):
        sim = Simulation(scene, method=method, rtol=1e-5, atol=1e-7)
        sim._one_call = one_call
        sim.driveline.x0[2] = 1e300   # the engine shaft's speed: the state overflows
        # the one call twice: the second run calls the bound entry point (run.call) directly
        for _rep in range(2 if one_call else 1):
            with pytest.raises(SolverError) as err:
                sim.run(0.1, sample_dt=0.01)
            messages.append(str(err.value))
    assert messages[0] == messages[1] == messages[2]


def test_pack_keeps_state_views_in_place_and_copies_the_rest():
    """run_nb.pack: an entry that is a view of the stepper's buffers is its offset there (the
    run writes the state in place), any other array is a copy; the compiled accessors give
    back every entry, 1-d and 2-d, float and int, empty ones included."""
    from numba import njit

    from cvj_ros.physics.kernel import run_nb

    fbuf = np.arange(30.0)
    ibuf = np.arange(10, dtype=np.int64)
    view_f, view_f2, view_i = fbuf[4:9], fbuf[10:16].reshape(2, 3), ibuf[3:7]
    own_f, own_f2 = np.array([7.5, -1.0]), np.arange(12.0).reshape(4, 3)
    own_i2, empty = np.arange(6, dtype=np.int64).reshape(3, 2), np.zeros((3, 0))
    entries = [view_f, own_f, view_f2, own_f2, empty, view_i, own_i2]
    fpk, ipk = run_nb.pack(entries, fbuf, ibuf)
    assert fpk.size == own_f.size + own_f2.size          # the views are not copied

    @njit
    def unpack(fpk, ipk, fbuf, ibuf):
        return (run_nb._f1(0, fpk, ipk, fbuf), run_nb._f1(1, fpk, ipk, fbuf),
                run_nb._f2(2, fpk, ipk, fbuf), run_nb._f2(3, fpk, ipk, fbuf),
                run_nb._f2(4, fpk, ipk, fbuf), run_nb._i1(5, ipk, ibuf),
                run_nb._i2(6, ipk, ibuf))

    got = unpack(fpk, ipk, fbuf, ibuf)
    for a, b in zip(got, entries):
        assert a.shape == b.shape and np.array_equal(a, b)
    got[0][0] = 99.0                                     # a state view writes the buffer
    assert fbuf[4] == 99.0
    with pytest.raises(ValueError, match='pack entry 0'):
        run_nb.pack([np.zeros((2, 2, 2))], fbuf, ibuf)


@pytest.mark.parametrize('scene_name', ['fwd_halfshaft', 'kavz685_lever'])
def test_the_one_call_fills_the_intermediate_members_as_the_separate_call_did(scene_name):
    """bind_run with the members' table fills their angles and speeds in the run's own call
    (no fill_mid_samples call after it): the same bytes as the run without them followed by
    that separate call, which the members' columns of the bare run do not have."""
    from cvj_ros.physics.kernel import entry_point_once
    from cvj_ros.physics.kernel.outputs_nb import fill_mid_samples

    scene = load_scene(SCENES / f'{scene_name}.yaml')
    sim = Simulation(scene, method='dopri5', rtol=1e-4, atol=1e-6)
    tr = sim.run(0.2, sample_dt=0.01, breakpoints=False)
    plan = next(iter(sim._plans.values()))
    mtab, mfp, _python = sim._mid_table
    assert mtab.shape[0] > 0
    m, n, n_sh = plan.shape
    bare = plan.stepper.bind_run(sim.driveline.x0, plan.times,
                                 (plan.grid, np.zeros(0, np.int64), np.zeros((0, 2), np.int64),
                                  np.zeros(0), np.zeros(2), np.zeros((2, n))), sim._shaft_table)
    X, eff = np.empty((m, n)), np.empty((m, n_sh))
    pos, vel = np.full((m, n_sh), np.nan), np.full((m, n_sh), np.nan)
    te, tl, res = np.empty(m), np.empty(m), np.empty(m)
    assert plan.grid.size == m   # no breakpoints: every landing a sample (XG is X)
    assert bare(sim._initial_energy(sim.driveline.x0), X, X, pos, vel, eff, te, tl, res) == -1
    mids = mtab[:, 0]
    assert not np.array_equal(pos[:, mids], tr.position[:, mids])   # not filled by the bare run
    args = (pos, vel, mtab, mfp)
    entry_point_once(fill_mid_samples, args)(*args)
    for got, want in ((pos, tr.position), (vel, tr.velocity), (eff, tr.effort)):
        assert np.array_equal(got, want)


def test_pack_2d_views_are_the_reshapes_they_replace() -> None:
    """run_nb._as_2d (the pack's 2-d entries): the same shape, strides, data and values as
    ``flat.reshape((d0, d1))`` for float64 and int64 (an empty entry: the shape), and, from
    an owned array, a view that keeps its data alive as numba's reshape does."""
    from numba import njit

    from cvj_ros.physics.kernel.run_nb import _as_2d

    @njit
    def view(a, o, d0, d1):
        return _as_2d(a[o:o + d0 * d1], d0, d1)

    for a, o, d0, d1 in [(np.arange(40.0), 3, 4, 7), (np.arange(40, dtype=np.int64), 5, 5, 3),
                         (np.arange(10.0), 2, 3, 0), (np.arange(10.0), 10, 0, 4)]:
        v = view(a, o, d0, d1)
        ref = a[o:o + d0 * d1].reshape((d0, d1))
        assert v.dtype == a.dtype and v.shape == ref.shape and np.array_equal(v, ref)
        if v.size:      # (an empty entry's strides are never used)
            assert v.strides == ref.strides
            assert v.__array_interface__['data'][0] == ref.__array_interface__['data'][0]
    a = np.arange(28.0) * 2.0
    v = view(a, 0, 4, 7)
    del a
    assert v[3, 6] == 54.0 and v.flags.c_contiguous
