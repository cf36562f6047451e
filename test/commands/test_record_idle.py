"""cvj-sim record --until-idle: idle time counts only while the recorder runs, so a process
starved of the CPU for seconds does not take its own pause for the end of the run."""
from __future__ import annotations

import pytest

from cvj_ros.commands.record import IDLE_TICK_MAX_S, IdleClock


def test_idle_counts_polls_not_wall_gaps() -> None:
    clock = IdleClock()
    assert clock.tick(0.0, 0.0) == 0.0          # no message yet: never idle
    assert clock.tick(5.0, 0.0) == 0.0
    clock.tick(5.0, 4.9)                        # first message
    t = 5.0
    for _ in range(10):                         # 10 polls of 20 ms: 0.2 s idle
        t += 0.02
        idle = clock.tick(t, 4.9)
    assert idle == pytest.approx(0.2)
    assert clock.tick(t + 3.0, 4.9) == pytest.approx(0.2 + IDLE_TICK_MAX_S)   # starved 3 s
    assert clock.tick(t + 3.02, 8.0) == 0.0    # a new message resets it


def test_loop_topics_behind_the_joint_states_hold_the_stop() -> None:
    from cvj_ros.commands.record import BEHIND_WAIT_S, behind_topics, idle_stop
    stamps = {'/driveline/joint_states': 300, '/clock': 300, '/engine/wrench': 239,
              '/coupling/cpl/wrench': 240, '/load/wrench': 300, '/load/front_left/wrench': 10,
              '/diagnostics': 100, '/driveline/scene': 0, '/engine/throttle': 5}
    # /diagnostics, the scene and the commands are not one-per-exchange topics
    assert behind_topics(stamps) == ['/coupling/cpl/wrench', '/engine/wrench', '/load/front_left/wrench']
    assert behind_topics({'/clock': 5}) == []          # no joint state yet: nothing to compare
    # the coupling node's own topics can lag too: the answers say how far the run went
    assert behind_topics({'/driveline/joint_states': 268, '/clock': 268, '/engine/wrench': 300,
                          '/diagnostics': 268}) == ['/clock', '/driveline/joint_states']
    behind = behind_topics(stamps)
    assert not idle_stop(2.0, 2.0, behind)             # S reached, answers still on the way
    assert not idle_stop(2.0 + BEHIND_WAIT_S - 0.1, 2.0, behind)
    assert idle_stop(2.0 + BEHIND_WAIT_S, 2.0, behind)  # bounded: a peer that stopped early
    assert idle_stop(2.0, 2.0, [])
    assert not idle_stop(1.9, 2.0, [])



def test_run_end_gives_the_newest_stamp_with_the_topics_behind_it() -> None:
    """The end-of-run note prints each behind topic's stamp and the run's newest stamp: the
    newest over the joint states and loop topics only (a later /diagnostics stamp is not)."""
    from cvj_ros.commands.record import run_end
    stamps = {'/driveline/joint_states': 300, '/clock': 300, '/engine/wrench': 239,
              '/load/wrench': 300, '/diagnostics': 400, '/driveline/scene': 0}
    assert run_end(stamps) == (300, {'/engine/wrench': 239})
    assert run_end({'/clock': 5, '/engine/wrench': 4}) == (0, {})   # no joint state yet


def test_loop_topics_and_one_publisher_topics_share_the_exchange_wrenches() -> None:
    """commands/record.loop_topic (one message per exchange) and the recorder's
    one-publisher set differ on purpose, and share bag.exchange_wrench_topic."""
    from cvj_ros.bag import _one_publisher_topic, exchange_wrench_topic
    from cvj_ros.commands.record import loop_topic
    for topic in ('/engine/wrench', '/load/wrench', '/coupling/tripod/wrench', '/load/front_left/wrench'):
        assert exchange_wrench_topic(topic) and loop_topic(topic) and _one_publisher_topic(topic)
    assert loop_topic('/clock') and not _one_publisher_topic('/clock')
    for topic in ('/driveline/scene', '/engine/throttle_scale', '/driveline/joint_states'):
        assert _one_publisher_topic(topic) and not loop_topic(topic)
    for topic in ('/diagnostics', '/engine/throttle', '/driveline/recorder_ready'):
        assert not loop_topic(topic) and not _one_publisher_topic(topic)


def test_idle_does_not_end_a_loop_whose_coupling_node_is_still_there() -> None:
    """A joint-state publisher still on the graph means the loop paused (a coupling node
    compiling its kernel mid-run, swapped out): the silence is not the end of the run."""
    from cvj_ros.commands.record import BEHIND_WAIT_S, idle_stop
    assert not idle_stop(100.0, 2.0, [], loop_alive=True)
    assert not idle_stop(2.0 + BEHIND_WAIT_S, 2.0, ['/clock'], loop_alive=True)
    assert idle_stop(2.0, 2.0, [], loop_alive=False)


def _wait_graph(node, until) -> None:
    """Poll the graph until ``until(node)`` holds (discovery of this process's own nodes:
    the deadline only turns a hang into a failure, it bounds no measured time)."""
    import time
    deadline = time.monotonic() + 60
    while not until(node):
        assert time.monotonic() < deadline, 'graph never showed the expected publishers'
        time.sleep(0.01)


def test_loop_alive_counts_only_the_runs_coupling_node(ctx) -> None:
    """Only the run's coupling node (by its fully qualified name: /coupling_node as cvj-sim
    run, the launch file and `ros2 run` name it, or the one given) keeps the recorder
    waiting; another joint-state publisher on the graph (a stack's, a finished run's
    lingering node) does not: it held the recorder until Ctrl-C."""
    import rclpy
    from sensor_msgs.msg import JointState

    from cvj_ros.commands.record import loop_alive
    topic = '/driveline/joint_states'
    observer = rclpy.create_node('recorder_probe', context=ctx)
    stack = rclpy.create_node('stack', context=ctx)
    stack.create_publisher(JointState, topic, 10)
    _wait_graph(observer, lambda n: n.count_publishers(topic) >= 1)
    assert not loop_alive(observer)                       # the old rule: True, for ever
    coupling = rclpy.create_node('coupling_node', context=ctx)
    coupling.create_publisher(JointState, topic, 10)
    other_ns = rclpy.create_node('coupling_node', namespace='/car', context=ctx)
    other_ns.create_publisher(JointState, topic, 10)
    _wait_graph(observer, lambda n: n.count_publishers(topic) >= 3)
    assert loop_alive(observer) and loop_alive(observer, '/coupling_node')
    assert loop_alive(observer, '/car/coupling_node')
    assert not loop_alive(observer, '/truck/coupling_node')
    coupling.destroy_node()                               # the run's coupling node leaves
    _wait_graph(observer, lambda n: n.count_publishers(topic) == 2)
    assert not loop_alive(observer)
    assert loop_alive(observer, '/car/coupling_node')


def test_coupling_node_option_takes_ros_node_names() -> None:
    from cvj_ros.commands.record import node_name
    from cvj_ros.errors import CvjError
    assert node_name('coupling_node') == '/coupling_node'
    assert node_name('/car/coupling_node') == '/car/coupling_node'
    for bad in ('/', '/car/', '/1node', '/a b', ''):
        with pytest.raises(CvjError, match='^--coupling-node: not a ROS node name'):
            node_name(bad)


def test_recorder_waits_out_a_paused_loop_and_stops_once_it_left(ctx, tmp_path) -> None:
    """`cvj-sim record --until-idle 0.5` records the coupling node's joint states, keeps
    recording through 3 s of its silence (here the old rule stopped after 0.5 s and lost the
    rest of a run whose coupling node stalled after step 0), and stops once the coupling
    node has left the graph, with a finalised bag, although another node's joint-state
    publisher stays on the graph (it held the recorder until Ctrl-C)."""
    import subprocess
    import sys
    import time
    from pathlib import Path

    import rclpy
    from sensor_msgs.msg import JointState

    from cvj_ros.bag import plain_mcap_bag
    out = tmp_path / 'rec'
    proc = subprocess.Popen([str(Path(sys.executable).parent / 'cvj-sim'), 'record', str(out),
                             '--until-idle', '0.5'], stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    try:
        stack = rclpy.create_node('stack', context=ctx)      # stays to the end, never publishes
        stack.create_publisher(JointState, '/driveline/joint_states', 10)
        node = rclpy.create_node('coupling_node', context=ctx)
        pub = node.create_publisher(JointState, '/driveline/joint_states', 10)
        deadline = time.monotonic() + 120     # the recorder's start on a loaded machine
        while pub.get_subscription_count() < 1:
            assert time.monotonic() < deadline and proc.poll() is None, proc.stdout.read()
            time.sleep(0.05)
        for k in range(10):                   # 1 s of joint states
            msg = JointState(name=['s'], position=[0.0], velocity=[1.0], effort=[0.0])
            msg.header.stamp.nanosec = k * 1_000_000
            pub.publish(msg)
            time.sleep(0.1)
        time.sleep(3.0)                       # the loop pauses: 6x the idle limit
        assert proc.poll() is None, 'the recorder stopped while the loop was still there'
        node.destroy_node()                   # the coupling node leaves, the stack stays
        rc = proc.wait(timeout=60)            # endpoint removal: immediate on a clean exit
        assert rc == 0, proc.stdout.read()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    plain = plain_mcap_bag(out / 'bag')          # metadata.yaml written: finalised
    assert plain is not None and plain[1]['/driveline/joint_states'][1] >= 1
