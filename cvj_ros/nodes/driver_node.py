"""driver_node: plays a scene's ``commands:`` schedule on the command topics.

On each /clock = t_k (k = t_k / h, the coupling node's exchange steps) it publishes the
channels whose value at step k differs from step k - 1 (all played channels at step 0):
``/engine/throttle``, ``/driveline/clutch``, ``/driveline/brake`` (std_msgs/Float64) and
``/driveline/gear`` (std_msgs/Int8), so the bag of every run carries its commands. The
lockstep rule (when a sample takes effect) is in :mod:`cvj_ros.nodes.command_plan` and
docs/ros.md, "Commands". A vehicle stack replaces this node with ``cvj-sim run --external
driver``.

Run alone: ``driver_node --ros-args -p scene:=launch_clutch_chain`` (waits for /clock).
"""
from __future__ import annotations

import sys
from collections.abc import Sequence
from typing import Any

from rosgraph_msgs.msg import Clock
from std_msgs.msg import Float64, Int8

from cvj_ros.nodes.command_plan import (CHANNEL_TOPICS, CommandError, CommandPlan,
                                        decode_clock_ns)
from cvj_ros.nodes.common import (NS_PER_S, CvjNode, ParameterError, ParamSpec,
                                  declare_parameters, load_scene_param, run_node)
from cvj_ros.nodes.intra import loop_publisher, loop_subscription
from cvj_ros.nodes.malformed import MalformedInputs
from cvj_ros.nodes.qos import CLOCK_TOPIC, DATA_QOS

__all__ = ['DriverNode', 'main']

PARAMS = (
    ParamSpec('scene', '', 'scene name (e.g. launch_clutch_chain) or scene YAML path; its '
              'commands: schedule is played'),
    ParamSpec('seed', -1, 'random seed (unused: a schedule is deterministic; accepted as every '
              'node of a run takes it)', lo=-1, hi=2**31 - 1),
    ParamSpec('exchange_step', 0.0, 'exchange step of the loop [s]; 0 = the scene exchange_step',
              lo=0.0, hi=3600.0),
    ParamSpec('duration', 0.0, 'simulated time to play [s]; 0 = the scene duration',
              lo=0.0, hi=1e9),
)


class DriverNode(CvjNode):
    """Command schedule player (see module docstring). Parameters: :data:`PARAMS`."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__('driver_node', **kwargs)
        p = self.params = declare_parameters(self, PARAMS)
        scene = load_scene_param(p['scene'])
        if not scene.commands:
            raise ParameterError('scene', f'{scene.name}: no commands: schedule to play')
        h = p['exchange_step'] or scene.exchange_step
        self.h_ns = int(round(h * NS_PER_S))
        if self.h_ns <= 0:
            raise ParameterError('exchange_step', f'must be >= 1 ns, got {h}')
        n_steps = int(round((p['duration'] or scene.duration) * NS_PER_S / self.h_ns))
        self.plan = CommandPlan.from_scene(scene, self.h_ns, n_steps)
        self.pubs = {c: loop_publisher(self, Int8 if c == 'gear' else Float64, CHANNEL_TOPICS[c],
                                       DATA_QOS) for c in self.plan.channels}
        self.malformed = MalformedInputs(self.get_logger())
        self.last_k = -1
        self.published = 0
        self.clock_sub = loop_subscription(self, Clock, CLOCK_TOPIC, self._on_clock, DATA_QOS)
        self.get_logger().info(
            f'scene {scene.name!r}: playing {", ".join(self.plan.channels)} '
            f'({sum(len(r) for _k, r in self.plan)} samples over {n_steps} steps of '
            f'{self.h_ns / NS_PER_S:g} s); waiting for /clock')

    def _on_clock(self, data: bytes) -> None:
        """/clock = t_k: publish the samples of every step up to k not yet played."""
        try:
            t_ns = decode_clock_ns(data)
        except CommandError as exc:
            self.malformed.drop(CLOCK_TOPIC, str(exc))
            return
        k = t_ns // self.h_ns
        if t_ns < 0 or t_ns % self.h_ns or k <= self.last_k:
            return          # not an exchange time, or already played
        for j in range(self.last_k + 1, k + 1):
            for channel, value in self.plan.at(j):
                msg = Int8(data=int(value)) if channel == 'gear' else Float64(data=value)
                self.pubs[channel].publish(msg)
                self.published += 1
        self.last_k = k


def main(args: Sequence[str] | None = None) -> None:
    sys.exit(run_node(DriverNode, args, prog='driver_node'))


if __name__ == '__main__':
    main()
