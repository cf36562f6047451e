"""rosbag2 bags of cvj_ros runs: writing (raw CDR, no round trip) and typed reading.

Writing goes through ``rosbags`` (``rosbags.rosbag2.Writer``, format version 9,
storage ``mcap`` by default or ``sqlite3``); reading through
``rosbags.highlevel.AnyReader``, which opens both storages.

Record timestamps (the bag's time axis) are simulated time, so a lockstep run gives
the same bag twice (docs/contracts.md "Topics and bags"):

* ``/clock`` (rosgraph_msgs/Clock): its ``clock`` field;
* stamped data (sensor_msgs/JointState, geometry_msgs/WrenchStamped): ``header.stamp``;
* ``/driveline/scene``: 0 (t0; it is published once before step 0, and when the latched
  message arrives relative to /clock differs from run to run);
* the samples of a command schedule a driver plays (``/engine/throttle``,
  ``/driveline/clutch``, ``/driveline/gear``, ``/driveline/brake``; std_msgs without a
  stamp) and the coupling node's ``/engine/throttle_scale`` (one per step in lockstep): the
  time t_k of the exchange step they belong to, counted per topic from the schedule
  (:meth:`BagRecorder.set_command_stamps`);
* everything else (``/diagnostics``, commands of an outside stack): the latest ``/clock``
  time seen by the recorder (0 before the first ``/clock``).
  ``/diagnostics`` headers may carry wall-clock stamps, so they are not used.

Both stamped layouts put a ``builtin_interfaces/Time`` first in the message, so the
stamp is read from the CDR bytes directly (``int32 sec``, ``uint32 nanosec`` right
after the 4-byte encapsulation header) without deserialising the message.

:class:`BagRecorder` (rclpy) lives in this module too, but rclpy is imported lazily so
the reading helpers work without a ROS installation.
"""
from __future__ import annotations

import functools
import heapq
import shutil
import struct
import threading
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from cvj_ros.bag_qos import fix_metadata_file, offered_qos, patch_ros_distro
from cvj_ros.errors import BagError
from cvj_ros.topic_pattern import topic_match, topic_selected

SCENE_TOPIC = '/driveline/scene'
CLOCK_TOPIC = '/clock'
JOINT_STATES_TOPIC = '/driveline/joint_states'

# Topic contract: topic -> rosbags message type name.
TOPIC_TYPES: dict[str, str] = {
    CLOCK_TOPIC: 'rosgraph_msgs/msg/Clock',
    JOINT_STATES_TOPIC: 'sensor_msgs/msg/JointState',
    '/engine/wrench': 'geometry_msgs/msg/WrenchStamped',
    '/load/wrench': 'geometry_msgs/msg/WrenchStamped',
    '/engine/throttle': 'std_msgs/msg/Float64',
    '/engine/throttle_scale': 'std_msgs/msg/Float64',
    '/driveline/clutch': 'std_msgs/msg/Float64',
    '/driveline/gear': 'std_msgs/msg/Int8',
    '/driveline/brake': 'std_msgs/msg/Float64',
    '/diagnostics': 'diagnostic_msgs/msg/DiagnosticArray',
    SCENE_TOPIC: 'std_msgs/msg/String',
}
# Pattern topics: `/coupling/<joint>/wrench`, `/load/<wheel>/wrench` (outside wheel loads).
PATTERN_TYPES: dict[str, str] = {
    '/coupling/*/wrench': 'geometry_msgs/msg/WrenchStamped',
    '/load/*/wrench': 'geometry_msgs/msg/WrenchStamped',
}
# Types that start with a std_msgs/Header.
HEADER_TYPES = frozenset({
    'sensor_msgs/msg/JointState',
    'geometry_msgs/msg/WrenchStamped',
    'diagnostic_msgs/msg/DiagnosticArray',
})
# Types whose first field is a builtin_interfaces/Time used as record timestamp.
STAMPED_TYPES = frozenset({
    'rosgraph_msgs/msg/Clock',
    'sensor_msgs/msg/JointState',
    'geometry_msgs/msg/WrenchStamped',
})
# Topics with one publisher in a run: BagRecorder(run_only=True) records a message of
# these only while its topic has one matched publisher (besides /coupling/*/wrench).
RUN_ONLY_TOPICS = frozenset({JOINT_STATES_TOPIC, '/engine/wrench', '/load/wrench', SCENE_TOPIC,
                             '/engine/throttle_scale'})


def exchange_wrench_topic(topic: str) -> bool:
    """A wrench topic with one message per exchange, stamped with the joint state it answers,
    from one node of the run: /engine/wrench, /load/wrench, /coupling/<joint>/wrench,
    /load/<wheel>/wrench."""
    return (topic in ('/engine/wrench', '/load/wrench') or topic_match(topic, '/coupling/*/wrench')
            or topic_match(topic, '/load/*/wrench'))


def _one_publisher_topic(topic: str) -> bool:
    """A topic with exactly one publisher in a run (RUN_ONLY_TOPICS, /coupling/*/wrench,
    /load/*/wrench). Not /clock: one writer too, but the recorder attributes its samples by
    value (``_is_ours``). ``commands/record.loop_topic`` differs on purpose: the topics with
    one message per exchange (/clock and the exchange wrenches, not the scene or
    /engine/throttle_scale)."""
    return topic in RUN_ONLY_TOPICS or exchange_wrench_topic(topic)
STORAGES = ('mcap', 'sqlite3')
BAG_VERSION = 9

# Flush policy of BagWriter (what a hard kill - SIGKILL, OOM killer, power loss - can lose).
# rosbags alone keeps an mcap chunk in memory until it holds 1 MiB (several simulated seconds of
# a run, and the schema/channel records are in the first chunk: a run killed before it lost
# everything) and commits a sqlite3 bag only at close (a kill lost all). BagWriter instead
# closes the mcap chunk / commits the sqlite3 transaction and fsyncs the file as soon as the
# pending messages span FLUSH_SIM_SPAN_S of record (= simulated) time, or FLUSH_WALL_S of wall
# time passed since the last flush with messages pending. On disk is then everything up to
# at most FLUSH_SIM_SPAN_S before the newest message the writer received; what `cvj-sim
# reindex` recovers after a kill (measured: test/robustness/test_hard_kill.py).
FLUSH_SIM_SPAN_S = 0.1
FLUSH_WALL_S = 0.5
# The file is fsynced (power loss; a killed process loses nothing the OS already has) at most
# once per FLUSH_WALL_S. sqlite3 runs in write-ahead-log mode with synchronous=NORMAL (the
# settings of rosbag2's own "resilient" sqlite3 preset): a commit appends to the -wal file
# without an fsync, so it costs tens of us and can follow the flush span even when the run
# is 10x faster than real time; a checkpoint every FLUSH_WALL_S syncs it, and the bag is
# switched back to a rollback journal (one self-contained .db3 file) when it is closed.
# Composed mode also bounds the writer's lag behind the loop (BatchingWriter, max_lag_s =
# MAX_LAG_S): the loop waits for the writer rather than run more than MAX_LAG_S of simulated
# time ahead of what is on disk; a recorder hands its messages over at least every
# HANDOFF_SPAN_S of record time.
MAX_LAG_S = 0.15
HANDOFF_SPAN_S = 0.05
_HANDOFF_SPAN_NS = int(HANDOFF_SPAN_S * 1e9)

_TYPESTORE = None
_monotonic = time.monotonic
_LE_STAMP = struct.Struct('<iI')
_BE_STAMP = struct.Struct('>iI')


def typestore() -> Any:
    """The rosbags type store for ROS 2 Jazzy (created once)."""
    global _TYPESTORE
    if _TYPESTORE is None:
        from rosbags.typesys import Stores, get_typestore
        _TYPESTORE = get_typestore(Stores.ROS2_JAZZY)
    return _TYPESTORE


def topic_type(topic: str) -> str | None:
    """rosbags type name of a contract topic (``None`` if the topic is not in the contract)."""
    if topic in TOPIC_TYPES:
        return TOPIC_TYPES[topic]
    for pattern, msgtype in PATTERN_TYPES.items():
        if topic_match(topic, pattern):
            return msgtype
    return None


def cdr_stamp_ns(data: bytes | memoryview) -> int:
    """Leading ``builtin_interfaces/Time`` of a CDR message, in ns.

    Layout (OMG CDR, as used by rmw): 4-byte encapsulation header (byte 1 = 1 for little
    endian), then ``int32 sec``, ``uint32 nanosec``.
    """
    if len(data) < 12:
        raise BagError(f'message: too short for a stamp ({len(data)} bytes)')
    fmt = '<iI' if data[1] == 1 else '>iI'
    sec, nanosec = struct.unpack_from(fmt, data, 4)
    return sec * 1_000_000_000 + nanosec


def _storage_plugin(storage: str) -> Any:
    from rosbags.rosbag2 import StoragePlugin
    if storage not in STORAGES:
        raise BagError(f'storage: must be one of {", ".join(STORAGES)}, got {storage!r}')
    return StoragePlugin.MCAP if storage == 'mcap' else StoragePlugin.SQLITE3


def _name_os_thread(name: str) -> None:
    """Give the calling thread ``name`` (<= 15 bytes) at the OS level too (Linux prctl
    PR_SET_NAME), so ``top -H``, ``ps -T`` and /proc show which thread of a run uses the CPU
    (scripts/separate_cpu.py); nothing happens elsewhere."""
    try:
        import ctypes
        ctypes.CDLL(None, use_errno=True).prctl(15, name.encode()[:15], 0, 0, 0)
    except (OSError, AttributeError):
        pass


class BagWriter:
    """Thread-safe rosbag2 writer of raw CDR messages (no ROS needed).

    All ``rosbags`` calls run on one writer thread fed by a queue: the sqlite3 storage
    may only be used from the thread that opened it, and callers (recorder callbacks)
    never wait for disk I/O. A storage error is raised by the next call or by
    :meth:`close`.

    Args:
        path: bag directory to create (must not exist unless ``overwrite``).
        storage: ``'mcap'`` (default) or ``'sqlite3'``.
        overwrite: delete an existing ``path`` first.
    """

    def __init__(self, path: str | Path, *, storage: str = 'mcap', overwrite: bool = False) -> None:
        import queue
        self.path = Path(path)
        plugin = _storage_plugin(storage)
        if self.path.exists():
            if not overwrite:
                raise BagError(f'{self.path}: bag exists already (use --overwrite)')
            shutil.rmtree(self.path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.storage = storage
        self.counts: dict[str, int] = {}
        self.closed = False
        self._lock = threading.Lock()
        self._queue: queue.SimpleQueue[tuple[Any, ...]] = queue.SimpleQueue()
        self._error: BaseException | None = None
        # the newest record stamp (ns) the writer thread has handed to the OS (chunk closed and
        # written / transaction committed); -1 before the first flush
        self.durable_ns = -1
        # per topic, the newest record stamp (ns) on the OS side (a copy made at each flush)
        self.durable_topics: dict[str, int] = {}
        self.flushes = 0          # flushes so far (each one updates durable_ns/durable_topics)
        self._written_topics: dict[str, int] = {}     # writer thread: newest stamp per topic
        self._durable = threading.Condition()
        self._opened = threading.Event()
        self._thread = threading.Thread(target=self._run, args=(plugin,), name='bag-writer', daemon=True)
        self._thread.start()
        self._opened.wait()
        self._raise_error()

    def _run(self, plugin: Any) -> None:
        _name_os_thread('bag-writer')
        from rosbags.rosbag2 import Writer
        connections: dict[str, Any] = {}
        try:
            writer = Writer(self.path, version=BAG_VERSION, storage_plugin=plugin)
            writer.open()
            patch_ros_distro(writer)
        except Exception as exc:  # reported to the constructor
            self._error = exc
            self._opened.set()
            return
        self._opened.set()
        import queue
        import time
        flusher = _Flusher(writer)
        flusher.on_durable = self._set_durable
        write_many = _mcap_batch_writer(writer) or (
            lambda items: [writer.write(c, ts, d) for c, ts, d in items])
        while True:
            try:
                op, *args = self._queue.get(timeout=FLUSH_WALL_S)
            except queue.Empty:
                op, args = 'idle', []
            try:
                if op == 'write':
                    if self._error is None:
                        write_many(((connections[args[0]], args[1], args[2]),))
                        flusher.wrote(args[1])
                        self._note_written(((args[0], args[1], None),))
                elif op == 'batch' and self._error is None:
                    items = args[0]
                    write_many([(connections[topic], stamp, data) for topic, stamp, data in items])
                    flusher.wrote_span(min(it[1] for it in items), max(it[1] for it in items))
                    self._note_written(items)
                if op == 'flush' and self._error is None:
                    flusher.flush(time.monotonic())
                elif op in ('write', 'batch', 'idle') and self._error is None:
                    flusher.maybe_flush(time.monotonic())
                elif op == 'topic':
                    connections[args[0]] = writer.add_connection(
                        args[0], args[1], typestore=typestore(), offered_qos_profiles=[offered_qos(args[0])])
                elif op == 'custom':
                    writer.set_custom_data(args[0], args[1])
                elif op == 'close':
                    flusher.finish()
                    writer.close()
                    fix_metadata_file(self.path)
                    return
            except Exception as exc:  # keep draining; close() reports the first error
                if self._error is None:
                    self._error = exc
                    self._set_durable(2**63 - 1)   # nobody waits for a writer that failed
                if op == 'close':
                    return

    def _note_written(self, items: Iterable[tuple[str, int, Any]]) -> None:
        """Writer thread: the newest record stamp per topic handed to the storage."""
        last = self._written_topics
        for topic, stamp, _data in items:
            if stamp > last.get(topic, -1):
                last[topic] = stamp

    def _set_durable(self, stamp_ns: int) -> None:
        with self._durable:
            if stamp_ns > self.durable_ns:
                self.durable_ns = stamp_ns
            self.durable_topics = dict(self._written_topics)
            self.flushes += 1
            self._durable.notify_all()

    def wait_durable(self, stamp_ns: int, timeout: float) -> bool:
        """Block until every message with a record stamp <= ``stamp_ns`` that was handed to the
        writer is on the OS side (see FLUSH_SIM_SPAN_S), at most ``timeout`` s of wall time;
        True if it is. Releases the GIL while it waits, so the writer thread runs."""
        with self._durable:
            return self._durable.wait_for(lambda: self.durable_ns >= stamp_ns
                                          or not self._thread.is_alive(), timeout)

    def wait_flush(self, seen: int, timeout: float) -> int:
        """Block until the writer has flushed more than ``seen`` times (:attr:`flushes`), or
        its thread ended, at most ``timeout`` s of wall time; the count of flushes then. Waits
        for :attr:`durable_topics` to change, which :meth:`wait_durable` cannot: the newest
        stamp of any topic can be ahead of a topic's (a /clock ahead of the answers)."""
        with self._durable:
            self._durable.wait_for(lambda: self.flushes > seen or not self._thread.is_alive(), timeout)
            return self.flushes

    def request_flush(self) -> None:
        """Ask the writer thread to put everything queued so far on disk now."""
        with self._lock:
            if not self.closed:
                self._queue.put(('flush',))

    def _raise_error(self) -> None:
        """Raise the first storage error as BagError."""
        if self._error is not None:
            raise BagError(f'{self.path}: bag storage error: {self._error}') from self._error

    def add_topic(self, topic: str, msgtype: str | None = None) -> None:
        """Register a topic (``msgtype`` like ``'sensor_msgs/msg/JointState'``; default from the contract)."""
        msgtype = msgtype or topic_type(topic)
        if msgtype is None:
            raise BagError(f'{topic}: unknown message type')
        with self._lock:
            if topic in self.counts or self.closed:
                return
            self.counts[topic] = 0
            self._queue.put(('topic', topic, msgtype))

    def write(self, topic: str, timestamp_ns: int, data: bytes | memoryview) -> None:
        """Append one raw CDR message with record time ``timestamp_ns`` (ns)."""
        with self._lock:
            if self.closed:
                return
            if topic not in self.counts:
                raise BagError(f'{topic}: topic not registered')
            self.counts[topic] += 1
            self._queue.put(('write', topic, int(timestamp_ns), bytes(data)))

    def write_batch(self, items: Sequence[tuple[str, int, bytes]]) -> None:
        """Append ``(topic, record time ns, raw CDR)`` messages in one hand-off to the writer
        thread: one wake-up (and GIL hand-off) per batch instead of per message
        (:class:`BatchingWriter`)."""
        with self._lock:
            if self.closed or not items:
                return
            for topic, _stamp, _data in items:
                if topic not in self.counts:
                    raise BagError(f'{topic}: topic not registered')
                self.counts[topic] += 1
            self._queue.put(('batch', list(items)))

    def set_custom_data(self, key: str, value: str) -> None:
        """Store ``key: value`` in metadata.yaml ``custom_data`` (rosbag2 format version 9)."""
        with self._lock:
            if not self.closed:
                self._queue.put(('custom', str(key), str(value)))

    def close(self) -> None:
        """Write everything queued and finalise the bag (metadata.yaml, mcap summary); idempotent.

        Raises:
            BagError: the storage failed while writing.
        """
        with self._lock:
            if self.closed:
                return
            self.closed = True
            self._queue.put(('close',))
        self._thread.join()
        self._raise_error()

    def __enter__(self) -> BagWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


_MCAP_MESSAGE = struct.Struct('<BQHIQQ')   # opcode 0x05, record length, channel, sequence, log/publish time
_MCAP_CHUNK_BYTES = 2**20                   # rosbags' McapWriter closes a chunk beyond this


def _mcap_batch_writer(writer: Any) -> Any:
    """``write_many(items)`` for a rosbags Writer on the mcap storage without compression:
    the same bytes as ``writer.write(connection, t, data)`` per item (rosbags 0.11.9
    ``McapWriter.write``: a Message record - opcode 0x05, uint64 length, uint16 channel id,
    uint32 sequence 0, uint64 log and publish time = t, the data - in the pending chunk, the
    chunk's time range and message index, the storage's time range and channel count, the
    writer's per-connection count and time range; the chunk closed beyond 1 MiB) with one ``struct.pack``
    per message instead of seven writes (measured here 6.1 -> 1.4 us per message; the writer
    thread shares the GIL with the loop in composed mode). None when the storage is not
    that (sqlite3, compression, another rosbags layout): the caller uses ``writer.write``.
    Byte identity with rosbags' own path: test/test_bag.py."""
    from rosbags.rosbag2.enums import CompressionMode
    st = getattr(writer, 'storage', None)
    chunk = getattr(st, 'chunk', None)
    if (writer.compression_mode != CompressionMode.NONE or chunk is None
            or not all(hasattr(writer, a) for a in ('counts', 'min_timestamp', 'max_timestamp'))
            or not all(hasattr(st, a) for a in ('close_chunk', 'channel_stats', 'message_start_time',
                                                 'message_end_time'))
            or not all(hasattr(chunk, a) for a in ('bio', 'msgs', 'message_start_time',
                                                    'message_end_time'))):
        return None
    if not all(hasattr(st, a) for a in ('compressor', 'compression', 'bio', 'chunks')):
        return None
    _install_mcap_close_chunk(st)
    pack = _MCAP_MESSAGE.pack
    counts = writer.counts

    def write_many(items: Sequence[tuple[Any, int, bytes]]) -> None:
        for _c, ts, _d in items:
            if ts < writer.min_timestamp:
                writer.min_timestamp = ts
            if ts > writer.max_timestamp:
                writer.max_timestamp = ts
        for connection, ts, data in items:
            cid = connection.id
            chunk = st.chunk
            bio = chunk.bio
            if ts < st.message_start_time:
                st.message_start_time = ts
            if ts > st.message_end_time:
                st.message_end_time = ts
            st.channel_stats[cid] += 1
            if ts < chunk.message_start_time:
                chunk.message_start_time = ts
            if ts > chunk.message_end_time:
                chunk.message_end_time = ts
            chunk.msgs[cid].append((ts, bio.tell()))
            bio.write(pack(5, 22 + len(data), cid, 0, ts, ts))
            bio.write(data)
            counts[cid] += 1
            if bio.tell() > _MCAP_CHUNK_BYTES:
                st.close_chunk()
    return write_many


_U64 = struct.Struct('<Q')
_CHUNK_HEAD = struct.Struct('<QQQI')       # start, end, uncompressed size, crc 0
_INDEX_HEAD = struct.Struct('<BQHI')      # opcode 0x07, record length, channel id, index bytes
_CHUNK_INDEX_HEAD = struct.Struct('<QQQQI')


def _install_mcap_close_chunk(st: Any) -> None:
    """Give a rosbags McapWriter (no compression) a ``close_chunk`` that writes the same
    bytes as rosbags 0.11.9's (Chunk record 0x06, one MessageIndex record 0x07 per channel,
    the ChunkIndex kept for the summary) with a handful of ``struct.pack`` calls and one
    numpy array per channel's (time, offset) pairs instead of two ``bytes.write`` per message
    (about 30 % of the bag writer thread's time in a composed run, which shares the GIL with
    the loop). Set on the instance, so rosbags' own ``close()`` uses it too."""
    import io
    from collections import defaultdict

    from rosbags.rosbag2.storage_mcap import PendingChunk
    compress = st.compressor
    name = st.compression.encode()
    name_bytes = struct.pack('<I', len(name)) + name

    def close_chunk() -> None:
        chunk = st.chunk
        data = compress(chunk.bio.getvalue())
        size = chunk.bio.tell()
        body = b''.join((_CHUNK_HEAD.pack(chunk.message_start_time, chunk.message_end_time, size, 0),
                         name_bytes, _U64.pack(len(data))))
        out = st.bio
        chunk_start = out.tell()
        out.write(b'\x06' + _U64.pack(len(body) + len(data)) + body)
        out.write(data)
        chunk_end = out.tell()
        offsets: list[tuple[int, int]] = []
        for cid, msgs in chunk.msgs.items():
            offsets.append((cid, out.tell()))
            index = np.asarray(msgs, dtype='<u8').tobytes() if msgs else b''
            out.write(_INDEX_HEAD.pack(0x07, 6 + len(index), cid, len(index)))
            out.write(index)
        rec = io.BytesIO()
        rec.write(_CHUNK_INDEX_HEAD.pack(chunk.message_start_time, chunk.message_end_time,
                                         chunk_start, chunk_end - chunk_start, len(offsets) * 10))
        for cid, offset in offsets:
            rec.write(struct.pack('<HQ', cid, offset))
        rec.write(_U64.pack(out.tell() - chunk_end))
        rec.write(name_bytes)
        rec.write(_U64.pack(len(data)))
        rec.write(_U64.pack(size))
        st.chunks.append(rec)
        st.chunk = PendingChunk(2**63 - 1, 0, io.BytesIO(), defaultdict(list))

    st.close_chunk = close_chunk


class _Flusher:
    """Puts a rosbags Writer's pending messages on disk (see FLUSH_SIM_SPAN_S): closes the
    pending mcap chunk and fsyncs the file, or commits the sqlite3 transaction (sqlite's
    default synchronous=FULL syncs it). Reaches into rosbags' storage objects
    (McapWriter.chunk/close_chunk/bio, Sqlite3Writer.conn) - checked by test/test_reindex.py."""

    def __init__(self, writer: Any) -> None:
        import time
        self.storage = writer.storage
        self.first_ns: int | None = None      # record time of the oldest unflushed message
        self.last_ns = 0
        self.last_flush = self.last_sync = time.monotonic()
        self.on_durable: Any = None           # called with last_ns after each flush
        if hasattr(self.storage, 'conn'):     # sqlite3: see FLUSH_WALL_S
            self.storage.conn.commit()
            self.storage.conn.execute('PRAGMA journal_mode=WAL')
            self.storage.conn.execute('PRAGMA synchronous=NORMAL')

    def wrote(self, timestamp_ns: int) -> None:
        if self.first_ns is None:
            self.first_ns = timestamp_ns
        self.last_ns = max(self.last_ns, timestamp_ns)

    def wrote_span(self, first_ns: int, last_ns: int) -> None:
        """A batch of messages with record times in [first_ns, last_ns] (ns)."""
        if self.first_ns is None:
            self.first_ns = first_ns
        self.last_ns = max(self.last_ns, last_ns)

    def maybe_flush(self, now: float) -> None:
        if self.first_ns is None:
            return
        if (self.last_ns - self.first_ns >= FLUSH_SIM_SPAN_S * 1e9
                or now - self.last_flush >= FLUSH_WALL_S):
            self.flush(now)

    def flush(self, now: float) -> None:
        import os
        st = self.storage
        if hasattr(st, 'close_chunk'):          # mcap: chunk to the OS now, fsync rate-limited
            if st.chunk.msgs:
                st.close_chunk()
            st.bio.flush()
            if now - self.last_sync >= FLUSH_WALL_S:
                os.fsync(st.bio.fileno())
                self.last_sync = now
        elif hasattr(st, 'conn'):               # sqlite3: a commit (WAL, no fsync); sync rate-limited
            st.conn.commit()
            if now - self.last_sync >= FLUSH_WALL_S:
                st.conn.execute('PRAGMA wal_checkpoint(PASSIVE)')
                self.last_sync = now
        self.first_ns = None
        self.last_flush = now
        if self.on_durable is not None:
            self.on_durable(self.last_ns)

    def finish(self) -> None:
        """Before the storage closes: sqlite3 back to a rollback journal, so the finished bag
        is one self-contained .db3 file (rosbags reads it immutable, ignoring a -wal file)."""
        st = self.storage
        if hasattr(st, 'conn'):
            st.conn.commit()
            st.conn.execute('PRAGMA journal_mode=DELETE')


# --------------------------------------------------------------------------- reading


@dataclass
class JointStateSeries:
    """``/driveline/joint_states`` as arrays: ``t`` (s, header stamps), ``names``,
    ``position`` (rad), ``velocity`` (rad/s), ``effort`` (N m), each (n_msgs, n_joints)."""
    t: np.ndarray
    names: list[str]
    position: np.ndarray
    velocity: np.ndarray
    effort: np.ndarray
    record_t: np.ndarray
    #: messages of the topic left out as not the run's (other joint names, undecodable)
    foreign: int = 0

    def shaft(self, name: str) -> int:
        """Column index of shaft ``name``."""
        try:
            return self.names.index(name)
        except ValueError:
            raise BagError(f'{name}: no such joint in joint states ({", ".join(self.names)})') from None


@dataclass
class WrenchSeries:
    """A WrenchStamped topic as arrays: ``t`` (s), ``force`` (N, (n, 3)), ``torque`` (N m, (n, 3))."""
    t: np.ndarray
    force: np.ndarray
    torque: np.ndarray
    frame_id: str
    record_t: np.ndarray
    #: messages of the topic left out as undecodable (another publisher's)
    foreign: int = 0

    @property
    def torque_z(self) -> np.ndarray:
        """``torque.z`` (N m), the torque about the shaft axis."""
        return self.torque[:, 2]


@dataclass
class ScalarSeries:
    """A Float64 or Clock topic: ``t`` (s), ``value`` (message value; for /clock the clock in s)."""
    t: np.ndarray
    value: np.ndarray
    record_t: np.ndarray
    #: messages of the topic left out as undecodable (/clock of another publisher)
    foreign: int = 0


@dataclass
class TextSeries:
    """A String topic: ``t`` (s, record time) and ``data`` (the strings)."""
    t: np.ndarray
    data: list[str]
    record_t: np.ndarray


@dataclass
class DiagnosticsSeries:
    """``/diagnostics``: ``t`` (s, record time) and per message a list of statuses
    ``{'name', 'level', 'message', 'hardware_id', 'values': {key: value}}``."""
    t: np.ndarray
    statuses: list[list[dict[str, Any]]]
    record_t: np.ndarray


@dataclass
class BagInfo:
    """Summary of a bag: ``storage`` id, ``counts`` per topic, ``types`` per topic,
    ``start``/``end`` record times (s) and metadata ``custom_data``."""
    path: Path
    storage: str
    counts: dict[str, int]
    types: dict[str, str]
    start: float
    end: float
    custom_data: dict[str, str] = field(default_factory=dict)


def _check_bag(path: str | Path) -> Path:
    p = Path(path)
    if not p.exists():
        raise BagError(f'{p}: no such bag')
    if p.is_dir() and not (p / 'metadata.yaml').exists():
        if any(p.glob('*.mcap')) or any(p.glob('*.db3')):
            raise BagError(f'{p}: no metadata.yaml (recording killed before it was finalised?); '
                           f'rebuild it from the data on disk with: cvj-sim reindex {p}')
        if (p / 'bag' / 'metadata.yaml').exists() or any((p / 'bag').glob('*.mcap')) \
                or any((p / 'bag').glob('*.db3')):     # a run's --out directory
            raise BagError(f'{p}: not a rosbag2 bag but a run directory; its bag is {p / "bag"}')
        raise BagError(f'{p}: not a rosbag2 bag (no metadata.yaml; was the recording finalised?)')
    return p


def _open_reader(path: str | Path) -> Any:
    from rosbags.highlevel import AnyReader
    p = _check_bag(path)
    try:
        reader = AnyReader([p], default_typestore=typestore())
        reader.open()
    except Exception as exc:  # rosbags raises several types for unreadable bags
        text = ' '.join(str(exc).split())                      # one line, bounded length
        text = text if len(text) <= 200 else text[:197] + '...'
        raise BagError(f'{p}: cannot read bag: {text or type(exc).__name__}') from exc
    return reader


def _close_quietly(reader: Any) -> None:
    """Close a rosbags reader; a damaged bag can make close() itself fail (it is closed then)."""
    try:
        reader.close()
    except Exception:  # noqa: BLE001  (e.g. AttributeError on a metadata.yaml with wrong types)
        pass


def bag_info(path: str | Path) -> BagInfo:
    """Topics, types, counts, time range and custom data of a bag."""
    p = _check_bag(path)
    reader = _open_reader(p)
    try:
        with _damage_as_bag_error(p):
            counts: dict[str, int] = {}
            types: dict[str, str] = {}
            for conn in reader.connections:
                counts[conn.topic] = counts.get(conn.topic, 0) + int(conn.msgcount)
                types[conn.topic] = str(conn.msgtype)
            start = reader.start_time * 1e-9 if reader.message_count else 0.0
            end = reader.end_time * 1e-9 if reader.message_count else 0.0
    finally:
        _close_quietly(reader)
    try:
        meta = yaml.safe_load((p / 'metadata.yaml').read_text(encoding='utf-8')) if p.is_dir() else {}
    except (OSError, ValueError, yaml.YAMLError) as exc:   # ValueError: not UTF-8
        raise BagError(f'{p / "metadata.yaml"}: cannot read: {str(exc).splitlines()[0]}') from None
    info = meta.get('rosbag2_bagfile_information', {}) if isinstance(meta, dict) else {}
    info = info if isinstance(info, dict) else {}
    storage = str(info.get('storage_identifier') or '')
    custom = info.get('custom_data')
    custom = {str(k): str(v) for k, v in custom.items()} if isinstance(custom, dict) else {}
    return BagInfo(p, storage, counts, types, start, end, custom)


def read_raw(path: str | Path, topics: Iterable[str] | None = None) -> list[tuple[str, str, int, bytes]]:
    """All messages as ``(topic, msgtype, record_time_ns, cdr_bytes)`` in record-time order."""
    reader = _open_reader(path)
    try:
        conns = _select(reader, topics, path)
        with _damage_as_bag_error(path):
            return [(c.topic, c.msgtype, ts, bytes(raw)) for c, ts, raw in reader.messages(connections=conns)]
    finally:
        _close_quietly(reader)


class _damage_as_bag_error:
    """Context manager: an exception of rosbags (or of a decoder) while reading the messages of
    a damaged bag becomes ``BagError('<path>: cannot read bag: ...')``."""

    def __init__(self, path: str | Path) -> None:
        self.path = path

    def __enter__(self) -> None:
        return None

    def __exit__(self, typ: Any, exc: Any, tb: Any) -> bool:
        if exc is None or isinstance(exc, (BagError, KeyboardInterrupt, SystemExit)):
            return False
        if isinstance(exc, Exception):
            text = ' '.join(str(exc).split())[:200] or type(exc).__name__
            raise BagError(f'{self.path}: cannot read bag: {text}') from exc
        return False


def _select(reader: Any, topics: Iterable[str] | None, path: str | Path) -> list[Any]:
    if topics is None:
        return list(reader.connections)
    wanted = list(topics)
    present = {c.topic for c in reader.connections}
    for topic in wanted:
        if not any(topic_selected(t, topic) for t in present):
            raise BagError(f'{topic}: topic not in bag {path}')
    return [c for c in reader.connections if any(topic_selected(c.topic, w) for w in wanted)]


def _stamp_s(stamp: Any) -> float:
    return stamp.sec + stamp.nanosec * 1e-9


def _metadata(path: Path) -> Any:
    """metadata.yaml parsed, remembered while the file keeps its modification time and size
    (the report reads it five times; with a vehicle scene in ``custom_data`` each parse cost
    ~20 ms). The result is shared: read it, do not change it. Raises as yaml.safe_load and
    Path.stat."""
    st = path.stat()
    return _metadata_cached(str(path), st.st_mtime_ns, st.st_size)


@functools.lru_cache(maxsize=8)
def _metadata_cached(path: str, _mtime_ns: int, _size: int) -> Any:
    return yaml.safe_load(Path(path).read_text(encoding='utf-8'))


@functools.lru_cache(maxsize=8)
def _yaml_text(text: str) -> Any:
    """A YAML string parsed (the scene text of metadata.yaml), remembered; shared as above."""
    return yaml.safe_load(text)


def run_joint_names(path: str | Path) -> list[str] | None:
    """The run's joint names of a bag: ``shaft_names`` of the scene message the recorder
    stored in metadata.yaml ``custom_data['cvj_ros.scene']`` (the run's ``/driveline/scene``),
    else None (no such entry, unreadable)."""
    try:
        info = _metadata(Path(path) / 'metadata.yaml')
        text = info['rosbag2_bagfile_information']['custom_data']['cvj_ros.scene']
        names = _yaml_text(text).get('shaft_names')
    except (OSError, ValueError, KeyError, TypeError, AttributeError, yaml.YAMLError):
        return None
    if isinstance(names, list) and names and all(isinstance(n, str) for n in names):
        return list(names)                     # a copy: the parsed text is shared
    return None


def read_bag(path: str | Path, topics: Iterable[str] | None = None, *,
             columns: Sequence[str] = ('position', 'velocity', 'effort'),
             joint_names: Sequence[str] | None = None) -> dict[str, Any]:
    """Read a bag (mcap or sqlite3) into typed numpy series, one per topic.

    Joint states, wrenches and /clock are decoded in batches straight into preallocated
    arrays (:mod:`cvj_ros.bag_decode`); the other topics message by message through rosbags.

    Args:
        path: bag directory.
        topics: topic names or glob patterns (``'/coupling/*/wrench'``, read per name
            segment: :mod:`cvj_ros.topic_pattern`); ``None`` = all.
        columns: the JointState arrays to read (others are left as zero-width arrays),
            e.g. ``('velocity', 'effort')`` for the report's metrics (a third less memory).
        joint_names: the run's joint names; default :func:`run_joint_names` (else the first
            joint state's). Joint states with other names and messages that do not decode
            are left out, counted in the series' ``foreign`` (another publisher's messages
            recorded by ``cvj-sim record``): never a reason to refuse the bag.

    Returns:
        ``{topic: series}`` with :class:`JointStateSeries` (JointState),
        :class:`WrenchSeries` (WrenchStamped), :class:`ScalarSeries` (Float64, Clock),
        :class:`TextSeries` (String), :class:`DiagnosticsSeries` (DiagnosticArray).
        Times ``t`` in s (header stamp where the message has one, else record time).

    Raises:
        BagError: missing bag, unreadable bag, or a requested topic absent (named).
    """
    from cvj_ros import bag_decode
    reader = _open_reader(path)
    rows: dict[str, list[tuple[int, Any]]] = {}
    builders: dict[str, Any] = {}
    types: dict[str, str] = {}
    try:
        selected = _select(reader, topics, path)
        counts: dict[str, int] = {}
        for conn in selected:
            counts[conn.topic] = counts.get(conn.topic, 0) + int(conn.msgcount or 0)
        names = list(joint_names) if joint_names else run_joint_names(path)
        deserialize = reader.deserialize
        msgtypes = {c.topic: c.msgtype for c in selected}

        def consume(blocks: Iterable[dict[str, tuple[list[int], list[Any]]]]) -> None:
            for block in blocks:          # {topic: ([record ns], [raw CDR])}
                for topic, (stamps, raws) in block.items():
                    builder = builders.get(topic)
                    if builder is None and topic not in rows:
                        msgtype = types[topic] = msgtypes[topic]
                        if bag_decode.batch_decodable(msgtype):
                            builder = builders[topic] = bag_decode.SeriesBuilder(
                                msgtype, counts.get(topic, 0), deserialize,
                                names=names if topic == JOINT_STATES_TOPIC else None,
                                columns=columns)
                    if builder is not None:
                        builder.add_many(stamps, raws)
                    else:
                        rows.setdefault(topic, []).extend(
                            (ts, deserialize(raw, types[topic]))
                            for ts, raw in zip(stamps, bag_decode.as_bytes(raws)))
        files = _plain_mcap_files(reader)
        with _damage_as_bag_error(path):
            if files:
                try:
                    for f in files:
                        consume(bag_decode.mcap_messages(str(f), set(msgtypes)))
                except bag_decode.NotPlain:      # rosbags reads it (and names the damage)
                    rows.clear(), builders.clear(), types.clear()
                    files = None
            if not files:
                consume({c.topic: ([ts], [raw])}
                        for c, ts, raw in reader.messages(connections=selected))
            done = {topic: b.finish() for topic, b in builders.items()}
        for conn in reader.connections:  # topics with zero messages
            if topics is None or conn.topic in rows or any(
                    topic_selected(conn.topic, w) for w in topics):
                types.setdefault(conn.topic, conn.msgtype)
                if conn.topic not in done:
                    rows.setdefault(conn.topic, [])
    finally:
        _close_quietly(reader)
    for msgs in rows.values():
        msgs.sort(key=lambda row: row[0])      # record-time order (stable), as rosbags reads
    with _damage_as_bag_error(path):
        out = {topic: _to_series(types[topic], msgs) for topic, msgs in rows.items()}
        out.update({topic: _built_series(types[topic], d) for topic, d in done.items()})
        return out


#: messages per block of a topic decoded into objects by :func:`iter_blocks` (a deserialised
#: DiagnosticArray holds ~10 kB of Python objects)
OBJECT_BLOCK = 256


def iter_blocks(path: str | Path, topics: Iterable[str] | None = None, *,
                columns: Sequence[str] = ('position', 'velocity', 'effort'),
                block: int | None = None,
                raw: Iterable[str] = (),
                joint_names: Sequence[str] | None = None) -> Iterator[tuple[str, str, Any]]:
    """Stream a bag: ``(topic, msgtype, block)`` with at most ``block`` (default
    :data:`cvj_ros.bag_decode.BATCH`) messages of one topic at a time, in file order per
    topic; memory holds one block per topic. Joint states, wrenches and /clock come as the
    dict of :meth:`cvj_ros.bag_decode.SeriesBuilder.finish` (``record_ns``, ``stamp_ns``,
    the ``columns`` or ``wrench`` arrays, ``names``, ``frame_id``), other types as a list of
    ``(record ns, deserialised message)`` (of ``(record ns, raw CDR bytes)`` for the topics
    in ``raw``). Plain mcap files are streamed without rosbags;
    a damaged or compressed mcap file raises :class:`cvj_ros.bag_decode.NotPlain` when the
    damage is reached (the caller reads the bag with :func:`read_bag` instead).

    Joint states not of the run's names (``joint_names``, default :func:`run_joint_names`,
    else the first block's) and undecodable messages are left out, counted in the block's
    ``foreign``.

    Raises:
        BagError: as :func:`read_bag`.
    """
    from cvj_ros import bag_decode
    size = bag_decode.BATCH if block is None else block
    raw_topics = frozenset(raw)
    plain = plain_mcap_bag(path)
    # a plain mcap bag is streamed without opening rosbags' reader, which reads every
    # chunk's message index at open (~6.7 kB per 0.1 s chunk of a run: 240 MB an hour)
    reader = None if plain is not None else _open_reader(path)
    try:
        if plain is not None:
            files, topic_types = plain
            msgtypes = _select_plain(topic_types, topics, path)
            store = typestore()

            def deserialize(raw: Any, msgtype: str) -> Any:
                return store.deserialize_cdr(bytes(raw), msgtype)
        else:
            selected = _select(reader, topics, path)
            msgtypes = {c.topic: c.msgtype for c in selected}
            deserialize = reader.deserialize
            files = _plain_mcap_files(reader)
        names0 = list(joint_names) if joint_names else run_joint_names(path)
        first_names: dict[str, list[str] | None] = {}

        def decoded(topic: str, stamps: list[int], segments: list[Any]) -> Any:
            msgtype = msgtypes[topic]
            if not bag_decode.batch_decodable(msgtype):
                raws = [r for g in segments for r in bag_decode.as_bytes(g)]
                if topic in raw_topics:
                    return list(zip(stamps, raws))
                return [(ts, deserialize(raw, msgtype)) for ts, raw in zip(stamps, raws)]
            js = msgtype == 'sensor_msgs/msg/JointState'
            b = bag_decode.SeriesBuilder(msgtype, len(stamps), deserialize,
                                         names=first_names.get(topic, names0) if js else None,
                                         columns=columns, batch=len(stamps) + 1)
            i = 0
            for g in segments:
                b.add_many(stamps[i:i + len(g)], g)
                i += len(g)
            d = b.finish()
            if js and d['names'] and first_names.get(topic) is None:
                first_names[topic] = d['names']     # later blocks: the same names
            return d
        source = (blk for f in files for blk in bag_decode.mcap_messages(str(f), set(msgtypes))) \
            if files else ({c.topic: ([ts], [raw])} for c, ts, raw in reader.messages(connections=selected))
        pending: dict[str, tuple[list[int], list[Any]]] = {}   # stamps, segments of raws
        with _damage_as_bag_error(path):
            for chunk in source:
                for topic, (stamps, raws) in chunk.items():
                    st, segs = pending.setdefault(topic, ([], []))
                    st.extend(stamps)
                    segs.append(raws)
                    if len(st) >= (size if bag_decode.batch_decodable(msgtypes[topic])
                                   else OBJECT_BLOCK):
                        del pending[topic]
                        yield topic, msgtypes[topic], decoded(topic, st, segs)
            for topic, (st, segs) in list(pending.items()):
                yield topic, msgtypes[topic], decoded(topic, st, segs)
    finally:
        if reader is not None:
            _close_quietly(reader)


def plain_mcap_bag(path: str | Path) -> tuple[list[Path], dict[str, tuple[str, int]]] | None:
    """``(files, {topic: (msgtype, message count)})`` of a finished mcap bag without
    bag-level compression, from its metadata.yaml alone (no rosbags reader), else None."""
    p = Path(path)
    try:
        info = _metadata(p / 'metadata.yaml')['rosbag2_bagfile_information']
        if info.get('storage_identifier') != 'mcap' or str(info.get('compression_mode') or '').lower() not in ('', 'none'):
            return None
        files = [p / Path(str(f)).name for f in info['relative_file_paths']]
        topics = {str(x['topic_metadata']['name']): (str(x['topic_metadata']['type']), int(x['message_count']))
                  for x in info['topics_with_message_count']}
    except (OSError, ValueError, KeyError, TypeError, AttributeError, yaml.YAMLError):
        return None
    return (files, topics) if files and all(f.suffix == '.mcap' and f.is_file() for f in files) else None


def _select_plain(topic_types: dict[str, tuple[str, int]], topics: Iterable[str] | None,
                  path: str | Path) -> dict[str, str]:
    """{topic: msgtype} of the wanted topics (names or patterns) as :func:`_select`."""
    if topics is None:
        return {t: ty for t, (ty, _n) in topic_types.items()}
    wanted = list(topics)
    for topic in wanted:
        if not any(topic_selected(t, topic) for t in topic_types):
            raise BagError(f'{topic}: topic not in bag {path}')
    return {t: ty for t, (ty, _n) in topic_types.items()
            if any(topic_selected(t, w) for w in wanted)}


def _plain_mcap_files(reader: Any) -> list[Path] | None:
    """The mcap files of a one-bag rosbags reader without bag-level compression (what
    :func:`cvj_ros.bag_decode.mcap_messages` streams), else None."""
    try:
        (r2,) = reader.readers
        r2 = getattr(r2, 'storage', r2)        # rosbags 0.11: Reader -> DirectoryReader
        if getattr(r2.metadata, 'compression_mode', None) or not r2.storages:
            return None
        paths = [Path(st.path) for st in r2.storages]
    except (AttributeError, TypeError, ValueError):
        return None
    return paths if all(p.suffix == '.mcap' and p.is_file() for p in paths) else None


def _built_series(msgtype: str, d: dict[str, Any]) -> Any:
    """The series of a topic read by :class:`cvj_ros.bag_decode.SeriesBuilder`."""
    rec = d['record_ns'] * 1e-9
    ns = d['stamp_ns']
    # sec + nanosec * 1e-9 as _stamp_s computes it per message: the same float64 bits
    t = (ns // 1_000_000_000).astype(float) + (ns % 1_000_000_000).astype(float) * 1e-9
    if msgtype == 'sensor_msgs/msg/JointState':
        empty = np.zeros((t.size, 0))
        return JointStateSeries(t, d['names'], d.get('position', empty), d.get('velocity', empty),
                                d.get('effort', empty), rec, d.get('foreign', 0))
    if msgtype == 'geometry_msgs/msg/WrenchStamped':
        w = d.get('wrench', np.zeros((t.size, 6)))
        return WrenchSeries(t, w[:, :3], w[:, 3:], d['frame_id'], rec, d.get('foreign', 0))
    return ScalarSeries(t.copy(), t, rec, d.get('foreign', 0))      # rosgraph_msgs/Clock


def _to_series(msgtype: str, msgs: list[tuple[int, Any]]) -> Any:
    rec = np.array([ts * 1e-9 for ts, _ in msgs], dtype=float)
    if msgtype == 'sensor_msgs/msg/JointState':
        names = list(msgs[0][1].name) if msgs else []
        n = len(names)
        n_all = len(msgs)
        msgs = [(ts, m) for ts, m in msgs if list(m.name) == names]   # the others: not the run's
        rec = np.array([ts * 1e-9 for ts, _ in msgs], dtype=float)

        def col(attr: str) -> np.ndarray:
            out = np.full((len(msgs), n), np.nan)
            for i, (_, m) in enumerate(msgs):
                v = np.asarray(getattr(m, attr), dtype=float)
                if v.size == n:
                    out[i] = v
            return out
        t = np.array([_stamp_s(m.header.stamp) for _, m in msgs], dtype=float)
        return JointStateSeries(t, names, col('position'), col('velocity'), col('effort'), rec,
                                n_all - len(msgs))
    if msgtype == 'geometry_msgs/msg/WrenchStamped':
        t = np.array([_stamp_s(m.header.stamp) for _, m in msgs], dtype=float)
        force = np.array([[m.wrench.force.x, m.wrench.force.y, m.wrench.force.z] for _, m in msgs],
                         dtype=float).reshape(-1, 3)
        torque = np.array([[m.wrench.torque.x, m.wrench.torque.y, m.wrench.torque.z] for _, m in msgs],
                          dtype=float).reshape(-1, 3)
        frame = msgs[0][1].header.frame_id if msgs else ''
        return WrenchSeries(t, force, torque, frame, rec)
    if msgtype == 'rosgraph_msgs/msg/Clock':
        value = np.array([_stamp_s(m.clock) for _, m in msgs], dtype=float)
        return ScalarSeries(value.copy(), value, rec)
    if msgtype in ('std_msgs/msg/Float64', 'std_msgs/msg/Int8'):
        return ScalarSeries(rec.copy(), np.array([m.data for _, m in msgs], dtype=float), rec)
    if msgtype == 'std_msgs/msg/String':
        return TextSeries(rec.copy(), [m.data for _, m in msgs], rec)
    if msgtype == 'diagnostic_msgs/msg/DiagnosticArray':
        statuses = [[{'name': s.name, 'level': int(s.level), 'message': s.message,
                      'hardware_id': s.hardware_id,
                      'values': {kv.key: kv.value for kv in s.values}} for s in m.status]
                    for _, m in msgs]
        return DiagnosticsSeries(rec.copy(), statuses, rec)
    return [m for _, m in msgs]  # other types: the deserialised messages


def read_scene_message(path: str | Path) -> dict[str, Any]:
    """The ``/driveline/scene`` YAML of a bag as a dict (keys ``scene``, ``seed``, ``fidelity``,
    ``mode``, ``coupling_scheme``); falls back to metadata ``custom_data['cvj_ros.scene']``."""
    info = bag_info(path)
    if info.counts.get(SCENE_TOPIC):
        text = read_bag(path, [SCENE_TOPIC])[SCENE_TOPIC].data[0]
    elif 'cvj_ros.scene' in info.custom_data:
        text = info.custom_data['cvj_ros.scene']
    else:
        raise BagError(f'{SCENE_TOPIC}: topic not in bag {path}')
    data = yaml.safe_load(text)
    if not isinstance(data, dict):
        raise BagError(f'{SCENE_TOPIC}: not a YAML mapping in bag {path}')
    return data


def load_torque_series(bag: str | Path, topic: str = '/load/wrench') -> tuple[np.ndarray, np.ndarray]:
    """Recorded torque of a WrenchStamped topic: ``(t, torque_z)`` in (s, N m).

    Samples are sorted by stamp; duplicate stamps keep the last sample.

    Raises:
        BagError: missing bag, topic absent, or no messages on it.
    """
    series = read_bag(bag, [topic])[topic]
    if not isinstance(series, WrenchSeries):
        raise BagError(f'{topic}: not a geometry_msgs/WrenchStamped topic')
    if series.t.size == 0:
        raise BagError(f'{topic}: no messages in bag {bag}')
    order = np.argsort(series.t, kind='stable')
    t, tz = series.t[order], series.torque_z[order]
    keep = np.append(np.diff(t) > 0, True)
    return t[keep], tz[keep]


# --------------------------------------------------------------------------- recording (rclpy)


def _msg_class(msgtype: str) -> Any:
    """rclpy message class for a rosbags type name (``'pkg/msg/Type'``)."""
    import importlib
    pkg, _, name = msgtype.split('/')
    return getattr(importlib.import_module(f'{pkg}.msg'), name)


class BatchingWriter:
    """Front of a :class:`BagWriter` for a recorder: messages are collected and handed to
    the writer thread ``batch`` at a time (:meth:`BagWriter.write_batch`), when they span
    :data:`HANDOFF_SPAN_S` of record time, or when :meth:`flush` is called (composed mode:
    every spin tick; :meth:`BagRecorder.spin`: after every wake). Why: one queue hand-off
    per message woke the writer thread ~6 times per exchange, and each wake-up made the
    recording thread wait for the GIL (measured on this 2-core machine under load, composed
    mode: the recorder callbacks took 1.3-2.5 ms per exchange, most of the exchange).
    ``counts`` include the collected messages, so progress and the drain see every message
    at once.

    ``max_lag_s`` (composed mode, where the loop and the writer share one process): at each
    hand-off, wait (at most ``wait_s`` of wall time) until the writer has everything older
    than ``max_lag_s`` of record time before the newest message handed over on disk. The
    loop then never runs further ahead of the disk than that: a SIGKILL of the process
    loses at most ``HANDOFF_SPAN_S + max_lag_s`` of simulated time (plus a drain's worth of
    messages in the recorder). Without it the writer thread, starved of the GIL by a loop 10x
    faster than real time, fell seconds of simulated time behind.
    """

    def __init__(self, writer: Any, *, batch: int = 1024, max_lag_s: float | None = None,
                 wait_s: float = 1.0, flush_lag_s: float | None = None,
                 lag_topics: Iterable[str] = ()) -> None:
        self.writer = writer
        # flush_lag_s measures from the oldest of these topics' newest flushed stamps
        # (BagWriter.durable_topics; none given: the newest flushed stamp of any topic)
        self.lag_topics = frozenset(lag_topics)
        # flush_lag_s (separate processes, whose loop waits for /driveline/recorded): at a
        # hand-off whose newest message is that far ahead of what is on disk, ask the writer
        # to flush now instead of at its own span (FLUSH_SIM_SPAN_S after the oldest pending
        # message: with an exchange step above 25 ms the held loop would wait FLUSH_WALL_S)
        self.flush_lag_ns = None if flush_lag_s is None else int(flush_lag_s * 1e9)
        self.batch = batch
        self.counts: dict[str, int] = {}
        self._items: list[tuple[str, int, bytes]] = []
        self._first_ns: int | None = None
        self.max_lag_ns = None if max_lag_s is None else int(max_lag_s * 1e9)
        self.wait_s = wait_s
        self.waits = 0            # hand-offs that waited for the writer
        self.wait_total_s = 0.0   # wall time spent waiting

    def add_topic(self, topic: str, msgtype: str | None = None) -> None:
        self.writer.add_topic(topic, msgtype)
        self.counts.setdefault(topic, 0)

    def write_many(self, items: list[tuple[str, int, bytes]]) -> None:
        """Collect ``(topic, record time ns, bytes)`` messages of registered topics."""
        if not items:
            return
        self._items.extend(items)
        counts = self.counts
        for topic, _ts, _data in items:
            counts[topic] += 1
        if self._first_ns is None:
            self._first_ns = items[0][1]
        if len(self._items) >= self.batch or items[-1][1] - self._first_ns >= _HANDOFF_SPAN_NS:
            self.flush()

    def write(self, topic: str, timestamp_ns: int, data: Any) -> None:
        """Collect one raw CDR message (record time ns); hand over when ``batch`` are collected."""
        self.write_many([(topic, int(timestamp_ns), bytes(data))])

    def set_custom_data(self, key: str, value: str) -> None:
        self.writer.set_custom_data(key, value)

    def flush(self) -> None:
        """Hand everything collected to the writer thread (and, with ``max_lag_s``, wait
        until the writer is no further behind than that)."""
        if not self._items:
            return
        items, self._items = self._items, []
        self._first_ns = None
        self.writer.write_batch(items)
        newest = max(items[-1][1], items[0][1])
        if self.flush_lag_ns is not None:
            durable = [v for t, v in self.writer.durable_topics.items() if t in self.lag_topics]
            if newest - (min(durable) if durable else self.writer.durable_ns) >= self.flush_lag_ns:
                self.writer.request_flush()
        if self.max_lag_ns is None:
            return
        need = newest - self.max_lag_ns
        if self.writer.durable_ns >= need:
            return
        self.writer.request_flush()
        t0 = _monotonic()
        self.writer.wait_durable(need, self.wait_s)
        self.waits += 1
        self.wait_total_s += _monotonic() - t0


def scene_command_stamps(text: str) -> dict[str, list[int]]:
    """Record times (ns) of the untimed samples of a run, from its ``/driveline/scene`` text:
    with ``commands: driver`` (a driver_node plays the scene's ``commands:``) each command
    topic's :meth:`~cvj_ros.nodes.command_plan.CommandPlan.record_stamps`, and in lockstep
    under a ``shift_schedule`` the throttle scale's t_0 .. t_N; ``{}`` when the text does not
    say (an older run, an outside stack) or does not parse."""
    try:
        d = yaml.safe_load(text)
        if not isinstance(d, dict) or not isinstance(d.get('scene'), dict):
            return {}
        h_ns = int(round(float(d['exchange_step']) * 1e9))
        n_steps = int(round(float(d['duration']) * 1e9 / h_ns))
        from cvj_ros.nodes.command_plan import CommandPlan, throttle_scale_stamps
        from cvj_ros.physics.scene import parse_scene
        scene = parse_scene(d['scene'])
        out: dict[str, list[int]] = {}
        if d.get('commands') == 'driver' and scene.commands:
            out.update(CommandPlan.from_scene(scene, h_ns, n_steps).record_stamps())
        if d.get('mode') == 'lockstep':
            out.update(throttle_scale_stamps(scene, h_ns, n_steps))
        return out
    except Exception:  # noqa: BLE001 (a scene text this recorder cannot read: latest /clock)
        return {}


class BagRecorder:
    """Records ROS topics of a run to a bag: raw CDR from ``raw=True`` subscriptions.

    Record timestamps are simulated time (module docstring). The recorder subscribes to
    the contract topics at once (so the coupling node sees it matched before step 0) and
    to any further ``/coupling/*/wrench`` topic it discovers (``discover_period``). A
    topic enters the bag with its first message (no empty connections).

    Args:
        node: an rclpy node to create subscriptions on (the caller spins it).
        writer: the open :class:`BagWriter`.
        topics: extra topics to subscribe to at once, e.g. the scene's
            ``/coupling/<joint>/wrench`` (contract types).
        discover_period: seconds between graph scans for new pattern topics (0 = off).
        run_only: record this run's publishers only (`cvj-sim run`); False records every
            well-formed message (`cvj-sim record`).

    Malformed messages (:func:`cvj_ros.nodes.cdr.checked_length`: not CDR, cut short,
    oversized, lengths outside the message, strings not UTF-8) are never written; they are
    counted per topic in :attr:`malformed`. Stray bytes after a message and its padding are
    left out (rosbags refuses them).

    Run identity (``run_only``; docs/ros.md "Run identity"). The run's publishers are the
    only publisher of each loop topic (cvj_ros.nodes.peers): a message of
    /driveline/joint_states, /engine/wrench, /load/wrench, /coupling/*/wrench or
    /driveline/scene that DDS received after its topic was last seen with one matched
    publisher, once it has more, cannot be attributed and is dropped, and so is every later
    one (the run's coupling node stops for such an intruder, and a match count can lag or
    flicker while DDS discovers it); samples received before are kept (the recorder may
    take them late); so is a joint state whose names differ from the run's (the first joint
    state written, or ``joint_names``) or whose stamp is not newer than the last one
    written, and any scene after the first. They are counted per topic in :attr:`foreign`. /diagnostics and
    /engine/throttle have several legitimate publishers and are recorded. /clock is
    attributed by value, whoever else publishes it: until the run's own first two joint
    states (stamps s0, s1) are in, /clock samples are kept back; those before s0 are not
    the run's. A /clock sample is written only if it is newer than the last one written
    (the run's own /clock is strictly increasing, so a repeat or a clock going backwards
    is another publisher's) and at most one exchange step after the run's own latest
    joint state taken (own /clock t_k goes out just before the state t_k), after
    :attr:`loop_ended` at most that state; a sample further ahead is kept back until the
    run's joint states catch up. What is still kept back at the end is not the run's.
    Observers (:attr:`observers`) get the samples written or kept back, not the dropped.
    """

    def __init__(self, node: Any, writer: BagWriter, *, topics: Sequence[str] = (),
                 discover_period: float = 0.2, run_only: bool = False,
                 joint_names: Sequence[str] | None = None) -> None:
        self.node = node
        self.writer = writer
        self.clock_ns = 0
        self.last_message_wall = 0.0
        self.wakes = 0     # spin(): wakes that took messages
        self.scene_text: str | None = None
        self.first_wall: dict[str, float] = {}   # monotonic s of the first message per topic
        self.last_wall: dict[str, float] = {}
        self.last_stamp: dict[str, int] = {}     # newest record stamp (ns) written per topic
        self._subs: dict[str, Any] = {}
        # per topic, called with every sample this recorder takes from DDS (after recording
        # it; also another run's and held ones): readers in this process that share the
        # recorder's subscriptions (cvj_ros.nodes.intra.RecorderFeed). They must not
        # raise.
        self.observers: dict[str, list[Callable[[bytes], None]]] = {}
        self._bus_subs: list[Any] = []          # composed mode: bus legs of mixed topics
        self._local: list[tuple[str, bytes]] = []   # composed: collected loop messages
        # composed mode: the hosted publishers are this run's by construction, so the
        # collected loop messages need no identity check
        self.trust_local = False
        self._types: dict[str, str] = {}
        self._lock = threading.Lock()
        # topics whose messages are dropped (counted in ``held``) until the run's own loop
        # starts: `cvj-sim run` holds the loop topics while it checks that no other run shares
        # the domain, so a refused run's bag never holds the other run's messages
        self.hold: frozenset[str] = frozenset()
        self.held = 0
        self.run_only = run_only
        self._foreign: dict[str, int] = {}    # dropped messages not the run's, per topic
        self._malformed: dict[str, int] = {}  # dropped malformed messages, per topic
        self._js_names: bytes | None = None   # names of the run's joint states (CDR bytes)
        self._joint_names = list(joint_names) if joint_names else None
        self._js_decoder: Any = None          # cvj_ros.nodes.cdr.JointStateDecoder (lazy)
        self._checked: Any = None             # (checked_length, CdrError), with the decoder
        # run_only: topics seen with two publishers -> reception time (ns) of the first
        # sample dropped for it; samples received before the last time the topic was seen
        # with one publisher (_clear_ns) are still the run's
        self._ambiguous: dict[str, int] = {}
        self._clear_ns: dict[str, int] = {}
        self._own_js_ns: list[int] = []       # the first two and the latest own joint-state stamps
        self._loop_ended = False
        # /clock samples (value ns, CDR) received before the run's own first two joint states
        self._pending_clock: list[tuple[int, bytes]] = []
        self._clock_started = False            # the start-up rule of the pending /clock done
        self._clock_written: int | None = None  # value (ns) of the last /clock written
        # command topics of a played schedule: topic -> record times (ns) of its samples in
        # order, and how many were taken (set_command_stamps)
        self._command_stamps: dict[str, list[int]] = {}
        self._command_taken: dict[str, int] = {}
        self._stamps_given = False     # set_command_stamps called: the scene message adds none
        self._untimed_seen: dict[str, int] = {}   # samples recorded at the latest /clock
        typestore()   # built now (~0.2 s), not inside the loop at the first /driveline/scene
        for topic in list(TOPIC_TYPES) + list(topics):
            self.subscribe(topic)
        self._timer = node.create_timer(discover_period, self.discover) if discover_period > 0 else None

    @property
    def loop_ended(self) -> bool:
        """Set by the owner once the run's coupling node exited. The run's own /clock never
        exceeds its last joint state (/clock t_k goes out before the state t_k), so from then
        on a /clock sample is written only up to the latest own state the recorder has taken
        (it may still be catching up on states in flight); what is still kept back then is
        another run's and counted in :attr:`foreign`."""
        return self._loop_ended

    @loop_ended.setter
    def loop_ended(self, value: bool) -> None:
        self.take_local()
        self._loop_ended = bool(value)

    @property
    def foreign(self) -> dict[str, int]:
        """Dropped messages of another run, per topic (a copy); once :attr:`loop_ended`,
        /clock samples still kept back count too."""
        self.take_local()
        out = dict(self._foreign)
        if self._loop_ended and self._pending_clock:
            out[CLOCK_TOPIC] = out.get(CLOCK_TOPIC, 0) + len(self._pending_clock)
        return out

    @property
    def malformed(self) -> dict[str, int]:
        """Dropped malformed messages, per topic (a copy)."""
        return dict(self._malformed)

    @property
    def counts(self) -> dict[str, int]:
        """Messages written per topic."""
        self.take_local()
        return dict(self.writer.counts)

    def subscribe(self, topic: str, msgtype: str | None = None) -> None:
        """Subscribe to ``topic`` (raw CDR) and register it in the bag."""
        msgtype = msgtype or topic_type(topic)
        if msgtype is None:
            raise BagError(f'{topic}: unknown message type')
        with self._lock:
            if topic in self._subs:
                return
            qos = recorder_qos(latched=topic == SCENE_TOPIC)
            stamped = msgtype in STAMPED_TYPES
            is_clock = topic == CLOCK_TOPIC

            self._types[topic] = msgtype
            from cvj_ros.nodes.intra import bus_for
            bus = bus_for(self.node.context)
            if bus is not None and (bus.carries(topic) or bus.is_mixed(topic)):
                # composed mode: the hosted publishers' bytes from the in-process bus (and, on
                # /diagnostics and /driveline/scene, the outside ones' from DDS). A /clock
                # there is this run's own (the bus carries only hosted publishers): no
                # attribution needed (class docstring)
                def local(data: bytes, _topic: str = topic, _type: str = msgtype) -> None:
                    self._on_message(_topic, _type, data, stamped=stamped, is_clock=is_clock,
                                     own_clock=is_clock)
                if bus.carries(topic):
                    # collected at publish time, handled in bulk (take_local) after each drain
                    self._subs[topic] = bus.tap(topic, self._collect, node=self.node)
                    if self.take_local not in bus.after_drain:
                        bus.after_drain.append(self.take_local)
                else:
                    hosted, outside = bus.subscribe_mixed(self.node, _msg_class(msgtype), topic,
                                                          local, qos)
                    self._subs[topic] = outside     # counts the DDS publishers, as before
                    self._bus_subs.append(hosted)
                return

            def callback(data: bytes, _topic: str = topic, _type: str = msgtype) -> None:
                if self._on_message(_topic, _type, data, stamped=stamped, is_clock=is_clock):
                    for fn in self.observers.get(_topic, ()):
                        fn(data)
            self._subs[topic] = self.node.create_subscription(
                _msg_class(msgtype), topic, callback, qos, raw=True)

    def set_command_stamps(self, stamps: dict[str, Sequence[int]]) -> None:
        """Record the samples of a played command schedule at their step's time: the n-th
        sample taken on ``topic`` is written at ``stamps[topic][n]`` (ns; a driver publishes
        the samples of step k on /clock t_k, in order:
        :meth:`cvj_ros.nodes.command_plan.CommandPlan.record_stamps`), not at the latest
        /clock the recorder has taken, which in separate processes depends on when the
        sample arrives. Samples beyond the list fall back to the latest /clock. Call before
        the first command sample arrives. Without this call (a recorder started by hand or
        by the launch file) the stamps come from the run's ``/driveline/scene``
        (:func:`scene_command_stamps`)."""
        self._stamps_given = True
        self._command_stamps = {topic: list(v) for topic, v in stamps.items()}
        self._command_taken = {topic: 0 for topic in stamps}

    def _untimed_stamp(self, topic: str, clock_ns: int) -> int:
        """Record time of a message without a stamp on ``topic``: its step's time for a
        played command sample (:meth:`set_command_stamps`), else ``clock_ns``."""
        stamps = self._command_stamps.get(topic)
        if stamps is None:
            self._untimed_seen[topic] = self._untimed_seen.get(topic, 0) + 1
            return clock_ns
        n = self._command_taken[topic]
        if n >= len(stamps):
            return clock_ns
        self._command_taken[topic] = n + 1
        return stamps[n]

    def _collect(self, topic: str, data: bytes) -> None:
        """A hosted publication of a loop topic (composed mode, the in-process bus's tap):
        kept until :meth:`take_local` (whose wall time the bookkeeping takes for all of them:
        the drain that published them lasts at most its 2 ms budget)."""
        self._local.append((topic, data))

    def take_local(self) -> None:
        """Handle the collected hosted publications in publication order, as
        :meth:`_on_message` would have one by one (the bus calls this after each drain, the
        composed container at every flush; also before any DDS message, so the record time
        of an untimed message still follows the latest /clock)."""
        pending = self._local
        if not pending:
            return
        self._local = []
        wall = _monotonic()
        if self.trust_local and hasattr(self.writer, 'write_many'):
            self._take_trusted(pending, wall)
            return
        types = self._types
        for topic, data in pending:
            msgtype = types[topic]
            is_clock = topic == CLOCK_TOPIC
            self._on_message(topic, msgtype, data, stamped=msgtype in STAMPED_TYPES,
                             is_clock=is_clock, own_clock=is_clock, wall=wall)

    def _take_trusted(self, pending: list[tuple[str, bytes]], wall: float) -> None:
        """:meth:`take_local` when every hosted publisher is this run's (:attr:`trust_local`):
        the loop topics are stamped, so each message needs only its record stamp (the
        header or /clock time) and the hold check - what :meth:`_write` does for them, in one
        loop and one hand-over to the writer (measured in a composed run: 7.4 -> ~1 us per
        message)."""
        hold = self.hold
        unpack = _LE_STAMP.unpack_from
        out = []
        clock_ns = None
        for topic, data in pending:
            if hold and topic in hold:
                self.held += 1
                continue
            if self._types[topic] not in STAMPED_TYPES:    # a hosted driver's commands:
                out.append((topic, self._untimed_stamp(
                    topic, self.clock_ns if clock_ns is None else max(self.clock_ns, clock_ns)),
                    data))        # at its step's time, else the latest /clock
                continue
            if data[1] != 1:       # not little-endian CDR: the general path
                self._write(topic, self._types[topic], data, stamped=True,
                            is_clock=topic == CLOCK_TOPIC, wall=wall)
                continue
            sec, nanosec = unpack(data, 4)
            stamp = sec * 1_000_000_000 + nanosec
            if topic == CLOCK_TOPIC:
                clock_ns = stamp if clock_ns is None else max(clock_ns, stamp)
            out.append((topic, stamp, data))
        if out:
            self._record(out, wall)
        if clock_ns is not None:
            self.clock_ns = max(self.clock_ns, clock_ns)
            self._clock_written = clock_ns

    def _on_message(self, topic: str, msgtype: str, data: bytes, *, stamped: bool,
                    is_clock: bool, own_clock: bool = False, wall: float | None = None,
                    received_ns: int | None = None) -> bool:
        """Record one message (class docstring); False when it was dropped (held,
        malformed, not the run's), True when written or kept back. ``received_ns``: when DDS
        received it (message info, system clock ns), where known."""
        if wall is None and self._local:
            self.take_local()          # hosted loop messages first: they were published before
        if topic in self.hold:
            self.held += 1
            return False
        if not own_clock:
            if self._js_decoder is None:     # imported once, not per message (~1 us each)
                from cvj_ros.nodes import cdr
                self._js_decoder = cdr.JointStateDecoder()
                self._checked = (cdr.checked_length, cdr.CdrError)
            checked_length, cdr_error = self._checked
            try:
                keep = checked_length(msgtype, data, self._js_decoder)
            except cdr_error:
                self._malformed[topic] = self._malformed.get(topic, 0) + 1
                return False
            if keep < len(data):
                data = bytes(data[:keep])     # stray bytes beyond the message and its padding
        if self.run_only and not own_clock:
            verdict = self._is_ours(topic, msgtype, data, is_clock=is_clock, received_ns=received_ns)
            if verdict is None:            # a /clock sample kept until it can be attributed
                return True
            if not verdict:
                self._foreign[topic] = self._foreign.get(topic, 0) + 1
                return False
        self._write(topic, msgtype, data, stamped=stamped, is_clock=is_clock, wall=wall)
        if self.run_only and topic == JOINT_STATES_TOPIC and (
                self._pending_clock or (len(self._own_js_ns) >= 2 and not self._clock_started)):
            self._flush_pending_clock()
        return True

    def _write(self, topic: str, msgtype: str, data: bytes, *, stamped: bool, is_clock: bool,
               wall: float | None = None) -> None:
        self._types.setdefault(topic, msgtype)
        if stamped:
            stamp = cdr_stamp_ns(data)
        elif topic == SCENE_TOPIC:
            stamp = 0  # published once before step 0 (t0 = 0); its arrival time races /clock
        else:
            stamp = self._untimed_stamp(topic, self.clock_ns)
        if is_clock:
            self.clock_ns = max(self.clock_ns, stamp)
            self._clock_written = stamp
        if topic == SCENE_TOPIC and self.scene_text is None:
            self.scene_text = typestore().deserialize_cdr(bytes(data), 'std_msgs/msg/String').data
            self.writer.set_custom_data('cvj_ros.scene', self.scene_text)
            if not self._stamps_given:     # started by hand: the schedule from the scene
                # (samples taken before it, if any, were recorded at the latest /clock: the
                # count goes on from them)
                self._command_stamps = scene_command_stamps(self.scene_text)
                self._command_taken = {t: self._untimed_seen.get(t, 0) for t in self._command_stamps}
        self._record([(topic, stamp, data)], _monotonic() if wall is None else wall)

    def _record(self, items: list[tuple[str, int, bytes]], wall: float) -> None:
        """Write (topic, record stamp ns, CDR) items in order: bag connections for topics
        new to the bag, the writer, the wall time (monotonic s) of the first and the last
        message and the newest record stamp per topic."""
        writer = self.writer
        topics = {topic for topic, _stamp, _data in items} if len(items) > 1 else (items[0][0],)
        for topic in topics:
            if topic not in writer.counts:   # bag connections only for topics with messages
                writer.add_topic(topic, self._types.get(topic) or topic_type(topic))
            self.first_wall.setdefault(topic, wall)
            self.last_wall[topic] = wall
        last_stamp = self.last_stamp
        for topic, stamp, _data in items:
            if stamp > last_stamp.get(topic, -1):
                last_stamp[topic] = stamp
        if len(items) == 1:
            writer.write(*items[0])
        else:
            writer.write_many(items)
        self.last_message_wall = wall

    def _keep_clock(self, value: int, data: bytes) -> None:
        """Keep a /clock sample back (``_pending_clock``: a heap by value, then bytes)."""
        heapq.heappush(self._pending_clock, (value, bytes(data)))

    def _flush_pending_clock(self) -> None:
        """Write the /clock samples kept back. Before the run's own first two joint states
        (s0, s1): after s0 those equal to s0; after s1 those in [s0, s1 + 2 (s1 - s0)]
        (/clock t_(k+1) goes out after the state t_k, which may be taken after it) or up to
        one step after the latest own joint state; those before s0 are another run's
        (counted). Later (samples kept back because they were ahead of the run's joint
        states): those now at most one step after the latest own joint state. Samples
        further ahead stay kept back; one not newer than the last written is another run's."""
        own = self._own_js_ns
        if len(own) == 1:
            keep = [(v, d) for v, d in self._pending_clock if v == own[0]]
            if not keep:
                return
            self._pending_clock = [(v, d) for v, d in self._pending_clock if v != own[0]]
            heapq.heapify(self._pending_clock)
        else:
            step = own[1] - own[0]
            hi = own[-1] + (0 if self._loop_ended else step)
            if not self._clock_started:
                self._clock_started = True
                hi = max(hi, own[1] + 2 * step)
            # a heap by value (_keep_clock): those below own[0] are another run's, those up
            # to hi are written, the rest stays - no scan per joint state (an intruder's 1 kHz
            # /clock far ahead of the run made a scan per state quadratic in the run's length:
            # the recorder fell seconds behind)
            pending = self._pending_clock
            if not pending or pending[0][0] > hi:
                return
            n_foreign = 0
            keep = []
            while pending and pending[0][0] <= hi:
                item = heapq.heappop(pending)
                if item[0] < own[0]:
                    n_foreign += 1
                else:
                    keep.append(item)
            if n_foreign:
                self._foreign[CLOCK_TOPIC] = self._foreign.get(CLOCK_TOPIC, 0) + n_foreign
        for v, data in sorted(keep, key=lambda vd: vd[0]):
            if self._clock_written is not None and v <= self._clock_written:
                self._foreign[CLOCK_TOPIC] = self._foreign.get(CLOCK_TOPIC, 0) + 1
                continue
            self._write(CLOCK_TOPIC, TOPIC_TYPES[CLOCK_TOPIC], data, stamped=True, is_clock=True)

    def _is_ours(self, topic: str, msgtype: str, data: bytes, *, is_clock: bool,
                 received_ns: int | None = None) -> bool | None:
        """Run-identity check of one well-formed message (class docstring); notes own
        joint-state stamps. None: a /clock sample kept in ``_pending_clock`` until the run's
        own joint states tell whose it is."""
        if is_clock:
            own = self._own_js_ns
            value = cdr_stamp_ns(data)
            if len(own) < 2 or not self._clock_started:
                self._keep_clock(value, data)
                return None
            if self._clock_written is not None and value <= self._clock_written:
                return False              # a repeat or an older value: not the run's
            if value <= own[-1] + (0 if self._loop_ended else own[1] - own[0]):
                return True
            self._keep_clock(value, data)            # ahead of own states: kept back
            return None
        if _one_publisher_topic(topic):
            since = self._ambiguous.get(topic)
            if received_ns is not None and received_ns <= self._clear_ns.get(topic, -1) and (
                    since is None or received_ns < since):
                pass                      # received while the topic had one publisher
            elif since is not None:
                return False
            else:
                sub = self._subs.get(topic)
                if sub is not None and not hasattr(sub, 'bus') and sub.get_publisher_count() > 1:
                    # whose it is cannot be told, from now on
                    self._ambiguous[topic] = received_ns if received_ns is not None else 0
                    return False
        if topic == JOINT_STATES_TOPIC:
            names = self._js_decoder.decode(data).name
            if self._joint_names is None:
                self._joint_names = list(names)
            elif names != self._joint_names:
                return False
            stamp = cdr_stamp_ns(data)
            own = self._own_js_ns
            if own and stamp <= own[-1]:
                return False              # the run's stamps increase: a copy or a repeat
            if len(own) < 3:
                own.append(stamp)
            else:
                own[2] = stamp
            return True
        if topic == SCENE_TOPIC:
            return self.scene_text is None        # the run's scene is published once
        return True

    def spin(self, stop: threading.Event, *, poll: float = 0.05, discover_period: float = 0.2,
             coalesce: float = 0.0) -> None:
        """Record until ``stop`` is set, without an executor: wait on all subscriptions and
        take every queued message of each ready one (of every one when observers are fed:
        :meth:`_take_queued`) (raw) in a tight loop.

        Measured on this 2-core machine during a lockstep run: an rclpy
        SingleThreadedExecutor (one callback per wait) fell ~0.7 s behind a 200-step run;
        taking all queued samples per wake keeps up. Use either this or an executor.

        ``coalesce`` (s): after a wake that took messages, wait this long before the next
        wait, so one wake takes the messages of several exchange steps (each wake costs
        the wait-set rebuild and a thread switch; the subscriptions' depth holds what
        arrives meanwhile). ``wakes`` counts the wakes that found messages. A writer with
        ``flush`` (:class:`BatchingWriter`) is flushed after every such wake.
        """
        from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
        ctx = self.node.context
        next_discovery = 0.0
        wait_set = None
        entries: list[tuple[str, Any, bool, bool, str]] = []
        flush = getattr(self.writer, 'flush', None)
        if threading.current_thread() is not threading.main_thread():
            _name_os_thread('recorder')
        import time
        while not stop.is_set() and ctx.ok():
            now = time.monotonic()
            if discover_period > 0 and now >= next_discovery:
                self.discover()
                next_discovery = now + discover_period
            with self._lock:
                # /clock last in each wake: joint states queued before it are taken first, so
                # the /clock attribution rarely has to keep a sample back (_is_ours)
                subs = sorted(self._subs.items(), key=lambda item: item[0] == CLOCK_TOPIC)
            if wait_set is None or len(subs) != len(entries):
                entries = [(topic, sub, self._types[topic] in STAMPED_TYPES, topic == CLOCK_TOPIC,
                            self._types[topic]) for topic, sub in subs]
                with ctx.handle:
                    wait_set = _rclpy.WaitSet(len(entries), 0, 0, 0, 0, 0, ctx.handle)
            with ctx.handle:
                wait_set.clear_entities()
                for _, sub, *_ in entries:
                    wait_set.add_subscription(sub.handle)
                wait_set.wait(int(poll * 1e9))
                ready = set(wait_set.get_ready_entities('subscription'))
            self._take_queued(entries, ready)
            if ready:
                self.wakes += 1
                if flush is not None:
                    flush()          # a BatchingWriter: this wake's messages in one hand-off
                if coalesce > 0:
                    stop.wait(coalesce)
        if ctx.ok() and entries:
            # stopped (possibly inside a coalesce wait): what arrived since the last wake is
            # queued in the subscriptions and would go with them - take it now
            self._take_queued(entries, None)
            if flush is not None:
                flush()

    def _take_queued(self, entries: list[tuple[str, Any, bool, bool, str]],
                     ready: set[Any] | None) -> None:
        """Take every queued message of the subscriptions in ``entries`` (those whose handle
        is in ``ready``; all when None) and record it (:meth:`spin`).

        The samples kept go to the observers after the whole wake, in loop order (header
        stamp; at equal stamps the state before its answers: :func:`_feed_order`), as the
        in-process bus of composed mode delivers them, not topic by topic as they are taken: a wake that took 150 joint states and then their 150
        answers would otherwise show a hosted monitor the states of a whole window before
        any answer of it (its first status then had no torques; seen in a CI run).

        With observers, every subscription is taken at every wake, ready or not, in the
        order of ``entries`` (joint states before the answers): a subscription found ready
        is taken some time after the wait returned (a busy machine may not run this thread
        for tens of ms), and the answers that arrived meanwhile, before the later states
        taken, must go to the observers with them, not a wake later."""
        feed: list[tuple[int, int, int, list[Callable[[bytes], None]], bytes]] = []
        if ready is not None and any(self.observers.values()):
            ready = None
        for rank, (topic, sub, stamped, is_clock, msgtype) in enumerate(entries):
            if ready is not None and sub.handle.pointer not in ready:
                continue
            fed = self.observers.get(topic)
            guarded = self.run_only and _one_publisher_topic(topic)
            if guarded and sub.get_publisher_count() <= 1:
                # every sample DDS received up to now came from the topic's one publisher
                self._clear_ns[topic] = time.time_ns()
            with sub.handle:
                while True:
                    taken = sub.handle.take_message(sub.msg_type, True)
                    if taken is None:
                        break
                    received = taken[1].get('received_timestamp') if guarded else None
                    if self._on_message(topic, msgtype, taken[0], stamped=stamped,
                                        is_clock=is_clock, received_ns=received) and fed:
                        feed.append((_feed_order(taken[0], msgtype), _FEED_RANK.get(topic, 64 + rank),
                                     len(feed), fed, taken[0]))
        if feed:
            feed.sort(key=lambda item: item[:3])
            for *_order, fns, data in feed:
                for fn in fns:
                    fn(data)

    def matched_publishers(self) -> dict[str, int]:
        """Per subscribed topic, the publishers its DDS reader has matched (the reader's side
        of each match; `cvj-sim record` reports them on /driveline/recorder_ready)."""
        with self._lock:
            subs = dict(self._subs)
        return {topic: sub.get_publisher_count() for topic, sub in sorted(subs.items())
                if hasattr(sub, 'get_publisher_count')}    # not an in-process bus leg

    def discover(self) -> None:
        """Subscribe to pattern topics (``/coupling/*/wrench``) that appeared in the graph."""
        for topic, _types in self.node.get_topic_names_and_types():
            if topic not in self._subs and topic_type(topic) is not None:
                self.subscribe(topic)

    def destroy(self) -> None:
        """Remove the subscriptions and timer (the caller closes the writer)."""
        self.take_local()
        with self._lock:
            for sub in self._subs.values():
                if hasattr(sub, 'bus'):     # an in-process bus subscription (composed mode)
                    sub.destroy()
                else:
                    self.node.destroy_subscription(sub)
            self._subs.clear()
            for sub in self._bus_subs:
                sub.destroy()
            self._bus_subs.clear()
        if self._timer is not None:
            self.node.destroy_timer(self._timer)
            self._timer = None


# Observers are fed in loop order: by header stamp, and at equal stamps the state t_k, the
# answers to it, then the other topics (in the order taken); samples without a stamp first
_FEED_RANK = {JOINT_STATES_TOPIC: 0, '/engine/wrench': 1, '/load/wrench': 2}
_HEADER_FIRST = STAMPED_TYPES | {'diagnostic_msgs/msg/DiagnosticArray'}


def _feed_order(data: bytes, msgtype: str) -> int:
    """Header stamp (ns) of a CDR sample of a type that begins with one (little- or
    big-endian); -1 for other types and short samples."""
    if msgtype not in _HEADER_FIRST or len(data) < 12:
        return -1
    sec, nsec = (_LE_STAMP if data[1] & 1 else _BE_STAMP).unpack_from(data, 4)
    return sec * 1_000_000_000 + nsec


def recorder_qos(*, latched: bool = False) -> Any:
    """QoS matching the publishers: ``cvj_ros.nodes.qos`` RECORDER_QOS / LATCHED_QOS
    (reliable, keep_last 10000: a lagging recorder keeps 10 s of a 1 ms loop; latched:
    reliable, transient_local, depth 1)."""
    try:
        from cvj_ros.nodes import qos as node_qos
        return node_qos.LATCHED_QOS if latched else node_qos.RECORDER_QOS
    except (ImportError, AttributeError):
        from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
        if latched:
            return QoSProfile(depth=1, history=HistoryPolicy.KEEP_LAST,
                              reliability=ReliabilityPolicy.RELIABLE,
                              durability=DurabilityPolicy.TRANSIENT_LOCAL)
        return QoSProfile(depth=10000, history=HistoryPolicy.KEEP_LAST,
                          reliability=ReliabilityPolicy.RELIABLE,
                          durability=DurabilityPolicy.VOLATILE)
