"""Start-up regression guard of `cvj-sim simulate` (issue 9 item 3: warm start <= 1.5 s).

Nothing here is timed (timing on a shared machine is noise); what made the warm start
slow is asserted absent instead, in a fresh interpreter after a warm-up run:

* modules the command does not need: scipy's submodules (numba's BLAS probe pulled in
  ``scipy.linalg``, ~0.3 s; the bare ``scipy`` package is numba's own version check at
  import and stays), matplotlib, rclpy, rosbags, the other subcommands;
* numba's full target initialisation (``CPUContext.refresh``, ~0.55 s measured): its
  first import is ``numba.np.arraymath``'s module, absent when the cached entry points
  were loaded by ``kernel.load_cached``;
* compiled entry points of other methods: exactly the chosen method's whole run
  (kernel/run_nb.py: integration and sample outputs in one call) and the intermediate
  members' fill are loaded;
* for rosenbrock and dop853 too: their coefficients come from physics/tableaux.py, not
  from solvers.py / scipy.integrate.
The numbers are in docs/solvers.md "Start-up".
"""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from cvj_ros.cli import command_named, main

PROBE = r'''
import json, sys
from cvj_ros.cli import main
rc = main(sys.argv[2:])
from numba.core.registry import CPUDispatcher
from cvj_ros.physics.kernel import outputs_nb, run_nb, steppers_nb
loaded = sorted(f'{m.__name__.rsplit(".", 1)[-1]}.{n}' for m in (steppers_nb, outputs_nb, run_nb)
                for n, f in vars(m).items()
                if isinstance(f, CPUDispatcher) and f.py_func.__module__ == m.__name__
                and f.overloads)
with open(sys.argv[1], 'w') as fh:
    json.dump({'rc': rc, 'modules': sorted(sys.modules), 'loaded': loaded}, fh)
'''

NOT_NEEDED = ('scipy.linalg', 'scipy.integrate', 'scipy.interpolate', 'scipy.signal',
              'scipy.optimize', 'matplotlib', 'rclpy', 'rosbags', 'cvj_ros.physics.solvers',
              'numba.np.arraymath', 'numba.np.linalg')


def _probe(tmp_path: Path, args: list[str]) -> dict:
    out = tmp_path / 'probe.json'
    proc = subprocess.run([sys.executable, '-c', PROBE, str(out), *args], capture_output=True,
                          text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    assert 'compiled the kernel' not in proc.stderr   # warm cache: loaded, not compiled
    return json.loads(out.read_text())


@pytest.mark.parametrize('method, stepper', [('dopri5', 'run_nb.dopri5_run'),
                                             ('rk4', 'run_nb.rk4_run'),
                                             ('rosenbrock', 'run_nb.ros_run'),
                                             ('dop853', 'run_nb.dop853_run')])
def test_warm_simulate_imports_and_loads_only_what_it_needs(tmp_path: Path, capsys,
                                                            method: str, stepper: str) -> None:
    args = ['simulate', 'kavz685_lever', '--duration', '0.05', '--method', method]
    assert main(args) == 0     # warm-up: compiles into the disk cache if it is cold
    capsys.readouterr()
    got = _probe(tmp_path, args)
    assert got['rc'] == 0
    mods = set(got['modules'])
    heavy = sorted(m for m in mods if m.split('.')[0] in ('matplotlib', 'rclpy', 'rosbags')
                   or any(m == n or m.startswith(n + '.') for n in NOT_NEEDED))
    assert heavy == []
    assert sorted(m for m in mods if m.startswith('cvj_ros.commands.')) == [
        'cvj_ros.commands.simulate']
    # one compiled call runs it (kernel/run_nb.py: integration and outputs, the lever
    # hinge's earring - an intermediate member - filled inside that call too)
    assert got['loaded'] == [stepper]


def test_fast_load_is_off_with_cvj_kernel_load_numba(tmp_path: Path, monkeypatch) -> None:
    """``CVJ_KERNEL_LOAD=numba`` restores numba's own load (full target initialisation):
    the switch the byte comparison in test_backends.py uses."""
    monkeypatch.setenv('CVJ_KERNEL_LOAD', 'numba')
    got = _probe(tmp_path, ['simulate', 'kavz685_lever', '--duration', '0.05'])
    assert 'numba.np.arraymath' in got['modules']
    assert got['loaded'] == ['run_nb.dopri5_run']


def test_command_named_picks_the_subcommand_or_none() -> None:
    assert command_named(['simulate', 'x']) == 'simulate'
    assert command_named(['--debug', 'run', 'x']) == 'run'
    assert command_named(['--help']) is None
    assert command_named(['simulatee']) is None
    assert command_named([]) is None


def test_help_and_unknown_command_still_list_every_subcommand(capsys) -> None:
    with pytest.raises(SystemExit):
        main(['--help'])
    out = capsys.readouterr().out
    for name in ('kinematics', 'simulate', 'run', 'analyze', 'bench', 'sweep'):
        assert name in out
    with pytest.raises(SystemExit) as exc:
        main(['simulat'])
    assert exc.value.code == 2
    assert 'simulate' in capsys.readouterr().err   # argparse's "invalid choice" lists them


def test_program_run_ends_without_teardown_but_with_all_output(tmp_path: Path, capsys) -> None:
    """As a program, `cvj-sim simulate` leaves through cli.exit_without_teardown: the JSON
    summary on stdout (block-buffered into a pipe) and the CSV must still be complete and
    equal to the in-process run's; a user error keeps exit status 2."""
    here = tmp_path / 'here.csv'
    assert main(['simulate', 'kavz685_lever', '--duration', '0.05', '--json',
                 '--csv', str(here)]) == 0
    want = json.loads(capsys.readouterr().out)
    there = tmp_path / 'there.csv'
    proc = subprocess.run([sys.executable, '-m', 'cvj_ros.cli', 'simulate', 'kavz685_lever',
                           '--duration', '0.05', '--json', '--csv', str(there)],
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    got = json.loads(proc.stdout)
    assert got['shafts'] == want['shafts'] and got['solver']['nfev'] == want['solver']['nfev']
    assert there.read_bytes() == here.read_bytes()
    bad = subprocess.run([sys.executable, '-m', 'cvj_ros.cli', 'simulate', 'no_such_scene'],
                         capture_output=True, text=True, timeout=600)
    assert bad.returncode == 2 and bad.stderr.startswith('cvj-sim: error: scene:')
