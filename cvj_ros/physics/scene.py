"""Scene files: a whole driveline (engine -> elements -> load) plus its run settings.

A scene is YAML (format in docs/scenes.md). :func:`load_scene` reads a file,
:func:`parse_scene` validates a plain dict; both return a frozen :class:`Scene`.
Every user error raises :class:`cvj_ros.errors.SceneError` whose message starts with
the dotted path of the offending field, e.g.
``driveline[3].params.beta_deg: must be < 90, got 95``.

Units: time s, inertia kg m^2, stiffness N m/rad, damping N m s/rad, speed rad/s
(``*_rpm`` keys are converted), angles in scene files carry ``_deg`` or ``_rad``,
lengths ``_m`` or ``_mm``; joint params are converted to SI (rad, m) for
:func:`cvj_ros.physics.joints.make_joint`.
"""
from __future__ import annotations

import difflib
import math
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from cvj_ros.errors import GeometryError, SceneError, not_a_number

SCENE_KEYS = ('name', 'description', 'seed', 'duration', 'exchange_step', 'sample_step',
              'accuracy_target', 'solver', 'engine', 'load', 'vehicle', 'initial', 'driveline',
              'commands', 'shift_schedule')
SOLVER_KEYS = ('method', 'rtol', 'atol', 'h', 'max_step')
# names users give joints that the registry calls otherwise (suggested, never accepted):
# a single cardan / universal joint is a Hooke joint (double_cardan is two of them)
KIND_ALIASES = {'cardan': 'hooke', 'universal': 'hooke', 'u_joint': 'hooke', 'ujoint': 'hooke',
                'single_cardan': 'hooke'}
INITIAL_KEYS = ('speed_rad_s', 'speed_rpm', 'angle_deg')
INERTIA_KEYS = ('type', 'name', 'J', 'limits', 'imbalance')
IMBALANCE_KEYS = ('mass_kg', 'radius_m', 'angle_deg')
GRAVITY = 9.81        # m/s^2
SPRING_KEYS = ('type', 'name', 'stiffness', 'damping', 'law', 'k2', 'backlash_deg',
               'backlash_smoothing', 'initial_twist_deg', 'fidelity', 'limits',
               'stiffness_variation')
VARIATION_KEYS = ('order', 'amplitude', 'phase_deg')
MAX_VARIATION_ORDER = 64
JOINT_KEYS = ('type', 'name', 'kind', 'fidelity', 'params', 'limits')
ELEMENT_TYPES = ('inertia', 'spring', 'joint', 'clutch', 'gearbox', 'brake')
# clutch, gearbox, brake: mode elements (cvj_ros.physics.hybrid, docs/clutch_gearbox.md)
MODE_ELEMENT_TYPES = ('clutch', 'gearbox', 'brake')
# vehicle scenes (a ``vehicle:`` block) also take wheels and differentials; their mode
# elements: clutch and gearbox in the trunk, a brake right after a wheel
TREE_TYPES = ('inertia', 'spring', 'joint', 'differential', 'wheel', 'clutch', 'gearbox', 'brake')
WHEEL_KEYS = ('type', 'name', 'J', 'radius', 'mu', 'load_share', 'axle', 'tyre', 'limits')
TYRE_KEYS = ('B', 'C', 'E', 'relaxation_length')
DIFF_KEYS = ('type', 'name', 'kind', 'ratio', 'J_carrier', 'J_side', 'J_spider', 'spider_ratio',
             'viscous', 'preload_nm', 'torque_bias', 'static_ratio', 'left', 'right', 'limits')
# clutch_pack: limited slip with stick/slip modes (cvj_ros.physics.hybrid.tree, Python reference)
DIFF_KINDS = ('open', 'locked', 'viscous', 'clutch_pack')
PACK_DIFF_KEYS = ('preload_nm', 'torque_bias', 'static_ratio')
AXLES = ('front', 'rear')
VEHICLE_KEYS = ('mass', 'grade_percent', 'rolling_coeff', 'drag_coeff', 'frontal_area',
                'air_density', 'speed_scale', 'cg_height', 'wheelbase', 'front_share',
                'initial_speed_kmh', 'initial_speed_m_s')
SPRING_LAWS = ('linear', 'progressive')
JOINT_FIDELITIES = ('auto', 'ideal', 'closed', 'exact')
SPRING_FIDELITIES = ('auto', 'elastic', 'rigid')
LIMIT_KEYS = ('max_angle_deg', 'max_speed_rad_s', 'max_torque_nm', 'max_twist_deg',
              'max_nonuniformity')
# Solver names of cvj_ros.physics.solvers.METHODS (validated here so a typo stops early):
# a scene's solver.method takes every method `cvj-sim simulate --method` takes, the two
# loose-tolerance RODAS methods included (each is compiled in the kernel too)
SOLVER_METHODS = ('dopri5', 'dop853', 'rosenbrock', 'rk4', 'ros2', 'rodas4', 'rodas3', 'tsit5',
                  'vern6', 'vern7', 'vern8')
# every solver an offline run takes (cvj-sim simulate --method, Simulation)
OFFLINE_METHODS = SOLVER_METHODS
# unit suffix in a scene file -> (SI unit of the registry, factor to SI)
_SUFFIX_TO_SI = {'_deg': ('rad', math.pi / 180.0), '_rad': ('rad', 1.0),
                 '_mm': ('m', 1e-3), '_m': ('m', 1.0), '_kg': ('kg', 1.0)}


# --- dataclasses -------------------------------------------------------------------------

@dataclass(frozen=True)
class Inertia:
    """Rigid rotating mass ``J`` (kg m^2). ``imbalance``: (m kg, e m, angle rad) of an
    unbalanced mass on a horizontal shaft, whose weight resists with m g e cos(phi + angle)
    (docs/imperfections.md); None = balanced. J includes the mass's m e^2."""

    name: str
    J: float
    limits: Mapping[str, float] = field(default_factory=dict)
    type: str = 'inertia'
    imbalance: tuple[float, float, float] | None = None


@dataclass(frozen=True)
class Spring:
    """Torsional spring-damper between two shafts.

    stiffness c (N m/rad), damping d (N m s/rad), law 'linear' (T = c e) or
    'progressive' (T = c e (1 + k2 e^2), k2 in 1/rad^2, rubber stiffening), optional
    backlash (total free play, rad) regularised by a softplus dead zone of relative
    width ``backlash_smoothing`` (fraction of the half gap). ``initial_twist`` (rad)
    is the twist at t = 0; ``fidelity`` 'auto' | 'elastic' | 'rigid'.
    ``variation``: circumferentially varying stiffness, (order n, amplitude eps, phase psi
    rad) terms of c(phi) = c (1 + sum eps cos(n phi + psi)) over the angle phi of the shaft
    right of the spring (docs/imperfections.md); empty = uniform.
    """

    name: str
    stiffness: float
    damping: float = 0.0
    law: str = 'linear'
    k2: float = 0.0
    backlash: float = 0.0
    backlash_smoothing: float = 0.1
    initial_twist: float = 0.0
    fidelity: str = 'auto'
    limits: Mapping[str, float] = field(default_factory=dict)
    type: str = 'spring'
    variation: tuple[tuple[int, float, float], ...] = ()


@dataclass(frozen=True)
class Joint:
    """Kinematic coupling from the registry (``kind``) with SI ``params`` (rad, m)."""

    name: str
    kind: str
    fidelity: str = 'auto'
    params: Mapping[str, Any] = field(default_factory=dict)        # SI (rad, m) for make_joint
    params_file: Mapping[str, Any] = field(default_factory=dict)   # as written (unit keys)
    limits: Mapping[str, float] = field(default_factory=dict)
    type: str = 'joint'


@dataclass(frozen=True)
class Wheel:
    """A wheel ending a branch: inertia ``J`` (kg m^2, wheel + hub + tyre), rolling
    ``radius`` (m), friction ``mu`` (-), static ``load_share`` of the vehicle weight (-),
    ``axle`` 'front' | 'rear' | None, magic-formula ``B``, ``C``, ``E`` (-) and
    ``relaxation_length`` (m) (cvj_ros.physics.tyre)."""

    name: str
    J: float
    radius: float
    mu: float
    load_share: float
    axle: str | None = None
    B: float = 10.0
    C: float = 1.9
    E: float = 0.97
    relaxation_length: float = 0.2
    limits: Mapping[str, float] = field(default_factory=dict)
    type: str = 'wheel'


@dataclass(frozen=True)
class Differential:
    """A bevel differential ending a chain and branching it into ``left`` and ``right``
    chains (cvj_ros.physics.differential): ``kind`` open | locked | viscous, ring ``ratio``
    omega_in / omega_carrier (-), ``J_carrier``, ``J_side`` (each side gear), ``J_spider``
    (sum of spider spin inertias) in kg m^2, ``spider_ratio`` z_side / z_spider (-),
    ``viscous`` c_v (N m s/rad)."""

    name: str
    kind: str
    ratio: float
    J_carrier: float
    J_side: float
    left: tuple[Any, ...]
    right: tuple[Any, ...]
    J_spider: float = 0.0
    spider_ratio: float = 1.0
    viscous: float = 0.0
    limits: Mapping[str, float] = field(default_factory=dict)
    preload: float = 0.0               # clutch_pack: N m
    torque_bias: float = 0.0           # clutch_pack: capacity per N m of carrier torque (-)
    static_ratio: float = 1.0          # clutch_pack: static / kinetic capacity (-)
    type: str = 'differential'


@dataclass(frozen=True)
class VehicleSpec:
    """The vehicle body of a vehicle scene (cvj_ros.physics.vehicle.VehicleBody): mass (kg),
    grade_percent (%), rolling_coeff C_r (-), drag_coeff C_d (-), frontal_area A (m^2),
    air_density (kg/m^3), speed_scale v_s (m/s), optional cg_height and wheelbase (m) and
    front_share (-) for load transfer, initial_speed (m/s)."""

    mass: float
    grade_percent: float = 0.0
    rolling_coeff: float = 0.012
    drag_coeff: float = 0.3
    frontal_area: float = 2.2
    air_density: float = 1.2
    speed_scale: float = 0.1
    cg_height: float | None = None
    wheelbase: float | None = None
    front_share: float | None = None
    initial_speed: float | None = None


Element = Inertia | Spring | Joint | Wheel | Differential   # plus cvj_ros.physics.hybrid's mode elements


@dataclass(frozen=True)
class SolverSettings:
    """Integrator choice: method name, rtol, atol (relative / absolute), h (s, fixed-step)."""

    method: str = 'dopri5'
    rtol: float = 1e-6
    atol: float = 1e-9
    h: float | None = None
    max_step: float | None = None


@dataclass(frozen=True)
class Scene:
    """A validated scene (frozen). ``driveline`` is ordered from engine to load; in a
    vehicle scene (``vehicle`` set, ``load`` empty) it may branch at differentials."""

    name: str
    description: str
    seed: int
    duration: float                    # s
    exchange_step: float               # s, lockstep exchange period
    solver: SolverSettings
    engine: Mapping[str, Any]                       # spec for engine_from_spec
    load: Mapping[str, Any] | list[Mapping[str, Any]]   # spec for load_from_spec (list = sum)
    driveline: tuple[Element, ...]
    initial_speed: float = 0.0         # rad/s of the first inertia
    initial_angle: float = 0.0         # rad of the first inertia
    accuracy_target: float | None = None
    sample_step: float | None = None   # s, output sampling (default exchange_step)
    source: str = '<dict>'
    vehicle: VehicleSpec | None = None   # vehicle scenes: the body replacing ``load``

    @property
    def is_tree(self) -> bool:
        """True for a vehicle scene (wheels, possibly differentials), False for a chain."""
        return self.vehicle is not None
    commands: tuple[Mapping[str, float], ...] = ()   # rows {t, throttle|clutch|gear|brake}
    shift_schedule: Any = None         # cvj_ros.physics.hybrid.shift.ShiftSchedule or None

    @property
    def has_modes(self) -> bool:
        """The scene holds a clutch, gearbox or brake or a command schedule: it runs on the
        mode-aware reference (cvj_ros.physics.hybrid), not on Driveline or the kernel."""
        return (bool(self.commands) or self.shift_schedule is not None
                or any(getattr(el, 'type', '') in MODE_ELEMENT_TYPES
                       or getattr(el, 'kind', '') == 'clutch_pack'
                       for el in iter_elements(self.driveline)))

    def element(self, name: str) -> Element:
        """The driveline element called ``name``, in any branch (KeyError if absent)."""
        for el in iter_elements(self.driveline):
            if el.name == name:
                return el
        raise KeyError(name)

    def to_dict(self) -> dict[str, Any]:
        """Plain dict in scene-file form; ``parse_scene(s.to_dict())`` == ``s`` (except source)."""
        d: dict[str, Any] = {'name': self.name, 'description': self.description, 'seed': self.seed,
                             'duration': self.duration, 'exchange_step': self.exchange_step}
        if self.sample_step is not None:
            d['sample_step'] = self.sample_step
        if self.accuracy_target is not None:
            d['accuracy_target'] = self.accuracy_target
        sol: dict[str, Any] = {'method': self.solver.method, 'rtol': self.solver.rtol,
                               'atol': self.solver.atol}
        if self.solver.h is not None:
            sol['h'] = self.solver.h
        if self.solver.max_step is not None:
            sol['max_step'] = self.solver.max_step
        d['solver'] = sol
        d['engine'] = _plain(self.engine)
        if self.vehicle is None:
            d['load'] = _plain(self.load)
        else:
            d['vehicle'] = _vehicle_dict(self.vehicle)
        d['initial'] = {'speed_rad_s': self.initial_speed,
                        'angle_deg': math.degrees(self.initial_angle)}
        if self.vehicle is not None and self.vehicle.initial_speed is not None:
            del d['initial']['speed_rad_s']    # set by the vehicle's speed
        d['driveline'] = _chain_dicts(self.driveline)
        if self.commands:
            d['commands'] = [dict(r) for r in self.commands]
        if self.shift_schedule is not None:
            from cvj_ros.physics.hybrid.shift import shift_schedule_dict
            d['shift_schedule'] = shift_schedule_dict(self.shift_schedule)
        return d

    def to_yaml(self) -> str:
        """The scene as YAML text (what is stored in bags as ``/driveline/scene``)."""
        import yaml
        return yaml.safe_dump(self.to_dict(), sort_keys=False)


def iter_elements(chain: tuple[Element, ...]) -> Any:
    """Every element of a driveline, depth first (a differential, then its left and its
    right branch)."""
    for el in chain:
        yield el
        if isinstance(el, Differential):
            yield from iter_elements(el.left)
            yield from iter_elements(el.right)


def _vehicle_dict(v: VehicleSpec) -> dict[str, Any]:
    d: dict[str, Any] = {'mass': v.mass, 'grade_percent': v.grade_percent,
                         'rolling_coeff': v.rolling_coeff, 'drag_coeff': v.drag_coeff,
                         'frontal_area': v.frontal_area, 'air_density': v.air_density,
                         'speed_scale': v.speed_scale}
    for key in ('cg_height', 'wheelbase', 'front_share'):
        if getattr(v, key) is not None:
            d[key] = getattr(v, key)
    if v.initial_speed is not None:
        d['initial_speed_m_s'] = v.initial_speed
    return d


def _chain_dicts(chain: tuple[Element, ...]) -> list[dict[str, Any]]:
    els = []
    for el in chain:
        e: dict[str, Any]
        if isinstance(el, Wheel):
            e = {'type': 'wheel', 'name': el.name, 'J': el.J, 'radius': el.radius, 'mu': el.mu,
                 'load_share': el.load_share}
            if el.axle is not None:
                e['axle'] = el.axle
            e['tyre'] = {'B': el.B, 'C': el.C, 'E': el.E,
                         'relaxation_length': el.relaxation_length}
        elif isinstance(el, Differential):
            e = {'type': 'differential', 'name': el.name, 'kind': el.kind, 'ratio': el.ratio,
                 'J_carrier': el.J_carrier, 'J_side': el.J_side, 'J_spider': el.J_spider,
                 'spider_ratio': el.spider_ratio}
            if el.kind == 'viscous':
                e['viscous'] = el.viscous
            if el.kind == 'clutch_pack':
                e.update(preload_nm=el.preload, torque_bias=el.torque_bias,
                         static_ratio=el.static_ratio)
            e['left'] = _chain_dicts(el.left)
            e['right'] = _chain_dicts(el.right)
        elif isinstance(el, Inertia):
            e = {'type': 'inertia', 'name': el.name, 'J': el.J}
            if el.imbalance is not None:
                m, r, ang = el.imbalance
                e['imbalance'] = {'mass_kg': m, 'radius_m': r, 'angle_deg': math.degrees(ang)}
        elif isinstance(el, Spring):
            e = {'type': 'spring', 'name': el.name, 'stiffness': el.stiffness,
                 'damping': el.damping, 'law': el.law}
            if el.law == 'progressive':
                e['k2'] = el.k2
            if el.backlash:
                e['backlash_deg'] = math.degrees(el.backlash)
                e['backlash_smoothing'] = el.backlash_smoothing
            if el.initial_twist:
                e['initial_twist_deg'] = math.degrees(el.initial_twist)
            if el.fidelity != 'auto':
                e['fidelity'] = el.fidelity
            if el.variation:
                e['stiffness_variation'] = [{'order': n, 'amplitude': eps,
                                             'phase_deg': math.degrees(psi)}
                                            for n, eps, psi in el.variation]
        elif isinstance(el, Joint):
            e = {'type': 'joint', 'name': el.name, 'kind': el.kind, 'fidelity': el.fidelity,
                 'params': dict(el.params_file)}
        else:
            from cvj_ros.physics.hybrid.scene_keys import mode_element_dict
            e = mode_element_dict(el)
        if getattr(el, 'limits', None):
            e['limits'] = dict(el.limits)
        els.append(e)
    return els


def _plain(value: Any) -> Any:
    if isinstance(value, Mapping):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    return value


# --- validation helpers ----------------------------------------------------------------

def _check_keys(data: Mapping[str, Any], allowed: tuple[str, ...], path: str) -> None:
    for key in data:
        if key not in allowed:
            where = f'{path}.{key}' if path else str(key)
            near = difflib.get_close_matches(str(key), allowed, n=1)
            hint = f"; did you mean '{near[0]}'?" if near else f'; allowed: {", ".join(allowed)}'
            if not str(key):   # an empty key names no field: name the mapping that holds it
                raise SceneError(path or 'scene', f"unknown empty key ''{hint}")
            raise SceneError(where, f'unknown key{hint}')


def _mapping(value: Any, path: str) -> Mapping[str, Any]:
    if not isinstance(value, Mapping):
        raise SceneError(path, f'must be a mapping, got {type(value).__name__}')
    return value


def _number(value: Any, path: str, *, positive: bool = False, nonneg: bool = False,
            lo: float | None = None, hi: float | None = None, hi_open: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise SceneError(path, not_a_number(value))
    v = float(value)
    if not math.isfinite(v):
        raise SceneError(path, f'must be finite, got {v}')
    if positive and v <= 0.0:
        raise SceneError(path, f'must be > 0, got {value}')
    if nonneg and v < 0.0:
        raise SceneError(path, f'must be >= 0, got {value}')
    if lo is not None and v < lo:
        raise SceneError(path, f'must be >= {lo}, got {value}')
    if hi is not None and (v > hi or (hi_open and v == hi)):
        raise SceneError(path, f'must be {"<" if hi_open else "<="} {hi}, got {value}')
    return v


def _variation(raw: Any, path: str) -> tuple[tuple[int, float, float], ...]:
    """A spring's ``stiffness_variation`` list -> ((order, amplitude, phase rad), ...); the
    amplitudes sum to < 1 so the stiffness stays positive all round."""
    if not isinstance(raw, list):
        raise SceneError(path, 'must be a list of {order, amplitude, phase_deg}, got '
                               f'{type(raw).__name__}')
    out: list[tuple[int, float, float]] = []
    for i, term in enumerate(raw):
        p = f'{path}[{i}]'
        t = _mapping(term, p)
        _check_keys(t, VARIATION_KEYS, p)
        for key in ('order', 'amplitude'):
            if key not in t:
                raise SceneError(f'{p}.{key}', 'missing')
        order = t['order']
        if isinstance(order, bool) or not isinstance(order, int) or \
                not 1 <= order <= MAX_VARIATION_ORDER:
            raise SceneError(f'{p}.order', f'must be an integer 1..{MAX_VARIATION_ORDER} '
                                           f'(cycles per revolution), got {order!r}')
        amp = _number(t['amplitude'], f'{p}.amplitude', nonneg=True, hi=1.0, hi_open=True)
        phase = math.radians(_number(t.get('phase_deg', 0.0), f'{p}.phase_deg'))
        out.append((order, amp, phase))
    total = sum(a for _n, a, _p in out)
    if total >= 1.0:
        raise SceneError(path, f'the amplitudes sum to {total:g}; they must sum to < 1 so the '
                               'stiffness stays positive all round')
    return tuple(out)


def _string(value: Any, path: str, *, choices: tuple[str, ...] | None = None) -> str:
    if not isinstance(value, str) or not value:
        raise SceneError(path, f'must be a non-empty string, got {value!r}')
    if choices is not None and value not in choices:
        near = difflib.get_close_matches(value, choices, n=1)
        hint = f"; did you mean '{near[0]}'?" if near else ''
        raise SceneError(path, f'must be one of {", ".join(choices)}, got {value!r}{hint}')
    return value


def _limits(value: Any, path: str) -> dict[str, float]:
    lim = _mapping(value, path)
    _check_keys(lim, LIMIT_KEYS, path)
    return {k: _number(v, f'{path}.{k}', positive=True) for k, v in lim.items()}


def _joint_params(kind: str, raw: Mapping[str, Any], path: str) -> dict[str, Any]:
    """Convert unit-suffixed scene params to the registry's SI names."""
    from cvj_ros.physics.joints import JOINTS
    spec = JOINTS[kind]
    # accepted file keys: name + suffix for each unit of the registry entry
    accepted: dict[str, tuple[str, float]] = {}
    for si_name, desc in spec.params.items():
        unit = desc.split(',')[0].strip()
        matched = False
        for suffix, (si_unit, factor) in _SUFFIX_TO_SI.items():
            if si_unit == unit:
                accepted[si_name + suffix] = (si_name, factor)
                matched = True
        if not matched:
            accepted[si_name] = (si_name, 1.0)   # dimensionless or other unit: as is
    out: dict[str, Any] = {}
    for key, value in raw.items():
        if key not in accepted:
            choices = tuple(accepted)
            # a bare name means the unit users write angles in: beta -> beta_deg, not beta_rad
            unit_forms = [c for c in choices if c.startswith(f'{key}_')]
            near = (sorted(unit_forms, key=lambda c: not c.endswith('_deg'))[:1]
                    or difflib.get_close_matches(str(key), choices, n=1))
            hint = (f"; did you mean '{near[0]}'?" if near
                    else f'; {kind} accepts: {", ".join(choices) or "no params"}')
            raise SceneError(f'{path}.{key}', f'unknown parameter{hint}')
        si_name, factor = accepted[key]
        if si_name in out:
            raise SceneError(f'{path}.{key}', f'{si_name} given twice (with different units)')
        if isinstance(value, (str, list, dict)) and factor == 1.0 and key == si_name:
            out[si_name] = value       # non-numeric option (e.g. double_cardan layout: Z)
            continue
        v = _number(value, f'{path}.{key}')
        if key.endswith('_deg') and not (-360.0 <= v <= 360.0):
            raise SceneError(f'{path}.{key}', f'angle out of range [-360, 360] deg, got {value}')
        out[si_name] = v * factor
    return out


def _element(raw: Any, path: str, *, tree: bool = False, depth: int = 0) -> Element:
    from cvj_ros.physics.joints import JOINTS, make_joint
    el = _mapping(raw, path)
    types = TREE_TYPES if tree else ELEMENT_TYPES
    if 'type' not in el:
        raise SceneError(f'{path}.type', f'missing; one of {", ".join(types)}')
    if not tree and el['type'] in ('differential', 'wheel'):
        raise SceneError(f'{path}.type', f"{el['type']!r} needs a vehicle scene (a 'vehicle:' "
                                         "block instead of 'load:')")
    etype = _string(el['type'], f'{path}.type', choices=types)
    if 'name' not in el:
        raise SceneError(f'{path}.name', 'missing')
    name = _string(el['name'], f'{path}.name')
    if not name.replace('_', 'a').isalnum() or not name[0].isalpha():
        raise SceneError(f'{path}.name', f'must be an identifier (letters, digits, _), got {name!r}')
    if etype in MODE_ELEMENT_TYPES:
        from cvj_ros.physics.hybrid.scene_keys import mode_element
        return mode_element(etype, el, name, path)
    limits = _limits(el['limits'], f'{path}.limits') if 'limits' in el else {}
    if etype == 'wheel':
        return _wheel(el, path, name, limits)
    if etype == 'differential':
        return _differential(el, path, name, limits, depth)
    if etype == 'inertia':
        _check_keys(el, INERTIA_KEYS, path)
        if 'J' not in el:
            raise SceneError(f'{path}.J', 'missing (kg m^2)')
        imb = None
        if 'imbalance' in el:
            raw = _mapping(el['imbalance'], f'{path}.imbalance')
            _check_keys(raw, IMBALANCE_KEYS, f'{path}.imbalance')
            for key in ('mass_kg', 'radius_m'):
                if key not in raw:
                    raise SceneError(f'{path}.imbalance.{key}', 'missing')
            imb = (_number(raw['mass_kg'], f'{path}.imbalance.mass_kg', nonneg=True),
                   _number(raw['radius_m'], f'{path}.imbalance.radius_m', nonneg=True, hi=10.0),
                   math.radians(_number(raw.get('angle_deg', 0.0), f'{path}.imbalance.angle_deg')))
            if tree:
                raise SceneError(f'{path}.imbalance', 'not available in a vehicle scene yet '
                                                      '(chain scenes only)')
        return Inertia(name=name, J=_number(el['J'], f'{path}.J', positive=True), limits=limits,
                       imbalance=imb)
    if etype == 'spring':
        _check_keys(el, SPRING_KEYS, path)
        if 'stiffness' not in el:
            raise SceneError(f'{path}.stiffness', 'missing (N m/rad)')
        law = _string(el.get('law', 'linear'), f'{path}.law', choices=SPRING_LAWS)
        if 'k2' in el and law != 'progressive':
            raise SceneError(f'{path}.k2', "only for law 'progressive'")
        backlash_deg = _number(el.get('backlash_deg', 0.0), f'{path}.backlash_deg', nonneg=True,
                               hi=90.0, hi_open=True)
        return Spring(
            name=name, stiffness=_number(el['stiffness'], f'{path}.stiffness', positive=True),
            damping=_number(el.get('damping', 0.0), f'{path}.damping', nonneg=True),
            law=law, k2=_number(el.get('k2', 0.0), f'{path}.k2', nonneg=True),
            backlash=math.radians(backlash_deg),
            backlash_smoothing=_number(el.get('backlash_smoothing', 0.1),
                                       f'{path}.backlash_smoothing', positive=True, hi=1.0),
            initial_twist=math.radians(_number(el.get('initial_twist_deg', 0.0),
                                               f'{path}.initial_twist_deg', lo=-90.0, hi=90.0)),
            fidelity=_string(el.get('fidelity', 'auto'), f'{path}.fidelity',
                             choices=SPRING_FIDELITIES),
            limits=limits,
            variation=_variation(el.get('stiffness_variation', []) or [],
                                 f'{path}.stiffness_variation'))
    _check_keys(el, JOINT_KEYS, path)
    if 'kind' not in el:
        raise SceneError(f'{path}.kind', f'missing; one of {", ".join(sorted(JOINTS))}')
    if isinstance(el['kind'], str) and el['kind'] in KIND_ALIASES:
        raise SceneError(f'{path}.kind', f'must be one of {", ".join(sorted(JOINTS))}, got '
                                         f"{el['kind']!r}; did you mean '{KIND_ALIASES[el['kind']]}'?")
    kind = _string(el['kind'], f'{path}.kind', choices=tuple(sorted(JOINTS)))
    fidelity = _string(el.get('fidelity', 'auto'), f'{path}.fidelity', choices=JOINT_FIDELITIES)
    if fidelity != 'auto' and fidelity not in JOINTS[kind].fidelities:
        raise SceneError(f'{path}.fidelity', f'{kind} has fidelities '
                                             f'{", ".join(JOINTS[kind].fidelities)}; got {fidelity!r}')
    raw_params = _mapping(el.get('params', {}) or {}, f'{path}.params')
    params = _joint_params(kind, raw_params, f'{path}.params')
    # build once at the most detailed fidelity: the joint's own geometry checks apply
    try:
        make_joint(kind, fidelity=JOINTS[kind].fidelities[-1], **params)
    except GeometryError as exc:
        # report with the file's key (beta -> beta_deg) and the file's unit
        file_key = next((k for k in raw_params if k.startswith(exc.parameter + '_')
                         or k == exc.parameter), exc.parameter)
        msg = str(exc)[len(exc.parameter) + 2:]
        if file_key.endswith('_deg') and file_key in raw_params and 'deg' not in msg:
            msg = _deg_message(msg, raw_params[file_key])
        raise SceneError(f'{path}.params.{file_key}', msg) from None
    return Joint(name=name, kind=kind, fidelity=fidelity, params=params,
                 params_file={k: (float(v) if isinstance(v, (int, float)) else v)
                              for k, v in raw_params.items()}, limits=limits)


def parse_element(raw: Any, path: str) -> Element:
    """One chain scene's ``driveline`` element validated as :func:`parse_scene` validates it
    (the element alone: the chain checks are the caller's); ``path`` (``driveline[i]``)
    names it in errors. Raises SceneError."""
    return _element(raw, path)


def _wheel(el: Mapping[str, Any], path: str, name: str, limits: dict[str, float]) -> Wheel:
    _check_keys(el, WHEEL_KEYS, path)
    for key, unit in (('J', 'kg m^2'), ('radius', 'm'), ('mu', '-'), ('load_share', '-')):
        if key not in el:
            raise SceneError(f'{path}.{key}', f'missing ({unit})')
    tyre = _mapping(el.get('tyre', {}) or {}, f'{path}.tyre')
    _check_keys(tyre, TYRE_KEYS, f'{path}.tyre')
    axle = _string(el['axle'], f'{path}.axle', choices=AXLES) if el.get('axle') is not None else None
    return Wheel(name=name, J=_number(el['J'], f'{path}.J', positive=True),
                 radius=_number(el['radius'], f'{path}.radius', positive=True, hi=5.0),
                 mu=_number(el['mu'], f'{path}.mu', positive=True, hi=3.0),
                 load_share=_number(el['load_share'], f'{path}.load_share', positive=True, hi=1.0),
                 axle=axle,
                 B=_number(tyre.get('B', 10.0), f'{path}.tyre.B', positive=True),
                 C=_number(tyre.get('C', 1.9), f'{path}.tyre.C', positive=True, hi=2.0),
                 E=_number(tyre.get('E', 0.97), f'{path}.tyre.E', hi=1.0),
                 relaxation_length=_number(tyre.get('relaxation_length', 0.2),
                                           f'{path}.tyre.relaxation_length', positive=True),
                 limits=limits)


#: nesting bound of differentials in branches (a 4x4 needs 2)
MAX_DIFF_DEPTH = 8


def _differential(el: Mapping[str, Any], path: str, name: str, limits: dict[str, float],
                  depth: int) -> Differential:
    _check_keys(el, DIFF_KEYS, path)
    if depth >= MAX_DIFF_DEPTH:
        raise SceneError(path, f'differentials nested deeper than {MAX_DIFF_DEPTH}')
    kind = _string(el.get('kind', 'open'), f'{path}.kind', choices=DIFF_KINDS)
    for key, unit in (('J_carrier', 'kg m^2'), ('J_side', 'kg m^2 of each side gear'),
                      ('left', 'list of elements'), ('right', 'list of elements')):
        if key not in el:
            raise SceneError(f'{path}.{key}', f'missing ({unit})')
    if 'viscous' in el and kind != 'viscous':
        raise SceneError(f'{path}.viscous', "only for kind 'viscous'")
    if kind == 'viscous' and 'viscous' not in el:
        raise SceneError(f'{path}.viscous', 'missing (N m s/rad, the coupling coefficient c_v)')
    for key in PACK_DIFF_KEYS:
        if key in el and kind != 'clutch_pack':
            raise SceneError(f'{path}.{key}', "only for kind 'clutch_pack'")
    if kind == 'clutch_pack' and 'preload_nm' not in el:
        raise SceneError(f'{path}.preload_nm', 'missing (N m, the pack\'s kinetic torque at zero '
                                               'carrier torque)')
    ratio = _number(el.get('ratio', 1.0), f'{path}.ratio')
    if not 1e-3 <= abs(ratio) <= 1e3:
        raise SceneError(f'{path}.ratio', f'must satisfy 1e-3 <= |ratio| <= 1e3 '
                                          f'(omega_in / omega_carrier), got {ratio:g}')
    branches = []
    for side in ('left', 'right'):
        raw = el[side]
        if not isinstance(raw, list) or not raw:
            raise SceneError(f'{path}.{side}', 'must be a non-empty list of elements')
        branches.append(tuple(_element(x, f'{path}.{side}[{i}]', tree=True, depth=depth + 1)
                              for i, x in enumerate(raw)))
    return Differential(
        name=name, kind=kind, ratio=ratio,
        J_carrier=_number(el['J_carrier'], f'{path}.J_carrier', positive=True),
        J_side=_number(el['J_side'], f'{path}.J_side', positive=True),
        left=branches[0], right=branches[1],
        J_spider=_number(el.get('J_spider', 0.0), f'{path}.J_spider', nonneg=True),
        spider_ratio=_number(el.get('spider_ratio', 1.0), f'{path}.spider_ratio', positive=True),
        viscous=_number(el.get('viscous', 0.0), f'{path}.viscous', nonneg=True), limits=limits,
        preload=_number(el.get('preload_nm', 0.0), f'{path}.preload_nm', nonneg=True, hi=1e6),
        torque_bias=_number(el.get('torque_bias', 0.0), f'{path}.torque_bias', nonneg=True, hi=0.9),
        static_ratio=_number(el.get('static_ratio', 1.0), f'{path}.static_ratio', lo=1.0, hi=10.0))


def _vehicle(raw: Any) -> VehicleSpec:
    v = _mapping(raw, 'vehicle')
    _check_keys(v, VEHICLE_KEYS, 'vehicle')
    if 'mass' not in v:
        raise SceneError('vehicle.mass', 'missing (kg)')
    opt = {k: (_number(v[k], f'vehicle.{k}', positive=True) if v.get(k) is not None else None)
           for k in ('cg_height', 'wheelbase', 'front_share')}
    given = [k for k, x in opt.items() if x is not None]
    if given and len(given) != 3:
        missing = next(k for k, x in opt.items() if x is None)
        raise SceneError(f'vehicle.{missing}', 'load transfer needs cg_height, wheelbase and '
                                               'front_share together')
    if opt['front_share'] is not None and opt['front_share'] >= 1.0:
        raise SceneError('vehicle.front_share', f'must be < 1, got {opt["front_share"]}')
    if 'initial_speed_kmh' in v and 'initial_speed_m_s' in v:
        raise SceneError('vehicle.initial_speed_m_s', 'give either initial_speed_kmh or '
                                                      'initial_speed_m_s, not both')
    v0 = None
    if 'initial_speed_kmh' in v:
        v0 = _number(v['initial_speed_kmh'], 'vehicle.initial_speed_kmh', lo=-500.0, hi=500.0) / 3.6
    elif 'initial_speed_m_s' in v:
        v0 = _number(v['initial_speed_m_s'], 'vehicle.initial_speed_m_s', lo=-150.0, hi=150.0)
    return VehicleSpec(
        mass=_number(v['mass'], 'vehicle.mass', positive=True),
        grade_percent=_number(v.get('grade_percent', 0.0), 'vehicle.grade_percent', lo=-100.0, hi=100.0),
        rolling_coeff=_number(v.get('rolling_coeff', 0.012), 'vehicle.rolling_coeff', nonneg=True),
        drag_coeff=_number(v.get('drag_coeff', 0.3), 'vehicle.drag_coeff', nonneg=True),
        frontal_area=_number(v.get('frontal_area', 2.2), 'vehicle.frontal_area', nonneg=True),
        air_density=_number(v.get('air_density', 1.2), 'vehicle.air_density', nonneg=True),
        speed_scale=_number(v.get('speed_scale', 0.1), 'vehicle.speed_scale', positive=True),
        cg_height=opt['cg_height'], wheelbase=opt['wheelbase'], front_share=opt['front_share'],
        initial_speed=v0)


def _deg_message(msg: str, given: Any) -> str:
    """Rewrite a rad-range message ('must be < 1.5707963 rad, got 1.65 rad') in degrees."""
    import re
    def repl(m: re.Match[str]) -> str:
        return f'{math.degrees(float(m.group(1))):.6g}'
    out = re.sub(r'(-?\d+(?:\.\d+)?(?:e-?\d+)?) rad', lambda m: repl(m) + ' deg', msg)
    return re.sub(r'got [^ ]+ deg$', f'got {given} deg', out)


def parse_scene(data: Any, *, source: str = '<dict>') -> Scene:
    """Validate a scene given as a plain dict (YAML-loaded). Raises SceneError."""
    d = _mapping(data, source if source != '<dict>' else 'scene')
    _check_keys(d, SCENE_KEYS, '')
    for key in ('name', 'duration', 'driveline', 'engine'):
        if key not in d:
            raise SceneError(key, 'missing')
    if 'load' in d and 'vehicle' in d:
        raise SceneError('vehicle', "give either 'load' (a chain's output) or 'vehicle' (wheels "
                                    "with tyres), not both")
    if 'load' not in d and 'vehicle' not in d:
        raise SceneError('load', "missing (or a 'vehicle' block for a driveline ending in wheels)")
    tree = 'vehicle' in d
    name = _string(d['name'], 'name')
    description = d.get('description', '')
    if not isinstance(description, str):
        raise SceneError('description', 'must be a string')
    seed = d.get('seed', 0)
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise SceneError('seed', f'must be a non-negative integer, got {seed!r}')
    duration = _number(d['duration'], 'duration', positive=True)
    exchange_step = _number(d.get('exchange_step', 1e-3), 'exchange_step', positive=True)
    if exchange_step > duration:
        raise SceneError('exchange_step', f'must be <= duration ({duration} s), got {exchange_step}')
    sample_step = (_number(d['sample_step'], 'sample_step', positive=True)
                   if d.get('sample_step') is not None else None)
    target = (_number(d['accuracy_target'], 'accuracy_target', positive=True, hi=1.0)
              if d.get('accuracy_target') is not None else None)
    sol = _mapping(d.get('solver', {}) or {}, 'solver')
    _check_keys(sol, SOLVER_KEYS, 'solver')
    solver = SolverSettings(
        method=_string(sol.get('method', 'dopri5'), 'solver.method', choices=SOLVER_METHODS),
        rtol=_number(sol.get('rtol', 1e-6), 'solver.rtol', positive=True, hi=1.0),
        atol=_number(sol.get('atol', 1e-9), 'solver.atol', positive=True),
        h=_number(sol['h'], 'solver.h', positive=True) if sol.get('h') is not None else None,
        max_step=(_number(sol['max_step'], 'solver.max_step', positive=True)
                  if sol.get('max_step') is not None else None))
    engine = _mapping(d['engine'], 'engine')
    load = d.get('load', {})
    if not isinstance(load, list):
        load = _mapping(load, 'load')
    vehicle = _vehicle(d['vehicle']) if tree else None
    # build once so spec errors stop here, before any run
    from cvj_ros.physics.engine import engine_from_spec
    from cvj_ros.physics.load import load_from_spec
    engine_from_spec(engine, field='engine')
    if not tree:
        load_from_spec(load, seed=seed, field='load')
    init = _mapping(d.get('initial', {}) or {}, 'initial')
    _check_keys(init, INITIAL_KEYS, 'initial')
    if 'speed_rad_s' in init and 'speed_rpm' in init:
        raise SceneError('initial.speed_rpm', 'give either speed_rad_s or speed_rpm, not both')
    speed = 0.0
    # bounded so that squares of speeds stay far from float overflow (1e6 rad/s ~ 9.5e6 rpm)
    if 'speed_rad_s' in init:
        speed = _number(init['speed_rad_s'], 'initial.speed_rad_s', lo=-1e6, hi=1e6)
    elif 'speed_rpm' in init:
        speed = _number(init['speed_rpm'], 'initial.speed_rpm', lo=-9.5e6, hi=9.5e6) * math.pi / 30.0
    angle = math.radians(_number(init.get('angle_deg', 0.0), 'initial.angle_deg'))
    if (tree and vehicle.initial_speed is not None
            and ('speed_rad_s' in init or 'speed_rpm' in init)):
        key = 'speed_rad_s' if 'speed_rad_s' in init else 'speed_rpm'
        raise SceneError(f'initial.{key}', "the vehicle's initial speed sets the driveline's "
                                           '(rolling without slip); give one of them')
    raw_chain = d['driveline']
    if not isinstance(raw_chain, list) or not raw_chain:
        raise SceneError('driveline', 'must be a non-empty list of elements')
    chain = tuple(_element(el, f'driveline[{i}]', tree=tree) for i, el in enumerate(raw_chain))
    if tree:
        check_tree(chain, vehicle)
    else:
        seen: dict[str, int] = {}
        for i, el in enumerate(chain):
            if el.name in seen:
                raise SceneError(f'driveline[{i}].name', f'duplicate name {el.name!r} '
                                                         f'(also driveline[{seen[el.name]}])')
            seen[el.name] = i
        check_layout(chain)
    check_hooke_phasing(chain)
    commands: tuple[Mapping[str, float], ...] = ()
    flat = tuple(iter_elements(chain))
    if d.get('commands') is not None:
        from cvj_ros.physics.hybrid.scene_keys import parse_commands
        commands = parse_commands(d['commands'], flat)
    shift = None
    if d.get('shift_schedule') is not None:
        from cvj_ros.physics.hybrid.shift import check_no_gear_rows, parse_shift_schedule
        if not tree:
            raise SceneError('shift_schedule', 'runs on vehicle scenes (a vehicle: block) for now; '
                                               'a chain scene shifts by gear rows in commands')
        shift = parse_shift_schedule(d['shift_schedule'],
                                     next((el for el in flat if getattr(el, 'type', '') == 'gearbox'),
                                          None))
        check_no_gear_rows(commands)
    if commands or shift is not None or any(getattr(el, 'type', '') in MODE_ELEMENT_TYPES
                                            or getattr(el, 'kind', '') == 'clutch_pack'
                                            for el in flat):
        from cvj_ros.physics.hybrid.scene_keys import check_mode_scene
        check_mode_scene(chain, solver.method, tree=tree)
    return Scene(name=name, description=description.strip(), seed=seed, duration=duration,
                 exchange_step=exchange_step, solver=solver, engine=dict(engine),
                 load=[dict(x) for x in load] if isinstance(load, list) else dict(load),
                 driveline=chain, initial_speed=speed, initial_angle=angle,
                 accuracy_target=target, sample_step=sample_step, source=source,
                 vehicle=vehicle, commands=commands, shift_schedule=shift)


def check_layout(chain: tuple[Element, ...]) -> None:
    """Reject chains the driveline cannot integrate (see docs/scenes.md, layouts).

    Rules: first and last element are inertias (engine and load act on them); every
    rigid section between two springs holds at least one inertia (a massless node
    between springs would be an algebraic constraint). Mode elements: a clutch or gearbox
    brings an inertia on each side; a brake only as the last element, after an inertia
    (it acts on the output shaft); at most one gearbox and one brake.
    """
    if not isinstance(chain[0], Inertia):
        raise SceneError('driveline[0].type', 'the first element must be an inertia '
                                              '(the engine acts on it)')
    last = len(chain) - 1
    types = [getattr(el, 'type', '') for el in chain]
    for i, t in enumerate(types):
        if t == 'brake' and i != last:
            raise SceneError(f'driveline[{i}].type', 'a brake must be the last element (it acts '
                                                     'on the output shaft, the inertia before it)')
        if t == 'gearbox' and 'gearbox' in types[:i]:
            raise SceneError(f'driveline[{i}].type', 'at most one gearbox (the gear command drives it)')
    if types[last] == 'brake':
        last -= 1
        chain = chain[:-1]
    if not isinstance(chain[last], Inertia):
        raise SceneError(f'driveline[{last}].type', 'the last element must be an inertia '
                                                    '(the load acts on it)')
    has_inertia = True
    for i, el in enumerate(chain):
        if isinstance(el, Spring):
            if not has_inertia:
                raise SceneError(f'driveline[{i}]', 'no inertia between this spring and the '
                                                    'previous one (massless node); add an inertia')
            has_inertia = False
        elif isinstance(el, Inertia) or getattr(el, 'type', '') in ('clutch', 'gearbox'):
            has_inertia = True


def check_hooke_phasing(chain: tuple[Element, ...], path: str = 'driveline') -> None:
    """Reject a Hooke joint that follows another Hooke joint with only inertias and springs
    (or nothing, inside a ``chain`` joint) between them, unless it states its yoke phase.

    The phase of such a pair decides whether its nonuniformities cancel (yokes of the
    shaft between in phase: ``phase_deg`` of the second = that of the first + 90 for a
    square cross) or add (90 deg out of phase, the law's default 0), so it is never
    assumed. ``path`` is the field path of ``chain`` in error messages.
    """
    prev: str | None = None          # field path of the last Hooke with only shafts since
    for i, el in enumerate(chain):
        here = f'{path}[{i}]'
        if isinstance(el, Differential):
            prev = None          # a bevel gear between: no propshaft pair across it
            check_hooke_phasing(el.left, f'{here}.left')
            check_hooke_phasing(el.right, f'{here}.right')
            continue
        if not isinstance(el, Joint):
            continue
        if el.kind == 'chain':
            stages = el.params.get('joints', ())
            for k, st in enumerate(stages):
                kind = st.get('kind') if isinstance(st, Mapping) else getattr(st, 'kind', None)
                if kind != 'hooke':
                    prev = None
                    continue
                stated = isinstance(st, Mapping) and 'phase' in st
                spath = f'{here}.params.joints[{k}]'
                if prev is not None and not stated and isinstance(st, Mapping):
                    raise SceneError(f'{spath}.phase', _phase_missing(prev))
                prev = spath
            continue
        if el.kind != 'hooke':
            prev = None
            continue
        if prev is not None and not any(k.startswith('phase_') for k in el.params_file):
            raise SceneError(f'{here}.params.phase_deg', _phase_missing(prev))
        prev = here


def _phase_missing(prev: str) -> str:
    return (f'missing: this Hooke joint follows the Hooke joint {prev} with only shafts between '
            'them, so their yoke phase decides whether the nonuniformities cancel or add; '
            'state it (phase_deg of the first + 90 puts the yokes of the shaft between in '
            'phase, + 0 puts them 90 deg out of phase)')


def _paths(chain: tuple[Element, ...], path: str = 'driveline') -> list[tuple[str, Element]]:
    """(field path, element) of every element, depth first."""
    out = []
    for i, el in enumerate(chain):
        p = f'{path}[{i}]'
        out.append((p, el))
        if isinstance(el, Differential):
            out += _paths(el.left, f'{p}.left') + _paths(el.right, f'{p}.right')
    return out


def check_tree(chain: tuple[Element, ...], vehicle: VehicleSpec) -> None:
    """Reject vehicle drivelines the equations cannot integrate (docs/scenes.md, vehicle
    scenes): names unique across branches; the main chain starts with an inertia; a
    differential is the last element of its chain; every chain ends in a wheel or a
    differential, and a wheel only there; every rigid section between springs holds an
    inertia (a differential's carrier and side gears count); static load shares sum to at
    most 1 (the rest rides on undriven wheels); with load transfer every wheel names its
    axle and the front wheels' shares fit in ``front_share``."""
    items = _paths(chain)
    seen: dict[str, str] = {}
    for p, el in items:
        if el.name in seen:
            raise SceneError(f'{p}.name', f'duplicate name {el.name!r} (also {seen[el.name]})')
        seen[el.name] = p
    if not isinstance(chain[0], Inertia):
        raise SceneError('driveline[0].type', 'the first element must be an inertia '
                                              '(the engine acts on it)')

    def walk(ch: tuple[Element, ...], path: str, has_inertia: bool) -> None:
        last = len(ch) - 1
        if last > 0 and getattr(ch[last], 'type', '') == 'brake':
            if not isinstance(ch[last - 1], Wheel):
                raise SceneError(f'{path}[{last}].type', 'a brake follows the wheel it acts on')
            last -= 1
        for i, el in enumerate(ch):
            p = f'{path}[{i}]'
            etype = getattr(el, 'type', '')
            if etype == 'brake' and i != last + 1:
                raise SceneError(f'{p}.type', 'a brake follows the wheel it acts on, as the last '
                                              'element of its chain')
            if etype in ('clutch', 'gearbox') and path != 'driveline':
                raise SceneError(f'{p}.type', f'a {etype} sits in the trunk (the top-level '
                                              'driveline), before the differential')
            if etype in ('clutch', 'gearbox'):
                has_inertia = True
            if isinstance(el, (Wheel, Differential)) and i != last:
                raise SceneError(f'{p}.type', f'a {el.type} must be the last element of its chain')
            if isinstance(el, Spring):
                if not has_inertia:
                    raise SceneError(p, 'no inertia between this spring and the previous one '
                                        '(massless node); add an inertia')
                has_inertia = False
            elif isinstance(el, (Inertia, Wheel, Differential)):
                has_inertia = True
            if isinstance(el, Differential):
                walk(el.left, f'{p}.left', True)
                walk(el.right, f'{p}.right', True)
        if not isinstance(ch[last], (Wheel, Differential)):
            raise SceneError(f'{path}[{last}].type', 'a vehicle driveline ends every chain in a '
                                                     'wheel or a differential')

    walk(chain, 'driveline', True)
    wheels = [(p, el) for p, el in items if isinstance(el, Wheel)]
    total = sum(el.load_share for _p, el in wheels)
    if total > 1.0 + 1e-9:
        raise SceneError(f'{wheels[-1][0]}.load_share', f'the wheels\' static load shares sum to '
                                                        f'{total:g} > 1')
    if vehicle.front_share is not None:
        for p, el in wheels:
            if el.axle is None:
                raise SceneError(f'{p}.axle', 'missing (front or rear): the vehicle has load '
                                              'transfer (cg_height)')
        for ax, cap in (('front', vehicle.front_share), ('rear', 1.0 - vehicle.front_share)):
            on = [(p, el) for p, el in wheels if el.axle == ax]
            s = sum(el.load_share for _p, el in on)
            if on and s > cap + 1e-9:
                raise SceneError(f'{on[-1][0]}.load_share', f'the {ax} wheels\' shares sum to '
                                                            f'{s:g}, more than the {ax} axle\'s '
                                                            f'static share {cap:g}')


# --- files ------------------------------------------------------------------------------

def load_scene(path: str | os.PathLike[str]) -> Scene:
    """Read and validate a scene YAML file. Malformed YAML names the line."""
    import yaml

    from cvj_ros.textfile import load_yaml_bounded, read_text_file
    p = Path(path)
    # UTF-8 text of at most 1 MiB, YAML at most 64 levels deep, aliases bounded (textfile.py)
    text = read_text_file(p, what='scene file')
    try:
        data = load_yaml_bounded(text, str(p))
    except yaml.YAMLError as exc:
        mark = getattr(exc, 'problem_mark', None)
        where = f'{p}:{mark.line + 1}' if mark is not None else str(p)
        problem = getattr(exc, 'problem', None) or str(exc).splitlines()[0]
        raise SceneError(where, f'malformed YAML: {problem}') from None
    if data is None:
        raise SceneError(str(p), 'empty scene file')
    return parse_scene(data, source=str(p))


def scene_dirs() -> list[Path]:
    """Directories searched for shipped scenes: the source tree's config/scenes and the
    ament share directory ``share/cvj_ros/config/scenes`` when installed: the first prefix
    of ``AMENT_PREFIX_PATH`` whose resource index marks the package
    (``share/ament_index/resource_index/packages/cvj_ros``), the lookup
    ament_index_python's ``get_package_share_directory`` makes, read here without
    importing a ROS package."""
    import os
    dirs = [Path(__file__).resolve().parents[2] / 'config' / 'scenes']
    for prefix in os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep):
        if prefix and (Path(prefix) / 'share' / 'ament_index' / 'resource_index' / 'packages'
                       / 'cvj_ros').is_file():
            dirs.append(Path(prefix) / 'share' / 'cvj_ros' / 'config' / 'scenes')
            break
    import sys
    dirs.append(Path(sys.prefix) / 'share' / 'cvj_ros' / 'config' / 'scenes')
    return [d for d in dict.fromkeys(dirs) if d.is_dir()]


def shipped_scenes() -> dict[str, Path]:
    """Shipped scene name -> file (first directory of :func:`scene_dirs` wins)."""
    out: dict[str, Path] = {}
    for d in scene_dirs():
        for f in sorted(d.glob('*.yaml')):
            out.setdefault(f.stem, f)
    return out


#: old shipped scene name -> its current name; the old name still works, with one line on stderr
DEPRECATED_SCENES: dict[str, str] = {'tripod_seed000': 'tripod_xiu2024'}


def find_scene(name_or_path: str | os.PathLike[str]) -> Path:
    """A scene file by path, or by shipped name (``kavz685_lever``). SceneError if neither.

    A deprecated shipped name (:data:`DEPRECATED_SCENES`) finds the renamed scene and prints
    one line on stderr naming the new name."""
    p = Path(name_or_path)
    if p.is_file():
        return p
    shipped = shipped_scenes()
    stem = p.name[:-5] if p.name.endswith('.yaml') else p.name
    if stem in shipped:
        return shipped[stem]
    if DEPRECATED_SCENES.get(stem) in shipped:
        import sys
        print(f"cvj_ros: scene name '{stem}' is deprecated; it is now "
              f"'{DEPRECATED_SCENES[stem]}'", file=sys.stderr, flush=True)
        return shipped[DEPRECATED_SCENES[stem]]
    near = difflib.get_close_matches(stem, list(shipped), n=1)
    hint = f"; did you mean '{near[0]}'?" if near else f'; shipped: {", ".join(shipped)}'
    raise SceneError('scene', f'no scene file or shipped scene {str(name_or_path)!r}{hint}')
