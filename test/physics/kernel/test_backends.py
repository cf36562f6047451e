"""The compiled kernel under Simulation and CoupledStepper against the Python reference
backend (issue 9): same scene, same algorithm, same step sequence; the trajectories differ
only by rounding.

Bounds: both backends take the same steps (equal accepted/rejected/fev counts), so the
difference is rounding in the rhs sums and in the stage combinations (BLAS dot in
Python, fixed-order loops in the kernel), amplified along the trajectory - unless that
rounding flips a step decision of the reference (its BLAS kernel decides its last bits:
awd_4x4 under OPENBLAS_CORETYPE=Haswell), when only the scene's tolerance is guaranteed
(:func:`_assert_two_solutions_of_one_tolerance`). Measured on the
shipped scenes over 0.3 s: <= 4e-11 relative (Simulation), <= 1.5e-13 (CoupledStepper, 500
exchanges); asserted 1e-9, >= 25x margin (efforts: see the conditioning note in the test).
"""
from __future__ import annotations

import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from cvj_ros.physics.cosim import SCHEMES, CoupledStepper
from cvj_ros.physics.driveline import Driveline
from cvj_ros.physics.engine import engine_from_spec
from cvj_ros.physics.kernel import drop_stale_cache, sources_digest
from cvj_ros.physics.load import load_from_spec
from cvj_ros.physics.scene import load_scene, shipped_scenes
from cvj_ros.physics.simulate import Simulation

REL = 1e-9
COUNTERS = ('naccept', 'nreject', 'nfev')
# scenes with clutch, gearbox or brake run on the Python mode reference only (physics/hybrid)
SCENES = sorted(n for n, p in shipped_scenes().items() if not load_scene(p).has_modes)


def _rel(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.max(np.abs(a - b)) / max(1.0, float(np.max(np.abs(b)))))


@pytest.mark.parametrize('name', SCENES)
def test_simulation_kernel_matches_python_reference(name: str) -> None:
    scene = load_scene(shipped_scenes()[name])
    dur = min(0.3, scene.duration)
    kern = Simulation(scene)
    ref = Simulation(scene, backend='python')
    a, b = kern.run(dur), ref.run(dur)
    if kern.backend == 'python':    # an element the kernel does not cover: said, not hidden
        assert kern.backend_note and kern.backend_note.startswith('compiled kernel: ')
        pytest.skip(kern.backend_note)
    assert a.solver['backend'] == 'kernel' and b.solver['backend'] == 'python'
    # effort holds spring torques c * twist: a twist differing by rounding (dphi) moves them
    # by c * dphi, ill-conditioned for the stiff scene (c = 1e6 N m/rad: measured 3.6e-8 N m
    # from 3e-14 rad); bound 10x that conditioning on top of REL.
    laws = [sp[0] if isinstance(sp, tuple) else sp for sp in kern.driveline.springs]  # tree: (law, l, r)
    c_max = max((law.c for law in laws), default=0.0)
    if any(a.solver[c] != b.solver[c] for c in COUNTERS):
        _assert_two_solutions_of_one_tolerance(scene, a, b, c_max)
        return
    assert _rel(a.velocity, b.velocity) < REL
    assert _rel(a.position, b.position) < REL
    d_eff = float(np.max(np.abs(a.effort - b.effort)))
    d_pos = float(np.max(np.abs(a.position - b.position)))
    assert d_eff <= REL * max(1.0, float(np.max(np.abs(b.effort)))) + 10 * c_max * d_pos
    assert np.allclose(a.energy_residual, b.energy_residual, rtol=0, atol=1e-9)
    # the kernel's samples come from the compiled walk (kernel/outputs_nb.py), the Python
    # ones from Driveline._walk / energy: torques and names must agree too
    assert _rel(a.engine_torque, b.engine_torque) < REL and _rel(a.load_torque, b.load_torque) < REL
    assert a.names == b.names


def _assert_two_solutions_of_one_tolerance(scene, a, b, c_max: float) -> None:
    """The kernel (fixed-order sums: the same bytes under every OPENBLAS_CORETYPE) and the
    Python reference (np.dot, LAPACK: its last bits follow the CPU's BLAS kernel) took
    different steps: a step decision of the reference lay within rounding of its threshold
    and flipped (awd_4x4 under OPENBLAS_CORETYPE=Haswell: 769 accepted / 52 rejected in the
    kernel, 770 / 50 in the reference; every other core type tried: the same steps). Equal
    step sequences are then not guaranteed, only two solutions of the same tolerance: the
    counts differ by a few steps (1 % of the accepted ones) and the samples by about one
    step's local error, below the scene's rtol (measured there: velocity 7.9e-9 relative,
    position 4.3e-12, rtol 1e-6)."""
    rtol = scene.solver.rtol
    assert abs(a.solver['naccept'] - b.solver['naccept']) <= 0.01 * b.solver['naccept'], (a.solver, b.solver)
    for got, ref in ((a.velocity, b.velocity), (a.position, b.position),
                     (a.engine_torque, b.engine_torque), (a.load_torque, b.load_torque)):
        assert _rel(got, ref) < rtol, (a.solver, b.solver, _rel(got, ref))
    # efforts: spring torques c * twist, conditioned as in the equal-steps case (the caller)
    d_pos = float(np.max(np.abs(a.position - b.position)))
    assert float(np.max(np.abs(a.effort - b.effort))) <= \
        rtol * max(1.0, float(np.max(np.abs(b.effort)))) + 10 * c_max * d_pos
    assert a.names == b.names


def test_a_source_the_kernel_does_not_cover_falls_back_with_one_line() -> None:
    scene = load_scene(shipped_scenes()['kavz685_lever'])

    class OwnLoad:      # a user's Python load model: the kernel cannot evaluate it
        def torque(self, t: float, omega: float, phi: float) -> float:
            return 100.0 + 0.1 * omega

        def slope(self, t: float, omega: float, phi: float) -> float:
            return 0.1

    sim = Simulation(scene, load=OwnLoad())
    assert sim.backend == 'python'
    assert sim.backend_note == ('compiled kernel: load model OwnLoad is not covered yet; '
                                'running the Python reference')
    assert '\n' not in sim.backend_note
    assert sim.run(0.01).solver['backend'] == 'python'


@pytest.mark.parametrize('scheme', SCHEMES)
@pytest.mark.parametrize('name', ['kavz685_lever', 'fwd_halfshaft'])
def test_coupled_stepper_kernel_matches_python(name: str, scheme: str) -> None:
    """The lockstep integration (coupling node) with the torques arriving at exchange
    points, each scheme's torque law through the kernel's input block."""
    scene = load_scene(shipped_scenes()[name])
    out = {}
    for backend in ('kernel', 'python'):
        dl = Driveline.from_scene(scene)
        eng = engine_from_spec(scene.engine)
        load = load_from_spec(scene.load, seed=scene.seed)
        cs = CoupledStepper(dl, scheme=scheme, method=scene.solver.method, rtol=scene.solver.rtol,
                            atol=scene.solver.atol, h=scene.solver.h, backend=backend)
        assert cs.backend == backend
        x, H, states = dl.x0.copy(), scene.exchange_step, []
        for k in range(200):
            t = k * H
            we, wl = dl.engine_omega(x), dl.load_omega(x)
            pe, pl = dl.engine_phi(x), dl.load_phi(x)
            x = cs.advance((k + 1) * H, eng.torque(t, we, pe), load.torque(t, wl, pl),
                           slope_engine=eng.slope(t, we, pe), slope_load=load.slope(t, wl, pl))
            states.append(np.array(x))
        out[backend] = (np.array(states), cs.stats())
    (a, sa), (b, sb) = out['kernel'], out['python']
    for c in COUNTERS:
        assert sa[c] == sb[c], c
    assert _rel(a, b) < REL


def test_coupled_stepper_backend_choice() -> None:
    scene = load_scene(shipped_scenes()['kavz685_lever'])
    assert CoupledStepper(Driveline.from_scene(scene)).backend == 'kernel'

    class Toy:          # any DrivelineLike that is not a Driveline runs in Python
        x0 = np.zeros(2)

        def rhs(self, t, x, Te, Tl):
            return np.array([x[1], Te - Tl])

        def engine_omega(self, x):
            return float(x[1])

        def load_omega(self, x):
            return float(x[1])

    assert CoupledStepper(Toy()).backend == 'python'
    with pytest.raises(ValueError, match='^backend: '):
        CoupledStepper(Toy(), backend='kernel')
    with pytest.raises(ValueError, match='^backend: '):
        CoupledStepper(Toy(), backend='fortran')


def test_stale_cache_is_dropped_when_a_physics_source_changes(tmp_path: Path) -> None:
    """numba checks a cached function against its own file only; the steppers inline
    rhs_nb and the joint formulas, so any physics edit must drop the package's cache."""
    phys = tmp_path / 'physics'
    (phys / 'kernel' / '__pycache__').mkdir(parents=True)
    (phys / 'joints' / '__pycache__').mkdir(parents=True)
    (phys / 'kernel' / 'rhs_nb.py').write_text('x = 1\n')
    (phys / 'joints' / 'hooke.py').write_text('y = 2\n')
    cached = [phys / 'kernel' / '__pycache__' / 'steppers_nb.dopri5_advance-1.py311.nbi',
              phys / 'kernel' / '__pycache__' / 'steppers_nb.dopri5_advance-1.py311.1.nbc',
              phys / 'joints' / '__pycache__' / 'hooke.f-3.py311.nbi']
    for f in cached:
        f.write_bytes(b'old')
    assert drop_stale_cache(None, phys) is True          # no stamp yet: unknown age
    assert not any(f.exists() for f in cached)
    for f in cached:
        f.write_bytes(b'new')
    assert drop_stale_cache(None, phys) is False         # sources unchanged: kept
    assert all(f.exists() for f in cached)
    (phys / 'joints' / 'hooke.py').write_text('y = 3\n')  # a callee changed
    assert drop_stale_cache(None, phys) is True
    assert not any(f.exists() for f in cached)
    assert sources_digest(phys) != sources_digest(Path(__file__).parent)


def test_only_the_modules_that_reach_a_changed_file_lose_their_cache(tmp_path: Path) -> None:
    """numba allows per-function recompilation; what a compiled function can inline is what
    its module imports (transitively): an edit drops exactly those modules' cache files."""
    phys = tmp_path / 'physics'
    for d in ('kernel', 'joints'):
        (phys / d / '__pycache__').mkdir(parents=True)
    (phys / '__pycache__').mkdir()
    (phys / '__init__.py').write_text('')
    (phys / 'joints' / '__init__.py').write_text('')
    (phys / 'kernel' / '__init__.py').write_text('')
    (phys / 'joints' / 'hooke.py').write_text('A = 1\n')
    (phys / 'joints' / 'tripod.py').write_text('B = 1\n')
    (phys / 'kernel' / 'rhs_nb.py').write_text('from cvj_ros.physics.joints import hooke\n')
    (phys / 'kernel' / 'steppers_nb.py').write_text('from . import rhs_nb\n')
    (phys / 'simulate.py').write_text('from cvj_ros.physics.kernel import steppers_nb\n')
    (phys / 'engine.py').write_text('def f():\n    from .joints.tripod import B\n')
    cache = {name: phys / sub / '__pycache__' / f'{name}.f-1.py311.nbi'
             for sub, name in (('joints', 'hooke'), ('joints', 'tripod'), ('kernel', 'rhs_nb'),
                               ('kernel', 'steppers_nb'), ('.', 'engine'))}

    def refill() -> None:
        for f in cache.values():
            f.write_bytes(b'x')

    def kept() -> set[str]:
        return {n for n, f in cache.items() if f.exists()}
    refill()
    assert drop_stale_cache(None, phys) is True and kept() == set()   # no record yet
    refill()
    (phys / 'simulate.py').write_text('from cvj_ros.physics.kernel import steppers_nb\nX = 2\n')
    assert drop_stale_cache(None, phys) is False and kept() == set(cache)   # nothing imports it
    (phys / 'joints' / 'hooke.py').write_text('A = 2\n')
    assert drop_stale_cache(None, phys) is True
    assert kept() == {'tripod', 'engine'}            # hooke, rhs_nb and steppers_nb recompile
    refill()
    (phys / 'joints' / 'tripod.py').write_text('B = 2\n')   # imported inside a function
    assert drop_stale_cache(None, phys) is True and kept() == {'hooke', 'rhs_nb', 'steppers_nb'}
    refill()
    (phys / 'kernel' / 'gone_nb.py').write_text('')
    orphan = phys / 'kernel' / '__pycache__' / 'old_nb.f-1.py311.nbi'   # module no longer there
    orphan.write_bytes(b'x')
    assert drop_stale_cache(None, phys) is True and not orphan.exists() and kept() == set(cache)


DIGEST = r'''
import hashlib, sys
from cvj_ros.cli import main
csv = sys.argv[1]
assert main(['simulate', 'kavz685_lever', '--duration', '0.3', '--csv', csv]) == 0
print(hashlib.sha256(open(csv, 'rb').read()).hexdigest())
'''


def test_offline_trace_bytes_do_not_depend_on_openblas_kernel(tmp_path: Path) -> None:
    """Issue 9 item 4: the integration path has no BLAS, so `cvj-sim simulate` writes the
    same bytes in-process and in fresh interpreters under every OPENBLAS_CORETYPE (each
    inherits this process's environment but that one variable). The last run loads the
    cached kernel numba's own way (``CVJ_KERNEL_LOAD=numba``, full target initialisation)
    instead of ``kernel.load_cached``: same machine code, so the same bytes."""
    from cvj_ros.cli import main
    here = tmp_path / 'here.csv'
    assert main(['simulate', 'kavz685_lever', '--duration', '0.3', '--csv', str(here)]) == 0
    import hashlib
    first = hashlib.sha256(here.read_bytes()).hexdigest()
    for core in ('Haswell', 'SkylakeX', 'Sandybridge', None, 'numba-load'):
        env = dict(os.environ)
        env.pop('OPENBLAS_CORETYPE', None)
        env.pop('CVJ_KERNEL_LOAD', None)
        if core == 'numba-load':
            env['CVJ_KERNEL_LOAD'] = 'numba'
        elif core is not None:
            env['OPENBLAS_CORETYPE'] = core
        proc = subprocess.run([sys.executable, '-c', DIGEST, str(tmp_path / f'{core}.csv')],
                              capture_output=True, text=True, timeout=300, env=env)
        assert proc.returncode == 0, proc.stderr
        assert proc.stdout.strip().splitlines()[-1] == first, core
    assert math.isfinite(float(here.read_text().splitlines()[-1].split(',')[1]))


@pytest.mark.parametrize('method', ['dopri5', 'dop853', 'rk4', 'ros2', 'rosenbrock', 'rodas4'])
def test_land_in_one_call_gives_the_bytes_of_the_advance_to_loop(method: str) -> None:
    """KernelStepper.land (Simulation's sampling without a progress callback) runs the same
    compiled advance per sample as advance_to, so states and counters are identical."""
    from cvj_ros.physics.kernel import rhs_nb
    from cvj_ros.physics.kernel.stepper import KernelStepper
    sim = Simulation(load_scene(shipped_scenes()['kavz685_lever']))
    model = sim._model(0.2)
    times = np.linspace(0.0, 0.2, 9)
    kw = dict(rtol=1e-6, atol=1e-9, h=1e-4 if method in ('rk4', 'ros2') else None,
              jac=rhs_nb.jac)
    a = KernelStepper(method, rhs_nb.rhs, model.ip, model.fp.copy(), 0.0, model.x0, **kw)
    b = KernelStepper(method, rhs_nb.rhs, model.ip, model.fp.copy(), 0.0, model.x0, **kw)
    X = np.empty((times.size, model.x0.size))
    a.land(times, X)
    for k in range(1, times.size):
        np.testing.assert_array_equal(X[k], b.advance_to(float(times[k])))
    assert (a.nfev, a.naccept, a.nreject, a.t) == (b.nfev, b.naccept, b.nreject, b.t)


def test_simulation_reruns_and_progress_path_give_identical_traces() -> None:
    """The packed model is kept per horizon and copied per run; a rerun and the
    per-sample path (taken when a progress callback is given) give the same bytes."""
    sim = Simulation(load_scene(shipped_scenes()['kavz685_lever']), rtol=1e-7, atol=1e-9)
    seen: list[float] = []
    first = sim.run(0.3, sample_dt=0.01)
    second = sim.run(0.3, sample_dt=0.01)
    third = sim.run(0.3, sample_dt=0.01, progress=seen.append)
    for tr in (second, third):
        np.testing.assert_array_equal(tr.velocity, first.velocity)
        np.testing.assert_array_equal(tr.position, first.position)
        assert tr.solver['nfev'] == first.solver['nfev']
    assert len(seen) == first.t.size - 1
