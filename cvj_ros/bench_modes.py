"""Work-precision of scenes with clutch, gearbox and brake (stick/slip modes with events).

Project: the compiled kernel (:class:`cvj_ros.physics.kernel.modes.KernelHybridSimulation`,
a vehicle scene :class:`cvj_ros.physics.kernel.tree_modes.KernelHybridTreeSimulation`;
each mode one compiled call with its witnesses and Brent on the dense output), with each of
:data:`KERNEL_METHODS` (the project's cheapest run at a level is its best method there, as
the expert's is the best of its two).
Baseline: plain ``scipy.integrate.solve_ivp`` (RK45) on the same mode equations, its event
functions the same witnesses (terminal, with their directions), restarted at every event and
command row: what a user of scipy writes (:class:`SolveIvpHybridSimulation`, a vehicle
scene :class:`SolveIvpHybridTreeSimulation`). Both share
the discrete decisions (the reference's code), the sampling and the recording. Reference:
the Python reference with dop853 at rtol 1e-12 on a chain; on a vehicle scene, whose Python
reference at that tolerance takes the better part of an hour for launch_clutch's 10 s, the
compiled kernel with dopri5 at rtol 1e-13 (:data:`KERNEL_REFERENCE`), which reproduces the
Python reference's events and states to 1e-12 on the same mesh
(test/physics/kernel/test_tree_modes_kernel.py) and is checked against it and against dop853
in test/test_bench_modes.py. Error: the largest sampled shaft speed
error over the run relative to the largest reference shaft speed (as ``cvj_ros.bench``'s
``err_speed_rel``). At each error level 1e-3..1e-8 the cheapest run of each family reaching
it is taken; the speedup is baseline wall / project wall, and the same with the process's
CPU time (``time.process_time``: on a loaded machine the fairer ratio).

Expert baseline (family ``baseline_expert``, when numbalsoda imports): numbalsoda's LSODA
(Petzold 1983) or DOP853 (Hairer, Norsett & Wanner 1993) on the kernel's compiled
right-hand side of each mode (``modes_nb.mode_eval``, ``tree_modes_nb.tm_eval``, through
:func:`cvj_ros.bench_expert.mode_expert_cfunc`) with **oracle events**: numbalsoda has no
event location, so each mode segment ends at the time and witness the oracle run (the
kernel at :data:`KERNEL_REFERENCE`) ended it (:class:`ExpertHybridSimulation`,
:class:`ExpertHybridTreeSimulation`). The expert gets the event times for free: a lower
bound on its cost. The mode loop around the segments (the discrete decisions, the
sampling, the recording) is the project's own, so both pay the same Python per transition.
A second expert family, ``baseline_expert_bisect`` (methods 'lsoda-bisect',
'dop853-bisect'), locates its own events: the witnesses (``segment_nb._witness_at``) on a
GRID_DT grid of numbalsoda's output, the earliest crossing in its direction refined on
REFINE_POINTS-point grids (bisection by subdivision) to 1e-12 s.
"""
from __future__ import annotations

import functools
import math
import os
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from cvj_ros.physics.kernel.modes import KernelHybridSimulation
from cvj_ros.physics.kernel.tree_modes import KernelHybridTreeSimulation

__all__ = ['ExpertHybridSimulation', 'ExpertHybridTreeSimulation', 'KERNEL_METHODS', 'KERNEL_REFERENCE',
           'MODE_SCENES', 'OracleMismatch', 'PYTHON_REFERENCE', 'SolveIvpHybridSimulation',
           'SolveIvpHybridTreeSimulation', 'event_time_error', 'expert_verdict',
           'format_expert_table', 'format_mode_table', 'mode_levels', 'mode_study', 'oracle_run', 'reference_run']

MODE_SCENES = ('launch_clutch_chain', 'launch_clutch')
LEVELS = (1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8)
TOLERANCES = (1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9, 1e-10)
#: reference of a vehicle mode scene: the compiled kernel, (method, rtol, atol)
KERNEL_REFERENCE = ('dopri5', 1e-13, 1e-15)
#: the kernel's methods timed on the mode scenes: dopri5 and the higher-order explicit
#: pairs of the kernel's mode segments (Hairer, Norsett & Wanner 1993; Verner 2010)
KERNEL_METHODS = ('dopri5', 'dop853', 'vern7')
PYTHON_REFERENCE = ('dop853', 1e-12, 1e-14)


class SolveIvpHybridSimulation(KernelHybridSimulation):
    """The mode loop with each mode integrated by plain solve_ivp (RK45, Python rhs, the
    witnesses as terminal event functions, dense output for the samples)."""

    def _segment(self, asm, mode, t, t_stop, y0, times, k_sample):
        from scipy.integrate import solve_ivp
        n = len(asm.groups)
        ws = self._witnesses(asm, mode)

        def fun(tt: float, yy: np.ndarray) -> np.ndarray:
            return self._eval(asm, mode, tt, yy).ydot
        events = []
        for w in ws:
            def ev(tt: float, yy: np.ndarray, w=w) -> float:
                return self._g(w, self._eval(asm, mode, tt, yy), tt, yy, n)
            ev.terminal = True
            ev.direction = w.direction
            events.append(ev)
        sol = solve_ivp(fun, (t, t_stop), np.asarray(y0, dtype=float), method='RK45',
                        rtol=self.rtol, atol=self.atol, events=events or None,
                        dense_output=True)
        if sol.status < 0:
            raise RuntimeError(f'solve_ivp: {sol.message}')
        self.stats['steps'] += len(sol.t) - 1
        self.stats['nfev'] += int(sol.nfev)
        ev_i, t_end, y = -1, t_stop, sol.y[:, -1]
        if sol.status == 1:
            hits = [(float(te[0]), i) for i, te in enumerate(sol.t_events) if len(te)]
            t_end, ev_i = min(hits)
            y = sol.y_events[ev_i][0]
        k_new = k_sample
        while k_new < times.size and times[k_new] <= t_end:
            k_new += 1
        Y = np.array([y if ts == t_end else sol.sol(ts) for ts in times[k_sample:k_new]])
        return np.array(y), t_end, ev_i, k_new, Y.reshape(k_new - k_sample, y.size)


def _solve_ivp_segment(fun: Callable[..., Any], g_fns: list[tuple[Callable[..., float], int]],
                       t: float, t_stop: float, y0: np.ndarray, times: np.ndarray,
                       k_sample: int, rtol: float, atol: Any, stats: dict[str, int]
                       ) -> tuple[np.ndarray, float, int, int, np.ndarray]:
    """One mode by solve_ivp RK45 with the witnesses g(t, y) as terminal events (their
    directions): (state at the end, end time, event index or -1, next sample, samples)."""
    from scipy.integrate import solve_ivp
    events = []
    for g, direction in g_fns:
        def ev(tt: float, yy: np.ndarray, g=g) -> float:
            return g(tt, yy)
        ev.terminal = True
        ev.direction = direction
        events.append(ev)
    sol = solve_ivp(fun, (t, t_stop), np.asarray(y0, dtype=float), method='RK45', rtol=rtol,
                    atol=atol, events=events or None, dense_output=True)
    if sol.status < 0:
        raise RuntimeError(f'solve_ivp: {sol.message}')
    stats['steps'] += len(sol.t) - 1
    stats['nfev'] += int(sol.nfev)
    ev_i, t_end, y = -1, t_stop, sol.y[:, -1]
    if sol.status == 1:
        hits = [(float(te[0]), i) for i, te in enumerate(sol.t_events) if len(te)]
        t_end, ev_i = min(hits)
        y = sol.y_events[ev_i][0]
    k_new = k_sample
    while k_new < times.size and times[k_new] <= t_end:
        k_new += 1
    Y = np.array([y if ts == t_end else sol.sol(ts) for ts in times[k_sample:k_new]])
    return np.array(y), t_end, ev_i, k_new, Y.reshape(k_new - k_sample, y.size)


class SolveIvpHybridTreeSimulation(KernelHybridTreeSimulation):
    """The vehicle mode loop with each mode integrated by plain solve_ivp (RK45, the
    reference's Python rhs, its witnesses as terminal event functions)."""

    def _segment(self, mt, mode, t, t_stop, y0, times, k_sample, stats):
        ws = self._witnesses(mode)
        need_t = any(w.key[0] == 'clutch' and w.key[2] != 0 for w in ws)     # as the reference

        def fun(tt: float, yy: np.ndarray) -> np.ndarray:
            return self._eval(mt, tt, yy, False).ydot
        g_fns = [((lambda tt, yy, w=w: self._g(w, self._eval(mt, tt, yy, need_t), tt, mode)),
                  w.direction) for w in ws]
        return _solve_ivp_segment(fun, g_fns, t, t_stop, y0, times, k_sample, self.rtol,
                                  self.atol, stats)


#: the expert's methods on the mode scenes: numbalsoda with oracle events, or with its own
#: witness bisection (family baseline_expert_bisect)
EXPERT_MODE_METHODS = ('lsoda', 'dop853', 'lsoda-bisect', 'dop853-bisect')
#: one oracle segment: (start time, end time, the witness key that ended it or None: t_stop)
OracleSegment = tuple[float, float, Any]


class OracleMismatch(RuntimeError):
    """The expert's run left the oracle's sequence of mode segments."""


class _OracleChain(KernelHybridSimulation):
    """The chain kernel recording each segment's (start, end, witness key) in ``oracle``."""

    oracle: list[OracleSegment]

    def _segment(self, asm, mode, t, t_stop, y0, times, k_sample):
        out = super()._segment(asm, mode, t, t_stop, y0, times, k_sample)
        ev_i = out[2]
        self.oracle.append((t, out[1], self._witnesses(asm, mode)[ev_i].key if ev_i >= 0 else None))
        return out


class _OracleTree(KernelHybridTreeSimulation):
    """The tree kernel recording each segment's (start, end, witness key) in ``oracle``."""

    oracle: list[OracleSegment]

    def _segment(self, mt, mode, t, t_stop, y0, times, k_sample, stats):
        out = super()._segment(mt, mode, t, t_stop, y0, times, k_sample, stats)
        ev_i = out[2]
        self.oracle.append((t, out[1], self._witnesses(mode)[ev_i].key if ev_i >= 0 else None))
        return out


def _expert_segment(sim: Any, kind: int, ip: np.ndarray, fp: np.ndarray, ramps: Sequence[int],
                    keys: list[tuple], t: float, t_stop: float, y0: np.ndarray,
                    times: np.ndarray, k_sample: int, stats: dict[str, int]
                    ) -> tuple[np.ndarray, float, int, int, np.ndarray]:
    """One mode segment by numbalsoda ``sim.expert_method`` from (t, y0) to the oracle's end
    of the segment starting at t (its witness index among ``keys``, or t_stop): (state at
    the end, end time, witness index or -1, next sample index, the samples' states). The
    commands' ramps end at t_stop, as in the kernel's segment (a jump there seen from the
    left); samples within 1e-12 s (relative) of an end take that end's state."""
    import numbalsoda

    from cvj_ros.bench_expert import P_COUNT, mode_expert_data
    i = sim._oracle_next
    if i >= len(sim.oracle):
        raise OracleMismatch(f'oracle events: a segment at t={t:.9f} s after the oracle run ended')
    t0, t_end, key = sim.oracle[i]
    if abs(t0 - t) > 1e-9 * max(1.0, abs(t)):
        raise OracleMismatch(f'oracle events: a segment at t={t:.9f} s, the oracle\'s at {t0:.9f} s')
    if key is None:
        ev_i, t_end = -1, t_stop
    elif key in keys:
        ev_i = keys.index(key)
    else:
        raise OracleMismatch(f'oracle events: the oracle\'s event {key} at t={t_end:.9f} s is not '
                             f'a witness of the mode at t={t:.9f} s')
    sim._oracle_next = i + 1
    for off in ramps:
        fp[off + 1 + 2 * int(fp[off])] = t_stop
    y0 = np.ascontiguousarray(y0, dtype=np.float64)
    ns = y0.size
    k_new = k_sample
    while k_new < times.size and times[k_new] <= t_end:
        k_new += 1
    samp = times[k_sample:k_new]
    eps = 1e-12 * max(1.0, abs(t_end))
    Y = np.empty((samp.size, ns))
    if t_end - t <= eps:
        Y[:] = y0
        return y0.copy(), t_end, ev_i, k_new, Y
    inner = (samp > t + eps) & (samp < t_end - eps)
    t_eval = np.concatenate(([t], samp[inner], [t_end]))
    sc = sim._expert_sc
    data = mode_expert_data(kind, ip, fp, ns, sc)
    sol, ok = getattr(numbalsoda, sim.expert_method)(
        sim.expert_address, y0, t_eval, data=data, rtol=float(sim.rtol), atol=sim._expert_atol,
        mxstep=1_000_000)
    if not ok:
        raise RuntimeError(f'numbalsoda {sim.expert_method}: integration failed near t={t:.6f} s')
    stats['nfev'] += int(data[P_COUNT])
    y = sol[-1].copy()
    Y[samp <= t + eps] = y0
    Y[samp >= t_end - eps] = y
    Y[inner] = sol[1:-1]
    return y, t_end, ev_i, k_new, Y


#: the witness-bisection expert's detection grid (s): witnesses checked every GRID_DT
GRID_DT = 0.001
#: points per refinement round of a crossing's grid interval (rounds until 1e-12 s relative)
REFINE_POINTS = 64


@functools.lru_cache(maxsize=1)
def _witness_rows() -> Any:
    """A compiled loop: the mode's witness values (segment_nb._witness_at) at each row of a
    numbalsoda solution (not disk-cached: compiled on first use, outside the timing)."""
    from numba import njit

    from cvj_ros.physics.kernel.segment_nb import _witness_at

    @njit
    def rows(kind, ts, Y, ip, fp, sc, W):   # pragma: no cover - compiled
        dy = np.zeros(Y.shape[1])
        wv = np.zeros(max(W.shape[1], 1))
        for k in range(ts.shape[0]):
            _witness_at(kind, ts[k], Y[k], ip, fp, dy, sc, wv)
            for i in range(W.shape[1]):
                W[k, i] = wv[i]
    return rows


def _first_crossing(W: np.ndarray, dirs: np.ndarray) -> tuple[int, int]:
    """(row k, witness i) of the earliest crossing between rows k-1 and k in the witness's
    direction (the kernel's rule: direction < 0 from > 0 to <= 0, else from < 0 to >= 0);
    (-1, -1) without one. Ties in a row: the lowest witness index."""
    if W.shape[1] == 0 or W.shape[0] < 2:
        return -1, -1
    a, b = W[:-1], W[1:]
    hit = np.where(dirs < 0, (a > 0.0) & (b <= 0.0), (a < 0.0) & (b >= 0.0))
    rows = np.flatnonzero(hit.any(axis=1))
    if rows.size == 0:
        return -1, -1
    k = int(rows[0]) + 1
    return k, int(np.flatnonzero(hit[k - 1])[0])


def _bisect_segment(sim: Any, kind: int, ip: np.ndarray, fp: np.ndarray, ramps: Sequence[int],
                    dirs: np.ndarray, t: float, t_stop: float, y0: np.ndarray,
                    times: np.ndarray, k_sample: int, stats: dict[str, int]
                    ) -> tuple[np.ndarray, float, int, int, np.ndarray]:
    """One mode segment by numbalsoda with its own event location: the solution on the
    samples and a GRID_DT grid up to t_stop, the witnesses at every grid row (compiled), and
    for the earliest crossing in its direction REFINE_POINTS-point refinements of its grid
    interval (one numbalsoda call each, from the interval's left state) until the interval
    is within 1e-12 s (relative) of the crossing; the event is its right end. Returns as
    the kernel's segment."""
    import numbalsoda

    from cvj_ros.bench_expert import P_COUNT, mode_expert_data
    for off in ramps:
        fp[off + 1 + 2 * int(fp[off])] = t_stop
    y0 = np.ascontiguousarray(y0, dtype=np.float64)
    ns = y0.size
    eps = 1e-12 * max(1.0, abs(t_stop))
    solve = getattr(numbalsoda, sim.expert_method)
    data = mode_expert_data(kind, ip, fp, ns, sim._expert_sc)
    rows = _witness_rows()
    nw = dirs.size

    def run(a: float, ya: np.ndarray, ts: np.ndarray) -> np.ndarray:
        data[P_COUNT] = 0.0
        sol, ok = solve(sim.expert_address, ya, ts, data=data, rtol=float(sim.rtol),
                        atol=sim._expert_atol, mxstep=1_000_000)
        stats['nfev'] += int(data[P_COUNT])
        if not ok:
            raise RuntimeError(f'numbalsoda {sim.expert_method}: integration failed near t={a:.6f} s')
        return sol
    k_end = k_sample
    while k_end < times.size and times[k_end] <= t_stop:
        k_end += 1
    samp = times[k_sample:k_end]
    if t_stop - t <= eps:
        return y0.copy(), t_stop, -1, k_end, np.tile(y0, (samp.size, 1))
    n_grid = max(1, int(math.ceil((t_stop - t) / GRID_DT)))
    grid = np.linspace(t, t_stop, n_grid + 1)
    ts = np.unique(np.concatenate((grid, samp[(samp > t + eps) & (samp < t_stop - eps)])))
    sol = run(t, y0, ts)
    ev_i, t_end, y_end = -1, t_stop, sol[-1]
    if nw:
        W = np.empty((ts.size, nw))
        rows(kind, ts, sol, ip, fp, sim._expert_sc, W)
        k, i = _first_crossing(W, dirs)
        if k >= 0:
            a, b, ya, yb = ts[k - 1], ts[k], sol[k - 1], sol[k]
            while b - a > eps:
                sub = np.linspace(a, b, REFINE_POINTS + 1)
                part = run(a, ya, sub)
                Wp = np.empty((sub.size, nw))
                rows(kind, sub, part, ip, fp, sim._expert_sc, Wp)
                kp, ip_ = _first_crossing(Wp, dirs)
                if kp < 0:          # the crossing vanished on the finer grid: take the old end
                    break
                i = ip_
                a, b, ya, yb = sub[kp - 1], sub[kp], part[kp - 1], part[kp]
            ev_i, t_end, y_end = i, float(b), yb
    k_new = k_sample
    while k_new < times.size and times[k_new] <= t_end:
        k_new += 1
    Y = np.empty((k_new - k_sample, ns))
    for j, tsj in enumerate(times[k_sample:k_new]):
        if tsj <= t + eps:
            Y[j] = y0
        elif tsj >= t_end - eps:
            Y[j] = y_end
        else:
            Y[j] = sol[int(np.searchsorted(ts, tsj))]
    return np.array(y_end), t_end, ev_i, k_new, Y


class _ExpertMixin:
    """The expert's settings: numbalsoda method, the cfunc's address, the oracle."""

    expert_method = 'dop853'
    expert_events = 'oracle'
    expert_address = 0
    oracle: Sequence[OracleSegment] = ()

    def _expert_setup(self, method: str, oracle: Sequence[OracleSegment]) -> None:
        """``method`` 'lsoda' or 'dop853' (oracle events: ``oracle`` the segments), or with
        '-bisect' (its own event location, :func:`_bisect_segment`; ``oracle`` unused)."""
        from cvj_ros.bench_expert import mode_expert_cfunc
        method, _, events = method.partition('-')
        if method not in ('lsoda', 'dop853') or events not in ('', 'bisect'):
            raise ValueError(f"expert method: 'lsoda' or 'dop853' (+ '-bisect'), not {method!r}")
        self.expert_events = events or 'oracle'
        if events:
            _witness_rows()          # compiled outside the timing
        atol = getattr(self, 'atol')
        if np.ndim(atol) != 0:
            raise NotImplementedError('numbalsoda takes one scalar atol')
        self.expert_method = method
        self.expert_address = mode_expert_cfunc().address
        self.oracle = oracle
        self._oracle_next = 0
        self._expert_atol = float(atol)
        self._expert_sc = np.zeros(256)


class ExpertHybridSimulation(_ExpertMixin, KernelHybridSimulation):
    """The chain's mode loop with each mode integrated by numbalsoda on the mode's compiled
    rhs (``modes_nb.mode_eval``) up to the oracle's end of the segment."""

    @classmethod
    def expert(cls, sim: Any, method: str, oracle: Sequence[OracleSegment]) -> ExpertHybridSimulation:
        """The expert twin of a (not yet run) Python-reference simulation."""
        out = cls.from_reference(sim)
        out._expert_setup(method, oracle)
        return out

    def run(self) -> Any:
        self._oracle_next = 0
        return super().run()

    def _segment(self, asm, mode, t, t_stop, y0, times, k_sample):
        from cvj_ros.physics.kernel.modes_nb import MH_RAMP_B, MH_RAMP_C, MH_RAMP_T
        ip, fp, _ns = self.mode_arrays(asm, mode)
        ws = self._witnesses(asm, mode)
        ramps = (ip[MH_RAMP_T], ip[MH_RAMP_C], ip[MH_RAMP_B])
        if self.expert_events == 'bisect':
            return _bisect_segment(self, 0, ip, fp, ramps, np.array([w.direction for w in ws]),
                                   t, t_stop, y0, times, k_sample, self.stats)
        return _expert_segment(self, 0, ip, fp, ramps, [w.key for w in ws], t, t_stop, y0,
                               times, k_sample, self.stats)


class ExpertHybridTreeSimulation(_ExpertMixin, KernelHybridTreeSimulation):
    """The vehicle's mode loop with each mode integrated by numbalsoda on the mode's
    compiled rhs (``tree_modes_nb.tm_eval``) up to the oracle's end of the segment."""

    @classmethod
    def expert(cls, sim: Any, method: str, oracle: Sequence[OracleSegment]) -> ExpertHybridTreeSimulation:
        """The expert twin of a (not yet run) Python-reference simulation."""
        out = cls.from_reference(sim)
        out._expert_setup(method, oracle)
        return out

    def run(self) -> Any:
        self._oracle_next = 0
        return super().run()

    def _segment(self, mt, mode, t, t_stop, y0, times, k_sample, stats):
        from cvj_ros.physics.kernel.tree_modes import tree_mode_arrays
        from cvj_ros.physics.kernel.tree_modes_nb import MB_RAMP_B, MB_RAMP_C, MB_RAMP_T
        ip, fp = tree_mode_arrays(self, mt, mode)
        mb = int(ip[-1])
        ws = self._witnesses(mode)
        ramps = (ip[mb + MB_RAMP_T], ip[mb + MB_RAMP_C], ip[mb + MB_RAMP_B])
        if self.expert_events == 'bisect':
            return _bisect_segment(self, 1, ip, fp, ramps, np.array([w.direction for w in ws]),
                                   t, t_stop, y0, times, k_sample, stats)
        return _expert_segment(self, 1, ip, fp, ramps, [w.key for w in ws], t, t_stop, y0,
                               times, k_sample, stats)


def oracle_run(scene: Any, horizon: float, sample_dt: float) -> tuple[Any, list[OracleSegment]]:
    """The kernel at :data:`KERNEL_REFERENCE` recording its mode segments: (its result, the
    segments' (start, end, witness key or None))."""
    from cvj_ros.physics.hybrid.from_scene import hybrid_simulation
    method, rtol, atol = KERNEL_REFERENCE
    sim = hybrid_simulation(scene, method=method, rtol=rtol, atol=atol, sample_dt=sample_dt,
                            duration=horizon)
    k = (_OracleTree if scene.is_tree else _OracleChain).from_reference(sim)
    k.oracle = []
    return k.run(), k.oracle


def event_time_error(r: Any, ref: Any) -> float:
    """The largest |t - t_ref| (s) over the run's events against the reference's, inf when
    the two take different discrete paths (another count, element or mode change)."""
    if [(e.element, e.before, e.after) for e in r.events] != \
            [(e.element, e.before, e.after) for e in ref.events]:
        return float('inf')
    return max((abs(a.t - b.t) for a, b in zip(r.events, ref.events)), default=0.0)


def _speed_error(r: Any, ref: Any) -> float:
    if r.speed.shape != ref.speed.shape or r.stall is not None:
        return float('inf')
    return float(np.max(np.abs(r.speed - ref.speed)) / max(1e-300, float(np.max(np.abs(ref.speed)))))


def reference_run(scene: Any, horizon: float, sample_dt: float, backend: str) -> Any:
    """The reference run: ``backend`` 'python' (:data:`PYTHON_REFERENCE` on the Python
    reference) or 'kernel' (:data:`KERNEL_REFERENCE` on the compiled kernel)."""
    from cvj_ros.physics.hybrid.from_scene import hybrid_simulation
    method, rtol, atol = KERNEL_REFERENCE if backend == 'kernel' else PYTHON_REFERENCE
    sim = hybrid_simulation(scene, method=method, rtol=rtol, atol=atol, sample_dt=sample_dt,
                            duration=horizon)
    if backend == 'kernel':
        sim = (KernelHybridTreeSimulation if scene.is_tree else KernelHybridSimulation).from_reference(sim)
    return sim.run()


def mode_study(scene_name: str = 'launch_clutch_chain', *,
               tolerances: Sequence[float] = TOLERANCES, samples: int = 20, repeats: int = 3,
               baseline_budget_s: float = 60.0, duration: float | None = None,
               reference: str = 'auto', expert_methods: Sequence[str] = (),
               baseline: bool = True, kernel_methods: Sequence[str] = ('dopri5',),
               log: Callable[[str], None] = print) -> dict[str, Any]:
    """Runs of both families at each tolerance (rtol = tol, atol = tol / 100) over the
    scene's duration (or ``duration`` s) with ``samples`` samples, best of ``repeats`` walls
    (the kernel's and the expert's: of at least 10; the baseline's stop repeating after
    ``baseline_budget_s``), against the ``reference`` ('python', 'kernel', or 'auto': the
    kernel on a vehicle scene, else the Python reference); ``expert_methods`` (numbalsoda
    'lsoda', 'dop853') add the ``baseline_expert`` family with oracle events (module
    docstring; skipped with ``expert_skipped`` set when numbalsoda does not import);
    ``baseline=False`` leaves out solve_ivp; ``kernel_methods`` the project's methods
    (rows labelled 'kernel METHOD', each at every tolerance). Each row keeps the load average before and
    after its runs and ``event_dt_max`` (:func:`event_time_error` against the reference); returns {'scene', 'duration', 'reference', 'rows', 'levels'}."""
    from cvj_ros.physics.hybrid.from_scene import hybrid_simulation
    from cvj_ros.physics.scene import find_scene, load_scene
    scene = load_scene(find_scene(scene_name))
    horizon = float(duration or scene.duration)
    sample_dt = horizon / samples
    backend = ('kernel' if scene.is_tree else 'python') if reference == 'auto' else reference
    if backend not in ('python', 'kernel'):
        raise ValueError(f"reference: 'auto', 'python' or 'kernel', not {reference!r}")
    method, rtol, _atol = KERNEL_REFERENCE if backend == 'kernel' else PYTHON_REFERENCE
    skipped: str | None = None
    bad = [m for m in expert_methods if m not in EXPERT_MODE_METHODS]
    if bad:
        raise ValueError(f"expert_methods: {', '.join(map(repr, EXPERT_MODE_METHODS))}, not "
                         f"{', '.join(map(repr, bad))}")
    from cvj_ros.physics.kernel.modes import KERNEL_MODE_METHODS
    bad = [m for m in kernel_methods if m not in KERNEL_MODE_METHODS]
    if bad or not kernel_methods:
        raise ValueError(f"kernel_methods: one or more of {', '.join(KERNEL_MODE_METHODS)}, not "
                         f"{', '.join(map(repr, bad)) or 'none'}")
    if expert_methods:
        from cvj_ros.bench_expert import mode_expert_cfunc, unavailable_reason
        skipped = unavailable_reason()
        if skipped is None:
            try:
                mode_expert_cfunc()      # compiled (or loaded) outside the timing
            except Exception as exc:     # an optional baseline never stops the bench
                skipped = ('numbalsoda is installed but its cfunc did not compile ('
                           + (str(exc).splitlines() or [type(exc).__name__])[0][:120] + ')')
        if skipped is not None:
            log(f'[bench] {scene.name}: baseline_expert skipped: {skipped}')
            expert_methods = ()
    t0 = time.perf_counter()
    oracle: list[OracleSegment] = []
    if backend == 'kernel' and expert_methods:
        ref, oracle = oracle_run(scene, horizon, sample_dt)     # the reference itself
    else:
        ref = reference_run(scene, horizon, sample_dt, backend)
    ref_wall = time.perf_counter() - t0
    log(f'[bench] {scene.name}: mode reference ({backend}, {method}, rtol {rtol:g}) in '
        f'{ref_wall:.1f} s, {len(ref.events)} events')
    if expert_methods and not oracle:
        t0 = time.perf_counter()
        _r, oracle = oracle_run(scene, horizon, sample_dt)
        log(f'[bench] {scene.name}: oracle events (kernel {KERNEL_REFERENCE[0]}, rtol '
            f'{KERNEL_REFERENCE[1]:g}) in {time.perf_counter() - t0:.1f} s, {len(oracle)} segments, '
            f'{len(_r.events)} events')
    kern: Any = KernelHybridTreeSimulation if scene.is_tree else KernelHybridSimulation
    base: Any = SolveIvpHybridTreeSimulation if scene.is_tree else SolveIvpHybridSimulation
    expert: Any = ExpertHybridTreeSimulation if scene.is_tree else ExpertHybridSimulation
    # one untimed kernel run per method: loads (or compiles) the compiled mode code
    for m in kernel_methods:
        kern.from_reference(hybrid_simulation(scene, method=m, sample_dt=sample_dt,
                                              duration=horizon)).run()
    families: list[tuple[str, str, Callable[[Any], Any], str]] = [
        ('project', f'kernel {m}', kern.from_reference, m) for m in kernel_methods]
    if baseline:
        families.append(('baseline', 'solve_ivp RK45 + events', base.from_reference, 'dopri5'))
    for m in expert_methods:
        bisect = m.endswith('-bisect')
        families.append(('baseline_expert_bisect' if bisect else 'baseline_expert',
                         f"numbalsoda {m.split('-')[0]} "
                         + (f'(witness bisection, {GRID_DT * 1e3:g} ms grid)' if bisect else '(oracle events)'),
                         lambda sim, m=m: expert.expert(sim, m, oracle), 'dopri5'))
        # one untimed run: numbalsoda's solver compiled outside the timing
        try:
            with _quiet(True):
                expert.expert(hybrid_simulation(scene, method='dopri5', rtol=1e-6, atol=1e-8,
                                                sample_dt=sample_dt, duration=horizon),
                              m, oracle).run()
        except Exception:
            pass                         # the timed runs record the failure
    rows: list[dict[str, Any]] = []
    for family, label, make, run_method in families:
        for tol in tolerances:
            walls: list[float] = []
            cpus: list[float] = []
            r = sim = None
            failed = ''
            load0 = _load()
            # numbalsoda's diagnostics on stdout go to /dev/null (a failure is the row's), outside the timing
            with _quiet(family == 'baseline_expert'):
                # the compiled runs are short: more repeats (their minimum) at little cost
                for _ in range(repeats if family == 'baseline' else max(repeats, 10)):
                    sim = make(hybrid_simulation(scene, method=run_method, rtol=tol, atol=tol * 1e-2,
                                                 sample_dt=sample_dt, duration=horizon))
                    w0 = time.perf_counter()
                    c0 = time.process_time()
                    try:
                        r = sim.run()
                    except Exception as exc:     # a failing configuration is a row, not a stop
                        r = None
                        failed = str(exc)[:100] or type(exc).__name__
                        break
                    walls.append(time.perf_counter() - w0)
                    cpus.append(time.process_time() - c0)
                    if family == 'baseline' and sum(walls) > baseline_budget_s:
                        break
            if failed:
                log(f'[bench] {scene.name}: {label} rtol {tol:g} failed: {failed}')
            row = {'scene': scene.name, 'family': family, 'tol': tol, 'ok': r is not None,
                   'label': label, 'note': failed}
            if r is not None:
                row.update(wall_s=min(walls), cpu_s=min(cpus), wall_per_sim_s=min(walls) / horizon,
                           repeats=len(walls), err_speed_rel=_speed_error(r, ref),
                           events=len(r.events), event_dt_max=event_time_error(r, ref),
                           steps=r.stats['steps'] if family in ('project', 'baseline') else None,
                           nfev=r.stats['nfev'], energy_residual=r.max_energy_residual,
                           load=(load0, _load()))
                steps = f"{row['steps']} steps" if row['steps'] is not None else f"{row['nfev']} rhs"
                log(f"[bench] {scene.name}: {label} rtol {tol:g}: err {row['err_speed_rel']:.2e}, "
                    f"{row['wall_s'] * 1e3:.1f} ms (CPU {row['cpu_s'] * 1e3:.1f} ms), {steps}, "
                    f"{row['events']} events (largest event time shift {row['event_dt_max']:.1e} s), "
                    f"energy residual {row['energy_residual']:.2e}")
            rows.append(row)
    out = {'scene': scene.name, 'duration': horizon,
           'reference': {'backend': backend, 'method': method, 'rtol': rtol, 'wall_s': ref_wall,
                         'events': len(ref.events),
                         'energy_residual': ref.max_energy_residual},
           'rows': rows, 'levels': mode_levels(rows)}
    if oracle:
        out['oracle'] = {'segments': len(oracle), 'events': sum(1 for o in oracle if o[2] is not None)}
    if skipped is not None:
        out['expert_skipped'] = skipped
    return out


def _quiet(on: bool) -> Any:
    """:func:`cvj_ros.bench_expert.quiet_stdout` when ``on``, else a no-op."""
    import contextlib
    if not on:
        return contextlib.nullcontext()
    from cvj_ros.bench_expert import quiet_stdout
    return quiet_stdout()


def _load() -> float:
    """The 1-minute load average (nan where the platform has none)."""
    try:
        return float(os.getloadavg()[0])
    except OSError:
        return float('nan')


def mode_levels(rows: Sequence[dict[str, Any]], levels: Sequence[float] = LEVELS
                ) -> list[dict[str, Any]]:
    """Per error level the cheapest row (least wall) of each family reaching it and the
    speedups over the project's in wall and CPU time ('speedup', 'cpu_speedup' against
    solve_ivp; 'speedup_expert', 'cpu_speedup_expert' against baseline_expert; '_bisect'
    against baseline_expert_bisect)."""
    out = []
    for lv in levels:
        entry: dict[str, Any] = {'level': lv}
        for fam in ('project', 'baseline', 'baseline_expert', 'baseline_expert_bisect'):
            cand = [r for r in rows if r.get('ok') and r['family'] == fam and r['err_speed_rel'] <= lv]
            entry[fam] = min(cand, key=lambda r: r['wall_s']) if cand else None
        p = entry['project']
        for b, key in ((entry['baseline'], ''), (entry['baseline_expert'], '_expert'),
                       (entry['baseline_expert_bisect'], '_bisect')):
            entry['speedup' + key] = b['wall_s'] / p['wall_s'] if p and b else None
            entry['cpu_speedup' + key] = (b['cpu_s'] / p['cpu_s'] if p and b and 'cpu_s' in p
                                          and 'cpu_s' in b and p['cpu_s'] > 0 else None)
        out.append(entry)
    return out


def format_mode_table(study: dict[str, Any]) -> str:
    """Markdown table of :func:`mode_study`'s levels: per family the rtol, CPU and wall ms,
    then the speedups in CPU time and in wall, and the load average over the two rows."""
    ref = study.get('reference', {})
    lines = [f"### {study['scene']} ({study['duration']:g} s): stick/slip modes with events "
             f"(kernel vs solve_ivp + events)",
             '',
             f"Reference: {ref.get('backend', 'python')} {ref.get('method', 'dop853')} at rtol "
             f"{ref.get('rtol', 1e-12):g}, {ref.get('events', '?')} events.",
             '',
             '| error level | best kernel | rtol | CPU ms | wall ms | solve_ivp RK45 + events rtol '
             '| CPU ms | wall ms | speedup (CPU time) | speedup (wall) | load |',
             '| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |']
    for e in study['levels']:
        p, b = e['project'], e['baseline']

        def cell(r: dict[str, Any] | None) -> tuple[str, str, str]:
            if not r:
                return ('-', '-', '-')
            cpu = f"{r['cpu_s'] * 1e3:.1f}" if 'cpu_s' in r else '-'
            return (f"{r['tol']:g}", cpu, f"{r['wall_s'] * 1e3:.1f}")
        sp = f"{e['speedup']:.1f}x" if e['speedup'] else '-'
        cpu = f"{e['cpu_speedup']:.1f}x" if e.get('cpu_speedup') else '-'
        loads = [x for r in (p, b) if r for x in r.get('load', ()) if x == x]
        load = f'{min(loads):.1f}-{max(loads):.1f}' if loads else '-'
        lines.append(f"| {e['level']:g} | {_kernel_name(p)} | {' | '.join(cell(p))} | "
                     f"{' | '.join(cell(b))} | {cpu} | {sp} | {load} |")
    return '\n'.join(lines) + '\n'


def _kernel_name(r: dict[str, Any] | None) -> str:
    """The method of a project row ('kernel dop853' -> 'dop853'), '-' for none."""
    return r['label'].removeprefix('kernel ') if r else '-'


#: the target against the expert baseline: the project at least this many times cheaper
EXPERT_TARGET = 2.0


def format_expert_table(study: dict[str, Any], family: str = 'baseline_expert') -> str:
    """Markdown table of the project against ``family`` ('baseline_expert': oracle events,
    or 'baseline_expert_bisect': the witness bisection) per error level (the cheapest run of
    each reaching it: rtol, CPU and wall ms, expert / project in CPU time and wall, the
    >= 2x verdict on both, the load) and a verdict line; the one skip line when the expert
    was asked for but numbalsoda is missing; '' when not asked for."""
    if study.get('expert_skipped'):
        return f"baseline_expert skipped: {study['expert_skipped']}\n" if family == 'baseline_expert' else ''
    if not any(r['family'] == family for r in study['rows']):
        return ''
    key = '_bisect' if family == 'baseline_expert_bisect' else '_expert'
    if key == '_expert':
        orc = study.get('oracle', {})
        head = (f"#### {study['scene']}: kernel vs numbalsoda on the same compiled mode rhs "
                '(oracle events)')
        text = ('The expert ends each mode segment at the oracle\'s event time and witness (the '
                f"kernel at rtol {KERNEL_REFERENCE[1]:g}: {orc.get('segments', '?')} segments, "
                f"{orc.get('events', '?')} located events): it gets the event times for free, a "
                'lower bound on its cost.')
    else:
        head = (f"#### {study['scene']}: kernel vs numbalsoda on the same compiled mode rhs "
                '(witness bisection)')
        text = (f'The expert locates its own events: the witnesses on a {GRID_DT * 1e3:g} ms grid, '
                f'each crossing refined on {REFINE_POINTS}-point grids to 1e-12 s.')
    lines = [head, '', text, '',
             '| error level | best kernel | rtol | CPU ms | wall ms | best numbalsoda | rtol | CPU ms '
             '| wall ms | expert / kernel (CPU time) | expert / kernel (wall) | >= 2x | load |',
             '| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |']
    for e in study['levels']:
        p, b = e['project'], e.get(family)
        if not p or not b:
            lines.append(f"| {e['level']:g} | {_kernel_name(p)} | {p['tol'] if p else '-'} | - | - | "
                         f"{'not reached' if not b else b['label']} | - | - | - | - | - | - | - |")
            continue
        sp, cpu = e['speedup' + key], e['cpu_speedup' + key]
        ok = _holds(e, key)
        loads = [x for r in (p, b) for x in r.get('load', ()) if x == x]
        load = f'{min(loads):.1f}-{max(loads):.1f}' if loads else '-'
        method = b['label'].split(' (')[0]
        lines.append(f"| {e['level']:g} | {_kernel_name(p)} | {p['tol']:g} | {p['cpu_s'] * 1e3:.1f} | {p['wall_s'] * 1e3:.1f} "
                     f"| {method} | {b['tol']:g} | {b['cpu_s'] * 1e3:.1f} | {b['wall_s'] * 1e3:.1f} "
                     f"| {cpu:.2f}x | {sp:.2f}x | {'yes' if ok else 'no'} | {load} |"
                     if cpu is not None else
                     f"| {e['level']:g} | {_kernel_name(p)} | {p['tol']:g} | - | {p['wall_s'] * 1e3:.1f} | {method} "
                     f"| {b['tol']:g} | - | {b['wall_s'] * 1e3:.1f} | - | {sp:.2f}x "
                     f"| {'yes' if ok else 'no'} | {load} |")
    return '\n'.join([*lines, '', expert_verdict(study, family)]) + '\n'


def _holds(e: dict[str, Any], key: str = '_expert') -> bool:
    """The level's best kernel run at least EXPERT_TARGET x cheaper than the best expert run
    (``key`` '_expert' or '_bisect'), in wall and (where measured) in CPU time."""
    sp, cpu = e.get('speedup' + key), e.get('cpu_speedup' + key)
    return sp is not None and sp >= EXPERT_TARGET and (cpu is None or cpu >= EXPERT_TARGET)


def expert_verdict(study: dict[str, Any], family: str = 'baseline_expert') -> str:
    """One line: the levels where the project holds >= 2x against ``family`` and where not
    (a level either family does not reach counts as not held)."""
    key = '_bisect' if family == 'baseline_expert_bisect' else '_expert'
    held = [f"{e['level']:g}" for e in study['levels'] if _holds(e, key)]
    missed = [f"{e['level']:g}" for e in study['levels'] if not _holds(e, key)]
    return (f'>= {EXPERT_TARGET:g}x against {family} (CPU time and wall): '
            + ('held at every level' if not missed else
               f"held at {', '.join(held) or 'no level'}; not at {', '.join(missed)}") + '.')


def write_mode_outputs(studies: Sequence[dict[str, Any]], out: Path) -> list[Path]:
    """modes.csv (every run) and modes.md (the level tables) in ``out``."""
    import csv
    keys = ['scene', 'family', 'label', 'tol', 'ok', 'err_speed_rel', 'wall_s', 'cpu_s',
            'wall_per_sim_s', 'repeats', 'steps', 'nfev', 'events', 'event_dt_max',
            'energy_residual', 'load',
            'note']
    p_csv = out / 'modes.csv'
    with p_csv.open('w', newline='') as fh:
        w = csv.DictWriter(fh, fieldnames=keys, extrasaction='ignore')
        w.writeheader()
        for s in studies:
            w.writerows(s['rows'])
    p_md = out / 'modes.md'
    parts = []
    for s in studies:
        tables = [t for t in (format_expert_table(s), format_expert_table(s, 'baseline_expert_bisect')) if t]
        parts.append('\n'.join([format_mode_table(s), *tables]))
    p_md.write_text('\n'.join(parts))
    return [p_csv, p_md]
