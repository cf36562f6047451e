"""Shipped reference scenes (DESIGN.md section 6): each parses and runs; seed 004 trends."""
from __future__ import annotations

import copy

import numpy as np
import pytest

from cvj_ros.physics.scene import load_scene, parse_scene, shipped_scenes
from cvj_ros.physics.simulate import Simulation

EXPECTED = {'kavz685_lever', 'fwd_halfshaft', 'cardan_truck', 'tripod_xiu2024', 'stiff'}


def test_all_reference_scenes_shipped() -> None:
    assert EXPECTED <= set(shipped_scenes())


@pytest.mark.parametrize('name', sorted(EXPECTED))
def test_scene_parses_and_runs(name: str) -> None:
    sc = load_scene(shipped_scenes()[name])
    assert sc.description
    assert parse_scene(sc.to_dict()) == parse_scene(load_scene(shipped_scenes()[name]).to_dict())
    tr = Simulation(sc).run(0.2)
    assert np.all(np.isfinite(tr.velocity)) and np.all(np.isfinite(tr.effort))
    assert tr.max_energy_residual < 1e-5
    assert tr.t[-1] == pytest.approx(0.2)
    assert tr.velocity[-1, 0] > 0


def _kavz(*, load_mean: float = 107.5, load_amp: float = 8.8, stiffness: float = 715.4) -> dict:
    """Amplitudes (max - min)/2 after a 1 s transient: torque M1 on the drive shaft = engine
    moment M_g1 (seed 004 eq. 3.23), M2 on the driven shaft = load M_c (eq. 3.21); speed
    and acceleration of drive_shaft and driven_shaft."""
    d = copy.deepcopy(load_scene(shipped_scenes()['kavz685_lever']).to_dict())
    d['load'].update(mean=load_mean, amplitude=load_amp)
    for el in d['driveline']:
        if el['type'] == 'spring':
            el['stiffness'] = stiffness
    tr = Simulation(parse_scene(d)).run(3.0, sample_dt=1e-3)
    mask = tr.t >= 1.0
    out = {'M1': 0.5 * np.ptp(tr.engine_torque[mask]), 'M2': 0.5 * np.ptp(tr.load_torque[mask])}
    for key, name in (('w1', 'drive_shaft'), ('w2', 'driven_shaft')):
        w = tr.velocity[:, tr.column(name)]
        out[key] = 0.5 * np.ptp(w[mask])
        out['a' + key[1]] = 0.5 * np.ptp(np.gradient(w, tr.t)[mask])
    return out


def test_kavz685_trends_seed004() -> None:
    """Seed 004 section 3.3.2: drive-shaft amplitudes below driven-shaft ones (the rubber
    elements smooth the drive shaft); amplitudes rise with the load (107.5 +- 8.8 ->
    225.4 +- 18.3 N m, fig. 3.11); the drive/driven difference falls as the stiffness rises
    (2.0e2 -> 8.2e2 N m/rad, fig. 3.17)."""
    base = _kavz()
    assert base['M1'] < base['M2'] and base['w1'] < base['w2'] and base['a1'] < base['a2']
    heavy = _kavz(load_mean=225.4, load_amp=18.3)
    for key in ('M1', 'M2', 'w1', 'w2', 'a1', 'a2'):
        assert heavy[key] > base[key], key
    soft = _kavz(stiffness=200.0)
    stiff = _kavz(stiffness=820.0)
    assert stiff['M2'] - stiff['M1'] < soft['M2'] - soft['M1']
    assert stiff['w2'] - stiff['w1'] < soft['w2'] - soft['w1']
