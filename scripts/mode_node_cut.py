"""launch_clutch's kernel runs with every mode segment cut where the engine speed crosses a
node of its map, against the same runs uncut (docs/benchmark.md, "Why launch_clutch's error
does not fall with the tolerance").

The map engine's torque is C1 only: T'' jumps at the full-load table's speeds (PCHIP held
constant outside the table, Fritsch and Carlson 1980) and at the idle governor's four
quadratic corners (``engine.smooth_ramp``, half-width 0.05 of the governor's range). A
step that spans one makes an error the embedded estimate does not bound. The crossing
times come from the reference (kernel dopri5, rtol 1e-13, atol 1e-15, 0.2 ms samples of
``engine_crank``, linear between samples); each ``run_segment`` call is then split there
(the kernel itself unchanged). Prints, per method and rtol (atol rtol / 100, 20 samples),
the uncut run's error against the uncut reference and the cut run's against the cut
reference, and their steps.

    PYTHONPATH=. python scripts/mode_node_cut.py [dopri5,dop853,vern7] [1e-6,...,1e-11]
"""
from __future__ import annotations

import sys

import numpy as np

import cvj_ros.physics.kernel.tree_modes as tree_modes
from cvj_ros.physics.hybrid.from_scene import hybrid_simulation
from cvj_ros.physics.scene import find_scene, load_scene

RPM = np.pi / 30.0


def engine_nodes_rpm(engine) -> list[float]:
    """The map engine's speeds (rpm) where its torque's second derivative jumps."""
    nodes = [float(x) for x in engine.full_load_rpm]
    if engine.idle_rpm > 0.0:             # g = ramp(K (n_idle - n)) corners at -w, w, 1-w, 1+w
        w = 0.05
        nodes += [engine.idle_rpm - u / engine.idle_gain for u in (-w, w, 1 - w, 1 + w)]
    return sorted(nodes)


def main() -> None:
    methods = sys.argv[1].split(',') if len(sys.argv) > 1 else ['dopri5', 'dop853', 'vern7']
    tols = [float(x) for x in sys.argv[2].split(',')] if len(sys.argv) > 2 else \
        [1e-6, 1e-7, 1e-8, 1e-9, 1e-10, 1e-11]
    scene = load_scene(find_scene('launch_clutch'))
    horizon = scene.duration
    kern = tree_modes.KernelHybridTreeSimulation

    def run(method: str, rtol: float, atol: float, sample_dt: float):
        return kern.from_reference(hybrid_simulation(scene, method=method, rtol=rtol, atol=atol,
                                                     sample_dt=sample_dt, duration=horizon)).run()
    fine = run('dopri5', 1e-13, 1e-15, 2e-4)
    if fine.shafts[0] != 'engine_crank':
        raise SystemExit('mode_node_cut: expected engine_crank as the first shaft')
    engine = hybrid_simulation(scene, sample_dt=1.0, duration=horizon).engine
    w, tt = fine.speed[:, 0], fine.t
    cuts = []
    for node in np.array(engine_nodes_rpm(engine)) * RPM:
        s = np.sign(w - node)
        for i in np.nonzero(s[:-1] * s[1:] < 0)[0]:
            cuts.append(tt[i] + (node - w[i]) / (w[i + 1] - w[i]) * (tt[i + 1] - tt[i]))
    cuts.sort()
    print('node crossings (s):', ' '.join(f'{c:.4f}' for c in cuts))
    plain = tree_modes.run_segment

    def cut(kind, method, t, t_stop, y, ip, fp, rtol, atol, max_step, h, times, k, Y, hlog,
            out_i, out_f):
        steps = nfev = rej = 0
        for c in [c for c in cuts if t < c < t_stop] + [t_stop]:
            plain(kind, method, t, c, y, ip, fp, rtol, atol, max_step, h, times, k, Y, hlog,
                  out_i, out_f)
            steps, nfev, rej = steps + out_i[3], nfev + out_i[4], rej + out_i[5]
            if out_i[0] != 0 or out_i[1] >= 0 or c == t_stop:
                break
            t, k = c, int(out_i[2])
        out_i[3], out_i[4], out_i[5], out_i[6] = steps, nfev, rej, 0

    sample_dt = horizon / 20
    ref = run('dopri5', 1e-13, 1e-15, sample_dt)
    tree_modes.run_segment = cut
    ref_cut = run('dopri5', 1e-13, 1e-15, sample_dt)
    scale = float(np.abs(ref.speed).max())
    print(f'cut reference against the uncut: {np.abs(ref_cut.speed - ref.speed).max() / scale:.1e}')
    for m in methods:
        for tol in tols:
            out = []
            for fn, r0 in ((plain, ref), (cut, ref_cut)):
                tree_modes.run_segment = fn
                r = run(m, tol, tol / 100, sample_dt)
                out.append((np.abs(r.speed - r0.speed).max() / scale, r.stats['steps']))
            print(f'{m} {tol:g}: uncut {out[0][0]:.1e} ({out[0][1]} steps), '
                  f'cut {out[1][0]:.1e} ({out[1][1]} steps)', flush=True)
    tree_modes.run_segment = plain


if __name__ == '__main__':
    main()
