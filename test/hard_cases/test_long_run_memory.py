"""Memory stays flat over a long kernel run: the 6000 rpm rigid Hooke study of
``scripts/long_run_kernel.py`` (dop853 at 1e-10, 200 samples) for 1e3 and then 1e5
revolutions (2.04e7 f-evals) in one fresh interpreter. The persistent stepper keeps its
state in fixed arrays and the trace holds only the samples, so the second, 100x longer run
must not raise the process's peak RSS. Measured (docs/benchmark.md, "Peak memory"): 1 and
1e5 revolutions 141.3 / 141.5 MiB in separate processes, 145.0 MiB after both runs in one;
the bound, 4 MiB, is 20x the first difference, while anything kept per step (~1.7e6
dop853 steps, 16 bytes or more each) would add tens of MiB."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
_CODE = '''
import importlib.util, sys
spec = importlib.util.spec_from_file_location('lrk', sys.argv[1])
lrk = importlib.util.module_from_spec(spec); spec.loader.exec_module(lrk)
sim = lrk.simulation()
short = lrk.run(sim, 1e3)
rss_short = lrk.peak_rss_mib()
long = lrk.run(lrk.simulation(), 1e5)
print(rss_short, lrk.peak_rss_mib(), long.solver['nfev'], long.max_energy_residual)
'''


@pytest.mark.slow
def test_peak_rss_flat_over_1e5_revolutions():
    env = {**os.environ, 'PYTHONPATH': str(ROOT)}
    out = subprocess.run([sys.executable, '-c', _CODE, str(ROOT / 'scripts' / 'long_run_kernel.py')],
                         capture_output=True, text=True, env=env, timeout=1800, check=True)
    rss_short, rss_long, nfev, res = out.stdout.split()[-4:]
    print(f'peak RSS after 1e3 revolutions {float(rss_short):.1f} MiB, after 1e5 '
          f'{float(rss_long):.1f} MiB ({int(nfev)} f-evals, energy residual {float(res):.1e})')
    assert int(nfev) > 1e7            # the long run did integrate 1e5 revolutions
    assert float(rss_long) - float(rss_short) < 4.0
