"""Sweep execution: metrics against a closed form, rows equal to a direct Simulation, bad
variants (skip / stop), one-line CLI errors, bytes equal across worker counts, resume, and
Ctrl-C keeping finished variants."""
from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from cvj_ros.cli import main
from cvj_ros.commands.sweep import load_scene_data
from cvj_ros.physics.joints.hooke import hooke_ratio
from cvj_ros.physics.scene import find_scene, parse_scene
from cvj_ros.physics.simulate import Simulation
from cvj_ros.sweep.results import ROWS, read_results
from cvj_ros.sweep.run import RunOptions, SerialExecutor, execute, metrics_row, order_amplitudes
from cvj_ros.sweep.spec import build_sweep

REPO = Path(__file__).resolve().parents[2]
# kavz685_lever shortened to 0.5 s: the sweep machinery, not the physics, is under test
LEVER_SETS = ['duration=0.5', 'driveline[coupling].params.alpha_deg=10:30:3',
              'driveline[bushings].stiffness=500,900']


def sweep_cli(*args: str) -> int:
    return main(['sweep', *args, '--no-plots'])


def test_hooke_sweep_against_closed_form(tmp_path: Path) -> None:
    """Rigid Hooke joint driven at constant speed (input inertia 1e9 kg m^2, engine torque
    m1 - k1 w = 0 at w0): the output speed ratio is cos b / (1 - sin^2 b cos^2 phi)
    (hooke.py, seed 002 eq. 10), between cos b and 1/cos b. w0 puts 20 samples of 1 ms on
    every quarter turn, so the samples hit both extremes and delta = (1/cos b - cos b) /
    mean over the same samples. dop853 at rtol 1e-10: measured deviation 1.2e-11 at
    b = 10..40 deg; the bound 1e-8 leaves a margin of 800."""
    w0 = math.pi / 2 / (20 * 1e-3)
    base = {'name': 'hooke_cf', 'duration': 1.6, 'exchange_step': 1e-3,
            'solver': {'method': 'dop853', 'rtol': 1e-10, 'atol': 1e-12},
            'engine': {'model': 'linear', 'm1': w0, 'k1': 1.0},
            'load': {'model': 'constant', 'torque': 0.0}, 'initial': {'speed_rad_s': w0},
            'driveline': [{'type': 'inertia', 'name': 'big', 'J': 1e9},
                          {'type': 'joint', 'name': 'h', 'kind': 'hooke',
                           'params': {'beta_deg': 10.0}},
                          {'type': 'inertia', 'name': 'out', 'J': 0.01}]}
    sweep = build_sweep(base, ['driveline[h].params.beta_deg=10:40:4'])
    report = execute(sweep, RunOptions(), tmp_path, executor=SerialExecutor())
    assert report.counts['ok'] == 4 and report.complete
    header, rows = read_results(tmp_path / 'results.csv')
    assert header[:3] == ['variant', 'driveline[h].params.beta_deg', 'status']
    t = np.arange(1601) * 1e-3
    # steady window (physics/steady.py): each 0.16 s slice holds 4 whole periods (pi/w0 =
    # 0.04 s) of the 2nd-order ratio, so every slice agrees with the last: the whole record
    window = t
    for row in rows:
        b = math.radians(float(row['driveline[h].params.beta_deg']))
        mean_ratio = float(np.mean(hooke_ratio(w0 * window, b)))
        assert float(row['out.delta']) == pytest.approx((1 / math.cos(b) - math.cos(b)) / mean_ratio,
                                                        rel=1e-8)
        assert float(row['out.mean_speed']) == pytest.approx(w0 * mean_ratio, rel=1e-8)
        assert float(row['big.delta']) < 1e-10    # the input turns uniformly


def test_rows_equal_a_direct_simulation(tmp_path: Path) -> None:
    """Each row is what Simulation(...).summary() gives for that variant (dense sampling),
    and the CSV text reads back to the same doubles (repr)."""
    assert sweep_cli('kavz685_lever', '--set', LEVER_SETS[0], '--set', LEVER_SETS[1],
                     '--out', str(tmp_path), '--workers', '1') == 0
    _, rows = read_results(tmp_path / 'results.csv')
    assert len(rows) == 3
    base = load_scene_data(find_scene('kavz685_lever'))
    for row, alpha in zip(rows, (10.0, 20.0, 30.0)):
        d = json.loads(json.dumps(base))
        d['duration'] = 0.5
        d['driveline'][2]['params']['alpha_deg'] = alpha
        sim = Simulation(parse_scene(d))
        sim.run(sampling='dense')
        expected = metrics_row(sim.summary())
        expected.update(order_amplitudes(sim.last_trace, 4, None))    # finds the window anew
        assert set(expected) | {'variant', 'status', 'error', LEVER_SETS[0].split('=')[0],
                                LEVER_SETS[1].split('=')[0]} == set(row)
        for key, value in expected.items():
            text = row[key]
            got = (text == 'true') if isinstance(value, bool) else \
                float(text) if isinstance(value, float) else type(value)(text)
            assert got == value, key


def test_bad_variant_skipped_or_stopping(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    args = ['kavz685_lever', '--set', 'duration=0.2', '--set',
            'driveline[coupling].params.alpha_deg=20,95', '--workers', '1']
    assert sweep_cli(*args, '--out', str(tmp_path / 'skip')) == 0
    out = capsys.readouterr().out
    assert '1 ok, 1 invalid' in out
    assert ('first bad variant: variant 1 (driveline[coupling].params.alpha_deg=95): '
            'driveline[2].params.alpha_deg: must be < 90 deg, got 95 deg') in out
    _, rows = read_results(tmp_path / 'skip' / 'results.csv')
    assert [r['status'] for r in rows] == ['ok', 'invalid']
    assert rows[1]['error'].startswith('driveline[2].params.alpha_deg: must be < 90 deg')
    assert rows[1]['drive_shaft.delta'] == ''
    assert sweep_cli(*args, '--out', str(tmp_path / 'stop'), '--on-error', 'stop') == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1] == ('cvj-sim: error: variant 1 (driveline[coupling].params.alpha_deg=95): '
                       'driveline[2].params.alpha_deg: must be < 90 deg, got 95 deg '
                       '(--on-error stop: nothing was run)')
    assert not (tmp_path / 'stop' / ROWS).exists()


@pytest.mark.parametrize('args, line', [
    (['--set', 'driveline[shaft].J=1'],
     "cvj-sim: error: --set driveline[shaft].J: driveline has no element named 'shaft' "
     "(drive_shaft, bushings, coupling, driven_shaft)"),
    (['--set', 'driveline[coupling].params.alpha_deg=5:25'],
     'cvj-sim: error: --set driveline[coupling].params.alpha_deg: a range lo:hi needs --samples N '
     '(random sampling); for a grid give start:stop:n'),
    (['--set', 'engine.m2=1,2'], 'cvj-sim: error: --set engine.m2: engine.m2: unknown key'),
    (['--set', 'engine.m1=1', '--samples', '-3'], 'cvj-sim: error: --samples: must be an integer'),
    (['--set', 'engine.m1=1', '--workers', '0'], 'cvj-sim: error: --workers: must be >= 1, got 0'),
    (['--set', 'engine.m1=1', '--cluster', 'nonsense'],
     'cvj-sim: error: --cluster nonsense: not a scheduler address, e.g. tcp://host:8786'),
    (['--set', 'engine.m1=1', '--orders', '-1'], 'cvj-sim: error: --orders: must be in 0..64'),
    (['--set', 'engine.m1=1', '--orders-shaft', 'crank'],
     'cvj-sim: error: --orders-shaft crank: no such shaft in kavz685_lever; shafts: drive_shaft, '),
])
def test_cli_errors_are_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                 args: list[str], line: str) -> None:
    assert sweep_cli('kavz685_lever', *args, '--out', str(tmp_path)) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(line), err
    assert 'Traceback' not in err[0]


def test_different_sweep_in_out_dir_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert sweep_cli('kavz685_lever', '--set', 'duration=0.1', '--out', str(tmp_path), '--workers', '1') == 0
    assert sweep_cli('kavz685_lever', '--set', 'duration=0.2', '--out', str(tmp_path), '--workers', '1') == 2
    assert 'holds a different sweep' in capsys.readouterr().err
    assert sweep_cli('kavz685_lever', '--set', 'duration=0.2', '--out', str(tmp_path), '--workers', '1',
                     '--fresh') == 0


@pytest.fixture(scope='module')
def serial_reference(tmp_path_factory: pytest.TempPathFactory) -> bytes:
    out = tmp_path_factory.mktemp('serial')
    args = [x for s in LEVER_SETS for x in ('--set', s)]
    assert sweep_cli('kavz685_lever', *args, '--out', str(out), '--workers', '1') == 0
    return (out / 'results.csv').read_bytes()


def test_same_bytes_with_two_workers_and_after_resume(tmp_path: Path, serial_reference: bytes,
                                                      capsys: pytest.CaptureFixture[str]) -> None:
    args = ['kavz685_lever', *[x for s in LEVER_SETS for x in ('--set', s)], '--out', str(tmp_path)]
    assert sweep_cli(*args, '--workers', '2') == 0
    assert (tmp_path / 'results.csv').read_bytes() == serial_reference
    timing = (tmp_path / 'timing.csv').read_text().splitlines()
    assert timing[0] == 'variant,wall_s' and len(timing) == 7
    # an interrupted sweep: keep 2 of 6 finished rows and a line cut short by a kill
    lines = (tmp_path / ROWS).read_text().splitlines(keepends=True)
    (tmp_path / ROWS).write_text(''.join(lines[:2]) + lines[2][:25])
    capsys.readouterr()
    assert sweep_cli(*args, '--workers', '1') == 0
    out = capsys.readouterr().out
    assert '6 ok, 0 invalid, 0 failed; 2 already done (resumed)' in out
    assert 'ran 4 in' in out
    assert (tmp_path / 'results.csv').read_bytes() == serial_reference
    manifest = json.loads((tmp_path / 'sweep.json').read_text())
    assert [r['variants_run'] for r in manifest['runs']] == [6, 4] and manifest['complete']
    assert manifest['definition']['sets'] == LEVER_SETS
    assert manifest['versions']['numba'] and manifest['definition']['scene']['sha256']


def test_ctrl_c_keeps_finished_variants_and_rerun_completes(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """SIGINT to `cvj-sim sweep --workers 2` once the first rows are on disk: exit 130, one
    line, the finished rows in results.csv; the same command again runs only the rest. The
    Python backend (~0.1-0.5 s a variant here) keeps the sweep running when SIGINT comes.
    Wall 5.7 s at load average 2, 24 s at load 11 (2.3 s CPU): not marked slow.

    The sweep is started with SIGINT at its default disposition, as from a terminal: a shell
    that starts a job in the background without job control (``cmd &`` in a script) hands
    it SIGINT ignored, and Python then installs no KeyboardInterrupt handler - how a
    fresh-clone CI launched that way saw exit 0 here."""
    env = dict(os.environ, PYTHONPATH=str(REPO))
    args = ['sweep', 'kavz685_lever', '--set', 'duration=0.2', '--set',
            'driveline[bushings].stiffness=400:1200:8', '--backend', 'python',
            '--out', str(tmp_path), '--no-plots']
    t0 = time.monotonic()
    proc = subprocess.Popen([sys.executable, '-m', 'cvj_ros.cli', *args, '--workers', '2'], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    rows = tmp_path / ROWS
    deadline = time.monotonic() + 90.0        # start-up: ~2-10 s on a shared machine
    while time.monotonic() < deadline and proc.poll() is None:
        if rows.is_file() and rows.stat().st_size > 0:
            break
        time.sleep(0.02)
    assert proc.poll() is None, proc.communicate()
    t_rows = time.monotonic() - t0
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, (f'first rows on disk after {t_rows:.2f} s, exit '
                                    f'{proc.returncode} after {time.monotonic() - t0:.2f} s: {err}')
    assert 'Traceback' not in err
    assert 'cvj-sim sweep: interrupted;' in err and 'rerun the same command to resume' in err
    _, partial = read_results(tmp_path / 'results.csv')
    assert 0 < len(partial) < 8
    capsys.readouterr()
    assert main([*args, '--workers', '1']) == 0
    assert f'8 ok, 0 invalid, 0 failed; {len(partial)} already done (resumed)' in capsys.readouterr().out
    _, full = read_results(tmp_path / 'results.csv')
    assert [int(r['variant']) for r in full] == list(range(8))
    by_variant = {r['variant']: r for r in full}
    assert all(by_variant[r['variant']] == r for r in partial)


def test_killed_worker_is_one_line_and_keeps_finished_rows(tmp_path: Path, process_table) -> None:
    """SIGKILL to a pool worker once rows are on disk: one error line (exit 2) and the
    finished rows kept in results.csv (resume itself: the tests above)."""
    env = dict(os.environ, PYTHONPATH=str(REPO))
    # 256 variants (chunks of 8 with 2 workers): work is left when the first rows land, also
    # on a loaded machine (CI once found the pool already gone with 16 one-variant chunks)
    args = ['sweep', 'kavz685_lever', '--set', 'duration=0.2', '--set',
            'driveline[bushings].stiffness=400:1200:256', '--backend', 'python',
            '--out', str(tmp_path), '--no-plots', '--workers', '2']
    proc = subprocess.Popen([sys.executable, '-m', 'cvj_ros.cli', *args], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    rows = tmp_path / ROWS
    deadline = time.monotonic() + 90.0
    workers: list[int] = []
    out = ''
    while time.monotonic() < deadline and proc.poll() is None and not workers:
        time.sleep(0.05)
        if not (rows.is_file() and rows.stat().st_size > 0):
            continue
        # the pool workers: children of the sweep's fork server, read from /proc (`ps` cuts
        # its args column at $COLUMNS: with a longer checkout path CI never saw 'forkserver')
        table = process_table()
        server = [p for p, (pp, cmd) in table.items() if pp == proc.pid and 'forkserver' in cmd]
        workers = [p for p, (pp, _) in table.items() if server and pp == server[0]]
        out = repr(table)
    assert proc.poll() is None, proc.communicate()
    assert workers, out
    os.kill(workers[0], signal.SIGKILL)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 2, err
    assert err.strip().splitlines()[-1].startswith('cvj-sim: error: --workers: a worker process died')
    assert 'Traceback' not in err
    _, partial = read_results(tmp_path / 'results.csv')
    assert 0 < len(partial) < 256


def _session_processes(sid: int) -> list[str]:
    """Command lines of the processes of session ``sid`` that are not ending: not a zombie,
    not one whose command line is gone already (it is exiting), not the multiprocessing
    resource tracker (it ends by itself once its parent's pipe closes, a moment after the
    parent)."""
    live = []
    for d in os.listdir('/proc'):
        if not d.isdigit():
            continue
        try:
            stat = Path(f'/proc/{d}/stat').read_text()
            cmd = Path(f'/proc/{d}/cmdline').read_bytes().replace(b'\0', b' ').decode()
        except OSError:
            continue
        fields = stat.rsplit(')', 1)[1].split()     # state, ppid, pgrp, session, ...
        if int(fields[3]) == sid and fields[0] != 'Z' and cmd \
                and 'resource_tracker' not in cmd:
            live.append(f'{d} {fields[0]} {cmd[:120]}')
    return live


@pytest.mark.skipif(not Path('/proc/self/stat').is_file(), reason='reads /proc')
def test_mistyped_scene_leaves_no_fork_server_behind(tmp_path: Path) -> None:
    """`cvj-sim sweep kavz685_levr --workers 2`: one line, exit 2, and no process of its
    session still running once it has exited (the pool's fork server, started before the
    scene is read, was loading the kernel for ~0.5 s after the command's exit)."""
    env = dict(os.environ, PYTHONPATH=str(REPO))
    # output to files, not pipes: the server inherits them, and reading a pipe to its end
    # would wait for the server too
    with open(tmp_path / 'err', 'w') as f:
        proc = subprocess.Popen(
            [sys.executable, '-m', 'cvj_ros.cli', 'sweep', 'kavz685_levr', '--set',
             'driveline[bushings].stiffness=300,400', '--workers', '2', '--no-plots', '--out',
             str(tmp_path / 'out')], env=env, start_new_session=True,
            stdout=subprocess.DEVNULL, stderr=f)
        proc.wait(timeout=120)
    left = _session_processes(proc.pid)
    err = (tmp_path / 'err').read_text()
    assert proc.returncode == 2 and 'Traceback' not in err
    assert "no scene file or shipped scene 'kavz685_levr'" in err
    assert left == []


@pytest.mark.skipif(not Path('/proc/self/stat').is_file(), reason='reads /proc')
def test_fork_server_ends_with_the_process_that_started_it(tmp_path: Path) -> None:
    """A process that starts the fork server and exits at once (the server's preload takes
    ~0.4 s CPU, so it is still loading then): no process of its session runs on. Before,
    the server ran its preload to the end after its parent had gone (the command test
    above catches that only when the command ends while the server still loads)."""
    env = dict(os.environ, PYTHONPATH=str(REPO))
    with open(tmp_path / 'err', 'w') as f:    # a file: the server inherits it (see above)
        proc = subprocess.Popen(
            [sys.executable, '-c', 'from cvj_ros.sweep.server import start_fork_server; '
                                   'start_fork_server(); raise SystemExit(2)'],
            env=env, start_new_session=True, stdout=subprocess.DEVNULL, stderr=f)
        proc.wait(timeout=120)
    left = _session_processes(proc.pid)
    assert proc.returncode == 2 and (tmp_path / 'err').read_text() == ''
    assert left == []



def test_a_fork_server_that_served_is_left_to_end_by_itself(tmp_path: Path) -> None:
    """After a sweep on the pool (the server forked its workers, so its preload is done)
    exit does not stop and wait for the server: it ends by itself once this process's pipe
    closes, as before. stop_fork_server leaves it running then, and stops one that has
    not served."""
    env = dict(os.environ, PYTHONPATH=str(REPO))
    code = ('import os\n'
            'from multiprocessing import forkserver\n'
            'from cvj_ros.commands.sweep import load_scene_data\n'
            'from cvj_ros.physics.scene import find_scene\n'
            'from cvj_ros.sweep import server\n'
            'from cvj_ros.sweep.run import Job, ProcessExecutor, RunOptions\n'
            'from cvj_ros.sweep.spec import build_sweep\n'
            'if __name__ == "__main__":\n'
            '    sw = build_sweep(load_scene_data(find_scene("kavz685_lever")),\n'
            '                     ["duration=0.05", "driveline[bushings].stiffness=500,900"])\n'
            '    job = Job(base=sw.base, keys=tuple(a.keys for a in sw.axes),\n'
            '              options=RunOptions())\n'
            '    ex = ProcessExecutor(2)\n'
            '    before = server._SERVED\n'
            '    rows = [o.row["status"] for c in ex.map(job, [list(enumerate(sw.variants))])\n'
            '            for o in c]\n'
            '    ex.close()\n'
            '    pid = forkserver._forkserver._forkserver_pid\n'
            '    server.stop_fork_server()\n'
            '    print(before, rows, server._SERVED, os.waitpid(pid, os.WNOHANG) == (0, 0))\n'
            '    server._SERVED = False\n'
            '    server.stop_fork_server()\n'
            '    print(forkserver._forkserver._forkserver_pid)\n')
    script = tmp_path / 'served.py'
    script.write_text(code)
    out = subprocess.run([sys.executable, str(script)], env=env, capture_output=True,
                         text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ['False', "['ok',", "'ok']", 'True', 'True', 'None']
