"""Where a batched sweep variant's CPU goes (docs/sweeps.md, "how far from 2000/s").

The 40 x 100 kavz685_lever grid (``alpha_deg=0:30:40`` x ``stiffness=300:3000:100:log``),
every 10th variant (400), run by one :class:`cvj_ros.sweep.batch.BatchRunner` in this
process after a warm pass over the same variants (templates and probes made). Each round
times the whole 400 with ``time.process_time`` (CPU of this process), then the same 400
again with per-stage timers wrapped around the batched path's functions (the timers add a
few per cent). Prints ms a variant per round.

    PYTHONPATH=. python scripts/sweep_stages.py [ROUNDS] [--against COMMIT]

``--against COMMIT``: paired instead - that commit's ``cvj_ros/sweep/batch.py`` (from
``git show``, loaded as a module of its own beside this tree's; the rest of cvj_ros is
this tree's) and this tree's, each with its own warm runner, the 400 variants
alternating between the two, ROUNDS pairs, CPU ms a variant each.
"""
from __future__ import annotations

import gc
import sys
import time
from collections import defaultdict
from typing import Any

from cvj_ros.commands.sweep import load_scene_data
from cvj_ros.physics.scene import find_scene
from cvj_ros.sweep.run import Job, RunOptions
from cvj_ros.sweep.spec import build_sweep

SETS = ['driveline[coupling].params.alpha_deg=0:30:40',
        'driveline[bushings].stiffness=300:3000:100:log']


def job_and_values() -> tuple[Job, list[tuple[Any, ...]]]:
    sw = build_sweep(load_scene_data(find_scene('kavz685_lever')), SETS)
    job = Job(base=sw.base, keys=tuple(a.keys for a in sw.axes), options=RunOptions())
    return job, [tuple(v) for v in sw.variants[::10]]


STAGES: dict[str, float] = defaultdict(float)


def wrap(module: Any, name: str, label: str) -> None:
    """Time ``module.name`` into STAGES[label] (CPU s)."""
    fn = getattr(module, name)

    def timed(*a: Any, **k: Any) -> Any:
        t0 = time.process_time()
        try:
            return fn(*a, **k)
        finally:
            STAGES[label] += time.process_time() - t0
    setattr(module, name, timed)


def load_batch_of(commit: str) -> Any:
    """``cvj_ros/sweep/batch.py`` of ``commit`` as a module of its own."""
    import importlib.util
    import subprocess
    import tempfile
    src = subprocess.run(['git', 'show', f'{commit}:cvj_ros/sweep/batch.py'], check=True,
                         capture_output=True, text=True).stdout
    path = tempfile.NamedTemporaryFile('w', suffix='_batch_before.py', delete=False)
    path.write(src)
    path.close()
    spec = importlib.util.spec_from_file_location('batch_before', path.name)
    mod = importlib.util.module_from_spec(spec)
    sys.modules['batch_before'] = mod
    spec.loader.exec_module(mod)
    return mod


def paired(rounds: int, commit: str) -> None:
    from cvj_ros.sweep import batch
    before = load_batch_of(commit)
    job, values = job_and_values()
    runners = {'before': before.BatchRunner(job), 'after': batch.BatchRunner(job)}
    gc.disable()
    for runner in runners.values():
        for _ in range(2):
            for v in values:
                runner.run(v)
    rows = {k: [repr(r.run(v)[0]) for v in values] for k, r in runners.items()}
    assert rows['before'] == rows['after'], 'rows differ'
    for r in range(rounds):
        line = []
        for name, runner in runners.items():
            t0 = time.process_time()
            for v in values:
                runner.run(v)
            line.append(f'{name} {(time.process_time() - t0) / len(values) * 1e3:.3f}')
        print(f'pair {r}: ' + '  '.join(line) + ' ms a variant')


def main() -> None:
    rounds = int(sys.argv[1]) if len(sys.argv) > 1 and sys.argv[1].isdigit() else 3
    if '--against' in sys.argv:
        paired(rounds, sys.argv[sys.argv.index('--against') + 1])
        return
    from cvj_ros.sweep import batch
    job, values = job_and_values()
    runner = batch.BatchRunner(job)
    gc.disable()
    for v in values:            # warm: templates, probes, entry points
        runner.run(v)
    for v in values:
        runner.run(v)
    for r in range(rounds):
        t0 = time.process_time()
        for v in values:
            runner.run(v)
        whole = (time.process_time() - t0) / len(values) * 1e3
        print(f'round {r}: whole {whole:.3f} ms a variant (stats {runner.stats})')
    import cvj_ros.physics.fidelity as fid
    import cvj_ros.physics.scene as sc
    import cvj_ros.sweep.orders as orders
    import cvj_ros.sweep.reduce as red
    import cvj_ros.sweep.run as run_mod
    wrap(sc, 'parse_scene', 'parse_scene')
    import cvj_ros.sweep.reparse as rp
    wrap(rp.Reparser, 'parse', 'validation (Reparser.parse)')
    wrap(fid, 'choose_fidelity', 'fidelity')
    wrap(batch, 'variant_dict', 'variant_dict')
    wrap(batch, 'lean_run', 'lean_run (compiled run, checks, Trace)')
    wrap(red, 'compiled_reduction', 'reduction (incl. earring fill)')
    wrap(batch.BatchRunner, '_reduce', '_reduce total')
    wrap(orders, 'order_amplitudes_cached', 'orders')
    wrap(run_mod, 'metrics_row', 'metrics_row')
    # the compiled calls of the reduction by name (reduce_lean: the window, the earring's
    # speeds and the metrics in one call); a full earring fill (a fallback) by itself
    orig_call = red._call

    def call(name: str, args: Any) -> Any:
        t0 = time.process_time()
        try:
            return orig_call(name, args)
        finally:
            STAGES[f'  compiled {name}'] += time.process_time() - t0
    red._call = call
    if hasattr(batch, 'MemberFill'):
        wrap(batch.MemberFill, '__call__', 'earring fill in full (outputs_nb)')
    else:       # the tree before: the fill is lean_run's closure
        orig_lean = batch.lean_run

        def lean(*a: Any, **k: Any) -> Any:
            trace, fill = orig_lean(*a, **k)

            def f(i: int) -> None:
                t0 = time.process_time()
                fill(i)
                STAGES['earring fill'] += time.process_time() - t0
            return trace, f
        batch.lean_run = lean
    for r in range(rounds):
        STAGES.clear()
        t0 = time.process_time()
        for v in values:
            runner.run(v)
        whole = (time.process_time() - t0) / len(values) * 1e3
        print(f'profiled round {r}: whole {whole:.3f} ms a variant')
        for k, s in sorted(STAGES.items(), key=lambda kv: -kv[1]):
            print(f'  {k:42s} {s / len(values) * 1e3:.3f}')


if __name__ == '__main__':
    main()
