"""Batch decoding of the project's own CDR messages read from a bag (numpy, no ROS).

A bag of a run holds one joint state, one /clock and one answer per topic per exchange
step, all with one layout: the same byte length, frame_id and joint names in every message.
:class:`SeriesBuilder` collects the raw messages of one topic and decodes them ``batch`` at a
time: the messages are joined into an (m, L) uint8 array, every byte outside the stamps, the
float64 values and the alignment padding (left uninitialised by rclpy) is compared with the
topic's first message, and the stamps and values are read as strided views. A batch that is
not one layout (other sizes, other names, big-endian CDR) is decoded message by message
through rosbags, with the same rules as before (``cvj_ros.bag._to_series``). Results go into
arrays allocated once for the topic's message count, so reading a bag holds its raw bytes
for at most one batch per topic.

Messages that are not the run's are left out and counted (:attr:`SeriesBuilder.foreign`),
never a reason to refuse the bag: a joint state whose names differ from the run's (the
``shaft_names`` of the bag's ``/driveline/scene``, else the first joint state's), and any
message that does not decode (another publisher's bytes recorded by ``cvj-sim record``).

Layouts (OMG CDR little endian, encapsulation ``00 01 00 00``; offsets are from the start of
the message, alignment relative to byte 4):
* ``std_msgs/Header``: ``int32 sec`` at 4, ``uint32 nanosec`` at 8, frame_id (uint32 length
  incl. NUL, bytes) at 12;
* ``sensor_msgs/JointState``: header, ``name`` (uint32 count, strings), then ``position``,
  ``velocity``, ``effort`` (uint32 count, float64 values 8-aligned);
* ``geometry_msgs/WrenchStamped``: header, force x y z, torque x y z (float64, 8-aligned);
* ``rosgraph_msgs/Clock``: ``int32 sec`` at 4, ``uint32 nanosec`` at 8 (12 bytes).
"""
from __future__ import annotations

import itertools
import struct
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

__all__ = ['BATCH', 'SeriesBuilder', 'as_bytes', 'batch_decodable', 'joint_state_layout',
           'mcap_log_time_parts', 'mcap_log_times', 'mcap_messages', 'wrench_layout']

#: messages decoded at once per topic (a few MiB of raw bytes at most)
BATCH = 8192
#: uncompressed mcap chunks whose indexed messages are gathered at once (0.1 s chunks of a
#: run: ~1.6 MiB), at most BYTES_AT_ONCE of them (rosbags' own chunks reach 1 MiB each)
CHUNKS_AT_ONCE = 16
BYTES_AT_ONCE = 2 << 20

JOINT_STATE = 'sensor_msgs/msg/JointState'
WRENCH = 'geometry_msgs/msg/WrenchStamped'
CLOCK = 'rosgraph_msgs/msg/Clock'
_U32 = struct.Struct('<I')


class Layout:
    """Byte layout of one message: ``size`` (bytes), ``fixed`` ([start, end) ranges that
    must equal the reference message's), ``starts`` (byte offsets of the float64 arrays),
    ``n`` (values per array), ``ref`` (the reference message as a uint8 array)."""
    __slots__ = ('size', 'fixed', 'starts', 'n', 'ref')

    def __init__(self, data: bytes, fixed: list[tuple[int, int]], starts: list[int], n: int) -> None:
        self.size = len(data)
        self.fixed = fixed
        self.starts = starts
        self.n = n
        self.ref = np.frombuffer(data, dtype=np.uint8)


def _string_end(data: bytes, at: int) -> int:
    """Offset after the CDR string (uint32 length incl. NUL, bytes) at ``at``."""
    return at + 4 + _U32.unpack_from(data, at)[0]


def joint_state_layout(data: bytes) -> Layout | None:
    """The :class:`Layout` of a little-endian JointState whose three arrays hold one value
    per name, else None."""
    try:
        if len(data) < 16 or data[1] != 1:
            return None
        end = _string_end(data, 12)                  # frame_id
        fixed = [(12, end)]
        off = end + (-(end - 4)) % 4
        count = _U32.unpack_from(data, off)[0]
        fixed.append((off, off + 4))
        off += 4
        for _ in range(count):
            off += (-(off - 4)) % 4
            end = _string_end(data, off)
            fixed.append((off, end))
            off = end
        starts = []
        for _ in range(3):
            off += (-(off - 4)) % 4
            if _U32.unpack_from(data, off)[0] != count:
                return None
            fixed.append((off, off + 4))
            off += 4
            if count:
                off += (-(off - 4)) % 8
            starts.append(off)
            off += 8 * count
    except struct.error:
        return None
    return Layout(data, fixed, starts, count) if off == len(data) else None


def wrench_layout(data: bytes) -> Layout | None:
    """The :class:`Layout` of a little-endian WrenchStamped (force then torque, 6 float64)."""
    try:
        if len(data) < 16 or data[1] != 1:
            return None
        end = _string_end(data, 12)
    except struct.error:
        return None
    off = end + (-(end - 4)) % 8
    return Layout(data, [(12, end)], [off], 6) if off + 48 == len(data) else None


def batch_decodable(msgtype: str) -> bool:
    """Whether :class:`SeriesBuilder` decodes ``msgtype`` in batches."""
    return msgtype in (JOINT_STATE, WRENCH, CLOCK)


def as_bytes(segment: Any) -> list[bytes]:
    """A segment of messages (list of bytes or (m, L) uint8 rows) as a list of bytes."""
    return [r.tobytes() for r in segment] if isinstance(segment, np.ndarray) else segment


def _rows(batch: Sequence[bytes], layout: Layout) -> np.ndarray | None:
    """The batch as an (m, size) uint8 array when every message has the layout, else None."""
    size = layout.size
    if any(len(d) != size for d in batch):
        return None
    return _check_rows(np.frombuffer(b''.join(batch), dtype=np.uint8).reshape(len(batch), size),
                       layout)


def _check_rows(buf: np.ndarray, layout: Layout) -> np.ndarray | None:
    """``buf`` ((m, size) uint8) when every row has the layout (little endian, the fixed
    byte ranges of the reference message), else None."""
    if np.any(buf[:, 1] != 1):
        return None
    ref = layout.ref
    for a, b in layout.fixed:
        if a < b and not np.array_equal(buf[:, a:b], np.broadcast_to(ref[a:b], (buf.shape[0], b - a))):
            return None
    return buf


def _stamps_ns(buf: np.ndarray) -> np.ndarray:
    """Header (or /clock) stamps of the rows (int64 ns)."""
    sec = np.ascontiguousarray(buf[:, 4:8]).view('<i4')[:, 0].astype(np.int64)
    nsec = np.ascontiguousarray(buf[:, 8:12]).view('<u4')[:, 0].astype(np.int64)
    return sec * 1_000_000_000 + nsec


def _values(buf: np.ndarray, start: int, n: int) -> np.ndarray:
    """(m, n) float64 values at byte ``start`` of every row."""
    return np.ascontiguousarray(buf[:, start:start + 8 * n]).view('<f8')


class SeriesBuilder:
    """Collects one topic's raw messages (:meth:`add`) and builds its arrays (:meth:`finish`).

    Args:
        msgtype: ``sensor_msgs/msg/JointState``, ``geometry_msgs/msg/WrenchStamped`` or
            ``rosgraph_msgs/msg/Clock``.
        capacity: expected message count (the bag's count for the topic); the arrays grow
            if more come.
        deserialize: ``(raw, msgtype) -> message`` for messages outside the layout (rosbags).
        names: the run's joint names (JointState); None = the first decodable joint state's.
            Joint states with other names are left out and counted in :attr:`foreign`.
        columns: JointState arrays to keep (subset of position, velocity, effort).
        batch: messages decoded at once (default :data:`BATCH`).
    """

    def __init__(self, msgtype: str, capacity: int, deserialize: Callable[[bytes, str], Any], *,
                 names: Sequence[str] | None = None,
                 columns: Sequence[str] = ('position', 'velocity', 'effort'),
                 batch: int | None = None) -> None:
        if not batch_decodable(msgtype):
            raise ValueError(f'{msgtype}: not batch decodable')
        self.msgtype = msgtype
        self.deserialize = deserialize
        #: messages left out: not the run's joint names, or not decodable
        self.foreign = 0
        self._expected = list(names) if names else None
        self.columns = tuple(columns)
        self.batch = BATCH if batch is None else batch
        self.capacity = max(int(capacity), 1)
        self.n = 0
        self.record_ns = np.empty(self.capacity, dtype=np.int64)
        self.stamp_ns = np.empty(self.capacity, dtype=np.int64)
        self.values: dict[str, np.ndarray] = {}
        self.layout: Layout | None = None
        self.names: list[str] | None = None
        self.frame_id = ''
        self.width = 0
        self._segments: list[Any] = []        # lists of bytes or (m, L) uint8 arrays
        self._rec: list[int] = []
        self._pending = 0
        self._learned = False
        if self._expected is not None and msgtype == JOINT_STATE:
            self.names, self.width = list(self._expected), len(self._expected)
            for c in self.columns:
                self.values[c] = np.full((self.capacity, self.width), np.nan)

    # --- collecting ---------------------------------------------------------------------

    def add(self, record_ns: int, raw: bytes | memoryview) -> None:
        """One message (record time ns, raw CDR)."""
        self.add_many([record_ns], [bytes(raw)])

    def add_many(self, record_ns: list[int], raws: Any) -> None:
        """Messages (record times ns, raw CDR) in order; ``raws`` a list of bytes or an (m, L)
        uint8 array of m messages of L bytes each (:func:`mcap_messages`)."""
        self._segments.append(raws)
        self._rec.extend(record_ns)
        self._pending += len(raws)
        if self._pending >= self.batch:
            self._decode()

    def _decode_one(self, data: bytes) -> Any:
        """The message through rosbags, or None when it does not decode (counted foreign)."""
        try:
            return self.deserialize(data, self.msgtype)
        except Exception:  # noqa: BLE001 (rosbags raises several types for bad CDR)
            self.foreign += 1
            return None

    def _first(self, data: bytes) -> bool:
        """Learn the topic's reference message: layout, names/frame, array widths; False
        (and counted foreign) when ``data`` is not the run's (does not decode; a joint state
        with other names than the expected ones)."""
        msg = self._decode_one(data)
        if msg is None:
            return False
        if self.msgtype == JOINT_STATE:
            names = list(msg.name)
            if self._expected is not None and names != self._expected:
                self.foreign += 1
                return False
            self.names = names
            self.frame_id = str(msg.header.frame_id)
            self.width = len(self.names)
            self.layout = joint_state_layout(data)
            if self.layout is not None and self.layout.n != self.width:
                self.layout = None
            for c in self.columns:
                self.values[c] = np.full((self.capacity, self.width), np.nan)
        elif self.msgtype == WRENCH:
            self.frame_id = str(msg.header.frame_id)
            self.width = 6
            self.layout = wrench_layout(data)
            self.values['wrench'] = np.empty((self.capacity, 6))
        else:
            self.width = 0
            self.layout = None if len(data) != 12 or data[1] != 1 else Layout(data, [], [], 0)
        return True

    def _grow(self, need: int) -> None:
        if need <= self.capacity:
            return
        cap = max(need, 2 * self.capacity)
        for name in ('record_ns', 'stamp_ns'):
            arr = getattr(self, name)
            new = np.empty(cap, dtype=arr.dtype)
            new[:self.n] = arr[:self.n]
            setattr(self, name, new)
        for key, arr in self.values.items():
            new = np.full((cap, arr.shape[1]), np.nan)
            new[:self.n] = arr[:self.n]
            self.values[key] = new
        self.capacity = cap

    def _decode(self) -> None:
        segments, rec = self._segments, self._rec
        if not segments:
            return
        self._segments, self._rec, self._pending = [], [], 0
        skip = 0                   # leading messages already refused (counted) by _first
        if not self._learned:
            rows = (r.tobytes() if isinstance(r, np.ndarray) else r for g in segments for r in g)
            for data in itertools.islice(rows, 64):
                self._learned = self._first(data)
                if self._learned:
                    break
                skip += 1
        m = len(rec)
        self._grow(self.n + m)
        lo, hi = self.n, self.n + m
        buf = None
        if self.layout is not None and skip == 0:
            if all(isinstance(g, np.ndarray) and g.shape[1] == self.layout.size for g in segments):
                buf = _check_rows(np.concatenate(segments) if len(segments) > 1 else segments[0],
                                  self.layout)
            else:
                buf = _rows([r for g in segments for r in as_bytes(g)], self.layout)
        if buf is not None:
            self.record_ns[lo:hi] = rec
            self.stamp_ns[lo:hi] = _stamps_ns(buf)
            if self.msgtype == JOINT_STATE:
                for c, start in zip(('position', 'velocity', 'effort'), self.layout.starts):
                    if c in self.values:
                        self.values[c][lo:hi] = _values(buf, start, self.width)
            elif self.msgtype == WRENCH:
                self.values['wrench'][lo:hi] = _values(buf, self.layout.starts[0], 6)
            self.n = hi
            return
        i = lo
        j = 0
        for g in segments:
            for data in as_bytes(g):
                if j < skip:
                    j += 1
                    continue
                if not self._learned:
                    self._learned = self._first(data)
                    if not self._learned:
                        j += 1
                        continue
                if self._one(i, data):
                    self.record_ns[i] = rec[j]
                    i += 1
                j += 1
        self.n = i

    def _one(self, i: int, data: bytes) -> bool:
        """Row ``i`` from one message decoded by rosbags (the rules of bag._to_series); False
        (counted foreign) when it does not decode or is a joint state with other names."""
        msg = self._decode_one(data)
        if msg is None:
            return False
        if self.msgtype == CLOCK:
            self.stamp_ns[i] = msg.clock.sec * 1_000_000_000 + msg.clock.nanosec
            return True
        if self.msgtype == JOINT_STATE and list(msg.name) != self.names:
            self.foreign += 1
            return False
        self.stamp_ns[i] = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        if self.msgtype == WRENCH:
            w = msg.wrench
            self.values['wrench'][i] = (w.force.x, w.force.y, w.force.z,
                                        w.torque.x, w.torque.y, w.torque.z)
            return True
        for c in self.columns:
            v = np.asarray(getattr(msg, c), dtype=float)
            self.values[c][i] = v if v.size == self.width else np.nan
        return True

    # --- result -------------------------------------------------------------------------

    def finish(self) -> dict[str, Any]:
        """``{'record_ns', 'stamp_ns', <columns> or 'wrench', 'names', 'frame_id', 'foreign'}``
        trimmed to the messages read (views, no copies); ``foreign``: messages left out."""
        self._decode()
        n = self.n
        out: dict[str, Any] = {'record_ns': self.record_ns[:n], 'stamp_ns': self.stamp_ns[:n],
                               'names': list(self.names or self._expected or []),
                               'frame_id': self.frame_id, 'foreign': self.foreign}
        for key, arr in self.values.items():
            out[key] = arr[:n]
        if n > 1 and np.any(out['record_ns'][1:] < out['record_ns'][:-1]):
            # read in file order: into record-time order as rosbags gives it (stable)
            order = np.argsort(out['record_ns'], kind='stable')
            for key in ('record_ns', 'stamp_ns', *self.values):
                out[key] = out[key][order]
        return out


# --- raw messages of an uncompressed mcap file, streamed --------------------------------------

_MCAP_MAGIC = b'\x89MCAP0\r\n'
_REC = struct.Struct('<BQ')           # opcode, record length
_MSG = struct.Struct('<HIQQ')         # channel id, sequence, log time, publish time
_CHUNK = struct.Struct('<QQQI')       # start, end, uncompressed size, crc


class NotPlain(Exception):
    """The file is not what :func:`mcap_messages` reads (compressed chunks, damage): read it
    through rosbags instead."""


def mcap_messages(path: str, topics: set[str] | None = None) -> Any:
    """The messages of an mcap file, one chunk at a time in file order, as ``{topic: ([log
    time ns], [raw CDR])}`` (rosbags' reader costs ~13-50 us per message here, in a
    generator per message; this a few us). Only uncompressed chunks (what cvj_ros writes); raises
    :class:`NotPlain` for anything else (compressed chunk, damaged or cut record) - the
    caller then reads the bag through rosbags, which names the damage. Stops at DataEnd.
    ``topics``: only these topics' messages."""
    channels: dict[int, str | None] = {}
    batch: list[tuple[bytes, int, int, list[tuple[int, bytes]]]] = []
    with open(path, 'rb') as fh:
        if fh.read(8) != _MCAP_MAGIC:
            raise NotPlain('no MCAP magic')
        while True:
            head = fh.read(9)
            if len(head) < 9:
                raise NotPlain('file ends without DataEnd')
            op, length = _REC.unpack(head)
            if op == 0x06:                                   # Chunk
                if length > 1 << 31:
                    raise NotPlain('chunk too large')
                data = fh.read(length)
                if len(data) != length:
                    raise NotPlain('chunk cut short')
                _start, _end, size, _crc = _CHUNK.unpack_from(data, 0)
                clen = _U32.unpack_from(data, 28)[0]
                if clen:
                    raise NotPlain('compressed chunk')
                pos = 32 + 8
                end = pos + struct.unpack_from('<Q', data, 32)[0]
                if end > len(data) or end - pos != size:
                    raise NotPlain('chunk sizes disagree')
                indexes = _message_indexes(fh)
                if not indexes or any(cid not in channels for cid, _pairs in indexes):
                    # channels defined in this chunk, or no indexes: walk its records
                    if batch:
                        yield _indexed_messages(batch, channels)
                        batch = []
                    yield from _chunk_messages(data, pos, end, channels, topics)
                else:
                    batch.append((data, pos, end, indexes))
                    if len(batch) >= CHUNKS_AT_ONCE or sum(len(b[0]) for b in batch) >= BYTES_AT_ONCE:
                        yield _indexed_messages(batch, channels)
                        batch = []
            elif op == 0x04:                                 # Channel (outside chunks)
                data = fh.read(length)
                _channel(data, 0, channels, topics)
            elif op == 0x05:                                 # Message outside a chunk
                if batch:
                    yield _indexed_messages(batch, channels)
                    batch = []
                data = fh.read(length)
                cid, _seq, log_time, _pub = _MSG.unpack_from(data, 0)
                topic = channels.get(cid, False)
                if topic is False:
                    raise NotPlain(f'message on unknown channel {cid}')
                if topic is not None:
                    yield {topic: ([log_time], [data[22:]])}
            elif op == 0x0F or op == 0x02:                   # DataEnd / Footer
                if batch:
                    yield _indexed_messages(batch, channels)
                return
            else:
                fh.seek(length, 1)


def mcap_log_times(path: str, topic: str) -> np.ndarray | None:
    """:func:`mcap_log_time_parts` joined into one int64 array (ns), or None."""
    parts = mcap_log_time_parts(path, topic)
    if parts is None:
        return None
    return np.concatenate(parts) if parts else np.zeros(0, dtype=np.int64)


def mcap_log_time_parts(path: str, topic: str) -> list[np.ndarray] | None:
    """The log (record) times (int64 ns, file order, one array per chunk) of one topic's messages in an
    uncompressed mcap file, from the MessageIndex records after each chunk: chunk bodies are
    skipped (read only until the topic's channel is known), so this reads ~3 % of a run's
    bag. None when the file is not that (compressed or damaged chunk, a chunk without
    message indexes, the channel defined nowhere before its messages): the caller reads
    the messages instead."""
    channels: dict[int, str | None] = {}
    cid_of: int | None = None
    parts: list[np.ndarray] = []
    try:
        with open(path, 'rb') as fh:
            if fh.read(8) != _MCAP_MAGIC:
                return None
            while True:
                head = fh.read(9)
                if len(head) < 9:
                    return None
                op, length = _REC.unpack(head)
                if op == 0x06:                                   # Chunk
                    if cid_of is None:
                        data = fh.read(length)
                        if len(data) != length or _U32.unpack_from(data, 28)[0]:
                            return None
                        pos = 40
                        end = pos + struct.unpack_from('<Q', data, 32)[0]
                        if end > len(data):
                            return None
                        for _ in _chunk_messages(data, pos, end, channels, {topic}):
                            pass
                        cid_of = next((c for c, tp in channels.items() if tp == topic), None)
                    else:
                        fh.seek(length, 1)
                    indexes = _message_indexes(fh)
                    if not indexes:
                        return None
                    for cid, pairs in indexes:
                        if cid == cid_of and pairs:
                            tv = np.frombuffer(pairs, dtype='<u8').reshape(-1, 2)
                            order = np.argsort(tv[:, 1], kind='stable')          # file order
                            parts.append(tv[order, 0].astype(np.int64))
                elif op == 0x04:                                 # Channel (outside chunks)
                    _channel(fh.read(length), 0, channels, {topic})
                    cid_of = next((c for c, tp in channels.items() if tp == topic), cid_of)
                elif op == 0x05:                                 # Message outside a chunk
                    return None
                elif op == 0x0F or op == 0x02:                   # DataEnd / Footer
                    break
                else:
                    fh.seek(length, 1)
    except (OSError, NotPlain, struct.error, ValueError):
        return None
    return parts


def _message_indexes(fh: Any) -> list[tuple[int, bytes]]:
    """The MessageIndex records (0x07: channel id, then (log time, offset) pairs) that follow
    a chunk, as (channel id, pairs bytes); the file is left at the next other record."""
    out = []
    while True:
        head = fh.read(9)
        if len(head) < 9:
            fh.seek(-len(head), 1)
            return out
        op, length = _REC.unpack(head)
        if op != 0x07:
            fh.seek(-9, 1)
            return out
        body = fh.read(length)
        if len(body) != length or length < 6:
            raise NotPlain('message index cut short')
        cid, n = struct.unpack_from('<HI', body, 0)
        if 6 + n > length or n % 16:
            raise NotPlain('message index sizes disagree')
        out.append((cid, body[6:6 + n]))


def _indexed_messages(batch: list[tuple[bytes, int, int, list[tuple[int, bytes]]]],
                      channels: dict[int, str | None]) -> dict[str, Any]:
    """The wanted messages of a few chunks located through their message indexes, without
    walking their records: per topic ``(log times, rows)`` in file order, ``rows`` an (m, L)
    uint8 array when the topic's messages have one length L (the joint states, answers and
    /clock of a run), else a list of bytes. The chunks are joined so that one gather per
    topic serves :data:`CHUNKS_AT_ONCE` of them (per-chunk numpy calls cost more than the
    copying)."""
    big = np.frombuffer(b''.join(d for d, _p, _e, _i in batch), dtype=np.uint8)
    base = np.cumsum([0] + [len(d) for d, _p, _e, _i in batch[:-1]])
    per: dict[int, list[tuple[np.ndarray, np.ndarray, int]]] = {}
    for (data, pos, end, indexes), b0 in zip(batch, base.tolist()):
        for cid, pairs in indexes:
            if channels[cid] is not None and pairs:
                per.setdefault(cid, []).append((np.frombuffer(pairs, dtype='<u8'), b0 + pos, b0 + end))
    out: dict[str, Any] = {}

    def windows(width: int) -> np.ndarray:
        """(len(big) - width + 1, width) view: row i is big[i:i + width]."""
        return np.lib.stride_tricks.sliding_window_view(big, width)
    for cid, parts in per.items():
        tv = np.concatenate([p for p, _s, _e in parts]).reshape(-1, 2).astype(np.int64)
        counts = [p.size // 2 for p, _s, _e in parts]
        offs = tv[:, 1] + np.repeat([s0 for _p, s0, _e in parts], counts)
        ends = np.repeat([e0 for _p, _s, e0 in parts], counts)
        order = np.argsort(offs, kind='stable')                       # file order
        times, offs, ends = tv[order, 0], offs[order], ends[order]
        if np.any(offs + 31 > ends) or np.any(big[offs] != 0x05):
            raise NotPlain('message index points outside the chunk\'s messages')
        lens = windows(8)[offs + 1].view('<u8')[:, 0].astype(np.int64)
        if np.any(offs + 9 + lens > ends) or np.any(lens < 22):
            raise NotPlain('message record runs past its chunk')
        if np.all(lens == lens[0]):
            # rows of a strided view, one contiguous copy per row (an (m, L) index array
            # gathered byte by byte cost ~7x more)
            rows = windows(int(lens[0]) - 22)[offs + 31]
        else:
            rows = [big[o + 31:o + 9 + n].tobytes() for o, n in zip(offs.tolist(), lens.tolist())]
        out[channels[cid]] = (times.tolist(), rows)
    return out


def _channel(data: bytes, pos: int, channels: dict[int, str | None], topics: set[str] | None) -> None:
    cid = struct.unpack_from('<H', data, pos)[0]
    n = _U32.unpack_from(data, pos + 4)[0]
    topic = data[pos + 8:pos + 8 + n].decode('utf-8')
    channels[cid] = topic if topics is None or topic in topics else None


def _chunk_messages(data: bytes, pos: int, end: int, channels: dict[int, str | None],
                    topics: set[str] | None) -> Any:
    """The messages of one uncompressed chunk's records as ``{topic: ([log time ns],
    [raw CDR])}`` (one dict per chunk: the caller hands each topic's lists on at once)."""
    unpack_rec, unpack_msg = _REC.unpack_from, _MSG.unpack_from
    out: dict[str, tuple[list[int], list[bytes]]] = {}
    last_cid = -1
    stamps: list[int] = []
    raws: list[bytes] = []
    while pos < end:
        op, length = unpack_rec(data, pos)
        body = pos + 9
        pos = body + length
        if pos > end:
            raise NotPlain('record runs past its chunk')
        if op == 0x05:
            cid, _seq, log_time, _pub = unpack_msg(data, body)
            if cid != last_cid:
                topic = channels.get(cid, False)
                if topic is False:
                    raise NotPlain(f'message on unknown channel {cid}')
                last_cid = cid
                if topic is None:
                    stamps = raws = None  # type: ignore[assignment]
                else:
                    stamps, raws = out.setdefault(topic, ([], []))
            if stamps is not None:
                stamps.append(log_time)
                raws.append(data[body + 22:pos])
        elif op == 0x04:
            _channel(data, body, channels, topics)
            last_cid = -1
    yield out
