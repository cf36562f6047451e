"""Batched sweep variants: the model built once per structure, each variant a patch of it.

:class:`BatchRunner` (what :func:`cvj_ros.sweep.run.run_chunk` uses by default, one per
worker thread and job) gives the rows of the per-variant path, the same bytes, with less
Python per variant. A *structure* is the fidelity decision (every joint's
and spring's level, :func:`cvj_ros.physics.fidelity.choose_fidelity`) of a variant; its
*template* is one full :class:`~cvj_ros.physics.simulate.Simulation` with its run plan
(sample times, breakpoints, the stepper bound to its one-call run). The kernel data of a
variant of that structure differ from the template's only where a sweep key enters:

* a key's *slots* are found by building it once per value (a *probe*: the template's
  values with that one key changed, a full parse, fidelity choice and build) and diffing
  bit for bit: the model's ``fp`` (kernel/layout.py), the intermediate members'
  parameters ``mfp`` (outputs_nb.mid_table) and the two parts of the initial energy; a value is
  probed when it comes a second time (its first variant runs in full), so a sweep whose
  values never repeat (random sampling of ranges) runs as before; a value of an axis the
  job lists as repeated (``Job.listed``: a grid axis) is probed on its first variant;
* a variant is the template's arrays with each key's slots written from its probe, run
  by the template's one-call run bound without the intermediate members
  (:func:`bind_lean`), whose rows are filled from the row before the steady window on
  (the rows the metrics read; :func:`lean_run`).

The mapping is checked, never assumed: a key is mapped only if it addresses one field of
one ``driveline[i]`` element (not its kind, name or fidelity; no other key on the same
element; other keys, e.g. a fixed ``duration``, must equal the template's), a probe must give the template's ``ip``, ``x0``, shaft and member tables and
fidelity levels, and the slots (and energy parts) two keys change must be disjoint over
every probe made. Anything else runs the variant on the per-variant path
(:func:`~cvj_ros.sweep.run.run_variant`): a key that changes structure, a variant whose
fidelity decision has no template yet (it becomes one), a mode scene, the Python backend,
a run that raises. Each variant is still validated and its fidelity chosen; the
validation parses only the elements its keys change (:mod:`cvj_ros.sweep.reparse`).
"""
from __future__ import annotations

import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = ['BatchRunner', 'MemberFill', 'bind_lean', 'element_local', 'lean_run', 'variant_dict']

_NOT_LOCAL = ('kind', 'name', 'fidelity', 'type')


def element_local(keys: Sequence[Sequence[str | int]]) -> list[bool]:
    """Per key: True if it is one field of a ``driveline[i]`` element (``params.X`` or a
    top-level field other than kind / name / fidelity) that no other key addresses - the
    keys the batched path maps to slots. A variant that differs from its template in any
    other key runs on the per-variant path."""
    def field_of(path: Sequence[str | int]) -> int | None:
        if len(path) < 3 or path[0] != 'driveline' or not isinstance(path[1], int) \
                or path[2] in _NOT_LOCAL:
            return None
        if (path[2] == 'params' and len(path) != 4) or (path[2] != 'params' and len(path) != 3):
            return None
        return path[1]
    elements = [field_of(p) for p in keys]
    return [e is not None and elements.count(e) == 1 for e in elements]


def variant_dict(base: Mapping[str, Any], keys: Sequence[Sequence[str | int]],
                 values: Sequence[Any]) -> dict[str, Any]:
    """:func:`cvj_ros.sweep.spec.apply_keys` without the deep copy: only the dicts and lists
    on the keys' paths are copied (once each), the rest is shared with ``base``, which
    stays unchanged. Equal to apply_keys' dict; for readers only (parse_scene), ~10x
    cheaper for a scene of a few elements."""
    d = dict(base)
    copied = {id(d)}
    for path, value in zip(keys, values):
        node: Any = d
        for k in path[:-1]:
            if isinstance(k, str) and (k not in node or node[k] is None):
                node[k] = {}
            child = node[k]
            if id(child) not in copied:
                child = dict(child) if isinstance(child, Mapping) else list(child)
                copied.add(id(child))
                node[k] = child
            node = child
        node[path[-1]] = value
    return d


def _bits(a: np.ndarray) -> np.ndarray:
    """The float64 array as int64 bit patterns (so -0.0 != 0.0 and NaN == NaN here)."""
    return np.ascontiguousarray(a, dtype=np.float64).view(np.int64)


@dataclass
class _Probe:
    """One key at one value inside a structure: its slots and values."""

    fp_slots: np.ndarray
    fp_vals: np.ndarray
    mfp_slots: np.ndarray
    mfp_vals: np.ndarray
    energy: tuple[float, float]          # (kinetic, elastic) of x0
    adjacent: dict[str, tuple[float, float]] | None = None  # fidelity._adjacent_inertias


@dataclass
class _Template:
    """One structure's full Simulation, its plan run once, and what its probes showed."""

    sim: Any
    values: tuple[Any, ...]
    levels: dict[str, str]
    ip: np.ndarray
    x0: np.ndarray
    fp0: np.ndarray
    mfp0: np.ndarray
    mtab: np.ndarray
    shafts: np.ndarray
    energy: tuple[float, float]
    fp: np.ndarray = field(default_factory=lambda: np.zeros(0))   # the plan's own arrays
    mfp: np.ndarray = field(default_factory=lambda: np.zeros(0))
    probes: dict[tuple[int, Any], _Probe | None] = field(default_factory=dict)
    fp_owner: dict[int, int] = field(default_factory=dict)      # slot -> axis that changes it
    mfp_owner: dict[int, int] = field(default_factory=dict)
    energy_owner: dict[int, int] = field(default_factory=dict)  # part (0 kin, 1 ela) -> axis
    separable: bool = True
    lean: Any = None        # the plan's one-call run without the members (bind_lean)
    vkeys: tuple[tuple[str, str], ...] = ()     # _value_key of each of ``values``
    x0_key: bytes = b''     # x0's bytes (Simulation._initial_energy's key)
    slices: Any = None      # reduce.checked_slices of the plan's sample times (every run's)
    # the fidelity rule without numbers (no accuracy target, a chain): per axis True if its
    # element is a spring, and the template's adjacent inertias; None: no such rule
    springs: tuple[bool, ...] | None = None
    adjacent: dict[str, tuple[float, float]] | None = None
    # (duration, EXPLICIT_STABILITY, MAX_EXPLICIT_STEPS) of simulate.explicit_step_check
    # for an explicit method (None: an implicit one, no bound)
    step_bound: tuple[float, float, float] | None = None


def _value_key(v: Any) -> tuple[str, str]:
    """A probe key that tells 1 from 1.0 and 0.0 from -0.0 (they may parse differently)."""
    return type(v).__name__, repr(v)


class BatchRunner:
    """Runs variants of one job, keeping templates and probes for the job's structures."""

    def __init__(self, job: Any) -> None:
        from cvj_ros.sweep.run import RunOptions
        self.job = job
        opts: RunOptions = job.options
        self.options = opts
        self.local = element_local(job.keys)
        listed = tuple(getattr(job, 'listed', ()) or ())
        self.listed = listed if len(listed) == len(self.local) else (False,) * len(self.local)
        self.enabled = opts.backend == 'kernel' and any(self.local)
        self.templates: dict[tuple[tuple[str, str], ...], _Template] = {}
        self.seen: set[tuple[int, tuple[str, str]]] = set()     # (axis, value) met before
        self.stats = {'batched': 0, 'full': 0, 'templates': 0, 'probes': 0}
        self.reparser: Any = None       # parse_scene of the changed elements (sweep.reparse)

    # --- the per-variant path and a full build ------------------------------------------

    def _full(self, values: Sequence[Any]) -> tuple[dict[str, Any], float]:
        """The per-variant path on a deep-copied variant dict (as run_chunk makes it)."""
        from cvj_ros.sweep.run import run_variant
        from cvj_ros.sweep.spec import apply_keys
        self.stats['full'] += 1
        return run_variant(apply_keys(self.job.base, self.job.keys, values), self.options)

    def _build(self, scene: Any) -> Any:
        """A Simulation of ``scene`` as run_variant makes it, or None if it is not a plain
        kernel run (modes, Python fallback, Python-filled members)."""
        from cvj_ros.physics.simulate import Simulation
        if scene.has_modes or scene.is_tree:
            return None
        sim = Simulation(scene, fidelity=dict(self.options.fidelity) or None,
                         backend=self.options.backend)
        if sim.backend != 'kernel':
            return None
        sim._output_tables()
        if sim._mid_table[2]:
            return None
        return sim

    @staticmethod
    def _energy(sim: Any) -> tuple[float, float]:
        e = sim.driveline.energy(sim.driveline.x0)
        return float(e['kinetic']), float(e['elastic'])

    def _template(self, sim: Any, values: tuple[Any, ...], levels: dict[str, str]) -> _Template:
        model = sim._model(float(sim.scene.duration))
        return _Template(sim=sim, values=values, levels=levels, ip=model.ip.copy(),
                         x0=np.array(sim.driveline.x0), fp0=model.fp.copy(),
                         mfp0=sim._mid_table[1].copy(), mtab=sim._mid_table[0].copy(),
                         shafts=sim._shaft_table.copy(), energy=self._energy(sim))

    def _probe(self, tpl: _Template, axis: int, value: Any) -> _Probe | None:
        """Build the template's values with ``axis`` at ``value``; its slots, or None when it
        is not a patch of the template (invalid, other structure, other tables)."""
        from cvj_ros.physics.fidelity import choose_fidelity
        from cvj_ros.physics.scene import parse_scene
        from cvj_ros.sweep.spec import apply_keys
        self.stats['probes'] += 1
        values = list(tpl.values)
        values[axis] = value
        try:
            scene = parse_scene(apply_keys(self.job.base, self.job.keys, values))
            report = choose_fidelity(scene, overrides=dict(self.options.fidelity) or None)
            if report.levels != tpl.levels:
                return None
            adjacent = _adjacent(scene, report)
            sim = self._build(scene)
            if sim is None:
                return None
            model = sim._model(float(sim.scene.duration))
            energy = self._energy(sim)
        except Exception:       # noqa: BLE001  (a variant with this value runs in full)
            return None
        mtab, mfp, _py = sim._mid_table
        if not (np.array_equal(model.ip, tpl.ip) and _bits(sim.driveline.x0).tobytes()
                == _bits(tpl.x0).tobytes() and np.array_equal(mtab, tpl.mtab)
                and np.array_equal(sim._shaft_table, tpl.shafts)
                and model.fp.size == tpl.fp0.size and mfp.size == tpl.mfp0.size):
            return None
        fs = np.flatnonzero(_bits(model.fp) != _bits(tpl.fp0))
        ms = np.flatnonzero(_bits(mfp) != _bits(tpl.mfp0))
        return _Probe(fs, model.fp[fs].copy(), ms, mfp[ms].copy(), energy, adjacent)

    def _claim(self, tpl: _Template, axis: int, pr: _Probe) -> None:
        """Record which axis changes which slots; two axes on one slot end the batching of
        this structure (the slots would not be separable)."""
        for owner, slots in ((tpl.fp_owner, pr.fp_slots), (tpl.mfp_owner, pr.mfp_slots)):
            for s in slots.tolist():
                if owner.setdefault(s, axis) != axis:
                    tpl.separable = False
        for part in (0, 1):
            if _bits(np.array(pr.energy[part])) != _bits(np.array(tpl.energy[part])):
                if tpl.energy_owner.setdefault(part, axis) != axis:
                    tpl.separable = False

    # --- one variant ----------------------------------------------------------------------

    def run(self, values: Sequence[Any]) -> tuple[dict[str, Any], float]:
        """(row, wall s) of the variant ``values``: the same row as run_variant."""
        from cvj_ros.physics.fidelity import choose_fidelity
        t0 = time.perf_counter()
        values = tuple(values)
        if not self.enabled:
            return self._full(values)
        # a probe pays only for a value that comes again: a value's first variant runs in
        # full (a random sweep of continuous ranges, every value new, costs what it did),
        # unless its axis is a listed one the sweep repeats (Job.listed): mapped at once
        vkeys = tuple(_value_key(v) for v in values)
        new = [(axis, vk) for axis, vk in enumerate(vkeys)
               if self.local[axis] and (axis, vk) not in self.seen]
        if new:
            self.seen.update(new)
            if not all(self.listed[axis] for axis, _vk in new):
                return self._full(values)
        try:
            if self.reparser is None:
                from cvj_ros.sweep.reparse import Reparser
                self.reparser = Reparser(self.job.base, self.job.keys, values, self.local)
            scene = self.reparser.parse(values, vkeys)
            if scene.has_modes or scene.is_tree:
                return self._full(values)
            levels = self._levels_of_template(scene, vkeys)
            if levels is None:
                from cvj_ros.physics.simulate import explicit_step_check
                report = choose_fidelity(scene, overrides=dict(self.options.fidelity) or None)
                levels = report.levels
                # Simulation.run's refusal of an explicit method on a stiff spring (the
                # lean run skips Simulation.run); the scene's method and duration are the
                # run's: the non-local keys equal the template's or the variant runs in full
                explicit_step_check(scene, report, scene.solver.method, float(scene.duration))
        except Exception:       # noqa: BLE001  (the per-variant path gives its row)
            return self._full(values)        # the same 'invalid' / 'failed' row
        skey = tuple(sorted(levels.items()))
        tpl = self.templates.get(skey)
        if tpl is None:
            return self._new_template(skey, scene, values, levels, t0)
        if not tpl.separable:
            return self._full(values)
        parts: list[tuple[int, _Probe]] = []
        for axis, (v, vk, tvk) in enumerate(zip(values, vkeys, tpl.vkeys)):
            if vk == tvk:
                continue
            if not self.local[axis]:
                return self._full(values)
            pk = (axis, vk)
            if pk not in tpl.probes:
                pr = self._probe(tpl, axis, v)
                tpl.probes[pk] = pr
                if pr is not None:
                    self._claim(tpl, axis, pr)
            pr = tpl.probes[pk]
            if pr is None or not tpl.separable:
                return self._full(values)
            parts.append((axis, pr))
        # the variant's arrays: the template's with every key's slots from its probe
        fp, mfp = tpl.fp, tpl.mfp
        fp[:] = tpl.fp0
        mfp[:] = tpl.mfp0
        energy = list(tpl.energy)
        for axis, pr in parts:
            fp[pr.fp_slots] = pr.fp_vals
            mfp[pr.mfp_slots] = pr.mfp_vals
            for part, owner in tpl.energy_owner.items():
                if owner == axis:
                    energy[part] = pr.energy[part]
        sim = tpl.sim
        sim._e0 = (tpl.x0_key, energy[0] + energy[1])
        try:
            row = self._reduce(sim, tpl.lean, tpl.slices)
        except Exception:       # noqa: BLE001  (the per-variant path gives the row)
            del self.templates[skey]
            return self._full(values)
        self.stats['batched'] += 1
        return row, time.perf_counter() - t0

    def _levels_of_template(self, scene: Any, vkeys: tuple[tuple[str, str], ...]
                            ) -> dict[str, str] | None:
        """choose_fidelity(scene).levels without running it, where they provably are the
        only template's, else None (the caller runs it). Without an accuracy target the
        rule reads no number for a level (a joint: forced, its only or its exact level; a
        spring: forced or elastic); its numbers can only make it raise. The premise: every
        key away from the template's value is element-local (the top level, names, kinds
        and fidelity fields are the template's) and probed without error (so each joint's
        error bounds and harmonic order, pure functions of its kind and parameters, were
        computed for these very parameters), and at most one of them changes an element
        other than a spring (so the adjacent inertias, a pure function of the inertias,
        joints and spring names, are that probe's or the template's). What is left is each
        spring's omega_n = sqrt(c (1/J_l + 1/J_r)), computed here with the variant's
        stiffness: it raises for J = 0 or c (1/J_l + 1/J_r) < 0, and band / omega_n divides
        by zero where it is 0 (c (1/J_l + 1/J_r) underflowing); such a variant (or one
        where any premise fails) is left to choose_fidelity. So is one whose omega_n
        duration / 6 exceeds 1e10 steps under an explicit method (the refusal of
        ``simulate.explicit_step_check``, which the caller then applies to the report)."""
        if len(self.templates) != 1:
            return None
        tpl = next(iter(self.templates.values()))
        springs = tpl.springs
        if springs is None or not tpl.separable:
            return None
        adjacent = tpl.adjacent
        other = False
        for axis, (vk, tvk) in enumerate(zip(vkeys, tpl.vkeys)):
            if vk == tvk:
                continue
            pr = tpl.probes.get((axis, vk)) if self.local[axis] else None
            if pr is None:
                return None
            if not springs[axis]:
                if other:
                    return None
                other = True
                adjacent = pr.adjacent
        if adjacent is None:
            return None
        from cvj_ros.physics.fidelity import spring_omega_n
        from cvj_ros.physics.scene import Spring
        bound = tpl.step_bound      # the scene's method and duration are the template's
        try:
            for el in scene.driveline:
                if isinstance(el, Spring):
                    omega = spring_omega_n(el.stiffness, *adjacent[el.name])
                    if omega == 0.0 or (bound is not None
                                        and omega * bound[0] / bound[1] > bound[2]):
                        return None
        except Exception:       # noqa: BLE001  (choose_fidelity then raises it)
            return None
        return tpl.levels

    def _new_template(self, skey: tuple[tuple[str, str], ...], scene: Any,
                      values: tuple[Any, ...], levels: dict[str, str],
                      t0: float) -> tuple[dict[str, Any], float]:
        """Run the variant in full on a new Simulation and keep it as its structure's
        template (when it is a plain kernel run that ends without an error)."""
        try:
            sim = self._build(scene)
        except Exception:       # noqa: BLE001  (the per-variant path gives its row)
            sim = None
        if sim is None:
            return self._full(values)
        try:
            row = self._reduce(sim)
        except Exception:       # noqa: BLE001
            return self._full(values)
        tpl = self._template(sim, values, levels)
        tpl.vkeys = tuple(_value_key(v) for v in values)
        tpl.x0_key = _bits(tpl.x0).tobytes()
        plan = next(iter(sim._plans.values()))
        tpl.fp = plan.model.fp          # the arrays the bound run reads
        tpl.mfp = sim._mid_table[1]
        if tpl.fp.size != tpl.fp0.size:
            return row, time.perf_counter() - t0
        self.templates[skey] = tpl
        if scene.accuracy_target is None:   # the rule without numbers: _levels_of_template
            from cvj_ros.physics.fidelity import choose_fidelity
            from cvj_ros.physics.scene import Spring
            chain = scene.driveline
            tpl.springs = tuple(isinstance(chain[int(k[1])], Spring) if local else False
                                for k, local in zip(self.job.keys, self.local))
            tpl.adjacent = _adjacent(scene, choose_fidelity(
                scene, overrides=dict(self.options.fidelity) or None))
            from cvj_ros.physics.simulate import (EXPLICIT_METHODS, EXPLICIT_STABILITY,
                                                  MAX_EXPLICIT_STEPS)
            if scene.solver.method in EXPLICIT_METHODS:
                tpl.step_bound = (float(scene.duration), EXPLICIT_STABILITY, MAX_EXPLICIT_STEPS)
        tpl.lean = bind_lean(sim, plan, self.options.sampling)
        from cvj_ros.sweep.reduce import checked_slices
        tpl.slices = checked_slices(plan.times)
        self.stats['templates'] += 1
        self.stats['full'] += 1
        return row, time.perf_counter() - t0

    def _reduce(self, sim: Any, lean: Any = None, slices: Any = None) -> dict[str, Any]:
        """Run ``sim`` and reduce it to the row (run_variant's steps after the build; the
        window and metrics compiled, cvj_ros.sweep.reduce). A template's later runs make
        the plan's one compiled call (Simulation._run_one_call) without Simulation.run's
        option handling; with ``lean`` (:func:`bind_lean`) that run without the members,
        filled from the row before the steady window on (the rows the metrics read);
        ``slices``: reduce.checked_slices of the plan's times (the lean run's trace's)."""
        from cvj_ros.sweep.run import simulation_row, trace_row
        plan = next(iter(sim._plans.values()), None)
        if plan is None or plan.run is None:
            return simulation_row(sim, self.options, compiled=True)
        if lean is None:
            return trace_row(sim._run_one_call(plan, sim.driveline.x0), self.options,
                             compiled=True)
        from cvj_ros.sweep.reduce import compiled_reduction
        # a row reads no member angle (the orders' angle is the first shaft's, never a
        # member: bind_lean), so the compiled reduction fills the members' speeds alone
        trace, fill = lean_run(sim, plan, lean, speeds_only=True)
        reduced = compiled_reduction(trace, self.options, fill=fill, slices=slices)
        if reduced is None:
            fill(0)         # the numpy path reads every row
        return trace_row(trace, self.options, compiled=reduced is not None, reduced=reduced)


def _adjacent(scene: Any, report: Any) -> dict[str, tuple[float, float]] | None:
    """The adjacent inertias (J_l, J_r) per spring that ``choose_fidelity`` gave ``report``
    used (fidelity._adjacent_inertias at its joint levels; {} without springs), or None for
    a scene with an accuracy target or a vehicle (their rules read numbers)."""
    from cvj_ros.physics.fidelity import _adjacent_inertias
    from cvj_ros.physics.scene import Differential, Spring
    if scene.accuracy_target is not None or scene.is_tree \
            or any(isinstance(el, Differential) for el in scene.driveline):
        return None
    if not any(isinstance(el, Spring) for el in scene.driveline):
        return {}
    joints = {c.name: c.chosen for c in report.choices if c.element == 'joint'}
    return _adjacent_inertias(scene, joints)


def bind_lean(sim: Any, plan: Any, sampling: str) -> Any | None:
    """The plan's one-call run (``KernelStepper.bind_run``, the same compiled function, packs
    and stepper) bound without the intermediate members (``mids`` None): it integrates and
    fills every sample's shaft outputs as ``plan.run`` does and leaves the members' columns
    unwritten, except the angles no row reads (after a joint that feeds neither the first
    shaft's angle nor a member's input: ``outputs_nb.unread_angles``), which are NaN. None when the members cannot wait for the window: none compiled, some filled
    in Python, or one of them is the first shaft (the steady window reads its speed)."""
    mtab, _mfp, python_members = sim._mid_table
    if not mtab.shape[0] or python_members or 0 in mtab[:, 0].tolist():
        return None
    n = sim.driveline.x0.size
    times = plan.times
    if sampling == 'land':      # as Simulation._kernel_plan builds the one-call plan
        grid = plan.grid
        gather = grid.size != times.size
        arrays = (grid, plan.rows.astype(np.int64) if gather else np.zeros(0, np.int64),
                  np.zeros((0, 2), np.int64), np.zeros(0))
    else:
        arrays = (np.zeros(0), np.zeros(0, np.int64),
                  np.array([(k, k_end) for k, k_end, _b in plan.segments], dtype=np.int64),
                  np.array([math.nan if b is None else b for _k, _ke, b in plan.segments]))
    # angles a row reads: the first shaft's (the torque orders') and the members' inputs; a
    # joint whose output angle feeds none of them gives its ratio alone (unread_angles)
    # (the integration's right-hand side too, for an exact lever hinge: ratio_only_ip)
    from cvj_ros.physics.kernel.outputs_nb import ratio_only_ip, unread_angles
    tab = sim._shaft_table
    skip = unread_angles(plan.stepper.ip, tab, sorted({0, *mtab[:, 1].tolist()}))
    run = plan.stepper.bind_run(sim.driveline.x0, times, (*arrays, np.zeros(2), np.zeros((2, n))),
                                tab, None, skip if skip.any() else None,
                                ratio_only_ip(plan.stepper.ip, skip))
    # fill's and the compiled reduction's entry points loaded now, not in a later chunk
    # (zero rows, the types fill passes; a tiny record: reduce.load_entries)
    from cvj_ros.physics.kernel import entry_point_once
    from cvj_ros.physics.kernel.outputs_nb import fill_mid_samples
    from cvj_ros.sweep.reduce import load_entries
    n_sh = plan.shape[2]
    args = (np.empty((0, n_sh)), np.empty((0, n_sh)), mtab, _mfp)
    entry_point_once(fill_mid_samples, args)(*args)
    load_entries()
    return run


class MemberFill:
    """``fill(i)`` of :func:`lean_run`: the intermediate members' angles and speeds from row
    i on, where not filled yet. ``members`` (pos, mtab, mfp), or None: what
    ``reduce.compiled_reduction`` needs to fill their speeds alone in its compiled call."""

    __slots__ = ('pos', 'vel', 'mtab', 'mfp', 'done', 'members')

    def __init__(self, pos: np.ndarray, vel: np.ndarray, mtab: np.ndarray, mfp: np.ndarray,
                 speeds_only: bool) -> None:
        self.pos, self.vel, self.mtab, self.mfp = pos, vel, mtab, mfp
        self.done = pos.shape[0]
        self.members = (pos, mtab, mfp) if speeds_only else None

    def __call__(self, i: int) -> None:
        if i < self.done:
            from cvj_ros.physics.kernel import entry_point_once
            from cvj_ros.physics.kernel.outputs_nb import fill_mid_samples
            args = (self.pos[i:self.done], self.vel[i:self.done], self.mtab, self.mfp)
            entry_point_once(fill_mid_samples, args)(*args)
            self.done = i


def lean_run(sim: Any, plan: Any, run: Any, speeds_only: bool = False
             ) -> tuple[Any, MemberFill]:
    """Simulation._run_one_call of ``sim``'s plan with the lean bound ``run``
    (:func:`bind_lean`): (trace, fill). ``fill(i)`` fills the intermediate members' angles
    and speeds (the lever hinge's earring: ``outputs_nb.fill_mid_samples``, the function
    the full run calls per row) from row i on, where not filled yet: each row from its own
    input angle and speed, so the rows filled are the full run's floats. ``speeds_only``:
    the caller reads no member angle, so compiled_reduction may fill the members' speeds
    alone (``fill.members``; the angles of those rows stay unwritten)."""
    m, n, n_sh = plan.shape
    X = np.empty((m, n))
    pos = np.empty((m, n_sh))
    vel = np.empty((m, n_sh))
    eff = np.empty((m, n_sh))
    te = np.empty(m)
    tl = np.empty(m)
    res = np.empty(m)
    e0 = sim._initial_energy(sim.driveline.x0)
    wall0 = time.perf_counter()
    bad = run(e0, X, X if plan.XG is None else plan.XG, pos, vel, eff, te, tl, res)
    wall = time.perf_counter() - wall0
    times = plan.times
    sim._check_outputs(times, bad, pos, vel, compiled_mids=True)   # raises if bad >= 0
    trace = sim._finish(plan.stepper, times.copy(), pos, vel, eff, te, tl, res, X[-1],
                        wall, wall)
    mtab, mfp, _py = sim._mid_table
    return trace, MemberFill(pos, vel, mtab, mfp, speeds_only)

