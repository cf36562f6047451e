"""The pool's fork server preload (cvj_ros/sweep/preload.py) in a fresh interpreter: numba
loads without importing coverage, and the entry points a batched worker uses are kept."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]

PROBE = '''
import sys
import cvj_ros.sweep.preload
from cvj_ros.physics.kernel import _ENTRIES
from cvj_ros.physics.kernel.outputs_nb import fill_mid_samples
from cvj_ros.sweep.reduce import _ENTRY
print(repr(sys.modules.get('coverage', 'absent')), 'numba' in sys.modules,
      fill_mid_samples in _ENTRIES, sorted(_ENTRY))
'''


def _probe(**env: str) -> str:
    clean = {k: v for k, v in os.environ.items()
             if not k.startswith(('COV_CORE', 'COVERAGE_'))}
    out = subprocess.run([sys.executable, '-c', PROBE], env=dict(clean, PYTHONPATH=str(REPO),
                                                                  **env),
                         capture_output=True, text=True, timeout=300, check=True)
    return out.stdout.strip()


def test_preload_loads_the_kernel_without_coverage() -> None:
    """numba imports coverage only to report lines it compiles to a running coverage; the
    server has none, so the import (~0.03-0.04 s) is left out; the members' fill and the
    reduction's entry points are loaded for the workers."""
    assert _probe() == ("None True True ['gradient_table', 'reduce_lean', 'steady_start', "
                        "'window_metrics']")


def test_preload_leaves_a_requested_coverage_alone() -> None:
    """With COVERAGE_PROCESS_START set (subprocess coverage asked for) coverage stays
    importable: numba then imports it as usual."""
    out = _probe(COVERAGE_PROCESS_START=str(REPO / 'no-such-coveragerc'))
    assert out.startswith("<module 'coverage'")
