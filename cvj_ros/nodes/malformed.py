"""Malformed input messages: dropped, counted per topic, the first one per topic named in one
WARN line (docs/robustness.md, "Hostile peers").

A node's raw subscription callback decodes with the checked readers of
:mod:`cvj_ros.nodes.cdr`; what they refuse (:class:`~cvj_ros.nodes.cdr.CdrError`: not CDR,
cut short, oversized, a length pointing outside the message) or what lacks the names the
node needs goes to :meth:`MalformedInputs.drop` instead of into the node.
"""
from __future__ import annotations

from typing import Any

__all__ = ['MALFORMED_KEY', 'MalformedInputs']

#: the diagnostics / loop-statistics key of the total count
MALFORMED_KEY = 'malformed_messages'


class MalformedInputs:
    """Per-topic counts of dropped input messages; ``drop(topic, reason)`` logs the first
    one of each topic as ``<topic>: malformed message dropped (<reason>); ...`` (WARN) and
    returns that line (None for later ones, which are only counted)."""

    def __init__(self, logger: Any) -> None:
        self.logger = logger
        self.counts: dict[str, int] = {}

    @property
    def total(self) -> int:
        return sum(self.counts.values())

    def drop(self, topic: str, reason: str) -> str | None:
        n = self.counts.get(topic, 0) + 1
        self.counts[topic] = n
        if n > 1:
            return None
        line = (f'{topic}: malformed message dropped ({reason}); further ones are counted '
                f'as {MALFORMED_KEY}')
        self.logger.warning(line)
        return line
