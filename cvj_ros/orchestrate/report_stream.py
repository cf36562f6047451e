"""The run report's figures from a bag in two streaming passes, in memory independent of the
run's length except the joint-state times and the reference speed (16 bytes per exchange).

:func:`cvj_ros.orchestrate.report.bag_metrics` reads the whole bag into arrays (about 0.75
MiB per simulated second of a composed run after the batch reader; 6 MiB before it). This
module computes the same figures from blocks of the bag (:func:`cvj_ros.bag.iter_blocks`):

1. joint states: times ``t`` and the reference speed ``w`` (the first shaft's) in full (from
   a run's mcap bag the times come from its message indexes, :func:`_indexed_times`, and ``w``
   from pass 2, which checks every stamp against them; other bags: a pass over the joint
   states) - the
   steady window's slices (:func:`cvj_ros.physics.steady.slice_bounds`), their Hann means,
   the reference speed's spans and the window's mean speed come from them exactly as before;
2. everything else per *segment* of rows (the slices, split once more where a window could
   start that is not a slice start - the fallback window of a record that never settled,
   and the last two rows): per shaft the sum, max and min of speed and torque, max and min of
   the acceleration (``np.gradient`` with ``edge_order=2`` over the whole record, computed
   block by block with two rows carried over: the same arithmetic per row), per wrench topic
   the sum, max and min of torque.z by its own stamps; the /diagnostics statuses the report
   reads (WARN/ERROR statuses and the last loop statuses, :class:`DiagnosticsKeeper`) and the
   /driveline/scene text.

The window (:func:`cvj_ros.physics.steady.window_from_slices`, the criterion shared with
``simulate`` and ``analyze``) is then a union of whole segments, so its maxima and minima are
exact and its means are sums of segment sums (equal to ``np.mean`` to rounding, ~1e-16
relative). A bag whose joint-state stamps do not increase (a second run recorded into it) is
left to the in-memory path (:class:`NotStreamable`).
"""
from __future__ import annotations

import struct
from collections import deque
from pathlib import Path
from typing import Any

import numpy as np

from cvj_ros import bag as bagmod
from cvj_ros.errors import CvjError

__all__ = ['DiagnosticsKeeper', 'NotStreamable', 'stream_bag_metrics']

LOOP_STATUS = 'coupling_node: loop'
KEEP_LOOP_MESSAGES = 16       # the last /diagnostics messages with a loop status kept


class NotStreamable(CvjError):
    """The bag needs the in-memory report path (stamps not increasing, names changing)."""


class DiagnosticsKeeper:
    """The /diagnostics messages the report reads, kept while the bag streams by (blocks of
    deserialised messages, :meth:`add`): every message with a WARN or ERROR status of a node
    other than the coupling loop (the report counts them all and names the first of each
    level), and the last :data:`KEEP_LOOP_MESSAGES` messages with a coupling loop status
    (the report reads the last loop counters and timings); :meth:`series` gives them as a
    DiagnosticsSeries in their order, None without messages."""

    def __init__(self) -> None:
        self.kept: list[tuple[int, float, list[dict[str, Any]]]] = []
        # (index, time: s for decoded entries, ns for raw ones, statuses or raw bytes)
        self.loop: deque[tuple[int, Any, Any]] = deque(maxlen=KEEP_LOOP_MESSAGES)
        self.seen = 0

    def add(self, block: list[tuple[int, bytes]]) -> None:
        """Raw CDR DiagnosticArray messages with their record times (ns). Each is first
        scanned for its statuses' levels and names (:func:`_scan_statuses`): one without the
        loop status and without WARN/ERROR is not needed, one with the loop status only (and
        OK ones) is kept as bytes until :meth:`series`; the others are decoded."""
        for ts, data in block:
            scan = _scan_statuses(data)
            if scan == (False, False):           # OK statuses of other nodes: not read
                pass
            elif scan == (True, False):          # the loop's status (+ OK ones): raw for now
                self.loop.append((self.seen, ts, data))
            else:
                statuses = _status_dicts(data)
                entry = (self.seen, ts * 1e-9, statuses)
                if any(st['name'] != LOOP_STATUS and st['level'] in (1, 2) for st in statuses):
                    self.kept.append(entry)
                elif any(st['name'] == LOOP_STATUS for st in statuses):
                    self.loop.append(entry)
            self.seen += 1

    def series(self) -> bagmod.DiagnosticsSeries | None:
        if not self.seen:
            return None
        loop = [e if isinstance(e[2], list) else (e[0], e[1] * 1e-9, _status_dicts(e[2]))
                for e in self.loop]
        rows = sorted(self.kept + loop, key=lambda e: e[0])
        t = np.array([e[1] for e in rows], dtype=float)
        return bagmod.DiagnosticsSeries(t.copy(), [e[2] for e in rows], t)


_LOOP_NAME = LOOP_STATUS.encode()
_U32 = struct.Struct('<I')


def _scan_statuses(data: bytes) -> tuple[bool, bool] | None:
    """``(has the coupling loop's status, has a WARN/ERROR status of another node)`` of a
    little-endian CDR DiagnosticArray, from its statuses' levels and names (every other
    string skipped by its length, nothing decoded); None when unsure (other encodings, a
    cut message): the caller decodes it."""
    if len(data) < 16 or data[1] != 1:
        return None
    # CDR aligns relative to byte 4 (after the encapsulation header), which is a multiple
    # of 4: a 4-aligned offset is (pos + 3) & -4. The walk is written out (no helper
    # function): it runs over every string of every /diagnostics message of a run
    u32 = _U32.unpack_from
    loop_name, n_loop = _LOOP_NAME, len(_LOOP_NAME) + 1
    try:
        pos = 16 + u32(data, 12)[0]                         # header.frame_id
        pos = (pos + 3) & -4
        count = u32(data, pos)[0]
        pos += 4
        loop = other = False
        for _ in range(count):
            level = data[pos]
            pos = (pos + 4) & -4
            n = u32(data, pos)[0]
            if n == n_loop and data[pos + 4:pos + 3 + n] == loop_name:
                loop = True
            elif level == 1 or level == 2:
                other = True
            pos += 4 + n
            pos = (pos + 3) & -4                            # message
            pos += 4 + u32(data, pos)[0]
            pos = (pos + 3) & -4                            # hardware_id
            pos += 4 + u32(data, pos)[0]
            pos = (pos + 3) & -4
            kv = u32(data, pos)[0]
            pos += 4
            for _ in range(2 * kv):                         # key, value strings
                pos = (pos + 3) & -4
                pos += 4 + u32(data, pos)[0]
        return (loop, other) if pos <= len(data) else None
    except (struct.error, IndexError):
        return None


def _status_dicts(data: bytes) -> list[dict[str, Any]]:
    """The statuses of a DiagnosticArray as bag.DiagnosticsSeries holds them."""
    return [{'name': name, 'level': int.from_bytes(level, 'little') if isinstance(level, bytes)
             else int(level), 'message': message, 'hardware_id': hw, 'values': dict(values)}
            for level, name, message, hw, values in _statuses(data)]


def _statuses(data: bytes) -> list[tuple[Any, ...]]:
    """(level, name, message, hardware_id, [(key, value)]) of a DiagnosticArray's statuses:
    the project's own CDR reader (cvj_ros.nodes.cdr, ~5x faster than rosbags' objects), or
    rosbags where rclpy is not installed or the bytes are not what it reads."""
    try:
        from cvj_ros.nodes.cdr import decode_diagnostic_array
        return decode_diagnostic_array(data)[2]
    except Exception:  # noqa: BLE001 (ImportError without rclpy; a message it cannot read)
        m = bagmod.typestore().deserialize_cdr(bytes(data), 'diagnostic_msgs/msg/DiagnosticArray')
        return [(int(st.level), st.name, st.message, st.hardware_id,
                 [(kv.key, kv.value) for kv in st.values]) for st in m.status]


class _Segments:
    """max / min / sum of columns over fixed row segments [starts[j], starts[j+1])."""

    def __init__(self, starts: np.ndarray, n_rows: int, width: int) -> None:
        self.starts = starts
        self.n_rows = n_rows
        m = starts.size
        self.mx = np.full((m, width), -np.inf)
        self.mn = np.full((m, width), np.inf)
        self.sum = np.zeros((m, width))
        self.nan = np.zeros((m, width), dtype=bool)
        self.count = np.zeros(m, dtype=np.int64)

    def add(self, row0: int, values: np.ndarray, *, with_sum: bool = True) -> None:
        """Rows ``row0 .. row0 + len(values) - 1`` (values (k, width))."""
        if values.shape[0] == 0:
            return
        rows = np.arange(row0, row0 + values.shape[0])
        seg = np.searchsorted(self.starts, rows, side='right') - 1
        cuts = np.flatnonzero(np.diff(seg)) + 1
        for a, b in zip(np.concatenate(([0], cuts)), np.append(cuts, values.shape[0])):
            self.add_to(int(seg[a]), values[a:b], with_sum=with_sum)

    def add_to(self, j: int, part: np.ndarray, *, with_sum: bool = True) -> None:
        """Rows ``part`` (k, width) of segment ``j``."""
        if part.shape[0] == 0:
            return
        self.mx[j] = np.fmax(self.mx[j], np.max(part, axis=0))
        self.mn[j] = np.fmin(self.mn[j], np.min(part, axis=0))
        self.nan[j] |= np.isnan(part).any(axis=0)
        self.count[j] += part.shape[0]
        if with_sum:
            self.sum[j] += np.sum(part, axis=0)

    def window(self, first: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(max, min, sum) per column over segments first..end (NaN where a NaN was seen)."""
        nan = self.nan[first:].any(axis=0)
        mx = np.where(nan, np.nan, self.mx[first:].max(axis=0))
        mn = np.where(nan, np.nan, self.mn[first:].min(axis=0))
        return mx, mn, self.sum[first:].sum(axis=0)

    def spans(self, groups: list[tuple[int, int]]) -> np.ndarray:
        """max - min per column over each group [j0, j1) of segments (NaN propagates)."""
        out = np.empty((len(groups), self.mx.shape[1]))
        for g, (j0, j1) in enumerate(groups):
            nan = self.nan[j0:j1].any(axis=0)
            out[g] = np.where(nan, np.nan, self.mx[j0:j1].max(axis=0) - self.mn[j0:j1].min(axis=0))
        return out


def stream_bag_metrics(path: Path) -> tuple[dict[str, Any], dict[str, Any]]:
    """``(metrics, extra)``: the dict of :func:`cvj_ros.orchestrate.report.bag_metrics` and
    ``{'diagnostics': DiagnosticsSeries | None, 'scene': str | None}``, from two streaming
    passes over the bag (module docstring).

    Raises:
        NotStreamable: joint-state stamps not strictly increasing (use the in-memory path).
        BagError: an unreadable bag (as read_bag).
    """
    js_topic = bagmod.JOINT_STATES_TOPIC
    plain = bagmod.plain_mcap_bag(path)      # counts and types without rosbags' reader
    if plain is not None:
        counts = {tp: c for tp, (_ty, c) in plain[1].items()}
        types = {tp: ty for tp, (ty, _c) in plain[1].items()}
    else:
        info = bagmod.bag_info(path)
        counts, types = info.counts, info.types
    n_js = int(counts.get(js_topic, 0))
    # pass 1: the joint-state times. A plain mcap bag gives them from its message indexes
    # (the record time of a stamped message is its header stamp, cvj_ros.bag.STAMPED_TYPES),
    # without reading the messages; pass 2 then checks every stamp against them and fills
    # the reference speed (a bag where they differ - another recorder, foreign joint
    # states - is read with both passes over the messages)
    indexed = (_indexed_times(plain, js_topic, n_js)
               if plain is not None and bagmod.run_joint_names(path) else None)
    if indexed is not None:
        try:
            return _stream(path, counts, types, indexed)
        except _NotIndexed:
            pass
    return _stream(path, counts, types, None)


class _NotIndexed(Exception):
    """The joint states' stamps are not their record times (or some are not the run's)."""


def _indexed_times(plain: Any, topic: str, count: int) -> np.ndarray | None:
    """The topic's record times (s, as :func:`_seconds`) from the mcap files' message
    indexes, None unless they give exactly ``count`` of them."""
    from cvj_ros.bag_decode import mcap_log_time_parts
    parts: list[np.ndarray] = []
    for f in plain[0]:
        got = mcap_log_time_parts(str(f), topic)
        if got is None:
            return None
        parts += got
    if not count or sum(p.size for p in parts) != count:
        return None
    # converted a few chunks at a time into the one array: the peak is the int64 times
    # (8 bytes per exchange, in chunk-sized pieces) and t, not whole-length temporaries
    t = np.empty(count)
    row = 0
    for i in range(0, len(parts), 256):
        sn = np.concatenate(parts[i:i + 256])
        t[row:row + sn.size] = _seconds(sn)
        row += sn.size
        parts[i:i + 256] = [None] * len(parts[i:i + 256])   # type: ignore[list-item]
    return t


def _seconds(sn: np.ndarray) -> np.ndarray:
    """sec + nanosec * 1e-9 as bag.read_bag computes it: the same float64 bits."""
    t = (sn // 1_000_000_000).astype(float)
    t += (sn % 1_000_000_000).astype(float) * 1e-9
    return t


def _stream(path: Path, counts: dict[str, int], types: dict[str, str],
            indexed: np.ndarray | None) -> tuple[dict[str, Any], dict[str, Any]]:
    """:func:`stream_bag_metrics` with the joint-state times ``indexed`` (s) when known
    (pass 2 checks each against its message and raises :class:`_NotIndexed` on the first
    difference), else pass 1 reads them from the messages."""
    from cvj_ros.physics import steady
    js_topic = bagmod.JOINT_STATES_TOPIC
    out: dict[str, Any] = {'shafts': {}, 'wrenches': {}}
    extra: dict[str, Any] = {'diagnostics': None, 'scene': None}
    n_js = int(counts.get(js_topic, 0))
    names, rows, speed_peak, foreign = None, 0, 0.0, 0
    if indexed is not None:
        t, w = indexed, np.full(n_js, np.nan)
        names = run_names = bagmod.run_joint_names(path)
        rows = n_js
    else:
        # times and the reference speed, into arrays allocated once for the count the bag
        # states (no concatenation, no int64 copy: 16 bytes per exchange at the peak)
        t, w = np.empty(n_js), np.empty(n_js)
        for _topic, _ty, d in (bagmod.iter_blocks(path, [js_topic], columns=('velocity',))
                               if n_js else ()):
            sn, k = d['stamp_ns'], d['stamp_ns'].size
            foreign += d.get('foreign', 0)      # not the run's (bag.iter_blocks): left out
            if rows + k > n_js:
                raise NotStreamable(f'{js_topic}: more messages than the bag states')
            t[rows:rows + k] = _seconds(sn)
            v0 = d['velocity'][:, 0] if d['velocity'].shape[1] else np.full(k, np.nan)
            w[rows:rows + k] = v0
            speed_peak = max(speed_peak, float(np.max(np.abs(v0)))) if k else speed_peak
            names = d['names']
            rows += k
        if rows + foreign != n_js:
            raise NotStreamable(f'{js_topic}: {rows} messages, the bag states {n_js}')
        t, w = t[:rows], w[:rows]
    wanted = [tp for tp, c in counts.items() if c and tp != bagmod.CLOCK_TOPIC and (
        tp in (bagmod.SCENE_TOPIC, '/diagnostics')
        or types.get(tp) == 'geometry_msgs/msg/WrenchStamped')]
    streaming = t.size >= 3 and bool(names)
    if streaming and not all(np.all(t[i + 1:j + 1] > t[i:j]) for i, j in (
            (i, min(i + 2**20, t.size - 1)) for i in range(0, t.size - 1, 2**20))):
        raise NotStreamable(f'{js_topic}: stamps not strictly increasing')
    n = t.size
    width = len(names or [])
    if streaming:
        edges, lo, hi = steady.slice_bounds(t)
        first_slice = steady.usable_tail(lo, hi)
        usable = first_slice is not None
        if usable:        # the slices after the last one in a gap of the record
            edges, lo, hi = edges[first_slice:], lo[first_slice:], hi[first_slice:]
        n_sl = edges.size - 1
        fb = int(np.searchsorted(t, steady.fallback_start(t), side='left'))
        starts = np.unique(np.concatenate(([0], lo, [fb, n - 2]))).astype(np.int64)
        bounds_t = t[starts]
        vel = _Segments(starts, n, width)
        eff = _Segments(starts, n, width)
        acc = _Segments(starts, n, width)
        # sums of (t - t[0]) * speed per segment: the window's least-squares speed trend
        tvel = _Segments(starts, n, width)
    torque_peak = 0.0
    wrench: dict[str, dict[str, Any]] = {}
    diags = DiagnosticsKeeper()
    row = done = 0
    carry_t, carry_v = np.zeros(0), np.zeros((0, width))
    # pass 2: per-segment statistics of everything the report reads
    topics = ([js_topic] if streaming else []) + wanted
    for topic, msgtype, d in (bagmod.iter_blocks(path, topics, columns=('velocity', 'effort'),
                                                 raw=('/diagnostics',)) if topics else ()):
        if topic == js_topic:
            v, e = d['velocity'], d['effort']
            k = v.shape[0]
            if indexed is not None:
                if (d.get('foreign', 0) or row + k > n or d['names'] != run_names
                        or not np.array_equal(_seconds(d['stamp_ns']), t[row:row + k])):
                    raise _NotIndexed(js_topic)
                v0 = v[:, 0] if v.shape[1] else np.full(k, np.nan)
                w[row:row + k] = v0
                speed_peak = max(speed_peak, float(np.max(np.abs(v0)))) if k else speed_peak
            vel.add(row, v)
            eff.add(row, e)
            tvel.add(row, (t[row:row + k] - t[0])[:, None] * v)
            if e.size:
                torque_peak = max(torque_peak, float(np.max(np.abs(e))))
            # acceleration, np.gradient(edge_order=2) block by block: the last three rows
            # are carried over; a row is final once its right neighbour is in (interior
            # formula, per row the arithmetic of the whole-record call); row 0 takes the
            # edge formula as there
            ext_t = np.concatenate((carry_t, t[row:row + k]))
            ext_v = np.concatenate((carry_v, v))
            first = row - carry_t.size
            if ext_t.size >= 3:
                g = np.gradient(ext_v, ext_t, axis=0, edge_order=2)
                a, b = done - first, ext_t.size - 1
                if a < b:
                    acc.add(done, g[a:b], with_sum=False)
                    done = first + b
                carry_t, carry_v = ext_t[-3:], ext_v[-3:]
            else:
                carry_t, carry_v = ext_t, ext_v
            row += k
        elif msgtype == 'geometry_msgs/msg/WrenchStamped':
            if not streaming:
                continue
            sn = d['stamp_ns']
            tw = (sn // 1_000_000_000).astype(float) + (sn % 1_000_000_000).astype(float) * 1e-9
            agg = wrench.setdefault(topic, {'count': 0, 'seg': _Segments(
                np.arange(starts.size, dtype=np.int64), starts.size, 1)})
            agg['count'] += tw.size
            seg = np.searchsorted(bounds_t, tw, side='right') - 1
            keep = (seg >= 0) & (tw <= t[-1])
            tz, seg = d['wrench'][keep, 5:6], seg[keep]
            for j in np.unique(seg):
                agg['seg'].add_to(int(j), tz[seg == j])
        elif topic == '/diagnostics':
            diags.add(d)
        elif topic == bagmod.SCENE_TOPIC and d and extra['scene'] is None:
            extra['scene'] = d[0][1].data
    extra['diagnostics'] = diags.series()
    if not streaming:
        return out, extra
    if row != n:
        if indexed is not None:
            raise _NotIndexed(js_topic)
        raise NotStreamable(f'{js_topic}: {row} rows in the second pass, {n} in the first')
    if done < n:                      # the last row: the edge formula over the last three
        g = np.gradient(carry_v, carry_t, axis=0, edge_order=2)
        acc.add(done, g[g.shape[0] - (n - done):], with_sum=False)
    # the steady window from the slice statistics
    reference = f'{names[0]} speed'
    signals = [reference] + [f'{name} torque' for name in names]
    stats = None
    if usable:
        seg_of = {int(x): j for j, x in enumerate(starts)}
        groups = [(seg_of[int(a)], seg_of[int(lo[k + 1])] if k + 1 < n_sl else starts.size)
                  for k, a in enumerate(lo)]
        w_spans = steady.slice_spans(w[:, None], lo)[:, 0]
        t_spans = eff.spans(groups)
        stats = [(reference, w_spans, speed_peak, steady.SPEED_FLOOR)]
        stats += [(f'{name} torque', t_spans[:, i], torque_peak, steady.TORQUE_FLOOR)
                  for i, name in enumerate(names)]
    means = None
    if usable:
        # the Hann means as the in-memory path takes them: of the first column of an (m,
        # shafts) array (a strided dot product rounds differently from a contiguous one)
        means = np.empty(n_sl)
        for k, (a, b) in enumerate(zip(lo, hi)):
            tmp = np.empty((b - a, width))
            tmp[:, 0] = w[a:b]
            means[k] = steady.hann_mean(tmp[:, 0])
    win = steady.window_from_slices(t, w, lo, hi, edges, stats, reference=reference,
                                    signals=signals, means=means)
    first_row = int(np.argmax(win.mask(t)))
    j0 = int(np.searchsorted(starts, first_row, side='right') - 1)
    if starts[j0] != first_row:
        raise NotStreamable(f'window start row {first_row} is not a segment start')
    count = n - first_row
    out['window_s'] = [float(t[first_row]), float(t[-1])]
    out['window'] = win.to_dict()
    out['window_text'] = win.describe()
    v_mx, v_mn, v_sum = vel.window(j0)
    e_mx, e_mn, e_sum = eff.window(j0)
    a_mx, a_mn, _ = acc.window(j0)
    for i, name in enumerate(names):
        mean = float(v_sum[i] / count)
        span = float(v_mx[i] - v_mn[i])
        out['shafts'][name] = {'mean_speed': mean,
                               'delta': span / abs(mean) if mean != 0.0 else float('inf'),
                               'speed_amplitude': 0.5 * span,
                               'acceleration_amplitude': 0.5 * float(a_mx[i] - a_mn[i]),
                               'mean_torque': float(e_sum[i] / count),
                               'torque_amplitude': 0.5 * float(e_mx[i] - e_mn[i])}
    from cvj_ros.physics.degenerate import slope_from_sums, trend_line_of
    tw_sum = tvel.window(j0)[2]
    tr = t[first_row:] - t[0]
    st, stt = float(tr.sum()), float(tr @ tr)
    out['speed_trend'] = trend_line_of(
        {name: (slope_from_sums(count, st, stt, float(v_sum[i]), float(tw_sum[i])),
                float(v_mx[i] - v_mn[i])) for i, name in enumerate(names)},
        float(t[-1] - t[first_row]))
    for topic in [tp for tp in wanted if tp in wrench]:   # bag order, as read_bag gives it
        agg = wrench[topic]
        seg = agg['seg']
        m = int(seg.count[j0:].sum())
        if agg['count'] < 3 or m < 2:
            continue
        mx, mn, sm = seg.window(j0)
        out['wrenches'][topic] = {'mean_torque': float(sm[0] / m),
                                  'torque_amplitude': 0.5 * float(mx[0] - mn[0])}
    return out, extra
