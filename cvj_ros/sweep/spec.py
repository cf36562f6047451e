"""Sweep definitions: ``--set PATH=SPEC`` parsing, field paths, expansion into variants.

A sweep varies fields of a scene file. Each ``--set`` names one field by the dotted path
scene errors print (``driveline[2].params.alpha_deg``, ``initial.speed_rad_s``,
``solver.rtol``, ``load.mean``); an element's name may stand in place of its index
(``driveline[coupling].params.alpha_deg``). SPEC is one of

* ``start:stop:n`` - a grid of n evenly spaced values (``numpy.linspace``), both ends
  included; ``start:stop:n:log`` - n log-spaced values (``numpy.geomspace``);
* ``a,b,c`` - a list (numbers, or words such as ``dopri5,rk4``); a single value fixes
  the field for every variant;
* ``lo:hi`` - a range, only with ``--samples N``: seeded uniform random sampling
  (``numpy.random.default_rng(seed)``); ``lo:hi:log`` samples log-uniformly.

Grid axes combine as a Cartesian product, the first ``--set`` varying slowest (nested
loops in the order given). With ``--samples N`` every range is sampled N times, lists are
drawn uniformly from their values and single values stay fixed. Variants are numbered
0..n-1 in that order; the number is the row of the result table.

Every variant is validated by :func:`cvj_ros.physics.scene.parse_scene`, so a bad
value is reported with the scene's field path. Errors in the specs themselves raise
:class:`SweepError` naming the ``--set`` and the field (the CLI prints one line, exit 2).
"""
from __future__ import annotations

import copy
import itertools
import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from cvj_ros.errors import CvjError, SceneError

Value = float | int | str
# token of a path: a key, or [index] / [name] after a key
_TOKEN = re.compile(r'([A-Za-z_][A-Za-z0-9_]*)|\[([^\]]*)\]|(\.)')
MAX_VARIANTS = 10_000_000      # guard against a typo such as 0:1:1e9 filling the memory


class SweepError(CvjError, ValueError):
    """A sweep definition error (a --set, --samples, an output directory)."""


@dataclass(frozen=True)
class Axis:
    """One ``--set``: the field ``path`` (as the user wrote it), its canonical index form
    ``field`` (as scene errors print it), and either grid ``values`` or a random ``range``."""

    text: str                          # the --set argument as given
    path: str                          # as written (names allowed)
    field: str                         # canonical: indices only, as scene errors print
    keys: tuple[str | int, ...]        # resolved keys into the scene dict
    values: tuple[Value, ...] = ()     # grid / list / single value
    range: tuple[float, float] | None = None   # random sampling range (lo, hi)
    log: bool = False                  # log spacing / log-uniform sampling

    @property
    def column(self) -> str:
        """Column name of this axis in results.csv (the path as the user wrote it)."""
        return self.path


@dataclass(frozen=True)
class Sweep:
    """An expanded sweep: the base scene dict and the variants' field assignments."""

    base: Mapping[str, Any]
    axes: tuple[Axis, ...]
    variants: tuple[tuple[Value, ...], ...]     # one value per axis, in axis order
    samples: int | None = None
    seed: int = 0
    definition: Mapping[str, Any] = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.variants)

    def scene_dict(self, index: int) -> dict[str, Any]:
        """The scene dict of variant ``index`` (a deep copy of the base with its values)."""
        return apply(self.base, self.axes, self.variants[index])


# --- values ------------------------------------------------------------------------------

def parse_value(token: str) -> Value:
    """``'3'`` -> 3, ``'1e-6'`` -> 1e-06, ``'dopri5'`` -> 'dopri5' (int, then float, else word).
    YAML would read ``1e-6`` as a string; this does not."""
    t = token.strip()
    try:
        return int(t)
    except ValueError:
        pass
    try:
        return float(t)
    except ValueError:
        return t


def _number(token: str, where: str) -> float:
    v = parse_value(token)
    if isinstance(v, str) or not math.isfinite(float(v)):
        raise SweepError(f'{where}: expected a finite number, got {token.strip()!r}')
    return float(v)


def parse_spec(text: str, where: str, *, random: bool) -> tuple[tuple[Value, ...], tuple[float, float] | None, bool]:
    """SPEC -> (values, range, log). ``where`` prefixes errors (``--set PATH=SPEC``)."""
    s = text.strip()
    if not s:
        raise SweepError(f'{where}: empty value; give start:stop:n, a,b,c or a value')
    if ':' in s:
        parts = [p.strip() for p in s.split(':')]
        log = bool(parts) and parts[-1].lower() == 'log'
        if log:
            parts = parts[:-1]
        if len(parts) == 2:
            if not random:
                raise SweepError(f'{where}: a range lo:hi needs --samples N (random sampling); '
                                 f'for a grid give start:stop:n')
            lo, hi = _number(parts[0], where), _number(parts[1], where)
            if not lo < hi:
                raise SweepError(f'{where}: range needs lo < hi, got {lo:g}:{hi:g}')
            if log and lo <= 0:
                raise SweepError(f'{where}: a log range needs lo > 0, got {lo:g}')
            return (), (lo, hi), log
        if len(parts) != 3:
            raise SweepError(f'{where}: expected start:stop:n (grid) or lo:hi (with --samples), '
                             f'optionally :log, got {s!r}')
        start, stop = _number(parts[0], where), _number(parts[1], where)
        n_val = parse_value(parts[2])
        if not isinstance(n_val, int) or n_val < 1:
            raise SweepError(f'{where}: n must be an integer >= 1, got {parts[2]!r}')
        if n_val > MAX_VARIANTS:
            raise SweepError(f'{where}: n must be <= {MAX_VARIANTS}, got {n_val}')
        if log and (start <= 0 or stop <= 0):
            raise SweepError(f'{where}: a log grid needs start, stop > 0')
        grid = np.geomspace(start, stop, n_val) if log else np.linspace(start, stop, n_val)
        return tuple(float(v) for v in grid), None, log
    items = [p.strip() for p in s.split(',')]
    if any(not p for p in items):
        raise SweepError(f'{where}: empty item in list {s!r}')
    values: list[Value] = []
    for p in items:
        v = parse_value(p)
        if isinstance(v, float) and not math.isfinite(v):
            raise SweepError(f'{where}: {p!r} is not finite')
        values.append(v)
    return tuple(values), None, False


# --- paths -------------------------------------------------------------------------------

def parse_path(path: str, where: str) -> list[str | tuple[str]]:
    """``driveline[coupling].params.alpha_deg`` -> ['driveline', ('coupling',), 'params',
    'alpha_deg'] (a bracketed token is a 1-tuple: index or element name)."""
    out: list[str | tuple[str]] = []
    pos = 0
    expect_key = True
    while pos < len(path):
        m = _TOKEN.match(path, pos)
        if m is None:
            raise SweepError(f'{where}: cannot read the field path {path!r} at {path[pos:]!r}; '
                             f'write it as scene errors print it, e.g. driveline[2].params.beta_deg')
        key, bracket, dot = m.groups()
        if dot:
            if expect_key:
                raise SweepError(f'{where}: empty key in field path {path!r}')
            expect_key = True
        elif key is not None:
            if not expect_key:
                raise SweepError(f'{where}: missing "." before {key!r} in field path {path!r}')
            out.append(key)
            expect_key = False
        else:
            if not out or expect_key:
                raise SweepError(f'{where}: [..] must follow a key in field path {path!r}')
            if not bracket.strip():
                raise SweepError(f'{where}: empty [] in field path {path!r}')
            out.append((bracket.strip(),))
        pos = m.end()
    if not out or expect_key:
        raise SweepError(f'{where}: incomplete field path {path!r}')
    return out


def resolve_path(base: Mapping[str, Any], path: str, where: str) -> tuple[tuple[str | int, ...], str]:
    """Resolve ``path`` in the scene dict ``base``: (keys, canonical field path). Names in
    brackets become indices; every container on the way must exist. The last key may be
    new (e.g. a spring's ``damping``): parse_scene decides whether it is allowed."""
    tokens = parse_path(path, where)
    keys: list[str | int] = []
    canon = ''
    node: Any = base
    for i, tok in enumerate(tokens):
        last = i == len(tokens) - 1
        if isinstance(tok, tuple):
            label = tok[0]
            if not isinstance(node, list):
                raise SweepError(f'{where}: {canon} is not a list, so [{label}] does not apply')
            if re.fullmatch(r'-?\d+', label):
                idx = int(label)
                if not 0 <= idx < len(node):
                    raise SweepError(f'{where}: {canon}[{idx}] out of range ({canon} has '
                                     f'{len(node)} entries)')
            else:
                names = [e.get('name') if isinstance(e, Mapping) else None for e in node]
                if label not in names:
                    known = ', '.join(str(n) for n in names if n is not None) or 'none named'
                    raise SweepError(f'{where}: {canon} has no element named {label!r} ({known})')
                idx = names.index(label)
            keys.append(idx)
            canon = f'{canon}[{idx}]'
            node = node[idx]
        else:
            canon = f'{canon}.{tok}' if canon else tok
            if not isinstance(node, Mapping):
                raise SweepError(f'{where}: {canon.rsplit(".", 1)[0]} is not a mapping')
            keys.append(tok)
            if tok in node:
                node = node[tok]
            elif last:
                node = None
            elif tokens[i + 1] and isinstance(tokens[i + 1], str):
                node = {}           # e.g. solver.rtol when the scene has no solver block
            else:
                raise SweepError(f'{where}: {canon} is not in the scene, so it has no entries')
    return tuple(keys), canon


def apply(base: Mapping[str, Any], axes: Sequence[Axis], values: Sequence[Value]) -> dict[str, Any]:
    """Deep copy of ``base`` with ``values[i]`` stored at ``axes[i].keys``."""
    return apply_keys(base, [a.keys for a in axes], values)


def apply_keys(base: Mapping[str, Any], keys: Sequence[Sequence[str | int]],
               values: Sequence[Any]) -> dict[str, Any]:
    """Deep copy of ``base`` with ``values[i]`` stored at the resolved ``keys[i]``."""
    d = copy.deepcopy(dict(base))
    for path, value in zip(keys, values):
        node: Any = d
        for k in path[:-1]:
            if isinstance(k, str) and (k not in node or node[k] is None):
                node[k] = {}
            node = node[k]
        node[path[-1]] = value
    return d


# --- a whole sweep -----------------------------------------------------------------------

def _probe(base: Mapping[str, Any], axis: Axis) -> None:
    """Reject an axis no variant could use: a field the scene format does not have (unknown
    key or parameter at the axis's own path), or one whose extreme values (first and last,
    or lo and hi) both make the scene invalid on their own (e.g. ``initial.speed_rad_s`` in a
    scene that gives ``speed_rpm``). Other errors belong to single variants."""
    from cvj_ros.physics.scene import parse_scene
    tried = list(dict.fromkeys(axis.values[:1] + axis.values[-1:])) if axis.values else \
        list(axis.range or ())
    errors: list[str] = []
    for value in tried:
        try:
            parse_scene(apply(base, [axis], [value]))
        except SceneError as exc:
            msg = str(exc)[len(exc.field) + 2:]
            if exc.field == axis.field and msg.startswith('unknown'):
                raise SweepError(f'--set {axis.path}: {axis.field}: {msg}') from None
            errors.append(' '.join(str(exc).split()))
        except CvjError as exc:
            errors.append(' '.join(str(exc).split()))
    if errors and len(errors) == len(tried):
        shown = ', '.join(str(v) for v in tried)
        raise SweepError(f'--set {axis.path}: every value tried ({shown}) makes the scene '
                         f'invalid: {errors[0]}')


def build_sweep(base: Mapping[str, Any], sets: Sequence[str], *, samples: int | None = None,
                seed: int = 0) -> Sweep:
    """Parse the ``--set`` arguments against the scene dict ``base`` and expand them."""
    if not sets:
        raise SweepError('--set: give at least one PATH=SPEC (e.g. --set initial.speed_rad_s=30:60:4)')
    if samples is not None and (isinstance(samples, bool) or samples < 1 or samples > MAX_VARIANTS):
        raise SweepError(f'--samples: must be an integer in 1..{MAX_VARIANTS}, got {samples}')
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise SweepError(f'--seed: must be a non-negative integer, got {seed!r}')
    axes: list[Axis] = []
    seen: dict[str, str] = {}
    for text in sets:
        path, sep, spec = text.partition('=')
        path = path.strip()
        where = f'--set {path or text}'
        if not sep or not path:
            raise SweepError(f'--set {text!r}: expected PATH=SPEC, e.g. '
                             f"'driveline[coupling].params.alpha_deg=5:25:5'")
        keys, canon = resolve_path(base, path, where)
        if canon in seen:
            raise SweepError(f'{where}: {canon} is already set by --set {seen[canon]}')
        seen[canon] = path
        values, rng, log = parse_spec(spec, where, random=samples is not None)
        axis = Axis(text=text, path=path, field=canon, keys=keys, values=values, range=rng, log=log)
        _probe(base, axis)
        axes.append(axis)
    if samples is None:
        count = math.prod(len(a.values) for a in axes)
        if count > MAX_VARIANTS:
            raise SweepError(f'--set: the grid has {count} variants, more than {MAX_VARIANTS}')
        variants = tuple(itertools.product(*(a.values for a in axes)))
    else:
        rng_gen = np.random.default_rng(seed)
        cols: list[list[Value]] = []
        for a in axes:
            if a.range is not None:
                lo, hi = a.range
                if a.log:
                    u = rng_gen.uniform(math.log(lo), math.log(hi), samples)
                    cols.append([float(v) for v in np.exp(u)])
                else:
                    cols.append([float(v) for v in rng_gen.uniform(lo, hi, samples)])
            elif len(a.values) > 1:
                idx = rng_gen.integers(0, len(a.values), samples)
                cols.append([a.values[int(i)] for i in idx])
            else:
                cols.append([a.values[0]] * samples)
        variants = tuple(zip(*cols))
    definition = {'sets': [a.text for a in axes], 'samples': samples,
                  'seed': seed if samples is not None else None,
                  'axes': [{'path': a.path, 'field': a.field,
                            'values': list(a.values) if a.range is None else None,
                            'range': list(a.range) if a.range is not None else None,
                            'log': a.log} for a in axes]}
    return Sweep(base=copy.deepcopy(dict(base)), axes=tuple(axes), variants=variants,
                 samples=samples, seed=seed, definition=definition)
