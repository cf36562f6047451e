"""Bad input end to end through the real `cvj-sim` CLI (DESIGN.md section 9).

Each case: exactly one stderr line ``cvj-sim: error: <field or topic>: <problem>``, a
non-zero exit status (2 = user error), no traceback, nothing on stdout and no run started
(no bag written). Scenes are checked through ``cvj-sim run`` (validation happens before
any process starts) and ``cvj-sim simulate``; bags through ``cvj-sim analyze``, ``replay``
and ``run --load-from-bag``. Most cases call :func:`cvj_ros.cli.main` in-process (fast); a few run
the installed ``cvj-sim`` executable to cover the real entry point.
"""
from __future__ import annotations

import copy
import re
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from cvj_ros import bag as bagmod
from cvj_ros.cli import main as cli_main

CVJ_SIM = str(Path(sys.executable).with_name('cvj-sim'))

VALID: dict[str, Any] = {
    'name': 'robust', 'seed': 1, 'duration': 0.1, 'exchange_step': 0.001,
    'engine': {'model': 'linear'}, 'load': {'model': 'constant', 'torque': 50.0},
    'initial': {'speed_rad_s': 30.0},
    'driveline': [
        {'type': 'inertia', 'name': 'crank', 'J': 0.128},
        {'type': 'spring', 'name': 'bush', 'stiffness': 715.4, 'damping': 6.35},
        {'type': 'joint', 'name': 'cardan', 'kind': 'hooke', 'params': {'beta_deg': 15.0}},
        {'type': 'inertia', 'name': 'wheel', 'J': 0.161},
    ],
}


def assert_one_error_line(code: int, out: str, err: str, field: str) -> str:
    """The common contract of every bad-input case; returns the message after the field."""
    assert code == 2, (code, out, err)
    assert 'Traceback' not in err and 'Traceback' not in out
    assert out == ''
    lines = err.splitlines()
    assert len(lines) == 1, err
    prefix = f'cvj-sim: error: {field}: '
    assert lines[0].startswith(prefix), lines[0]
    return lines[0][len(prefix):]


def run_scene(tmp_path: Path, capsys: pytest.CaptureFixture[str], scene: Any,
              *, text: str | None = None, command: str = 'run') -> tuple[int, str, str]:
    """`cvj-sim run SCENE --out DIR` (or `cvj-sim simulate SCENE`) in-process; asserts that
    no run directory appeared."""
    path = tmp_path / 'scene.yaml'
    path.write_text(text if text is not None else yaml.safe_dump(scene, sort_keys=False))
    out_dir = tmp_path / 'run'
    argv = ['run', str(path), '--out', str(out_dir)] if command == 'run' else [command, str(path)]
    code = cli_main(argv)
    out, err = capsys.readouterr()
    assert not (out_dir / 'bag').exists()
    return code, out, err


def mutate(path: str, value: Any) -> dict[str, Any]:
    """VALID with the dotted/indexed ``path`` set to ``value`` (``value is DELETE`` removes it)."""
    scene = copy.deepcopy(VALID)
    keys = [int(k) if k.isdigit() else k for k in re.findall(r'[^.\[\]]+', path)]
    node = scene
    for k in keys[:-1]:
        node = node[k]
    if value is DELETE:
        del node[keys[-1]]
    else:
        node[keys[-1]] = value
    return scene


DELETE = object()


def test_valid_scene_passes_validation_helper(tmp_path: Path) -> None:
    """Control: the base scene is valid, so every failure below comes from its mutation."""
    from cvj_ros.physics.scene import parse_scene
    assert parse_scene(copy.deepcopy(VALID)).name == 'robust'


def test_malformed_yaml_names_the_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    text = yaml.safe_dump(VALID, sort_keys=False).splitlines()
    bad_line = next(i for i, s in enumerate(text) if s.startswith('duration'))
    text[bad_line] = 'duration: [0.1'                        # unclosed flow sequence
    code, out, err = run_scene(tmp_path, capsys, None, text='\n'.join(text) + '\n')
    assert code == 2 and err.count('\n') == 1 and 'Traceback' not in err
    m = re.match(r'cvj-sim: error: (.+\.yaml):(\d+): malformed YAML', err)
    assert m, err
    # the parser reports where it noticed the problem: the bad line or the one after it
    assert int(m.group(2)) in (bad_line + 1, bad_line + 2)


def test_tab_indented_yaml_names_the_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    text = 'name: x\nduration: 1\nengine:\n\tmodel: linear\n'
    code, out, err = run_scene(tmp_path, capsys, None, text=text)
    assert re.match(r'cvj-sim: error: .+\.yaml:4: malformed YAML', err), err
    assert code == 2 and err.count('\n') == 1


@pytest.mark.parametrize('path,value,field,words', [
    # unknown keys, with a did-you-mean
    ('duraton', 1.0, 'duraton', "did you mean 'duration'"),
    ('driveline[1].stifness', 1.0, 'driveline[1].stifness', "did you mean 'stiffness'"),
    ('driveline[2].params.beta_dge', 10.0, 'driveline[2].params.beta_dge', "did you mean 'beta_deg'"),
    ('driveline[2].kind', 'hoke', 'driveline[2].kind', "did you mean 'hooke'"),
    ('solver', {'methd': 'dopri5'}, 'solver.methd', "did you mean 'method'"),
    ('engine.m11', 600.0, 'engine.m11', "did you mean 'm1'"),
    # wrong units: a bare angle without its unit suffix, a unit written into a value
    ('driveline[2].params', {'beta': 15.0}, 'driveline[2].params.beta', "did you mean 'beta_"),
    ('driveline[1].stiffness', '715.4 N m/rad', 'driveline[1].stiffness', 'must be a number'),
    ('initial.speed_rpm', '3000 rpm', 'initial', ''),
    ('exchange_step', '1 ms', 'exchange_step', 'must be a number'),
    # wrong types
    ('driveline[0].J', [0.1], 'driveline[0].J', 'must be a number'),
    ('driveline[0].J', True, 'driveline[0].J', 'must be a number'),
    ('driveline', {'a': 1}, 'driveline', 'list'),
    ('seed', -3, 'seed', 'non-negative integer'),
    ('driveline[0]', 'inertia', 'driveline[0]', 'mapping'),
    # out of range: angles and stiffness / inertia
    ('driveline[2].params.beta_deg', 90.0, 'driveline[2].params.beta_deg', '< 90'),
    ('driveline[2].params.beta_deg', -5.0, 'driveline[2].params.beta_deg', '>= 0'),
    ('driveline[1].stiffness', 0.0, 'driveline[1].stiffness', '> 0'),
    ('driveline[1].stiffness', -1e6, 'driveline[1].stiffness', '> 0'),
    ('driveline[0].J', 0.0, 'driveline[0].J', '> 0'),
    ('driveline[1].damping', -1.0, 'driveline[1].damping', '>= 0'),
    ('duration', -1.0, 'duration', '> 0'),
    # NaN / inf
    ('driveline[1].stiffness', float('nan'), 'driveline[1].stiffness', 'finite'),
    ('driveline[0].J', float('inf'), 'driveline[0].J', 'finite'),
    ('driveline[2].params.beta_deg', float('nan'), 'driveline[2].params.beta_deg', 'finite'),
    ('initial.speed_rad_s', float('-inf'), 'initial.speed_rad_s', 'finite'),
    ('engine.m1', float('nan'), 'engine.m1', ''),
    ('load.torque', float('inf'), 'load.torque', ''),
    # missing things
    ('driveline[0].J', DELETE, 'driveline[0].J', 'missing'),
    # two Hooke joints in a row without the second's yoke phase; a cross that locks
    ('driveline', [VALID['driveline'][0], VALID['driveline'][2],
                   {'type': 'inertia', 'name': 'centre', 'J': 0.02},
                   dict(VALID['driveline'][2], name='cardan_rear'), VALID['driveline'][3]],
     'driveline[3].params.phase_deg', 'missing'),
    ('driveline[2].params.cross_angle_deg', 10.0, 'driveline[2].params.cross_angle_deg', 'locks'),
    ('engine', DELETE, 'engine', 'missing'),
    # non-monotonic time series (inline load samples)
    ('load', {'model': 'time_series', 't': [0.0, 0.2, 0.1], 'torque': [1.0, 2.0, 3.0]},
     'load.t', 'increasing'),
    ('load', {'model': 'time_series', 't': [0.0, 0.1, 0.1], 'torque': [1.0, 2.0, 3.0]},
     'load.t', 'increasing'),
    ('load', {'model': 'time_series', 't': [0.0, float('nan')], 'torque': [1.0, 2.0]},
     'load.t', ''),
])
@pytest.mark.parametrize('command', ['run', 'simulate'])
def test_bad_scene_field(tmp_path: Path, capsys: pytest.CaptureFixture[str], path: str,
                         value: Any, field: str, words: str, command: str) -> None:
    code, out, err = run_scene(tmp_path, capsys, mutate(path, value), command=command)
    # the field may carry an index/sub-key after the named prefix (load.t[2], initial.speed_rpm)
    assert code == 2 and 'Traceback' not in err and out == '', err
    assert err.count('\n') == 1, err
    msg = err[len('cvj-sim: error: '):]
    assert err.startswith('cvj-sim: error: ') and msg.startswith(field), err
    assert words in msg, err


def test_non_monotonic_time_series_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    csv = tmp_path / 'load.csv'
    csv.write_text('t,torque\n0.0,10\n0.05,11\n0.04,12\n0.1,13\n')
    code, out, err = run_scene(tmp_path, capsys, mutate('load', {'model': 'time_series',
                                                                 'file': str(csv)}))
    msg = assert_one_error_line(code, out, err, err[16:].split(':')[0])
    assert err[16:].startswith('load.'), err
    assert 'increasing' in msg, err


def test_scene_not_found_did_you_mean(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code = cli_main(['run', 'kavz685_levr', '--out', str(tmp_path / 'r')])
    out, err = capsys.readouterr()
    msg = assert_one_error_line(code, out, err, 'scene')
    assert "did you mean 'kavz685_lever'" in msg


# --- bags --------------------------------------------------------------------------------

def _bag_with_clock_only(path: Path) -> Path:
    """A valid rosbag2 bag holding only /clock messages (no joint states, no load)."""
    from rosgraph_msgs.msg import Clock
    from rclpy.serialization import serialize_message
    from builtin_interfaces.msg import Time
    with bagmod.BagWriter(path) as w:
        w.add_topic('/clock')
        for k in range(5):
            w.write('/clock', k * 1_000_000, serialize_message(Clock(clock=Time(nanosec=k * 1_000_000))))
    return path


def test_analyze_missing_bag(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    missing = tmp_path / 'nope'
    code = cli_main(['analyze', str(missing)])
    out, err = capsys.readouterr()
    assert_one_error_line(code, out, err, str(missing))


def test_analyze_bag_without_joint_states(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    b = _bag_with_clock_only(tmp_path / 'clock_only')
    code = cli_main(['analyze', str(b)])
    out, err = capsys.readouterr()
    assert code == 2 and out == '' and 'Traceback' not in err and err.count('\n') == 1, err
    assert '/driveline/joint_states' in err


def test_replay_missing_bag_and_topic(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    missing = tmp_path / 'nope'
    code = cli_main(['replay', str(missing)])
    out, err = capsys.readouterr()
    assert_one_error_line(code, out, err, str(missing))
    b = _bag_with_clock_only(tmp_path / 'clock_only')
    code = cli_main(['replay', str(b), '--topics', '/load/wrench'])
    out, err = capsys.readouterr()
    msg = assert_one_error_line(code, out, err, '--topics')
    assert '/load/wrench' in msg


def test_run_load_from_bag_without_load_topic(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    b = _bag_with_clock_only(tmp_path / 'clock_only')
    path = tmp_path / 'scene.yaml'
    path.write_text(yaml.safe_dump(VALID))
    code = cli_main(['run', str(path), '--out', str(tmp_path / 'r'), '--load-from-bag', str(b)])
    out, err = capsys.readouterr()
    assert code == 2 and out == '' and 'Traceback' not in err and err.count('\n') == 1, err
    assert '/load/wrench' in err
    assert not (tmp_path / 'r' / 'bag').exists()


def test_run_load_from_missing_bag(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / 'scene.yaml'
    path.write_text(yaml.safe_dump(VALID))
    code = cli_main(['run', str(path), '--out', str(tmp_path / 'r'), '--load-from-bag',
                     str(tmp_path / 'nope')])
    out, err = capsys.readouterr()
    assert code == 2 and out == '' and 'Traceback' not in err and err.count('\n') == 1, err
    assert str(tmp_path / 'nope') in err


@pytest.mark.parametrize('argv,field', [
    (['run', '{scene}', '--out', '{tmp}/r', '--exchange-step', '-0.001'], '--exchange-step'),
    # named by its RunOptions name, not the flag (the other run options use the flag)
    (['run', '{scene}', '--out', '{tmp}/r', '--peer-timeout', '0'], 'peer_timeout'),
    (['run', '{scene}', '--out', '{tmp}/r', '--seed', '-1'], '--seed'),
    (['analyze', '{tmp}/nope', '--skip', '-1'], '--skip'),
    (['simulate', '{scene}', '--method', 'rk45'], '--method'),
    (['simulate', '{scene}', '--rtol', 'nan'], '--rtol'),
    (['simulate', '{scene}', '--fidelity', 'cardan=closed'], 'fidelity.cardan'),
    (['simulate', '{scene}', '--fidelity', 'nosuch=exact'], 'fidelity.nosuch'),
    (['simulate', '{scene}', '--duration', '-2'], '--duration'),
])
def test_bad_options(tmp_path: Path, capsys: pytest.CaptureFixture[str], argv: list[str],
                     field: str) -> None:
    scene = tmp_path / 's.yaml'
    scene.write_text(yaml.safe_dump(VALID))
    code = cli_main([a.format(scene=scene, tmp=tmp_path) for a in argv])
    out, err = capsys.readouterr()
    assert_one_error_line(code, out, err, field)
    assert not (tmp_path / 'r' / 'bag').exists()


def test_bad_option_through_the_executable(tmp_path: Path) -> None:
    """The installed entry point (a real process): one line, exit 2, no traceback."""
    scene = tmp_path / 's.yaml'
    scene.write_text(yaml.safe_dump(VALID))
    proc = subprocess.run([CVJ_SIM, 'run', str(scene), '--out', str(tmp_path / 'r'),
                           '--duration', 'nan'], capture_output=True, text=True, timeout=60)
    assert_one_error_line(proc.returncode, proc.stdout, proc.stderr, '--duration')
    assert not (tmp_path / 'r' / 'bag').exists()


def test_nan_in_yaml_through_the_executable(tmp_path: Path) -> None:
    """YAML's own .nan spelling reaches the validator and is named by field."""
    text = yaml.safe_dump(VALID, sort_keys=False).replace('stiffness: 715.4', 'stiffness: .nan')
    assert '.nan' in text
    scene = tmp_path / 's.yaml'
    scene.write_text(text)
    proc = subprocess.run([CVJ_SIM, 'run', str(scene), '--out', str(tmp_path / 'r')],
                          capture_output=True, text=True, timeout=60)
    msg = assert_one_error_line(proc.returncode, proc.stdout, proc.stderr, 'driveline[1].stiffness')
    assert 'finite' in msg
    assert not np.isfinite(float('nan'))


@pytest.mark.parametrize('damage', ['truncate', 'garbage', 'no_metadata'])
def test_analyze_damaged_bag(tmp_path: Path, capsys: pytest.CaptureFixture[str], damage: str) -> None:
    """A bag cut short (recorder killed, disk full), overwritten or missing its metadata:
    one line naming the bag directory, exit 2."""
    b = _bag_with_clock_only(tmp_path / 'bag')
    data_file = next(p for p in b.iterdir() if p.suffix == '.mcap')
    if damage == 'truncate':
        raw = data_file.read_bytes()
        data_file.write_bytes(raw[:len(raw) // 2])
    elif damage == 'garbage':
        data_file.write_bytes(b'not an mcap file\n' * 10)
    else:
        (b / 'metadata.yaml').unlink()
    code = cli_main(['analyze', str(b)])
    out, err = capsys.readouterr()
    assert_one_error_line(code, out, err, str(b))


def _bag_with_load(path: Path, torques: list[float]) -> Path:
    """A bag with /load/wrench samples of ``torques`` at t = 0, 1, 2, ... ms."""
    from geometry_msgs.msg import WrenchStamped
    from rclpy.serialization import serialize_message
    w = bagmod.BagWriter(path)
    w.add_topic('/load/wrench')
    for k, tz in enumerate(torques):
        m = WrenchStamped()
        m.header.stamp.nanosec = k * 1_000_000
        m.wrench.torque.z = tz
        w.write('/load/wrench', k * 1_000_000, serialize_message(m))
    w.close()
    return path


def test_run_load_from_bag_with_non_finite_torque(tmp_path: Path,
                                                  capsys: pytest.CaptureFixture[str]) -> None:
    """Refused before any process starts (was: every node started, then the coupling node
    stopped at the sample), naming the bag, the sample and its time."""
    pytest.importorskip('rclpy')
    b = _bag_with_load(tmp_path / 'nan_load', [50.0, 50.0, 50.0, float('nan')] + [50.0] * 6)
    path = tmp_path / 'scene.yaml'
    path.write_text(yaml.safe_dump(VALID))
    code = cli_main(['run', str(path), '--out', str(tmp_path / 'r'), '--load-from-bag', str(b)])
    msg = assert_one_error_line(code, *capsys.readouterr(), '--load-from-bag')
    assert msg == (f'{b}: /load/wrench torque.z not finite (nan N m) at t = 0.003 s (sample 3 of '
                   '10, 1 such); a recorded load must be finite')
    assert not (tmp_path / 'r').exists()


@pytest.mark.parametrize('where', ['proc', 'file_parent'])
def test_unwritable_out_names_out(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                  where: str) -> None:
    """A run directory that cannot be written is one line naming --out, exit 2, before any
    process starts (was `<scene>: OSError ... (unexpected ...)`, exit 1). Read-only
    directories are covered by the same check (tempfile in OUT), but this machine's tests
    run as root, which writes anyway; /proc and a file as parent fail for root too."""
    path = tmp_path / 'scene.yaml'
    path.write_text(yaml.safe_dump(VALID))
    if where == 'proc':
        out = Path('/proc/cvj_run')
    else:
        (tmp_path / 'plain_file').write_text('x')
        out = tmp_path / 'plain_file' / 'run'
    code = cli_main(['run', str(path), '--out', str(out)])
    msg = assert_one_error_line(code, *capsys.readouterr(), '--out')
    assert msg.startswith(f'cannot write to {out}: '), msg


@pytest.mark.parametrize('command', ['run', 'simulate'])
def test_exponent_yaml_reads_as_text_says_how_to_write_it(tmp_path: Path,
                                                          capsys: pytest.CaptureFixture[str],
                                                          command: str) -> None:
    """PyYAML (YAML 1.1) reads ``1.0e300`` and ``1e6`` as strings (a float needs a dot and a
    signed exponent): the line says so and gives the spelling that reads as the number."""
    text = yaml.safe_dump(VALID, sort_keys=False).replace('J: 0.128', 'J: 1.0e300')
    assert 'J: 1.0e300' in text
    code, out, err = run_scene(tmp_path, capsys, None, text=text, command=command)
    msg = assert_one_error_line(code, out, err, 'driveline[0].J')
    assert msg.startswith("must be a number, got the text '1.0e300'") and 'write 1.0e+300' in msg, msg
    assert yaml.safe_load('J: 1.0e+300') == {'J': 1e300}     # the spelling it suggests is a float
    text = yaml.safe_dump(VALID, sort_keys=False).replace('stiffness: 715.4', 'stiffness: 1e6')
    code, out, err = run_scene(tmp_path, capsys, None, text=text, command=command)
    msg = assert_one_error_line(code, out, err, 'driveline[1].stiffness')
    assert 'write 1.0e+06' in msg and yaml.safe_load('k: 1.0e+06') == {'k': 1e6}, msg


def test_simulate_larger_than_memory_names_duration_and_step(tmp_path: Path,
                                                             capsys: pytest.CaptureFixture[str]) -> None:
    """1e12 s at 1 ms are 1e15 samples, >= 24 bytes each (time, an angle, a speed): more than
    any machine's RAM; was a MemoryError (or numpy's 'Maximum allowed size exceeded') with
    exit 1."""
    path = tmp_path / 'scene.yaml'
    path.write_text(yaml.safe_dump(VALID, sort_keys=False))
    code = cli_main(['simulate', str(path), '--duration', '1e12'])
    out, err = capsys.readouterr()
    msg = assert_one_error_line(code, out, err, '--duration / exchange_step')
    assert msg.startswith('1e+12 s in samples of 0.001 s are 1e+15 samples'), msg
    # a random load packs its knots over the run's duration only: a scene of 1e15 s (1e17
    # knots of 0.01 s) runs 0.01 s (was refused: its knots were packed over the scene's)
    scene = mutate('load', {'model': 'random', 'mean': 50.0, 'amplitude': 5.0})
    scene['duration'] = 1e15
    code = cli_main(['simulate', str(_write(tmp_path / 'random.yaml', scene)), '--duration', '0.01',
                     '--json'])
    out, err = capsys.readouterr()
    assert code == 0 and 'Traceback' not in err, (code, err)


def _write(path: Path, scene: Any) -> Path:
    path.write_text(yaml.safe_dump(scene, sort_keys=False))
    return path


def test_run_size_bound_is_the_lower_bound_of_the_arrays() -> None:
    """The bound's edge: VALID's 0.1 s at 1 ms are 101 samples, 24 bytes each = 2424 bytes."""
    from cvj_ros.commands.simulate import check_run_size
    from cvj_ros.errors import SceneError
    from cvj_ros.physics.scene import parse_scene
    scene = parse_scene(copy.deepcopy(VALID))
    check_run_size(scene, None, None, memory=2424)
    with pytest.raises(SceneError, match=r'^duration / exchange_step: 0.1 s in samples of 0.001 s'):
        check_run_size(scene, None, None, memory=2423)
    # a random load's knots of 1e-5 s over the run's duration, 16 bytes each (the packed
    # float64 array kept and the run's copy of it; measured 16.1-16.2 bytes of RSS a knot
    # at 1e7 and 2e7 knots): 1e4 knots over the scene's 0.1 s are 160000 bytes, 5e3 over a
    # run of 0.05 s 80000 bytes
    raw = mutate('load', {'model': 'random', 'mean': 50.0, 'amplitude': 5.0, 'sample_interval': 1e-5})
    scene = parse_scene(raw)
    check_run_size(scene, None, None, memory=160000)
    with pytest.raises(SceneError, match=r'^duration / load.sample_interval: a random load over '
                                         r'0.1 s in knots of 1e-05 s needs 1e\+04 knots'):
        check_run_size(scene, None, None, memory=159999)
    check_run_size(scene, 0.05, None, memory=159999)
    with pytest.raises(SceneError, match=r'^--duration / load.sample_interval: .* over 0.05 s '):
        check_run_size(scene, 0.05, None, memory=79999)


def test_absurd_stiffness_is_refused_before_an_explicit_run(tmp_path: Path,
                                                           capsys: pytest.CaptureFixture[str]) -> None:
    # 1e300 N m/rad: dopri5 would creep at ~1e-150 s steps (48 s to overflow on kavz685_lever);
    # refused at once, naming the field and what to do instead
    code, out, err = run_scene(tmp_path, capsys, mutate('driveline[1].stiffness', 1e300),
                               command='simulate')
    msg = assert_one_error_line(code, out, err, 'driveline[1].stiffness')
    assert 'steps' in msg and 'rosenbrock' in msg, msg


def test_absurd_stiffness_in_a_vehicle_scene_with_modes_is_refused(shipped_scene_with,
                                                                   capsys: pytest.CaptureFixture[str]) -> None:
    # launch_clutch (clutch, gearbox, wheel brakes) with its left halfshaft at 1e300 N m/rad:
    # `cvj-sim simulate` refuses it naming the branch's path (was: the mode kernel's compile,
    # then steps near 1e-11 s with no line)
    path = shipped_scene_with('launch_clutch', 'stiffness: 8770.0', 'stiffness: 1.0e+300')
    code = cli_main(['simulate', str(path), '--duration', '0.1'])
    out, err = capsys.readouterr()
    msg = assert_one_error_line(code, out, err, 'driveline[5].left[2].stiffness')
    assert msg.startswith("spring 'midshaft_left_twist' and its neighbours' inertias have a mode "
                          "at 8.46e+150 rad/s: dopri5 would need ~1.4e+149 steps for 0.1 s"), msg


def test_absurd_stiffness_in_a_chain_scene_with_modes_is_refused(shipped_scene_with,
                                                                 capsys: pytest.CaptureFixture[str]) -> None:
    # launch_clutch_chain (clutch, gearbox, brake on a chain) with its halfshaft at
    # 1e300 N m/rad: refused naming the stiffness (was: not checked - its fidelity report
    # could not be built - and a 0.1 s run with the brake holding passed); omega_n of 1st gear
    # against the braked wheel, sqrt(1e300 / (0.015 * 14.21^2 + 0.02)) = 5.73e+149 rad/s
    path = shipped_scene_with('launch_clutch_chain', 'stiffness: 6100.0', 'stiffness: 1.0e+300')
    code = cli_main(['simulate', str(path), '--duration', '0.1'])
    out, err = capsys.readouterr()
    msg = assert_one_error_line(code, out, err, 'driveline[5].stiffness')
    assert msg.startswith("spring 'halfshaft' and its neighbours' inertias have a mode "
                          "at 5.73e+149 rad/s: dopri5 would need ~9.5e+147 steps for 0.1 s"), msg


@pytest.mark.parametrize('composed', [False, True])
def test_absurd_stiffness_is_refused_before_a_ros_run_starts(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], composed: bool) -> None:
    # `cvj-sim run` (separate processes or --composed): the same line before any process or
    # node starts, over the run's duration (was: every node started, then ~60 s of dopri5
    # steps near 1e-11 s in the coupling node ending in an overflow, exit 1)
    path = tmp_path / 'scene.yaml'
    path.write_text(yaml.safe_dump(mutate('driveline[1].stiffness', 1e300), sort_keys=False))
    code = cli_main(['run', str(path), '--out', str(tmp_path / 'run'), '--duration', '0.05']
                    + ['--composed'] * composed)
    out, err = capsys.readouterr()
    msg = assert_one_error_line(code, out, err, 'driveline[1].stiffness')
    assert 'dopri5 would need' in msg and 'steps for 0.05 s' in msg and 'rosenbrock' in msg, msg
    assert not (tmp_path / 'run').exists()
