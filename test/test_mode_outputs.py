"""`cvj-sim simulate SCENE --bag/--plots` for scenes with clutch, gearbox, brake or commands
(cvj_ros/mode_outputs.py): the bag carries the run's joint states (angles, speeds, torques)
and engine torque, the commands as driver_node plays them and the mode events, and `cvj-sim
analyze` reads it; the figure marks every event; the same scene gives the same bag bytes."""
from __future__ import annotations

import json

import numpy as np

from cvj_ros import bag as bagmod
from cvj_ros.cli import main
from cvj_ros.mode_outputs import EVENT_STATUS, MODE_STATUS
from cvj_ros.nodes.command_plan import CHANNEL_TOPICS, NS_PER_S, CommandPlan
from cvj_ros.physics.scene import load_scene, shipped_scenes


def _simulate(tmp_path, capsys, *argv: str) -> dict:
    csv = tmp_path / 'run.csv'
    assert main(['simulate', *argv, '--json', '--csv', str(csv), '--bag', str(tmp_path / 'bag'),
                 '--plots', str(tmp_path / 'plots')]) == 0
    cap = capsys.readouterr()
    s = json.loads(cap.out)
    s['csv'] = np.loadtxt(csv, delimiter=',', skiprows=1, ndmin=2)
    s['err'] = cap.err
    return s


def _check_bag(tmp_path, s: dict, scene_name: str) -> dict:
    scene = load_scene(shipped_scenes()[scene_name])
    data = bagmod.read_bag(tmp_path / 'bag')
    js = data[bagmod.JOINT_STATES_TOPIC]
    names = list(s['final_speeds'])
    assert js.names == names
    # the samples of the run, the speeds bit for bit (the CSV: t, speeds, gear, energy
    # residual); stamps are integer ns
    np.testing.assert_allclose(js.t, s['csv'][:, 0], rtol=0.0, atol=0.6e-9)
    np.testing.assert_array_equal(js.velocity, s['csv'][:, 1:1 + len(names)])
    # the commands: driver_node's samples at the scene's exchange step
    h_ns = int(round(scene.exchange_step * NS_PER_S))
    plan = CommandPlan.from_scene(scene, h_ns, int(round(s['duration'] * NS_PER_S)) // h_ns)
    assert plan.channels
    for c in plan.channels:
        series = data[CHANNEL_TOPICS[c]]
        want = [(k * h_ns, v) for k, step in plan for ch, v in step if ch == c]
        assert [int(round(t * NS_PER_S)) for t in series.t] == [k for k, _v in want]
        assert list(series.value) == [v for _k, v in want]
    # the events, then the final modes in the loop status's keys
    st = [x for msg in data['/diagnostics'].statuses for x in msg]
    ev = [x for x in st if x['name'] == EVENT_STATUS]
    assert [(x['values']['element'], x['values']['after'], float(x['values']['t_s']))
            for x in ev] == [(e['element'], e['after'], e['t']) for e in s['event_list']]
    final = [x for x in st if x['name'] == MODE_STATUS]
    assert len(final) == 1 and final[0]['values']['mode_events'] == str(len(s['event_list']))
    assert (tmp_path / 'plots' / 'mode_speeds.png').stat().st_size > 10_000
    return final[0]['values']


def test_chain_scene_bag_and_plots(tmp_path, capsys) -> None:
    """launch_clutch_chain's first 2.5 s (brake hold and release) on the Python reference."""
    s = _simulate(tmp_path, capsys, 'launch_clutch_chain', '--duration', '2.5', '--backend', 'python')
    assert [e['after'] for e in s['event_list']] == ['stuck', 'slip+']
    final = _check_bag(tmp_path, s, 'launch_clutch_chain')
    assert final['clutch_state.clutch'] == 'slip+' and final['gear.gearbox'] == '1'
    assert final['brake_state.brake'] == 'slip+'
    assert 'mode events and the commands to bag' in s['err']
    _check_joint_states(tmp_path, s)
    _check_analyze(tmp_path, capsys, s)


def test_vehicle_scene_bag_and_plots(tmp_path, capsys) -> None:
    """launch_clutch's first 2 s on the compiled kernel: both wheel brakes hold, then slip."""
    s = _simulate(tmp_path, capsys, 'launch_clutch', '--duration', '2')
    assert s['solver']['backend'] == 'kernel'
    assert [e['after'] for e in s['event_list']] == ['stuck', 'stuck', 'slip+', 'slip+']
    final = _check_bag(tmp_path, s, 'launch_clutch')
    assert final['brake_state.brake_left'] == 'slip+' and final['gear.gearbox'] == '1'
    js = _check_joint_states(tmp_path, s)
    # both wheels pinned by their brakes until the release: angle and speed exactly 0
    held = js.t < min(e['t'] for e in s['event_list'] if e['after'] == 'slip+')
    for wheel in ('wheel_left', 'wheel_right'):
        j = js.names.index(wheel)
        assert np.count_nonzero(held) > 10
        assert np.all(js.position[held, j] == 0.0) and np.all(js.velocity[held, j] == 0.0)
    _check_analyze(tmp_path, capsys, s)


def _check_joint_states(tmp_path, s: dict):
    """Every shaft's angle and torque beside its speed, the engine torque on /engine/wrench
    at every joint-state stamp; the angles are the time integral of the speeds (trapezoid
    rule on the samples, an independent check of the sampled positions)."""
    data = bagmod.read_bag(tmp_path / 'bag')
    js = data[bagmod.JOINT_STATES_TOPIC]
    assert js.position.shape == js.velocity.shape == js.effort.shape
    assert np.all(np.isfinite(js.position)) and np.all(np.isfinite(js.effort))
    eng = data['/engine/wrench']
    np.testing.assert_array_equal(eng.t, js.t)
    assert np.all(np.isfinite(eng.torque_z)) and np.any(eng.torque_z != 0.0)
    dt = np.diff(js.t)[:, None]
    integral = np.concatenate([np.zeros((1, js.velocity.shape[1])),
                               np.cumsum(0.5 * dt * (js.velocity[1:] + js.velocity[:-1]), axis=0)])
    travel = js.position - js.position[0]
    # trapezoid error per sample step <= dt^3/12 max|w''|; summed over the run it stays
    # below 1 % of each shaft's largest travelled angle here (measured 0.1-0.4 %)
    scale = np.maximum(np.max(np.abs(travel), axis=0), 1e-9)
    assert np.all(np.max(np.abs(integral - travel), axis=0) <= 1e-2 * scale + 1e-9)
    return js


def _check_analyze(tmp_path, capsys, s: dict) -> None:
    """`cvj-sim analyze` reads the bag (exit 0) and reports its mode events and final modes."""
    assert main(['analyze', str(tmp_path / 'bag'), '--json']) == 0
    rep = json.loads(capsys.readouterr().out)
    ev = rep['modes']['events']
    assert [(e['element'], e['after'], e['t_s']) for e in ev] == [
        (e['element'], e['after'], e['t']) for e in s['event_list']]
    assert rep['modes']['final']['mode_events'] == str(len(s['event_list']))
    assert 'energy_residual_max_abs' in ''.join(rep['diagnostics']['figures'])
    assert main(['analyze', str(tmp_path / 'bag')]) == 0
    text = capsys.readouterr().out
    assert f"modes: {len(s['event_list'])} mode events" in text


def test_mode_figure_marks_every_event() -> None:
    from cvj_ros.mode_outputs import mode_speeds_figure
    from cvj_ros.physics.hybrid.from_scene import hybrid_simulation
    from cvj_ros.plots import plt
    r = hybrid_simulation(load_scene(shipped_scenes()['launch_clutch_chain']), duration=2.5).run()
    fig = mode_speeds_figure(r, 'x')
    ax, axg = fig.axes[:2]
    vlines = [ln for ln in ax.lines if ln.get_linestyle() == ':']
    assert sorted(float(ln.get_xdata()[0]) for ln in vlines) == sorted(e.t for e in r.events)
    assert len(ax.lines) - len(vlines) == len(r.shafts)
    plt.close(fig)


def test_refusals_before_the_run(tmp_path, capsys) -> None:
    (tmp_path / 'bag').mkdir()
    assert main(['simulate', 'launch_clutch_chain', '--bag', str(tmp_path / 'bag')]) == 2
    assert main(['simulate', 'launch_clutch_chain', '--dense']) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and 'exists' in err[0] and '--dense' in err[1]



def _bag_bytes(path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(path.iterdir())}


def test_same_scene_same_bag_bytes(tmp_path, capsys) -> None:
    """Determinism: two runs of one scene and seed write byte-identical bags."""
    for name in ('a', 'b'):          # the same bag name (the storage file is named after it)
        assert main(['simulate', 'launch_clutch', '--duration', '1.2', '--bag',
                     str(tmp_path / name / 'bag')]) == 0
    capsys.readouterr()
    a, b = _bag_bytes(tmp_path / 'a' / 'bag'), _bag_bytes(tmp_path / 'b' / 'bag')
    assert list(a) == list(b) and a == b


def test_joint_samples_leave_the_run_unchanged() -> None:
    """Sampling angles and torques (``joint_samples``) evaluates the model at the samples
    only: speeds, events and residuals are bit for bit those of a run without, on the
    reference and the kernel, chain and vehicle."""
    from cvj_ros.physics.hybrid.from_scene import hybrid_simulation
    from cvj_ros.physics.kernel.modes import KernelHybridSimulation
    from cvj_ros.physics.kernel.tree_modes import KernelHybridTreeSimulation
    cases = [('launch_clutch_chain', 2.5, None), ('launch_clutch_chain', 4.0, KernelHybridSimulation),
             ('launch_clutch', 2.0, KernelHybridTreeSimulation)]
    for name, duration, kernel in cases:
        runs = []
        for on in (False, True):
            sim = hybrid_simulation(load_scene(shipped_scenes()[name]), duration=duration)
            sim = kernel.from_reference(sim) if kernel else sim
            sim.joint_samples = on
            runs.append(sim.run())
        off, on_ = runs
        assert off.position is None and on_.position.shape == on_.speed.shape
        np.testing.assert_array_equal(off.speed, on_.speed)
        np.testing.assert_array_equal(off.energy_residual, on_.energy_residual)
        assert [(e.t, e.element, e.after) for e in off.events] == [
            (e.t, e.element, e.after) for e in on_.events]
        # the walk's speeds are the sampled ones
        assert np.all(np.isfinite(on_.position)) and np.all(np.isfinite(on_.effort))


def test_mode_figure_of_a_vehicle_keeps_its_panels_tall_beside_a_long_legend() -> None:
    """~30 shafts (a vehicle): the legend goes beside the panels in two columns instead of
    stretching the speed panel's column (it had left the panel a third of the figure)."""
    from types import SimpleNamespace

    from cvj_ros.mode_outputs import mode_speeds_figure
    from cvj_ros.plots import plt
    t = np.linspace(0.0, 1.0, 11)
    shafts = [f'shaft_{i}' for i in range(30)]
    events = [SimpleNamespace(t=0.3, element='clutch'), SimpleNamespace(t=0.6, element='brake')]
    r = SimpleNamespace(t=t, speed=np.ones((t.size, len(shafts))), shafts=shafts,
                        events=events, gear=np.ones(t.size))
    fig = mode_speeds_figure(r, 'x')
    fig.canvas.draw()
    ax = fig.axes[0]
    assert ax.get_position().height > 0.5              # of the figure: 3/4 of the two panels
    (legend,) = fig.legends
    assert len(legend.get_texts()) == len(shafts) + len(set(e.element for e in events))
    box = legend.get_window_extent().transformed(fig.transFigure.inverted())
    assert box.x0 >= ax.get_position().x1 and box.y0 >= 0.0   # beside the panels, inside
    plt.close(fig)
