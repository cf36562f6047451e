"""End to end: a free run's bag starts at t = 0, also when its first exchange is slow.

`cvj-sim run --mode free-run`, separate processes and `--composed`, on a two-mass scene at
h = 5 ms, with the coupling node's first exchange made SLOW s slower than the others (a
``sitecustomize`` on the run's PYTHONPATH, test-only: the first ``CoupledStepper.advance``
of the process that runs the coupling node sleeps; a mode scene's compiled code loaded on
first use cost 0.31-0.74 s there). Before the free-run clock started after the first
exchange, that cost made the next wake-up skip every tick up to wall time: the bag held
t_0, t_1 and then nothing until about SLOW s.

Checked against the bag and the report (what the design guarantees, on a busy machine
too): the joint states, /clock and both answers are recorded at t_0 and t_1 (the clock
starts once state 0 is answered and the first exchange ran); no gap between recorded
states reaches SLOW (only a stall of the run as long as the injected cost would make one);
the joint states missing from the bag are the ticks the node reports skipped, and the
report's gaps line says so whenever it skipped any.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from cvj_ros import bag

pytestmark = [pytest.mark.e2e, pytest.mark.ros]

BIN = Path(sys.executable).parent
H = 0.005                       # s, exchange step
DURATION = 1.0                  # s simulated
N = int(round(DURATION / H))
SLOW = 0.5                      # s, injected extra cost of the coupling node's first exchange
SCENE = {
    'name': 'free_run_start', 'seed': 3, 'duration': DURATION, 'exchange_step': H,
    'solver': {'method': 'dopri5', 'rtol': 1e-8, 'atol': 1e-10},
    'engine': {'model': 'linear', 'm1': 623.0, 'k1': 13.2},
    'load': {'model': 'constant', 'torque': 107.5},
    'initial': {'speed_rad_s': (623.0 - 107.5) / 13.2},
    'driveline': [{'type': 'inertia', 'name': 'crank', 'J': 0.128},
                  {'type': 'spring', 'name': 'shaft', 'stiffness': 715.4, 'damping': 6.35},
                  {'type': 'inertia', 'name': 'wheel', 'J': 0.161}],
}
# imported at start-up by every Python process of the run (PYTHONPATH); acts only in the
# process that runs the coupling node, at its first exchange step
SITECUSTOMIZE = '''
import os, sys, time
if os.environ.get('CVJ_TEST_SLOW_FIRST_STEP'):
    from cvj_ros.physics import cosim
    _advance = cosim.CoupledStepper.advance
    _calls = []

    def advance(self, *args, **kwargs):
        if not _calls and 'cvj_ros.nodes.coupling_node' in sys.modules:
            _calls.append(1)
            time.sleep(float(os.environ['CVJ_TEST_SLOW_FIRST_STEP']))
            with open(os.environ['CVJ_TEST_SLOW_MARK'], 'a') as fh:
                fh.write(f'{os.getpid()}\\n')
        return _advance(self, *args, **kwargs)
    cosim.CoupledStepper.advance = advance
'''


@pytest.mark.parametrize('layout', ['separate', 'composed'])
def test_free_run_bag_starts_at_zero_after_a_slow_first_exchange(tmp_path: Path, layout: str) -> None:
    (tmp_path / 'scene.yaml').write_text(yaml.safe_dump(SCENE, sort_keys=False))
    site = tmp_path / 'site'
    site.mkdir()
    (site / 'sitecustomize.py').write_text(SITECUSTOMIZE)
    mark = tmp_path / 'slow_mark'
    env = dict(os.environ, CVJ_TEST_SLOW_FIRST_STEP=str(SLOW), CVJ_TEST_SLOW_MARK=str(mark),
               PYTHONPATH=os.pathsep.join([str(site), *filter(None, [os.environ.get('PYTHONPATH')])]))
    out = tmp_path / 'run'
    r = subprocess.run([str(BIN / 'cvj-sim'), 'run', str(tmp_path / 'scene.yaml'), '--out', str(out),
                        '--mode', 'free-run', *(['--composed'] if layout == 'composed' else [])],
                       capture_output=True, text=True, timeout=300, env=env)
    assert r.returncode == 0, r.stdout + r.stderr
    assert len(mark.read_text().split()) == 1          # the first exchange was made slow, once
    h_ns = int(round(H * 1e9))
    data = bag.read_bag(out / 'bag', ['/driveline/joint_states', '/clock', '/engine/wrench', '/load/wrench'])
    stamps = {topic: np.rint(s.t * 1e9).astype(np.int64) for topic, s in data.items()}
    for topic, st in stamps.items():
        assert list(st[:2]) == [0, h_ns], topic
    js = stamps['/driveline/joint_states']
    assert js[-1] == N * h_ns
    assert int(np.max(np.diff(js))) < SLOW * 1e9
    report = json.loads((out / 'report.json').read_text())
    skipped = report['metrics']['free_run']['ticks_skipped']
    assert js.size == N + 1 - skipped                  # missing states = ticks skipped
    gaps = report['metrics']['gaps']['topics']
    assert gaps.get('/driveline/joint_states', {'missing': 0})['missing'] == skipped
    if skipped:
        assert f'{skipped} tick{"s" if skipped != 1 else ""} skipped by free-run catch-up' in r.stdout, r.stdout
