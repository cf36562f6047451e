"""The coupling node refuses an explicit solver on a spring it cannot step (as
`cvj-sim simulate` does: cvj_ros.physics.simulate.explicit_step_check), before it builds
or compiles anything and before any peer is awaited: one line naming the stiffness, exit 2."""
from __future__ import annotations

import math

import pytest
import yaml

pytest.importorskip('rclpy')

from rclpy.parameter import Parameter  # noqa: E402

from cvj_ros.errors import SceneError  # noqa: E402
from cvj_ros.nodes import coupling_node  # noqa: E402
from cvj_ros.nodes.coupling_node import CouplingNode  # noqa: E402
from cvj_ros.physics import simulate as simmod  # noqa: E402

pytestmark = pytest.mark.ros

J1, J2 = 0.128, 0.161          # kg m^2, the two-mass scene of test_coupling_node


def scene_file(tmp_path, stiffness: float, duration: float = 10.0) -> str:
    data = {'name': 'stiff_two_mass', 'duration': duration, 'exchange_step': 0.001,
            'solver': {'method': 'dopri5', 'rtol': 1e-6, 'atol': 1e-8},
            'engine': {'model': 'linear'}, 'load': {'model': 'constant', 'torque': 100.0},
            'initial': {'speed_rad_s': 30.0},
            'driveline': [{'type': 'inertia', 'name': 'engine_crank', 'J': J1},
                          {'type': 'spring', 'name': 'shaft', 'stiffness': stiffness},
                          {'type': 'inertia', 'name': 'wheel', 'J': J2}]}
    path = tmp_path / 'scene.yaml'
    path.write_text(yaml.safe_dump(data))
    return str(path)


def test_hand_started_node_refuses_an_absurd_stiffness_in_one_line(tmp_path, capsys):
    """`python -m cvj_ros.nodes.coupling_node --ros-args -p scene:=... -p duration:=0.5` on a
    1e300 N m/rad spring: exit 2 and the one line (was: peers awaited, then minutes of
    ~1e-11 s steps ending in an overflow)."""
    path = scene_file(tmp_path, 1e300)
    with pytest.raises(SystemExit) as code:
        coupling_node.main(['--ros-args', '-p', f'scene:={path}', '-p', 'duration:=0.5'])
    assert code.value.code == 2
    out, err = capsys.readouterr()
    assert out == '' and 'Traceback' not in err
    omega = math.sqrt(1e300 * (1 / J1 + 1 / J2))
    steps = omega * 0.5 / simmod.EXPLICIT_STABILITY
    assert err.splitlines() == [
        f"coupling_node: error: driveline[1].stiffness: spring 'shaft' and its neighbours' "
        f"inertias have a mode at {omega:.3g} rad/s: dopri5 would need ~{steps:.1e} steps for "
        f"0.5 s just to stay stable (more than 1e+10); check the value, or use solver "
        f"rosenbrock or rigid fidelity for it"]


def test_node_checks_the_run_duration_the_solver_and_forced_fidelity(ctx, tmp_path):
    """c = 1e20 N m/rad: omega_n = 3.75e10 rad/s needs 6.2e10 explicit steps for the scene's
    10 s (refused) but 6.2e7 for a run of 0.01 s (accepted: the run's duration counts, not
    the scene's); an implicit solver or a spring forced rigid is never refused."""
    path = scene_file(tmp_path, 1e20)
    omega = math.sqrt(1e20 * (1 / J1 + 1 / J2))
    assert omega * 10.0 / simmod.EXPLICIT_STABILITY > simmod.MAX_EXPLICIT_STEPS
    assert omega * 0.01 / simmod.EXPLICIT_STABILITY < simmod.MAX_EXPLICIT_STEPS
    with pytest.raises(SceneError, match=r'^driveline\[1\]\.stiffness: .* steps for 10 s '):
        CouplingNode(context=ctx, parameter_overrides=[Parameter('scene', value=path)])
    for extra in (Parameter('duration', value=0.01), Parameter('solver', value='rosenbrock'),
                  Parameter('fidelity', value=['shaft=rigid'])):
        node = CouplingNode(context=ctx, parameter_overrides=[Parameter('scene', value=path), extra])
        node.destroy_node()


def test_node_refuses_it_on_a_vehicle_scene_with_modes(shipped_scene_with, capsys):
    """launch_clutch (clutch, gearbox, wheel brakes; the mode model) with its clutch damper at
    1e300 N m/rad: the same refusal, over the scene's 10 s (the node's duration unset), on
    the lowest frequency of the spring's locked modes (fidelity_tree.mode_tree_spring_omega_n)."""
    path = shipped_scene_with('launch_clutch', 'stiffness: 1200.0', 'stiffness: 1.0e+300')
    with pytest.raises(SystemExit) as code:
        coupling_node.main(['--ros-args', '-p', f'scene:={path}'])
    assert code.value.code == 2
    out, err = capsys.readouterr()
    assert out == '' and len(err.splitlines()) == 1, err
    assert err.startswith("coupling_node: error: driveline[2].stiffness: spring 'clutch_damper' "
                          "and its neighbours' inertias have a mode at 5.45e+150 rad/s: dopri5 "
                          "would need ~9.1e+150 steps for 10 s"), err


def test_node_refuses_it_on_a_chain_scene_with_modes(shipped_scene_with, capsys):
    """launch_clutch_chain (clutch, gearbox, brake on a chain) with its halfshaft at
    1e300 N m/rad and the node's duration 0.1 s (the brake still holding): the same refusal,
    on the lowest frequency of the spring's locked modes, 1st gear against the braked wheel
    (fidelity.mode_chain_spring_omega_n; was: no report, not checked)."""
    path = shipped_scene_with('launch_clutch_chain', 'stiffness: 6100.0', 'stiffness: 1.0e+300')
    with pytest.raises(SystemExit) as code:
        coupling_node.main(['--ros-args', '-p', f'scene:={path}', '-p', 'duration:=0.1'])
    assert code.value.code == 2
    out, err = capsys.readouterr()
    assert out == '' and len(err.splitlines()) == 1, err
    assert err.startswith("coupling_node: error: driveline[5].stiffness: spring 'halfshaft' "
                          "and its neighbours' inertias have a mode at 5.73e+149 rad/s: dopri5 "
                          "would need ~9.5e+147 steps for 0.1 s"), err
