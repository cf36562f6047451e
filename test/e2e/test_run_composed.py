"""Composed mode (cvj_ros.composed): one process, one executor, the same nodes, topics and bag
(with the in-process bus of cvj_ros.nodes.intra, the default, and without it).

Lockstep physics is deterministic (integer-ns stamps, the same compiled kernel, torques
exchanged as CDR doubles), so a scene run with one process per node and the same scene run
composed must give the same bag message for message: the same topics, counts, record stamps
and payload bytes on every loop topic. Only /diagnostics differs in content (the coupling
node's loop status carries wall-clock timings: real-time factor, microseconds per exchange),
so there the statuses are compared by name, level and message, and the count.

Known difference allowed (and stated in the assertion): in separate mode the peers' answer to
the final state t_N is not waited for by anyone and may be lost when the run stops the peer
processes (test_run.py, _check_bag_layout); composed mode drains it in-process.
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
import yaml

from cvj_ros import bag

pytestmark = pytest.mark.e2e

H = 1e-3
DURATION = 0.2
N = int(round(DURATION / H))
BIN = Path(sys.executable).parent
CVJ_SIM = str(BIN / 'cvj-sim')
# the console script once the package is (re)installed, else the module (same main())
COMPOSED = ([str(BIN / 'driveline_composed')] if (BIN / 'driveline_composed').exists()
            else [sys.executable, '-m', 'cvj_ros.composed'])

# Engine, elastic bushing, exact Hooke joint at 15 deg, seeded random load: every model the
# loop exchanges (the random load checks that both modes draw the same seeded sequence).
SCENE = {
    'name': 'e2e_composed', 'description': 'composed vs separate', 'seed': 5,
    'duration': 1.0, 'exchange_step': H,
    'solver': {'method': 'dopri5', 'rtol': 1e-9, 'atol': 1e-11},
    'engine': {'model': 'linear'},
    'load': {'model': 'random', 'mean': 107.5, 'amplitude': 8.8, 'sample_interval': 0.01},
    'initial': {'speed_rpm': 300.0},
    'driveline': [
        {'type': 'inertia', 'name': 'crank', 'J': 0.128},
        {'type': 'spring', 'name': 'bush', 'stiffness': 715.4, 'damping': 6.35},
        {'type': 'joint', 'name': 'cpl', 'kind': 'hooke', 'fidelity': 'exact', 'params': {'beta_deg': 15.0}},
        {'type': 'inertia', 'name': 'driven', 'J': 0.161},
    ],
}
LOOP_TOPICS = ('/clock', '/driveline/joint_states', '/driveline/scene', '/engine/wrench',
               '/load/wrench', '/coupling/cpl/wrench')
PEER_TOPICS = ('/engine/wrench', '/load/wrench')


def _cli(args: list[str], **kw) -> subprocess.CompletedProcess:
    return subprocess.run([CVJ_SIM, *args], capture_output=True, text=True, timeout=180, **kw)


def raw_messages(bag_path: Path) -> dict[str, list[tuple[int, bytes]]]:
    """Every message of a bag as (record stamp ns, canonical CDR bytes) per topic.

    Canonical = decoded and encoded again (rosbags): the same message gives the same bytes,
    every field bit for bit, while the trailing alignment padding that DDS may append to a
    sample (3 zero bytes after the /driveline/scene string between processes, none inside
    one) does not count. Frame ids are plain frame names (no run token), so nothing else
    is taken out."""
    from rosbags.rosbag2 import Reader
    store = bag.typestore()
    out: dict[str, list[tuple[int, bytes]]] = {}
    with Reader(bag_path) as reader:
        for conn, stamp, data in reader.messages():
            msg = store.deserialize_cdr(bytes(data), conn.msgtype)
            out.setdefault(conn.topic, []).append(
                (int(stamp), bytes(store.serialize_cdr(msg, conn.msgtype))))
    for msgs in out.values():
        msgs.sort()   # bag order of equal stamps follows arrival; compare as sorted lists
    return out


def diagnostics_summary(bag_path: Path) -> Counter:
    """(status name, level, message) counts of /diagnostics (values carry wall timings)."""
    diags = bag.read_bag(bag_path, ['/diagnostics'])['/diagnostics']
    return Counter((st['name'], int(st['level']), st['message'])
                   for statuses in diags.statuses for st in statuses)


def assert_same_bag(separate: Path, composed: Path) -> None:
    a, b = raw_messages(separate), raw_messages(composed)
    assert set(a) == set(b), (sorted(a), sorted(b))
    assert set(LOOP_TOPICS) <= set(a)
    for topic in LOOP_TOPICS:
        ma, mb = a[topic], b[topic]
        if topic in PEER_TOPICS and len(ma) == N and len(mb) == N + 1:
            mb = mb[:N]   # separate mode lost the unawaited answer to t_N (module docstring)
        assert len(ma) == len(mb), (topic, len(ma), len(mb))
        for i, (x, y) in enumerate(zip(ma, mb)):
            assert x == y, f'{topic} message {i}: separate {x[0]} ns {x[1].hex()} != composed {y[0]} ns {y[1].hex()}'
    assert len(a['/diagnostics']) == len(b['/diagnostics'])
    assert diagnostics_summary(separate) == diagnostics_summary(composed)


@pytest.fixture(scope='module')
def work(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp('e2e_composed')
    (d / 'scene.yaml').write_text(yaml.safe_dump(SCENE, sort_keys=False))
    return d


@pytest.fixture(scope='module')
def runs(work: Path) -> dict[str, tuple[subprocess.CompletedProcess, Path]]:
    out = {}
    for mode, extra in (('separate', []), ('composed', ['--composed']),
                        ('composed_dds', ['--composed', '--no-intra-process'])):
        r = _cli(['run', str(work / 'scene.yaml'), '--out', str(work / mode), '--duration', str(DURATION),
                  *extra])
        out[mode] = (r, work / mode / 'bag')
    return out


def test_composed_run_reports_one_process(runs) -> None:
    r, bag_path = runs['composed']
    assert r.returncode == 0, r.stdout + r.stderr
    assert 'loop running in one process' in r.stdout
    assert 'process composed, executor events' in r.stdout, r.stdout
    assert 'loop per exchange: wall ' in r.stdout and 'target' not in r.stdout   # bench's, not the run's
    assert 's of loop (first to last joint state recorded)' in r.stdout
    assert f'/driveline/joint_states {N + 1}' in r.stdout
    report = yaml.safe_load((bag_path.parent / 'report.json').read_text())
    assert report['settings']['process'] == 'composed' and report['real_time_factor'] > 0
    assert bag.bag_info(bag_path).custom_data['cvj_ros.process'] == 'composed'
    assert r.stderr == '', r.stderr     # node logs go to OUT/logs/ros, not the console


def test_separate_and_composed_bags_are_identical(runs) -> None:
    for mode in ('separate', 'composed'):
        assert runs[mode][0].returncode == 0, runs[mode][0].stdout + runs[mode][0].stderr
    assert_same_bag(runs['separate'][1], runs['composed'][1])
    # composed mode waits for the answers to t_N in-process: nothing lost
    counts = bag.bag_info(runs['composed'][1]).counts
    assert all(counts[t] == N + 1 for t in PEER_TOPICS), counts


def test_composed_without_the_in_process_bus_gives_the_same_bag(runs) -> None:
    """--no-intra-process: every message through DDS inside the process too (how composed
    mode ran before cvj_ros.nodes.intra); the same bag either way."""
    r, bag_path = runs['composed_dds']
    assert r.returncode == 0, r.stdout + r.stderr
    assert_same_bag(runs['separate'][1], bag_path)
    assert_same_bag(runs['composed'][1], bag_path)


def test_load_node_alone_against_composed_rest(runs, work: Path) -> None:
    """`cvj-sim run --composed --external load` hosts engine, monitor and coupling; a
    load_node process (as `ros2 run cvj_ros load_node` starts it) answers: the same bag."""
    env = dict(os.environ)
    load = subprocess.Popen([str(BIN / 'load_node'), '--ros-args', '-p', f'scene:={work / "scene.yaml"}'],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, env=env)
    try:
        r = _cli(['run', str(work / 'scene.yaml'), '--out', str(work / 'ext'), '--duration', str(DURATION),
                  '--composed', '--external', 'load', '--external-timeout', '60'])
    finally:
        load.send_signal(signal.SIGINT)
        log = load.communicate(timeout=30)[0].decode(errors='replace')
    assert r.returncode == 0, r.stdout + r.stderr + log
    assert load.returncode == 0, log
    assert_same_bag(runs['separate'][1], work / 'ext' / 'bag')


def test_driveline_composed_console_script(runs, work: Path) -> None:
    """The console script for a ROS install: global -p parameters reach every hosted node,
    --record writes the bag from inside the process; the same loop messages."""
    bag_dir = work / 'script_bag'
    r = subprocess.run([*COMPOSED, '--record', str(bag_dir), '--ros-args',
                        '-p', f'scene:={work / "scene.yaml"}', '-p', f'duration:={DURATION}',
                        '-p', 'min_subscribers:=4'],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stdout + r.stderr
    a, b = raw_messages(runs['separate'][1]), raw_messages(bag_dir)
    for topic in ('/driveline/joint_states', '/coupling/cpl/wrench', '/clock'):
        assert a[topic] == b[topic], topic


def test_driveline_composed_without_record_starts_with_its_default_peer_count(work: Path) -> None:
    """No --record and no min_subscribers: the hosted coupling node waits for engine, load and
    the hosted monitor only (not for the four subscribers a hand-started run has), and finishes."""
    r = subprocess.run([*COMPOSED, '--ros-args', '-p', f'scene:={work / "scene.yaml"}',
                        '-p', f'duration:={DURATION}'], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stdout + r.stderr
    assert 'waiting for peers (' not in r.stdout + r.stderr


def test_default_min_subscribers_counts_hosted_peers_unless_set(tmp_path: Path) -> None:
    import argparse

    from cvj_ros.composed import _default_min_subscribers
    opts = argparse.Namespace(without=[], record=None)
    assert _default_min_subscribers(['--ros-args', '-p', 'scene:=x'], opts) == \
        ['--ros-args', '-p', 'min_subscribers:=3']
    opts = argparse.Namespace(without=['monitor_node'], record=tmp_path / 'bag')
    assert _default_min_subscribers([], opts)[-1] == 'min_subscribers:=3'
    assert _default_min_subscribers(['--ros-args', '-p', 'min_subscribers:=5'], opts) is None
    params = tmp_path / 'p.yaml'
    params.write_text('/**:\n  ros__parameters:\n    min_subscribers: 2\n')
    assert _default_min_subscribers(['--ros-args', '--params-file', str(params)], opts) is None


def test_driveline_composed_bad_parameter_is_one_line() -> None:
    r = subprocess.run([*COMPOSED, '--ros-args', '-p', 'scene:=no_such_scene'],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 2, r.stdout + r.stderr
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert lines[-1].startswith('driveline_composed: error: engine_node: scene'), r.stderr
    assert 'Traceback' not in r.stderr


def test_composed_sigint_leaves_readable_bag(work: Path) -> None:
    out = work / 'sigint'
    p = subprocess.Popen([CVJ_SIM, 'run', str(work / 'scene.yaml'), '--out', str(out), '--duration', '60',
                          '--composed'], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 60
    line = ''
    while time.monotonic() < deadline and 'loop running' not in line:   # bounded wait, no sleep
        line = p.stdout.readline()
        if not line and p.poll() is not None:
            break
    assert 'loop running' in line, p.communicate()
    p.send_signal(signal.SIGINT)
    stdout, stderr = p.communicate(timeout=60)
    assert p.returncode == 130, stdout + stderr
    assert 'stopped by SIGINT' in stdout
    counts = bag.bag_info(out / 'bag').counts
    assert counts['/driveline/joint_states'] >= 1
    js = bag.read_bag(out / 'bag', ['/driveline/joint_states'])['/driveline/joint_states']
    assert js.t.size == counts['/driveline/joint_states']


def test_composed_free_run_accounts_every_tick(work: Path) -> None:
    """Free-run in composed mode (the engine and load answers come over the in-process bus,
    the coupling node steps on wall time): every tick is run or skipped, the recorded joint
    states are the run ticks plus the initial state, on the k h grid, and every recorded
    state was answered by both peers (the answers echo the state's stamp)."""
    out = work / 'free_run'
    h, duration = 0.005, 1.0
    n = int(round(duration / h))
    r = _cli(['run', str(work / 'scene.yaml'), '--out', str(out), '--duration', str(duration),
              '--exchange-step', str(h), '--mode', 'free-run', '--composed'])
    assert r.returncode == 0, r.stdout + r.stderr
    loop = loop_diagnostics(out / 'bag')
    run, skipped = int(float(loop['ticks_run'])), int(float(loop['ticks_skipped']))
    assert run + skipped == n, loop
    data = bag.read_bag(out / 'bag', ['/driveline/joint_states', *PEER_TOPICS])
    ks = np.rint(data['/driveline/joint_states'].t / h).astype(int)
    assert ks.size == run + 1 and ks[0] == 0 and ks[-1] == n
    np.testing.assert_allclose(data['/driveline/joint_states'].t, ks * h, rtol=0, atol=1e-12)
    for topic in PEER_TOPICS:        # each state answered once (the last one may be in flight)
        answered = np.rint(data[topic].t / h).astype(int)
        assert set(ks[:-1]) <= set(answered) <= set(ks), topic


def loop_diagnostics(bag_path: Path) -> dict[str, str]:
    """The coupling node's last 'coupling_node: loop' status values."""
    diags = bag.read_bag(bag_path, ['/diagnostics'])['/diagnostics']
    for statuses in reversed(diags.statuses):
        for st in statuses:
            if st['name'] == 'coupling_node: loop' and 'ticks_run' in st['values']:
                return st['values']
    raise AssertionError('no coupling_node loop status with free-run counters in the bag')
