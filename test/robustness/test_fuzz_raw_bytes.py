"""Fuzz with raw bytes: scene files through `cvj-sim simulate`, bags through analyze, replay
and reindex. Fixed, seeded case counts (case k uses ``random.Random(k)``): reproducible on
any machine and at any load, no time box.

Scene files (:data:`N_SCENE_CASES`): the bytes of a shipped scene (or of a small valid one)
mutated by one of: bit flips, truncation, random bytes (whole file or a spliced run), NUL
bytes, the text re-encoded as UTF-16 (with and without BOM) or latin-1 with accents,
deep nesting (flow and block style, 100 to 100 000 levels), an alias bomb, huge numbers
(1e309, 5000-digit integers, -1e308), an oversized file (> 1 MiB). Each goes through the
real entry point ``cvj_ros.cli.main(['simulate', FILE, ...])`` in this process.
Oracle: exit 0 with a JSON summary on stdout, or exit 2 with exactly one stderr line
``cvj-sim: error: ...`` - never the guard's "unexpected" line (exit 1), never a traceback.

Bags (:data:`N_BAG_CASES_CI` in `make test`, all :data:`N_BAG_CASES` with `-m slow`): a small mcap and a small sqlite3 bag (synthetic lockstep
signals, test_analysis.py), mutated by: truncation anywhere (a run killed mid-write),
bit flips, a range overwritten with random bytes or zeros, garbage appended, metadata.yaml
deleted, truncated, bit-flipped, replaced by random bytes, or with one field changed to a
wrong type or value. Each goes through ``cvj-sim analyze --json``, the replay node's
reading path (:class:`~cvj_ros.nodes.replay_node.ReplayNode` constructed on one context,
not started; `cvj-sim replay` reads the bag exactly so), and ``cvj-sim reindex`` (then
analyze again if reindex succeeded). Oracle: as above (exit 0, or exit 2 with one line).
"""
from __future__ import annotations

import contextlib
import io
import json
import random
import shutil
from pathlib import Path

import pytest
import yaml

from cvj_ros.cli import main as cli_main
from cvj_ros.errors import CvjError
from cvj_ros.physics.scene import shipped_scenes

N_SCENE_CASES = 600
N_BAG_CASES = 240          # the whole seeded set: the slow test (pytest -m slow this file)
N_BAG_CASES_CI = 120      # cases 0..119 in `make test` (~0.2-0.4 s each: keeps the suite near 10 min)

SMALL_SCENE = b'''name: fuzz_small
duration: 0.01
exchange_step: 0.001
engine: {model: linear, m1: 50.0, k1: 0.4}
load: {model: constant, torque: 10.0}
initial: {speed_rad_s: 100.0}
driveline:
  - {type: inertia, name: drive, J: 0.01}
  - {type: spring, name: shaft, stiffness: 1000.0, damping: 1.0}
  - {type: inertia, name: driven, J: 0.01}
'''


def _run_cli(args: list[str]) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = cli_main(args)
    return code, out.getvalue(), err.getvalue()


def _check_outcome(case: str, code: int, out: str, err: str, *, json_out: bool) -> None:
    assert 'Traceback' not in err, f'{case}: traceback\n{err}'
    if code == 0:
        if json_out:
            json.loads(out)
        return
    lines = err.strip().splitlines()
    assert code == 2, f'{case}: exit {code}, stderr: {err}'
    assert len(lines) == 1 and lines[0].startswith('cvj-sim: error: '), f'{case}: {err!r}'


# ------------------------------------------------------------------------------- scenes

def _scene_bases() -> list[bytes]:
    bases = [SMALL_SCENE]
    for path in shipped_scenes().values():
        if b'tripod' not in path.read_bytes():      # exact tripod: 0.15-1 s to build per case
            bases.append(path.read_bytes())
    return bases


def mutate_scene(rng: random.Random, raw: bytes) -> tuple[str, bytes]:
    """One raw-bytes mutation of a scene file: (description, bytes)."""
    kind = rng.choice(['bitflip', 'bitflip', 'truncate', 'random', 'splice', 'nul', 'utf16',
                       'utf16le', 'latin1', 'deep_flow', 'deep_block', 'bomb', 'huge', 'oversize'])
    b = bytearray(raw)
    if kind == 'bitflip':
        for _ in range(rng.randint(1, 8)):
            i = rng.randrange(len(b))
            b[i] ^= 1 << rng.randrange(8)
    elif kind == 'truncate':
        del b[rng.randrange(len(b) + 1):]
    elif kind == 'random':
        b = bytearray(rng.randbytes(rng.randint(0, 3000)))
    elif kind == 'splice':
        i = rng.randrange(len(b) + 1)
        b[i:i + rng.randint(0, 20)] = rng.randbytes(rng.randint(1, 40))
    elif kind == 'nul':
        b.insert(rng.randrange(len(b) + 1), 0)
    elif kind in ('utf16', 'utf16le'):
        b = bytearray(raw.decode().encode('utf-16' if kind == 'utf16' else 'utf-16-le'))
    elif kind == 'latin1':
        b = bytearray(raw.decode().replace('name: ', 'name: Gelenkwelle_\u00e4\u00df_', 1).encode('latin-1'))
    elif kind == 'deep_flow':
        n = rng.choice([100, 1000, 100_000])
        b = bytearray(raw + b'\nextra: ' + b'[' * n + b']' * n + b'\n')
    elif kind == 'deep_block':
        n = rng.choice([100, 2000])
        b = bytearray(raw + b'\nextra:\n' + b''.join(b'  ' * i + b'- \n' for i in range(1, n)))
    elif kind == 'bomb':
        lines = [b'a0: &a0 [lol, lol, lol, lol, lol, lol, lol, lol, lol]']
        lines += [f'a{i}: &a{i} [{", ".join([f"*a{i - 1}"] * 9)}]'.encode() for i in range(1, 10)]
        b = bytearray(raw + b'\n' + b'\n'.join(lines) + b'\n')
    elif kind == 'huge':
        text = raw.decode()
        numbers = [tok for tok in text.replace(',', ' ').replace('}', ' ').split() if
                   tok.replace('.', '', 1).replace('e', '', 1).replace('-', '').isdigit()]
        new = rng.choice(['1e309', '-1e308', '9' * 5000, '1' + '0' * 400, '.inf', '0x' + 'f' * 300])
        if numbers:
            old = rng.choice(numbers)
            text = text.replace(old, new, 1)
        b = bytearray(text.encode())
    elif kind == 'oversize':
        b = bytearray(raw + b'\n#' + b'x' * (1 << 20))
    return kind, bytes(b)


def test_fuzz_scene_file_bytes_through_cvj_sim_simulate(tmp_path: Path) -> None:
    bases = _scene_bases()
    kinds: dict[str, list[int]] = {}
    for case in range(N_SCENE_CASES):
        rng = random.Random(case)
        kind, data = mutate_scene(rng, rng.choice(bases))
        path = tmp_path / f'scene_{case}.yaml'
        path.write_bytes(data)
        code, out, err = _run_cli(['simulate', str(path), '--duration', '0.003', '--sample-dt', '0.001',
                                   '--json'])
        _check_outcome(f'scene case {case} ({kind})', code, out, err, json_out=True)
        kinds.setdefault(kind, [0, 0])[code == 0] += 1
        path.unlink()
    print(f'\nraw scene fuzz: {N_SCENE_CASES} cases; (rejected, accepted) by mutation: {kinds}')
    rejected = sum(v[0] for v in kinds.values())
    accepted = sum(v[1] for v in kinds.values())
    assert rejected > N_SCENE_CASES // 2 and accepted > 10      # both outcomes are explored


# --------------------------------------------------------------------------------- bags

def _synthetic_module():
    import importlib.util
    spec = importlib.util.spec_from_file_location('_synthetic_bag_raw', Path(__file__).parents[1] / 'test_analysis.py')
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(scope='module')
def base_bags(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp('fuzz_bags')
    synth = _synthetic_module()
    return {storage: synth.write_synthetic_bag(root / storage, storage=storage, duration=0.3)
            for storage in ('mcap', 'sqlite3')}


def _storage_file(d: Path) -> Path:
    return next(p for p in d.iterdir() if p.suffix in ('.mcap', '.db3'))


def mutate_bag(rng: random.Random, d: Path) -> str:
    """Damage the bag directory ``d`` in place; returns a description."""
    target = rng.choice(['data', 'data', 'data', 'meta'])
    if target == 'data':
        f = _storage_file(d)
        b = bytearray(f.read_bytes())
        kind = rng.choice(['truncate', 'truncate_nometa', 'bitflip', 'overwrite', 'zeros', 'append'])
        if kind.startswith('truncate'):
            del b[rng.randrange(len(b) + 1):]
            if kind == 'truncate_nometa':         # what a hard kill leaves
                (d / 'metadata.yaml').unlink()
        elif kind == 'bitflip':
            for _ in range(rng.randint(1, 16)):
                i = rng.randrange(len(b))
                b[i] ^= 1 << rng.randrange(8)
        elif kind in ('overwrite', 'zeros'):
            i = rng.randrange(len(b))
            n = rng.randint(1, 4096)
            b[i:i + n] = rng.randbytes(n) if kind == 'overwrite' else bytes(n)
        else:
            b += rng.randbytes(rng.randint(1, 2000))
        f.write_bytes(bytes(b))
        return f'{f.suffix} {kind}'
    meta = d / 'metadata.yaml'
    raw = meta.read_bytes()
    kind = rng.choice(['delete', 'truncate', 'bitflip', 'random', 'field', 'field', 'list'])
    if kind == 'delete':
        meta.unlink()
    elif kind == 'truncate':
        meta.write_bytes(raw[:rng.randrange(len(raw) + 1)])
    elif kind == 'bitflip':
        b = bytearray(raw)
        for _ in range(rng.randint(1, 8)):
            i = rng.randrange(len(b))
            b[i] ^= 1 << rng.randrange(8)
        meta.write_bytes(bytes(b))
    elif kind == 'random':
        meta.write_bytes(rng.randbytes(rng.randint(0, 500)))
    elif kind == 'list':
        meta.write_text('- 1\n- 2\n')
    else:
        data = yaml.safe_load(raw)
        info = data['rosbag2_bagfile_information']
        key = rng.choice(sorted(info))
        info[key] = rng.choice([None, 'x', -1, 10**30, [], {'a': 1}, 1.5, '../../etc/passwd', True])
        meta.write_text(yaml.safe_dump(data))
        kind = f'field {key}'
    return f'metadata.yaml {kind}'


def test_fuzz_bag_bytes_through_analyze_replay_and_reindex(base_bags: dict[str, Path], tmp_path: Path,
                                                          ctx) -> None:
    fuzz_bags(base_bags, tmp_path, ctx, N_BAG_CASES_CI)


@pytest.mark.slow
def test_fuzz_bag_bytes_all_cases(base_bags: dict[str, Path], tmp_path: Path, ctx) -> None:
    fuzz_bags(base_bags, tmp_path, ctx, N_BAG_CASES)


def fuzz_bags(base_bags: dict[str, Path], tmp_path: Path, ctx, n_cases: int) -> None:
    """Cases 0..n_cases-1 (case k uses random.Random(k)): the first cases are the same
    in both tests."""
    from rclpy.parameter import Parameter

    from cvj_ros.nodes.replay_node import ReplayNode
    outcomes: dict[str, list[int]] = {}
    for case in range(n_cases):
        rng = random.Random(case)
        storage = rng.choice(sorted(base_bags))
        d = tmp_path / f'bag_{case}'
        shutil.copytree(base_bags[storage], d)
        what = f'bag case {case} ({storage}: {mutate_bag(rng, d)})'
        code, out, err = _run_cli(['analyze', str(d), '--json'])
        _check_outcome(what + ' analyze', code, out, err, json_out=True)
        try:                                   # the replay node's reading path (cvj-sim replay)
            node = ReplayNode(context=ctx, parameter_overrides=[Parameter('bag', value=str(d))],
                              autostart=False)
            node.destroy_node()
            replay_ok = 1
        except CvjError as exc:
            assert str(exc).startswith('bag: '), f'{what} replay: {exc}'
            replay_ok = 0
        code_r, out_r, err_r = _run_cli(['reindex', str(d)])
        _check_outcome(what + ' reindex', code_r, out_r, err_r, json_out=False)
        if code_r == 0:
            code2, out2, err2 = _run_cli(['analyze', str(d), '--json'])
            _check_outcome(what + ' analyze after reindex', code2, out2, err2, json_out=True)
        stats = outcomes.setdefault(what.split('(')[1].split(':')[0], [0, 0, 0, 0])
        stats[0] += code == 0
        stats[1] += replay_ok
        stats[2] += code_r == 0
        stats[3] += 1
        shutil.rmtree(d)
    print(f'\nbag fuzz: {n_cases} cases; per storage [analyze ok, replay read ok, reindex ok, cases]: '
          f'{outcomes}')
    total_reindexed = sum(v[2] for v in outcomes.values())
    assert total_reindexed > n_cases // 4      # reindex really recovers damaged bags
