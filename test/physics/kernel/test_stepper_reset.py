"""KernelStepper.reset (kernel/stepper.py): a stepper started again at (t0, y0) takes the
same steps, with the same bytes and counters, as a new stepper of the same options -
Simulation.run reuses one stepper per plan on this promise."""
from __future__ import annotations

import numpy as np
import pytest

from cvj_ros.physics.kernel.stepper import KERNEL_METHODS
from cvj_ros.physics.scene import find_scene, load_scene
from cvj_ros.physics.simulate import Simulation


@pytest.mark.parametrize('scene', ['stiff', 'kavz685_lever'])
@pytest.mark.parametrize('method', KERNEL_METHODS)
def test_reset_repeats_a_new_steppers_run(scene: str, method: str) -> None:
    sim = Simulation(load_scene(find_scene(scene)), method=method, rtol=1e-5, atol=1e-7)
    x0 = sim.driveline.x0.copy()
    opts = dict(rtol=1e-5, atol=1e-7, h=1e-4 if method in ('rk4', 'ros2') else None)
    times = np.linspace(0.0, 0.2, 9)

    def run(st) -> tuple[bytes, dict]:
        Y = np.empty((times.size, x0.size))
        Y[0] = x0
        st.land(times, Y)
        Z = st.sample(np.linspace(st.t, st.t + 0.05, 4))   # dense output past the grid too
        return Y.tobytes() + Z.tobytes(), st.stats()

    new = sim.make_stepper(x0, 1.0, **opts)
    at_start = new.dense(0.0).tobytes()   # before any step (reads the last step's length)
    fresh = run(new)
    used = sim.make_stepper(x0, 1.0, **opts)
    run(used)
    used.advance_to(0.4)           # a different end state, h, last step and counters
    used.reset(0.0, x0)
    assert used.t == 0.0 and used.naccept == 0 and used.nfev == 0
    assert used.y.tobytes() == x0.tobytes()
    assert used.dense(0.0).tobytes() == at_start
    assert run(used) == fresh


@pytest.mark.parametrize('method', ['rodas3', 'dopri5'])
def test_stats_read_the_counters_the_attributes_hold(method: str) -> None:
    """stats() and stats_into() read t, h and the counters from the kernel arrays as slices
    (fs[t:h], cnt[nfev:nreject]); after a run they equal the attributes _sync sets from the
    layout constants one by one, and stats_into writes them into a dict without its other keys
    changing."""
    sim = Simulation(load_scene(find_scene('stiff')), method=method, rtol=1e-4, atol=1e-4)
    st = sim.make_stepper(sim.driveline.x0.copy(), 1.0, rtol=1e-4, atol=1e-4)
    st.advance_to(0.05)
    st.advance_to(0.1)
    d = st.stats()
    st._sync()
    assert d == {'method': method, 't': st.t, 'h': st.h, 'nfev': st.nfev, 'njev': st.njev,
                 'nlu': st.nlu, 'naccept': st.naccept, 'nreject': st.nreject}
    assert st.t == 0.1 and st.nfev > 0 and st.naccept > 0
    kept = {k: -1 for k in d} | {'method': 'other', 'extra': 'kept'}
    st.stats_into(kept)
    assert kept == d | {'method': 'other', 'extra': 'kept'}
