"""Batched bag writes of the composed-mode recorder (cvj_ros.bag.BatchingWriter,
cvj_ros.bag.BagWriter.write_batch): the same bag as one write per message, counts at once."""
from __future__ import annotations

from pathlib import Path

import pytest

from cvj_ros import bag
from cvj_ros.bag import BatchingWriter


def _messages() -> list[tuple[str, int, bytes]]:
    # /clock CDR: encapsulation header + sec + nanosec (the stamp is all a Clock holds)
    out = []
    for k in range(10):
        sec, nsec = divmod(k * 1_000_000, 1_000_000_000)
        out.append(('/clock', k * 1_000_000, b'\x00\x01\x00\x00' + sec.to_bytes(4, 'little')
                    + nsec.to_bytes(4, 'little')))
    return out


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_batched_writes_give_the_same_bag(tmp_path: Path, storage: str) -> None:
    msgs = _messages()
    with bag.BagWriter(tmp_path / 'one', storage=storage) as w:
        w.add_topic('/clock')
        for m in msgs:
            w.write(*m)
    w2 = bag.BagWriter(tmp_path / 'batched', storage=storage)
    front = BatchingWriter(w2, batch=4)
    front.add_topic('/clock')
    for i, m in enumerate(msgs):
        front.write(*m)
        assert front.counts['/clock'] == i + 1          # counted at once, handed over later
    assert w2.counts['/clock'] == 8                     # two full batches of 4 handed over
    front.flush()
    assert w2.counts['/clock'] == 10
    w2.close()
    assert bag.read_raw(tmp_path / 'one') == bag.read_raw(tmp_path / 'batched')


def test_write_batch_rejects_unregistered_topic(tmp_path: Path) -> None:
    with bag.BagWriter(tmp_path / 'b') as w:
        with pytest.raises(bag.BagError, match='/nope: topic not registered'):
            w.write_batch([('/nope', 0, b'')])
