"""Rigid sections of a scene's chain: element list -> per-section op lists, and the
section kinematics (phi_end, a, b, M, C) at a section angle q. Shared by
cvj_ros.physics.driveline (equations of motion) and cvj_ros.physics.fidelity (the spring
rule's adjacent inertias), so neither imports the other at module level.
See driveline.py's module docstring for the equations.
"""
from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

from cvj_ros.errors import SceneError
from cvj_ros.physics.joints import JOINTS, make_joint
from cvj_ros.physics.scene import Inertia, Joint, Scene, Spring

ScalarFn = Callable[[float], tuple[float, float, float]]
Op = tuple[float, 'ScalarFn | None']


@dataclass(frozen=True)
class SpringLaw:
    """Torque law of one elastic spring (units: N m/rad, N m s/rad, 1/rad^2, rad).

    Elastic deflection e(theta) is theta itself, or with backlash a softplus dead zone
    e = w ln(1+exp((theta-g)/w)) - w ln(1+exp((-theta-g)/w)), g = half gap, w = smoothing*g,
    which tends to theta -/+ g outside the gap and to ~0 inside, smooth everywhere so
    adaptive solvers keep their order. Potential V = c (e^2/2 + k2 e^4/4) (k2 = 0 for
    'linear'); torque T = dV/dtheta + d e'(theta) thetadot (damping acts only in contact).
    """

    name: str
    c: float
    d: float
    k2: float
    gap: float       # half gap g (rad), 0 = no backlash
    width: float     # smoothing width w (rad)

    def deflection(self, th: float) -> tuple[float, float, float]:
        """(e, de/dtheta, d2e/dtheta2) of the (regularised) dead zone."""
        g = self.gap
        if g == 0.0:
            return th, 1.0, 0.0
        w = self.width
        u1, u2 = (th - g) / w, (-th - g) / w
        sp1 = w * (max(u1, 0.0) + math.log1p(math.exp(-abs(u1))))
        sp2 = w * (max(u2, 0.0) + math.log1p(math.exp(-abs(u2))))
        s1 = _sigmoid(u1)
        s2 = _sigmoid(u2)
        return sp1 - sp2, s1 + s2, (s1 * (1.0 - s1) - s2 * (1.0 - s2)) / w

    def evaluate(self, th: float, thd: float) -> tuple[float, float, float, float, float]:
        """(torque N m, dT/dtheta, dT/dthetadot, potential J, dissipated power W)."""
        e, de, dde = self.deflection(th)
        c, k2, d = self.c, self.k2, self.d
        f_el = c * (e + k2 * e * e * e)          # dV/de
        t = f_el * de + d * de * thd
        k_th = c * (1.0 + 3.0 * k2 * e * e) * de * de + f_el * dde + d * dde * thd
        v = c * (0.5 * e * e + 0.25 * k2 * e ** 4)
        return t, k_th, d * de, v, d * de * thd * thd


def _sigmoid(u: float) -> float:
    if u >= 0.0:
        return 1.0 / (1.0 + math.exp(-u))
    z = math.exp(u)
    return z / (1.0 + z)


@dataclass(frozen=True)
class Shaft:
    """One named JointState shaft: section index, position in the op list, role."""

    name: str
    section: int
    op_index: int          # op of the section whose before/after state this shaft is
    role: str              # 'inertia' | 'input' | 'output' | 'mid'
    joint: Any = None      # joint model for 'mid'


@dataclass(frozen=True)
class SectionChain:
    """A scene's chain split at its elastic springs (see build_sections)."""

    ops: list[tuple[Op, ...]]          # per section: (J, None) inertia, (0.0, scalar_fn) joint
    names: list[list[str]]             # per section: element names in chain order
    springs: list[SpringLaw]           # one per section boundary
    shafts: list[Shaft]                # JointState shafts, engine -> load
    joint_models: dict[str, Any]       # joint name -> joint model


def build_sections(scene: Scene, levels: Mapping[str, str]) -> SectionChain:
    """Split ``scene.driveline`` at its elastic springs (springs at level 'rigid' merge their
    two sections); joints are built at ``levels[name]`` (default: their best fidelity)."""
    joint_models: dict[str, Any] = {}
    # ops per section: (J, None) for an inertia, (0.0, scalar_fn) for a joint
    sections: list[list[tuple[float, ScalarFn | None]]] = [[]]
    names: list[list[str]] = [[]]
    springs: list[SpringLaw] = []
    shafts: list[Shaft] = []
    made_by: list[int] = []            # per shaft: index of the element that made it
    for i, el in enumerate(scene.driveline):
        sec = len(sections) - 1
        if isinstance(el, Inertia):
            shafts.append(Shaft(el.name, sec, len(sections[sec]), 'inertia'))
            sections[sec].append((el.J, None))
            names[sec].append(el.name)
            made_by.append(i)
        elif isinstance(el, Joint):
            level = levels.get(el.name) or JOINTS[el.kind].fidelities[-1]
            try:
                model = make_joint(el.kind, fidelity=level, **dict(el.params))
            except ValueError as exc:
                raise SceneError(f'driveline[{i}]', str(exc)) from None
            joint_models[el.name] = model
            k = len(sections[sec])
            shafts.append(Shaft(f'{el.name}_input', sec, k, 'input'))
            mid = getattr(model, 'mid_name', None)
            if mid:
                shafts.append(Shaft(f'{el.name}_{mid}', sec, k, 'mid', model))
            shafts.append(Shaft(f'{el.name}_output', sec, k, 'output'))
            sections[sec].append((0.0, model.scalar))
            names[sec].append(el.name)
            made_by.extend([i] * (len(shafts) - len(made_by)))
        elif isinstance(el, Spring):
            if levels.get(el.name, 'elastic') == 'rigid':
                continue    # merged: the two sections become one rigid body
            g = 0.5 * el.backlash
            springs.append(SpringLaw(el.name, el.stiffness, el.damping,
                                     el.k2 if el.law == 'progressive' else 0.0,
                                     g, el.backlash_smoothing * g))
            sections.append([])
            names.append([])
        else:       # a clutch, gearbox or brake: cvj_ros.physics.hybrid splits the chain there
            raise SceneError(f'driveline[{i}]', f'{getattr(el, "type", type(el).__name__)} '
                                                f'{el.name!r} needs the mode-aware driveline '
                                                f'(cvj_ros.physics.hybrid)')
    origin: dict[str, int] = {}        # unique JointState names, by construction
    for sh, i in zip(shafts, made_by):
        j = origin.setdefault(sh.name, i)
        if j != i:
            a, b = scene.driveline[j].name, scene.driveline[i].name
            raise SceneError(f'driveline[{i}].name',
                             f'shaft name {sh.name!r} is made by both driveline[{j}] ({a!r}) and '
                             f'driveline[{i}] ({b!r}; a joint names its shafts <name>_input, '
                             f'<name>_output and <name>_<member>); rename one of them')
    return SectionChain([tuple(s) for s in sections], names, springs, shafts, joint_models)


def section_kinematics(ops: tuple[Op, ...], q: float) -> tuple[float, float, float, float, float]:
    """(phi_end, a_end, b_end, M, C) of one section's op list at q (rad, -, 1/rad, kg m^2,
    kg m^2/rad): a <- ratio a, b <- ratio_slope a^2 + ratio b, M = sum J a^2, C = sum J a b."""
    phi, a, b, m, c = q, 1.0, 0.0, 0.0, 0.0
    for jv, fn in ops:
        if fn is None:
            m += jv * a * a
            c += jv * a * b
        else:
            po, r, s = fn(phi)
            b = s * a * a + r * b
            a = r * a
            phi = po
    return phi, a, b, m, c
