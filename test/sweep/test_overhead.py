"""The per-variant shortcuts of the sweep (docs/sweeps.md, "Where a variant's time goes")
give the same numbers as the code they replace, and the per-process caches are keyed on
everything they depend on: a sweep of the joint geometry never reuses another variant's
entry. Every comparison here is exact (==, array_equal): the shortcuts must not change a
single bit of results.csv."""
from __future__ import annotations

import math

import numpy as np
import pytest

from cvj_ros.commands.sweep import load_scene_data
from cvj_ros.physics import fidelity, load as load_mod
from cvj_ros.physics.fidelity import choose_fidelity, joint_error_bounds, joint_max_order
from cvj_ros.physics.joints.lever_hinge import LeverHinge
from cvj_ros.physics.load import RandomLoad
from cvj_ros.physics.metrics import shaft_metrics
from cvj_ros.physics.scene import find_scene, parse_scene
from cvj_ros.physics.steady import slice_spans
from cvj_ros.sweep.run import Job, RunOptions, run_chunk, run_variant
from cvj_ros.sweep.spec import build_sweep


def clear_caches() -> None:
    """Forget every per-process cache the variants use (as a fresh worker would)."""
    fidelity._joint_error_bounds.cache_clear()
    fidelity._joint_max_order.cache_clear()
    load_mod._uniform_block.cache_clear()
    fidelity._ADJACENT.clear()


def test_geometry_sweep_never_reuses_a_cache_entry_wrongly() -> None:
    """kavz685_lever at accuracy target 1e-3 over hinge angle x support tilt: the coupling's
    fidelity alternates between neighbouring variants (ideal without tilt, closed with it,
    measured below), so bounds cached for one geometry and reused for the next would pick
    the wrong level and change the row. Rows of one chunk (caches warm, shared by all
    variants) equal rows computed each with all caches cleared first."""
    base = load_scene_data(find_scene('kavz685_lever'))
    sweep = build_sweep(base, ['duration=0.3', 'accuracy_target=0.001',
                               'driveline[coupling].params.alpha_deg=2,15,28',
                               'driveline[coupling].params.delta_alpha_deg=0,1.72'])
    job = Job(base=sweep.base, keys=tuple(a.keys for a in sweep.axes), options=RunOptions())
    clear_caches()
    warm = run_chunk(job, list(enumerate(sweep.variants)))
    # one bounds entry per distinct geometry (alpha, delta_alpha), nothing shared wrongly
    assert fidelity._joint_error_bounds.cache_info().currsize == 6
    levels = []
    for i, outcome in enumerate(warm):
        clear_caches()
        scene = parse_scene(sweep.scene_dict(i))
        levels.append(choose_fidelity(scene).levels['coupling'])
        clear_caches()
        fresh, _wall = run_variant(sweep.scene_dict(i), RunOptions())
        assert outcome.row == fresh, f'variant {i} differs with warm caches'
    assert levels == ['ideal', 'closed'] * 3       # the sweep does switch levels


def test_cached_bounds_equal_uncached_and_key_on_type_and_sign() -> None:
    """joint_error_bounds / joint_max_order from the cache equal a direct evaluation; the
    key tells apart values that compare equal (0.0 and -0.0, 1 and 1.0); callers get
    copies (mutating one does not reach the cache)."""
    clear_caches()
    params = {'alpha': math.radians(20.0), 'delta_alpha': 0.03}
    first = joint_error_bounds('lever_hinge', params)
    first['exact']['speed_error'] = 123.0
    again = joint_error_bounds('lever_hinge', params)
    assert again == fidelity._joint_error_bounds_uncached('lever_hinge', params, fidelity.N_SAMPLES)
    assert joint_max_order('lever_hinge', params) == \
        fidelity._joint_max_order_uncached('lever_hinge', params, 256)
    assert fidelity._params_key({'a': 0.0}) != fidelity._params_key({'a': -0.0})
    assert fidelity._params_key({'a': 1}) != fidelity._params_key({'a': 1.0})
    assert fidelity._params_key({'layout': ['x']}) is None      # unhashable: not cached
    assert joint_error_bounds('hooke', {'beta': 0.2}) == \
        fidelity._joint_error_bounds_uncached('hooke', {'beta': 0.2}, fidelity.N_SAMPLES)


@pytest.mark.parametrize('level', ['ideal', 'closed', 'exact'])
def test_lever_hinge_mid_angle_is_evaluate_phi_mid(level: str) -> None:
    """mid_angle() (used by Driveline.fill_mid) gives the bits of evaluate().phi_mid, over
    many revolutions and both signs of the angle."""
    rng = np.random.default_rng(7)
    phi = np.concatenate([rng.uniform(-1e3, 1e3, 4001), np.linspace(-7.0, 7.0, 1001)])
    joint = LeverHinge(math.radians(23.0), fidelity=level, delta_alpha=0.03)
    assert np.array_equal(joint.mid_angle(phi), joint.evaluate(phi).phi_mid)


def reference_shaft_metrics(t: np.ndarray, names: list[str], vel: np.ndarray, eff: np.ndarray,
                            mask: np.ndarray) -> dict[str, dict[str, float]]:
    """shaft_metrics as it was before the vectorisation: one shaft at a time."""
    increasing = bool(np.all(np.diff(t) > 0.0))
    out = {}
    for i, name in enumerate(names):
        w = vel[:, i]
        if t.size <= 2:
            acc = np.zeros_like(w)
        else:
            acc = np.gradient(w, t, edge_order=2) if increasing else np.full_like(w, np.nan)
        mean = float(np.mean(w[mask]))
        span = float(np.max(w[mask]) - np.min(w[mask]))
        out[name] = {'mean_speed': mean,
                     'delta': span / abs(mean) if mean != 0.0 else float('inf'),
                     'speed_amplitude': 0.5 * span,
                     'acceleration_amplitude': 0.5 * float(np.max(acc[mask]) - np.min(acc[mask])),
                     'mean_torque': float(np.mean(eff[mask, i])),
                     'torque_amplitude': 0.5 * float(np.max(eff[mask, i]) - np.min(eff[mask, i]))}
    return out


@pytest.mark.parametrize('case', ['uniform', 'nonuniform', 'repeated_stamp', 'two_samples'])
def test_vectorised_shaft_metrics_equal_per_shaft(case: str) -> None:
    """All shafts at once (np.gradient along axis 0, contiguous rows for the means) equal
    the per-shaft computation bit for bit, also for a non-uniform grid, a repeated stamp
    (acceleration NaN) and a two-sample record."""
    from cvj_ros.physics.steady import SteadyWindow
    rng = np.random.default_rng(3)
    n = 2 if case == 'two_samples' else 2001
    t = np.arange(n) * 1e-3
    if case == 'nonuniform':
        t = np.cumsum(rng.uniform(0.5e-3, 1.5e-3, n))
    if case == 'repeated_stamp':
        t[700] = t[699]
    names = ['a', 'b_mid', 'c', 'd']
    vel = 40.0 + rng.standard_normal((n, 4)).cumsum(axis=0) * 1e-3
    eff = 100.0 + rng.standard_normal((n, 4))
    window = SteadyWindow(float(t[n // 3]), float(t[-1]), True, 0.0, 0.0, '', 0.1, 3, 'a')
    got = shaft_metrics(t, names, vel, eff, window=window)
    want = reference_shaft_metrics(t, names, vel, eff, window.mask(t))
    assert got.keys() == want.keys()
    for name in names:
        for key, value in want[name].items():
            assert got[name][key] == value or (math.isnan(value) and math.isnan(got[name][key])), \
                (name, key)


def test_slice_spans_equal_per_slice_max_minus_min() -> None:
    """reduceat spans equal np.max - np.min of each slice and column, NaN included."""
    rng = np.random.default_rng(5)
    x = rng.standard_normal((1000, 5))
    x[123, 2] = np.nan
    starts = np.array([3, 100, 250, 251 + 1, 600, 998])
    got = slice_spans(x, starts)
    ends = list(starts[1:]) + [x.shape[0]]
    want = np.array([[np.max(x[a:b, j]) - np.min(x[a:b, j]) for j in range(5)]
                     for a, b in zip(starts, ends)])
    assert np.array_equal(got, want, equal_nan=True)


def test_random_load_blocks_cached_read_only_and_equal() -> None:
    """Cached knot blocks equal a fresh generator's, cannot be written, and two loads of
    the same seed give the same knots as with the cache cleared."""
    clear_caches()
    blk = load_mod._uniform_block(685, 0, -3, RandomLoad.BLOCK)
    want = np.random.default_rng([685, 0, load_mod._zigzag(-3)]).uniform(-1.0, 1.0, RandomLoad.BLOCK)
    assert np.array_equal(blk, want)
    with pytest.raises(ValueError):
        blk[0] = 0.0
    a = RandomLoad(seed=685).unit_knots(-300, 900)
    clear_caches()
    b = RandomLoad(seed=685).unit_knots(-300, 900)
    assert np.array_equal(a, b)
    assert not np.array_equal(a, RandomLoad(seed=686).unit_knots(-300, 900))


def test_run_chunk_restores_the_garbage_collector() -> None:
    """run_chunk pauses the cyclic collector only for its chunk (also on error) and leaves a
    collector the caller disabled disabled."""
    import gc
    base = load_scene_data(find_scene('kavz685_lever'))
    sweep = build_sweep(base, ['duration=0.05', 'driveline[coupling].params.alpha_deg=5,95'])
    job = Job(base=sweep.base, keys=tuple(a.keys for a in sweep.axes), options=RunOptions())
    assert gc.isenabled()
    out = run_chunk(job, list(enumerate(sweep.variants)))
    assert gc.isenabled() and [o.row['status'] for o in out] == ['ok', 'invalid']
    gc.disable()
    try:
        run_chunk(job, [(0, sweep.variants[0])])
        assert not gc.isenabled()
    finally:
        gc.enable()
    with pytest.raises(TypeError):
        run_chunk(job, [(0, None)])     # broken chunk: the collector still comes back
    assert gc.isenabled()


def test_a_warm_variant_leaves_no_reference_cycles() -> None:
    """What makes pausing the collector safe: after the first chunk (kernel load, lazy
    imports) an ok or invalid variant leaves no unreachable objects. In a fresh interpreter:
    this one may hold other tests' threads (Dask) whose garbage gc.collect() would count."""
    import os
    import subprocess
    import sys
    code = (
        'import gc\n'
        'from cvj_ros.commands.sweep import load_scene_data\n'
        'from cvj_ros.physics.scene import find_scene\n'
        'from cvj_ros.sweep.run import Job, RunOptions, run_chunk\n'
        'from cvj_ros.sweep.spec import build_sweep\n'
        "sw = build_sweep(load_scene_data(find_scene('kavz685_lever')), ['duration=0.2', "
        "'driveline[coupling].params.alpha_deg=5,95,20', 'driveline[bushings].stiffness=500,900'])\n"
        'job = Job(sw.base, tuple(a.keys for a in sw.axes), RunOptions())\n'
        'run_chunk(job, list(enumerate(sw.variants)))\n'
        'gc.collect()\n'
        'out = run_chunk(job, list(enumerate(sw.variants)))\n'
        "print(sorted({o.row['status'] for o in out}), gc.collect())\n")
    done = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                          timeout=300, env=dict(os.environ))
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.split() == ["['invalid',", "'ok']", '0']


def test_adjacent_inertias_cache_keys_on_geometry_not_stiffness() -> None:
    """The spring rule's adjacent inertias from the cache equal a direct evaluation; a
    sweep of the bushings' stiffness shares one entry, the hinge angle and an inertia do
    not (they change the reduced inertias)."""
    base = load_scene_data(find_scene('kavz685_lever'))
    sweep = build_sweep(base, ['driveline[coupling].params.alpha_deg=10,25',
                               'driveline[bushings].stiffness=300,3000',
                               'driveline[0].J=0.5,0.6'])
    fidelity._ADJACENT.clear()
    seen = {}
    for i, values in enumerate(sweep.variants):
        scene = parse_scene(sweep.scene_dict(i))
        levels = {'coupling': 'exact'}
        got = fidelity._adjacent_inertias(scene, levels)
        assert got == fidelity._adjacent_inertias_uncached(scene, levels)
        seen.setdefault((values[0], values[2]), got)
        assert got == seen[(values[0], values[2])]
    assert len(fidelity._ADJACENT) == 4
    assert len({tuple(v['bushings']) for v in seen.values()}) == 4
