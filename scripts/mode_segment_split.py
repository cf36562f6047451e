"""Where a mode segment's time goes: copies of ``kernel/segment_nb.py`` with one piece
doubled or cut off, replaying the segments of one kernel run of each mode scene
(docs/benchmark.md, "Against the expert baseline: numbalsoda with oracle events").

One run of ``launch_clutch_chain`` and of ``launch_clutch`` (dopri5, rtol TOL, atol TOL/100,
20 samples) records every ``run_segment`` call's arguments and results; each variant's
compiled ``mode_segment`` then replays all of them (CPU time, min of 3 x REPS replays),
the variants alternating in every round:

- A: the module unchanged;
- B: every rhs evaluation twice (B - A: the rhs in place, per call);
- C: the step-end witnesses twice (C - A: their cost per accepted step);
- E: the event location twice (Brent's method and its two end evaluations);
- D: DOPRI5's stage arguments (y + h sum a_ij k_j) computed twice;
- F: the error norm computed twice (the mean of the two: the same bits);
- G: before every stage one extra rhs call at the step's start state into a scratch row (G -
  A: an rhs call between other work, not right after the same one);
- Z: the segment stops after its set-up (entry, arrays, f0, first step, witnesses at t0).

Then the removal the doubling cannot give: every segment's accepted steps (a run with the step
log) replayed as bare ``segment_nb._attempt`` calls (6 rhs calls, the stage arguments, the
error norm) at the logged sizes, without step control, rejected attempts, witnesses or
samples (CPU time, median of 5 rounds of 20 replays).

Beside them, in the same rounds, the expert on the same segments (when numbalsoda imports):
numbalsoda's DOP853 (X) and LSODA (L) through ``bench_expert.mode_expert_cfunc`` from each
segment's start state to its end (the run's event time or t_stop; the samples inside as
t_eval, the ramps ending at t_stop as in ``bench_modes._expert_segment``), one compiled call
per segment. Its rhs calls are counted twice: the cfunc's own counter in its parameter
block, and a second cfunc of the same body that counts into an array of its own (fixed
address, no parameter-block slot), on the same segments; the two must agree.

A to G must reproduce the run's results bit for bit (checked before the timing).
The copies compile into a scratch directory (~40 s each), not the package's cache.
``--only A``: the unchanged module (and the expert) only, no copies. ``--base REV``: one
more variant O, ``segment_nb.py`` and ``tree_modes_nb.py`` as of git revision REV, in the
same rounds (a before/after pair under the same load; O must give A's results bit for bit).

    PYTHONPATH=. python scripts/mode_segment_split.py TOL [ROUNDS] [SCRATCH_DIR] [--only A]
        [--base REV]
"""
from __future__ import annotations

import importlib
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import cvj_ros.physics.kernel.modes as km
import cvj_ros.physics.kernel.tree_modes as tmm
from cvj_ros.physics.hybrid.from_scene import hybrid_simulation
from cvj_ros.physics.kernel import entry_point
from cvj_ros.physics.kernel.modes import (KernelHybridSimulation, _coefficients,
                                          _METHOD_CODE)
from cvj_ros.physics.kernel.tree_modes import KernelHybridTreeSimulation
from cvj_ros.physics.scene import find_scene, load_scene

SCENES = ('launch_clutch_chain', 'launch_clutch')
_RHS = ('        mode_eval(t, y, ip, fp, dy, sc, want)\n    else:\n'
        '        tm_eval(t, y, ip, fp, dy, sc, want)\n')
_RHS_TWICE = ('        mode_eval(t, y, ip, fp, dy, sc, want)\n' * 2 + '    else:\n'
              + '        tm_eval(t, y, ip, fp, dy, sc, want)\n' * 2)
_WIT = '            _witness_from(kind, t_new, y, ip, fp, K[fsal], sc, g_new)\n'
_I20, _I41, _I37 = ' ' * 20, ' ' * 41, ' ' * 37
_ENDS = ''.join(
    f'{_I20}{fx} = _dense_witness(kind, method, {tx}, i, y, y_old, fs, cnt, K, ip, fp,\n'
    f'{_I41}yy, dy, sc, wv, D8, AX, CX, RH)\n' for fx, tx in (('f_a', 't_old'), ('f_b', 't_new')))
_BRENT = (f'{_I20}t_i = brent_root(kind, t_old, t_new, f_a, f_b, i, method, y, y_old, fs, cnt,\n'
          f'{_I37}K, ip, fp, yy, dy, sc, wv, D8, AX, CX, RH)\n')
_ARG = ('        for i in range(n):\n            arg[i] = y[i]\n        for j in range(s):\n'
        '            c = h * DP_A[s, j]\n            if c != 0.0:\n                kj = K[j]\n'
        '                for i in range(n):\n                    arg[i] += c * kj[i]\n')
_STAGE = '        _f(kind, t + DP_C[s] * h, arg, ip, fp, K[s], sc, False)\n    ynew = work[1]\n'
_NORM = ('    ss = 0.0\n    for i in range(n):\n        e = 0.0\n        for j in range(7):\n'
         '            e += DP_E[j] * K[j, i]\n'
         '        scl = max(abs(y[i]), abs(ynew[i])) * rtol + atol[i]\n'
         '        ss += (e / scl) ** 2\n')
_SETUP = '    _witness_at(kind, t0, y, ip, fp, dy, sc, g_old)\n    k = k0\n'


def variants(src: str) -> dict[str, str]:
    """The module's text per variant (module docstring)."""
    for piece in (_RHS, _WIT, _ENDS + _BRENT, _ARG + _STAGE, _NORM, _SETUP):
        if piece not in src:
            raise SystemExit('mode_segment_split: segment_nb.py changed; a piece to double '
                             'was not found')
    return {
        'A': src,
        'B': src.replace(_RHS, _RHS_TWICE),
        'C': src.replace(_WIT, _WIT + _WIT),
        'E': src.replace(_ENDS + _BRENT,
                         _ENDS + _BRENT.replace('t_i = ', 't_i2 = ') + _ENDS + _BRENT),
        'D': src.replace(_ARG + _STAGE, _ARG + _ARG + _STAGE),
        'F': src.replace(_NORM, _NORM + _NORM.replace('ss', 'ss2') + '    ss = (ss + ss2) / 2\n'),
        'G': src.replace(_STAGE, '        _f(kind, t, y, ip, fp, work[3], sc, False)\n' + _STAGE),
        'Z': src.replace(_SETUP, '    _witness_at(kind, t0, y, ip, fp, dy, sc, g_old)\n'
                                 '    if t0 < t_stop:\n        return\n    k = k0\n'),
    }


def base_variant(rev: str, scratch: Path) -> str:
    """segment_nb.py as of git revision ``rev``, importing that revision's tree_modes_nb.py
    (written into ``scratch`` as segvar_O_tm.py)."""
    import subprocess
    root = Path(km.__file__).parents[3]
    texts = []
    for name in ('segment_nb.py', 'tree_modes_nb.py'):
        r = subprocess.run(['git', 'show', f'{rev}:cvj_ros/physics/kernel/{name}'], cwd=root,
                           capture_output=True, text=True)
        if r.returncode != 0 or not rev:
            raise SystemExit(f'mode_segment_split: --base: no {name} at revision {rev!r}')
        texts.append(r.stdout)
    path = scratch / 'segvar_O_tm.py'
    if not path.exists() or path.read_text() != texts[1]:
        path.write_text(texts[1])
    return texts[0].replace('from cvj_ros.physics.kernel.tree_modes_nb import',
                            'from segvar_O_tm import')


def capture(scene_name: str, tol: float, step_log: bool = False) -> list[list]:
    """Every run_segment call of one kernel run: its arguments and (out_i, out_f, y, hlog)
    after."""
    calls: list[list] = []
    orig = km.run_segment

    def cap(*a):  # noqa: ANN002, ANN202
        calls.append([x.copy() if isinstance(x, np.ndarray) else x for x in a])
        orig(*a)
        calls[-1].append((a[15].copy(), a[16].copy(), a[4].copy(), a[14].copy()))
    km.run_segment = tmm.run_segment = cap
    try:
        scene = load_scene(find_scene(scene_name))
        kern = KernelHybridTreeSimulation if scene.is_tree else KernelHybridSimulation
        kern.from_reference(hybrid_simulation(scene, method='dopri5', rtol=tol, atol=tol * 1e-2,
                                              sample_dt=scene.duration / 20,
                                              duration=scene.duration),
                            step_log=step_log).run()
    finally:
        km.run_segment = tmm.run_segment = orig
    return calls


def seg_args(c: list) -> tuple:
    """mode_segment's arguments of a recorded call, the arrays it overwrites fresh."""
    (kind, method, t, t_stop, y, ip, fp, rtol, atol, max_step, h_in, times, k, Y, hlog, oi,
     of) = c[:17]
    return (int(kind), _METHOD_CODE[method], float(t), float(t_stop), y.copy(), ip, fp.copy(),
            float(rtol), atol, float(max_step), float(h_in), times, int(k), Y.copy(), hlog,
            oi.copy(), of.copy(), *_coefficients(method))


def main() -> None:
    argv = sys.argv[1:]
    only = None
    base = None
    if '--base' in argv:
        i = argv.index('--base')
        base = argv[i + 1] if i + 1 < len(argv) else ''
        del argv[i:i + 2]
    if '--only' in argv:
        i = argv.index('--only')
        only = argv[i + 1:i + 2]
        del argv[i:i + 2]
    try:
        tol = float(argv[0])
        rounds = int(argv[1]) if len(argv) > 1 else 5
        if not (0.0 < tol < 1.0 and rounds > 0) or only not in (None, ['A']):
            raise ValueError
    except (IndexError, ValueError):
        raise SystemExit('mode_segment_split: usage: mode_segment_split.py TOL (0 < TOL < 1) '
                         '[ROUNDS > 0] [SCRATCH_DIR]') from None
    scratch = Path(argv[2] if len(argv) > 2 else tempfile.mkdtemp(prefix='segsplit_'))
    src = (Path(km.__file__).parent / 'segment_nb.py').read_text()
    texts = variants(src)
    if only:
        texts = {'A': texts['A']}
    if base is not None:
        texts['O'] = base_variant(base, scratch)
    for v, text in texts.items():
        path = scratch / f'segvar_{v}.py'
        if not path.exists() or path.read_text() != text:     # unchanged: its cache holds
            path.write_text(text)
    sys.path.insert(0, str(scratch))
    scenes = {s: capture(s, tol) for s in SCENES}
    ents = {}
    for v in texts:
        ents[v] = entry_point(importlib.import_module(f'segvar_{v}').mode_segment,
                              seg_args(scenes[SCENES[0]][0]))
    for v in (x for x in 'ABCDEFGO' if x in texts):
        for s, segs in scenes.items():
            for c in segs:
                a = seg_args(c)
                ents[v](*a)
                if not (np.array_equal(a[15], c[17][0]) and np.array_equal(a[16], c[17][1])
                        and np.array_equal(a[4], c[17][2])):
                    raise SystemExit(f'mode_segment_split: variant {v} changed a result on {s}')

    def replay(ent, segs, reps):  # noqa: ANN001, ANN202
        a = [[seg_args(c) for c in segs] for _ in range(reps)]
        t0 = time.process_time()
        for xs in a:
            for x in xs:
                ent(*x)
        return (time.process_time() - t0) / reps
    experts = expert_setup(scenes)
    res = {s: {v: [] for v in (*ents, *experts.get(s, {}))} for s in scenes}
    for r in range(rounds):
        for s, segs in scenes.items():
            reps = 20 if s == SCENES[0] else 4
            for v, ent in ents.items():
                res[s][v].append(min(replay(ent, segs, reps) for _ in range(3)))
            for v, (fn, cases, _n) in experts.get(s, {}).items():
                res[s][v].append(min(expert_replay(fn, cases, reps) for _ in range(3)))
        print(f'round {r}, load {os.getloadavg()[0]:.2f}', flush=True)
    for s, segs in scenes.items():
        nacc = sum(int(c[17][0][3]) for c in segs)
        nfev = sum(int(c[17][0][4]) for c in segs)
        nev = sum(1 for c in segs if c[17][0][1] >= 0)
        m = {v: float(np.median(x)) for v, x in res[s].items()}
        print(f'{s} rtol {tol:g}: kernel dopri5 segments {m["A"] * 1e3:.3f} ms, {nfev} rhs '
              f'calls, {m["A"] / nfev * 1e9:.0f} ns per rhs call all in')
        if 'O' in m:
            print(f'{s} rtol {tol:g}: the base revision\'s segments {m["O"] * 1e3:.3f} ms '
                  f'({m["O"] / nfev * 1e9:.0f} ns per rhs call all in); this / base '
                  f'{m["A"] / m["O"]:.2f}x (per-round ratios '
                  + ', '.join(f'{a / o:.2f}' for a, o in zip(res[s]['A'], res[s]['O'])) + ')')
        for v, (_fn, cases, calls) in experts.get(s, {}).items():
            print(f'{s} rtol {tol:g}: numbalsoda {EXPERTS[v]} on the same {len(cases)} '
                  f'segments {m[v] * 1e3:.3f} ms, {calls} rhs calls (both counters), '
                  f'{m[v] / calls * 1e9:.0f} ns per rhs call all in; expert / kernel '
                  f'{m[v] / m["A"]:.2f}x')
        if 'B' not in m:
            continue
        rhs, wit, ev, setup = m['B'] - m['A'], m['C'] - m['A'], m['E'] - m['A'], m['Z']
        arg, norm, rhs_g = m['D'] - m['A'], m['F'] - m['A'], m['G'] - m['A']
        n_g = 5 * (nacc + sum(int(c[17][0][5]) for c in segs))     # G's calls: 5 per attempt
        rest = m['A'] - rhs - wit - ev - setup - arg - norm
        print(f'{s} rtol {tol:g}: {len(segs)} segments, {nev} events, {nacc} steps, {nfev} rhs '
              f'calls; segments {m["A"] * 1e3:.3f} ms ({m["A"] / nfev * 1e9:.0f} ns per rhs call, '
              f'{m["A"] / nacc * 1e6:.2f} us per step)')
        print(f'  rhs {rhs * 1e3:.3f} ms ({rhs / nfev * 1e9:.0f} ns/call), step-end witnesses '
              f'{wit * 1e3:.3f} ms ({wit / nacc * 1e9:.0f} ns/step), event location '
              f'{ev * 1e3:.3f} ms ({ev / max(nev, 1) * 1e6:.1f} us/event), set-up '
              f'{setup * 1e3:.3f} ms ({setup / len(segs) * 1e6:.1f} us/segment), the rest '
              f'(control, loop, samples, what the doubling misses) '
              f'{rest * 1e3:.3f} ms ({rest / nacc * 1e9:.0f} ns/step)')
        print(f'  stage arguments {arg * 1e3:.3f} ms, error norm {norm * 1e3:.3f} ms; an rhs call '
              f'between other work (G) {rhs_g / n_g * 1e9:.0f} ns')
    for s in SCENES:
        attempts_only(s, tol)


EXPERTS = {'X': 'dop853', 'L': 'lsoda'}


def _counting_cfunc(counter: np.ndarray):  # noqa: ANN202
    """mode_expert_cfunc's body, counting its calls into ``counter[0]`` (its address a
    compile-time constant) instead of the parameter block."""
    import numba as nb
    from numba import types

    from cvj_ros.bench_expert import P_FP, P_IP, P_KIND, P_NFP, P_NIP, P_NSC, P_NSTATE, P_SC
    from cvj_ros.bench_expert import _pointer_intrinsic
    from cvj_ros.physics.kernel.modes_nb import mode_eval
    from cvj_ros.physics.kernel.tree_modes_nb import tm_eval
    _as_pointer = _pointer_intrinsic()
    addr = int(counter.ctypes.data)
    sig = types.void(types.double, types.CPointer(types.double), types.CPointer(types.double),
                     types.CPointer(types.double))

    @nb.cfunc(sig)
    def f(t, u, du, p):  # noqa: ANN001, ANN202
        cnt = nb.carray(_as_pointer(np.int64(addr)), (1,), dtype=np.float64)
        cnt[0] += 1.0
        n = np.int64(p[P_NSTATE])
        ip = nb.carray(_as_pointer(np.int64(p[P_IP])), (np.int64(p[P_NIP]),), dtype=np.int64)
        fp = nb.carray(_as_pointer(np.int64(p[P_FP])), (np.int64(p[P_NFP]),), dtype=np.float64)
        sc = nb.carray(_as_pointer(np.int64(p[P_SC])), (np.int64(p[P_NSC]),), dtype=np.float64)
        y = nb.carray(u, (n,))
        dy = nb.carray(du, (n,))
        if p[P_KIND] == 0.0:
            mode_eval(t, y, ip, fp, dy, sc, False)
        else:
            tm_eval(t, y, ip, fp, dy, sc, False)
    return f


def expert_cases(segs: list[list]) -> list[tuple]:
    """numbalsoda's arguments per recorded segment of non-zero length: (kind, y0, t_eval,
    parameter block, rtol, atol, the arrays the block points at)."""
    from cvj_ros.bench_expert import mode_expert_data
    from cvj_ros.physics.kernel.modes_nb import MH_RAMP_B, MH_RAMP_C, MH_RAMP_T
    from cvj_ros.physics.kernel.tree_modes_nb import MB_RAMP_B, MB_RAMP_C, MB_RAMP_T
    out = []
    for c in segs:
        kind, t, t_stop, y, ip, fp, rtol, atol = (int(c[0]), float(c[2]), float(c[3]), c[4],
                                                  c[5], c[6].copy(), float(c[7]), c[8])
        t_end = float(c[17][1][0])
        if kind == 0:
            ramps = (ip[MH_RAMP_T], ip[MH_RAMP_C], ip[MH_RAMP_B])
        else:
            mb = ip[-1]
            ramps = (ip[mb + MB_RAMP_T], ip[mb + MB_RAMP_C], ip[mb + MB_RAMP_B])
        for off in ramps:
            fp[off + 1 + 2 * int(fp[off])] = t_stop
        eps = 1e-12 * max(1.0, abs(t_end))
        if t_end - t <= eps:
            continue
        if np.ptp(atol) != 0.0:
            raise SystemExit('mode_segment_split: numbalsoda takes one scalar atol')
        samp = c[11][int(c[12]):]
        samp = samp[(samp > t + eps) & (samp < t_end - eps)]
        t_eval = np.concatenate(([t], samp, [t_end]))
        sc = np.zeros(256)
        data = mode_expert_data(kind, ip, fp, y.size, sc)
        out.append((kind, y.copy(), t_eval, data, rtol, float(atol[0]), (ip, fp, sc)))
    return out


def expert_setup(scenes: dict[str, list]) -> dict[str, dict[str, tuple]]:
    """Per scene {'X': (numbalsoda dop853's compiled entry, its arguments per segment, the rhs
    calls of one replay), 'L': the same for lsoda}; the two counters must agree (else
    SystemExit). {} without numbalsoda."""
    from cvj_ros.bench_expert import P_COUNT, mode_expert_cfunc, unavailable_reason
    if unavailable_reason():
        print(f'mode_segment_split: expert skipped: {unavailable_reason()}')
        return {}
    import numbalsoda
    addr = mode_expert_cfunc().address
    counter = np.zeros(1)
    addr_count = _counting_cfunc(counter).address
    out: dict[str, dict[str, tuple]] = {}
    for s, segs in scenes.items():
        cases = expert_cases(segs)
        out[s] = {}
        for v, meth in EXPERTS.items():
            disp = getattr(numbalsoda, meth)
            k, y0, t_eval, data, rtol, atol, _keep = cases[0]
            a = (addr, y0.copy(), t_eval, data, rtol, atol, 1_000_000)
            disp(*a)
            fn = disp.overloads[tuple(disp.typeof_pyval(x) for x in a)].entry_point
            own = 0
            counter[0] = 0.0
            for k, y0, t_eval, data, rtol, atol, _keep in cases:
                data[P_COUNT] = 0.0
                sol, ok = fn(addr, y0.copy(), t_eval, data, rtol, atol, 1_000_000)
                if not ok:
                    raise SystemExit(f'mode_segment_split: numbalsoda {meth} failed on {s}')
                own += int(data[P_COUNT])
                fn(addr_count, y0.copy(), t_eval, data, rtol, atol, 1_000_000)
            if own != int(counter[0]):
                raise SystemExit(f'mode_segment_split: numbalsoda {meth} on {s}: the counters '
                                 f'disagree ({own} against {int(counter[0])})')
            out[s][v] = (fn, [(addr, *c[1:]) for c in cases], own)   # c[6]: kept alive
    return out


def expert_replay(fn, cases, reps):  # noqa: ANN001, ANN201
    """CPU time (s) of one replay of numbalsoda's calls on a scene's segments (the mean of
    ``reps``; the start states copied before the clock)."""
    xs = [[(c[0], c[1].copy(), c[2], c[3], c[4], c[5]) for c in cases] for _ in range(reps)]
    t0 = time.process_time()
    for row in xs:
        for addr, y0, t_eval, data, rtol, atol in row:
            fn(addr, y0, t_eval, data, rtol, atol, 1_000_000)
    return (time.process_time() - t0) / reps


def attempts_only(scene_name: str, tol: float) -> None:
    """Print the cost of the run's accepted steps as bare _attempt calls (docstring)."""
    from numba import njit

    from cvj_ros.physics.kernel.borrow_nb import borrowed_all
    from cvj_ros.physics.kernel.modes_nb import MH_N, N_SCRATCH_EXTRA
    from cvj_ros.physics.kernel.segment_nb import _attempt, _f, _scratch
    from cvj_ros.physics.kernel.steppers_nb import FS_T, NCNT, NFS
    from cvj_ros.physics.kernel.tree_modes_nb import MB_NWIT

    @njit
    def mesh(kind, t0, y0, ip, fp, rtol, atol, hs, sc, reps):  # noqa: ANN001, ANN202
        y0, ip, fp, atol, hs, sc = borrowed_all((y0, ip, fp, atol, hs, sc))
        n = y0.shape[0]
        K = _scratch(7, n)                 # as mode_segment: borrowed arguments, stack scratch
        work = _scratch(4, n)
        fs = _scratch(1, NFS)[0]
        cnt = np.zeros(NCNT, np.int64)
        y = _scratch(1, n)[0]
        for _ in range(reps):
            y[:] = y0
            t = t0
            _f(kind, t, y, ip, fp, K[0], sc, False)
            for h in hs:
                fs[FS_T] = t
                _attempt(kind, h, y, ip, fp, fs, cnt, rtol, atol, K, work, sc)
                y[:] = work[1]
                K[0, :] = K[6]
                t = t + h
        return y[0]
    calls = capture(scene_name, tol, step_log=True)
    calls = [c for c in calls if c[17][0][6] == c[17][0][3]]     # complete logs only
    nacc = sum(int(c[17][0][3]) for c in calls)
    res = []
    for _r in range(5):
        tot = 0.0
        for c in calls:
            kind, y, ip, fp = int(c[0]), c[4], c[5], c[6].copy()
            hs = c[17][3][:int(c[17][0][6])].copy()
            if kind == 0:
                sc = np.zeros(ip[MH_N] + N_SCRATCH_EXTRA)
            else:
                sc = np.zeros(max(ip[ip[ip.shape[0] - 1] + MB_NWIT], 1))
            args = (kind, float(c[2]), y, ip, fp, float(c[7]), c[8], hs, sc)
            mesh(*args, 1)
            t0 = time.process_time()
            mesh(*args, 20)
            tot += (time.process_time() - t0) / 20
        res.append(tot)
    med = float(np.median(res))
    print(f'{scene_name} rtol {tol:g}: {nacc} accepted steps as bare _attempt calls '
          f'{med * 1e3:.3f} ms ({med / nacc * 1e9:.0f} ns/step, {med / (6 * nacc) * 1e9:.0f} ns '
          f'per rhs call all in), load {os.getloadavg()[0]:.2f}')


if __name__ == '__main__':
    main()
