"""Node parameters: ParamSpec declaration/validation, --param parsing, scene loading helpers.

Moved out of nodes/common.py (layout split); common.py re-exports these names.
"""

import math
import re
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, ParameterType, SetParametersResult
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException, ParameterException
from rclpy.node import Node
from rclpy.parameter import Parameter

from cvj_ros.errors import CvjError



NS_PER_S = 1_000_000_000

EXIT_OK, EXIT_RUNTIME, EXIT_PARAMETER = 0, 1, 2


class ParameterError(CvjError, ValueError):
    """Invalid ROS parameter; ``str()`` starts with the parameter name."""

    def __init__(self, parameter: str, message: str) -> None:
        self.parameter = parameter
        super().__init__(f'{parameter}: {message}')


# --- parameters -------------------------------------------------------------------------

@dataclass(frozen=True)
class ParamSpec:
    """One node parameter.

    Attributes:
        name: parameter name.
        default: default value; its Python type fixes the parameter type
            (bool, int, float, str, list[str]).
        description: meaning, with the unit in brackets (e.g. ``'exchange step [s]'``).
        lo, hi: numeric bounds (inclusive unless ``lo_open`` / ``hi_open``).
        choices: allowed string values.
        read_only: cannot be changed after start.
    """

    name: str
    default: Any
    description: str
    lo: float | None = None
    hi: float | None = None
    lo_open: bool = False
    hi_open: bool = False
    choices: tuple[str, ...] | None = None
    read_only: bool = True

    @property
    def kind(self) -> type:
        return type(self.default)

    def descriptor(self) -> ParameterDescriptor:
        """The rclpy descriptor: description, range, read_only, type."""
        d = ParameterDescriptor(name=self.name, read_only=self.read_only)
        text = self.description
        if self.choices:
            text += f' (one of: {", ".join(self.choices)})'
        d.description = text
        if self.kind is float:
            # Integers given on the command line (duration:=1) are accepted and converted.
            d.dynamic_typing = True
            if self.lo is not None and self.hi is not None:
                d.floating_point_range = [FloatingPointRange(from_value=float(self.lo),
                                                             to_value=float(self.hi), step=0.0)]
        elif self.kind is int and not isinstance(self.default, bool):
            d.type = ParameterType.PARAMETER_INTEGER
            if self.lo is not None and self.hi is not None:
                d.integer_range = [IntegerRange(from_value=int(self.lo), to_value=int(self.hi), step=0)]
        elif self.kind is bool:
            d.type = ParameterType.PARAMETER_BOOL
        elif self.kind is str:
            d.type = ParameterType.PARAMETER_STRING
        elif self.kind is list:
            d.type = ParameterType.PARAMETER_STRING_ARRAY
        return d

    def validate(self, value: Any) -> Any:
        """Return the value converted to the spec's type or raise :class:`ParameterError`."""
        name = self.name
        if self.kind is float:
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise ParameterError(name, f'must be a number, got {value!r}')
            value = float(value)
            if not math.isfinite(value):
                raise ParameterError(name, f'must be finite, got {value}')
        elif self.kind is int and not isinstance(self.default, bool):
            if isinstance(value, bool) or not isinstance(value, int):
                raise ParameterError(name, f'must be an integer, got {value!r}')
        elif self.kind is bool:
            if not isinstance(value, bool):
                raise ParameterError(name, f'must be true or false, got {value!r}')
        elif self.kind is str:
            if not isinstance(value, str):
                raise ParameterError(name, f'must be a string, got {value!r}')
        elif self.kind is list:
            if isinstance(value, str):
                value = [value] if value else []
            value = list(value or [])
            if not all(isinstance(v, str) for v in value):
                raise ParameterError(name, f'must be a list of strings, got {value!r}')
        if self.lo is not None and (value < self.lo or (self.lo_open and value == self.lo)):
            raise ParameterError(name, f'must be {">" if self.lo_open else ">="} {self.lo}, got {value}')
        if self.hi is not None and (value > self.hi or (self.hi_open and value == self.hi)):
            raise ParameterError(name, f'must be {"<" if self.hi_open else "<="} {self.hi}, got {value}')
        if self.choices is not None and value not in self.choices:
            raise ParameterError(name, f'must be one of {", ".join(self.choices)}; got {value!r}')
        return value


def declare_parameters(node: Node, specs: Sequence[ParamSpec]) -> dict[str, Any]:
    """Declare ``specs`` on ``node`` and return their validated values by name.

    Raises:
        ParameterError: the first invalid value (rclpy's own range/type rejections included).
    """
    values: dict[str, Any] = {}
    for spec in specs:
        default = spec.default
        if spec.kind is list:
            default = Parameter('x', Parameter.Type.STRING_ARRAY, list(default)).value
        try:
            param = node.declare_parameter(spec.name, default, spec.descriptor())
        except (InvalidParameterTypeException, InvalidParameterValueException,
                ParameterException) as exc:
            raise ParameterError(spec.name, _rclpy_reason(exc)) from None
        value = param.value
        if spec.kind is list and value is None:
            value = []
        values[spec.name] = spec.validate(value)
    by_name = {s.name: s for s in specs}

    def on_set(params: list[Parameter]) -> SetParametersResult:
        for p in params:
            spec = by_name.get(p.name)
            if spec is None:
                continue
            try:
                values[p.name] = spec.validate(p.value)
            except ParameterError as exc:
                return SetParametersResult(successful=False, reason=str(exc))
        return SetParametersResult(successful=True)

    node.add_on_set_parameters_callback(on_set)
    return values


_TYPE_REJECTED = re.compile(r"Trying to set parameter '[^']*' to '(?P<value>.*)' of type "
                            r"'(?P<got>\w+)', expecting type '(?:Type\.)?(?P<want>\w+)'", re.S)


def _rclpy_reason(exc: Exception) -> str:
    """rclpy's rejection as the problem part of one line; a type rejection (``-p seed:=abc``)
    as ``must be of type INTEGER, got 'abc' (STRING)`` instead of rclpy's sentence, which
    repeats the name after a colon."""
    m = _TYPE_REJECTED.search(str(exc.args[0]) if exc.args else '')
    if m:
        return f"must be of type {m['want']}, got {m['value']!r} ({m['got']})"
    text = str(exc).strip().splitlines()
    return text[-1] if text else type(exc).__name__


def parse_assignments(name: str, items: Iterable[str]) -> dict[str, str]:
    """Parse a string list ``["joint=level", ...]`` into a dict (``ParameterError`` on bad items)."""
    out: dict[str, str] = {}
    for i, item in enumerate(items):
        key, sep, val = item.partition('=')
        if not sep or not key.strip() or not val.strip():
            raise ParameterError(f'{name}[{i}]', f'expected "name=value", got {item!r}')
        out[key.strip()] = val.strip()
    return out


def load_yaml_mapping(name: str, text: str) -> dict[str, Any]:
    """Parse a YAML/JSON mapping given as a parameter string (empty -> {})."""
    import yaml
    if not text.strip():
        return {}
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise ParameterError(name, f'not valid YAML: {str(exc).splitlines()[0]}') from None
    if not isinstance(data, dict):
        raise ParameterError(name, f'must be a YAML mapping, got {type(data).__name__}')
    return data


# --- scene ------------------------------------------------------------------------------

def load_scene_param(value: str) -> Any:
    """Resolve the ``scene`` parameter (scene name or YAML path) to a Scene.

    Raises:
        ParameterError: naming ``scene`` and, for an invalid scene file, its field.
    """
    from cvj_ros.physics.scene import find_scene, load_scene
    if not value.strip():
        raise ParameterError('scene', 'must name a scene (e.g. kavz685_lever) or a scene YAML path')
    try:
        return load_scene(find_scene(value))
    except CvjError as exc:
        text = str(exc)
        if text.startswith('scene: '):
            text = text[len('scene: '):]
        elif not text.startswith(value):
            text = f'{value}: {text}'
        raise ParameterError('scene', text) from None
    except OSError as exc:
        raise ParameterError('scene', f'{value}: {exc.strerror or exc}') from None


def scene_dict(scene: Any) -> dict[str, Any]:
    """The scene as a plain dict (``Scene.to_dict()``)."""
    return scene.to_dict() if hasattr(scene, 'to_dict') else dict(scene)


def scene_elements(driveline: Any) -> Iterator[Mapping[str, Any]]:
    """Every element mapping of a scene dict's ``driveline`` list, depth first: a
    differential, then its ``left`` and its ``right`` branch (a vehicle scene)."""
    for el in driveline or []:
        if not isinstance(el, Mapping):
            continue
        yield el
        if el.get('type') == 'differential':
            yield from scene_elements(el.get('left'))
            yield from scene_elements(el.get('right'))


def inertia_names(scene: Any) -> list[str]:
    """Names of the scene's inertias, engine side first (the shafts engine and load act on).

    Reads ``Scene.to_dict()['driveline']``; an element is an inertia when its ``type``
    (or ``element``/``kind``) is ``'inertia'`` or it is a one-key mapping ``{inertia: {...}}``.
    """
    names: list[str] = []
    for el in scene_dict(scene).get('driveline', []) or []:
        if not isinstance(el, Mapping):
            continue
        tag = el.get('type', el.get('element', el.get('kind')))
        if tag == 'inertia' and 'name' in el:
            names.append(str(el['name']))
        elif len(el) == 1 and 'inertia' in el and isinstance(el['inertia'], Mapping):
            names.append(str(el['inertia'].get('name')))
    if not names:
        raise ParameterError('scene', 'the scene has no inertia elements in its driveline')
    return names


def scene_seed(scene: Any, seed_param: int) -> int:
    """Seed to use: the ``seed`` parameter when >= 0, else the scene's seed (default 0)."""
    if seed_param >= 0:
        return seed_param
    seed = getattr(scene, 'seed', None)
    if seed is None:
        seed = scene_dict(scene).get('seed', 0)
    return int(seed or 0)


# --- stamps and diagnostics ---------------------------------------------------------------
