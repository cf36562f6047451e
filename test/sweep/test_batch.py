"""The batched variants (cvj_ros.sweep.batch) give the per-variant path's rows and
results.csv bytes, on a grid whose fidelity decision changes (new templates), with an
invalid variant (a fallback), and their patched kernel arrays equal a full build's bit for
bit."""
from __future__ import annotations

import copy
import math
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from cvj_ros.commands.sweep import load_scene_data
from cvj_ros.physics.scene import find_scene, parse_scene
from cvj_ros.physics.simulate import Simulation
from cvj_ros.sweep.batch import BatchRunner, element_local, variant_dict
from cvj_ros.sweep.run import Job, RunOptions, SerialExecutor, execute, run_chunk
from cvj_ros.sweep.spec import apply_keys, build_sweep

# accuracy target 1e-2 (measured with choose_fidelity): the coupling is ideal at 0 and 15 deg,
# closed at 30; the bushings rigid at 3e5 N m/rad, elastic below: four structures, and
# alpha 95 deg is invalid
SETS = ['duration=0.3', 'accuracy_target=0.01',
        'driveline[coupling].params.alpha_deg=0,15,30,95',
        'driveline[bushings].stiffness=300,900,3000,300000']


class PerVariantExecutor(SerialExecutor):
    """The serial executor on the per-variant path (run_variant for every variant)."""

    def map(self, job: Job, work: list[list[tuple[int, Sequence[Any]]]]) -> Iterator[list[Any]]:
        for chunk in work:
            yield run_chunk(job, chunk, batched=False)


def sweep():
    return build_sweep(load_scene_data(find_scene('kavz685_lever')), SETS)


def test_element_local_keys() -> None:
    assert element_local([('driveline', 2, 'params', 'alpha_deg'),
                          ('driveline', 1, 'stiffness')]) == [True, True]
    # two keys of one element: neither is mapped (their slots could interact)
    assert element_local([('driveline', 2, 'params', 'alpha_deg'),
                          ('driveline', 2, 'params', 'delta_alpha_deg')]) == [False, False]
    assert element_local([('driveline', 2, 'kind'), ('duration',), ('solver', 'rtol'),
                          ('driveline', 1, 'stiffness')]) == [False, False, False, True]


def test_batched_rows_and_arrays_equal_the_per_variant_path() -> None:
    sw = sweep()
    job = Job(base=sw.base, keys=tuple(a.keys for a in sw.axes), options=RunOptions())
    items = list(enumerate(sw.variants))
    reference = run_chunk(job, items, batched=False)
    runner = BatchRunner(job)
    assert runner.enabled
    for _pass in range(2):      # the second pass: every value seen, every structure known
        for (i, values), ref in zip(items, reference):
            before = runner.stats['batched']
            row, _wall = runner.run(values)
            assert repr(row) == repr(ref.row), f'variant {i} {values}'
            if runner.stats['batched'] == before:
                continue        # ran in full
            # the arrays the variant ran with equal a full build of it, bit for bit
            scene = parse_scene(sw.scene_dict(i))
            full = Simulation(scene)
            model = full._model(float(scene.duration))
            full._output_tables()
            tpl = runner.templates[tuple(sorted(full.fidelity_report.levels.items()))]
            assert tpl.fp.tobytes() == model.fp.tobytes()
            assert tpl.sim._mid_table[1].tobytes() == full._mid_table[1].tobytes()
            assert tpl.sim._e0[1] == full._initial_energy(full.driveline.x0)
    assert [r.row['status'] for r in reference].count('invalid') == 4
    # first pass: a value's first variant runs in full, 4 templates, 2 batched (measured
    # by hand from the grid order); second pass: the 12 valid variants all batched
    assert runner.stats['templates'] == 4
    assert runner.stats['batched'] == 2 + 12
    assert runner.stats['full'] == 32 - 14


def test_listed_axes_are_mapped_on_a_values_first_variant() -> None:
    """Job.listed (grid axes): a new value is probed on its first variant instead of running
    in full; the rows are the per-variant path's, and only the templates and the invalid
    variants run in full."""
    sw = sweep()
    keys = tuple(a.keys for a in sw.axes)
    listed = tuple(a.range is None and 1 < len(a.values) < len(sw.variants) for a in sw.axes)
    assert listed == (False, False, True, True)     # duration and accuracy target fixed
    job = Job(base=sw.base, keys=keys, options=RunOptions(), listed=listed)
    items = list(enumerate(sw.variants))
    reference = run_chunk(job, items, batched=False)
    runner = BatchRunner(job)
    rows = [runner.run(values)[0] for _i, values in items]
    assert [repr(r) for r in rows] == [repr(o.row) for o in reference]
    assert runner.stats['templates'] == 4
    assert runner.stats['full'] == 4 + 4           # the templates' first runs, the invalid
    assert runner.stats['batched'] == 16 - 8


def test_values_that_never_repeat_are_not_probed() -> None:
    """Random sampling of ranges: every value is new, every variant runs in full (no probe
    costs on top), the rows are the per-variant path's."""
    sw = build_sweep(load_scene_data(find_scene('kavz685_lever')),
                     ['duration=0.2', 'driveline[coupling].params.alpha_deg=5:25',
                      'driveline[bushings].stiffness=300:3000'], samples=4, seed=3)
    job = Job(base=sw.base, keys=tuple(a.keys for a in sw.axes), options=RunOptions())
    runner = BatchRunner(job)
    rows = [repr(runner.run(v)[0]) for v in sw.variants]
    assert runner.stats == {'batched': 0, 'full': 4, 'templates': 0, 'probes': 0}
    assert rows == [repr(o.row) for o in run_chunk(job, list(enumerate(sw.variants)),
                                                   batched=False)]


def test_results_csv_bytes_batched_equal_per_variant(tmp_path: Path) -> None:
    sw = sweep()
    execute(sw, RunOptions(), tmp_path / 'a', executor=PerVariantExecutor())
    execute(sw, RunOptions(), tmp_path / 'b', executor=SerialExecutor())
    a = (tmp_path / 'a' / 'results.csv').read_bytes()
    assert a == (tmp_path / 'b' / 'results.csv').read_bytes()
    assert a.count(b',invalid,') == 4


def test_keys_on_one_element_run_per_variant() -> None:
    """Two keys of one element are not mapped (their slots could interact): every variant
    that differs from the template in one of them takes the per-variant path."""
    sw = build_sweep(load_scene_data(find_scene('kavz685_lever')),
                     ['duration=0.2', 'driveline[coupling].params.alpha_deg=10,20',
                      'driveline[coupling].params.delta_alpha_deg=0,1'])
    job = Job(base=sw.base, keys=tuple(a.keys for a in sw.axes), options=RunOptions())
    runner = BatchRunner(job)
    rows = [runner.run(v)[0] for v in sw.variants]
    assert runner.stats['full'] == 4 and runner.stats['batched'] == 0
    assert [repr(r) for r in rows] == [repr(o.row) for o in
                                       run_chunk(job, list(enumerate(sw.variants)), batched=False)]
    assert np.isfinite([r['energy_residual'] for r in rows]).all()


def test_variant_dict_equals_apply_keys_and_leaves_base_unchanged() -> None:
    base = load_scene_data(find_scene('kavz685_lever'))
    frozen = copy.deepcopy(base)
    keys = [('driveline', 2, 'params', 'alpha_deg'), ('driveline', 1, 'stiffness'),
            ('driveline', 1, 'damping'), ('solver', 'max_step'), ('duration',)]
    values = [12.5, 700.0, 0.5, 1e-3, 0.7]
    d = variant_dict(base, keys, values)
    assert d == apply_keys(base, keys, values)
    assert base == frozen
    assert d['engine'] is base['engine']            # shared, not copied
    assert d['driveline'][2] is not base['driveline'][2]


def test_lean_run_fills_the_same_rows_as_the_one_call_run() -> None:
    """bind_lean's run (no members) plus fill(i) gives the one-call run's arrays bit for bit
    in every row it fills; the shaft columns are the same in every row, but the angles no
    row reads (after the lever hinge, which feeds neither the first shaft nor the earring's
    input: outputs_nb.unread_angles), which are NaN. The integration runs on the ip whose
    lever hinge gives its ratio alone (outputs_nb.ratio_only_ip): the same states."""
    from cvj_ros.physics.kernel.outputs_nb import ratio_only_ip, unread_angles
    from cvj_ros.sweep.batch import bind_lean, lean_run
    data = apply_keys(load_scene_data(find_scene('kavz685_lever')),
                      [('duration',), ('driveline', 2, 'params', 'alpha_deg')], [0.3, 30.0])
    sim = Simulation(parse_scene(data), fidelity={'coupling': 'exact'})
    full = sim.run(sampling='dense')
    plan = next(iter(sim._plans.values()))
    ref = sim._run_one_call(plan, sim.driveline.x0)
    lean = bind_lean(sim, plan, 'dense')
    assert lean is not None and sim._mid_table[0].shape[0] > 0   # the earring is a member
    assert ratio_only_ip(plan.stepper.ip, unread_angles(plan.stepper.ip, sim._shaft_table,
                                                        [0, 1])) is not None
    members = sim._mid_table[0][:, 0].tolist()
    shafts = [c for c in range(ref.velocity.shape[1]) if c not in members]
    unread = [sim.driveline.shaft_names.index(s) for s in ('coupling_output', 'driven_shaft')]
    read = [c for c in range(ref.velocity.shape[1]) if c not in unread]
    m = ref.t.size
    for first in (m // 2, 0):
        trace, fill = lean_run(sim, plan, lean)
        for name in ('t', 'engine_torque', 'load_torque', 'energy_residual'):
            assert getattr(trace, name).tobytes() == getattr(ref, name).tobytes(), name
        for name in ('position', 'velocity', 'effort'):
            cols = [c for c in shafts if c in read] if name == 'position' else shafts
            assert getattr(trace, name)[:, cols].tobytes() == \
                getattr(ref, name)[:, cols].tobytes(), name
        assert np.isnan(trace.position[:, unread]).all()
        fill(first)
        assert trace.velocity[first:].tobytes() == ref.velocity[first:].tobytes()
        assert trace.position[first:, read].tobytes() == ref.position[first:, read].tobytes()
    assert ref.velocity.tobytes() == full.velocity.tobytes()


def test_template_slices_give_the_same_reduction() -> None:
    """reduce.checked_slices once per template: compiled_reduction with them gives what it
    computes itself, and times it does not cover give None."""
    from cvj_ros.sweep.reduce import checked_slices, compiled_reduction
    data = apply_keys(load_scene_data(find_scene('kavz685_lever')),
                      [('duration',), ('driveline', 2, 'params', 'alpha_deg')], [0.3, 30.0])
    trace = Simulation(parse_scene(data)).run(sampling='dense')
    slices = checked_slices(trace.t)
    assert slices is not None
    own = compiled_reduction(trace, RunOptions())
    given = compiled_reduction(trace, RunOptions(), slices=slices)
    assert own is not None and given is not None
    assert repr(own[1]) == repr(given[1]) and own[0].start_s == given[0].start_s
    t = trace.t.copy()
    t[5] = t[4]
    assert checked_slices(t) is None and checked_slices(trace.t[:2]) is None


def test_orders_of_the_earring_with_its_speeds_alone() -> None:
    """The batched path fills only the members' speeds (no member angle): the torque orders
    of the first shaft and of the earring (--orders-shaft coupling_earring, over the first
    shaft's angle) are the per-variant path's."""
    sw = build_sweep(load_scene_data(find_scene('kavz685_lever')),
                     ['duration=0.4', 'driveline[coupling].params.alpha_deg=10,25',
                      'driveline[bushings].stiffness=900,3000'])
    keys = tuple(a.keys for a in sw.axes)
    items = list(enumerate(sw.variants))
    for shaft in (None, 'coupling_earring'):
        job = Job(base=sw.base, keys=keys, options=RunOptions(orders=3, orders_shaft=shaft),
                  listed=(False, True, True))
        reference = run_chunk(job, items, batched=False)
        runner = BatchRunner(job)
        rows = [runner.run(values)[0] for _i, values in items]
        assert runner.stats['batched'] == 3
        assert [repr(r) for r in rows] == [repr(o.row) for o in reference]
        col = f'{shaft or "drive_shaft"}.torque_order2'
        assert all(math.isfinite(r[col]) for r in rows)


def _levels_checked(sets: list[str], base_changes: dict[int, Any] | None = None
                    ) -> tuple[BatchRunner, list[Any], int, int]:
    """Run the grid batched twice (listed axes), with choose_fidelity's levels checked
    wherever BatchRunner._levels_of_template gives levels without it; the rows against the
    per-variant path. Returns the runner, the rows, and how often the levels came from the
    template and how often it declined."""
    from cvj_ros.physics.fidelity import choose_fidelity
    data = load_scene_data(find_scene('kavz685_lever'))
    for k, v in (base_changes or {}).items():
        data['driveline'][k]['J'] = v
    sw = build_sweep(data, sets)
    keys = tuple(a.keys for a in sw.axes)
    listed = tuple(a.range is None and 1 < len(a.values) < len(sw.variants) for a in sw.axes)
    job = Job(base=sw.base, keys=keys, options=RunOptions(), listed=listed)
    items = list(enumerate(sw.variants))
    reference = run_chunk(job, items, batched=False)
    runner = BatchRunner(job)
    counts = [0, 0]
    original = runner._levels_of_template

    def checked(scene: Any, vkeys: Any) -> Any:
        levels = original(scene, vkeys)
        counts[levels is None] += 1
        if levels is not None:
            assert levels == choose_fidelity(scene).levels
        return levels
    runner._levels_of_template = checked
    rows = []
    for _pass in range(2):
        rows = [runner.run(values)[0] for _i, values in items]
        assert [repr(r) for r in rows] == [repr(o.row) for o in reference]
    return runner, rows, counts[0], counts[1]


def test_fidelity_levels_of_the_template_without_an_accuracy_target() -> None:
    """No accuracy target: a variant whose keys were all probed takes the template's
    levels without choose_fidelity (a hinge angle and a stiffness at once included);
    the same levels and rows as the per-variant path."""
    runner, rows, fast, declined = _levels_checked(
        ['duration=0.05', 'driveline[coupling].params.alpha_deg=5,15,25',
         'driveline[bushings].stiffness=300,715.4,3000'])
    # 18 runs: the first (no template yet) and 4 with an unprobed value in the first pass
    # (a new value's probe comes after the levels) by choose_fidelity; the other 13 from
    # the template (counted by hand from the grid order)
    assert (fast, declined) == (13, 5)
    assert runner.stats['templates'] == 1 and runner.stats['full'] == 1
    assert all(r['status'] == 'ok' for r in rows)


def test_fidelity_levels_fall_back_where_the_rule_could_raise() -> None:
    """The guard: a stiffness of 5e-324 N m/rad beside a drive shaft of 1e6 kg m^2 (the
    driven shaft 1e6 too) makes c (1/J_l + 1/J_r) underflow to 0 and choose_fidelity
    divide by zero, though each value alone passes (both probes made, the premise holds):
    that variant takes choose_fidelity and the per-variant path's 'failed' row."""
    runner, rows, fast, declined = _levels_checked(
        ['duration=0.05', 'driveline[drive_shaft].J=0.128,1e6',
         'driveline[bushings].stiffness=715.4,5e-324'], base_changes={3: 1e6})
    assert [r['status'] for r in rows] == ['ok'] * 3 + ['failed']
    assert rows[3]['error'].startswith('ZeroDivisionError')
    tpl = next(iter(runner.templates.values()))
    assert tpl.springs == (False, False, True)
    assert all(p is not None for p in tpl.probes.values()) and len(tpl.probes) == 2
    # pass 1: the first variant and the two new values by choose_fidelity, the failing
    # one by the guard; pass 2: three from the template, the failing one by the guard
    assert (fast, declined) == (3, 5)


def test_fidelity_levels_with_an_accuracy_target_are_chosen() -> None:
    """An accuracy target makes the rule read numbers: every variant takes
    choose_fidelity (the module's four-structure grid)."""
    _runner, _rows, fast, _declined = _levels_checked(SETS)
    assert fast == 0



def test_explicit_method_refused_on_a_stiff_spring_as_per_variant() -> None:
    """A stiffness of 1e300 N m/rad: Simulation.run refuses dopri5 there (omega_n ~3.7e150
    rad/s, omega_n duration / 6 ~3e148 steps > 1e10: simulate.explicit_step_check). The
    batched variant gets that 'failed' row (choose_fidelity's report checked before the
    lean run) instead of the lean run stepping at ~1e-150 s; and the template's levels
    decline such a variant even where its values were probed (the guard alone here: a
    probe of 1e300 is put in by hand, as a stiffness probed beside other inertias)."""
    import dataclasses
    runner, rows, fast, declined = _levels_checked(
        ['duration=0.05', 'driveline[coupling].params.alpha_deg=5,15',
         'driveline[bushings].stiffness=300,1e300'])
    assert [r['status'] for r in rows] == ['ok', 'failed', 'ok', 'failed']
    assert rows[1]['error'].startswith("driveline[1].stiffness: spring 'bushings' and its "
                                       "neighbours' inertias have a mode at 3.74e+150 rad/s: "
                                       "dopri5 would need ~3.1e+148 steps for 0.05 s")
    # pass 1: the template, the 15 deg variant (its value new) by choose_fidelity, the two
    # refused by its report; pass 2: the two 300 N m/rad variants from the template
    assert (fast, declined) == (2, 6)
    assert runner.stats['batched'] == 3 and runner.stats['full'] == 5
    tpl = next(iter(runner.templates.values()))
    stiff = ('float', '1e+300')
    tpl.probes[(2, stiff)] = dataclasses.replace(tpl.probes[(1, ('int', '15'))])
    data = load_scene_data(find_scene('kavz685_lever'))
    data['duration'] = 0.05
    for stiffness, levels in ((1e300, None), (300, tpl.levels)):
        data['driveline'][1]['stiffness'] = stiffness
        vkeys = (tpl.vkeys[0], tpl.vkeys[1], stiff if stiffness == 1e300 else tpl.vkeys[2])
        assert runner._levels_of_template(parse_scene(data), vkeys) == levels
