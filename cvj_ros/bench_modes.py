"""Work-precision of scenes with clutch, gearbox and brake (stick/slip modes with events).

Project: the compiled kernel (:class:`cvj_ros.physics.kernel.modes.KernelHybridSimulation`,
a vehicle scene :class:`cvj_ros.physics.kernel.tree_modes.KernelHybridTreeSimulation`;
dopri5, each mode one compiled call with its witnesses and Brent on the dense output).
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
"""
from __future__ import annotations

import os
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from cvj_ros.physics.kernel.modes import KernelHybridSimulation
from cvj_ros.physics.kernel.tree_modes import KernelHybridTreeSimulation

__all__ = ['KERNEL_REFERENCE', 'MODE_SCENES', 'PYTHON_REFERENCE', 'SolveIvpHybridSimulation',
           'SolveIvpHybridTreeSimulation', 'format_mode_table', 'mode_levels', 'mode_study',
           'reference_run']

MODE_SCENES = ('launch_clutch_chain', 'launch_clutch')
LEVELS = (1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8)
TOLERANCES = (1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9, 1e-10)
#: reference of a vehicle mode scene: the compiled kernel, (method, rtol, atol)
KERNEL_REFERENCE = ('dopri5', 1e-13, 1e-15)
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
               reference: str = 'auto', log: Callable[[str], None] = print) -> dict[str, Any]:
    """Runs of both families at each tolerance (rtol = tol, atol = tol / 100) over the
    scene's duration (or ``duration`` s) with ``samples`` samples, best of ``repeats`` walls
    (the kernel's: of at least 10; the baseline's stop repeating after
    ``baseline_budget_s``), against the ``reference`` ('python', 'kernel', or 'auto': the
    kernel on a vehicle scene, else the Python reference); each row keeps the load average
    before and after its runs; returns {'scene', 'duration', 'reference', 'rows', 'levels'}."""
    from cvj_ros.physics.hybrid.from_scene import hybrid_simulation
    from cvj_ros.physics.scene import find_scene, load_scene
    scene = load_scene(find_scene(scene_name))
    horizon = float(duration or scene.duration)
    sample_dt = horizon / samples
    backend = ('kernel' if scene.is_tree else 'python') if reference == 'auto' else reference
    if backend not in ('python', 'kernel'):
        raise ValueError(f"reference: 'auto', 'python' or 'kernel', not {reference!r}")
    method, rtol, _atol = KERNEL_REFERENCE if backend == 'kernel' else PYTHON_REFERENCE
    t0 = time.perf_counter()
    ref = reference_run(scene, horizon, sample_dt, backend)
    ref_wall = time.perf_counter() - t0
    log(f'[bench] {scene.name}: mode reference ({backend}, {method}, rtol {rtol:g}) in '
        f'{ref_wall:.1f} s, {len(ref.events)} events')
    kern: Any = KernelHybridTreeSimulation if scene.is_tree else KernelHybridSimulation
    base: Any = SolveIvpHybridTreeSimulation if scene.is_tree else SolveIvpHybridSimulation
    # one untimed kernel run: loads (or compiles) the compiled mode code
    kern.from_reference(hybrid_simulation(scene, sample_dt=sample_dt, duration=horizon)).run()
    rows: list[dict[str, Any]] = []
    for family, cls in (('project', kern), ('baseline', base)):
        for tol in tolerances:
            walls: list[float] = []
            cpus: list[float] = []
            r = sim = None
            load0 = _load()
            # the kernel's runs are short: more repeats (their minimum) at little cost
            for _ in range(max(repeats, 10) if family == 'project' else repeats):
                sim = cls.from_reference(hybrid_simulation(scene, method='dopri5', rtol=tol,
                                                           atol=tol * 1e-2, sample_dt=sample_dt,
                                                           duration=horizon))
                w0 = time.perf_counter()
                c0 = time.process_time()
                try:
                    r = sim.run()
                except Exception as exc:     # a failing configuration is a row, not a stop
                    r = None
                    log(f'[bench] {scene.name}: {family} rtol {tol:g} failed: {str(exc)[:100]}')
                    break
                walls.append(time.perf_counter() - w0)
                cpus.append(time.process_time() - c0)
                if family == 'baseline' and sum(walls) > baseline_budget_s:
                    break
            row = {'scene': scene.name, 'family': family, 'tol': tol, 'ok': r is not None}
            if r is not None:
                row.update(wall_s=min(walls), cpu_s=min(cpus), wall_per_sim_s=min(walls) / horizon,
                           repeats=len(walls), err_speed_rel=_speed_error(r, ref),
                           events=len(r.events), steps=r.stats['steps'], nfev=r.stats['nfev'],
                           energy_residual=r.max_energy_residual, load=(load0, _load()),
                           label='kernel dopri5' if family == 'project' else 'solve_ivp RK45 + events')
                log(f"[bench] {scene.name}: {row['label']} rtol {tol:g}: err {row['err_speed_rel']:.2e}, "
                    f"{row['wall_s'] * 1e3:.1f} ms (CPU {row['cpu_s'] * 1e3:.1f} ms), {row['steps']} steps, "
                    f"{row['events']} events, energy residual {row['energy_residual']:.2e}")
            rows.append(row)
    return {'scene': scene.name, 'duration': horizon,
            'reference': {'backend': backend, 'method': method, 'rtol': rtol, 'wall_s': ref_wall,
                          'events': len(ref.events),
                          'energy_residual': ref.max_energy_residual},
            'rows': rows, 'levels': mode_levels(rows)}


def _load() -> float:
    """The 1-minute load average (nan where the platform has none)."""
    try:
        return float(os.getloadavg()[0])
    except OSError:
        return float('nan')


def mode_levels(rows: Sequence[dict[str, Any]], levels: Sequence[float] = LEVELS
                ) -> list[dict[str, Any]]:
    """Per error level the cheapest row of each family reaching it and the speedup."""
    out = []
    for lv in levels:
        entry: dict[str, Any] = {'level': lv}
        for fam in ('project', 'baseline'):
            cand = [r for r in rows if r.get('ok') and r['family'] == fam and r['err_speed_rel'] <= lv]
            entry[fam] = min(cand, key=lambda r: r['wall_s']) if cand else None
        p, b = entry['project'], entry['baseline']
        entry['speedup'] = b['wall_s'] / p['wall_s'] if p and b else None
        entry['cpu_speedup'] = (b['cpu_s'] / p['cpu_s'] if p and b and 'cpu_s' in p and 'cpu_s' in b
                                and p['cpu_s'] > 0 else None)
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
             '| error level | kernel dopri5 rtol | CPU ms | wall ms | solve_ivp RK45 + events rtol '
             '| CPU ms | wall ms | speedup (CPU time) | speedup (wall) | load |',
             '| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |']
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
        lines.append(f"| {e['level']:g} | {' | '.join(cell(p))} | {' | '.join(cell(b))} | {cpu} "
                     f"| {sp} | {load} |")
    return '\n'.join(lines) + '\n'


def write_mode_outputs(studies: Sequence[dict[str, Any]], out: Path) -> list[Path]:
    """modes.csv (every run) and modes.md (the level tables) in ``out``."""
    import csv
    keys = ['scene', 'family', 'label', 'tol', 'ok', 'err_speed_rel', 'wall_s', 'cpu_s',
            'wall_per_sim_s', 'repeats', 'steps', 'nfev', 'events', 'energy_residual', 'load']
    p_csv = out / 'modes.csv'
    with p_csv.open('w', newline='') as fh:
        w = csv.DictWriter(fh, fieldnames=keys, extrasaction='ignore')
        w.writeheader()
        for s in studies:
            w.writerows(s['rows'])
    p_md = out / 'modes.md'
    p_md.write_text('\n'.join(format_mode_table(s) for s in studies))
    return [p_csv, p_md]
