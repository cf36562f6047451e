"""Fuzz of the wrench inputs of the lockstep loop with a seeded generator.

Physics level: CoupledStepper.advance gets random torques (NaN, +-inf, huge, subnormal,
-0.0, ordinary): a non-finite torque raises LockstepError naming T_engine / T_load and
leaves the state untouched; a finite one integrates to a finite state or raises
SolverError; nothing else.

Node level (rclpy in-process, coupling_node with fake engine/load responders): for every
exchange step the responders send the right answer plus a seeded random burst of junk:
stale, future, off-by-1-ns, zero and random stamps with wild torques (1e300, -1e6,
subnormal ...) before it, and duplicates with the right stamp after it. Oracle: every
junk message is ignored and counted, never integrated - the momentum balance
J1 w1 + J2 w2 = (J1 + J2) w0 + (T_e - T_l) t (internal spring and damper cancel) holds to
1e-8 at every published state. With a NaN or inf torque injected at a random step (and
random stamp) the node stops with exit 1, an ERROR naming the topic, nothing non-finite
published, and the balance still holds on what was published.
"""
from __future__ import annotations

import math
import random
import time

import numpy as np
import pytest
import yaml

from cvj_ros.errors import LockstepError, SolverError

J1, J2 = 0.128, 0.161          # kg m^2 (seed 004 KAVZ-685)
T_ENGINE, T_LOAD = 150.0, 100.0
W0 = 30.0                      # rad/s
H_NS = 1_000_000               # 1 ms exchange
N_STEPS = 25
WILD = [1e300, -1e300, 1e6, -1e6, 5e-324, -0.0, 0.0, 123.456, -7.0]


def two_mass_scene() -> dict:
    return {
        'name': 'fuzz_two_mass', 'duration': N_STEPS * H_NS * 1e-9, 'exchange_step': H_NS * 1e-9,
        'solver': {'method': 'dopri5', 'rtol': 1e-10, 'atol': 1e-12},
        'engine': {'model': 'linear'}, 'load': {'model': 'constant', 'torque': T_LOAD},
        'initial': {'speed_rad_s': W0},
        'driveline': [{'type': 'inertia', 'name': 'engine_crank', 'J': J1},
                      {'type': 'spring', 'name': 'shaft', 'stiffness': 715.4, 'damping': 6.35},
                      {'type': 'inertia', 'name': 'wheel', 'J': J2}]}


def test_coupled_stepper_torque_fuzz() -> None:
    from cvj_ros.physics.cosim import CoupledStepper
    from cvj_ros.physics.driveline import Driveline
    from cvj_ros.physics.scene import parse_scene
    rng = random.Random(2024)
    # |T| > ~1e140 N m: test_huge_finite_torque_fails_loudly
    values = [v for v in WILD if abs(v) < 1e300] + [1e12, math.nan, math.inf, -math.inf]
    n_rejected = n_solver = 0
    for case in range(60):
        dl = Driveline.from_scene(parse_scene(two_mass_scene()))
        cs = CoupledStepper(dl, scheme=rng.choice(['zoh', 'extrapolate', 'linear_implicit']),
                            method='dopri5', rtol=1e-8, atol=1e-10)
        for k in range(8):
            te, tl = rng.choice(values), rng.choice(values)
            se, sl = rng.choice([0.0, -1.0, math.nan]), rng.choice([0.0, 2.0, math.inf])
            before = cs.x.copy()
            try:
                x = cs.advance((k + 1) * 1e-3, te, tl, slope_engine=se, slope_load=sl)
            except LockstepError as exc:
                bad = [n for n, v in (('T_engine', te), ('T_load', tl), ('slope_engine', se),
                                      ('slope_load', sl)) if not math.isfinite(v)]
                assert bad and str(exc).startswith(bad[0] + ':'), (exc, te, tl, se, sl)
                np.testing.assert_array_equal(cs.x, before)       # never integrated
                n_rejected += 1
                continue
            except SolverError:
                n_solver += 1                                      # loud failure is fine
                break
            assert all(math.isfinite(v) for v in (te, tl, se, sl))   # else it must have raised
            assert np.all(np.isfinite(x)), (case, k, te, tl)
    assert n_rejected > 50


def test_huge_finite_torque_fails_loudly() -> None:
    """A finite but absurd torque (1e300 N m, e.g. from a broken peer) must end in a
    CvjError (SolverError / LockstepError), never in another exception. (Was a
    ZeroDivisionError in solvers._initial_step: the RMS norm overflowed, h0 became 0.)"""
    from cvj_ros.errors import CvjError
    from cvj_ros.physics.cosim import CoupledStepper
    from cvj_ros.physics.driveline import Driveline
    from cvj_ros.physics.scene import parse_scene
    dl = Driveline.from_scene(parse_scene(two_mass_scene()))
    cs = CoupledStepper(dl, scheme='zoh', method='dopri5', rtol=1e-8, atol=1e-10)
    for torque in (1e300, -1e300, 1e200):
        try:
            x = cs.advance(cs.t + 1e-3, torque, 0.0)
        except CvjError as exc:
            assert str(exc).startswith('t: '), exc
            continue
        assert np.all(np.isfinite(x))


# --- node level ------------------------------------------------------------------------

rclpy = pytest.importorskip('rclpy')


def junk_plan(rng: random.Random, k: int, inject: tuple[int, str] | None,
              topic: str) -> list[tuple[int, float]]:
    """(stamp ns, torque) messages of one responder for step k: junk, the answer, dups."""
    t_k = k * H_NS
    good = T_ENGINE if topic == 'engine' else T_LOAD
    wrong_stamps = [t_k - H_NS, t_k + H_NS, t_k + 1, t_k - 1, 0 if k else H_NS,
                    rng.randrange(1, 10**12) * H_NS + 7]
    before = [(rng.choice([s for s in wrong_stamps if s >= 0 and s != t_k]), rng.choice(WILD))
              for _ in range(rng.randrange(4))]
    after = [(t_k, rng.choice(WILD)) for _ in range(rng.randrange(3))]
    msgs = before + [(t_k, good)] + after
    if inject is not None and inject[0] == k and inject[1] == topic:
        stamp = rng.choice([t_k, t_k + H_NS, t_k - H_NS]) if k else t_k
        msgs.insert(rng.randrange(len(msgs) + 1), (max(stamp, 0), rng.choice([math.nan, math.inf,
                                                                               -math.inf])))
    return msgs


def run_fuzzed(ctx, tmp_path, seed: int, inject: tuple[int, str] | None):
    from builtin_interfaces.msg import Time
    from geometry_msgs.msg import WrenchStamped
    from rclpy.parameter import Parameter
    from sensor_msgs.msg import JointState

    from cvj_ros.nodes.common import make_executor
    from cvj_ros.nodes.coupling_node import CouplingNode
    from cvj_ros.nodes.qos import DATA_QOS
    path = tmp_path / 'scene.yaml'
    path.write_text(yaml.safe_dump(two_mass_scene()))
    rng = random.Random(seed)
    peers = rclpy.create_node('fuzz_peers', context=ctx)
    pubs = {'engine': peers.create_publisher(WrenchStamped, '/engine/wrench', DATA_QOS),
            'load': peers.create_publisher(WrenchStamped, '/load/wrench', DATA_QOS)}
    states: list[JointState] = []
    sent = {'junk': 0}

    def on_state(msg: JointState) -> None:
        states.append(msg)
        k = round((msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec) / H_NS)
        for topic, pub in pubs.items():
            plan = junk_plan(rng, k, inject, topic)
            sent['junk'] += len(plan) - 1
            for stamp, torque in plan:
                w = WrenchStamped()
                w.header.stamp = Time(sec=stamp // 10**9, nanosec=stamp % 10**9)
                w.wrench.torque.z = torque
                pub.publish(w)

    peers.create_subscription(JointState, '/driveline/joint_states', on_state, DATA_QOS)
    node = CouplingNode(context=ctx, parameter_overrides=[
        Parameter('scene', value=str(path)), Parameter('min_subscribers', value=1),
        Parameter('peer_timeout', value=2.0)])
    ex = make_executor('events', ctx)
    ex.add_node(peers)
    ex.add_node(node)
    t0 = time.monotonic()
    try:
        while node.exit_code is None:
            assert time.monotonic() - t0 < 20.0, 'coupling node did not finish'
            ex.spin_once(timeout_sec=0.05)
        # every state the node published is delivered (its exit follows the publication of
        # the last one; a fixed number of spins stood for "long enough")
        t1 = time.monotonic()
        while len(states) < node.joint_states_published and time.monotonic() - t1 < 10.0:
            ex.spin_once(timeout_sec=0.01)
        for _ in range(5):
            ex.spin_once(timeout_sec=0.01)
    finally:
        ex.shutdown()
        peers.destroy_node()
        node.destroy_node()
    return node, states, sent['junk']


def check_balance(states) -> None:
    """Momentum balance at every published state (no junk torque ever integrated)."""
    for msg in states:
        t = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec
        w = np.asarray(msg.velocity)
        assert np.all(np.isfinite(w))
        p = J1 * w[0] + J2 * w[-1]
        assert p == pytest.approx((J1 + J2) * W0 + (T_ENGINE - T_LOAD) * t, rel=1e-8), t


@pytest.mark.ros
@pytest.mark.parametrize('seed', [1, 2])
def test_lockstep_ignores_fuzzed_junk(ctx, tmp_path, seed: int) -> None:
    node, states, junk = run_fuzzed(ctx, tmp_path, seed, None)
    assert node.exit_code == 0, node.error_message
    assert len(states) == N_STEPS + 1
    assert junk > 2 * N_STEPS and node.ignored_stamps > N_STEPS
    check_balance(states)


@pytest.mark.ros
@pytest.mark.parametrize('seed', [3, 4, 5])
def test_lockstep_rejects_fuzzed_non_finite_torque(ctx, tmp_path, seed: int) -> None:
    rng = random.Random(seed)
    inject = (rng.randrange(2, N_STEPS - 2), rng.choice(['engine', 'load']))
    node, states, _ = run_fuzzed(ctx, tmp_path, seed, inject)
    topic = f'/{inject[1]}/wrench'
    assert node.exit_code == 1
    assert node.error_message.startswith(f'{topic}: torque.z not finite'), node.error_message
    assert node.rejected_torques == 1
    # stopped at the injected step (or right after it, when the bad message trailed both answers)
    assert inject[0] <= node.k <= inject[0] + 1
    check_balance(states)
