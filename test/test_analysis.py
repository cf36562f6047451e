"""Offline bag analysis against synthetic bags whose signals are known in closed form.

The synthetic bag is written here with rosbags directly (independent of cvj_ros/bag.py):
* ``engine_crank``: phi = w0 t + a/(2 w0) sin(2 w0 t), so omega = w0 + a cos(2 w0 t):
  speed amplitude a, delta = 2a/w0, acceleration amplitude 2 a w0; its torque is
  T0 + sum A_k cos(k phi + p_k) over the true (non-uniform) angle plus an order-20 term.
* ``hooke_input``/``hooke_output``: a Hooke joint at beta built from tan(phi2) = tan(phi1)/cos(beta)
  with np.unwrap (not the project's Hooke model). Its geometric amplitude is
  atan((1 - cos b)/(2 sqrt(cos b))) and the kinematic range cos b - 1 .. 1/cos b - 1.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from cvj_ros import analysis
from cvj_ros.errors import BagError
from cvj_ros.physics import signal

W0 = 20.0            # rad/s
A_SPEED = 0.6        # rad/s
T0 = 100.0           # N m
HARMONICS = {1: (8.0, 0.5), 2: (5.0, -1.0), 3: (2.0, 2.5)}   # k: (A_k N m, p_k rad)
BETA = math.radians(30.0)
DT = 1e-3
DURATION = 4.0


def crank_angle(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return W0 * t + A_SPEED / (2 * W0) * np.sin(2 * W0 * t), W0 + A_SPEED * np.cos(2 * W0 * t)


def crank_torque(phi: np.ndarray) -> np.ndarray:
    tq = T0 + sum(a * np.cos(k * phi + p) for k, (a, p) in HARMONICS.items())
    return tq + 1.5 * np.cos(20 * phi)   # above the analysed orders: must not leak into them


def write_synthetic_bag(path: Path, *, storage: str = 'mcap', duration: float = DURATION,
                        diagnostics: bool = True, joint_states: bool = True,
                        foreign_every: int = 0, reaction: bool = False,
                        scene: str = 'name: synthetic\nseed: 7\n', missing: range = range(0),
                        ticks_skipped: int | None = None) -> Path:
    """Write a lockstep-like bag with the signals of the module docstring; returns ``path``.
    ``foreign_every`` > 0: after every that many joint states another publisher's JointState
    (other names, other sizes) on the same topic, as `cvj-sim record` keeps them.
    ``reaction``: also ``/coupling/hooke/wrench`` (frame hooke_housing), force
    (3 cos phi_in, 2, 0) N and torque (0, 0, 50 + sin 2 phi_in) N m. ``scene``: the
    /driveline/scene text. ``missing``: sample indices left out of the joint states and
    wrenches (as ticks a free run skipped). ``ticks_skipped``: with every diagnostics array
    also a ``coupling_node: loop`` status holding it, as a free run's coupling node sends."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_JAZZY)
    T = ts.types
    n = int(round(duration / DT)) + 1
    t = np.arange(n) * DT
    phi_c, w_c = crank_angle(t)
    tq_c = crank_torque(phi_c)
    phi_in = W0 * t
    c = math.cos(BETA)
    phi_out = np.unwrap(np.arctan2(np.sin(phi_in), c * np.cos(phi_in)))
    w_out = W0 * c / (1.0 - math.sin(BETA) ** 2 * np.cos(phi_in) ** 2)
    names = ['engine_crank', 'hooke_input', 'hooke_output', 'wheel']
    plugin = StoragePlugin.MCAP if storage == 'mcap' else StoragePlugin.SQLITE3
    with Writer(path, version=9, storage_plugin=plugin) as w:
        cj = w.add_connection('/driveline/joint_states', 'sensor_msgs/msg/JointState', typestore=ts)
        ce = w.add_connection('/engine/wrench', 'geometry_msgs/msg/WrenchStamped', typestore=ts)
        cl = w.add_connection('/load/wrench', 'geometry_msgs/msg/WrenchStamped', typestore=ts)
        cd = w.add_connection('/diagnostics', 'diagnostic_msgs/msg/DiagnosticArray', typestore=ts)
        cs = w.add_connection('/driveline/scene', 'std_msgs/msg/String', typestore=ts)
        cr = (w.add_connection('/coupling/hooke/wrench', 'geometry_msgs/msg/WrenchStamped', typestore=ts)
              if reaction else None)
        w.write(cs, 0, ts.serialize_cdr(T['std_msgs/msg/String'](data=scene), 'std_msgs/msg/String'))
        for i in range(n):
            ns = i * 1_000_000
            stamp = T['builtin_interfaces/msg/Time'](sec=ns // 10**9, nanosec=ns % 10**9)
            hdr = T['std_msgs/msg/Header'](stamp=stamp, frame_id='')
            gone = i in missing
            if joint_states and not gone:
                js = T['sensor_msgs/msg/JointState'](
                    header=hdr, name=names,
                    position=np.array([phi_c[i], phi_in[i], phi_out[i], phi_out[i]]),
                    velocity=np.array([w_c[i], W0, w_out[i], w_out[i]]),
                    effort=np.array([tq_c[i], 50.0, 50.0, 40.0]))
                w.write(cj, ns, ts.serialize_cdr(js, 'sensor_msgs/msg/JointState'))
                if foreign_every and i % foreign_every == foreign_every - 1:
                    other = T['sensor_msgs/msg/JointState'](
                        header=hdr, name=['intruder_a', 'intruder_b'], position=np.zeros(2),
                        velocity=np.ones(1), effort=np.zeros(0))
                    w.write(cj, ns, ts.serialize_cdr(other, 'sensor_msgs/msg/JointState'))
            for conn, tz in ((ce, tq_c[i]), (cl, 40.0 + 3.0 * math.cos(2 * phi_out[i]))) if not gone else ():
                v = T['geometry_msgs/msg/Vector3']
                wr = T['geometry_msgs/msg/WrenchStamped'](
                    header=hdr, wrench=T['geometry_msgs/msg/Wrench'](force=v(x=0.0, y=0.0, z=0.0),
                                                                    torque=v(x=0.0, y=0.0, z=float(tz))))
                w.write(conn, ns, ts.serialize_cdr(wr, 'geometry_msgs/msg/WrenchStamped'))
            if cr is not None and not gone:
                v = T['geometry_msgs/msg/Vector3']
                rh = T['std_msgs/msg/Header'](stamp=stamp, frame_id='hooke_housing')
                wr = T['geometry_msgs/msg/WrenchStamped'](
                    header=rh, wrench=T['geometry_msgs/msg/Wrench'](
                        force=v(x=3.0 * math.cos(phi_in[i]), y=2.0, z=0.0),
                        torque=v(x=0.0, y=0.0, z=50.0 + math.sin(2 * phi_in[i]))))
                w.write(cr, ns, ts.serialize_cdr(wr, 'geometry_msgs/msg/WrenchStamped'))
            if diagnostics and i % 500 == 0:
                kv = T['diagnostic_msgs/msg/KeyValue']
                st = T['diagnostic_msgs/msg/DiagnosticStatus'](
                    level=b'\x00'[0], name='monitor', message='ok', hardware_id='',
                    values=[kv(key='energy_residual', value=f'{1e-9 * (i + 1):.6e}'),
                            kv(key='wait_us', value='120.0'), kv(key='note', value='text')])
                statuses = [st]
                if i == 1000:
                    statuses.append(T['diagnostic_msgs/msg/DiagnosticStatus'](
                        level=2, name='coupling_node', message='T_load: NaN rejected', hardware_id='',
                        values=[]))
                if ticks_skipped is not None:
                    statuses.append(T['diagnostic_msgs/msg/DiagnosticStatus'](
                        level=0, name='coupling_node: loop', message='running', hardware_id='',
                        values=[kv(key='ticks_skipped', value=str(ticks_skipped))]))
                arr = T['diagnostic_msgs/msg/DiagnosticArray'](header=hdr, status=statuses)
                w.write(cd, ns, ts.serialize_cdr(arr, 'diagnostic_msgs/msg/DiagnosticArray'))
    return path


@pytest.fixture(scope='module')
def synthetic_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_synthetic_bag(tmp_path_factory.mktemp('bags') / 'synthetic')


@pytest.fixture(scope='module')
def report(synthetic_bag: Path) -> dict:
    return analysis.analyze_bag(synthetic_bag)


def test_speed_amplitudes_and_delta(report: dict) -> None:
    s = report['shafts']['engine_crank']
    assert s['mean_speed_rad_s'] == pytest.approx(W0, rel=1e-3)
    assert s['speed_amplitude_rad_s'] == pytest.approx(A_SPEED, rel=1e-3)
    assert s['speed_nonuniformity'] == pytest.approx(2 * A_SPEED / W0, rel=2e-3)
    # Central differences at h = 1 ms: relative error (2 w0 h)^2 / 6 ~ 3e-4.
    assert s['acceleration_amplitude_rad_s2'] == pytest.approx(2 * A_SPEED * W0, rel=2e-3)
    assert report['shafts']['hooke_input']['speed_nonuniformity'] == pytest.approx(0.0, abs=1e-12)


def test_torque_harmonics_recover_amplitude_and_phase(report: dict) -> None:
    h = report['shafts']['engine_crank']['torque_harmonics']
    assert h['mean'] == pytest.approx(T0, abs=0.02)
    assert h['revolutions'] >= 9
    for k in range(1, 7):
        a_true, p_true = HARMONICS.get(k, (0.0, 0.0))
        assert h['amplitude'][k - 1] == pytest.approx(a_true, abs=0.02), k
        if a_true:
            dp = (h['phase_rad'][k - 1] - p_true + math.pi) % (2 * math.pi) - math.pi
            assert abs(dp) < 5e-3, k
    # The engine wrench carries the same torque, analysed over the crank angle.
    he = report['engine']['torque_harmonics']
    assert he['amplitude'][1] == pytest.approx(5.0, abs=0.02)
    assert report['engine']['torque_amplitude_Nm'] == pytest.approx(
        signal.half_range(crank_torque(np.linspace(0, 2 * np.pi, 20001))), rel=1e-3)


def test_joint_nonuniformity_matches_hooke_closed_form(report: dict) -> None:
    j = report['joints']['hooke']
    c = math.cos(BETA)
    geo = math.atan((1 - c) / (2 * math.sqrt(c)))
    assert j['geometric_amplitude_rad'] == pytest.approx(geo, rel=1e-3)
    assert j['geometric_max_rad'] == pytest.approx(geo, rel=1e-3)
    assert j['kinematic_min'] == pytest.approx(c - 1.0, rel=1e-3)
    assert j['kinematic_max'] == pytest.approx(1.0 / c - 1.0, rel=1e-3)


def test_lockstep_and_diagnostics(report: dict) -> None:
    ls = report['lockstep']
    assert ls['steps'] == int(round(DURATION / DT)) + 1
    assert ls['stamps_strictly_increasing']
    assert ls['exchange_step_s'] == pytest.approx(DT, rel=1e-6)
    assert ls['engine_echo_fraction'] == 1.0 and ls['load_echo_fraction'] == 1.0
    figs = report['diagnostics']['figures']
    assert figs['monitor/energy_residual']['last'] == pytest.approx(1e-9 * 4001, rel=1e-5)
    assert figs['monitor/wait_us']['mean'] == pytest.approx(120.0)
    assert 'monitor/note' not in figs
    assert report['diagnostics']['levels'] == {'ok': 9, 'warn': 0, 'error': 1, 'stale': 0}
    assert report['diagnostics']['errors'] == ['coupling_node at t = 1 s: T_load: NaN rejected']
    text = analysis.format_report(report)
    assert 'ERROR coupling_node at t = 1 s: T_load: NaN rejected' in text and '1 ERROR' in text
    assert report['scene']['present'] and report['scene']['seed'] == 7
    # Steady window: the signals are periodic from t = 0, so the criterion keeps it all.
    assert report['window']['steady'] is True
    assert report['window']['skipped_s'] == 0.0


def test_harmonics_function_closed_form_and_reverse_rotation() -> None:
    phi = np.linspace(0.3, -6 * np.pi, 5000)          # negative rotation, 3 revolutions
    vals = 4.0 + 2.0 * np.cos(2 * phi + 0.7)
    h = signal.harmonics_over_angle(phi, vals, n_harmonics=3)
    assert h.revolutions == 3                            # whole revolutions in 6 pi + 0.3 rad
    assert h.amplitudes == pytest.approx([0.0, 2.0, 0.0], abs=2e-3)
    assert h.phases[1] == pytest.approx(0.7, abs=2e-3)
    assert h.synthesize([0.0, 1.0]) == pytest.approx(4.0 + 2.0 * np.cos(2 * np.array([0.0, 1.0]) + 0.7), abs=5e-3)
    with pytest.raises(ValueError, match='^phi: need at least one whole revolution'):
        signal.harmonics_over_angle(np.linspace(0, 5, 100), np.ones(100))
    with pytest.raises(ValueError, match='^phi: shaft angle must be strictly monotonic'):
        phi_back = np.r_[0:7:0.1, 6.9:0:-0.1]
        signal.harmonics_over_angle(phi_back, np.ones_like(phi_back))


def test_sqlite3_bag_reads_the_same(tmp_path: Path) -> None:
    bag = write_synthetic_bag(tmp_path / 'sq', storage='sqlite3', duration=1.0, diagnostics=False)
    rep = analysis.analyze_bag(bag, skip_s=0.0)
    assert rep['shafts']['engine_crank']['speed_amplitude_rad_s'] == pytest.approx(A_SPEED, rel=1e-3)
    assert rep['window']['skipped_s'] == 0.0
    assert rep['diagnostics']['figures'] == {}


def test_missing_bag_and_missing_topic(tmp_path: Path) -> None:
    with pytest.raises(BagError, match='nope: no such bag'):
        analysis.read_bag_signals(tmp_path / 'nope')
    bag = write_synthetic_bag(tmp_path / 'nojs', duration=0.05, joint_states=False)
    with pytest.raises(BagError, match='^/driveline/joint_states: no messages in bag'):
        analysis.read_bag_signals(bag)


def test_gear_stage_nonuniformity_is_relative_to_its_ratio() -> None:
    """A 3.5:1 stage with a small 2nd-order ripple: ratio recovered, ripple measured."""
    phi = np.linspace(0.0, 40.0, 8001)
    out = 3.5 * phi + 1e-3 * np.sin(2 * phi) + 0.2
    w_in = np.full_like(phi, 10.0)
    w_out = 10.0 * (3.5 + 2e-3 * np.cos(2 * phi))
    nu = signal.joint_nonuniformity(phi, out, w_in, w_out)
    assert nu.nominal_ratio == pytest.approx(3.5, rel=1e-5)
    # the slope fit over 12.7 ripple half-periods tilts the deviation by a few % of the ripple
    assert nu.geometric_amplitude == pytest.approx(1e-3, rel=5e-2)
    assert nu.kinematic_max == pytest.approx(2e-3 / 3.5, rel=1e-3)
    cv = signal.joint_nonuniformity(phi, phi + 2 * np.pi, w_in, w_in)      # one whole turn apart
    assert cv.nominal_ratio == 1.0 and cv.geometric_amplitude < 1e-12 and abs(cv.geometric_max) < 1e-12


def test_reaction_wrenches_are_reported_per_joint_over_the_window(tmp_path: Path) -> None:
    """/coupling/<joint>/wrench: mean and amplitude of each component over the window. The
    window holds many but not whole revolutions of phi_in: a harmonic's mean is then within
    its amplitude / (pi x revolutions) of 0 (< 0.05 here), the amplitudes exact to the
    sampling (1e-3)."""
    rep = analysis.analyze_bag(write_synthetic_bag(tmp_path / 'react', reaction=True), skip_s=0.0)
    r = rep['reactions']['hooke']
    assert r['frame_id'] == 'hooke_housing' and r['samples'] == rep['window']['samples']
    assert r['mean_force_N'][1] == pytest.approx(2.0) and r['mean_force_N'][2] == 0.0
    assert r['force_amplitude_N'][0] == pytest.approx(3.0, rel=1e-3)
    assert abs(r['mean_force_N'][0]) < 0.05
    assert r['mean_torque_Nm'][2] == pytest.approx(50.0, abs=0.05)
    assert r['torque_amplitude_Nm'][2] == pytest.approx(1.0, rel=1e-3)
    text = analysis.format_report(rep)
    assert 'reaction wrenches (housing frame)' in text and '  hooke ' in text
    # a bag without them: no section
    assert 'reactions' not in analysis.analyze_bag(write_synthetic_bag(tmp_path / 'plain'), skip_s=0.0)


@pytest.mark.parametrize(('fidelity', 'shown'), [
    ({'choices': [{'name': 'hooke', 'chosen': 'exact'}]}, 'hooke=exact'),
    ({'levels': {'clutch_damper': 'elastic'}}, 'clutch_damper=elastic'),
    ({'levels': {}}, None),          # a mode scene without choices: nothing, not a dict repr
    ({}, None),
    ('hooke=exact', 'hooke=exact')])
def test_scene_summary_shows_fidelity_as_name_level_pairs(fidelity, shown) -> None:
    import yaml
    summary = analysis._scene_summary(yaml.safe_dump({'name': 's', 'fidelity': fidelity}))
    assert summary.get('fidelity') == shown


FREE_RUN_SCENE = 'name: synthetic\nseed: 7\nmode: free-run\nexchange_step: 0.001\n'


def test_gaps_line_for_a_loop_bag_with_missing_samples(tmp_path: Path) -> None:
    """A free run's bag lacking t = 1.000 .. 1.049 s on its three loop topics (50 ticks
    skipped, as its loop diagnostics say): `analyze` prints `cvj-sim run`'s gaps line, with
    the figures of cvj_ros.orchestrate.gaps (50 of 4001 grid times, the run of 0.05 s)."""
    bag = write_synthetic_bag(tmp_path / 'gaps', scene=FREE_RUN_SCENE, missing=range(1000, 1050),
                              ticks_skipped=50)
    rep = analysis.analyze_bag(bag)
    g = rep['gaps']
    assert g['grid_topics'] == 3 and g['ticks_skipped'] == 50
    for topic in ('/driveline/joint_states', '/engine/wrench', '/load/wrench'):
        assert g['topics'][topic] == {'expected': 4001, 'missing': 50, 'gap_from_s': 1.0, 'gap_s': 0.05}
    text = analysis.format_report(rep)
    line = ('  gaps: all 3 loop topics miss 50 of 4001 sample times (longest run 0.05 s from '
            't = 1 s); 50 ticks skipped by free-run catch-up')
    assert line in text.splitlines()
    # in the loop's block: after its line and the answers, before the diagnostics
    lines = text.splitlines()
    i = lines.index(line)
    assert lines[i - 3].startswith('free-run: 3951 steps over 4 s') and lines[i - 1].startswith(
        '  load answers: 3951') and lines[i + 1].startswith('diagnostics: ')
    # lost without a skip: said so (no loop diagnostics with the count)
    rep = analysis.analyze_bag(write_synthetic_bag(tmp_path / 'lost', scene=FREE_RUN_SCENE,
                                                   missing=range(1000, 1003)))
    assert ('  gaps: all 3 loop topics miss 3 of 4001 sample times (longest run 0.003 s from '
            't = 1 s); no tick skipped: lost before the recorder') in analysis.format_report(rep)


def test_no_gaps_line_without_gaps_or_for_bags_not_of_the_loop(report: dict, tmp_path: Path) -> None:
    # a complete loop bag: nothing to say
    rep = analysis.analyze_bag(write_synthetic_bag(tmp_path / 'full', scene=FREE_RUN_SCENE))
    assert not rep.get('gaps', {}).get('topics') and 'gaps:' not in analysis.format_report(rep)
    # no loop mode in the bag (the synthetic bag's scene, an offline `simulate` bag): no grid
    assert 'gaps' not in report and 'gaps:' not in analysis.format_report(report)
    rep = analysis.analyze_bag(write_synthetic_bag(
        tmp_path / 'offline', scene='name: s\nmode: offline\nexchange_step: 0.001\n',
        missing=range(1000, 1050)))
    assert 'gaps' not in rep


def test_loop_exchange_step_from_the_scene_message_or_the_run_metadata() -> None:
    assert analysis.loop_exchange_step('mode: lockstep\nexchange_step: 0.002\n', {}) == 0.002
    assert analysis.loop_exchange_step(None, {'cvj_ros.mode': 'free-run',
                                              'cvj_ros.exchange_step': '0.005'}) == 0.005
    for scene, meta in (('mode: offline\nexchange_step: 0.001\n', {}), (None, {}),
                        ('mode: lockstep\nexchange_step: -1\n', {}), ('mode: lockstep\n', {}),
                        (': [', {'cvj_ros.mode': 'lockstep', 'cvj_ros.exchange_step': 'nan'})):
        assert analysis.loop_exchange_step(scene, meta) is None, (scene, meta)
