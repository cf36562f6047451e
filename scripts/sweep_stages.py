"""Where a batched sweep variant's CPU goes (docs/sweeps.md, "how far from 2000/s").

The 40 x 100 kavz685_lever grid (``alpha_deg=0:30:40`` x ``stiffness=300:3000:100:log``),
every 10th variant (400), run by one :class:`cvj_ros.sweep.batch.BatchRunner` in this
process after a warm pass over the same variants (templates and probes made). Each round
times the whole 400 with ``time.process_time`` (CPU of this process), then the same 400
again with per-stage timers wrapped around the batched path's functions (the timers add a
few per cent). Prints ms a variant per round.

    PYTHONPATH=. python scripts/sweep_stages.py [ROUNDS] [--against COMMIT]

``--timeline N [TREE ...]``: the whole ``cvj-sim sweep`` of the grid (``--workers 2
--no-plots``), N runs in child processes (with several source trees as PYTHONPATH,
alternating between them), times in s from the child process's start: when the fork server
starts, when each worker starts its first chunk and ends its last (its CPU in chunks),
when the parent submits, has its last chunk and has written the tables; the parent's CPU
(``getrusage``) and the MD5 of results.csv. Prints a few lines a run.

``--server N [TREE ...]``: the fork server's load alone, N rounds alternating between the
source trees (default this one): a fresh interpreter imports what the server imports
(``multiprocessing.forkserver`` and ``cvj_ros.sweep.preload``) and prints its whole CPU
(``getrusage``, the interpreter's start included), s.

``--against COMMIT``: paired instead - that commit's ``cvj_ros/sweep/batch.py`` (from
``git show``, loaded as a module of its own beside this tree's; the rest of cvj_ros is
this tree's) and this tree's, each with its own warm runner, the 400 variants
alternating between the two, ROUNDS pairs, CPU ms a variant each.
"""
from __future__ import annotations

import gc
import os
import sys
import time
from collections import defaultdict
from typing import Any

SETS = ['driveline[coupling].params.alpha_deg=0:30:40',
        'driveline[bushings].stiffness=300:3000:100:log']


def job_and_values() -> tuple[Any, list[tuple[Any, ...]]]:
    from cvj_ros.commands.sweep import load_scene_data
    from cvj_ros.physics.scene import find_scene
    from cvj_ros.sweep.run import Job, RunOptions
    from cvj_ros.sweep.spec import build_sweep
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


TIMELINE = os.environ.get('SWEEP_TIMELINE_FILE', '')


def timed_chunk(job: Any, chunk: Any, **kw: Any) -> Any:
    """run_chunk with (pid, wall start, wall end, CPU start, CPU end, n) appended to
    SWEEP_TIMELINE_FILE (the workers resolve it as this module's function)."""
    from cvj_ros.sweep import run as run_mod
    w0, c0 = time.time(), time.process_time()
    out = run_mod.run_chunk(job, chunk, **kw)
    with open(TIMELINE, 'a') as f:
        f.write(f'{os.getpid()} {w0!r} {time.time()!r} {c0!r} {time.process_time()!r} '
                f'{len(chunk)}\n')
    return out


def timeline_child(path: str, out: str, against: str | None) -> None:
    """One ``cvj-sim sweep`` of the grid in this process, the chunks timed (timed_chunk)."""
    import resource
    # the process's start (/proc: clock ticks after boot), not this line's
    ticks = os.sysconf('SC_CLK_TCK')
    with open('/proc/self/stat') as f:
        start_ticks = int(f.read().rsplit(')', 1)[1].split()[19])
    with open('/proc/stat') as f:
        btime = next(int(ln.split()[1]) for ln in f if ln.startswith('btime'))
    t_cmd = btime + start_ticks / ticks
    marks: dict[str, float] = {'script': time.time()}
    os.environ['SWEEP_TIMELINE_FILE'] = path
    from cvj_ros import cli
    from cvj_ros.sweep import results, run as run_mod

    def map_(self: Any, job: Any, work: Any) -> Any:
        import concurrent.futures as cf
        marks['submit'] = time.time()
        self.futures = [self.pool.submit(timed_chunk, job, c) for c in work]
        from cvj_ros.sweep import server
        served = getattr(server, 'mark_served', lambda: None)    # (a tree before it)
        for fut in cf.as_completed(self.futures):
            result = fut.result()
            served()
            yield result
        marks['last chunk'] = time.time()
    run_mod.ProcessExecutor.map = map_
    orig_write = results.ResultStore.write_tables

    def write(self: Any, *a: Any, **k: Any) -> Any:
        marks['tables from'] = time.time()
        try:
            return orig_write(self, *a, **k)
        finally:
            marks['tables to'] = time.time()
    results.ResultStore.write_tables = write
    from multiprocessing import forkserver
    orig_ensure = forkserver.ensure_running

    def ensure() -> None:
        marks.setdefault('fork server start', time.time())
        orig_ensure()
    forkserver.ensure_running = ensure
    orig_append = results.ResultStore.append
    cpu_rows = [0.0]

    def append(self: Any, outcomes: Any) -> None:
        c0 = time.process_time()
        orig_append(self, outcomes)
        cpu_rows[0] += time.process_time() - c0
    results.ResultStore.append = append
    argv = ['sweep', 'kavz685_lever', *sum((['--set', s] for s in SETS), []), '--workers', '2',
            '--no-plots', '--fresh', '--out', out]
    import contextlib
    import io
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf), contextlib.redirect_stderr(io.StringIO()):
        rc = cli.main(argv)
    marks['exit'] = time.time()
    marks['rows.jsonl CPU'] = t_cmd + cpu_rows[0]
    ru = resource.getrusage(resource.RUSAGE_SELF)
    printed = [ln for ln in buf.getvalue().splitlines() if ln.startswith('ran ')]
    with open(path + '.parent', 'w') as f:
        f.write(repr({'t_cmd': t_cmd, 'marks': marks, 'cpu': ru.ru_utime + ru.ru_stime,
                      'rc': rc, 'printed': printed}))


def timeline(runs: int, trees: list[str]) -> None:
    import ast
    import hashlib
    import subprocess
    import tempfile
    for r in range(runs * len(trees)):
        tree = trees[r % len(trees)]
        d = tempfile.mkdtemp(prefix='sweep_timeline_')
        path = os.path.join(d, 'chunks.txt')
        load = os.getloadavg()[0]
        t0 = time.time()
        subprocess.run([sys.executable, __file__, '--timeline-child', path, os.path.join(d, 'out')],
                       check=True, env={**os.environ, 'PYTHONPATH': tree})
        wall = time.time() - t0
        par = ast.literal_eval(open(path + '.parent').read())
        tc = par['t_cmd']
        per: dict[int, list[tuple[float, ...]]] = defaultdict(list)
        for ln in open(path):
            pid, *vals = ln.split()
            per[int(pid)].append(tuple(float(v) for v in vals))
        md5 = hashlib.md5(open(os.path.join(d, 'out', 'results.csv'), 'rb').read()).hexdigest()
        parts = [f'run {r} ({tree}): load {load:.2f}, process wall {wall:.2f} s, '
                 f'{par["printed"][0][4:]}']
        for pid, rows in sorted(per.items()):
            rows.sort()
            n = sum(int(x[4]) for x in rows)
            cpu = sum(x[3] - x[2] for x in rows)
            first = rows[0]
            parts.append(f'  worker {pid}: first chunk {first[0] - tc:.3f}-{first[1] - tc:.3f} s'
                         f' (CPU at its start {first[2]:.3f} s, chunk {first[3] - first[2]:.3f} s)'
                         f', last ends {rows[-1][1] - tc:.3f} s; {n} variants, {len(rows)} chunks,'
                         f' {cpu:.3f} s CPU in chunks ({cpu / n * 1e3:.3f} ms a variant)')
        m = par['marks']
        parts.append('  parent: ' + ', '.join(f'{k} {v - tc:.3f}' for k, v in m.items())
                     + f' s; CPU {par["cpu"]:.3f} s; results.csv {md5}')
        print('\n'.join(parts), flush=True)


def server_load(rounds: int, trees: list[str]) -> None:
    import statistics
    import subprocess
    code = ('import resource; from multiprocessing.forkserver import main; '
            'import cvj_ros.sweep.preload; r = resource.getrusage(resource.RUSAGE_SELF); '
            'print(r.ru_utime + r.ru_stime)')
    cpu: dict[str, list[float]] = defaultdict(list)
    for _r in range(rounds):
        for tree in trees:
            out = subprocess.run([sys.executable, '-c', code], check=True, capture_output=True,
                                 text=True, env={**os.environ, 'PYTHONPATH': tree},
                                 cwd=tree).stdout    # -c puts the working directory first
            cpu[tree].append(float(out))
    for tree in trees:
        c = sorted(cpu[tree])
        print(f'{tree}: server CPU {c[0]:.3f}-{c[-1]:.3f} s, median {statistics.median(c):.3f} '
              f'({len(c)} runs, load {os.getloadavg()[0]:.2f})')


def main() -> None:
    if '--server' in sys.argv:
        i = sys.argv.index('--server')
        server_load(int(sys.argv[i + 1]), sys.argv[i + 2:] or [os.getcwd()])
        return
    if '--timeline-child' in sys.argv:
        i = sys.argv.index('--timeline-child')
        timeline_child(sys.argv[i + 1], sys.argv[i + 2], None)
        return
    if '--timeline' in sys.argv:
        i = sys.argv.index('--timeline')
        timeline(int(sys.argv[i + 1]), sys.argv[i + 2:] or [os.getcwd()])
        return
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
