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
