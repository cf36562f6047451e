"""`cvj-sim simulate SCENE --bag/--plots` for scenes with clutch, gearbox, brake or commands
(cvj_ros/mode_outputs.py): the bag carries the run's speeds, the commands as driver_node
plays them and the mode events; the figure marks every event."""
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
    # analyze needs shaft angles: one line pointing at --plots, no traceback
    assert main(['analyze', str(tmp_path / 'bag')]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and 'no shaft angles' in err[0]


def test_vehicle_scene_bag_and_plots(tmp_path, capsys) -> None:
    """launch_clutch's first 2 s on the compiled kernel: both wheel brakes hold, then slip."""
    s = _simulate(tmp_path, capsys, 'launch_clutch', '--duration', '2')
    assert s['solver']['backend'] == 'kernel'
    assert [e['after'] for e in s['event_list']] == ['stuck', 'stuck', 'slip+', 'slip+']
    final = _check_bag(tmp_path, s, 'launch_clutch')
    assert final['brake_state.brake_left'] == 'slip+' and final['gear.gearbox'] == '1'


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

