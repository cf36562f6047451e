"""Measure the rclpy publish -> callback -> publish -> callback round trip.

In-process (:func:`measure_round_trip`): two nodes in one process and one executor: ``ping`` publishes a Float64 on a private
topic, ``pong`` answers it in its callback on a second topic, and ``ping``'s callback
records the elapsed wall time and publishes the next ping. This is exactly the message
path of one lockstep exchange (joint state out, wrench back), minus the physics, so it
is the floor the lockstep overhead per exchange is judged against.

Inter-process (:func:`measure_round_trip_ipc`): the lockstep runs its nodes in separate
processes, so the fair floor is a round trip across processes: ``echoes`` echo nodes in
subprocesses (``python -m cvj_ros.nodes.roundtrip echo ...``) answer every ping from this
process, with the same QoS, executor and Fast DDS settings as the node processes of
``cvj-sim run`` (:func:`cvj_ros.nodes.qos.dds_environment`). With ``echoes=2`` a round
trip ends when both answers are in: the message pattern of one exchange with engine_node
and load_node.
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from collections.abc import Sequence
from typing import Literal

import numpy as np

EXECUTORS = ('events', 'single')
# Bound on discovery of the pinging process by an echo process (s); matching takes ~0.1-1 s idle.
ECHO_MATCH_TIMEOUT_S = 30.0


def _us_summary(seconds: np.ndarray) -> dict[str, float]:
    """Mean, median and 95th percentile (us) of round-trip times given in s."""
    us = seconds * 1e6
    return {'us_mean': float(us.mean()), 'us_p50': float(np.percentile(us, 50)),
            'us_p95': float(np.percentile(us, 95))}


def measure_round_trip(n: int = 1000, executor: Literal['events', 'single'] = 'events', *,
                       warmup: int = 50, timeout: float = 60.0) -> dict[str, float]:
    """Round-trip wall time of ``n`` ping-pong exchanges with the given executor.

    Args:
        n: number of measured round trips (after ``warmup`` unmeasured ones).
        executor: 'events' (rclpy.experimental.EventsExecutor) or 'single'
            (rclpy.executors.SingleThreadedExecutor).
        warmup: round trips discarded before measuring (discovery, allocation).
        timeout: wall seconds after which the measurement is abandoned (RuntimeError).

    Returns:
        dict with ``us_mean``, ``us_p50``, ``us_p95`` (microseconds per round trip),
        ``n`` and ``executor``.
    """
    import rclpy
    from rclpy.context import Context
    from std_msgs.msg import Float64

    from cvj_ros.nodes.qos import DATA_QOS

    if executor not in EXECUTORS:
        raise ValueError(f'executor: must be one of {EXECUTORS}, got {executor!r}')
    if n < 1:
        raise ValueError(f'n: must be >= 1, got {n}')
    ctx = Context()
    rclpy.init(context=ctx)
    suffix = f'{os.getpid()}_{time.monotonic_ns()}'
    ping_topic, pong_topic = f'/cvj_rt/ping_{suffix}', f'/cvj_rt/pong_{suffix}'
    try:
        ping = rclpy.create_node('cvj_rt_ping', context=ctx)
        pong = rclpy.create_node('cvj_rt_pong', context=ctx)
        ping_pub = ping.create_publisher(Float64, ping_topic, DATA_QOS)
        pong_pub = pong.create_publisher(Float64, pong_topic, DATA_QOS)
        pong.create_subscription(Float64, ping_topic, lambda m: pong_pub.publish(m), DATA_QOS)
        total = n + warmup
        samples = np.empty(total)
        state = {'i': 0, 't0': 0.0}
        msg = Float64()

        def on_pong(_m: Float64) -> None:
            samples[state['i']] = time.perf_counter() - state['t0']
            state['i'] += 1
            if state['i'] < total:
                state['t0'] = time.perf_counter()
                ping_pub.publish(msg)

        ping.create_subscription(Float64, pong_topic, on_pong, DATA_QOS)
        if executor == 'events':
            from rclpy.experimental import EventsExecutor
            ex = EventsExecutor(context=ctx)
        else:
            from rclpy.executors import SingleThreadedExecutor
            ex = SingleThreadedExecutor(context=ctx)
        ex.add_node(ping)
        ex.add_node(pong)
        deadline = time.monotonic() + timeout
        # Wait until both directions are matched so no message is lost.
        while (ping_pub.get_subscription_count() < 1 or pong_pub.get_subscription_count() < 1):
            ex.spin_once(timeout_sec=0.01)
            if time.monotonic() > deadline:
                raise RuntimeError('round trip: ping/pong topics never matched')
        state['t0'] = time.perf_counter()
        ping_pub.publish(msg)
        while state['i'] < total:
            ex.spin_once(timeout_sec=0.1)
            if time.monotonic() > deadline:
                raise RuntimeError(f'round trip: only {state["i"]} of {total} exchanges in {timeout} s')
        ex.shutdown()
        ping.destroy_node()
        pong.destroy_node()
    finally:
        rclpy.shutdown(context=ctx)
    return {**_us_summary(samples[warmup:]), 'n': n, 'executor': executor}


def measure_round_trip_peers(n: int = 1000, peers: int = 2, *, warmup: int = 100,
                             timeout: float = 60.0) -> dict[str, float]:
    """In-process round trip with ``peers`` answering nodes on one EventsExecutor (us): the
    composed loop's topology (engine + load answering the coupling node; the bench compares
    the composed overhead per exchange with it).

    The ping node publishes a Float64; each peer node answers on its own topic; the round
    trip (time.perf_counter) ends when all ``peers`` answers are in, and the next ping goes
    out from that callback, like the lockstep coupling node. The executor spins on a Future
    completed after the last round trip (no Python loop per event). Every message goes
    through DDS inside the process (no in-process bus: what rclpy gives an application).
    Returns ``us_mean``, ``us_p50``, ``us_p95``, ``n``, ``peers``, ``executor``."""
    import rclpy
    from rclpy.context import Context
    from rclpy.experimental import EventsExecutor
    from rclpy.task import Future
    from std_msgs.msg import Float64

    from cvj_ros.nodes.qos import DATA_QOS
    if n < 1:
        raise ValueError(f'n: must be >= 1, got {n}')
    if peers < 1:
        raise ValueError(f'peers: must be >= 1, got {peers}')
    ctx = Context()
    rclpy.init(context=ctx)
    suffix = f'{os.getpid()}_{time.monotonic_ns()}'
    try:
        ping = rclpy.create_node('cvj_rt_ping', context=ctx)
        ping_pub = ping.create_publisher(Float64, f'/cvj_rt/ping_{suffix}', DATA_QOS)
        nodes = [ping]
        for i in range(peers):
            peer = rclpy.create_node(f'cvj_rt_peer{i}', context=ctx)
            pub = peer.create_publisher(Float64, f'/cvj_rt/pong{i}_{suffix}', DATA_QOS)
            peer.create_subscription(Float64, f'/cvj_rt/ping_{suffix}',
                                     lambda m, _p=pub: _p.publish(m), DATA_QOS)
            nodes.append(peer)
        total = n + warmup
        samples = np.empty(total)
        state = {'i': 0, 'got': 0, 't0': 0.0}
        msg = Float64()
        done = Future()

        def on_pong(_m: Float64) -> None:
            state['got'] += 1
            if state['got'] < peers:
                return
            state['got'] = 0
            samples[state['i']] = time.perf_counter() - state['t0']
            state['i'] += 1
            if state['i'] < total:
                state['t0'] = time.perf_counter()
                ping_pub.publish(msg)
            else:
                done.set_result(True)
        subs = [ping.create_subscription(Float64, f'/cvj_rt/pong{i}_{suffix}', on_pong, DATA_QOS)
                for i in range(peers)]
        ex = EventsExecutor(context=ctx)
        for node in nodes:
            ex.add_node(node)
        deadline = time.monotonic() + timeout
        while ping_pub.get_subscription_count() < peers or any(sub.get_publisher_count() < 1
                                                               for sub in subs):
            ex.spin_once(timeout_sec=0.01)
            if time.monotonic() > deadline:
                raise RuntimeError('round trip: topics never matched')
        state['t0'] = time.perf_counter()
        ping_pub.publish(msg)
        ex.spin_until_future_complete(done, timeout_sec=timeout)
        if not done.done():
            raise RuntimeError(f'round trip: only {state["i"]} of {total} in {timeout} s')
        ex.shutdown()
        for node in nodes:
            node.destroy_node()
    finally:
        rclpy.shutdown(context=ctx)
    return {**_us_summary(samples[warmup:]), 'n': n, 'peers': peers, 'executor': 'events'}


def measure_lockstep(scene: str, *, duration: float | None = None, exchange_step: float | None = None,
                     executor: Literal['events', 'single'] = 'events', coupling_scheme: str = 'zoh',
                     timeout: float = 120.0) -> dict[str, float]:
    """Run coupling_node, engine_node and load_node in one process and one executor.

    Args:
        scene: scene name or YAML path. duration, exchange_step: overrides (s).
        executor: 'events' or 'single'. coupling_scheme: zoh | extrapolate | linear_implicit.
        timeout: wall seconds before giving up (RuntimeError).

    Returns:
        the coupling node's ``loop_stats()``: steps, real_time_factor, exchange_wall_us_mean,
        lockstep_wait_us_mean, integration_us_mean, overhead_us_mean (= wall per exchange
        minus integration), ... plus ``wall_s``.
    """
    import rclpy
    from rclpy.context import Context
    from rclpy.parameter import Parameter

    from cvj_ros.nodes.common import make_executor
    from cvj_ros.nodes.coupling_node import CouplingNode
    from cvj_ros.nodes.engine_node import EngineNode
    from cvj_ros.nodes.load_node import LoadNode

    ctx = Context()
    rclpy.init(context=ctx)
    try:
        scene_p = [Parameter('scene', value=scene)]
        over = scene_p + [Parameter('coupling_scheme', value=coupling_scheme),
                          Parameter('diagnostics_every', value=10**9)]
        if duration:
            over.append(Parameter('duration', value=float(duration)))
        if exchange_step:
            over.append(Parameter('exchange_step', value=float(exchange_step)))
        nodes = [EngineNode(context=ctx, parameter_overrides=scene_p),
                 LoadNode(context=ctx, parameter_overrides=scene_p)]
        coupling = CouplingNode(context=ctx, parameter_overrides=over)
        nodes.append(coupling)
        ex = make_executor(executor, ctx)
        for n in nodes:
            ex.add_node(n)
        t0 = time.monotonic()
        ex.spin_until_future_complete(coupling.done, timeout_sec=timeout)
        if coupling.exit_code is None:
            raise RuntimeError(f'lockstep: not finished within {timeout} s')
        stats = dict(coupling.loop_stats())
        stats['wall_s'] = time.monotonic() - t0
        stats['exit_code'] = coupling.exit_code
        ex.shutdown()
        for n in nodes:
            n.destroy_node()
    finally:
        rclpy.shutdown(context=ctx)
    return stats


def _echo_main(ping_topic: str, pong_topic: str, executor: str) -> int:
    """Echo process: answer every Float64 on ``ping_topic`` on ``pong_topic`` until stdin closes."""
    import threading

    import rclpy
    from rclpy.context import Context
    from std_msgs.msg import Float64

    from cvj_ros.nodes.common import make_executor
    from cvj_ros.nodes.qos import DATA_QOS

    ctx = Context()
    rclpy.init(context=ctx)
    node = rclpy.create_node(f'cvj_rt_echo_{os.getpid()}', context=ctx)
    pub = node.create_publisher(Float64, pong_topic, DATA_QOS)
    sub = node.create_subscription(Float64, ping_topic, pub.publish, DATA_QOS)
    ex = make_executor(executor, ctx)
    ex.add_node(node)
    from rclpy.task import Future
    done = Future()
    # 'ready' only once both of our endpoints see the pinging process (matching is seen from
    # each side separately): a pong published before our writer has matched the parent's reader
    # is dropped for good (volatile durability), and the parent would wait for it forever. That
    # was the cause of "only 0 of 70 exchanges" under load. Bounded wait, no fixed sleep.
    deadline = time.monotonic() + ECHO_MATCH_TIMEOUT_S
    while pub.get_subscription_count() < 1 or sub.get_publisher_count() < 1:
        if time.monotonic() > deadline:
            print(f'roundtrip echo: error: {ping_topic}: pinging process not matched within '
                  f'{ECHO_MATCH_TIMEOUT_S} s', file=sys.stderr)
            ex.shutdown()
            node.destroy_node()
            rclpy.shutdown(context=ctx)
            return 1
        ex.spin_once(timeout_sec=0.01)

    def watch_stdin() -> None:   # the parent closes our stdin (or dies): stop
        sys.stdin.read()
        done.set_result(True)

    threading.Thread(target=watch_stdin, daemon=True).start()
    print('ready', flush=True)
    try:
        while not done.done() and ctx.ok():
            ex.spin_until_future_complete(done, timeout_sec=0.25)
    except KeyboardInterrupt:
        pass
    finally:
        ex.shutdown()
        node.destroy_node()
        rclpy.shutdown(context=ctx)
    return 0


def measure_round_trip_ipc(n: int = 1000, executor: Literal['events', 'single'] = 'events', *,
                           echoes: int = 1, warmup: int = 50, timeout: float = 60.0) -> dict[str, float]:
    """Inter-process round trip: ping from this process, answered by ``echoes`` subprocesses.

    Every echo process subscribes the ping topic and publishes the same Float64 on its own
    pong topic; a round trip is the wall time (``time.perf_counter``) from publishing a
    ping to having the answers of all ``echoes`` processes. QoS :data:`~cvj_ros.nodes.qos.DATA_QOS`,
    the given executor on both sides, and the node-process DDS settings of ``cvj-sim run``
    (:func:`cvj_ros.nodes.qos.dds_environment`; in this process they apply only if rclpy
    has not created a participant before, since Fast DDS reads them once per process).

    Args:
        n: measured round trips (after ``warmup`` discarded ones).
        executor: 'events' or 'single' (both processes).
        echoes: number of answering processes (1, or 2 = the engine + load pattern).
        warmup: round trips discarded first (discovery, allocation).
        timeout: wall seconds for start-up plus measurement (RuntimeError after it).

    Returns:
        dict with ``us_mean``, ``us_p50``, ``us_p95`` (microseconds per round trip), ``n``,
        ``executor``, ``echoes``, ``processes`` = echoes + 1, and ``event_thread_wakes``:
        wake-ups of an echo process's Fast DDS event thread per round trip (mean over the
        echo processes; :func:`event_thread_sleeps`, None where /proc cannot tell).
    """
    if executor not in EXECUTORS:
        raise ValueError(f'executor: must be one of {EXECUTORS}, got {executor!r}')
    if n < 1:
        raise ValueError(f'n: must be >= 1, got {n}')
    if not 1 <= echoes <= 8:
        raise ValueError(f'echoes: must be in 1..8, got {echoes}')
    env = run_dds_settings()
    return _measure_ipc(n, executor, echoes=echoes, warmup=warmup, timeout=timeout, env=env)


def run_dds_settings() -> dict[str, str]:
    """The environment with the DDS settings of `cvj-sim run`'s node processes
    (:func:`cvj_ros.nodes.qos.dds_environment`, the profile file in a stable per-user
    directory), for the processes a measurement starts; the same keys are also set in this
    process's environment where unset. Fast DDS reads them once, when a process creates its
    first participant: a benchmark calls this before any rclpy measurement, so the pinging
    side of a round trip has the settings of the loop's coupling node too."""
    import tempfile

    from cvj_ros.nodes.qos import dds_environment
    # a stable per-user directory: the profile path may stay in os.environ after this call
    profile_dir = os.path.join(tempfile.gettempdir(), f'cvj_ros_dds_{os.getuid()}')
    os.makedirs(profile_dir, exist_ok=True)
    env = dds_environment(dict(os.environ), profile_dir=profile_dir)
    for key in ('RMW_FASTRTPS_PUBLICATION_MODE', 'FASTRTPS_DEFAULT_PROFILES_FILE',
                'ROS_AUTOMATIC_DISCOVERY_RANGE', 'RMW_IMPLEMENTATION'):
        if key in env:
            os.environ.setdefault(key, env[key])
    return env


def event_thread_sleeps(pid: int) -> int | None:
    """Voluntary context switches of process ``pid``'s Fast DDS event threads (``dds.ev.*``):
    each one is a wake-up of a thread that had gone to sleep. None where /proc cannot tell
    (not Linux, process gone, or no such thread: another RMW)."""
    total, found = 0, False
    try:
        tids = os.listdir(f'/proc/{pid}/task')
    except OSError:
        return None
    for tid in tids:
        try:
            with open(f'/proc/{pid}/task/{tid}/comm') as fh:
                if not fh.read().startswith('dds.ev'):
                    continue
            with open(f'/proc/{pid}/task/{tid}/status') as fh:
                for line in fh:
                    if line.startswith('voluntary_ctxt_switches:'):
                        total += int(line.split()[1])
                        found = True
        except OSError:
            continue
    return total if found else None


def _wait_ready(proc: subprocess.Popen, deadline: float) -> None:
    """Read ``proc``'s stdout until its 'ready' line, at most until ``deadline`` (monotonic s)."""
    import selectors
    assert proc.stdout is not None
    with selectors.DefaultSelector() as sel:
        sel.register(proc.stdout, selectors.EVENT_READ)
        while True:
            left = deadline - time.monotonic()
            if left <= 0 or not sel.select(timeout=left):
                raise RuntimeError('round trip: echo process not ready (discovery) in time')
            line = proc.stdout.readline()
            if not line:
                raise RuntimeError(f'round trip: echo process exited with {proc.wait()}')
            if line.strip() == b'ready':
                return


def _measure_ipc(n: int, executor: str, *, echoes: int, warmup: int, timeout: float,
                 env: dict[str, str]) -> dict[str, float]:
    import rclpy
    from rclpy.context import Context
    from std_msgs.msg import Float64

    from cvj_ros.nodes.common import make_executor
    from cvj_ros.nodes.qos import DATA_QOS

    suffix = f'{os.getpid()}_{time.monotonic_ns()}'
    ping_topic = f'/cvj_rt/ipc_ping_{suffix}'
    pong_topics = [f'/cvj_rt/ipc_pong_{suffix}_{i}' for i in range(echoes)]
    procs = [subprocess.Popen([sys.executable, '-m', 'cvj_ros.nodes.roundtrip', 'echo', ping_topic, pong,
                               executor], stdin=subprocess.PIPE, stdout=subprocess.PIPE, env=env)
             for pong in pong_topics]
    ctx = Context()
    rclpy.init(context=ctx)
    total = n + warmup
    samples = np.empty(total)
    try:
        node = rclpy.create_node(f'cvj_rt_ipc_{os.getpid()}', context=ctx)
        pub = node.create_publisher(Float64, ping_topic, DATA_QOS)
        state = {'i': 0, 't0': 0.0, 'got': 0}
        msg = Float64()

        def on_pong(_m: Float64) -> None:
            state['got'] += 1
            if state['got'] < echoes:
                return
            samples[state['i']] = time.perf_counter() - state['t0']
            state['i'] += 1
            state['got'] = 0
            if state['i'] < total:
                state['t0'] = time.perf_counter()
                pub.publish(msg)

        subs = [node.create_subscription(Float64, t, on_pong, DATA_QOS) for t in pong_topics]
        ex = make_executor(executor, ctx)
        ex.add_node(node)
        deadline = time.monotonic() + timeout
        for p in procs:   # each echo process prints 'ready' once it has matched our endpoints
            _wait_ready(p, deadline)
        while (pub.get_subscription_count() < echoes
               or any(s.get_publisher_count() < 1 for s in subs)):
            ex.spin_once(timeout_sec=0.01)
            if time.monotonic() > deadline:
                raise RuntimeError('round trip: echo processes never matched')
        ev_before = [event_thread_sleeps(p.pid) for p in procs]
        state['t0'] = time.perf_counter()
        pub.publish(msg)
        while state['i'] < total:
            ex.spin_once(timeout_sec=0.1)
            if time.monotonic() > deadline:
                raise RuntimeError(f'round trip: only {state["i"]} of {total} exchanges in {timeout} s')
        ev_after = [event_thread_sleeps(p.pid) for p in procs]
        ex.shutdown()
        node.destroy_node()
    finally:
        rclpy.shutdown(context=ctx)
        for p in procs:
            if p.stdin is not None:
                p.stdin.close()
        for p in procs:
            try:
                p.wait(timeout=5.0)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()
            if p.stdout is not None:
                p.stdout.close()
    woke = [b - a for a, b in zip(ev_before, ev_after) if a is not None and b is not None]
    return {**_us_summary(samples[warmup:]), 'n': n, 'executor': executor,
            'echoes': echoes, 'processes': echoes + 1,
            # per round trip and echo process: the DDS profile keeps it far below 1
            # (cvj_ros.nodes.qos, NACK suppression); None where /proc cannot tell
            'event_thread_wakes': (sum(woke) / len(woke) / total) if woke else None}


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m cvj_ros.nodes.roundtrip [--n N]``: print both round trips for both executors;
    ``... echo PING PONG EXECUTOR``: run one echo process (used by measure_round_trip_ipc)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] == ['echo']:
        if len(argv) != 4:
            print('roundtrip echo: error: expected PING_TOPIC PONG_TOPIC EXECUTOR', file=sys.stderr)
            return 2
        return _echo_main(argv[1], argv[2], argv[3])
    parser = argparse.ArgumentParser(prog='python -m cvj_ros.nodes.roundtrip')
    parser.add_argument('--n', type=int, default=2000, help='round trips per measurement')
    args = parser.parse_args(argv)
    for name in EXECUTORS:
        print('in-process', name, measure_round_trip(args.n, name))  # type: ignore[arg-type]
        for k in (1, 2):
            print(f'inter-process x{k}', name, measure_round_trip_ipc(args.n, name, echoes=k))  # type: ignore[arg-type]
    return 0


if __name__ == '__main__':
    sys.exit(main())
