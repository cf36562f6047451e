"""Every error line quoted in README.md and docs/*.md (`` `cvj-sim: error: ...` ``) is the
program's real text: each concrete example has a recipe here that makes that bad input, runs
``cvj-sim`` on it (in-process, :func:`cvj_ros.cli.main`) and compares stderr with the quote,
``DIR`` standing for the test's directory. Templates (``<field>``, ``...``) are skipped; the
few examples that need a ROS run are listed in :data:`NEEDS_A_RUN` with the test that
produces them, and a new quote without a recipe fails :func:`test_every_quoted_error_has_a_recipe`.
"""
from __future__ import annotations

import copy
import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
import yaml

from cvj_ros.cli import main as cli_main

ROOT = Path(__file__).resolve().parents[1]
DOCS = [ROOT / 'README.md', *sorted((ROOT / 'docs').glob('*.md'))]

# a quoted error line: in backticks, or alone on a line of a fenced block
_QUOTED = re.compile(r'`((?:cvj-sim|[a-z_]+_node|driveline_composed): error: [^`]+)`'
                     r'|^((?:cvj-sim): error: .+)$', re.M)
_TEMPLATE = re.compile(r'<[a-z\'"]|\.\.\.|\bN\b ERROR')


def quoted_errors() -> list[tuple[str, str]]:
    """(file name, quoted line) of every concrete error example in the docs, once each."""
    seen: dict[str, str] = {}
    for path in DOCS:
        for m in _QUOTED.finditer(path.read_text(encoding='utf-8')):
            text = ' '.join((m.group(1) or m.group(2)).split())
            if not _TEMPLATE.search(text):
                seen.setdefault(text, path.name)
    return [(name, text) for text, name in seen.items()]


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


def _scene(tmp: Path, change: Callable[[dict[str, Any]], None] | None = None, *,
           text: str | bytes | None = None, name: str = 'scene.yaml') -> list[str]:
    """``cvj-sim simulate DIR/<name>`` with VALID changed by ``change`` (or ``text``)."""
    scene = copy.deepcopy(VALID)
    if change is not None:
        change(scene)
    path = tmp / name
    if isinstance(text, bytes):
        path.write_bytes(text)
    else:
        path.write_text(text if text is not None else yaml.safe_dump(scene, sort_keys=False))
    return ['simulate', str(path)]


def _set(path: str, value: Any) -> Callable[[dict[str, Any]], None]:
    """Set the dotted/indexed ``path`` of a scene dict to ``value``."""
    keys = [int(k) if k.isdigit() else k for k in re.findall(r'[^.\[\]]+', path)]

    def change(scene: dict[str, Any]) -> None:
        node = scene
        for k in keys[:-1]:
            node = node[k]
        node[keys[-1]] = value
    return change


def _joint_at_1(kind: str, params: dict[str, Any]) -> Callable[[dict[str, Any]], None]:
    def change(scene: dict[str, Any]) -> None:
        scene['driveline'][1:3] = [{'type': 'joint', 'name': 'j', 'kind': kind, 'params': params}]
    return change


def _clock_only_bag(path: Path) -> Path:
    from builtin_interfaces.msg import Time
    from rclpy.serialization import serialize_message
    from rosgraph_msgs.msg import Clock

    from cvj_ros import bag as bagmod
    with bagmod.BagWriter(path) as w:
        w.add_topic('/clock')
        for k in range(5):
            w.write('/clock', k * 1_000_000, serialize_message(Clock(clock=Time(nanosec=k * 1_000_000))))
    return path


def _load_bag(path: Path, torques: list[float]) -> Path:
    from geometry_msgs.msg import WrenchStamped
    from rclpy.serialization import serialize_message

    from cvj_ros import bag as bagmod
    with bagmod.BagWriter(path) as w:
        w.add_topic('/load/wrench')
        for k, tz in enumerate(torques):
            m = WrenchStamped()
            m.header.stamp.nanosec = k * 1_000_000
            m.wrench.torque.z = tz
            w.write('/load/wrench', k * 1_000_000, serialize_message(m))
    return path


def _damaged(tmp: Path, how: str) -> Path:
    b = _clock_only_bag(tmp / 'bag')
    data = next(p for p in b.iterdir() if p.suffix == '.mcap')
    if how == 'truncate':
        raw = data.read_bytes()
        data.write_bytes(raw[:len(raw) // 2])
    else:
        (b / 'metadata.yaml').unlink()
    return b


def _bomb() -> bytes:
    return b'\n'.join([b'a0: &a0 [lol, lol, lol, lol, lol, lol, lol, lol, lol]']
                      + [f'a{i}: &a{i} [{", ".join([f"*a{i - 1}"] * 9)}]'.encode() for i in range(1, 10)])


def _malformed_line_4(tmp: Path) -> list[str]:
    return _scene(tmp, text='name: robust\nseed: 1\nduration: [0.1\nexchange_step: 0.001\n')


def _unexpected(tmp: Path, monkeypatch: pytest.MonkeyPatch) -> list[str]:
    """An exception no check foresaw (the simulate command dividing by zero)."""
    from cvj_ros.commands import simulate

    def broken(args: Any) -> int:
        return 1.0 / 0.0   # type: ignore[return-value]
    monkeypatch.setattr(simulate, 'run', broken)
    monkeypatch.delenv('CVJ_DEBUG', raising=False)
    return _scene(tmp)


def _reindex_junk(tmp: Path) -> list[str]:
    (tmp / 'junk').mkdir()
    (tmp / 'junk' / 'junk.mcap').write_bytes(b'not an mcap file at all')
    return ['reindex', str(tmp / 'junk')]


def _empty_dir(path: Path) -> Path:
    path.mkdir()
    return path


def _reindex_empty(tmp: Path) -> list[str]:
    (tmp / 'empty').mkdir()
    return ['reindex', str(tmp / 'empty')]


def _run(tmp: Path, *extra: str) -> list[str]:
    return ['run', *_scene(tmp)[1:], '--out', str(tmp / 'r'), *extra]


_HOOKE = 'driveline[2].params.beta_deg: must be >= 0 and < 90 deg (pi/2 rad), got {a} deg ({r} rad)'

#: quoted line (DIR = the test directory) -> the argv that produces it, from (DIR, monkeypatch)
RECIPES: dict[str, Callable[[Path, pytest.MonkeyPatch], list[str]]] = {
    "DIR/scene.yaml:4: malformed YAML: expected ',' or ']', but got ':'":
        lambda d, m: _malformed_line_4(d),
    "duraton: unknown key; did you mean 'duration'?": lambda d, m: _scene(d, _set('duraton', 1.0)),
    "driveline[1].stifness: unknown key; did you mean 'stiffness'?":
        lambda d, m: _scene(d, _set('driveline[1].stifness', 1.0)),
    "driveline[1].kind: must be one of chain, double_cardan, gear, hooke, ideal_cv, lever_hinge, "
    "runout, rzeppa, tripod, got 'cardan'; did you mean 'hooke'?":
        lambda d, m: _scene(d, _joint_at_1('cardan', {'beta_deg': 15.0})),
    'driveline[1].params.alpha_deg: the sum alpha + delta_alpha must be in [0, 90) deg, got 89 + '
    '1.72 = 90.72 deg':
        lambda d, m: _scene(d, _joint_at_1('lever_hinge', {'alpha_deg': 89.0, 'delta_alpha_deg': 1.72})),
    '--out: cannot write to /proc/foo: No such file or directory':
        lambda d, m: ['run', *_scene(d)[1:], '--out', '/proc/foo'],
    '--out: cannot write to /proc/run: No such file or directory':
        lambda d, m: ['run', *_scene(d)[1:], '--out', '/proc/run'],
    "engine.m11: unknown key; did you mean 'm1'? (known: k1, m1, model, no_load_speed, throttle)":
        lambda d, m: _scene(d, _set('engine.m11', 600.0)),
    "driveline[2].kind: must be one of chain, double_cardan, gear, hooke, ideal_cv, lever_hinge, "
    "runout, rzeppa, tripod, got 'hoke'; did you mean 'hooke'?":
        lambda d, m: _scene(d, _set('driveline[2].kind', 'hoke')),
    "driveline[2].params.beta: unknown parameter; did you mean 'beta_deg'?":
        lambda d, m: _scene(d, _set('driveline[2].params', {'beta': 15.0})),
    "driveline[0].J: must be a number, got the text '1.0e300' (YAML 1.1, as read here, takes a number "
    "with an exponent only with a dot and a signed exponent: write 1.0e+300)":
        lambda d, m: _scene(d, text=yaml.safe_dump(VALID, sort_keys=False).replace('J: 0.128', 'J: 1.0e300')),
    "driveline[1].stiffness: spring 'bush' and its neighbours' inertias have a mode at 3.74e+150 "
    "rad/s: dopri5 would need ~6.2e+148 steps for 0.1 s just to stay stable (more than 1e+10); "
    "check the value, or use solver rosenbrock or rigid fidelity for it":
        lambda d, m: _scene(d, _set('driveline[1].stiffness', 1e300)),
    "driveline[1].stiffness: must be a number, got '715.4 N m/rad'":
        lambda d, m: _scene(d, _set('driveline[1].stiffness', '715.4 N m/rad')),
    'driveline[0].J: must be a number, got [0.1]': lambda d, m: _scene(d, _set('driveline[0].J', [0.1])),
    _HOOKE.format(a=90, r=1.5708): lambda d, m: _scene(d, _set('driveline[2].params.beta_deg', 90.0)),
    _HOOKE.format(a=95, r=1.65806): lambda d, m: _scene(d, _set('driveline[2].params.beta_deg', 95.0)),
    'driveline[1].stiffness: must be > 0, got 0.0': lambda d, m: _scene(d, _set('driveline[1].stiffness', 0.0)),
    'driveline[1].stiffness: must be finite, got nan':
        lambda d, m: _scene(d, _set('driveline[1].stiffness', float('nan'))),
    'driveline[0].J: must be finite, got inf': lambda d, m: _scene(d, _set('driveline[0].J', float('inf'))),
    'initial.speed_rad_s: must be <= 1000000.0, got 1e+308':
        lambda d, m: _scene(d, _set('initial.speed_rad_s', 1e308)),
    'load.t[2]: must be strictly increasing: 0.1 follows 0.2':
        lambda d, m: _scene(d, _set('load', {'model': 'time_series', 't': [0.0, 0.2, 0.1],
                                             'torque': [1.0, 2.0, 3.0]})),
    "scene: no scene file or shipped scene 'kavz685_levr'; did you mean 'kavz685_lever'?":
        lambda d, m: ['simulate', 'kavz685_levr'],
    'DIR/nope: no such bag': lambda d, m: ['analyze', str(d / 'nope')],
    'DIR/bag: cannot read bag: File end magic is invalid.':
        lambda d, m: ['analyze', str(_damaged(d, 'truncate'))],
    'DIR/bag: no metadata.yaml (recording killed before it was finalised?); rebuild it from the '
    'data on disk with: cvj-sim reindex DIR/bag':
        lambda d, m: ['analyze', str(_damaged(d, 'no_metadata'))],
    'DIR/bag: not a rosbag2 bag (no metadata.yaml; was the recording finalised?)':
        lambda d, m: ['analyze', str(_empty_dir(d / 'bag'))],
    '/driveline/joint_states: no messages in bag DIR/clock_only (topics: /clock)':
        lambda d, m: ['analyze', str(_clock_only_bag(d / 'clock_only'))],
    '--topics: /load/wrench: topic not in bag DIR/clock_only':
        lambda d, m: ['replay', str(_clock_only_bag(d / 'clock_only')), '--topics', '/load/wrench'],
    '--load-from-bag: /load/wrench: topic not in bag DIR/clock_only':
        lambda d, m: _run(d, '--load-from-bag', str(_clock_only_bag(d / 'clock_only'))),
    '--load-from-bag: DIR/nan_load: /load/wrench torque.z not finite (nan N m) at t = 0.003 s '
    '(sample 3 of 10, 1 such); a recorded load must be finite':
        lambda d, m: _run(d, '--load-from-bag', str(_load_bag(
            d / 'nan_load', [50.0, 50.0, 50.0, float('nan')] + [50.0] * 6))),
    '--duration: must be a finite number > 0, got nan': lambda d, m: _run(d, '--duration', 'nan'),
    'DIR/latin1.yaml:1: not UTF-8 text: byte 0xe4 at column 19 (latin-1 or another encoding? '
    'save the file as UTF-8)':
        lambda d, m: _scene(d, text='name: Gelenkwelle_\u00e4\n'.encode('latin-1'), name='latin1.yaml'),
    'DIR/scene.yaml: UTF-16 text; cvj_ros reads UTF-8: save the file as UTF-8':
        lambda d, m: _scene(d, text='name: x\n'.encode('utf-16')),
    'DIR/scene.yaml: binary data (NUL byte at offset 8), not a UTF-8 text file':
        lambda d, m: _scene(d, text=b'name: x\n\x00\x01'),
    'DIR/scene.yaml: scene file larger than 1024 KiB; not a scene file?':
        lambda d, m: _scene(d, text=b'#' * ((1 << 20) + 1)),
    'DIR/scene.yaml:2: YAML nested deeper than 64 levels':
        lambda d, m: _scene(d, text=b'name: x\nextra: ' + b'[' * 10_000 + b']' * 10_000),
    'DIR/scene.yaml: YAML aliases expand to more than 100000 values (alias bomb?)':
        lambda d, m: _scene(d, text=_bomb()),
    'duration: must be a finite number, got an integer of 401 digits (beyond the float range)':
        lambda d, m: _scene(d, text=b'name: x\nduration: 1' + b'0' * 400),
    'DIR/empty: no .mcap or .db3 file to reindex': lambda d, m: _reindex_empty(d),
    'DIR/junk/junk.mcap: not an MCAP file (no MCAP magic at the start)': lambda d, m: _reindex_junk(d),
    'DIR/scene.yaml: ZeroDivisionError: float division by zero (unexpected; run with --debug or '
    'CVJ_DEBUG=1 for the traceback)': _unexpected,
    'beta: must be >= 0 and < 90 deg (pi/2 rad), got 90 deg (1.5708 rad)':
        lambda d, m: ['kinematics', 'hooke', '--beta', '90'],
}

#: examples from a run of ROS processes (a killed node, a shared domain, a missing outside
#: node): too slow for this check; the test named beside each produces that text
NEEDS_A_RUN: dict[str, str] = {
    'coupling_node: killed by SIGKILL': 'test/robustness/test_faults_processes.py',
    'lockstep: /driveline/joint_states has 1 publishers (expected 0)':
        'test/robustness/test_faults_processes.py::test_second_run_on_the_same_domain_is_refused_and_mixes_nothing',
    'lockstep: /engine/wrench has 2 publishers': 'the same test (its peers discovered first)',
    '--external load: no outside node published': 'test/e2e/test_vehicle_stack.py',
    '--external load: no': 'the same, quoted across lines in a fenced block of docs/ros.md',
    '--external load: /load/wrench is published by /wrong_stack as std_msgs/msg/String':
        'test/e2e/test_vehicle_stack.py::test_run_external_names_a_publisher_of_the_wrong_type',
    "seed: must be of type INTEGER, got 'abc' (STRING)":
        'test/nodes/test_params.py::test_bad_parameter_exits_2_with_one_line',
}


def _key(quote: str) -> str:
    return quote.split(': error: ', 1)[1]


def test_every_quoted_error_has_a_recipe() -> None:
    quotes = quoted_errors()
    assert len(quotes) >= 30
    missing = [(name, q) for name, q in quotes
               if _key(q) not in RECIPES and not any(_key(q).startswith(k) for k in NEEDS_A_RUN)]
    assert not missing, f'quoted error lines without a recipe in {__file__}: {missing}'


@pytest.mark.parametrize('quote', sorted(RECIPES))
def test_quoted_error_is_the_program_text(quote: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                          capsys: pytest.CaptureFixture[str]) -> None:
    if 'bag' in quote or 'nan_load' in quote:
        pytest.importorskip('rclpy')
    in_docs = {_key(q) for _, q in quoted_errors()}
    assert quote in in_docs, 'recipe for a line no doc quotes any more: drop it'
    argv = RECIPES[quote](tmp_path, monkeypatch)
    code = cli_main(argv)
    out, err = capsys.readouterr()
    assert code in (1, 2) and out == ''
    assert err == f'cvj-sim: error: {quote.replace("DIR", str(tmp_path))}\n'
