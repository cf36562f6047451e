"""The hand-written rhs of the bench's 2-DOF Hooke model is the kernel's rhs, bit for bit (so
the ns-per-call ratio compares the same arithmetic), and its timing entry is well formed."""
from __future__ import annotations

import math

import numpy as np

from cvj_ros import bench
from cvj_ros.bench_handrhs import hooke_2dof_params, hooke_2dof_rhs, time_hooke_2dof_calls
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
    assert math.isfinite(time_hooke_2dof_calls(100, 0.0, y, p))


def test_hand_written_cost_entry() -> None:
    out = bench.hand_written_rhs_cost(calls=2000, rounds=3)
    assert out['rounds'] == 3
    assert 0 < out['hand_ns_min'] <= out['hand_ns'] <= out['hand_ns_max']
    assert 0 < out['kernel_ns_min'] <= out['kernel_ns'] <= out['kernel_ns_max']
    assert out['ratio'] > 0
