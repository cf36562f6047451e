"""The mode segments' right-hand sides without heap allocation: ``tree_modes_nb.tm_eval``
keeps its scratch rows (and the backward walk's) in its stack frame, ``segment_nb``'s
mode_segment its own, so a segment's NRT allocations do not grow with its rhs calls.

numba counts NRT allocations only with NUMBA_NRT_STATS=1 set before it starts: the counts
are taken in a child process."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip('numba')

ROOT = Path(__file__).resolve().parents[3]

_CHILD = r'''
import json
import numpy as np
from numba import njit
from numba.core.runtime import rtsys
import cvj_ros.physics.kernel.modes as km
import cvj_ros.physics.kernel.tree_modes as tmm
from cvj_ros.physics.hybrid.from_scene import hybrid_simulation
from cvj_ros.physics.kernel.modes import KernelHybridSimulation
from cvj_ros.physics.kernel.tree_modes import KernelHybridTreeSimulation
from cvj_ros.physics.kernel.tree_modes_nb import MB_NWIT, tm_eval
from cvj_ros.physics.scene import find_scene, load_scene


@njit
def loop(t, y, ip, fp, dy, wv, want, reps):
    for _ in range(reps):
        tm_eval(t, y, ip, fp, dy, wv, want)
    return dy[0]


def allocs():
    return rtsys.get_allocation_stats().alloc


out = {}
for name in ('launch_clutch', 'launch_clutch_chain'):
    calls = []
    orig = km.run_segment

    def rec(*a):
        calls.append([x.copy() if isinstance(x, np.ndarray) else x for x in a])
        orig(*a)
    km.run_segment = tmm.run_segment = rec
    scene = load_scene(find_scene(name))
    kern = KernelHybridTreeSimulation if scene.is_tree else KernelHybridSimulation
    kern.from_reference(hybrid_simulation(scene, method='dopri5', rtol=1e-5, atol=1e-7,
                                          sample_dt=0.5, duration=2.0)).run()
    km.run_segment = tmm.run_segment = orig
    segs = []
    for c in calls:
        a = [x.copy() if isinstance(x, np.ndarray) else x for x in c]
        orig(*a)                                   # compiled / loaded, warm
        a = [x.copy() if isinstance(x, np.ndarray) else x for x in c]
        n0 = allocs()
        orig(*a)
        segs.append([allocs() - n0, int(a[15][4])])
    out[name] = {'segments': segs}
    if scene.is_tree:
        kind, t, y, ip, fp = c[0], c[2], c[4], c[5], c[6]
        dy = np.zeros_like(y)
        wv = np.zeros(max(int(ip[ip[-1] + MB_NWIT]), 1))
        rows = []
        for want in (False, True):
            for reps in (1, 1000):          # the call's own: its array arguments' meminfos
                loop(t, y, ip, fp, dy, wv, want, reps)
                n0 = allocs()
                loop(t, y, ip, fp, dy, wv, want, reps)
                rows.append(allocs() - n0)
        out[name]['tm_eval'] = rows
print(json.dumps(out))

'''


def test_mode_segments_allocate_per_segment_not_per_rhs_call() -> None:
    """A compiled loop of 1000 tm_eval calls (want False and True) allocates what one call
    does (its arguments' meminfos from Python); every segment of launch_clutch's and
    launch_clutch_chain's first 2 s allocates the same count whatever its rhs calls (before:
    three arrays per tm_eval call, the witnesses' walk three more)."""
    env = dict(os.environ, NUMBA_NRT_STATS='1', PYTHONPATH=str(ROOT))
    res = subprocess.run([sys.executable, '-c', _CHILD], capture_output=True, text=True,
                         env=env, cwd=ROOT, timeout=1800)
    assert res.returncode == 0, res.stderr[-2000:]
    out = json.loads(res.stdout.strip().splitlines()[-1])
    one_f, many_f, one_t, many_t = out['launch_clutch']['tm_eval']
    assert many_f == one_f and many_t == one_t, out['launch_clutch']['tm_eval']
    for name in ('launch_clutch', 'launch_clutch_chain'):
        segs = out[name]['segments']
        assert max(n for _a, n in segs) > 5 * min(n for _a, n in segs), segs
        assert len({a for a, _n in segs}) == 1, segs
