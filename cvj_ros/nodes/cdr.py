"""Hand-written CDR encoders/decoders for the hot-path messages (JointState, WrenchStamped, Clock).

Moved out of nodes/common.py (layout split); common.py re-exports these names.
"""

import struct
from collections.abc import Sequence
from typing import Any

import numpy as np


from cvj_ros.nodes.parameters import NS_PER_S
from cvj_ros.nodes.diagnostics import stamp_to_ns

_CDR_HEADER = b'\x00\x01\x00\x00'
_STAMP = struct.Struct('<iI')


def _cdr_string(text: str, offset: int) -> tuple[bytes, int]:
    """CDR of a string starting at payload ``offset``: (bytes incl. alignment, new offset)."""
    data = text.encode('utf-8') + b'\x00'
    pad = (-offset) % 4
    out = b'\x00' * pad + struct.pack('<I', len(data)) + data
    return out, offset + len(out)


def _align(offset: int, size: int) -> tuple[bytes, int]:
    pad = (-offset) % size
    return b'\x00' * pad, offset + pad


def _self_check(encoded: bytes, msg: Any) -> bool:
    """Same length as rclpy's serialisation and decodes to ``msg`` (rclpy leaves alignment
    padding uninitialised, so the bytes themselves may differ there; ours are zeros)."""
    from rclpy.serialization import deserialize_message, serialize_message
    try:
        return (len(serialize_message(msg)) == len(encoded)
                and deserialize_message(encoded, type(msg)) == msg)
    except Exception:  # noqa: BLE001 (no typesupport: use message objects)
        return False


class WrenchStampedEncoder:
    """CDR of geometry_msgs/WrenchStamped with a fixed ``frame_id``.

    ``encode(sec, nanosec, fx, fy, fz, tx, ty, tz)``: stamp (s, ns), force (N), torque (N m).
    """

    def __init__(self, frame_id: str) -> None:
        from geometry_msgs.msg import WrenchStamped
        text, off = _cdr_string(frame_id, _STAMP.size)
        pad, off = _align(off, 8)
        self._head = text + pad
        self._body = struct.Struct('<6d')
        probe = WrenchStamped()
        probe.header.stamp.sec, probe.header.stamp.nanosec = -3, 7
        probe.header.frame_id = frame_id
        probe.wrench.force.x, probe.wrench.torque.z = 1.5, -2.25
        self.ok = _self_check(self.encode(-3, 7, 1.5, 0.0, 0.0, 0.0, 0.0, -2.25), probe)

    def encode(self, sec: int, nanosec: int, fx: float, fy: float, fz: float,
               tx: float, ty: float, tz: float) -> bytes:
        return b''.join((_CDR_HEADER, _STAMP.pack(sec, nanosec), self._head,
                         self._body.pack(fx, fy, fz, tx, ty, tz)))


class ClockEncoder:
    """CDR of rosgraph_msgs/Clock: ``encode(sec, nanosec)``."""

    def __init__(self) -> None:
        from rosgraph_msgs.msg import Clock
        probe = Clock()
        probe.clock.sec, probe.clock.nanosec = 12, 345
        self.ok = _self_check(self.encode(12, 345), probe)

    @staticmethod
    def encode(sec: int, nanosec: int) -> bytes:
        return _CDR_HEADER + _STAMP.pack(sec, nanosec)


class JointStateEncoder:
    """CDR of sensor_msgs/JointState with fixed ``names`` and ``frame_id`` (default '') and
    position (rad), velocity (rad/s), effort (N m) arrays of len(names) float64 values each:
    ``encode(sec, nanosec, position, velocity, effort)`` (numpy float64 arrays)."""

    def __init__(self, names: Sequence[str], frame_id: str = '') -> None:
        from sensor_msgs.msg import JointState
        self.n = n = len(names)
        parts: list[bytes] = []
        text, off = _cdr_string(frame_id, _STAMP.size)            # header.frame_id
        parts.append(text)
        pad, off = _align(off, 4)
        parts.append(pad + struct.pack('<I', n))                  # name sequence
        off += 4
        for name in names:
            text, off = _cdr_string(name, off)
            parts.append(text)
        self._gaps: list[bytes] = []
        for _array in range(3):                                   # position, velocity, effort
            pad, off = _align(off, 4)
            gap = pad + struct.pack('<I', n)
            off += 4
            pad, off = _align(off, 8) if n else (b'', off)
            self._gaps.append(gap + pad)
            off += 8 * n
        self._head = b''.join(parts) + self._gaps[0]
        probe = JointState()
        probe.header.stamp.sec, probe.header.stamp.nanosec = 5, 6
        probe.header.frame_id = frame_id
        probe.name = list(names)
        values = np.arange(3 * n, dtype=float).reshape(3, n) + 0.25
        probe.position, probe.velocity, probe.effort = (v.tolist() for v in values)
        self.ok = _self_check(self.encode(5, 6, values[0], values[1], values[2]), probe)

    def encode(self, sec: int, nanosec: int, position: Any, velocity: Any, effort: Any) -> bytes:
        return b''.join((_CDR_HEADER, _STAMP.pack(sec, nanosec), self._head,
                         np.asarray(position, dtype='<f8').tobytes(), self._gaps[1],
                         np.asarray(velocity, dtype='<f8').tobytes(), self._gaps[2],
                         np.asarray(effort, dtype='<f8').tobytes()))


_LE_UINT32 = struct.Struct('<I')
_LE_DOUBLE = struct.Struct('<d')
_BE_STAMP = struct.Struct('>iI')
_BE_UINT32 = struct.Struct('>I')
_BE_DOUBLE = struct.Struct('>d')

#: largest serialised message any decoder reads (bytes): the loop's largest, a joint state of
#: a few dozen shafts, is ~2 kB; anything beyond is dropped as oversized, unread
MAX_MESSAGE_BYTES = 1 << 20
#: longest string (bytes, NUL included) in a header, a joint name or a diagnostic field
MAX_STRING_BYTES = 4096
#: most entries of a sequence (joint names, array values, diagnostic statuses or values)
MAX_SEQUENCE = 4096


class CdrError(ValueError):
    """A serialised message that cannot be read: not CDR, cut short, oversized, or a length
    field pointing outside the message. The message says what, in a few words."""


def _cdr_kind(data: bytes | memoryview) -> bool:
    """True for big-endian CDR, False for little-endian; CdrError otherwise (encapsulation
    ``00 00`` / ``00 01``, at least the 4 encapsulation bytes and a stamp, at most
    :data:`MAX_MESSAGE_BYTES`)."""
    size = len(data)
    if size > MAX_MESSAGE_BYTES:
        raise CdrError(f'oversized: {size} bytes (limit {MAX_MESSAGE_BYTES})')
    if size < 12 or data[0] != 0 or data[1] > 1:
        raise CdrError(f'not CDR: {size} bytes starting {bytes(data[:4]).hex() or "(empty)"}')
    return data[1] == 0


def _wrench_fields(data: bytes | memoryview) -> tuple[int, int, bytes, float]:
    """(sec, nanosec, frame_id bytes, torque.z) of a serialised WrenchStamped, every length
    checked: stamp at payload offset 0, frame_id string at 8, six float64 8-aligned after
    it (torque.z last). Bytes after them are not read (rclpy's own serialisation may leave
    a few there)."""
    big = _cdr_kind(data)
    stamp, u32, f64 = (_BE_STAMP, _BE_UINT32, _BE_DOUBLE) if big else (_STAMP, _LE_UINT32, _LE_DOUBLE)
    size = len(data)
    if size < 16:
        raise CdrError(f'cut short: {size} bytes, a WrenchStamped has at least 64')
    n = u32.unpack_from(data, 12)[0]          # frame_id length, NUL included
    if not 1 <= n <= MAX_STRING_BYTES:
        raise CdrError(f'header.frame_id length {n} (1..{MAX_STRING_BYTES})')
    off = 12 + n                              # payload offset after frame_id
    off += (-off) % 8
    end = 4 + off + 48
    if size < end:
        raise CdrError(f'cut short: {size} bytes, a WrenchStamped with this frame_id has {end}')
    if data[15 + n] != 0:
        raise CdrError('header.frame_id not NUL-terminated')
    sec, nanosec = stamp.unpack_from(data, 4)
    return sec, nanosec, bytes(data[16:15 + n]), f64.unpack_from(data, end - 8)[0]


def decode_wrench_stamp_torque_z(data: bytes) -> tuple[int, float]:
    """(stamp in integer ns, torque.z in N m) of a serialised geometry_msgs/WrenchStamped
    (little- or big-endian CDR, read in place: stamp at payload offset 0, frame_id string at
    8, then six float64 aligned to 8, torque.z last). Raises :class:`CdrError` for anything
    else (sizes and lengths are checked before any read)."""
    sec, nanosec, _frame, tz = _wrench_fields(data)
    return sec * NS_PER_S + nanosec, tz


def decode_wrench_header_torque_z(data: bytes) -> tuple[int, bytes, float]:
    """(stamp in integer ns, header.frame_id as UTF-8 bytes, torque.z in N m) of a serialised
    geometry_msgs/WrenchStamped; checked as :func:`decode_wrench_stamp_torque_z`."""
    sec, nanosec, frame, tz = _wrench_fields(data)
    return sec * NS_PER_S + nanosec, frame, tz


def decode_float64(data: bytes) -> float:
    """std_msgs/Float64 (``data``) of serialised CDR: 4 encapsulation bytes, then the float64
    (12 bytes; bytes after it are not read). Raises :class:`CdrError` otherwise."""
    big = _cdr_kind(data)
    if len(data) < 12:
        raise CdrError(f'{len(data)} bytes, a Float64 has 12')
    return (_BE_DOUBLE if big else _LE_DOUBLE).unpack_from(data, 4)[0]


def decode_string(data: bytes) -> str:
    """std_msgs/String (``data``) of serialised CDR, UTF-8 checked (:class:`CdrError`
    otherwise; the string may be up to :data:`MAX_MESSAGE_BYTES` long)."""
    big = _cdr_kind(data)
    size = len(data)
    if size < 9:
        raise CdrError(f'cut short: {size} bytes')
    n = (_BE_UINT32 if big else _LE_UINT32).unpack_from(data, 4)[0]
    if n < 1 or 8 + n > size or data[7 + n] != 0:
        raise CdrError(f'string length {n} does not fit {size} bytes')
    try:
        return bytes(data[8:7 + n]).decode('utf-8')
    except UnicodeDecodeError as exc:
        raise CdrError(f'not UTF-8 text (byte {exc.start})') from None


# --- node base and main loop ----------------------------------------------------------------


# --- JointState decoder (raw subscriptions) -------------------------------------------------

class _Stamp:
    __slots__ = ('sec', 'nanosec')

    def __init__(self, sec: int, nanosec: int) -> None:
        self.sec, self.nanosec = sec, nanosec


class _Header:
    __slots__ = ('stamp', 'frame_id')

    def __init__(self, stamp: _Stamp, frame_id: str) -> None:
        self.stamp, self.frame_id = stamp, frame_id


class JointStateView:
    """The fields of a serialised sensor_msgs/JointState that the nodes read, as plain Python:
    ``header.stamp.sec`` / ``.nanosec``, ``header.frame_id`` (str), ``name`` (list of str),
    ``position``, ``velocity``, ``effort`` (tuples of float, rad, rad/s, N m)."""
    __slots__ = ('header', 'name', 'position', 'velocity', 'effort')

    def __init__(self, header: _Header, name: list[str], position: tuple[float, ...],
                 velocity: tuple[float, ...], effort: tuple[float, ...]) -> None:
        self.header, self.name = header, name
        self.position, self.velocity, self.effort = position, velocity, effort


class JointStateDecoder:
    """Reads a serialised JointState without rclpy's Python message (measured here, 5 shafts,
    load average ~10: rclpy's deserialisation to a Python JointState 99 us per sample, this
    22 us). Little-endian CDR
    (encapsulation 00 01): stamp at payload offset 0, frame_id string at 8, then the
    sequences name (strings), position, velocity, effort (float64, 8-aligned), alignment
    relative to the payload (byte 4). The name list of the previous message is reused when
    its bytes are the same (the loop sends the same names every step). Other encodings go
    through rclpy.serialization.deserialize_message."""

    def __init__(self) -> None:
        self._names_raw = b''
        self._names: list[str] = []
        self._frame_raw = b''
        self._frame = ''
        self._arrays: dict[int, struct.Struct] = {}
        self.end = 0          # bytes the last little-endian sample decoded took

    # the last sample decoded by any decoder and its view: in composed mode the engine, load
    # and monitor nodes get the same bytes object from the in-process bus (cvj_ros.nodes.intra)
    # and the first decode serves all three (a view is read-only)
    _last: tuple[Any, Any] = (None, None)

    def decode(self, data: bytes) -> Any:
        """A :class:`JointStateView` (or, for a non-little-endian sample, the rclpy message).

        Fast path: a sample whose frame_id and name sequence have the bytes of the
        previous one is read with one slice comparison each and one precompiled unpack per
        array (13 shafts, load average ~4.7: 18 us -> ~6 us)."""
        last = JointStateDecoder._last
        if data is last[0]:
            return last[1]
        view = self._decode(data)
        JointStateDecoder._last = (data, view)
        return view

    def _decode(self, data: bytes) -> Any:
        if _cdr_kind(data):
            return _deserialize_checked(data, 'sensor_msgs/JointState')
        try:
            return self._decode_le(data)
        except struct.error:
            raise CdrError(f'cut short: a length field points past the end of {len(data)} bytes') from None

    def _decode_le(self, data: bytes) -> Any:
        """Little-endian CDR; every length is checked against its limit and the message size
        before it is used (CdrError), a read past the end raises struct.error."""
        size = len(data)
        u32 = _LE_UINT32.unpack_from
        sec, nanosec = _STAMP.unpack_from(data, 4)
        n = u32(data, 12)[0]
        if not 1 <= n <= MAX_STRING_BYTES or 16 + n > size:
            raise CdrError(f'header.frame_id length {n} does not fit {size} bytes')
        frame_raw = data[16:15 + n]
        if frame_raw != self._frame_raw:
            try:
                self._frame = bytes(frame_raw).decode('utf-8')
            except UnicodeDecodeError:
                raise CdrError('header.frame_id not UTF-8') from None
            self._frame_raw = bytes(frame_raw)
        frame = self._frame
        off = 12 + n                                  # payload offset after frame_id
        off += (-off) % 4
        start = off
        known = self._names_raw
        if known and data[4 + start:4 + start + len(known)] == known:
            off = start + len(known)
        else:
            count = u32(data, 4 + off)[0]
            if count > MAX_SEQUENCE:
                raise CdrError(f'{count} joint names (limit {MAX_SEQUENCE})')
            off += 4
            names = []
            for _ in range(count):
                off += (-off) % 4
                m = u32(data, 4 + off)[0]
                if not 1 <= m <= MAX_STRING_BYTES or 8 + off + m > size:
                    raise CdrError(f'joint name length {m} does not fit {size} bytes')
                try:
                    names.append(bytes(data[4 + off + 4:4 + off + 3 + m]).decode('utf-8'))
                except UnicodeDecodeError:
                    raise CdrError('joint name not UTF-8') from None
                off += 4 + m
            self._names_raw, self._names = bytes(data[4 + start:4 + off]), names
        arrays = []
        for _ in range(3):
            off += (-off) % 4
            k = u32(data, 4 + off)[0]
            if k > MAX_SEQUENCE:
                raise CdrError(f'array of {k} values (limit {MAX_SEQUENCE})')
            off += 4
            if k:
                off += (-off) % 8
            unpack = self._arrays.get(k)
            if unpack is None:
                unpack = self._arrays[k] = struct.Struct(f'<{k}d')
            arrays.append(unpack.unpack_from(data, 4 + off))
            off += 8 * k
        self.end = 4 + off                            # bytes the message takes (padding not)
        return JointStateView(_Header(_Stamp(sec, nanosec), frame), self._names, *arrays)


def _deserialize_checked(data: bytes, type_name: str) -> Any:
    """A big-endian sample through rclpy's deserialisation (which raises on malformed bytes,
    measured on 9000 random ones): the rclpy message, or CdrError."""
    from importlib import import_module

    from rclpy.serialization import deserialize_message
    pkg, name = type_name.split('/')
    cls = getattr(import_module(f'{pkg}.msg'), name)
    try:
        return deserialize_message(bytes(data), cls)
    except Exception as exc:  # noqa: BLE001 (rclpy/Fast CDR raise assorted types)
        raise CdrError(f'malformed {type_name} ({type(exc).__name__})') from None


# --- bulk readers (the monitor reads its collected samples at once) --------------------------

class JointStateBlock:
    """Samples of one layout read at once: ``stamp_ns`` (m,) int64 (ns), ``frame_id`` (str),
    ``name`` (the decoder's list of str), ``position`` / ``velocity`` / ``effort`` (m, n)
    float64 (rad, rad/s, N m)."""
    __slots__ = ('stamp_ns', 'frame_id', 'name', 'position', 'velocity', 'effort')

    def __init__(self, stamp_ns: Any, frame_id: str, name: list[str], position: Any,
                 velocity: Any, effort: Any) -> None:
        self.stamp_ns, self.frame_id, self.name = stamp_ns, frame_id, name
        self.position, self.velocity, self.effort = position, velocity, effort


def _joint_state_arrays(data: bytes) -> tuple[list[tuple[int, int]], list[int]] | None:
    """(content byte ranges [start, end) of frame_id, names and the array lengths - the
    alignment padding left out, which rclpy leaves uninitialised -, [absolute byte offsets
    of the position, velocity, effort values]) of a little-endian JointState whose three
    arrays have one value per name, else None (also for anything cut short or beyond the
    limits of :class:`JointStateDecoder`)."""
    if not 20 <= len(data) <= MAX_MESSAGE_BYTES or data[0] != 0 or data[1] != 1:
        return None
    try:
        return _joint_state_arrays_le(data)
    except struct.error:
        return None


def _joint_state_arrays_le(data: bytes) -> tuple[list[tuple[int, int]], list[int]] | None:
    u32 = _LE_UINT32.unpack_from
    if not 1 <= u32(data, 12)[0] <= MAX_STRING_BYTES:
        return None
    fixed = [(12, 16 + u32(data, 12)[0])]     # frame_id: length, bytes, NUL
    off = 12 + u32(data, 12)[0]               # payload offset after frame_id
    off += (-off) % 4
    count = u32(data, 4 + off)[0]
    if count > MAX_SEQUENCE:
        return None
    fixed.append((4 + off, 8 + off))
    off += 4
    for _ in range(count):
        off += (-off) % 4
        m = u32(data, 4 + off)[0]
        if not 1 <= m <= MAX_STRING_BYTES:
            return None
        end = off + 4 + m
        fixed.append((4 + off, 4 + end))
        off = end
    starts = []
    for _ in range(3):
        off += (-off) % 4
        if u32(data, 4 + off)[0] != count:
            return None
        fixed.append((4 + off, 8 + off))
        off += 4
        if count:
            off += (-off) % 8
        starts.append(4 + off)
        off += 8 * count
    return (fixed, starts) if 4 + off == len(data) else None


def _same_size_le(batch: Sequence[bytes]) -> int:
    """The common length of little-endian CDR samples, or 0 (empty, short, other encoding,
    lengths differ): a block needs one layout."""
    if not batch:
        return 0
    first = batch[0]
    size = len(first)
    if size < 16 or first[1] != 1 or any(len(d) != size for d in batch):
        return 0
    return size


def _read_rows(batch: Sequence[bytes], size: int, fixed: Any, starts: Sequence[int],
               n: int) -> tuple[Any, Any] | None:
    """(stamp_ns (m,), values (len(starts), m, n)) of one-layout samples through the compiled
    :func:`cvj_ros.physics.kernel.window_nb.cdr_rows`, or None when the ``fixed`` byte ranges
    differ between samples."""
    from cvj_ros.physics.kernel.window_nb import cdr_rows
    m = len(batch)
    buf = np.frombuffer(b''.join(batch), dtype=np.uint8).reshape(m, size)
    stamp_ns = np.empty(m, dtype=np.int64)
    values = np.empty((len(starts), m, n))
    if not cdr_rows(buf, np.asarray(fixed, dtype=np.int64), np.array(starts, dtype=np.int64), n,
                    stamp_ns, values):
        return None
    return stamp_ns, values


def read_joint_state_block(batch: Sequence[bytes], decoder: 'JointStateDecoder', *,
                           position: bool = True) -> JointStateBlock | None:
    """The samples of ``batch`` as one :class:`JointStateBlock`, when they are little-endian
    CDR with the same frame_id and names and full position/velocity/effort arrays (what the
    coupling node publishes); else None (read them one by one). ``position=False``: leave
    the positions out (``block.position`` None; the monitor reads speeds and efforts).

    The bytes are joined into an (m, L) uint8 array that one compiled call reads
    (cvj_ros.physics.kernel.window_nb.cdr_rows: every byte outside the stamps and the
    float64 values and the alignment padding must equal the first sample's). One call instead of ~15 numpy calls:
    inside a running composed loop each numpy call cost 40-60 us (a cold cache after the
    loop's callbacks), 100 samples took ~0.9 ms that way."""
    size = _same_size_le(batch)
    layout = _joint_state_arrays(batch[0]) if size else None
    if layout is None:
        return None
    fixed, starts = layout
    view = decoder.decode(batch[0])
    got = _read_rows(batch, size, fixed, starts if position else starts[1:], len(view.name))
    if got is None:
        return None
    stamp_ns, values = got
    pos, vel, eff = (values[0], values[1], values[2]) if position else (None, values[0], values[1])
    return JointStateBlock(stamp_ns, view.header.frame_id, view.name, pos, vel, eff)


def read_wrench_torque_z_block(batch: Sequence[bytes]) -> tuple[Any, bytes, Any] | None:
    """(stamp_ns (m,) int64, frame_id bytes, torque.z (m,) N m) of little-endian
    WrenchStamped samples with one frame_id (the layout :func:`decode_wrench_header_torque_z`
    reads), else None. Read like :func:`read_joint_state_block`."""
    size = _same_size_le(batch)
    if not size:
        return None
    first = batch[0]
    n = _LE_UINT32.unpack_from(first, 12)[0]
    if not 1 <= n <= MAX_STRING_BYTES or size > MAX_MESSAGE_BYTES:
        return None
    off = 12 + n
    off += (-off) % 8
    if 4 + off + 48 != size:
        return None
    got = _read_rows(batch, size, [(12, 16 + n)], [4 + off + 40], 1)   # frame_id, not padding
    if got is None:
        return None
    stamp_ns, values = got
    return stamp_ns, bytes(first[16:16 + max(n - 1, 0)]), values[0, :, 0]


# --- diagnostic_msgs/DiagnosticArray -----------------------------------------------------------

_PADS = (b'', b'\x00', b'\x00\x00', b'\x00\x00\x00')


class DiagnosticArrayEncoder:
    """CDR of diagnostic_msgs/DiagnosticArray from plain values:
    ``encode(stamp_ns, frame_id, statuses)`` with statuses as (level (bytes of 1),
    name, message, hardware_id, [(key, value), ...]) tuples of str. rclpy builds one
    Python object per status and key/value and converts each to C (~18 us per status, ~0.4
    ms per monitor publication); this writes the bytes directly (payload-relative alignment:
    uint32 lengths and counts to 4, the level byte unaligned)."""

    def __init__(self) -> None:
        from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
        probe = DiagnosticArray()
        probe.header.stamp.sec, probe.header.stamp.nanosec = 3, 4
        probe.header.frame_id = 'f@x'
        probe.status = [DiagnosticStatus(level=b'\x01', name='a: b', message='ok é',
                                         hardware_id='hw', values=[KeyValue(key='k', value='1.5'),
                                                                   KeyValue(key='kk', value='')]),
                        DiagnosticStatus(level=b'\x02', name='c', message='', hardware_id='')]
        plain = [(st.level, st.name, st.message, st.hardware_id,
                  [(kv.key, kv.value) for kv in st.values]) for st in probe.status]
        self.ok = _self_check(self.encode(3 * NS_PER_S + 4, 'f@x', plain), probe)

    @staticmethod
    def encode(stamp_ns: int, frame_id: str, statuses: Sequence[tuple[Any, ...]]) -> bytes:
        sec, nanosec = divmod(stamp_ns, NS_PER_S)
        pack = _LE_UINT32.pack
        pad_bytes = _PADS
        parts = [_CDR_HEADER, _STAMP.pack(sec, nanosec)]
        append = parts.append
        pos = 8                                    # payload offset
        raw = frame_id.encode('utf-8')
        append(pack(len(raw) + 1))
        append(raw + b'\x00')
        pos += 5 + len(raw)
        pad = -pos & 3
        append(pad_bytes[pad] + pack(len(statuses)))
        pos += pad + 4
        for level, name, message, hardware_id, values in statuses:
            append(level)
            pos += 1
            for text in (name, message, hardware_id):
                raw = text.encode('utf-8')
                pad = -pos & 3
                append(pad_bytes[pad] + pack(len(raw) + 1) + raw + b'\x00')
                pos += pad + 5 + len(raw)
            pad = -pos & 3
            append(pad_bytes[pad] + pack(len(values)))
            pos += pad + 4
            for pair in values:
                for text in pair:
                    raw = text.encode('utf-8')
                    pad = -pos & 3
                    append(pad_bytes[pad] + pack(len(raw) + 1) + raw + b'\x00')
                    pos += pad + 5 + len(raw)
        return b''.join(parts)


class ShaftReader:
    """Reads one shaft's position (rad) and velocity (rad/s) and the stamp and frame_id of
    serialised JointState samples - what a torque responder needs - with one slice
    comparison and two float reads per sample, for as long as the samples keep one layout
    (frame_id, names, array lengths: the coupling node's). ``read(data)`` gives
    (sec, nanosec, frame_id str, position, velocity) or None when the sample has another
    layout or encoding or lacks the shaft (read it with :class:`JointStateDecoder` then)."""

    def __init__(self, shaft: str) -> None:
        self.shaft = shaft
        self._size = -1
        self._key = b''
        self._gap = b''
        self._gap_at = 0
        self._frame = ''
        self._pos = self._vel = 0

    def read(self, data: bytes) -> tuple[int, int, str, float, float] | None:
        key = self._key
        gap_at = self._gap_at
        if (len(data) != self._size or data[12:12 + len(key)] != key
                or data[gap_at:gap_at + len(self._gap)] != self._gap):
            if not self._learn(data):
                return None
        sec, nanosec = _STAMP.unpack_from(data, 4)
        return (sec, nanosec, self._frame, _LE_DOUBLE.unpack_from(data, self._pos)[0],
                _LE_DOUBLE.unpack_from(data, self._vel)[0])

    def _learn(self, data: bytes) -> bool:
        self._size = -1
        if len(data) < 16 or data[1] != 1:
            return False
        layout = _joint_state_arrays(data)
        if layout is None:
            return False
        _fixed, starts = layout
        try:
            view = JointStateDecoder().decode(data)
        except CdrError:
            return False
        if self.shaft not in view.name:
            return False
        i = view.name.index(self.shaft)
        self._key = bytes(data[12:starts[0]])     # frame_id, names, position count and padding
        self._gap_at = starts[0] + 8 * len(view.name)
        self._gap = bytes(data[self._gap_at:starts[1]])   # velocity count and padding
        self._size = len(data)
        self._frame = view.header.frame_id
        self._pos, self._vel = starts[0] + 8 * i, starts[1] + 8 * i
        return True


def decode_diagnostic_array(data: bytes) -> tuple[int, str, list[tuple[Any, ...]]]:
    """(stamp in integer ns, header.frame_id, statuses) of a serialised
    diagnostic_msgs/DiagnosticArray, statuses as :class:`DiagnosticArrayEncoder` takes them:
    (level bytes, name, message, hardware_id, [(key, value), ...]). Little-endian CDR is read
    directly (rclpy's Python message costs 200-400 us for a coupling status); big-endian
    goes through rclpy.serialization.deserialize_message. Every string and sequence length
    is checked against its limit and the message size first: :class:`CdrError` otherwise."""
    if _cdr_kind(data):
        msg = _deserialize_checked(data, 'diagnostic_msgs/DiagnosticArray')
        return (stamp_to_ns(msg.header.stamp), msg.header.frame_id,
                [(st.level, st.name, st.message, st.hardware_id,
                  [(kv.key, kv.value) for kv in st.values]) for st in msg.status])
    try:
        return _decode_diagnostic_array_le(data)
    except struct.error:
        raise CdrError(f'cut short: a length field points past the end of {len(data)} bytes') from None


def _decode_diagnostic_array_le(data: bytes) -> tuple[int, str, list[tuple[Any, ...]]]:
    u32 = _LE_UINT32.unpack_from
    size = len(data)
    pos = 12                     # absolute offset; alignment is relative to the payload (4)

    def string() -> str:
        nonlocal pos
        pos += -(pos - 4) % 4
        n = u32(data, pos)[0]
        if not 1 <= n <= MAX_STRING_BYTES or pos + 4 + n > size:
            raise CdrError(f'string length {n} does not fit {size} bytes')
        try:
            text = bytes(data[pos + 4:pos + 3 + n]).decode('utf-8')
        except UnicodeDecodeError:
            raise CdrError('a string is not UTF-8') from None
        pos += 4 + n
        return text

    def count() -> int:
        nonlocal pos
        pos += -(pos - 4) % 4
        n = u32(data, pos)[0]
        if n > MAX_SEQUENCE or pos + 4 + n > size:
            raise CdrError(f'sequence of {n} entries does not fit {size} bytes')
        pos += 4
        return n

    sec, nanosec = _STAMP.unpack_from(data, 4)
    frame = string()
    statuses = []
    for _ in range(count()):
        if pos >= size:
            raise CdrError(f'cut short at byte {pos} of {size}')
        level = bytes(data[pos:pos + 1])
        pos += 1
        name, message, hardware_id = string(), string(), string()
        values = [(string(), string()) for _ in range(count())]
        statuses.append((level, name, message, hardware_id, values))
    _LAST_END[0] = pos
    return sec * NS_PER_S + nanosec, frame, statuses


_LAST_END = [0]     # bytes the last little-endian DiagnosticArray decoded took (check_message)


def checked_length(type_name: str, data: bytes | memoryview,
                   js_decoder: 'JointStateDecoder | None' = None) -> int:
    """How many bytes of the serialised message ``data`` of rosbags type ``type_name`` (e.g.
    ``sensor_msgs/msg/JointState``) to keep: all of them, or the message without the bytes
    beyond its end and 3 bytes of padding (rclpy's serialisation can leave 4-8 stray bytes
    there; rosbags, what ``cvj-sim analyze`` reads with, refuses more than 3). Raises
    :class:`CdrError` when it cannot be read: the checked decoders above for the contract
    types (strings UTF-8, as rosbags wants them), the CDR encapsulation and size limit for
    others. What the recorder checks before it writes a message. ``js_decoder``: a decoder
    kept by the caller (its name cache makes the loop's joint states a slice comparison)."""
    if type_name == 'std_msgs/msg/Int8':      # 5 bytes (+ padding): under _cdr_kind's minimum
        if len(data) > 64 or len(data) < 5 or data[0] != 0 or data[1] > 1:
            raise CdrError(f'not a CDR Int8: {len(data)} bytes starting {bytes(data[:4]).hex() or "(empty)"}')
        return 5 if len(data) > 8 else len(data)
    big = _cdr_kind(data)
    end: int | None = None
    if type_name == 'sensor_msgs/msg/JointState':
        dec = js_decoder or JointStateDecoder()
        view = dec._decode(data)
        end = None if big else dec.end
        # the view of these very bytes: a later decode() of them (the recorder's joint-name
        # check) reuses it instead of decoding the message a second time
        JointStateDecoder._last = (data, view)
    elif type_name == 'geometry_msgs/msg/WrenchStamped':
        frame = _wrench_fields(data)[2]
        try:
            frame.decode('utf-8')
        except UnicodeDecodeError:
            raise CdrError('header.frame_id not UTF-8') from None
        n = (_BE_UINT32 if big else _LE_UINT32).unpack_from(data, 12)[0]
        end = 4 + 12 + n + (-(12 + n)) % 8 + 48
    elif type_name == 'rosgraph_msgs/msg/Clock':
        if (_BE_STAMP if big else _STAMP).unpack_from(data, 4)[1] >= NS_PER_S:
            raise CdrError('clock.nanosec >= 1e9')
        end = 12
    elif type_name == 'diagnostic_msgs/msg/DiagnosticArray':
        decode_diagnostic_array(data)
        end = None if big else _LAST_END[0]
    elif type_name == 'std_msgs/msg/Float64':
        decode_float64(data)
        end = 12
    elif type_name == 'std_msgs/msg/String':
        decode_string(data)
        end = 8 + (_BE_UINT32 if big else _LE_UINT32).unpack_from(data, 4)[0]
    if end is not None and len(data) > end + 3:
        return end
    return len(data)


def check_message(type_name: str, data: bytes | memoryview,
                  js_decoder: 'JointStateDecoder | None' = None) -> str | None:
    """Why ``data`` cannot be read (:func:`checked_length`), or None when it can."""
    try:
        checked_length(type_name, data, js_decoder)
    except CdrError as exc:
        return str(exc)
    return None
