"""Model only what a scene needs: per-element fidelity choice.

Joints. Each cheaper fidelity is sampled over one input revolution (N points) against
the joint's exact model: e_phi = max |phi_out_cheap - phi_out_exact| (rad) and
e_ratio = max |ratio_cheap - ratio_exact|. The output speed is omega_out = ratio *
omega_in, so at a steady input speed the relative output-speed error is bounded by
e_speed = e_ratio / mean|ratio_exact|. The cheapest fidelity (ideal < closed < exact)
with e_speed <= accuracy_target is chosen; without a target 'auto' means exact.

Springs. Elastic unless it may become rigid: its natural frequency with the adjacent
rigid sections (reduced to the spring's shafts), omega_n = sqrt(c (1/J_l + 1/J_r)),
against the scene's excitation band omega_band = omega_op * n_max, where omega_op is
the initial first-inertia speed and n_max the highest excitation order per revolution
(joint ratio harmonics above 1 % of the largest one, engine firing order
cylinders/2 for a four-stroke when the engine spec gives ``cylinders``, at least 1).
Quasi-static bound: a spring-mass driven at r = omega_band/omega_n < 1 amplifies the
transmitted oscillation by 1/(1 - r^2), so treating it rigid errs by at most
e = r^2/(1 - r^2) (relative, of the oscillating part); rigid when e <= accuracy_target
(target 0.01 <=> omega_n >= ~10 omega_band). The static wind-up (mean torque / c) is
a constant angle offset and does not affect speeds. Without a target, or at standstill
start (omega_op = 0), springs stay elastic.

Vehicle scenes (a tree of differentials and wheels): the same spring rule with each
side's apparent inertia across the differentials and the vehicle's mass on gripping
tyres, the operating speed from the rolling initial state; the tyres' slip relaxation is
reported, never removed (cvj_ros.physics.fidelity_tree).

Chains and vehicle scenes with clutch, gearbox or brake: springs stay elastic unless forced;
each gets the lowest omega_n of its locked modes (every clutch stuck, each gear, the brake
stuck), the frequency an explicit solver must step (:func:`mode_chain_spring_omega_n`,
cvj_ros.physics.fidelity_tree.mode_tree_spring_omega_n).

Users force any level by scene (``fidelity:`` on an element) or by ``overrides``.
"""
from __future__ import annotations

import functools
import json
import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from cvj_ros.errors import SceneError
from cvj_ros.physics.joints import JOINTS, make_joint
from cvj_ros.physics.scene import Inertia, Joint, Scene, Spring, iter_elements
from cvj_ros.physics.sections import build_sections, section_kinematics

N_SAMPLES = 2048          # samples per revolution for joint error bounds
HARMONIC_FLOOR = 0.01     # joint harmonics above this fraction of the largest count
ORDER = {'ideal': 0, 'closed': 1, 'exact': 2}


@dataclass(frozen=True)
class FidelityChoice:
    """Choice for one element: chosen level, candidate bounds, and why."""

    name: str
    element: str                                  # 'joint' | 'spring' | 'tyre'
    chosen: str
    reason: str
    candidates: dict[str, dict[str, float]] = field(default_factory=dict)


@dataclass(frozen=True)
class FidelityReport:
    """Per-element fidelity choices of a scene (printable, JSON-serialisable)."""

    accuracy_target: float | None
    operating_speed: float                         # rad/s
    excitation_band: float                         # rad/s
    choices: tuple[FidelityChoice, ...]

    @property
    def levels(self) -> dict[str, str]:
        """Chosen level per joint and spring (a tyre's relaxation is always kept)."""
        return {c.name: c.chosen for c in self.choices if c.element != 'tyre'}

    def to_dict(self) -> dict[str, Any]:
        return {'accuracy_target': self.accuracy_target, 'operating_speed': self.operating_speed,
                'excitation_band': self.excitation_band,
                'choices': [asdict(c) for c in self.choices]}

    def to_json(self) -> str:
        return json.dumps(self.to_dict())

    def __str__(self) -> str:
        tgt = 'none' if self.accuracy_target is None else f'{self.accuracy_target:g}'
        lines = [f'fidelity (accuracy target {tgt}, operating speed {self.operating_speed:.4g} '
                 f'rad/s, excitation band {self.excitation_band:.4g} rad/s):']
        for c in self.choices:
            cand = ', '.join(f'{k} {_fmt_bound(v)}' for k, v in c.candidates.items())
            lines.append(f'  {c.name:<16} {c.element:<6} -> {c.chosen:<8} {c.reason}'
                         + (f' [{cand}]' if cand else ''))
        return '\n'.join(lines)


def _fmt_bound(b: Mapping[str, float]) -> str:
    if 'lag_error' in b:
        return f'lag e={b["lag_error"]:.2e}'
    return f'e={b.get("speed_error", float("nan")):.2e}'


def _params_key(params: Mapping[str, float]) -> tuple[tuple[str, str, str, Any], ...] | None:
    """Hashable key of a joint's parameters: (name, type, repr, value) per parameter, so
    values that compare equal but compute differently (1 and 1.0, 0.0 and -0.0) do not
    share an entry. None if a value is not hashable (then nothing is cached)."""
    key = tuple(sorted((k, type(v).__name__, repr(v), v) for k, v in dict(params).items()))
    try:
        hash(key)
    except TypeError:
        return None
    return key


def joint_error_bounds(kind: str, params: Mapping[str, float], *, n: int = N_SAMPLES
                       ) -> dict[str, dict[str, float]]:
    """Per fidelity of ``kind``: phi_error (rad), ratio_error (-), speed_error (-) vs exact.

    A pure function of (kind, params, n): cached per process (a sweep that does not vary a
    joint's geometry evaluates its bounds once instead of per variant, ~1.5 ms each for a
    lever hinge); callers get their own copy."""
    key = _params_key(params)
    bounds = _joint_error_bounds(kind, key, n) if key is not None else \
        _joint_error_bounds_uncached(kind, params, n)
    return {f: dict(b) for f, b in bounds.items()}


@functools.lru_cache(maxsize=1024)
def _joint_error_bounds(kind: str, key: tuple[tuple[str, str, str, Any], ...], n: int
                        ) -> dict[str, dict[str, float]]:
    return _joint_error_bounds_uncached(kind, {k: v for k, _t, _r, v in key}, n)


def _joint_error_bounds_uncached(kind: str, params: Mapping[str, float], n: int
                                 ) -> dict[str, dict[str, float]]:
    fids = JOINTS[kind].fidelities
    phi = np.linspace(0.0, 2.0 * math.pi, n, endpoint=False)
    ref = make_joint(kind, fidelity=fids[-1], **dict(params)).evaluate(phi)
    mean_ratio = float(np.mean(np.abs(ref.ratio))) or 1.0
    out = {}
    for f in fids:
        ev = make_joint(kind, fidelity=f, **dict(params)).evaluate(phi)
        e_phi = float(np.max(np.abs(ev.phi_out - ref.phi_out)))
        e_ratio = float(np.max(np.abs(ev.ratio - ref.ratio)))
        out[f] = {'phi_error': e_phi, 'ratio_error': e_ratio, 'speed_error': e_ratio / mean_ratio}
    return out


def joint_max_order(kind: str, params: Mapping[str, float], *, n: int = 256) -> int:
    """Highest harmonic (per input revolution) of the exact ratio above HARMONIC_FLOOR
    (cached per process like :func:`joint_error_bounds`)."""
    key = _params_key(params)
    return _joint_max_order(kind, key, n) if key is not None else \
        _joint_max_order_uncached(kind, params, n)


@functools.lru_cache(maxsize=1024)
def _joint_max_order(kind: str, key: tuple[tuple[str, str, str, Any], ...], n: int) -> int:
    return _joint_max_order_uncached(kind, {k: v for k, _t, _r, v in key}, n)


def _joint_max_order_uncached(kind: str, params: Mapping[str, float], n: int) -> int:
    fids = JOINTS[kind].fidelities
    phi = np.linspace(0.0, 2.0 * math.pi, n, endpoint=False)
    ratio = make_joint(kind, fidelity=fids[-1], **dict(params)).evaluate(phi).ratio
    amp = np.abs(np.fft.rfft(ratio - np.mean(ratio))) * 2.0 / n
    if amp.max() < 1e-12:
        return 0
    big = np.nonzero(amp >= HARMONIC_FLOOR * amp.max())[0]
    return int(big.max())


def engine_order(spec: Mapping[str, Any]) -> float:
    """Firing order per crank revolution: cylinders/2 (four-stroke) if ``cylinders`` given."""
    cyl = spec.get('cylinders')
    if isinstance(cyl, (int, float)) and not isinstance(cyl, bool) and cyl > 0:
        strokes = spec.get('strokes', 4)
        return float(cyl) * 2.0 / float(strokes if strokes in (2, 4) else 4)
    return 0.0


def spring_omega_n(stiffness: float, j_l: float, j_r: float) -> float:
    """Natural frequency omega_n = sqrt(c (1/J_l + 1/J_r)) (rad/s) of a spring of stiffness c
    (N m/rad) between the inertias J_l, J_r (kg m^2) it joins, the two-mass oscillator."""
    return math.sqrt(stiffness * (1.0 / j_l + 1.0 / j_r))


def choose_fidelity(scene: Scene, *, overrides: Mapping[str, str] | None = None
                    ) -> FidelityReport:
    """Resolve 'auto' levels of every joint and spring of ``scene`` (see module doc)."""
    overrides = dict(overrides or {})
    elements = list(iter_elements(scene.driveline))   # a chain's elements, or every branch's
    by_name = {el.name: el for el in elements}
    for name, level in overrides.items():
        el = by_name.get(name)
        if el is None or not isinstance(el, (Joint, Spring)):
            import difflib
            names = [e.name for e in elements if isinstance(e, (Joint, Spring))]
            near = difflib.get_close_matches(name, names, n=1)
            hint = f"; did you mean '{near[0]}'?" if near else f'; joints/springs: {", ".join(names)}'
            raise SceneError(f'fidelity.{name}', f'no joint or spring of that name{hint}')
        allowed = JOINTS[el.kind].fidelities if isinstance(el, Joint) else ('elastic', 'rigid')
        if level not in allowed:
            raise SceneError(f'fidelity.{name}', f'must be one of {", ".join(allowed)}, got {level!r}')
    target = scene.accuracy_target
    tree = scene.vehicle is not None
    # a vehicle scene without modes: springs and tyres by cvj_ros.physics.fidelity_tree
    tree_rule = tree and not scene.has_modes
    omega_op = abs(scene.initial_speed)
    order = max(1.0, engine_order(scene.engine))
    choices: list[FidelityChoice] = []
    joint_orders = []
    for el in elements:
        if not isinstance(el, Joint):
            continue
        fids = JOINTS[el.kind].fidelities
        bounds = joint_error_bounds(el.kind, el.params) if len(fids) > 1 else {}
        joint_orders.append(joint_max_order(el.kind, el.params))
        if el.name in overrides:
            chosen, reason = overrides[el.name], 'forced by argument'
        elif el.fidelity != 'auto':
            chosen, reason = el.fidelity, 'forced by scene'
        elif len(fids) == 1:
            chosen, reason = fids[0], 'only fidelity'
        elif target is None:
            chosen, reason = fids[-1], 'no accuracy target: exact'
        else:
            ok = [f for f in fids if bounds[f]['speed_error'] <= target]
            chosen = min(ok, key=lambda f: ORDER.get(f, 9))
            reason = (f'cheapest with speed error {bounds[chosen]["speed_error"]:.2e} '
                      f'<= target {target:g}')
        choices.append(FidelityChoice(el.name, 'joint', chosen, reason, bounds))
    if joint_orders:
        order = max(order, float(max(joint_orders)))
    joint_levels = {c.name: c.chosen for c in choices}
    if tree_rule:
        from cvj_ros.physics import fidelity_tree
        omega_op = fidelity_tree.tree_operating_speed(scene, joint_levels)
    band = omega_op * order
    springs = [el for el in elements if isinstance(el, Spring)]
    # a chain with clutch, gearbox or brake (cvj_ros.physics.hybrid.chain): springs as a
    # vehicle tree's with modes, elastic, omega_n the lowest over the locked modes
    mode_chain = not tree and any(getattr(el, 'type', '') in MODE_ELEMENT_TYPES for el in elements)
    adjacent = (_adjacent_inertias(scene, joint_levels)
                if springs and not tree and not mode_chain else {})
    if tree_rule and springs:
        tree_j = fidelity_tree.tree_spring_inertias(scene, joint_levels)
        adjacent = {name: (j['j_left_grip'], j['j_right_grip']) for name, j in tree_j.items()}
    mode_omega: dict[str, float] = {}
    if tree and not tree_rule and springs:
        from cvj_ros.physics import fidelity_tree
        mode_omega = fidelity_tree.mode_tree_spring_omega_n(scene, joint_levels)
    elif mode_chain and springs:
        mode_omega = mode_chain_spring_omega_n(scene, joint_levels)
    for el in springs:
        if (tree and not tree_rule) or mode_chain:
            # the adjacent inertias across a differential are a 2x2 matrix, not two numbers:
            # the rigid rule is not derived for them, a vehicle scene's springs stay elastic;
            # omega_n: the lowest over the locked modes (fidelity_tree.mode_tree_spring_omega_n)
            if el.name in overrides:
                chosen, reason = overrides[el.name], 'forced by argument'
            elif el.fidelity != 'auto':
                chosen, reason = el.fidelity, 'forced by scene'
            elif mode_chain:
                chosen, reason = 'elastic', ('with clutch, gearbox or brake: springs stay '
                                             'elastic unless forced')
            else:
                chosen, reason = 'elastic', 'vehicle scene: springs stay elastic unless forced'
            omega_low = mode_omega.get(el.name)
            cand = ({} if omega_low is None else
                    {'elastic': {'speed_error': 0.0, 'omega_n': omega_low}})
            choices.append(FidelityChoice(el.name, 'spring', chosen, reason, cand))
            continue
        j_l, j_r = adjacent[el.name]
        omega_n = spring_omega_n(el.stiffness, j_l, j_r)
        r = band / omega_n
        bound = r * r / (1.0 - r * r) if r < 1.0 else math.inf
        cand = {'elastic': {'speed_error': 0.0, 'omega_n': omega_n},
                'rigid': {'speed_error': bound, 'omega_n': omega_n}}
        if tree_rule:       # the free-tyre frequency, for information (the grip one decides)
            j = tree_j[el.name]
            cand['rigid']['omega_n_free_tyres'] = math.sqrt(
                el.stiffness * (1.0 / j['j_left'] + 1.0 / j['j_right']))
        if el.name in overrides:
            chosen, reason = overrides[el.name], 'forced by argument'
        elif el.fidelity != 'auto':
            chosen, reason = el.fidelity, 'forced by scene'
        elif target is None:
            chosen, reason = 'elastic', 'no accuracy target: elastic'
        elif band == 0.0:
            chosen, reason = 'elastic', 'standstill start: no excitation band, elastic'
        elif bound <= target:
            chosen = 'rigid'
            reason = (f'omega_n {omega_n:.4g} rad/s = {omega_n / band:.3g} x band, quasi-static '
                      f'error {bound:.2e} <= target')
        else:
            chosen = 'elastic'
            reason = (f'omega_n {omega_n:.4g} rad/s = {omega_n / band:.3g} x band, quasi-static '
                      f'error {bound:.2e} > target')
        choices.append(FidelityChoice(el.name, 'spring', chosen, reason, cand))
    if tree_rule:
        for name, b in fidelity_tree.tyre_relaxation_bounds(scene, band).items():
            tau = b['time_constant_s']
            choices.append(FidelityChoice(
                name, 'tyre', 'relaxed',
                f'slip relaxation kept (standstill regularisation), tau {tau:.3g} s at the '
                f'initial speed', {'instant': b}))
    return FidelityReport(target, omega_op, band, tuple(choices))


MODE_ELEMENT_TYPES = ('clutch', 'gearbox', 'brake')


def mode_chain_spring_omega_n(scene: Scene, joint_levels: Mapping[str, str]) -> dict[str, float]:
    """Per spring of a chain with clutch, gearbox or brake (cvj_ros.physics.hybrid.chain):
    the lowest natural frequency (rad/s) of its locked modes, min over the gears (each
    forward gear and reverse; one mode without a gearbox) of sqrt(c (1/J_l + 1/J_r)) with
    every clutch stuck and the brake stuck. A lock merges the sections on both sides into
    one rigid group (more inertia, a lower frequency); J_l = M_g / a_end^2 and J_r = M_g+1
    of the spring's two groups (sum J a^2 along the group, the group's end ratio a_end),
    averaged over 16 angles of one revolution as the chain rule; 1/J_r = 0 when a stuck
    brake pins the spring's right group. Empty when the chain cannot be built (its run
    names why)."""
    from cvj_ros.physics.hybrid.chain import HybridChain, Mode
    from cvj_ros.physics.hybrid.friction import STUCK
    levels = dict(joint_levels)
    stiffness = {el.name: el.stiffness for el in scene.driveline if isinstance(el, Spring)}
    levels.update({name: 'elastic' for name in stiffness})
    try:
        chain = HybridChain(scene.driveline, levels=levels)
    except (SceneError, KeyError, ValueError, ZeroDivisionError):
        return {}
    boxes = list(chain.gearboxes.values())
    gears = ([g for g in range(-1, len(boxes[0][0].ratios) + 1) if g != 0] if boxes else [0])
    qs = np.linspace(0.0, 2.0 * math.pi, 16, endpoint=False)
    low: dict[str, float] = {}
    for gear in gears:
        mode = Mode(clutch={name: STUCK for name in chain.clutches},
                    gear={name: gear for name in chain.gearboxes},
                    brake=STUCK if chain.brake is not None else None,
                    offsets={b: 0.0 for b in range(len(chain.boundaries))})
        asm = chain.assemble(mode)
        last = len(asm.groups) - 1
        for g, b in enumerate(asm.links):
            bd = chain.boundaries[b]
            if bd.kind != 'spring':
                continue
            left, right = asm.groups[g].ops, asm.groups[g + 1].ops
            try:
                j_l = float(np.mean([kin[3] / kin[1] ** 2
                                     for kin in (section_kinematics(left, q) for q in qs)]))
                j_r = (math.inf if asm.pinned and g + 1 == last else
                       float(np.mean([section_kinematics(right, q)[3] for q in qs])))
                w = spring_omega_n(stiffness[bd.name], j_l, j_r)
            except (ValueError, ZeroDivisionError):     # a singular group: no figure
                return {}
            low[bd.name] = min(low.get(bd.name, math.inf), w)
    return low


_ADJACENT: dict[tuple[Any, ...], dict[str, tuple[float, float]]] = {}
_ADJACENT_MAX = 1024


def _adjacent_key(scene: Scene, joint_levels: Mapping[str, str]) -> tuple[Any, ...] | None:
    """What :func:`_adjacent_inertias` depends on: every inertia (name, J, imbalance),
    joint (name, kind, parameters as in :func:`_params_key`) and spring name in chain order,
    and the joint levels; not the springs' laws (they are all elastic there). None when an
    element is of another type or a value is not hashable (nothing is cached)."""
    parts: list[Any] = []
    for el in scene.driveline:
        if isinstance(el, Inertia):
            parts.append(('inertia', el.name, type(el.J).__name__, repr(el.J), repr(el.imbalance)))
        elif isinstance(el, Joint):
            pk = _params_key(el.params)
            if pk is None:
                return None
            parts.append(('joint', el.name, el.kind, pk))
        elif isinstance(el, Spring):
            parts.append(('spring', el.name))
        else:
            return None
    return tuple(parts), tuple(sorted(joint_levels.items()))


def _adjacent_inertias(scene: Scene, joint_levels: Mapping[str, str]) -> dict[str, tuple[float, float]]:
    """Per spring: (J_left, J_right) in kg m^2 of the adjacent rigid sections reduced to
    the spring's two shafts, averaged over one revolution (all springs elastic). A pure
    function of :func:`_adjacent_key`: cached per process (a sweep of a spring's stiffness
    computes it once per joint geometry instead of per variant, ~0.2-0.3 ms each)."""
    key = _adjacent_key(scene, joint_levels)
    if key is None:
        return _adjacent_inertias_uncached(scene, joint_levels)
    out = _ADJACENT.get(key)
    if out is None:
        out = _adjacent_inertias_uncached(scene, joint_levels)
        if len(_ADJACENT) >= _ADJACENT_MAX:
            _ADJACENT.clear()
        _ADJACENT[key] = out
    return dict(out)


def _adjacent_inertias_uncached(scene: Scene, joint_levels: Mapping[str, str]
                                ) -> dict[str, tuple[float, float]]:
    levels = dict(joint_levels)
    levels.update({el.name: 'elastic' for el in scene.driveline if isinstance(el, Spring)})
    chain = build_sections(scene, levels)
    ops = chain.ops
    out = {}
    qs = np.linspace(0.0, 2.0 * math.pi, 16, endpoint=False)
    for k, sp in enumerate(chain.springs):
        j_l = float(np.mean([section_kinematics(ops[k], q)[3]
                             / section_kinematics(ops[k], q)[1] ** 2 for q in qs]))
        j_r = float(np.mean([section_kinematics(ops[k + 1], q)[3] for q in qs]))
        out[sp.name] = (j_l, j_r)
    return out
