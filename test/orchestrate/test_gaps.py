"""The report's gaps: missing sample times on the loop topics counted against the grid
t_k = k h (fabricated stamps, closed-form counts), starved steady-window slices, the one
line (only when there is something to say), and the figures read from a written bag."""
from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from cvj_ros.orchestrate.gaps import gap_line, gap_summary, grid_topic, run_gaps, starved_slices

H_NS = 1_000_000          # 1 ms


def grid(ks) -> np.ndarray:
    return np.asarray(ks, dtype=np.int64) * H_NS


def test_gap_summary_counts_missing_grid_times_and_the_longest_run() -> None:
    full = grid(range(101))                                     # t_0 .. t_100
    skipped = np.delete(full, list(range(1, 61)) + [70, 71])    # 60 after t_0, 2 at 70 ms
    late = full[30:]                                            # recorder missed t_0 .. t_29
    s = gap_summary({'/ok': full, '/skip': skipped, '/late': late,
                     '/off': np.concatenate((full[:50], full[50:] + 1))}, H_NS, 100 * H_NS)
    assert '/ok' not in s
    assert s['/skip'] == {'expected': 101, 'missing': 62, 'gap_from_s': 0.001, 'gap_s': 0.06}
    assert s['/late'] == {'expected': 101, 'missing': 30, 'gap_from_s': 0.0, 'gap_s': 0.03}
    # stamps off the grid are not present: t_50 .. t_100 missing, the run at the end
    assert s['/off'] == {'expected': 101, 'missing': 51, 'gap_from_s': 0.05, 'gap_s': 0.051}


def test_gap_summary_ignores_duplicates_and_stamps_beyond_the_end() -> None:
    ts = np.concatenate((grid(range(11)), grid([3, 3, 12, 13]), [-H_NS]))
    assert gap_summary({'/a': ts}, H_NS, 10 * H_NS) == {}
    assert gap_summary({'/a': ts}, 0, 10 * H_NS) == {}


def test_grid_topics_are_the_loop_topics_with_one_sample_per_step() -> None:
    assert all(grid_topic(t) for t in ('/clock', '/driveline/joint_states', '/engine/wrench',
                                       '/load/wrench', '/coupling/tripod/wrench', '/load/fl/wrench'))
    assert not any(grid_topic(t) for t in ('/diagnostics', '/driveline/scene', '/engine/throttle',
                                           '/engine/throttle_scale', '/driveline/clutch'))


def test_starved_slices_are_the_slices_with_fewer_than_two_samples() -> None:
    t = np.arange(0, 10.0001, 0.01)                 # 10 s: 10 slices of 1 s (steady.N_SLICES)
    assert starved_slices(t) == (0, 10, None)
    gap = t[(t < 0.005) | (t > 2.5)]                # nothing in 0.005 .. 2.5 s
    bad, n, until = starved_slices(gap)
    assert (bad, n) == (2, 10) and until == 2.0     # 0..1 s holds 1 sample, 1..2 s none


def test_gap_line_one_line_only_with_something_to_say() -> None:
    assert gap_line({}) is None
    assert gap_line({'topics': {}, 'grid_topics': 4, 'starved_slices': 0}) is None
    same = {'missing': 62, 'expected': 101, 'gap_from_s': 0.001, 'gap_s': 0.06}
    gaps = {'topics': {t: same for t in ('/clock', '/driveline/joint_states', '/engine/wrench',
                                         '/load/wrench')},
            'grid_topics': 4, 'starved_slices': 0}
    line = gap_line(gaps, 62)
    assert line == ('  gaps: all 4 loop topics miss 62 of 101 sample times (longest run 0.06 s '
                    'from t = 0.001 s); 62 ticks skipped by free-run catch-up')
    assert '\n' not in line
    # the recorder lost more than the node skipped, on one topic
    gaps['topics']['/clock'] = {'missing': 70, 'expected': 101, 'gap_from_s': 0.0, 'gap_s': 0.008}
    line = gap_line({**gaps, 'starved_slices': 2, 'slices': 5, 'starved_until_s': 0.04}, 62)
    assert line == ('  gaps: /clock miss 70 of 101 sample times (longest run 0.008 s from t = 0 s); '
                    '/driveline/joint_states, /engine/wrench, /load/wrench miss 62 of 101 sample '
                    'times (longest run 0.06 s from t = 0.001 s); 62 ticks skipped by free-run '
                    'catch-up, 8 more lost before the recorder; 2 of 5 steady-window slices with '
                    '< 2 joint states (window from 0.04 s at the earliest)')
    # lockstep (no tick skipped): what is missing was lost
    assert gap_line({'topics': {'/clock': same}, 'grid_topics': 4}).endswith(
        'no tick skipped: lost before the recorder')
    # skipped ticks are said even when the bag shows no gap of its own
    assert gap_line({'topics': {}, 'grid_topics': 4}, 3) == '  gaps: 3 ticks skipped by free-run catch-up'
    assert gap_line({'topics': {}, 'grid_topics': 4}, 1) == '  gaps: 1 tick skipped by free-run catch-up'


def test_run_gaps_from_a_written_bag(tmp_path: Path) -> None:
    """A bag written as a run's recorder writes it (record time = stamp), mcap and sqlite3:
    the same figures from the message indexes and from the messages."""
    from cvj_ros.bag import BagWriter
    from cvj_ros.nodes.cdr import ClockEncoder, JointStateEncoder, WrenchStampedEncoder
    js, eng, clock = JointStateEncoder(['a', 'b'], 'driveline'), WrenchStampedEncoder('a'), ClockEncoder()
    ks = [k for k in range(201) if not 10 <= k < 40]          # t_10 .. t_39 skipped
    for storage in ('mcap', 'sqlite3'):
        path = tmp_path / storage
        with BagWriter(path, storage=storage) as w:
            for topic in ('/clock', '/driveline/joint_states', '/engine/wrench'):
                w.add_topic(topic)
            for k in ks:
                sec, nsec = divmod(k * H_NS, 10**9)
                w.write('/clock', k * H_NS, clock.encode(sec, nsec))
                w.write('/driveline/joint_states', k * H_NS,
                        js.encode(sec, nsec, np.zeros(2), np.ones(2), np.zeros(2)))
                if k != 200:                                  # the last answer in flight
                    w.write('/engine/wrench', k * H_NS, eng.encode(sec, nsec, 0, 0, 0, 0, 0, 1.0))
        counts = {'/clock': len(ks), '/driveline/joint_states': len(ks), '/engine/wrench': len(ks) - 1,
                  '/diagnostics': 3}
        g = run_gaps(path, 0.001, counts=counts)
        assert g['grid_topics'] == 3 and g['slices'] > 0, storage
        assert g['topics']['/driveline/joint_states'] == g['topics']['/clock'] == {
            'expected': 201, 'missing': 30, 'gap_from_s': 0.01, 'gap_s': 0.03}, storage
        assert g['topics']['/engine/wrench']['missing'] == 31, storage


def test_gap_summary_matches_a_set_reference_on_random_stamps() -> None:
    """Unsorted stamps with repeats, off-grid and out-of-range ones: the counts and the
    longest run equal those of a plain Python set of the grid indices present."""
    rng = np.random.default_rng(3)
    n = 500
    for _ in range(20):
        ts = rng.integers(-5, n + 20, size=rng.integers(0, 2 * n)) * H_NS
        ts[rng.random(ts.size) < 0.1] += 7                  # off the grid
        present = {int(t) // H_NS for t in ts if 0 <= t <= (n - 1) * H_NS and t % H_NS == 0}
        runs, best, start = [], (0, 0), 0
        run = 0
        for k in range(n + 1):
            if k < n and k not in present:
                if run == 0:
                    start = k
                run += 1
                continue
            if run > best[0]:
                best = (run, start)
            run = 0
        got = gap_summary({'/a': ts}, H_NS, (n - 1) * H_NS)
        if len(present) == n:
            assert got == {}
            continue
        assert got['/a'] == {'expected': n, 'missing': n - len(present),
                             'gap_from_s': best[1] * H_NS / 1e9, 'gap_s': best[0] * H_NS / 1e9}
