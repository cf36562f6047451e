"""Reading user text files (scenes, YAML) so that any bytes give one clear error line.

:func:`read_text_file` reads at most :data:`MAX_TEXT_BYTES` and rejects binary files, UTF-16 /
UTF-32 text and bytes that are not UTF-8, naming the file and the place.
:func:`load_yaml_bounded` parses YAML with PyYAML's safe loader but rejects nesting deeper
than :data:`MAX_YAML_DEPTH` (PyYAML's composer recurses once per level: 10^4 levels of
``[[[...`` raised RecursionError) and documents whose aliases expand to more than
:data:`MAX_YAML_NODES` nodes (the "billion laughs" alias bomb: 9 levels of 10 aliases is
1e9 nodes for every recursive walk over the result).
Both raise ``error(field, message)`` (by default :class:`~cvj_ros.errors.SceneError`).
"""
from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

from cvj_ros.errors import CvjError, SceneError

# 1 MiB: the largest shipped scene is 2.6 kB; a time series belongs in a data file (load.file).
MAX_TEXT_BYTES = 1 << 20
# Scene files are at most ~5 levels deep (driveline[i].params.x, load.series.t).
MAX_YAML_DEPTH = 64
# Expanded node count (every alias counted as a full copy); a shipped scene has < 300.
MAX_YAML_NODES = 100_000

ErrorFactory = Callable[[str, str], CvjError]

_BOMS = ((b'\x00\x00\xfe\xff', 'UTF-32'), (b'\xff\xfe\x00\x00', 'UTF-32'),
         (b'\xfe\xff', 'UTF-16'), (b'\xff\xfe', 'UTF-16'))


def decode_text(raw: bytes, where: str, *, error: ErrorFactory = SceneError) -> str:
    """``raw`` as UTF-8 text (a UTF-8 byte-order mark is dropped); ``error(where, ...)`` for
    binary data (NUL bytes), UTF-16/32 text and invalid UTF-8 (names line and column)."""
    for bom, name in _BOMS:
        if raw.startswith(bom):
            return _raise(error, where, f'{name} text; cvj_ros reads UTF-8: save the file as UTF-8')
    if raw.startswith(b'\xef\xbb\xbf'):
        raw = raw[3:]
    nul = raw.find(b'\x00')
    if nul >= 0:
        return _raise(error, where, f'binary data (NUL byte at offset {nul}), not a UTF-8 text file')
    try:
        return raw.decode('utf-8')
    except UnicodeDecodeError as exc:
        line = raw.count(b'\n', 0, exc.start) + 1
        col = exc.start - (raw.rfind(b'\n', 0, exc.start) + 1) + 1
        return _raise(error, f'{where}:{line}', f'not UTF-8 text: byte 0x{raw[exc.start]:02x} at '
                                                f'column {col} (latin-1 or another encoding? save the file as UTF-8)')


def read_text_file(path: str | os.PathLike[str], *, what: str = 'scene file',
                   error: ErrorFactory = SceneError, limit: int = MAX_TEXT_BYTES) -> str:
    """Text of ``path`` (UTF-8, at most ``limit`` bytes), or ``error(str(path), ...)``."""
    p = Path(path)
    try:
        with open(p, 'rb') as fh:
            raw = fh.read(limit + 1)    # bounded even for /dev/zero or a pipe
    except OSError as exc:
        return _raise(error, str(p), f'cannot read {what} ({exc.strerror or exc})')
    if len(raw) > limit:
        return _raise(error, str(p), f'{what} larger than {limit // 1024} KiB; not a {what}?')
    return decode_text(raw, str(p), error=error)


def _raise(error: ErrorFactory, where: str, message: str) -> Any:
    raise error(where, message)


def _make_loader() -> type:
    import yaml

    class BoundedSafeLoader(yaml.SafeLoader):
        """SafeLoader whose composer stops at :data:`MAX_YAML_DEPTH` levels."""
        depth = 0

        def compose_node(self, parent: Any, index: Any) -> Any:
            self.depth += 1
            try:
                if self.depth > MAX_YAML_DEPTH:
                    mark = self.peek_event().start_mark
                    raise _TooDeep(mark.line + 1 if mark is not None else None)
                return super().compose_node(parent, index)
            finally:
                self.depth -= 1
    return BoundedSafeLoader


class _TooDeep(Exception):
    def __init__(self, line: int | None) -> None:
        super().__init__(line)
        self.line = line


def _expanded_size_exceeds(node: Any, budget: int) -> bool:
    """True if walking ``node`` with every alias expanded visits more than ``budget`` nodes."""
    import yaml
    stack, seen = [node], 0
    while stack:
        n = stack.pop()
        seen += 1
        if seen > budget:
            return True
        if isinstance(n, yaml.SequenceNode):
            stack.extend(n.value)
        elif isinstance(n, yaml.MappingNode):
            for k, v in n.value:
                stack.append(k)
                stack.append(v)
    return False


def _reject_huge_integers(data: Any, error: ErrorFactory) -> None:
    """``error(<field path>, ...)`` for an integer beyond the float range (|n| >= 2**1024):
    no scene value can be one, and float(n) would raise OverflowError deep in the parser."""
    stack: list[tuple[str, Any]] = [('', data)]
    while stack:
        path, v = stack.pop()
        if isinstance(v, dict):
            stack += [(f'{path}.{k}' if path else str(k), x) for k, x in v.items()]
        elif isinstance(v, list):
            stack += [(f'{path}[{i}]', x) for i, x in enumerate(v)]
        elif isinstance(v, int) and not isinstance(v, bool) and abs(v) >= 2 ** 1024:
            _raise(error, path or '<document>', f'must be a finite number, got an integer of '
                                                f'{len(str(abs(v)))} digits (beyond the float range)')


def load_yaml_bounded(text: str, where: str, *, error: ErrorFactory = SceneError) -> Any:
    """``yaml.safe_load(text)`` with the depth and alias-expansion bounds of this module.

    yaml.YAMLError (malformed YAML) propagates for the caller to name the line; the bounds and
    values PyYAML cannot convert (an integer of more than 4300 digits) raise ``error``."""
    loader = _make_loader()(text)
    try:
        try:
            node = loader.get_single_node()
        except _TooDeep as exc:
            at = f'{where}:{exc.line}' if exc.line else where
            return _raise(error, at, f'YAML nested deeper than {MAX_YAML_DEPTH} levels')
        except RecursionError:
            return _raise(error, where, f'YAML nested deeper than {MAX_YAML_DEPTH} levels')
        if node is None:
            return None
        if _expanded_size_exceeds(node, MAX_YAML_NODES):
            return _raise(error, where, f'YAML aliases expand to more than {MAX_YAML_NODES} values '
                                        '(alias bomb?)')
        try:
            data = loader.construct_document(node)
        except (ValueError, OverflowError, TypeError, RecursionError) as exc:
            return _raise(error, where, f'cannot convert a YAML value: {str(exc).splitlines()[0].split(";")[0]}')
        _reject_huge_integers(data, error)
        return data
    finally:
        loader.dispose()
