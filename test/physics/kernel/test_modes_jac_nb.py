"""The analytic Jacobian of a chain mode (kernel/modes_jac_nb.py, hybrid/chain_jac.py)
against central differences of the mode's right-hand side, and the two backends against
each other, at the start of every mode of the shipped launch (clutch slipping and stuck,
brake stuck and slipping, every gear, neutral) and at states with random slip speeds.

Bound: a central difference of increment h_j = 1e-6 max(1, |y_j|) errs by
h_j^2 |f'''| / 6 (truncation) plus ~eps |f| / h_j (rounding); on these states both are
below 1e-6 of the column's scale max(max_i |J_ij|, max_i |f_i| / max(1, |y_j|))
(measured <= 4.9e-10), so an entry off by a missing term (relative 1) fails. The two
backends' Jacobians are the same formula: measured equal bit for bit, bound 1e-12.
"""
from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from cvj_ros.physics.hybrid.from_scene import hybrid_simulation
from cvj_ros.physics.scene import load_scene, shipped_scenes

pytest.importorskip('numba')
from cvj_ros.physics.kernel.modes import KernelHybridSimulation  # noqa: E402
from cvj_ros.physics.kernel.modes_jac_nb import mode_jac  # noqa: E402
from cvj_ros.physics.kernel.modes_nb import N_SCRATCH_EXTRA, mode_eval  # noqa: E402

FD_TOL = 1e-6


def _mode_starts(name: str = 'launch_clutch_chain', duration: float = 6.0, sim=None):
    """(simulation, kernel simulation, [(asm, mode, t, y0)]) of every mode segment of a
    dopri5 kernel run of a shipped scene (or of ``sim``)."""
    if sim is None:
        sim = hybrid_simulation(load_scene(shipped_scenes()[name]), duration=duration)
    k = KernelHybridSimulation.from_reference(sim)
    seen = []
    plain = k._segment

    def spy(asm, mode, t, t_stop, y0, times, k_sample):
        seen.append((asm, mode.copy(), t, np.array(y0, dtype=float)))
        return plain(asm, mode, t, t_stop, y0, times, k_sample)
    k._segment = spy
    k.run()
    return sim, k, seen


def _states(asm, y0, rng):
    """y0 and two states with random angles and speeds around it (slip of either sign)."""
    n = len(asm.groups)
    out = [y0]
    for _ in range(2):
        y = y0.copy()
        y[:n] += rng.uniform(-0.5, 0.5, n)
        y[n:2 * n] += rng.uniform(-30.0, 30.0, n)
        if asm.pinned:
            y[2 * n - 1] = 0.0
        out.append(y)
    return out


def _central(f, t, y):
    n = y.size
    J = np.empty((n, n))
    for j in range(n):
        h = 1e-6 * max(1.0, abs(y[j]))
        yp, ym = y.copy(), y.copy()
        yp[j] += h
        ym[j] -= h
        J[:, j] = (f(t, yp) - f(t, ym)) / (2.0 * h)
    return J


def _check(J, J_fd, f0, y) -> float:
    scale = np.maximum(np.max(np.abs(J), axis=0), np.max(np.abs(f0)) / np.maximum(1.0, np.abs(y)))
    scale = np.maximum(scale, 1e-300)
    err = float(np.max(np.abs(J - J_fd) / scale))
    assert err <= FD_TOL, err
    return err


def _random_chain(seed: int):
    """test_modes_kernel's random chain under random commands (a Hooke joint in some)."""
    spec = importlib.util.spec_from_file_location(
        'modes_kernel_cases', Path(__file__).with_name('test_modes_kernel.py'))
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod._random_chain_sim(seed)()


def _has_joint(sim) -> bool:
    return any(fn is not None for sec in sim.chain.sections for _jv, fn in sec)


def test_mode_jacobians_match_central_differences_and_each_other() -> None:
    _check_run(*_mode_starts(), min_modes=4)


def test_mode_jacobians_through_a_hooke_joint() -> None:
    """Random chains with a Hooke joint behind the gearbox (the ratio slope b, dM/dq and
    the central-difference dC/dq of a group) under random commands."""
    sims = [s for s in (_random_chain(seed) for seed in range(6)) if _has_joint(s)]
    assert sims, 'no random chain with a joint'
    for sim in sims[:2]:
        _check_run(*_mode_starts(sim=sim), min_modes=2)


def _check_run(sim, k, seen, min_modes: int) -> None:
    """Every mode start (and two random states around it): kernel and reference Jacobians
    against central differences and each other."""
    rng = np.random.default_rng(7)
    kinds = set()
    worst_fd = worst_twin = 0.0
    for asm, mode, t, y0 in seen:
        kinds.add((tuple(sorted(mode.clutch.items())), tuple(sorted(mode.gear.items())),
                   mode.brake))
        ip, fp, ns = k.mode_arrays(asm, mode)
        sc = np.zeros(ip[0] + N_SCRATCH_EXTRA)

        def f_kernel(tt, yy):
            dy = np.zeros(ns)
            mode_eval(tt, yy, ip, fp, dy, sc, False)
            return dy

        def f_ref(tt, yy, asm=asm, mode=mode):
            return sim._eval(asm, mode, tt, yy).ydot

        for y in _states(asm, y0, rng):
            Jk = np.zeros((ns, ns))
            mode_jac(t, y, ip, fp, Jk)
            Jp = sim._jac(asm, mode, t, y)
            f0 = f_ref(t, y)
            worst_fd = max(worst_fd, _check(Jk, _central(f_kernel, t, y), f0, y),
                           _check(Jp, _central(f_ref, t, y), f0, y))
            # the same formula in both backends: equal to rounding
            scale = np.maximum(np.max(np.abs(Jp), axis=0), 1.0)
            d = float(np.max(np.abs(Jk - Jp) / scale))
            worst_twin = max(worst_twin, d)
            assert d <= 1e-12, d
    # the modes: the clutch slipping and stuck, several gears and neutral
    assert len(kinds) >= min_modes, kinds
    assert worst_fd > 0.0


def test_pinned_group_rows_are_zero() -> None:
    """A stuck brake pins the last group: its angle and speed rows of J are zero."""
    sim, k, seen = _mode_starts(duration=1.0)
    pinned = [(a, m, t, y) for a, m, t, y in seen if a.pinned]
    assert pinned, 'the launch starts held by the brake'
    asm, mode, t, y = pinned[0]
    n = len(asm.groups)
    J = sim._jac(asm, mode, t, y)
    assert not J[n - 1].any() and not J[2 * n - 1].any()
