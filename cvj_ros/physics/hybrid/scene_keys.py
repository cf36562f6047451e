"""Scene-file keys of the mode elements (``clutch``, ``gearbox``, ``brake``) and of the
``commands:`` schedule; errors name the field path (docs/clutch_gearbox.md, "Scene keys").
Uses the scene module's field checks so messages read alike."""
from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

from cvj_ros.errors import SceneError
from cvj_ros.physics.hybrid.commands import CHANNELS, CommandSchedule
from cvj_ros.physics.hybrid.elements import Brake, Clutch, Gearbox, ModeElement
from cvj_ros.physics.hybrid.friction import CoulombPack
from cvj_ros.physics.scene import _check_keys, _mapping, _number

__all__ = ['BRAKE_KEYS', 'CLUTCH_KEYS', 'DENSE_METHODS', 'GEARBOX_KEYS', 'MODE_TYPES',
           'check_mode_scene', 'mode_element', 'mode_gap',
           'mode_element_dict', 'parse_commands']

MODE_TYPES = ('clutch', 'gearbox', 'brake')
#: steppers with an error-controlled step and dense output (the events need both)
DENSE_METHODS = ('dopri5', 'dop853', 'rosenbrock', 'rodas4', 'rodas3', 'tsit5', 'vern6', 'vern7',
                 'vern8')
PACK_KEYS = ('mu_static', 'mu_kinetic', 'cgeo_m', 'normal_force_max')
CLUTCH_KEYS = ('type', 'name', 'J_input', 'J_output') + PACK_KEYS
GEARBOX_KEYS = ('type', 'name', 'J_input', 'J_output', 'ratios', 'reverse_ratio', 'max_input_rpm')
BRAKE_KEYS = ('type', 'name') + PACK_KEYS


def _required(el: Mapping[str, Any], key: str, path: str, unit: str) -> Any:
    if key not in el:
        raise SceneError(f'{path}.{key}', f'missing ({unit})')
    return el[key]


def _pack(el: Mapping[str, Any], path: str) -> CoulombPack:
    mu_k = _number(_required(el, 'mu_kinetic', path, '-'), f'{path}.mu_kinetic', positive=True, hi=10.0)
    mu_s = _number(_required(el, 'mu_static', path, '-'), f'{path}.mu_static', positive=True, hi=10.0)
    if mu_s < mu_k:
        raise SceneError(f'{path}.mu_static', f'must be >= mu_kinetic ({mu_k}), got {mu_s}')
    return CoulombPack(mu_s=mu_s, mu_k=mu_k,
                       cgeo=_number(_required(el, 'cgeo_m', path, 'm'), f'{path}.cgeo_m',
                                    positive=True, hi=100.0),
                       fn_max=_number(_required(el, 'normal_force_max', path, 'N'),
                                      f'{path}.normal_force_max', positive=True, hi=1e9))


def mode_element(etype: str, el: Mapping[str, Any], name: str, path: str) -> ModeElement:
    """A Clutch, Gearbox or Brake from its scene mapping (SceneError naming the field)."""
    if etype == 'brake':
        _check_keys(el, BRAKE_KEYS, path)
        return Brake(name, _pack(el, path))
    j_in = _number(_required(el, 'J_input', path, 'kg m^2'), f'{path}.J_input', positive=True)
    j_out = _number(_required(el, 'J_output', path, 'kg m^2'), f'{path}.J_output', positive=True)
    if etype == 'clutch':
        _check_keys(el, CLUTCH_KEYS, path)
        return Clutch(name, j_in, j_out, _pack(el, path))
    _check_keys(el, GEARBOX_KEYS, path)
    raw = _required(el, 'ratios', path, 'list of omega_in / omega_out, 1st gear first')
    if not isinstance(raw, list) or not raw or len(raw) > 32:
        raise SceneError(f'{path}.ratios', f'must be a list of 1..32 ratios, got {raw!r}'[:200])
    ratios = tuple(_number(r, f'{path}.ratios[{k}]', positive=True, lo=1e-3, hi=1e3)
                   for k, r in enumerate(raw))
    rev = _number(_required(el, 'reverse_ratio', path, 'omega_in / omega_out, < 0'),
                  f'{path}.reverse_ratio', lo=-1e3, hi=-1e-3)
    rpm = _number(_required(el, 'max_input_rpm', path, 'rpm: a gear that would turn the input '
                                                      'faster is refused'),
                  f'{path}.max_input_rpm', positive=True, hi=1e6)
    return Gearbox(name, j_in, j_out, ratios, rev, rpm * math.pi / 30.0)


def mode_element_dict(el: ModeElement) -> dict[str, Any]:
    """Scene-file form of a mode element (inverse of :func:`mode_element`)."""
    d: dict[str, Any] = {'type': el.type, 'name': el.name}
    if isinstance(el, (Clutch, Gearbox)):
        d['J_input'], d['J_output'] = el.J_input, el.J_output
    if isinstance(el, Gearbox):
        d['ratios'] = list(el.ratios)
        d['reverse_ratio'] = el.reverse_ratio
        d['max_input_rpm'] = el.max_input_speed * 30.0 / math.pi
    else:
        p = el.pack
        d.update(mu_static=p.mu_s, mu_kinetic=p.mu_k, cgeo_m=p.cgeo, normal_force_max=p.fn_max)
    return d


def parse_commands(raw: Any, chain: Sequence[Any]) -> tuple[dict[str, float], ...]:
    """Validate ``commands:`` (rows ``{t: s, throttle|clutch|gear|brake: value}``) against the
    driveline's elements; returns the rows as plain dicts."""
    if not isinstance(raw, list):
        raise SceneError('commands', f'must be a list of rows {{t: ..., {": ..., ".join(CHANNELS)}: ...}}')
    if len(raw) > 100000:
        raise SceneError('commands', f'at most 100000 rows, got {len(raw)}')
    types = {getattr(el, 'type', '') for el in chain}
    gearbox = next((el for el in chain if isinstance(el, Gearbox)), None)
    rows: list[dict[str, float]] = []
    for i, r in enumerate(raw):
        row = _mapping(r, f'commands[{i}]')
        _check_keys(row, ('t',) + CHANNELS, f'commands[{i}]')
        if 't' not in row:
            raise SceneError(f'commands[{i}].t', 'missing (s)')
        for ch, need in (('clutch', 'clutch'), ('gear', 'gearbox'), ('brake', 'brake')):
            if ch in row and need not in types:
                raise SceneError(f'commands[{i}].{ch}', f'the driveline has no {need}')
        rows.append(dict(row))
    CommandSchedule([(r['t'], {k: v for k, v in r.items() if k != 't'}) for r in rows])
    if gearbox is not None:
        for i, r in enumerate(rows):
            if 'gear' in r and not gearbox.valid_gear(int(r['gear'])):
                raise SceneError(f'commands[{i}].gear', f'{gearbox.name} has gears -1 (reverse), '
                                 f'0 (neutral), 1..{len(gearbox.ratios)}; got {r["gear"]}')
    return tuple({k: (int(v) if k == 'gear' else float(v)) for k, v in r.items()} for r in rows)


def mode_gap(scene: Any) -> tuple[str, str]:
    """(field, one-line reason) why ``scene`` (``has_modes``) cannot be built as the
    event-free Driveline or TreeDriveline (its modes need cvj_ros.physics.hybrid)."""
    from cvj_ros.physics.scene import _paths
    where = ('stick/slip modes need the mode model (`cvj-sim simulate`, `cvj-sim run`, '
             '`cvj-sim sweep`), not the event-free one')
    for path, el in _paths(scene.driveline):
        if getattr(el, 'type', '') in MODE_TYPES or getattr(el, 'kind', '') == 'clutch_pack':
            what = 'clutch-pack differential' if getattr(el, 'kind', '') == 'clutch_pack' else el.type
            return (path, f'{what} {el.name!r}: {where}')
    if getattr(scene, 'shift_schedule', None) is not None:
        return ('shift_schedule', f'a shift schedule: {where}')
    return ('commands', f'a command schedule: {where}')


def check_mode_scene(chain: Sequence[Any], method: str, *, tree: bool = False) -> None:
    """A scene with mode elements or commands: its chain splits into valid segments
    (HybridChain; a vehicle tree's layout is checked by check_tree and ModeTree) and its
    solver has dense output (SceneError naming the field)."""
    from cvj_ros.physics.hybrid.chain import HybridChain
    if method not in DENSE_METHODS:
        raise SceneError('solver.method', f'a scene with clutch, gearbox, brake or commands needs an '
                                          f'adaptive method with dense output ({", ".join(DENSE_METHODS)}), '
                                          f'got {method!r}')
    if not tree:
        HybridChain(chain)
