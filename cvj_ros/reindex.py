"""`cvj-sim reindex BAG`: rebuild a bag whose recording was killed (mirrors `ros2 bag reindex`).

A run killed hard (SIGKILL, OOM killer, power loss) leaves its storage file without
``metadata.yaml`` and, for mcap, without the summary section and end magic (the last chunk
may be cut short); every reader refuses such a bag. :func:`reindex` salvages every complete
message on disk and writes the bag again:

* **mcap**: the file is scanned record by record from the start (no summary needed):
  schemas, channels and messages, also inside chunks (uncompressed, zstd or lz4). A record
  cut short by the kill ends the scan; in a truncated *uncompressed* chunk (the cvj_ros
  default) the complete messages before the cut are kept too.
* **sqlite3**: the committed rows of ``topics`` and ``messages`` (sqlite rolls back the
  transaction the kill interrupted, and replays the write-ahead log cvj_ros records with);
  a file SQLite refuses (cut short, damaged pages) is read page by page instead
  (:func:`scan_sqlite3_pages`): every row of its intact pages.

The salvaged messages are written with rosbags into a new storage file of the same storage
(named ``<bag dir name>.mcap`` / ``.db3`` as rosbags names it) plus a new ``metadata.yaml``
(topics, types, counts, start and duration, storage id); the damaged original is kept next
to it as ``<file>.orig`` (never deleted). Custom data: the old ``metadata.yaml``'s if it is
still readable, else what the bag itself holds: ``cvj_ros.scene`` and the seed, mode and
coupling scheme from the ``/driveline/scene`` message, plus ``cvj_ros.reindexed``.
"""
from __future__ import annotations

import os
import shutil
import sqlite3
import struct
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from cvj_ros.errors import BagError

MCAP_MAGIC = b'\x89MCAP0\r\n'


@dataclass
class Salvage:
    """Messages recovered from one storage file."""
    storage: str                                           # 'mcap' | 'sqlite3'
    topics: dict[str, str] = field(default_factory=dict)   # topic -> msgtype (file order)
    msgdefs: dict[str, tuple[str, str]] = field(default_factory=dict)  # msgtype -> (encoding, text)
    messages: list[tuple[str, int, bytes]] = field(default_factory=list)  # (topic, ns, cdr)
    damage: str = ''                                       # why the scan stopped early ('' = clean)


@dataclass
class ReindexResult:
    """What :func:`reindex` wrote."""
    path: Path
    storage: str
    counts: dict[str, int]
    start_ns: int
    end_ns: int
    damage: str
    kept_original: list[Path]

    @property
    def duration_s(self) -> float:
        return (self.end_ns - self.start_ns) * 1e-9 if self.counts else 0.0


class _Cut(Exception):
    """A record runs past the end of the data (truncated) or is inconsistent."""


class _Buf:
    """Bounds-checked little-endian reader over bytes."""

    def __init__(self, data: bytes | memoryview, pos: int = 0, end: int | None = None) -> None:
        self.data, self.pos = memoryview(data), pos
        self.end = len(data) if end is None else end

    def take(self, n: int) -> memoryview:
        if n < 0 or self.pos + n > self.end:
            raise _Cut(f'record runs past the end at byte {self.pos}')
        out = self.data[self.pos:self.pos + n]
        self.pos += n
        return out

    def u16(self) -> int:
        return struct.unpack('<H', self.take(2))[0]

    def u32(self) -> int:
        return struct.unpack('<I', self.take(4))[0]

    def u64(self) -> int:
        return struct.unpack('<Q', self.take(8))[0]

    def string(self) -> str:
        try:
            return bytes(self.take(self.u32())).decode('utf-8')
        except UnicodeDecodeError as exc:
            raise _Cut(f'string is not UTF-8 at byte {self.pos}') from exc


def _decompress(compression: str, data: bytes, size: int) -> bytes:
    if compression == '':
        return data
    try:
        if compression == 'zstd':
            try:
                from compression import zstd   # Python 3.14 / backports
                return zstd.decompress(data)
            except ImportError:
                import zstandard
                return zstandard.ZstdDecompressor().decompress(data, max_output_size=size)
        if compression == 'lz4':
            import lz4.frame
            return lz4.frame.decompress(data)
    except ImportError:
        raise _Cut(f'chunk compression {compression!r}: no decompressor installed') from None
    except Exception as exc:  # noqa: BLE001  (a damaged chunk)
        raise _Cut(f'chunk does not decompress: {exc}') from None
    raise _Cut(f'unknown chunk compression {compression!r}')


class _McapScan:
    def __init__(self) -> None:
        self.out = Salvage('mcap')
        self.schemas: dict[int, tuple[str, str, str]] = {}
        self.channels: dict[int, tuple[str, str]] = {}   # id -> (topic, msgtype)

    def records(self, buf: _Buf, *, in_chunk: bool) -> None:
        """Read records until the end of ``buf``; _Cut if one is incomplete or inconsistent."""
        while buf.pos < buf.end:
            op = buf.take(1)[0]
            length = buf.u64()
            if buf.pos + length > buf.end:
                if op == 0x06 and not in_chunk:
                    self.partial_chunk(_Buf(buf.data, buf.pos, buf.end))
                raise _Cut(f'record 0x{op:02x} at byte {buf.pos - 9} cut short '
                           f'({buf.end - buf.pos} of {length} bytes)')
            rec = _Buf(buf.data, buf.pos, buf.pos + length)
            buf.pos += length
            if op == 0x03:
                sid, name, enc = rec.u16(), rec.string(), rec.string()
                text = bytes(rec.take(rec.u32())).decode('utf-8', errors='replace')
                self.schemas[sid] = (name, enc, text)
            elif op == 0x04:
                cid, sid, topic = rec.u16(), rec.u16(), rec.string()
                if sid not in self.schemas:
                    raise _Cut(f'channel {topic!r} refers to unknown schema {sid}')
                name, enc, text = self.schemas[sid]
                self.channels[cid] = (topic, name)
                self.out.topics.setdefault(topic, name)
                self.out.msgdefs.setdefault(name, (enc, text))
            elif op == 0x05:
                cid, _seq, log_time, _pub = rec.u16(), rec.u32(), rec.u64(), rec.u64()
                if cid not in self.channels:
                    raise _Cut(f'message on unknown channel {cid} at byte {rec.pos}')
                self.out.messages.append((self.channels[cid][0], log_time, bytes(rec.take(rec.end - rec.pos))))
            elif op == 0x06 and not in_chunk:
                rec.u64(), rec.u64()
                size, _crc = rec.u64(), rec.u32()
                compression = rec.string()
                data = bytes(rec.take(rec.u64()))
                inner = _decompress(compression, data, size)
                self.records(_Buf(inner), in_chunk=True)
            elif op in (0x0F, 0x02):     # DataEnd / Footer: the summary follows, nothing new
                return

    def partial_chunk(self, rec: _Buf) -> None:
        """Complete messages of an uncompressed chunk cut short by the kill."""
        try:
            rec.u64(), rec.u64(), rec.u64(), rec.u32()
            if rec.string() != '':
                return                   # a compressed stream cannot be cut and decoded
            rec.u64()
            self.records(_Buf(rec.data, rec.pos, rec.end), in_chunk=True)
        except _Cut:
            pass


def scan_mcap(path: Path) -> Salvage:
    """Every complete schema, channel and message of an mcap file, in file order."""
    data = _read(path)
    if not data.startswith(MCAP_MAGIC):
        raise BagError(f'{path}: not an MCAP file (no MCAP magic at the start)')
    scan = _McapScan()
    try:
        scan.records(_Buf(data, len(MCAP_MAGIC)), in_chunk=False)
        if not data.endswith(MCAP_MAGIC):
            scan.out.damage = 'no summary section and end magic (recording not finalised)'
    except _Cut as exc:
        scan.out.damage = str(exc)
    except (struct.error, ValueError) as exc:
        scan.out.damage = f'unreadable record: {exc}'
    return scan.out


def scan_sqlite3(path: Path) -> Salvage:
    """The committed topics and messages of a rosbag2 sqlite3 file (SQLite replays its
    write-ahead log); when SQLite refuses the file (cut short, damaged pages) or stops early,
    what its intact pages hold (:func:`scan_sqlite3_pages`), if that is more."""
    try:
        out = _scan_sqlite3_sql(path)
    except BagError as exc:
        pages = scan_sqlite3_pages(path)
        if not pages.topics:
            raise exc from None
        return pages
    if out.damage:                 # the SQL scan stopped early: the pages may hold more
        pages = scan_sqlite3_pages(path)
        if len(pages.messages) > len(out.messages):
            return pages
    return out


def _scan_sqlite3_sql(path: Path) -> Salvage:
    out = Salvage('sqlite3')
    try:
        conn = sqlite3.connect(f'file:{path}', uri=True)
    except sqlite3.Error as exc:
        raise BagError(f'{path}: cannot open sqlite3 bag: {exc}') from None
    try:
        names: dict[int, str] = {}
        for tid, name, msgtype in conn.execute('SELECT id, name, type FROM topics ORDER BY id'):
            names[int(tid)] = str(name)
            out.topics.setdefault(str(name), str(msgtype))
        try:
            for tid, ts, data in conn.execute('SELECT topic_id, timestamp, data FROM messages ORDER BY id'):
                if tid in names and isinstance(data, bytes):
                    out.messages.append((names[tid], int(ts), data))
        except sqlite3.DatabaseError as exc:
            out.damage = f'messages table damaged after {len(out.messages)} rows: {exc}'
    except sqlite3.DatabaseError as exc:
        raise BagError(f'{path}: not a readable sqlite3 bag: {exc}') from None
    finally:
        conn.close()
    return out


def _varint(buf: bytes, pos: int) -> tuple[int, int]:
    """SQLite varint at ``pos``: (value, position after it); 1-9 bytes, big-endian 7-bit
    groups, the 9th byte whole."""
    value = 0
    for i in range(8):
        b = buf[pos + i]
        value = (value << 7) | (b & 0x7F)
        if b < 0x80:
            return value, pos + i + 1
    return (value << 8) | buf[pos + 8], pos + 9


def _record(payload: bytes) -> list[Any] | None:
    """The values of an SQLite record (a header of serial types, then the values), or None
    when it does not parse."""
    try:
        size, pos = _varint(payload, 0)
        types = []
        while pos < size:
            st, pos = _varint(payload, pos)
            types.append(st)
        pos = size
        values: list[Any] = []
        for st in types:
            if st == 0:
                values.append(None)
            elif 1 <= st <= 6:
                n = (1, 2, 3, 4, 6, 8)[st - 1]
                values.append(int.from_bytes(payload[pos:pos + n], 'big', signed=True))
                pos += n
            elif st == 7:
                values.append(struct.unpack('>d', payload[pos:pos + 8])[0])
                pos += 8
            elif st in (8, 9):
                values.append(st - 8)
            elif st >= 12:
                n = (st - 12) // 2
                raw = payload[pos:pos + n]
                if len(raw) != n:
                    return None
                values.append(raw if st % 2 == 0 else raw.decode('utf-8'))
                pos += n
            else:
                return None
        return values if pos <= len(payload) else None
    except (IndexError, UnicodeDecodeError, struct.error):
        return None


def _leaf_rows(page: bytes, head: int, usable: int,
               pages: dict[int, bytes]) -> list[tuple[int, list[Any]]]:
    """(rowid, values) of the cells of a table b-tree leaf page whose b-tree header is at
    ``head`` (100 on page 1). A payload that spills to overflow pages (``pages``: number ->
    bytes of the pages read) is followed while they are there, else the row is skipped."""
    rows = []
    n_cells = struct.unpack_from('>H', page, head + 3)[0]
    x = usable - 35
    m = ((usable - 12) * 32 // 255) - 23
    for i in range(n_cells):
        try:
            (off,) = struct.unpack_from('>H', page, head + 8 + 2 * i)
            size, pos = _varint(page, off)
            rowid, pos = _varint(page, pos)
        except (IndexError, struct.error):
            continue
        if size <= x:
            payload = page[pos:pos + size]
        else:
            k = m + (size - m) % (usable - 4)
            local = k if k <= x else m
            if pos + local + 4 > len(page):
                continue
            parts = [page[pos:pos + local]]
            (nxt,) = struct.unpack_from('>I', page, pos + local)
            got = local
            while got < size and nxt in pages:
                ov = pages[nxt]
                (nxt,) = struct.unpack_from('>I', ov, 0)
                take = min(usable - 4, size - got)
                parts.append(ov[4:4 + take])
                got += take
            if got < size:
                continue
            payload = b''.join(parts)
        if len(payload) == size:
            values = _record(payload)
            if values is not None:
                rows.append((rowid, values))
    return rows


def scan_sqlite3_pages(path: Path) -> Salvage:
    """What the intact pages of a rosbag2 sqlite3 file hold, read without SQLite (for a file
    SQLite refuses: cut short, 'database disk image is malformed').

    SQLite file format: page size at header offset 16 (1 = 65536), reserved bytes per page
    at 20; every table b-tree leaf page (type byte 0x0D; page 1's header at offset 100)
    holds cells (payload size and rowid varints, the record: a header of serial types, then
    the values) behind its cell pointer array. Pages of the main file are read, then the
    frames of its write-ahead log (``<file>-wal``: 32-byte header, frames of a 24-byte
    header and one page; a later frame of a page replaces the earlier). Rows shaped like
    the ``topics`` table (rowid, five texts) and the ``messages`` table (rowid, topic id,
    timestamp, blob) are kept by rowid, in rowid order (the order of insertion); a page cut
    short or damaged loses only its own rows. ``damage`` says what was done."""
    data = _read(path)
    out = Salvage('sqlite3')
    if len(data) < 100 or not data.startswith(b'SQLite format 3\x00'):
        out.damage = 'not an SQLite file (no header)'
        return out
    page_size = struct.unpack_from('>H', data, 16)[0]
    page_size = 65536 if page_size == 1 else page_size
    usable = page_size - data[20]
    pages: dict[int, bytes] = {}
    for k in range(len(data) // page_size):             # whole pages of the main file only
        pages[k + 1] = data[k * page_size:(k + 1) * page_size]
    cut = len(data) % page_size
    wal = path.with_name(path.name + '-wal')
    if wal.exists():
        log = _read(wal)
        pos = 32
        while pos + 24 + page_size <= len(log):
            (number,) = struct.unpack_from('>I', log, pos)
            pages[number] = log[pos + 24:pos + 24 + page_size]
            pos += 24 + page_size
    topics: dict[int, tuple[str, str]] = {}
    messages: dict[int, tuple[int, int, bytes]] = {}
    for number, page in pages.items():
        head = 100 if number == 1 else 0
        if len(page) <= head + 8 or page[head] != 0x0D:
            continue
        for rowid, values in _leaf_rows(page, head, usable, pages):
            if (len(values) == 6 and values[0] is None
                    and all(isinstance(v, str) for v in values[1:])):
                topics[rowid] = (values[1], values[2])
            elif (len(values) == 4 and values[0] is None and isinstance(values[1], int)
                  and isinstance(values[2], int) and isinstance(values[3], bytes)):
                messages[rowid] = (values[1], values[2], values[3])
    for tid in sorted(topics):
        out.topics.setdefault(topics[tid][0], topics[tid][1])
    names = {tid: name for tid, (name, _ty) in topics.items()}
    out.messages = [(names[tid], ts, blob) for _rowid, (tid, ts, blob) in sorted(messages.items())
                    if tid in names]
    out.damage = (f'SQLite refused the file; {len(out.messages)} messages read from its intact '
                  f'pages ({len(pages)} pages' + (f'; a partial page of {cut} bytes at the end '
                                                  'dropped' if cut else '') + ')')
    return out


def _read(path: Path) -> bytes:
    try:
        return path.read_bytes()
    except OSError as exc:
        raise BagError(f'{path}: cannot read ({exc.strerror or exc})') from None


def _storage_files(bag_dir: Path) -> list[Path]:
    files = sorted(p for p in bag_dir.iterdir() if p.suffix in ('.mcap', '.db3') and p.is_file())
    if not files:
        raise BagError(f'{bag_dir}: no .mcap or .db3 file to reindex')
    kinds = {p.suffix for p in files}
    if len(kinds) > 1:
        raise BagError(f'{bag_dir}: both .mcap and .db3 files; keep one storage per bag')
    return files


def _old_custom_data(bag_dir: Path) -> dict[str, str]:
    import yaml
    try:
        meta = yaml.safe_load((bag_dir / 'metadata.yaml').read_text(encoding='utf-8'))
        custom = meta['rosbag2_bagfile_information']['custom_data']
        return {str(k): str(v) for k, v in custom.items()}
    except Exception:  # noqa: BLE001  (missing or damaged: recover from the data instead)
        return {}


def _custom_from_scene(messages: list[tuple[str, int, bytes]]) -> dict[str, str]:
    """cvj_ros custom data recovered from the /driveline/scene message (std_msgs/String)."""
    import yaml

    from cvj_ros.bag import SCENE_TOPIC, typestore
    for topic, _ts, data in messages:
        if topic != SCENE_TOPIC:
            continue
        try:
            text = typestore().deserialize_cdr(data, 'std_msgs/msg/String').data
            scene = yaml.safe_load(text)
        except Exception:  # noqa: BLE001  (damaged message: nothing to recover)
            return {}
        out = {'cvj_ros.scene': text}
        if isinstance(scene, dict):
            for key in ('seed', 'mode', 'coupling_scheme'):
                if scene.get(key) is not None:
                    out[f'cvj_ros.{key}'] = str(scene[key])
        return out
    return {}


def _add_connection(writer: Any, topic: str, msgtype: str, msgdef: tuple[str, str] | None) -> Any:
    from cvj_ros.bag import typestore
    from cvj_ros.bag_qos import offered_qos
    ts = typestore()
    qos = [offered_qos(topic)]
    if msgtype in ts.fielddefs:
        return writer.add_connection(topic, msgtype, typestore=ts, offered_qos_profiles=qos)
    if msgdef is None:
        raise BagError(f'{topic}: message type {msgtype} unknown and no definition in the bag')
    from rosbags.typesys import get_types_from_msg
    try:
        ts.register(get_types_from_msg(msgdef[1], msgtype))
    except Exception as exc:  # noqa: BLE001
        raise BagError(f'{topic}: cannot use the definition of {msgtype} in the bag: {exc}') from None
    return writer.add_connection(topic, msgtype, typestore=ts, offered_qos_profiles=qos)


def reindex(path: str | os.PathLike[str]) -> ReindexResult:
    """Rebuild the bag directory ``path`` (or the directory of a given .mcap/.db3 file) from
    the data on disk: salvage, rewrite, new metadata.yaml; the original file is kept as
    ``<file>.orig``. BagError when there is nothing to reindex or the file is unreadable."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    from cvj_ros.bag import BAG_VERSION
    from cvj_ros.bag_qos import fix_metadata_file, patch_ros_distro
    p = Path(path)
    if not p.exists():
        raise BagError(f'{p}: no such bag')
    bag_dir = p.parent if p.is_file() else p
    files = [p] if p.is_file() and p.suffix in ('.mcap', '.db3') else _storage_files(bag_dir)
    storage = 'mcap' if files[0].suffix == '.mcap' else 'sqlite3'
    parts = [scan_mcap(f) if storage == 'mcap' else scan_sqlite3(f) for f in files]
    topics: dict[str, str] = {}
    msgdefs: dict[str, tuple[str, str]] = {}
    messages: list[tuple[str, int, bytes]] = []
    for part in parts:
        for t, ty in part.topics.items():
            topics.setdefault(t, ty)
        msgdefs.update(part.msgdefs)
        messages.extend(part.messages)
    damage = '; '.join(f'{f.name}: {part.damage}' for f, part in zip(files, parts) if part.damage)
    if not topics:
        raise BagError(f'{bag_dir}: nothing to recover ({damage or "no topics in the storage file"})')
    messages.sort(key=lambda m: m[1])          # stable: file order within one record time
    custom = _old_custom_data(bag_dir) or _custom_from_scene(messages)
    custom['cvj_ros.reindexed'] = damage or 'clean'

    tmp_root = bag_dir.parent / f'.{bag_dir.name}.reindex-{os.getpid()}'
    shutil.rmtree(tmp_root, ignore_errors=True)
    tmp_root.mkdir()
    try:
        new_bag = tmp_root / bag_dir.name
        plugin = StoragePlugin.MCAP if storage == 'mcap' else StoragePlugin.SQLITE3
        writer = Writer(new_bag, version=BAG_VERSION, storage_plugin=plugin)
        writer.open()
        patch_ros_distro(writer)
        try:
            conns = {t: _add_connection(writer, t, ty, msgdefs.get(ty)) for t, ty in topics.items()}
            for key, value in custom.items():
                writer.set_custom_data(key, value)
            for topic, ts, data in messages:
                writer.write(conns[topic], ts, data)
        finally:
            writer.close()
        fix_metadata_file(new_bag)
        kept = []
        for f in files:                           # the damaged originals stay, renamed
            backup = f.with_name(f.name + '.orig')
            k = 1
            while backup.exists():
                backup, k = f.with_name(f'{f.name}.orig{k}'), k + 1
            f.rename(backup)
            kept.append(backup)
            for side in ('-wal', '-shm'):         # SQLite's log stays with its database
                log = f.with_name(f.name + side)
                if log.exists():
                    log.rename(backup.with_name(backup.name + side))
        for stale in ('metadata.yaml', *(f.name + '-journal' for f in files)):
            if (bag_dir / stale).exists():
                (bag_dir / stale).unlink()
        for item in new_bag.iterdir():
            shutil.move(str(item), str(bag_dir / item.name))
    except OSError as exc:
        raise BagError(f'{bag_dir}: cannot write the reindexed bag ({exc.strerror or exc})') from None
    except BagError:
        raise
    except Exception as exc:  # noqa: BLE001  (rosbags rejects what was salvaged)
        raise BagError(f'{bag_dir}: cannot write the reindexed bag: {exc}') from None
    finally:
        shutil.rmtree(tmp_root, ignore_errors=True)
    counts: dict[str, int] = {t: 0 for t in topics}
    for topic, _ts, _d in messages:
        counts[topic] += 1
    start = messages[0][1] if messages else 0
    end = messages[-1][1] if messages else 0
    return ReindexResult(bag_dir, storage, counts, start, end, damage, kept)
