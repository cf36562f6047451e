"""Measure the rclpy publish -> callback -> publish -> callback round trip.

Two nodes in one process and one executor: ``ping`` publishes a Float64 on a private
topic, ``pong`` answers it in its callback on a second topic, and ``ping``'s callback
records the elapsed wall time and publishes the next ping. This is exactly the message
path of one lockstep exchange (joint state out, wrench back), minus the physics, so it
is the floor the lockstep overhead per exchange is judged against (DESIGN.md sec. 3).
"""
from __future__ import annotations

import os
import time
from typing import Literal

import numpy as np

EXECUTORS = ('events', 'single')


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
    us = samples[warmup:] * 1e6
    return {'us_mean': float(us.mean()), 'us_p50': float(np.percentile(us, 50)),
            'us_p95': float(np.percentile(us, 95)), 'n': n, 'executor': executor}


if __name__ == '__main__':
    for name in EXECUTORS:
        print(name, measure_round_trip(2000, name))


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
