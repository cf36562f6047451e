"""cvj_ros.progress: at most one line per second on a terminal, nothing otherwise; the
numbers on the line (real-time factor, ETA) from a fake clock, checked by hand."""
from __future__ import annotations

import io

from cvj_ros.progress import Progress, format_duration


class FakeTTY(io.StringIO):
    def isatty(self) -> bool:
        return True


class FakeClock:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def test_at_most_one_line_per_second_on_a_terminal() -> None:
    out, clock = FakeTTY(), FakeClock()
    p = Progress(60.0, label='cvj-sim run', stream=out, clock=clock)
    assert p.enabled
    # 1 simulated ms per 0.5 wall ms (factor 2), 4001 updates over 2 wall s: 2 lines
    for k in range(1, 4002):
        clock.t = 100.0 + 0.0005 * k
        p.update(0.001 * k)
    assert p.lines == 2   # at wall 1.0 s and 2.0 s after the first update (t0 = 100.0005)
    last = out.getvalue().split('\r')[-1]
    # at wall 2.0 s after t0 the sim time is ~4.0 s: factor 2, ETA (60 - 4) / 2 = 28 s
    assert last.startswith('cvj-sim run: t=4.001/60 s simulated (7%), real-time factor 2, ETA 28 s')
    p.close()
    assert out.getvalue().endswith('\r' + ' ' * len(last.rstrip()) + '\r')


def test_quiet_when_not_a_terminal() -> None:
    out, clock = io.StringIO(), FakeClock()
    p = Progress(10.0, label='cvj-sim simulate', stream=out, clock=clock)
    assert not p.enabled
    for k in range(100):
        clock.t += 1.0
        p.update(0.1 * k)
    p.close()
    assert out.getvalue() == '' and p.lines == 0


def test_count_progress_eta_from_mean_time_per_item() -> None:
    out, clock = FakeTTY(), FakeClock()
    p = Progress(140, label='cvj-sim bench', unit='runs', stream=out, clock=clock)
    p.update(0)
    clock.t += 24.0       # 12 runs in 24 s: 2 s per run, 128 left -> 256 s
    p.update(12)
    assert out.getvalue() == '\rcvj-sim bench: 12/140 runs (9%), ETA 4 min 16 s'


def test_shorter_line_overwrites_the_longer_one() -> None:
    out, clock = FakeTTY(), FakeClock()
    p = Progress(1000, label='x', unit='runs', stream=out, clock=clock)
    p.update(0)
    clock.t += 1000.0
    p.update(1)                      # long ETA text
    first = out.getvalue().split('\r')[-1]
    clock.t += 1.0
    p.update(999)
    second = out.getvalue().split('\r')[-1]
    assert len(second) == len(first) and second.rstrip() != second


def test_format_duration() -> None:
    assert [format_duration(s) for s in (0.4, 47, 185, 7260)] == ['0 s', '47 s', '3 min 5 s', '2 h 01 min']


def _ticking_clock(monkeypatch) -> None:
    """Every reading of the progress clock advances 1 s: one line per update."""
    clock = FakeClock()

    def tick() -> float:
        clock.t += 1.0
        return clock.t
    monkeypatch.setattr(Progress, 'default_clock', staticmethod(tick))


def test_simulate_cli_progress_on_a_terminal_only(monkeypatch, capsys) -> None:
    from cvj_ros.cli import main
    assert main(['simulate', 'kavz685_lever', '--duration', '0.05']) == 0
    quiet = capsys.readouterr()
    assert quiet.err == ''                         # not a terminal: nothing
    _ticking_clock(monkeypatch)
    tty = FakeTTY()
    monkeypatch.setattr('sys.stderr', tty)
    assert main(['simulate', 'kavz685_lever', '--duration', '0.05']) == 0
    out = capsys.readouterr().out                  # the summary stays on stdout, unchanged
    assert out.splitlines()[1:] == quiet.out.splitlines()[1:]   # line 0 holds the wall time
    err = tty.getvalue()
    assert '\rcvj-sim simulate: t=0.05/0.05 s simulated (100%), real-time factor' in err
    assert err.endswith('\r')                      # the line is erased at the end


# test/test_bench.py's reduced lever scene (seed 004 KAVZ-685 inertias and bushing)
BENCH_SCENE = {'name': 'mini_lever', 'duration': 1.0, 'engine': {'model': 'linear'},
               'load': {'model': 'constant', 'torque': 107.5}, 'initial': {'speed_rad_s': 30.0},
               'driveline': [{'type': 'inertia', 'name': 'engine_crank', 'J': 0.128},
                             {'type': 'joint', 'name': 'hooke', 'kind': 'hooke',
                              'params': {'beta_deg': 15}},
                             {'type': 'spring', 'name': 'bush', 'stiffness': 715.4, 'damping': 6.35},
                             {'type': 'inertia', 'name': 'wheel', 'J': 0.161}]}


def test_bench_cli_progress_counts_runs(tmp_path, monkeypatch, capsys) -> None:
    import yaml

    from cvj_ros.cli import main
    scene_file = tmp_path / 'mini_lever.yaml'
    scene_file.write_text(yaml.safe_dump(BENCH_SCENE))
    _ticking_clock(monkeypatch)
    # the count below is without the numbalsoda family (installed by `make bench` only)
    monkeypatch.setattr('cvj_ros.bench.expert_methods_run', lambda cfg: ())
    tty = FakeTTY()
    monkeypatch.setattr('sys.stderr', tty)
    rc = main(['bench', '--scenes', str(scene_file), '--solvers', 'dopri5', '--fidelities', 'exact',
               '--baselines', 'RK45', '--tolerances', '1e-4,1e-8', '--horizon', '0.1', '--samples', '10',
               '--repeats', '1', '--exchange-steps', '1e-3', '--no-ros', '--out', str(tmp_path / 'out')])
    assert rc == 0
    err = tty.getvalue()
    # 1 scene x (1 fidelity x 2 tolerances x (landing, dense sampling) x (with, without the
    # work integrals) + 1 baseline x 2 tolerances x 2 families: Python and compiled rhs) = 12 runs
    assert '\rcvj-sim bench: 12/12 runs (100%), ETA 0 s' in err
    assert '[bench] done in' in err
    capsys.readouterr()
