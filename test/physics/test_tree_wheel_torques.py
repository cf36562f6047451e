"""TreeDriveline with outside wheel loads (set_wheel_torques): the torque a wheel's tyre gives
at a state, handed in from outside, gives the same right-hand side (an independent path:
the tyre's F_x r through the input, divided back by r); a constant outside torque obeys the
energy balance; the compiled kernel refuses them by name."""
from __future__ import annotations

import numpy as np
import pytest

from cvj_ros.physics.scene import find_scene, load_scene
from cvj_ros.physics.tree import TreeDriveline


def _tree(name: str = 'fwd_axle', **kw) -> TreeDriveline:
    return TreeDriveline.from_scene(load_scene(find_scene(name)), **kw)


def test_tyre_torques_handed_in_from_outside_give_the_same_rhs() -> None:
    dl = _tree()
    x = np.array(dl.x0)
    x[2 * dl.n_dof:2 * dl.n_dof + dl.n_wheel] = [0.04, -0.02]      # some slip on each wheel
    f_tyre = dl.rhs(0.0, x, 120.0)
    out = dl.wheel_outputs(x)
    dl.set_wheel_torques([out[w.name]['fx'] * w.tyre.radius for w in dl.wheels])
    assert dl.wheel_names == ['wheel_left', 'wheel_right']
    np.testing.assert_allclose(dl.rhs(0.0, x, 120.0), f_tyre, rtol=1e-12, atol=1e-12)
    names, _p, _v, eff = dl.joint_states(x, 120.0)
    for w in ('wheel_left', 'wheel_right'):      # a wheel shaft's effort is the outside torque
        assert eff[names.index(w)] == pytest.approx(out[w]['fx'] * 0.3, rel=1e-12)
    dl.set_wheel_torques(None)
    np.testing.assert_array_equal(dl.rhs(0.0, x, 120.0), f_tyre)
    with pytest.raises(ValueError, match='2 needed, got 1'):
        dl.set_wheel_torques([1.0])


def test_constant_outside_wheel_torques_keep_the_energy_balance() -> None:
    from cvj_ros.physics.solvers import make_stepper
    dl = _tree(track_energy=True)
    dl.set_wheel_torques([150.0, 90.0])                 # unequal: the differential's delta moves
    x0 = np.array(dl.x0)
    e = dl.energy(x0)
    st = make_stepper('dopri5', lambda t, x: dl.rhs(t, x, 100.0), 0.0, x0, rtol=1e-10, atol=1e-12)
    x = st.advance_to(0.05)
    # the bound: the integrator's tolerance (1e-10 relative) over 0.05 s
    assert abs(dl.energy_residual(x, e['kinetic'] + e['elastic'])) < 1e-8
    # the body is driven by sum T/r as it would be by tyre forces
    dv = float(x[dl._iv] - x0[dl._iv])
    assert dv == pytest.approx(0.05 * dl.body.acceleration(float(x0[dl._iv]), 240.0 / 0.3), rel=2e-2)


def test_kernel_refuses_outside_wheel_loads_by_name() -> None:
    from cvj_ros.physics.kernel.layout import build_model
    dl = _tree()
    dl.set_wheel_torques([0.0, 0.0])
    with pytest.raises(NotImplementedError, match='outside wheel loads'):
        build_model(dl)
