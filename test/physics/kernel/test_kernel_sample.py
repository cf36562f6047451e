"""Compiled dense sampling of the Rosenbrock methods and dop853 (``KernelStepper.sample``:
steppers_nb.ros_sample / ros2_sample / dop853_sample) against the step-by-step Python loop
it replaced (``kernel.stepper.super_sample``: stepper_base.sample_dense over the same
stepper's step/dense): same bytes, same steps and counters, same errors."""
from __future__ import annotations

import numpy as np
import pytest

from cvj_ros.bench import resolve_scene
from cvj_ros.physics.kernel.stepper import super_sample
from cvj_ros.physics.simulate import Simulation
from cvj_ros.physics.stepper_base import SolverOptionError

METHODS = ('rosenbrock', 'rodas4', 'rodas3', 'ros2', 'dop853')
COUNTERS = ('t', 't_old', 'h', 'nfev', 'njev', 'nlu', 'naccept', 'nreject')


def _pair(scene: str, method: str, tol: float) -> tuple:
    """Two fresh kernel steppers of ``scene``'s closed loop, identical."""
    sim = Simulation(resolve_scene(scene), method=method, rtol=tol, atol=tol)
    assert sim.backend == 'kernel'
    h = 2e-5 if method == 'ros2' else None
    return tuple(sim.make_stepper(sim.driveline.x0.copy(), 1.0, rtol=tol, atol=tol, h=h)
                 for _ in range(2))


@pytest.mark.parametrize('method', METHODS)
@pytest.mark.parametrize('scene', ['kavz685_lever', 'stiff', 'fwd_halfshaft'])
def test_compiled_sample_is_the_python_loop(scene: str, method: str) -> None:
    tol = 1e-6
    a, b = _pair(scene, method, tol)
    # from t = 0 over samples closer than the steps, with a repeated time
    t1 = np.concatenate([np.linspace(0.0, 0.05, 41), [0.05, 0.0625]])
    ya, yb = a.sample(t1), super_sample(b, t1)
    assert ya.tobytes() == yb.tobytes()
    # continuing inside the last step (t_old <= t <= t) and past it
    t2 = np.sort([a.t_old, 0.5 * (a.t_old + a.t), a.t, 0.07, 0.1])
    ya, yb = a.sample(t2), super_sample(b, t2)
    assert ya.tobytes() == yb.tobytes()
    for name in COUNTERS:
        assert getattr(a, name) == getattr(b, name), name
    assert a.y.tobytes() == b.y.tobytes()
    # the stepper goes on from where the compiled loop left it, as from the Python loop
    t_next = a.t + 0.05
    assert a.advance_to(t_next).tobytes() == b.advance_to(t_next).tobytes()


@pytest.mark.parametrize('method', METHODS)
def test_compiled_sample_rejects_times_before_the_last_step(method: str) -> None:
    a, _ = _pair('kavz685_lever', method, 1e-6)
    a.advance_to(0.01)
    with pytest.raises(SolverOptionError, match='t_eval'):
        a.sample(np.array([0.5 * a.t_old, a.t]))
    assert a.sample(np.empty(0)).shape == (0, a.n)


@pytest.mark.parametrize('scene, method', [('stiff', 'rosenbrock'), ('stiff', 'rodas4'),
                                           ('kavz685_lever', 'dop853')])
def test_dense_run_matches_landing_within_tolerance(scene: str, method: str) -> None:
    """Simulation.run(sampling='dense') on the compiled loop: fewer steps than landing on
    20 samples, speeds within 1e-4 relative of the landed ones (tol 1e-5; the dense
    interpolants are 3rd-7th order, their error is of the step error's size)."""
    sc = resolve_scene(scene)
    kw = dict(rtol=1e-5, atol=1e-5)
    land = Simulation(sc, method=method, **kw).run(0.5, sample_dt=0.025)
    dense = Simulation(sc, method=method, **kw).run(0.5, sample_dt=0.025, sampling='dense')
    assert dense.solver['naccept'] < land.solver['naccept']
    np.testing.assert_array_equal(dense.t, land.t)
    scale = np.max(np.abs(land.velocity))
    assert np.max(np.abs(dense.velocity - land.velocity)) < 1e-4 * scale


def test_dense_of_every_method_in_one_process() -> None:
    """rodas4's dense() calls hermite_dense with its K row, ros2's and rk4's with the default
    one: after a rodas4 dense() the others once raised 'hermite_dense expected 10 arguments,
    got 9' (one cached entry point per function). Every method's dense() in one process,
    rodas4 first."""
    for method in ('rodas4', 'ros2', 'rk4', 'rosenbrock', 'dop853', 'dopri5'):
        sim = Simulation(resolve_scene('kavz685_lever'), method=method, rtol=1e-6, atol=1e-6)
        h = 2e-5 if method in ('ros2', 'rk4') else None
        st = sim.make_stepper(sim.driveline.x0.copy(), 1.0, rtol=1e-6, atol=1e-6, h=h)
        st.advance_to(0.01)
        st.step()
        y = st.dense(0.5 * (st.t_old + st.t))
        assert y.shape == (st.n,) and np.all(np.isfinite(y)), method
