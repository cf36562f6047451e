"""Hard case (DESIGN.md section 8): Hooke joint at 60, 80 and 89 deg, and a clear error at
90 deg or more at every entry point (joint factory, scene, CLI).

Already covered elsewhere (not repeated here, see docs/robustness.md):
kinematics against the rotation-matrix construction and ratio range 1/cos b .. cos b at
60/80/89 deg (test/physics/joints/test_hooke.py), rigid 89 deg energy run
(test/physics/test_simulate.py::test_hooke_large_angle_rigid_conserves_energy), factory errors
at >= 90 deg (test_hooke.py), kinematics CLI at 90/120 deg
(test/commands/test_kinematics_cli.py), scene field error at 90/95 deg
(test/physics/test_scene.py).

Here: the dynamics at 60 and 80 deg with an elastic shaft in front of the joint (the
joint's 2nd-order excitation drives the torsional mode, J(q) swings by 1/cos^4 b), the
error at 90/95/180 deg through a scene file on the real `cvj-sim run` and kinematics CLIs,
and the 89 deg ratio checked against a numerical derivative of the position function.
"""
from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from cvj_ros.cli import main as cli_main
from cvj_ros.errors import GeometryError, SceneError
from cvj_ros.physics.joints import make_joint
from cvj_ros.physics.scene import load_scene, parse_scene
from cvj_ros.physics.simulate import Simulation

CVJ_SIM = str(Path(sys.executable).with_name('cvj-sim'))


class ZeroTorque:
    """Torque source giving 0 N m."""

    def torque(self, t: float, omega: float, phi: float = 0.0) -> float:
        return 0.0

    def slope(self, t: float, omega: float, phi: float = 0.0) -> float:
        return 0.0


def hooke_scene(beta_deg: float, *, spring: bool = True) -> dict:
    """Scene dict: inertia -> (spring -> inertia) -> Hooke(beta) -> inertia, no damping."""
    chain: list[dict] = [{'type': 'inertia', 'name': 'a', 'J': 0.5}]
    if spring:
        chain += [{'type': 'spring', 'name': 's', 'stiffness': 5000.0, 'damping': 0.0},
                  {'type': 'inertia', 'name': 'm', 'J': 0.05}]
    chain += [{'type': 'joint', 'name': 'h', 'kind': 'hooke', 'fidelity': 'exact',
               'params': {'beta_deg': beta_deg}},
              {'type': 'inertia', 'name': 'b', 'J': 0.01}]
    return {'name': f'hooke_{beta_deg:g}', 'duration': 1.0, 'engine': {'model': 'linear'},
            'load': {'model': 'constant', 'torque': 10.0}, 'initial': {'speed_rad_s': 20.0},
            'driveline': chain}


@pytest.mark.hard
@pytest.mark.parametrize('beta_deg', [60.0, 80.0])
def test_elastic_hooke_energy_conserved(beta_deg: float) -> None:
    """Zero damping, zero external torque, 1 s (~3 revolutions at 20 rad/s):
    relative energy residual < 1e-8; output speed swings by the kinematic ratio."""
    sim = Simulation(parse_scene(hooke_scene(beta_deg)), method='dop853', rtol=1e-10, atol=1e-12,
                     engine=ZeroTorque(), load=ZeroTorque())
    tr = sim.run(1.0, sample_dt=1e-3)
    assert np.all(np.isfinite(tr.velocity))
    assert tr.max_energy_residual < 1e-8
    # output/input speed of the joint == closed-form ratio at the recorded input angle
    i_in, i_out = tr.column('h_input'), tr.column('h_output')
    b = math.radians(beta_deg)
    ratio = math.cos(b) / (1.0 - math.sin(b) ** 2 * np.cos(tr.position[:, i_in]) ** 2)
    assert np.max(np.abs(tr.velocity[:, i_out] - ratio * tr.velocity[:, i_in])) \
        < 1e-9 * np.max(np.abs(tr.velocity[:, i_out]))


@pytest.mark.hard
def test_89_deg_ratio_matches_numerical_derivative() -> None:
    """At 89 deg the ratio reaches 1/cos b = 57.3 in a narrow peak around phi = 0: the
    analytic ratio and slope match central differences of phi_out (h = 1e-6 rad)."""
    joint = make_joint('hooke', beta=math.radians(89.0))
    phi = np.concatenate([np.linspace(-0.2, 0.2, 401), np.linspace(0.0, 2 * np.pi, 201) + 1e3])
    h = 1e-6
    ev = joint.evaluate(phi)
    d1 = (joint.evaluate(phi + h).phi_out - joint.evaluate(phi - h).phi_out) / (2 * h)
    d2 = (joint.evaluate(phi + h).ratio - joint.evaluate(phi - h).ratio) / (2 * h)
    # bound: truncation (h^2/6 times the third derivative, ~3e-8 here) plus the rounding
    # of phi_out(phi +- h) at |phi| = 1e3 rad, amplified by 1/h
    roundoff = 4 * np.finfo(float).eps * (np.abs(phi) + 1.0) / h
    assert np.all(np.abs(d1 - ev.ratio) < 1e-7 * ev.ratio.max() + roundoff)
    assert np.all(np.abs(d2 - ev.ratio_slope) < 1e-7 * np.abs(ev.ratio_slope).max()
                  + roundoff * ev.ratio.max())
    assert ev.ratio.max() == pytest.approx(1 / math.cos(math.radians(89.0)), rel=1e-12)


@pytest.mark.parametrize('beta_deg', [90.0, 95.0, 180.0])
def test_scene_file_at_90_deg_or_more_names_the_field(tmp_path: Path, beta_deg: float) -> None:
    path = tmp_path / 'h.yaml'
    path.write_text(yaml.safe_dump(hooke_scene(beta_deg, spring=False)))
    field = 'driveline[1].params.beta_deg'
    with pytest.raises(SceneError, match=r'^' + field.replace('[', r'\[').replace(']', r'\]')
                       + r': .*90'):
        load_scene(path)


@pytest.mark.parametrize('beta', [math.pi / 2, math.pi / 2 + 1e-12, math.radians(135.0)])
def test_factory_rejects_90_deg_and_beyond_in_rad(beta: float) -> None:
    with pytest.raises(GeometryError, match=r'^beta: .*90 deg'):
        make_joint('hooke', beta=beta)


def test_run_cli_at_90_deg_one_line_exit_2_nothing_started(tmp_path: Path) -> None:
    """`cvj-sim run` on a 90 deg scene: one error line naming the field, exit 2, no
    traceback, and no run directory created (nothing started)."""
    path = tmp_path / 'h90.yaml'
    path.write_text(yaml.safe_dump(hooke_scene(90.0)))
    out = tmp_path / 'run'
    proc = subprocess.run([CVJ_SIM, 'run', str(path), '--out', str(out)], capture_output=True,
                          text=True, timeout=60)
    assert proc.returncode == 2, proc.stderr
    assert 'Traceback' not in proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1
    assert lines[0].startswith('cvj-sim: error: driveline[3].params.beta_deg: ')
    assert '90' in lines[0]
    assert not (out / 'bag').exists()


def test_kinematics_cli_param_in_rad_at_90_deg(capsys: pytest.CaptureFixture[str]) -> None:
    code = cli_main(['kinematics', 'hooke', '--param', f'beta={math.pi / 2!r}'])
    err = capsys.readouterr().err
    assert code == 2 and err.count('\n') == 1 and err.startswith('cvj-sim: error: beta: ')
