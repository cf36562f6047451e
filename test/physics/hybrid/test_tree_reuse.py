"""tree_reuse: a repeated call with the same arguments returns the first call's objects; any
change of an argument (a bit of the state, the engine torque, another forces object)
evaluates afresh; a tree with a clutch-pack differential keeps no walk."""
from __future__ import annotations

import numpy as np

from cvj_ros.physics.hybrid.tree_reuse import LastKinematics, LastWalk, reuse_tree


def _counting(result):
    calls = []

    def fn(*args, **kwargs):
        calls.append((args, kwargs))
        return result(len(calls))
    return fn, calls


def test_last_kinematics_keys_on_the_state_bytes() -> None:
    fn, calls = _counting(lambda i: object())
    kin = LastKinematics(fn)
    x = np.array([1.0, 2.0, 3.0])
    first = kin(x)
    assert kin(x.copy()) is first and len(calls) == 1
    y = x.copy()
    y[1] = np.nextafter(2.0, 3.0)                    # one ulp
    assert kin(y) is not first and len(calls) == 2
    assert kin(x.copy()) is not first                # back to x: the last kept is y's
    z = np.array([0.0, 1.0])
    kin(z)
    kin(np.array([-0.0, 1.0]))                       # -0.0 differs in its bits
    assert len(calls) == 5
    kin([1.0, 2.0])                                  # not an array: never kept
    kin([1.0, 2.0])
    assert len(calls) == 7


def test_last_walk_keys_on_torque_state_and_the_objects() -> None:
    fn, calls = _counting(lambda i: (i,))
    walk = LastWalk(fn)
    x = np.array([0.5, 1.5])
    kin, fo = object(), object()
    r = walk(x, 10.0, kin=kin, fo=fo)
    assert walk(x.copy(), 10.0, kin=kin, fo=fo) is r and len(calls) == 1
    assert walk(x, 10.5, kin=kin, fo=fo) is not r
    assert walk(x, 10.5, kin=kin, fo=object()) is not r
    n = len(calls)
    walk(x, 10.5)                                    # without kin and fo: always afresh
    walk(x, 10.5)
    assert len(calls) == n + 2


class _Tree:
    def __init__(self, packs):
        self.packs = packs

    def _kinematics(self, x):
        return x.sum()

    def _walk(self, x, T_engine, *, kin=None, fo=None):
        return T_engine


def test_reuse_tree_installs_once_and_no_walk_with_a_pack() -> None:
    t = reuse_tree(_Tree({}))
    k, w = t._kinematics, t._walk
    assert isinstance(k, LastKinematics) and isinstance(w, LastWalk)
    assert reuse_tree(t)._kinematics is k and t._walk is w
    p = reuse_tree(_Tree({'lsd': None}))
    assert isinstance(p._kinematics, LastKinematics) and not isinstance(p._walk, LastWalk)
