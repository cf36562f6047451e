"""kernel/kept_nb.py: the kept Rosenbrock run called with its arrays by address gives the same
bytes and counters as the bound entry point called with the arrays (a fresh Simulation's
run), on every run, for the three Rosenbrock tableaux, both samplings and a landing grid
apart from the samples; the other methods keep the bound call."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cvj_ros.physics.kernel import kept_nb
from cvj_ros.physics.scene import load_scene
from cvj_ros.physics.simulate import Simulation

SCENES = Path(__file__).resolve().parents[3] / 'config' / 'scenes'
FIELDS = ('t', 'position', 'velocity', 'effort', 'engine_torque', 'load_torque',
          'energy_residual')
COUNTERS = ('nfev', 'njev', 'nlu', 'naccept', 'nreject', 't', 'h')


def _bytes(tr) -> list[bytes]:
    return [getattr(tr, f).tobytes() for f in FIELDS]


# stiff rodas3 dense: the bench's run at 1e-3..1e-6; kavz685_lever land: its random load's
# breakpoints (every 10 ms) lie between the 7 ms samples, so the landing grid XG is not X;
# cardan_truck: intermediate members filled after the call (fill_mid_samples)
@pytest.mark.parametrize('scene_name, method, sampling', [
    ('stiff', 'rodas3', 'dense'), ('stiff', 'rosenbrock', 'land'),
    ('kavz685_lever', 'rodas4', 'land'), ('kavz685_lever', 'rosenbrock', 'dense'),
    ('cardan_truck', 'rodas3', 'dense')])
def test_kept_call_gives_the_bound_calls_bytes(scene_name: str, method: str,
                                               sampling: str) -> None:
    sc = load_scene(SCENES / f'{scene_name}.yaml')
    ref_sim = Simulation(sc, method=method, rtol=1e-4, atol=1e-6)
    ref = ref_sim.run(0.25, sample_dt=0.007, sampling=sampling)
    sim = Simulation(sc, method=method, rtol=1e-4, atol=1e-6)
    first = sim.run(0.25, sample_dt=0.007, sampling=sampling, reuse_trace=True)
    plan = sim._fast[1]
    assert plan.kept_call is not None
    if scene_name == 'kavz685_lever' and sampling == 'land':
        assert plan.XG is not None          # the landing grid apart from the samples
    expected = _bytes(ref)
    assert _bytes(first) == expected
    for _ in range(2):                      # spoiled, then rewritten by the kept call
        for f in FIELDS[1:]:
            getattr(first, f).fill(np.nan)
        sim.final_state.fill(np.nan)
        for k in COUNTERS:
            first.solver[k] = -1
        again = sim.run(0.25, sample_dt=0.007, sampling=sampling, reuse_trace=True)
        assert again is first
        assert _bytes(again) == expected
        assert sim.final_state.tobytes() == ref_sim.final_state.tobytes()
        assert {k: again.solver[k] for k in COUNTERS} == {k: ref.solver[k] for k in COUNTERS}


def test_kept_call_only_for_the_rosenbrock_run() -> None:
    """dopri5's kept run calls its bound entry point with the arrays (no kept call)."""
    sc = load_scene(SCENES / 'stiff.yaml')
    sim = Simulation(sc, method='dopri5', rtol=1e-3, atol=1e-3)
    for _ in range(2):
        sim.run(0.01, sample_dt=0.005, reuse_trace=True)
    assert sim._fast[1].kept is not None and sim._fast[1].kept_call is None


def test_kept_table_refuses_what_ros_run_would_not_take() -> None:
    """An array that is not C-contiguous, of another dtype or ndim, or read-only: no table
    (the run is then called with the arrays, which numba checks)."""
    f1, i1, f2 = np.zeros(4), np.zeros(4, np.int64), np.zeros((3, 2))
    head = [f1, i1, f1, i1, f1, i1, f1, f1, 0.0, 1e-3, np.inf, True, False, 0.5, 3, 6.0, 4]
    per_run = [f2, f2, f2, f2, f2, f1, f1, f1]
    table, floats = kept_nb.kept_table(head, per_run)
    assert table.shape == (kept_nb.TABLE_LEN,) and table[3] == f1.ctypes.data
    assert table[kept_nb.K_INTS:].tolist() == [1, 0, 3, 4]
    assert floats.tolist() == [0.0, 1e-3, np.inf, 0.5, 6.0]
    ro = np.zeros(4)
    ro.flags.writeable = False
    for k, bad in [(1, np.zeros(8)[::2]), (2, np.zeros(4)), (6, np.zeros((2, 2), np.int64)),
                   (7, ro)]:
        h = list(head)
        h[k - 1] = bad
        assert kept_nb.kept_table(h, per_run) is None, k
    assert kept_nb.kept_table(head, per_run[:-1]) is None


def test_kept_entry_compiles_by_signature_and_gives_the_same_bytes() -> None:
    """kept_entry compiles a dispatcher without a disk cache by its signature (it has no
    table to call it with, so nothing runs), and that entry point on a kept run's table
    writes the kept call's bytes."""
    from numba import njit
    sc = load_scene(SCENES / 'stiff.yaml')
    sim = Simulation(sc, method='rodas3', rtol=1e-3, atol=1e-3)
    first = sim.run(0.2, sample_dt=0.01, sampling='dense', reuse_trace=True)
    expected = _bytes(first)
    fresh = njit(kept_nb.ros_run_kept.py_func)     # caching off: compiled here
    entry = kept_nb.kept_entry(fresh)
    assert kept_nb.kept_entry(fresh) is entry and fresh.signatures == [kept_nb._SIG]
    call = sim._fast[1].kept_call
    for f in FIELDS[1:]:
        getattr(first, f).fill(np.nan)
    assert entry(call.args[0], sim._initial_energy(sim.driveline.x0)) == (0, -1)
    assert _bytes(first) == expected
