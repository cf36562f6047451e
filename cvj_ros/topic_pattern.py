"""Glob patterns over ROS topic names, read one name segment at a time.

A pattern is split at ``/`` like the topic; each segment matches one topic segment with the
shell wildcards of :func:`fnmatch.fnmatchcase` (``*`` any characters, ``?`` one, ``[...]``
a set), which therefore never cross a ``/``: ``/coupling/*/wrench`` matches
``/coupling/tripod/wrench`` but not ``/coupling/a/b/wrench``. A segment that is exactly
``**`` matches zero or more whole segments (``/coupling/**/wrench`` matches both), as in
gitignore and zsh.

:func:`topic_match` is the whole-name match (the contract's pattern topics).
:func:`topic_selected` is the match of a user's topic selection (``--topics``,
``read_bag(path, topics)``): a pattern also selects every topic under a namespace it
matches, as a gitignore pattern naming a directory covers its files (``/coupling/*``
selects ``/coupling/tripod/wrench``, ``/load/*`` both ``/load/wrench`` and
``/load/front_left/wrench``).
"""
from __future__ import annotations

import functools
from fnmatch import fnmatchcase

__all__ = ['topic_match', 'topic_selected']


@functools.lru_cache(maxsize=4096)
def _segments_match(topic: tuple[str, ...], pattern: tuple[str, ...]) -> bool:
    if not pattern:
        return not topic
    head, rest = pattern[0], pattern[1:]
    if head == '**':
        return any(_segments_match(topic[i:], rest) for i in range(len(topic) + 1))
    return bool(topic) and fnmatchcase(topic[0], head) and _segments_match(topic[1:], rest)


def topic_match(topic: str, pattern: str) -> bool:
    """Whether the whole topic name matches the pattern, segment by segment (module
    docstring: ``*``, ``?`` and ``[...]`` stay inside a segment, a ``**`` segment spans any
    number of them)."""
    return _segments_match(tuple(topic.split('/')), tuple(pattern.split('/')))


def topic_selected(topic: str, pattern: str) -> bool:
    """Whether a topic selection pattern takes this topic: it matches the name
    (:func:`topic_match`) or one of the namespaces the topic lies under (``/a`` and ``/a/b``
    for ``/a/b/c``)."""
    parts = topic.split('/')
    pat = tuple(pattern.split('/'))
    return any(_segments_match(tuple(parts[:i]), pat) for i in range(2, len(parts) + 1))
