"""The run report's streaming pass (cvj_ros.orchestrate.report_stream) against the in-memory
bag_metrics it replaces: the same window (text and bounds, exactly) and the same figures to
rounding (sums of segment sums against np.mean: 1e-12 relative), for steady and never-steady
records, with blocks small enough to split slices and the acceleration's carried rows; the
/diagnostics figures the report reads are the same; and its memory grows by the joint-state
times and reference speed only (a few tens of bytes per exchange, against ~200 for the
in-memory path), measured with tracemalloc on two bag lengths (a few seconds)."""
from __future__ import annotations

import math
import tracemalloc
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip('rclpy')

from cvj_ros import bag, bag_decode  # noqa: E402
from cvj_ros.orchestrate import report  # noqa: E402
from cvj_ros.orchestrate.report_stream import stream_bag_metrics  # noqa: E402

H_NS = 1_000_000
NAMES = ['engine_crank', 'cpl_input', 'cpl_output', 'wheel']


def write_run_bag(path: Path, steps: int, *, ramp: float = 0.0, storage: str = 'mcap',
                  scene: bool = False, late_record: int | None = None,
                  gap: range = range(0)) -> Path:
    """A run-like bag: per step /clock, joint states (4 shafts, 2nd-order ripple, speed
    ramp ``ramp`` rad/s^2), an engine and a load answer; /diagnostics every 50 steps with a
    WARN every 1000; the project's own encoders (fast). ``scene``: the run's joint names in
    metadata.yaml (as a run's recorder stores them); ``late_record``: that joint state
    recorded 1 ns after its stamp (not what cvj_ros records); ``gap``: steps not recorded at
    all (ticks a free run skipped to catch up)."""
    from cvj_ros.nodes.cdr import ClockEncoder, JointStateEncoder, WrenchStampedEncoder
    from cvj_ros.nodes.diagnostics import diagnostic_array_encoder, plain_status
    js, eng, load, clock = (JointStateEncoder(NAMES, 'driveline'), WrenchStampedEncoder('engine_crank'),
                            WrenchStampedEncoder('wheel'), ClockEncoder())
    diag = diagnostic_array_encoder()
    w = bag.BagWriter(path, storage=storage)
    if scene:
        import yaml
        w.set_custom_data('cvj_ros.scene', yaml.safe_dump({'seed': 1, 'shaft_names': NAMES}))
    for topic in (bag.CLOCK_TOPIC, bag.JOINT_STATES_TOPIC, '/engine/wrench', '/load/wrench',
                  '/diagnostics'):
        w.add_topic(topic)
    items = []
    k = np.arange(steps)
    t = k * 1e-3
    phi = 40.0 * t + 0.5 * ramp * t ** 2
    omega = 40.0 + ramp * t
    for i in range(steps):
        if i in gap:
            continue
        sec, nsec = divmod(i * H_NS, 1_000_000_000)
        ripple = np.array([0.0, 0.1, 0.4, 0.3]) * np.sin(2 * phi[i] + np.arange(4))
        eff = 100.0 + np.array([5.0, 3.0, 2.0, 1.0]) * np.cos(2 * phi[i])
        items += [(bag.CLOCK_TOPIC, i * H_NS, clock.encode(sec, nsec)),
                  (bag.JOINT_STATES_TOPIC, i * H_NS + (i == late_record),
                   js.encode(sec, nsec, phi[i] + np.zeros(4), omega[i] + ripple, eff)),
                  ('/engine/wrench', i * H_NS, eng.encode(sec, nsec, 0, 0, 0, 0, 0, eff[0])),
                  ('/load/wrench', i * H_NS, load.encode(sec, nsec, 0, 0, 0, 0, 0, 99.0 + math.sin(i)))]
        if i % 50 == 0:
            level = b'\x01' if i % 1000 == 0 else b'\x00'
            items.append(('/diagnostics', i * H_NS, diag.encode(i * H_NS, 'driveline', [
                plain_status('coupling_node: loop', b'\x00', 'running',
                             {'ignored_stamps': i // 50, 'overhead_us_mean': 50.0}),
                plain_status('monitor: cpl_input', level, f'nonuniformity {i}')])))
        if len(items) >= 4096:
            w.write_batch(items)
            items = []
    w.write_batch(items)
    w.close()
    return path


def _same(a: dict, b: dict) -> None:
    assert a.keys() == b.keys()
    assert a.get('window_text') == b.get('window_text') and a.get('window_s') == b.get('window_s')
    assert a.get('speed_trend') == b.get('speed_trend')
    assert list(a['wrenches']) == list(b['wrenches'])
    for group in ('shafts', 'wrenches'):
        for name, figures in a[group].items():
            for key, x in figures.items():
                y = b[group][name][key]
                assert (math.isnan(x) and math.isnan(y)) or y == pytest.approx(x, rel=1e-12, abs=1e-12), \
                    (group, name, key, x, y)


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
@pytest.mark.parametrize('ramp', [0.0, 8.0], ids=['steady', 'never_steady'])
def test_stream_equals_in_memory(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, ramp: float,
                                 storage: str) -> None:
    path = write_run_bag(tmp_path / 'b', 3001, ramp=ramp, storage=storage)
    full = report.bag_metrics(path)
    monkeypatch.setattr(bag_decode, 'BATCH', 97)      # blocks split the slices
    streamed, side = stream_bag_metrics(path)
    _same(full, streamed)
    assert streamed['window']['steady'] is (ramp == 0.0)
    # the ramp (8 rad/s^2) dominates the window's max - min (2 x 0.4 rad/s ripple): named
    assert (streamed['speed_trend'] is None) is (ramp == 0.0)
    if ramp:
        import re
        slope = re.search(r'accelerates by \S+ rad/s over the window \(\+(\S+) rad/s\^2\)',
                          streamed['speed_trend'])
        assert slope and float(slope.group(1)) == pytest.approx(8.0, rel=1e-3)   # ripple: 7.997
    diags = bag.read_bag(path, ['/diagnostics'])['/diagnostics']
    for fn in (report.loop_counters, report.loop_timing, report.monitor_statuses):
        assert fn(path, diags=side['diagnostics']) == fn(path, diags=diags), fn.__name__
    assert report.monitor_statuses(path, diags=side['diagnostics'])['warn'] == 4


def test_a_gap_at_the_start_leaves_the_later_slices_measurable(tmp_path: Path,
                                                               monkeypatch: pytest.MonkeyPatch) -> None:
    """Steps 5..599 of 3001 (1 ms) not recorded, as the free run of a clutch launch whose
    report said 'not measurable (fewer than 2 samples per slice)' with 472 samples: the
    first two 0.3 s slices hold 5 and 0 samples, the eight after them 300 each. Both paths
    compare those eight (steady.usable_tail): the same window, steady, drift measured."""
    path = write_run_bag(tmp_path / 'b', 3001, gap=range(5, 600))
    full = report.bag_metrics(path)
    monkeypatch.setattr(bag_decode, 'BATCH', 97)
    streamed, _side = stream_bag_metrics(path)
    _same(full, streamed)
    assert streamed['window']['steady'] is True and streamed['window']['slices'] == 8
    assert streamed['window_s'][0] == pytest.approx(0.6)
    assert 'not measurable' not in streamed['window_text'] and 'drift ' in streamed['window_text']


@pytest.mark.parametrize('late_record', [None, 1234], ids=['indexed', 'record_time_differs'])
def test_times_from_the_message_indexes_equal_the_messages(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, late_record: int | None) -> None:
    """A run's mcap bag (joint names in metadata.yaml): the joint-state times come from the
    message indexes and pass 2 checks each stamp against them; a joint state recorded at
    another time than its stamp sends the report back to reading the times from the
    messages - either way the figures equal the in-memory path's."""
    from cvj_ros.orchestrate import report_stream
    path = write_run_bag(tmp_path / 'b', 3001, scene=True, late_record=late_record)
    full = report.bag_metrics(path)
    monkeypatch.setattr(bag_decode, 'BATCH', 97)      # the check runs block by block
    calls = []
    real = report_stream._stream

    def spy(path, counts, types, indexed):
        calls.append(indexed is not None)
        return real(path, counts, types, indexed)
    monkeypatch.setattr(report_stream, '_stream', spy)
    streamed, side = stream_bag_metrics(path)
    _same(full, streamed)
    assert calls == ([True] if late_record is None else [True, False])
    ns = bag_decode.mcap_log_times(str(path / 'b.mcap'), bag.JOINT_STATES_TOPIC)
    expected = np.arange(3001) * H_NS
    if late_record is not None:
        expected[late_record] += 1
    assert np.array_equal(ns, expected)
    assert bag_decode.mcap_log_times(str(path / 'b.mcap'), '/nope').size == 0
    cut = tmp_path / 'cut.mcap'
    cut.write_bytes((path / 'b.mcap').read_bytes()[:5000])
    assert bag_decode.mcap_log_times(str(cut), bag.JOINT_STATES_TOPIC) is None


@pytest.mark.parametrize('scene', [False, True], ids=['times_from_messages', 'times_from_index'])
def test_report_memory_grows_by_the_times_and_reference_speed_only(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, scene: bool) -> None:
    """Traced peak (tracemalloc: Python objects and numpy arrays) of the streaming report on
    10 000 and 40 000 steps: the growth per step is bounded by the joint-state times and
    reference speed it keeps (16 B) plus slack: 48 B. The in-memory path holds ~200 B per
    step of arrays (speeds, torques, every answer). The read-ahead (chunks gathered at once,
    messages decoded at once) is a constant, set small here so that both bags exceed it."""
    monkeypatch.setattr(bag_decode, 'CHUNKS_AT_ONCE', 1)
    monkeypatch.setattr(bag_decode, 'BATCH', 1024)
    peaks = {}
    for steps in (10_000, 40_000):
        path = write_run_bag(tmp_path / f'b{steps}', steps, scene=scene)
        stream_bag_metrics(path)                 # warm: imports, type store, caches
        tracemalloc.start()
        try:
            stream_bag_metrics(path)
            peaks[steps] = tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()
    per_step = (peaks[40_000] - peaks[10_000]) / 30_000
    print(f'\nstreaming report: traced peak {peaks[10_000] / 2**20:.1f} / {peaks[40_000] / 2**20:.1f} '
          f'MiB for 10k / 40k steps: {per_step:.1f} B per step')
    assert per_step <= 48.0
