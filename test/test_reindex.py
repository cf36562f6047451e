"""`cvj-sim reindex` (cvj_ros.reindex) on bags damaged the way a hard kill damages them.

The salvaged messages must be byte-identical to the originals (same topic, record time and
CDR bytes), a prefix of them in record-time order; metadata.yaml is rebuilt with topics,
types, counts, time range, storage id and custom data. Synthetic bags: test_analysis.py.
"""
from __future__ import annotations

import importlib.util
import shutil
from pathlib import Path

import pytest

from cvj_ros import bag
from cvj_ros.cli import main as cli_main
from cvj_ros.errors import BagError
from cvj_ros.reindex import reindex

_spec = importlib.util.spec_from_file_location('_synthetic_bag_reindex', Path(__file__).parent / 'test_analysis.py')
_synth = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(_synth)


@pytest.fixture(scope='module')
def originals(tmp_path_factory: pytest.TempPathFactory) -> dict[str, tuple[Path, list]]:
    root = tmp_path_factory.mktemp('reindex_src')
    out = {}
    for storage in ('mcap', 'sqlite3'):
        p = _synth.write_synthetic_bag(root / storage, storage=storage, duration=0.5)
        out[storage] = (p, bag.read_raw(p))
    return out


def _copy(src: Path, dst: Path) -> Path:
    shutil.copytree(src, dst)
    return dst


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_missing_metadata_rebuilt_with_every_message(originals, tmp_path: Path, storage: str) -> None:
    src, raw = originals[storage]
    d = _copy(src, tmp_path / 'bag')
    custom = bag.bag_info(d).custom_data
    (d / 'metadata.yaml').unlink()
    with pytest.raises(BagError, match=f'cvj-sim reindex {d}'):
        bag.bag_info(d)
    res = reindex(d)
    assert res.storage == storage and res.damage == ''           # the file itself was complete
    assert bag.read_raw(d) == raw                                 # nothing lost, bytes identical
    info = bag.bag_info(d)
    assert info.storage == storage and sum(info.counts.values()) == len(raw)
    assert info.start == pytest.approx(raw[0][2] * 1e-9) and info.end == pytest.approx(raw[-1][2] * 1e-9)
    # custom data: metadata.yaml was gone, so it comes from the /driveline/scene message
    assert 'cvj_ros.scene' in info.custom_data and info.custom_data['cvj_ros.seed'] == '7'
    assert set(custom) <= set(info.custom_data) | {'cvj_ros.scene'}
    assert (d / (res.kept_original[0].name)).exists()             # original kept as *.orig


@pytest.mark.parametrize('keep', [0.8, 0.5, 0.2])
def test_truncated_mcap_recovers_the_complete_messages_of_the_cut_chunk(originals, tmp_path: Path,
                                                                         keep: float) -> None:
    """The synthetic bag is one uncompressed chunk (rosbags closes chunks at 1 MiB): every
    cut lands inside it; the messages before the cut are recovered, in order, byte-identical."""
    src, raw = originals['mcap']
    d = _copy(src, tmp_path / 'bag')
    (d / 'metadata.yaml').unlink()
    f = next(d.glob('*.mcap'))
    data = f.read_bytes()
    f.write_bytes(data[:int(len(data) * keep)])
    res = reindex(d)
    assert 'cut short' in res.damage
    got = bag.read_raw(d)
    n = len(got)
    assert 0 < n < len(raw)
    got_set = set(got)
    assert got_set <= set(raw)                                    # byte-identical messages
    t_last = max(m[2] for m in got)                               # the data was written in time order:
    assert all(m in got_set for m in raw if m[2] < t_last)        # no hole before the cut


def test_reindex_cli_report_and_errors(originals, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    src, raw = originals['mcap']
    d = _copy(src, tmp_path / 'bag')
    assert cli_main(['reindex', str(d)]) == 0
    out = capsys.readouterr().out
    assert out.startswith(f'reindexed {d} (mcap): {len(raw)} messages on ')
    empty = tmp_path / 'empty'
    empty.mkdir()
    assert cli_main(['reindex', str(empty)]) == 2
    assert capsys.readouterr().err == f'cvj-sim: error: {empty}: no .mcap or .db3 file to reindex\n'
    junk = tmp_path / 'junk'
    junk.mkdir()
    (junk / 'junk.mcap').write_bytes(b'not an mcap file at all')
    assert cli_main(['reindex', str(junk)]) == 2
    assert capsys.readouterr().err == (f'cvj-sim: error: {junk / "junk.mcap"}: not an MCAP file '
                                       '(no MCAP magic at the start)\n')
    assert cli_main(['reindex', str(tmp_path / 'nope')]) == 2
    assert capsys.readouterr().err == f'cvj-sim: error: {tmp_path / "nope"}: no such bag\n'


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_bag_writer_puts_all_but_the_last_flush_span_on_disk_while_open(tmp_path: Path, storage: str) -> None:
    """BagWriter's flush policy (cvj_ros/bag.py FLUSH_SIM_SPAN_S): with the writer still open
    (as at a SIGKILL), a copy of what is on disk, reindexed, holds every message up to at
    most FLUSH_SIM_SPAN_S (+ one 1 ms step) before the newest one written."""
    import time

    from cvj_ros.bag import FLUSH_SIM_SPAN_S, BagWriter, typestore
    ts = typestore()
    Clock, Time = ts.types['rosgraph_msgs/msg/Clock'], ts.types['builtin_interfaces/msg/Time']
    writer = BagWriter(tmp_path / 'live', storage=storage)
    writer.add_topic('/clock')
    n = 1001                                                       # 0 .. 1.0 s at 1 ms
    for k in range(n):
        t_ns = k * 1_000_000
        cdr = ts.serialize_cdr(Clock(clock=Time(sec=t_ns // 10**9, nanosec=t_ns % 10**9)),
                               'rosgraph_msgs/msg/Clock')
        writer.write('/clock', t_ns, cdr)
    t_newest = (n - 1) * 1e-3
    deadline = time.monotonic() + 10.0                             # the writer thread catches up
    recovered = -1.0
    try:
        while time.monotonic() < deadline:
            snap = tmp_path / f'snap{int(time.monotonic() * 1e3)}'
            # a rollback journal exists only while SQLite sets the bag up (it records in
            # write-ahead-log mode, cvj_ros/bag.py), the -shm index is rebuilt from the -wal:
            # neither is what a kill leaves to recover, and either may vanish mid-copy
            shutil.copytree(tmp_path / 'live', snap,
                            ignore=shutil.ignore_patterns('*-journal', '*-shm'))
            try:
                reindex(snap)
                recovered = bag.bag_info(snap).end
            except BagError:
                pass                                               # nothing flushed yet
            if recovered >= t_newest - FLUSH_SIM_SPAN_S - 1e-3:
                break
            time.sleep(0.05)                                       # poll interval, bounded above
    finally:
        writer.close()
    assert recovered >= t_newest - FLUSH_SIM_SPAN_S - 1e-3, recovered


@pytest.mark.parametrize('keep', [0.35, 0.62, 0.9])
def test_truncated_sqlite3_yields_what_its_intact_pages_hold(tmp_path: Path, keep: float) -> None:
    """A sqlite3 bag cut short (copy interrupted, disk full) is refused by SQLite ('database
    disk image is malformed'); reindex reads its intact pages instead: the messages it
    recovers are the first ones written, byte for byte, about as many as the file kept
    (rows are appended to leaf pages in insertion order; the index b-tree's pages are
    interleaved, so the fraction is a little lower than the file's)."""
    from cvj_ros.bag import BagWriter, typestore
    ts = typestore()
    Clock, Time = ts.types['rosgraph_msgs/msg/Clock'], ts.types['builtin_interfaces/msg/Time']
    Float64 = ts.types['std_msgs/msg/Float64']
    src = tmp_path / 'src'
    writer = BagWriter(src, storage='sqlite3')
    writer.add_topic('/clock')
    writer.add_topic('/engine/throttle')
    written = []
    for k in range(6000):
        t_ns = k * 1_000_000
        clock = ts.serialize_cdr(Clock(clock=Time(sec=t_ns // 10**9, nanosec=t_ns % 10**9)),
                                 'rosgraph_msgs/msg/Clock')
        written.append(('/clock', t_ns, bytes(clock)))
        if k % 7 == 0:      # a second topic with larger messages
            written.append(('/engine/throttle', t_ns,
                            bytes(ts.serialize_cdr(Float64(data=k / 6000), 'std_msgs/msg/Float64'))))
    writer.write_batch(written)
    writer.close()
    bad = _copy(src, tmp_path / 'cut')
    (bad / 'metadata.yaml').unlink()
    db = next(bad.glob('*.db3'))
    size = db.stat().st_size
    with open(db, 'r+b') as fh:
        fh.truncate(int(size * keep) + 1234)                     # mid-page too
    res = reindex(bad)
    assert 'SQLite refused the file' in res.damage and 'intact pages' in res.damage
    got = [(t, ts_, bytes(d)) for t, _ty, ts_, d in bag.read_raw(bad)]
    n = len(got)
    assert got == sorted(written[:n], key=lambda m: m[1]), 'not the first messages written'
    assert (keep - 0.1) * len(written) <= n <= (keep + 0.02) * len(written) + 100, (n, len(written))
