"""Executor plumbing: CvjNode base, executors, spin loop, run_node main wrapper, publisher flush.

Moved out of nodes/common.py (layout split); common.py re-exports these names.
"""

import sys
import time
from collections.abc import Callable, Sequence
from typing import Any

import rclpy
from rclpy.context import Context
from rclpy.node import Node

from cvj_ros.errors import CvjError, StartCancelled

from cvj_ros.nodes.parameters import EXIT_OK, EXIT_PARAMETER, EXIT_RUNTIME

class CvjNode(Node):
    """Node with an exit status: ``exit_code`` stays ``None`` while the node should keep running."""

    def __init__(self, name: str, **kwargs: Any) -> None:
        super().__init__(name, **kwargs)
        from rclpy.task import Future
        self.exit_code: int | None = None
        self.error_message: str | None = None
        # completed when exit_code is set: lets executors spin without polling
        self.done = Future()
        from cvj_ros.nodes.diagnostics import diagnostic_array_encoder
        diagnostic_array_encoder()       # /diagnostics as CDR: built now, not inside the loop

    def fail(self, message: str, *, code: int = EXIT_RUNTIME) -> None:
        """Log one ERROR line and ask the main loop to exit with ``code``."""
        if self.exit_code is None:
            self.error_message = message
            self.get_logger().error(message)
            self.exit_code = code
            self.done.set_result(code)

    def finish(self) -> None:
        if self.exit_code is None:
            self.exit_code = EXIT_OK
            self.done.set_result(EXIT_OK)


def make_executor(kind: str, context: Context) -> Any:
    """'events' -> rclpy.experimental.EventsExecutor (about 8x faster round trip here),
    'single' -> SingleThreadedExecutor."""
    if kind == 'events':
        from rclpy.experimental import EventsExecutor
        return EventsExecutor(context=context)
    from rclpy.executors import SingleThreadedExecutor
    return SingleThreadedExecutor(context=context)


def freeze_heap() -> None:
    """Exempt every object that exists now from Python's cyclic garbage collector
    (``gc.freeze``), called once the nodes are built and before the loop spins.

    Why: a node process holds ~10^6 long-lived objects (rclpy, numba, numpy, the rosbags
    type store) and the loop allocates steadily (message tuples, batches), so the collector
    ran full (generation 2) passes over all of them during runs - measured with gc
    callbacks in composed fwd_halfshaft 5 s runs: one pass of 85-99 ms inside the loop and
    101-114 ms of collection in the loop in all; after ``freeze`` no generation-2 pass and
    14-17 ms. Reference cycles among the
    frozen objects are never collected (they live for the process anyway)."""
    import gc
    gc.freeze()


def spin_until_done(node: CvjNode, executor: Any, *, timeout: float | None = None,
                    poll: float = 0.2) -> int | None:
    """Spin until ``node.exit_code`` is set, the context shuts down or ``timeout`` (s) passes."""
    import time
    deadline = None if timeout is None else time.monotonic() + timeout
    ctx = node.context
    while node.exit_code is None and ctx.ok():
        executor.spin_until_future_complete(node.done, timeout_sec=poll)
        if deadline is not None and time.monotonic() > deadline:
            break
    return node.exit_code


def run_node(factory: Callable[..., CvjNode], args: Sequence[str] | None, *, prog: str,
             executor: str = 'events') -> int:
    """Create the node, spin it until it finishes; returns the process exit status.

    0: finished (or stopped by Ctrl-C / SIGTERM), 1: runtime error, 2: bad parameter or
    scene (one line ``<prog>: error: <parameter>: <problem>`` on stderr, no traceback).
    Anything unexpected: one line and exit 1 (:func:`cvj_ros.guard.guarded`; the traceback
    with CVJ_DEBUG=1).
    """
    from cvj_ros.guard import guarded
    return int(guarded(prog, lambda: _run_node(factory, args, prog=prog, executor=executor)))


#: the SIGINT/SIGTERM :func:`run_node`'s handler caught in this process (0: none yet)
_STOP = {'signal': 0}


def stop_requested() -> int:
    """The signal number (SIGINT/SIGTERM) :func:`run_node` caught since it started, else 0:
    for code that blocks before the node spins (the coupling node's start gate), which the
    handler does not interrupt."""
    return _STOP['signal']


def _run_node(factory: Callable[..., CvjNode], args: Sequence[str] | None, *, prog: str,
              executor: str = 'events') -> int:
    """:func:`run_node` without the guard."""
    import signal

    from rclpy.executors import ExternalShutdownException
    from rclpy.signals import SignalHandlerOptions

    from cvj_ros.nodes.qos import domain_id, node_dds_defaults
    domain_id()             # a bad ROS_DOMAIN_ID: one line, before DDS logs its own
    node_dds_defaults()     # a hand-started node: `cvj-sim run`'s delivery settings
    ctx = Context()
    # Own SIGINT/SIGTERM handling: finish the spin loop cleanly and exit 0.
    rclpy.init(args=list(args) if args is not None else None, context=ctx,
               signal_handler_options=SignalHandlerOptions.NO)
    stop = _STOP
    stop['signal'] = 0

    def on_signal(signum: int, _frame: Any) -> None:
        stop['signal'] = signum

    previous = {sig: signal.signal(sig, on_signal) for sig in (signal.SIGINT, signal.SIGTERM)}
    node = None
    try:
        try:
            node = factory(context=ctx)
        except StartCancelled as exc:     # told to wait for a start signal that never came
            print(f'{prog}: {exc}', file=sys.stderr)
            return EXIT_OK
        except CvjError as exc:
            print(f'{prog}: error: {exc}', file=sys.stderr)
            return EXIT_PARAMETER
        ex = make_executor(executor, ctx)
        ex.add_node(node)
        freeze_heap()
        try:
            # Spin inside the executor until the node is done (no per-event Python loop:
            # about 4x less overhead per lockstep exchange than spin_once); wake every
            # 0.25 s to honour SIGINT/SIGTERM.
            while node.exit_code is None and ctx.ok() and not stop['signal']:
                ex.spin_until_future_complete(node.done, timeout_sec=0.25)
        except (KeyboardInterrupt, ExternalShutdownException):
            return EXIT_OK
        finally:
            ex.shutdown()
        if stop['signal']:
            return EXIT_OK
        code = node.exit_code  # a runtime error was already logged as one ERROR line
        return EXIT_OK if code is None else code
    finally:
        stop['signal'] = 0     # not seen by a later node of this process (tests, composed)
        if node is not None:
            if ctx.ok():
                flush_publishers(node)
            node.destroy_node()
        if ctx.ok():
            rclpy.shutdown(context=ctx)
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def flush_publishers(node: Node, *, budget_s: float = 1.0) -> None:
    """Wait (at most ``budget_s`` s in total) until every data publisher's samples are
    acknowledged by all reliable subscribers, so the last messages of a run (final joint
    state, last answers) reach the recorder before the node is destroyed. Measured: up to
    23 of 201 final joint states were lost without it; the wait ends within 0-25 ms with
    a 20 ms heartbeat. /diagnostics first (a failing node's last word, its ERROR, is one
    message, and a frozen peer - a reliable joint-state reader that cannot acknowledge - would
    otherwise take the whole budget in the joint states' wait before it), then joint states,
    /clock last."""
    from rclpy.duration import Duration
    deadline = time.monotonic() + budget_s
    order = {'/diagnostics': -1, '/driveline/joint_states': 0, '/clock': 2}
    for pub in sorted(node.publishers, key=lambda p: order.get(p.topic_name, 1)):
        if pub.topic_name in ('/rosout', '/parameter_events'):
            continue
        try:
            pub.wait_for_all_acked(Duration(seconds=max(0.0, deadline - time.monotonic())))
        except Exception:  # noqa: BLE001 (context already shut down)
            pass


# --- torque responders (engine_node, load_node) ----------------------------------------------
