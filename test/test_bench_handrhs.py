"""The hand-written rhs of the bench's 2-DOF Hooke model and of the stiff scene are the
kernel's rhs, bit for bit (so the ns-per-call ratio compares the same arithmetic), and their
timing entries are well formed."""
from __future__ import annotations

import math

import numpy as np

from cvj_ros import bench
import pytest

from cvj_ros.bench_handrhs import (fwd_halfshaft_params, fwd_halfshaft_rhs, hooke_2dof_params,
                                  hooke_2dof_rhs, stiff_params, stiff_rhs,
                                  time_fwd_halfshaft_calls, time_hooke_2dof_calls, time_stiff_calls)
from cvj_ros.physics.kernel.layout import build_model
from cvj_ros.physics.kernel.rhs_nb import rhs
from cvj_ros.physics.simulate import Simulation


def test_hand_written_rhs_equals_the_kernel_rhs_and_the_closed_form() -> None:
    scene = bench.hooke_2dof_scene()
    sim = Simulation(scene, fidelity=bench.forced_levels(scene, 'exact'))
    model = build_model(sim.driveline, engine=sim.engine, load=sim.load)
    p = hooke_2dof_params(scene)
    rng = np.random.default_rng(7)
    for _ in range(20):
        y = model.x0 + rng.normal(scale=2.0, size=model.x0.size)
        want, got = np.empty_like(y), np.empty_like(y)
        rhs(0.01, y, model.ip, model.fp, want)
        hooke_2dof_rhs(0.01, y, p, got)
        assert np.array_equal(got, want)
    # at q1 = 0 the Hooke ratio is 1/cos(beta) and its slope 0 (closed form): w1' by hand
    y = np.array([0.3, 0.0, 100.0, 99.0] + [0.0] * (model.x0.size - 4))
    cb = math.cos(math.radians(20.0))
    ts = 1000.0 * 0.3 + 1.0 * 1.0
    r = 1.0 / cb
    got = np.empty_like(y)
    hooke_2dof_rhs(0.0, y, p, got)
    assert math.isclose(got[3], (ts - 20.0 * r) / (0.2 * r * r), rel_tol=1e-14)
    assert math.isclose(got[2], (100.0 - 0.5 * 100.0 - ts) / 0.1, rel_tol=1e-14)
    assert math.isfinite(time_hooke_2dof_calls(100, 0.0, y[None, :], p))


def test_hand_written_stiff_rhs_equals_the_kernel_rhs_and_the_closed_form() -> None:
    scene = bench.resolve_scene('stiff')
    sim = Simulation(scene, fidelity=bench.forced_levels(scene, 'exact'))
    model = build_model(sim.driveline, engine=sim.engine, load=sim.load)
    p = stiff_params(scene)
    rng = np.random.default_rng(8)
    for _ in range(20):
        y = model.x0 + rng.normal(scale=2.0, size=model.x0.size)
        want, got = np.empty_like(y), np.empty_like(y)
        rhs(0.01, y, model.ip, model.fp, want)
        stiff_rhs(0.01, y, p, got)
        assert np.array_equal(got, want)
    # closed form at a 1 mrad twist: T = 1e6 x 1e-3 + 10 x 0.5 = 1005 N m
    y = np.array([1e-3, 0.0, 100.5, 100.0] + [0.0] * (model.x0.size - 4))
    got = np.empty_like(y)
    stiff_rhs(0.0, y, p, got)
    assert math.isclose(got[3], (1005.0 - 10.0) / 0.01, rel_tol=1e-14)
    assert math.isclose(got[2], (50.0 - 0.4 * 100.5 - 1005.0) / 0.01, rel_tol=1e-14)
    assert math.isfinite(time_stiff_calls(100, 0.0, y[None, :], p))


def test_hand_written_fwd_halfshaft_rhs_equals_the_kernel_rhs_and_the_closed_form() -> None:
    """Bit for bit against the kernel at random states around the start (clutch in and out of
    its lash); at rest but for the wheel (speed w) the tripod's series and the clutch vanish
    and the wheel sees the midshaft's damping -d w and the road load."""
    scene = bench.resolve_scene('fwd_halfshaft')
    sim = Simulation(scene, fidelity=bench.forced_levels(scene, 'exact'))
    model = build_model(sim.driveline, engine=sim.engine, load=sim.load)
    p = fwd_halfshaft_params(scene)
    rng = np.random.default_rng(9)
    for _ in range(30):
        y = model.x0 + rng.normal(scale=[0.05] * 3 + [5.0] * 3 + [1.0] * 3)
        want, got = np.empty_like(y), np.empty_like(y)
        rhs(0.01, y, model.ip, model.fp, want)
        fwd_halfshaft_rhs(0.01, y, p, got)
        assert np.array_equal(got, want)
    w = 40.0
    y = np.array([0.0, 0.0, 0.0, 0.0, 0.0, w, 0.0, 0.0, 0.0])
    got = np.empty_like(y)
    fwd_halfshaft_rhs(0.0, y, p, got)
    assert math.isclose(got[5], (-20.0 * w - sim.load.torque(0.0, w)) / 119.0, rel_tol=1e-12)
    assert math.isfinite(time_fwd_halfshaft_calls(100, 0.0, y[None, :], p))


@pytest.mark.parametrize('name', bench.HAND_WRITTEN)
def test_hand_written_cost_entry(name: str) -> None:
    out = bench.hand_written_rhs_cost(name, calls=2000, rounds=3)
    assert out['rounds'] == 3
    assert 0 < out['hand_ns_min'] <= out['hand_ns'] <= out['hand_ns_max']
    assert 0 < out['kernel_ns_min'] <= out['kernel_ns'] <= out['kernel_ns_max']
    assert out['ratio'] > 0
    assert out['loop'] == 'chain' and out['clock'] == 'cpu' and out['floor_ns'] > 0


def test_hand_written_cost_keeps_the_cycled_loop_and_the_wall_clock() -> None:
    """The earlier measurement (states cycled, wall clock) stays available beside the chain."""
    out = bench.hand_written_rhs_cost('stiff', calls=2000, rounds=2, loop='cycle', clock='wall')
    assert out['rounds'] == 2 and out['loop'] == 'cycle' and 'floor_ns' not in out
    with pytest.raises(ValueError, match="loop must be 'chain' or 'cycle'"):
        bench.hand_written_rhs_cost('stiff', calls=10, rounds=1, loop='fixed')
    with pytest.raises(ValueError, match="clock 'cpu' or 'wall'"):
        bench.hand_written_rhs_cost('stiff', calls=10, rounds=1, clock='tsc')


def test_hand_written_cost_names_its_models() -> None:
    with pytest.raises(ValueError, match='no hand-written rhs'):
        bench.hand_written_rhs_cost('kavz685_lever', calls=10, rounds=1)


def test_timing_loops_compute_the_same_sums() -> None:
    """The kernel's and the hand-written loop return the same checksum over the same cycled
    states (the same arithmetic is timed), and the states differ from row to row."""
    from cvj_ros.bench_handrhs import time_kernel_calls, timing_states
    for scene, params, timer in ((bench.hooke_2dof_scene(), hooke_2dof_params, time_hooke_2dof_calls),
                                 (bench.resolve_scene('stiff'), stiff_params, time_stiff_calls),
                                 (bench.resolve_scene('fwd_halfshaft'), fwd_halfshaft_params,
                                  time_fwd_halfshaft_calls)):
        sim = Simulation(scene, fidelity=bench.forced_levels(scene, 'exact'))
        model = build_model(sim.driveline, engine=sim.engine, load=sim.load)
        ys = timing_states(model.x0)
        assert ys.shape == (16, model.x0.size) and np.unique(ys[:, 0]).size == 16
        assert time_kernel_calls(1000, 0.001, ys, model.ip, model.fp) == timer(1000, 0.001, ys, params(scene))


def _chain_cases():
    from cvj_ros import bench_handrhs as hw
    return ((bench.hooke_2dof_scene(), hooke_2dof_params, hw.time_hooke_2dof_chain),
            (bench.resolve_scene('stiff'), stiff_params, hw.time_stiff_chain),
            (bench.resolve_scene('fwd_halfshaft'), fwd_halfshaft_params, hw.time_fwd_halfshaft_chain))


def test_chained_loops_compute_the_same_sums_from_chained_states() -> None:
    """On the chained loop (each input z = y_j + h f of the call before) the kernel's and
    the hand-written rhs give the same sum bit for bit - the same states and the same
    arithmetic are timed -, the sum repeats from call to call (the same states every round),
    and it differs from h = 0, so each call's input does depend on the previous output."""
    from cvj_ros import bench_handrhs as hw
    for scene, params, timer in _chain_cases():
        sim = Simulation(scene, fidelity=bench.forced_levels(scene, 'exact'))
        model = build_model(sim.driveline, engine=sim.engine, load=sim.load)
        ys = hw.timing_states(model.x0)
        p = params(scene)
        got = timer(1000, 0.001, ys, hw.CHAIN_H, p)
        assert math.isfinite(got)
        assert hw.time_kernel_chain(1000, 0.001, ys, hw.CHAIN_H, model.ip, model.fp) == got
        assert timer(1000, 0.001, ys, hw.CHAIN_H, p) == got
        assert timer(1000, 0.001, ys, 0.0, p) != got
        assert hw.time_kernel_chain(1000, 0.001, ys, 0.0, model.ip, model.fp) == timer(1000, 0.001, ys, 0.0, p)
    assert hw.time_null_chain(100, 0.0, ys, hw.CHAIN_H, p) == 0.0


def test_call_not_inlined_is_a_call_that_llvm_keeps() -> None:
    """A one-line callee stays a call (LLVM's noinline on the call site), where a plain call
    of the same function is inlined: the chained loops time the rhs behind a call boundary."""
    from numba import njit

    from cvj_ros.bench_handrhs import call_not_inlined

    @njit
    def twice(x):
        return 2.0 * x

    @njit
    def kept(x):
        return call_not_inlined(twice, (x,)) + 1.0

    @njit
    def plain(x):
        return twice(x) + 1.0

    assert kept(3.0) == plain(3.0) == 7.0
    name = twice.overloads[twice.signatures[0]].fndesc.mangled_name
    ir_kept = next(iter(kept.inspect_llvm().values()))
    ir_plain = next(iter(plain.inspect_llvm().values()))
    entry = ir_kept[ir_kept.index('define '):]
    assert f'call i32 @{name}' in entry or f'call i32 @"{name}"' in entry
    assert 'noinline' in entry
    plain_entry = ir_plain[ir_plain.index('define '):]
    assert f'@{name}(' not in plain_entry.split('\n}')[0]


def test_call_not_inlined_propagates_the_callee_exception() -> None:
    from numba import njit

    from cvj_ros.bench_handrhs import call_not_inlined

    @njit
    def inverse(x):
        return 1.0 / x

    @njit
    def kept(x):
        return call_not_inlined(inverse, (x,))

    assert kept(4.0) == 0.25
    with pytest.raises(ZeroDivisionError):
        kept(0.0)
