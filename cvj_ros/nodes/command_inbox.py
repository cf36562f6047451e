"""What the coupling node receives on the command topics, and when it acts on it.

With a :class:`~cvj_ros.nodes.command_plan.CommandPlan` (a driver plays the scene's
schedule) the samples of step k are awaited: :meth:`CommandInbox.ready` is False until each
channel has delivered its step-k samples (per publisher in order), :meth:`CommandInbox.take`
consumes them and checks them against the plan. Without a plan (an outside stack sends the
commands) every valid sample is kept as its channel's latest value and taken at the next
exchange step the node integrates (``ready`` is always True). A sample that does not decode
is malformed (dropped, named once per topic by the node); one out of range is refused.
"""
from __future__ import annotations

from collections import deque

from cvj_ros.nodes.command_plan import (CHANNEL_TOPICS, CommandError, CommandPlan,
                                        check_command, decode_command)

__all__ = ['CommandInbox']


class CommandInbox:
    """Command samples per channel; see the module docstring."""

    def __init__(self, plan: CommandPlan | None, *, n_gears: int | None = None) -> None:
        self.plan = plan
        self.n_gears = n_gears
        self.queues: dict[str, deque[float]] = {c: deque() for c in CHANNEL_TOPICS}
        self.latest: dict[str, float] = {}
        self.received = {c: 0 for c in CHANNEL_TOPICS}
        self.refused = {c: 0 for c in CHANNEL_TOPICS}

    def offer(self, channel: str, data: bytes) -> float:
        """A serialised sample of ``channel``: its value, kept; CommandError (``malformed``
        or out of range) otherwise, nothing kept."""
        try:
            value = check_command(channel, decode_command(channel, data), self.n_gears)
        except CommandError as exc:
            if not exc.malformed:
                self.refused[channel] += 1
            raise
        self.received[channel] += 1
        if self.plan is None:
            self.latest[channel] = value
        else:
            self.queues[channel].append(value)
        return value

    def ready(self, k: int) -> bool:
        """Every sample of step k is in (always True without a plan)."""
        if self.plan is None:
            return True
        need: dict[str, int] = {}
        for c, _v in self.plan.at(k):
            need[c] = need.get(c, 0) + 1
        return all(len(self.queues[c]) >= n for c, n in need.items())

    def missing(self, k: int) -> list[str]:
        """Topics whose step-k samples are not all in."""
        if self.plan is None:
            return []
        return [CHANNEL_TOPICS[c] for c, _v in self.plan.at(k) if not self.queues[c]]

    def take(self, k: int) -> dict[str, float]:
        """The commands to put in force at step k (channel -> value; only those sent). With a
        plan: the step's samples, CommandError when one differs from the plan (the driver
        plays another schedule)."""
        if self.plan is None:
            out, self.latest = self.latest, {}
            return out
        out: dict[str, float] = {}
        for c, v in self.plan.at(k):
            got = self.queues[c].popleft()
            if got != v:
                raise CommandError(f'{CHANNEL_TOPICS[c]}: step {k} carried {got:g}, the scene\'s '
                                   f'schedule says {v:g}: the driver plays another schedule',
                                   malformed=False)
            out[c] = got
        return out
