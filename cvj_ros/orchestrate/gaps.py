"""Gaps in a run's record: sample times missing on the topics with one sample per exchange
step, and the steady-window slices they starve.

The loop's topics - ``/clock``, ``/driveline/joint_states``, and the wrenches answering or
accompanying each state (``/engine/wrench``, ``/load/wrench``, ``/coupling/<joint>/wrench``,
``/load/<wheel>/wrench``) - have one sample at every t_k = k h from t_0 = 0 to the last
joint state recorded. A sample time missing on one of them is a tick a free run skipped to
catch up with wall time (then missing on all of them alike, and counted by the coupling
node as ``ticks_skipped``) or a sample lost on the way to the recorder. :func:`gap_summary`
counts them per topic with the longest run of missing times; :func:`gap_line` is the
report's one line, only when something is missing, ticks were skipped or slices starved.
"""
from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from cvj_ros import bag as bagmod


def grid_topic(topic: str) -> bool:
    """A topic with one sample per exchange step, stamped t_k (module docstring)."""
    return (topic in (bagmod.CLOCK_TOPIC, bagmod.JOINT_STATES_TOPIC)
            or bagmod.exchange_wrench_topic(topic))


def record_times(bag: Path, topics: list[str]) -> dict[str, np.ndarray]:
    """Record times (int64 ns, file order) of ``topics`` in ``bag``: from the message indexes
    of a plain mcap bag (the messages are not read), else from the messages. For these
    topics the record time is the sample's stamp (header stamp, /clock's value)."""
    out: dict[str, np.ndarray] = {}
    plain = bagmod.plain_mcap_bag(bag)
    if plain is not None:
        from cvj_ros.bag_decode import mcap_log_time_parts
        for topic in topics:
            parts: list[np.ndarray] = []
            for f in plain[0]:
                got = mcap_log_time_parts(str(f), topic)
                if got is None:
                    break
                parts += got
            else:
                out[topic] = np.concatenate(parts) if parts else np.zeros(0, dtype=np.int64)
    rest = [t for t in topics if t not in out]
    if rest:
        for topic, _ty, d in bagmod.iter_blocks(bag, rest, columns=()):
            sn = np.asarray(d['record_ns'], dtype=np.int64)
            out[topic] = np.concatenate((out[topic], sn)) if topic in out else sn
    return out


def gap_summary(times: Mapping[str, np.ndarray], h_ns: int,
                end_ns: int) -> dict[str, dict[str, Any]]:
    """Per topic with any sample time of the grid t_k = k ``h_ns`` (k = 0 .. ``end_ns`` // h)
    missing: ``expected`` grid times, ``missing`` of them, and the longest run of missing
    times, ``gap_from_s`` (its first missing time, s) and ``gap_s`` (its length, missing
    times x h, s). Stamps off the grid or beyond ``end_ns`` are not counted as present;
    topics with nothing missing are left out."""
    h_ns, end_ns = int(h_ns), int(end_ns)
    if h_ns <= 0 or end_ns < 0:
        return {}
    n = end_ns // h_ns + 1
    out: dict[str, dict[str, Any]] = {}
    for topic, ts in times.items():
        ts = np.asarray(ts, dtype=np.int64)
        k = np.sort(ts[(ts >= 0) & (ts <= end_ns) & (ts % h_ns == 0)] // h_ns)
        k = k[np.concatenate(([True], k[1:] != k[:-1]))] if k.size else k   # distinct
        missing = n - int(k.size)
        if missing <= 0:
            continue
        # runs of missing grid indices between present ones (virtual present -1 and n)
        edges = np.concatenate(([-1], k, [n]))
        runs = np.diff(edges) - 1
        i = int(np.argmax(runs))
        out[topic] = {'expected': n, 'missing': missing,
                      'gap_from_s': (int(edges[i]) + 1) * h_ns / 1e9,
                      'gap_s': int(runs[i]) * h_ns / 1e9}
    return out


def starved_slices(t: np.ndarray) -> tuple[int, int, float | None]:
    """``(starved, slices, after_s)`` of the joint-state times ``t`` (s): slices of the steady
    criterion (:func:`cvj_ros.physics.steady.slice_bounds`) holding fewer than two samples
    (they cannot be compared, so the window can only start after the last of them), how
    many slices there are, and the end (s) of the last starved one (None without)."""
    from cvj_ros.physics import steady
    if t.size < 3:
        return 0, 0, None
    edges, lo, hi = steady.slice_bounds(t)
    bad = np.flatnonzero(hi - lo < 2)
    return int(bad.size), int(lo.size), (float(edges[bad[-1] + 1]) if bad.size else None)


def run_gaps(bag: Path, h: float, *, counts: Mapping[str, int]) -> dict[str, Any]:
    """The gap figures of a run's bag (exchange step ``h`` s, topic ``counts``): ``topics``
    (:func:`gap_summary` up to the last joint state recorded), ``grid_topics`` (how many
    such topics the bag has) and the steady window's
    ``starved_slices``, ``slices`` and ``starved_until_s`` (:func:`starved_slices`); empty
    without joint states."""
    topics = [t for t, c in counts.items() if c and grid_topic(t)]
    if bagmod.JOINT_STATES_TOPIC not in topics:
        return {}
    times = record_times(bag, topics)
    js = np.sort(times[bagmod.JOINT_STATES_TOPIC])
    if js.size == 0:
        return {}
    h_ns = int(round(h * 1e9))
    out: dict[str, Any] = {'topics': gap_summary(times, h_ns, int(js[-1])),
                           'grid_topics': len(topics)}
    t = (js // 1_000_000_000).astype(float) + (js % 1_000_000_000).astype(float) * 1e-9
    n_bad, n_slices, until = starved_slices(t)
    out.update(starved_slices=n_bad, slices=n_slices, starved_until_s=until)
    return out


def gap_line(gaps: Mapping[str, Any], ticks_skipped: int = 0) -> str | None:
    """The report's line on gaps in the record, None when there is nothing to say: per group
    of topics missing the same sample times (``all N loop topics`` when every one does), how
    many of how many and the longest run; the ticks a free run skipped to catch up (the
    coupling node's count: what is missing beyond them was lost before the recorder); the
    steady-window slices left with fewer than two joint states."""
    parts: list[str] = []
    found = gaps.get('topics', {})
    groups: dict[tuple[int, int, float, float], list[str]] = {}
    for topic, g in sorted(found.items()):
        key = (g['missing'], g['expected'], g['gap_from_s'], g['gap_s'])
        groups.setdefault(key, []).append(topic)
    n_grid = int(gaps.get('grid_topics', 0))
    for (missing, expected, start, length), topics in sorted(groups.items(),
                                                             key=lambda kv: -kv[0][0]):
        who = f'all {n_grid} loop topics' if len(topics) == n_grid > 1 else ', '.join(topics)
        parts.append(f'{who} miss {missing} of {expected} sample times (longest run '
                     f'{length:.6g} s from t = {start:.6g} s)')
    worst = max((g['missing'] for g in found.values()), default=0)
    if ticks_skipped:
        parts.append(f'{ticks_skipped} tick{"s" if ticks_skipped != 1 else ""} skipped by '
                     'free-run catch-up'
                     + (f', {worst - ticks_skipped} more lost before the recorder'
                        if worst > ticks_skipped else ''))
    elif worst:
        parts.append('no tick skipped: lost before the recorder')
    if gaps.get('starved_slices'):
        parts.append(f'{gaps["starved_slices"]} of {gaps["slices"]} steady-window slices with < 2 '
                     f'joint states (window from {gaps["starved_until_s"]:.6g} s at the earliest)')
    return ('  gaps: ' + '; '.join(parts)) if parts else None
