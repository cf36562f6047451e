"""kernel/borrow_nb.py: reference-count-free views write through to the caller's arrays,
leave its reference counts alone, and pass non-arrays through."""
from __future__ import annotations

import sys

import numpy as np
from numba import njit

from cvj_ros.physics.kernel.borrow_nb import borrowed, borrowed_all


@njit
def _fill_through_view(a, b, k):
    a, b, k = borrowed_all((a, b, k))
    for i in range(a.shape[0]):
        a[i] = 2.0 * b[i, 1] + k
    return a.sum()


@njit
def _view_of(a):
    v = borrowed(a)
    return v[0], v.shape[0], v.strides[0]


def test_borrowed_views_write_through_and_keep_reference_counts():
    a = np.zeros(5)
    b = np.arange(10.0).reshape(5, 2)
    before = (sys.getrefcount(a), sys.getrefcount(b))
    total = _fill_through_view(a, b, 3)
    np.testing.assert_array_equal(a, 2.0 * b[:, 1] + 3)
    assert total == a.sum()
    for _ in range(100):
        _fill_through_view(a, b, 3)
    assert (sys.getrefcount(a), sys.getrefcount(b)) == before


def test_borrowed_keeps_shape_strides_and_non_contiguous_views():
    base = np.arange(12.0)
    a = base[::3]
    assert _view_of(a) == (0.0, 4, 24)


def test_kernel_entry_points_borrow_their_arrays():
    """Every stepper entry point Python calls starts with borrowed_all (a missing one only
    costs speed, so it is checked in the source)."""
    import ast
    import inspect

    from cvj_ros.physics.kernel import steppers_nb
    tree = ast.parse(inspect.getsource(steppers_nb))
    entries = {'dopri5_advance', 'dop853_advance', 'ros2_advance', 'ros_advance', 'rk4_advance',
               'dopri5_land', 'dop853_land', 'ros2_land', 'ros_land', 'rk4_land',
               'dopri5_step_once', 'dop853_step', 'ros2_step_once', 'ros_step', 'rk4_step_once',
               'dopri5_sample', 'rk4_sample', 'dop853_dense', 'hermite_dense'}
    seen = set()
    for node in tree.body:
        if isinstance(node, ast.FunctionDef) and node.name in entries:
            first = node.body[1]
            assert isinstance(first, ast.Assign) and first.value.func.id == 'borrowed_all', node.name
            seen.add(node.name)
    assert seen == entries


def test_rhs_call_tree_and_step_chain_compile_without_calls_between_them():
    """The helpers under the rhs and the step chain under each land/advance are inlined at
    numba IR level, and the rhs compiles without reference counting: every call left
    between them passed its arrays exploded with an NRT incref/decref per array (rhs per
    call, docs/solvers.md "Where an rhs call's time goes": stiff 96 -> 27 ns). A missing
    flag only costs speed, so the flags themselves are checked."""
    from cvj_ros.physics.kernel import joints_nb, rhs_nb, sources_nb, steppers_nb
    inlined = {rhs_nb: ('section', '_sigmoid_of', 'spring_deflection', 'spring_eval',
                        'deflection_slope', 'spring_torque', 'engine_torque', 'load_torque'),
               sources_nb: ('engine_eval', 'load_eval', 'random_load', 'time_series_load'),
               joints_nb: ('joint_eval', 'tripod_series_at', 'fmod_two_pi_3'),
               steppers_nb: ('_first_nonfinite', '_proposal', '_dopri5_attempt', 'dopri5_step',
                             '_dopri5_fsal', 'dopri5_advance', '_store_row', 'lu_factor',
                             'lu_solve', '_ros_prepare', '_ros_stages', '_proposal_nobeta',
                             '_rk4_take', 'rk4_advance', '_ros2_take', 'ros2_advance',
                             'ros_step', 'ros_advance', 'dop853_step', 'dop853_advance')}
    for mod, names in inlined.items():
        for name in names:
            assert getattr(mod, name).targetoptions.get('inline') == 'always', name
    assert rhs_nb.rhs.targetoptions.get('_nrt') is False


def test_rhs_without_reference_counting_called_from_python_leaves_counts_alone():
    """rhs (compiled with _nrt=False) called from Python, as the bench's solve_ivp with the
    compiled rhs does: the caller's arrays keep their reference counts, dy is written."""
    from cvj_ros.physics.kernel import rhs_nb
    from cvj_ros.physics.kernel.layout import build_model
    from cvj_ros.physics.scene import find_scene, load_scene
    from cvj_ros.physics.simulate import Simulation
    sim = Simulation(load_scene(find_scene('kavz685_lever')))
    model = build_model(sim.driveline, engine=sim.engine, load=sim.load, horizon=1.0)
    y, dy = model.x0.copy(), np.full(model.n_state, np.nan)
    counts = [sys.getrefcount(a) for a in (y, model.ip, model.fp, dy)]
    for _ in range(100):
        rhs_nb.rhs(0.01, y, model.ip, model.fp, dy)
    assert [sys.getrefcount(a) for a in (y, model.ip, model.fp, dy)] == counts
    np.testing.assert_allclose(dy, sim.fun(0.01, y), rtol=1e-12, atol=0.0)


def test_stack_zeros_2d_is_zeroed_writable_and_released_per_call():
    """stack_zeros_2d: zeros of the asked shape, writable, a fresh zeroed array at every call
    (a million calls from a loop: the stack does not grow)."""
    from cvj_ros.physics.kernel.borrow_nb import stack_zeros_2d

    @njit
    def fill(r, c):
        a = stack_zeros_2d(r, c)
        s = 0.0
        for i in range(r):
            for j in range(c):
                s += a[i, j]          # zero before any write
                a[i, j] += 10.0 * i + j
        return s, a.sum(), a.shape[0], a.shape[1], a.strides[0]

    @njit
    def many(n):
        t = 0.0
        for _ in range(n):
            t += fill(11, 4)[1]
        return t

    assert fill(3, 5) == (0.0, sum(10.0 * i + j for i in range(3) for j in range(5)), 3, 5, 40)
    assert many(1_000_000) == 1_000_000 * fill(11, 4)[1]
