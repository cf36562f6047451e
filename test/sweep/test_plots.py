"""Sweep plots from a results directory (no simulation: written tables), --replot and
--metric errors, and the per-order torque amplitudes against a synthetic signal."""
from __future__ import annotations

import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from cvj_ros.cli import main
from cvj_ros.commands.sweep import load_scene_data
from cvj_ros.physics.scene import find_scene
from cvj_ros.sweep.plots import axis_label, metric_label, write_sweep_plots
from cvj_ros.sweep.results import ResultStore
from cvj_ros.sweep.run import Outcome, order_amplitudes
from cvj_ros.sweep.spec import SweepError, build_sweep


def fake_sweep(out: Path, sets: list[str], samples: int | None = None) -> None:
    """A sweep directory whose rows follow delta = 1e-3 alpha^2 / sqrt(stiffness) and an
    order-2 torque growing with speed; variant 3 is invalid (a grey cell)."""
    base = load_scene_data(find_scene('kavz685_lever'))
    sweep = build_sweep(base, sets, samples=samples, seed=1)
    store = ResultStore(out)
    store.write_manifest({'definition': {'scene': {'name': 'kavz685_lever'}, **sweep.definition}})
    outcomes = []
    for i, (alpha, k) in enumerate(sweep.variants):
        if i == 3:
            outcomes.append(Outcome(i, {'status': 'invalid', 'error': 'x: bad'}, 0.0))
            continue
        w = 20.0 + 10.0 * i / len(sweep)
        outcomes.append(Outcome(i, {'status': 'ok', 'drive_shaft.mean_speed': w,
                                    'driven_shaft.delta': 1e-3 * alpha ** 2 / math.sqrt(k),
                                    'drive_shaft.torque_order1': 1e-9,
                                    'drive_shaft.torque_order2': 0.1 * w, 'error': ''}, 0.01))
    store.append(outcomes)
    store.write_tables([a.column for a in sweep.axes], sweep.variants, store.load_done())


def test_grid_plots(tmp_path: Path) -> None:
    fake_sweep(tmp_path, ['driveline[coupling].params.alpha_deg=5:25:5',
                          'driveline[bushings].stiffness=300:3000:6:log'])
    paths = write_sweep_plots(tmp_path)
    assert [p.name for p in paths] == ['line_driven_shaft_delta.png', 'map_driven_shaft_delta.png',
                                       'resonance.png']
    assert all(p.stat().st_size > 10_000 for p in paths)     # a drawn figure, not an empty one
    assert axis_label('driveline[bushings].stiffness') == 'driveline[bushings].stiffness (N m/rad)'
    assert axis_label('driveline[coupling].params.alpha_deg').endswith('(deg)')
    assert metric_label('driven_shaft.delta') == 'driven_shaft: nonuniformity δ (-)'


def test_random_plots(tmp_path: Path) -> None:
    fake_sweep(tmp_path, ['driveline[coupling].params.alpha_deg=5:25',
                          'driveline[bushings].stiffness=300:3000:log'], samples=40)
    names = [p.name for p in write_sweep_plots(tmp_path, metric='driven_shaft.delta')]
    assert names[:2] == ['line_driven_shaft_delta.png', 'map_driven_shaft_delta.png']


def test_replot_errors(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(['sweep', '--replot', str(tmp_path / 'none')]) == 2
    assert 'no finished sweep there' in capsys.readouterr().err
    fake_sweep(tmp_path, ['driveline[coupling].params.alpha_deg=5:25:3',
                          'driveline[bushings].stiffness=300,600'])
    assert main(['sweep', '--replot', str(tmp_path), '--metric', 'driven_shaft.detla']) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["cvj-sim: error: --metric driven_shaft.detla: not a column of results.csv; "
                   "did you mean 'driven_shaft.delta'?"]
    with pytest.raises(SweepError):
        write_sweep_plots(tmp_path, metric='nope')


def test_order_amplitudes_of_a_known_signal() -> None:
    """Torque T0 + 3 cos(2 phi) + 0.5 sin(4 phi) at constant speed: orders 1..4 are
    (0, 3, 0, 0.5) N m. Harmonics on a 72-point grid by linear interpolation of 1 ms
    samples at 40 rad/s (0.04 rad apart): interpolation error ~ (0.04 k)^2 / 8 relative,
    3.2e-3 at order 4 (measured 2.1e-3 at order 4, 5.3e-4 at order 2; bounds 10x those)."""
    t = np.arange(0, 2.0001, 1e-3)
    phi = 40.0 * t
    torque = 100.0 + 3.0 * np.cos(2 * phi) + 0.5 * np.sin(4 * phi)
    trace = SimpleNamespace(t=t, names=['a', 'b'], position=np.stack([phi, phi], 1),
                            velocity=np.full((t.size, 2), 40.0),   # the steady window needs speeds
                            effort=np.stack([torque, np.zeros_like(t)], 1),
                            column=lambda n: ['a', 'b'].index(n))
    amps = order_amplitudes(trace, 4, None)
    assert list(amps) == ['a.torque_order1', 'a.torque_order2', 'a.torque_order3', 'a.torque_order4']
    assert amps['a.torque_order1'] < 1e-3 and amps['a.torque_order3'] < 1e-3
    assert amps['a.torque_order2'] == pytest.approx(3.0, rel=6e-3)
    assert amps['a.torque_order4'] == pytest.approx(0.5, rel=2.5e-2)


def test_sweep_progress_line_has_rate_and_eta() -> None:
    """Rate counts only the variants run in this invocation (resumed ones excluded)."""
    import io

    from cvj_ros.commands.sweep import SweepProgress
    now = [0.0]
    stream = io.StringIO()
    p = SweepProgress(1000, label='cvj-sim sweep', unit='variants', stream=stream,
                      clock=lambda: now[0], enabled=True)
    p.start = 200.0                # 200 variants done by an earlier run
    p.update(200)
    now[0] = 10.0
    p.update(700)                  # 500 new in 10 s: 50 variants/s, 300 left: 6 s
    assert stream.getvalue() == '\rcvj-sim sweep: 700/1000 variants (70%), 50 variants/s, ETA 6 s'


def test_line_plot_that_drops_series_says_so(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """10 stiffness values and MAX_LINES = 8 lines: the 2 left out are named in the plot's
    title and on the CLI (--replot), and a plot drawing every value says nothing."""
    from cvj_ros.sweep import plots as sweep_plots
    fake_sweep(tmp_path, ['driveline[coupling].params.alpha_deg=5:25:3',
                          'driveline[bushings].stiffness=300:3000:10'])
    kept: list = []
    notes: list[str] = []
    close = sweep_plots.plt.close
    sweep_plots.plt.close = kept.append
    try:
        write_sweep_plots(tmp_path, notes=notes)
    finally:
        sweep_plots.plt.close = close
    line_fig = kept[0]
    title = line_fig.axes[0].get_title().replace('\n', ' ')
    values = np.linspace(300, 3000, 10)
    picked = np.unique(np.linspace(0, 9, sweep_plots.MAX_LINES).round().astype(int))
    left = [f'{values[i]:.4g}' for i in range(10) if i not in picked]
    assert len(left) == 2 and len(line_fig.axes[0].get_legend().get_texts()) == 8
    assert f'8 of 10 values of driveline[bushings].stiffness drawn, not drawn: {", ".join(left)}' in title
    assert notes == [f'line_driven_shaft_delta.png: 8 of 10 values of driveline[bushings].stiffness '
                     f'drawn, not drawn: {", ".join(left)}']
    for f in kept:
        close(f)
    assert main(['sweep', '--replot', str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert f'plot note: {notes[0]}' in out.splitlines()
    # every value drawn: no note
    small = tmp_path / 'small'
    fake_sweep(small, ['driveline[coupling].params.alpha_deg=5:25:3',
                       'driveline[bushings].stiffness=300,600'])
    notes = []
    write_sweep_plots(small, notes=notes)
    assert notes == []
    assert sweep_plots.dropped_note('b', [1.0, 2.0], [1.0, 2.0], [2.0]) == \
        'no ok variant (no line) at b = 2'
