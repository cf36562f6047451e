#!/usr/bin/env python3
"""Drive a vehicle mode scene's lockstep model offline as a free run would, with a seeded
tick pattern (docs/clutch_gearbox.md, "Free-run launch_clutch").

The coupling node's model (``hybrid_lockstep``) and the engine model run as the loop runs
them at a 1 ms exchange step, except that each tick may integrate with the previous tick's
engine answer (``--lag``: probability per tick), be merged with the next (``--skip``: a
skipped tick, the run tick integrating both with the torques held), start a burst of 10-100
ticks with no engine answer at all (``--burst``: a descheduled engine process) and take the
commands a random 0..``--cmd-lag`` ticks late. Prints the mode events, the final modes and
the engaged gear. Deterministic: a seed gives one run.

    python scripts/free_run_replay.py --lag 0.5 --skip 0.1 --burst 0.005 --cmd-lag 20 --seed 3
"""
from __future__ import annotations

import argparse
import sys
import time
from collections import Counter
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from cvj_ros.nodes.command_plan import CommandPlan  # noqa: E402
from cvj_ros.nodes.common import scene_dict  # noqa: E402
from cvj_ros.physics.engine import engine_from_spec  # noqa: E402
from cvj_ros.physics.hybrid.lockstep import hybrid_lockstep  # noqa: E402
from cvj_ros.physics.scene import find_scene, load_scene  # noqa: E402

H = 1e-3


def replay(scene_name: str, *, lag: float, skip: float, burst: float, cmd_lag: int, seed: int,
           duration: float, backend: str):
    """The lockstep model after ``duration`` s under the tick pattern (see the module)."""
    scene = load_scene(find_scene(scene_name))
    hyb = hybrid_lockstep(scene, backend=backend)
    n = int(round(duration / H))
    plan = CommandPlan.from_scene(scene, 1_000_000, n)
    engine = engine_from_spec(dict(scene_dict(scene)['engine']))
    rng = np.random.default_rng(seed)
    pedal = 0.0
    t_prev: float | None = None     # the engine's answer to the previous tick's state
    t_use = 0.0
    hold = 0
    k = 0
    while k < n and hyb.stall is None:
        ticks = 1
        while k + ticks < n and rng.random() < skip:
            ticks += 1
        late = int(rng.integers(0, cmd_lag + 1)) if cmd_lag else 0
        row: dict[str, float] = {}
        for j in range(max(k - ticks + 1 - late, 0), max(k - late, 0) + 1):
            row.update(plan.at(j))
        pedal = row.get('throttle', pedal)
        hyb.set_commands(clutch=row.get('clutch'), brake=row.get('brake'),
                         gear=None if 'gear' not in row else int(row['gear']))
        pos, vel, _eff = hyb.joint_states()
        engine.set_throttle(pedal * hyb.throttle_scale())
        t_k = engine.torque(k * H, vel[0], pos[0])
        if hold > 0:
            hold -= ticks
        elif burst > 0.0 and t_prev is not None and rng.random() < burst:
            hold = int(rng.integers(10, 100))
        elif t_prev is None or rng.random() >= lag:
            t_use = t_k
        else:
            t_use = t_prev
        if hold <= 0:
            t_prev = t_k
        hyb.advance((k + ticks) * H, t_use, 0.0)
        k += ticks
    return hyb


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--scene', default='launch_clutch')
    ap.add_argument('--lag', type=float, default=0.0)
    ap.add_argument('--skip', type=float, default=0.0)
    ap.add_argument('--burst', type=float, default=0.0)
    ap.add_argument('--cmd-lag', type=int, default=0)
    ap.add_argument('--seed', type=int, default=0)
    ap.add_argument('--duration', type=float, default=10.0)
    ap.add_argument('--backend', choices=('kernel', 'python'), default='kernel')
    a = ap.parse_args(argv)
    c0 = time.process_time()
    hyb = replay(a.scene, lag=a.lag, skip=a.skip, burst=a.burst, cmd_lag=a.cmd_lag, seed=a.seed,
                 duration=a.duration, backend=a.backend)
    print(f'{len(hyb.events)} mode events, gear {hyb.gear()}, modes {hyb.mode_names()}, '
          f'stall {hyb.stall or "-"}, CPU {time.process_time() - c0:.1f} s')
    print(dict(Counter((e.element, e.after) for e in hyb.events)))
    return 0


if __name__ == '__main__':
    sys.exit(main())
