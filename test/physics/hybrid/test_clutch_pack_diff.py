"""Clutch-pack limited-slip differential (preload + torque bias, stick/slip modes) on the
vehicle tree, against independent constructions: the open and the locked differential of
TreeDriveline (its two limits), and the torque-sensing law at a slipping state."""
from __future__ import annotations

import copy

import numpy as np
import pytest
import yaml

from cvj_ros.errors import SceneError
from cvj_ros.physics.hybrid.from_scene import run_hybrid
from cvj_ros.physics.scene import parse_scene, shipped_scenes
from cvj_ros.physics.simulate import Simulation

DURATION = 0.3


def _split_mu(kind: str, **pack) -> dict:
    """fwd_axle_split_mu (left wheel on ice) without firing ripple, rtol 1e-8, 0.3 s."""
    with open(shipped_scenes()['fwd_axle_split_mu'], encoding='utf-8') as f:
        d = yaml.safe_load(f)
    d['engine'] = {'model': 'map', 'throttle': 1.0}
    d['solver'] = {'method': 'dopri5', 'rtol': 1e-8, 'atol': 1e-10}
    d['duration'] = DURATION
    d['driveline'][4] = dict(d['driveline'][4], kind=kind, **pack)
    return d


def _wheels_reference(kind: str) -> np.ndarray:
    sim = Simulation(parse_scene(_split_mu(kind)), backend='python')
    tr = sim.run(DURATION, sample_dt=0.01)
    return np.column_stack([tr.velocity[:, tr.column(w)] for w in ('wheel_left', 'wheel_right')])


def _wheels_pack(**pack) -> tuple[np.ndarray, object]:
    _sim, r, _w = run_hybrid(parse_scene(_split_mu('clutch_pack', **pack)), sample_dt=0.01)
    return np.column_stack([r.column('wheel_left'), r.column('wheel_right')]), r


@pytest.mark.parametrize('kind, pack', [
    ('locked', {'preload_nm': 1.0e5}),          # never breaks away: a locked differential
    ('open', {'preload_nm': 0.0}),              # no capacity: never sticks, no bias: open
])
def test_limits_are_the_locked_and_the_open_differential(kind: str, pack: dict) -> None:
    """Both runs at rtol 1e-8 from the same start; bound 1e-6 relative (100x rtol)."""
    ref = _wheels_reference(kind)
    got, r = _wheels_pack(**pack)
    np.testing.assert_allclose(got, ref, rtol=1e-6, atol=1e-6)
    after = [e.after for e in r.events]
    if kind == 'locked':
        assert after == ['stuck']
    else:        # zero capacity: only slip directions change (at zero slip), never stuck
        assert 'stuck' not in after
    assert r.max_energy_residual < 1e-9


def test_breakaway_and_torque_sensing_bias() -> None:
    """Preload 100 N m, torque bias 0.2: stuck at the start, breaks away (the ice wheel
    spins up) when the torque split needs more than the static capacity; slipping, the bias
    torque T_b solves T_b = T_p + k |T_L + T_R| with the side torques of the backward walk
    at T_b (checked by a fresh walk), and the right (grip) wheel gets more torque than the
    open differential would give it."""
    d = _split_mu('clutch_pack', preload_nm=100.0, torque_bias=0.2)
    sim, r, _w = run_hybrid(parse_scene(d), sample_dt=0.01)
    ev = [(e.element, e.before, e.after) for e in r.events]
    assert ev == [('differential', 'slip+', 'stuck'), ('differential', 'stuck', 'slip+')]
    assert 0.0 < r.events[1].t < 0.2
    mt = sim.tree(r.final_mode)
    x, _ = mt.from_state(r.final, False)
    el, d_i = mt.packs['differential']
    di = mt.diffs[d_i]
    kin = mt._kinematics(x)
    fo = mt._forces(DURATION, x, kin, sim.engine.torque, 0.0)
    fo.link_t, fo.wheel_extra = [], [0.0] * mt.n_wheel
    tb = mt._pack_bias(x, kin, fo, el, di, 1)
    fo.q[di.left] -= tb
    fo.q[di.right] += tb
    start = mt._walk(x, fo.T_engine, kin=kin, fo=fo)[3]
    t_c = start[di.left] + start[di.right]
    assert tb == pytest.approx(100.0 + 0.2 * abs(t_c), rel=1e-9)
    assert tb > 100.0
    open_ref = _wheels_reference('open')
    got = np.column_stack([r.column('wheel_left'), r.column('wheel_right')])
    assert got[-1, 0] < open_ref[-1, 0]          # the ice wheel spins less
    assert got[-1, 1] > open_ref[-1, 1]          # the grip wheel drives more
    assert r.max_energy_residual < 1e-9


def test_pack_keys_only_for_clutch_pack() -> None:
    d = _split_mu('open')
    d['driveline'][4]['preload_nm'] = 10.0
    with pytest.raises(SceneError) as exc:
        parse_scene(d)
    assert exc.value.field == 'driveline[4].preload_nm'
    d = _split_mu('clutch_pack')
    with pytest.raises(SceneError) as exc:
        parse_scene(d)
    assert exc.value.field == 'driveline[4].preload_nm'
    sc = parse_scene(_split_mu('clutch_pack', preload_nm=50.0, torque_bias=0.3, static_ratio=1.2))
    assert sc.has_modes and parse_scene(copy.deepcopy(sc.to_dict())) == sc
