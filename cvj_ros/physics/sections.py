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
from typing import Any, NamedTuple

from cvj_ros.errors import SceneError
from cvj_ros.physics.joints import JOINTS, make_joint
from cvj_ros.physics.scene import GRAVITY, Inertia, Joint, Scene, Spring

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

    Circumferentially varying stiffness (``variation``, (order n, eps, psi rad) terms): the
    potential is s(phi) V(theta), s = 1 + sum eps cos(n phi + psi), phi the angle of the
    shaft right of the spring (the element turns with it). Both sides then carry s dV/dtheta
    (+ damping), and the right side also -ds/dphi V (:meth:`evaluate_varying`).
    """

    name: str
    c: float
    d: float
    k2: float
    gap: float       # half gap g (rad), 0 = no backlash
    width: float     # smoothing width w (rad)
    variation: tuple[tuple[int, float, float], ...] = ()

    def modulation(self, phi: float) -> tuple[float, float, float]:
        """(s, ds/dphi, d2s/dphi2) of s(phi) = 1 + sum eps cos(n phi + psi)."""
        s, s1, s2 = 1.0, 0.0, 0.0
        for n, eps, psi in self.variation:
            x = n * phi + psi
            cx, sx = math.cos(x), math.sin(x)
            s += eps * cx
            s1 -= eps * n * sx
            s2 -= eps * n * n * cx
        return s, s1, s2

    def evaluate_varying(self, th: float, thd: float, phi: float) -> VaryingSpring:
        """Torques and partials of the spring with varying stiffness at twist th (rad),
        twist rate thd (rad/s) and right-shaft angle phi (rad); see :class:`VaryingSpring`."""
        e, de, dde = self.deflection(th)
        c, k2, d = self.c, self.k2, self.d
        f_el = c * (e + k2 * e * e * e)
        el = f_el * de                                   # dV/dtheta
        k_el = c * (1.0 + 3.0 * k2 * e * e) * de * de + f_el * dde
        v0 = c * (0.5 * e * e + 0.25 * k2 * e ** 4)
        s, s1, s2 = self.modulation(phi)
        return VaryingSpring(s * el + d * de * thd, -s1 * v0, s * k_el + d * dde * thd,
                             d * de, s1 * el, -s1 * el, -s2 * v0, s * v0, d * de * thd * thd)

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


class VaryingSpring(NamedTuple):
    """One evaluation of a spring with varying stiffness (SpringLaw.evaluate_varying).

    ``torque`` acts on both sides (-torque a_end on the left section, +torque on the right),
    ``extra`` = -ds/dphi V on the right section only (N m); partials by theta (N m/rad),
    thetadot (N m s/rad) and the explicit phi (N m/rad); ``potential`` s V (J) and the
    dissipated power (W)."""

    torque: float
    extra: float
    dt_dth: float
    dt_dthd: float
    dt_dphi: float
    dx_dth: float
    dx_dphi: float
    potential: float
    p_damp: float


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
    # per section: (op index of the inertia, m g e N m, angle rad) of each imbalance
    imbalances: list[list[tuple[int, float, float]]]


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
    imbalances: list[list[tuple[int, float, float]]] = [[]]
    for i, el in enumerate(scene.driveline):
        sec = len(sections) - 1
        if isinstance(el, Inertia):
            shafts.append(Shaft(el.name, sec, len(sections[sec]), 'inertia'))
            if el.imbalance is not None and el.imbalance[0] * el.imbalance[1] > 0.0:
                m, e, ang = el.imbalance
                imbalances[sec].append((len(sections[sec]), m * GRAVITY * e, ang))
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
                                     g, el.backlash_smoothing * g, el.variation))
            sections.append([])
            names.append([])
            imbalances.append([])
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
    return SectionChain([tuple(s) for s in sections], names, springs, shafts, joint_models,
                        imbalances)


def section_imbalance(ops: tuple[Op, ...], imbs: list[tuple[int, float, float]], q: float
                      ) -> tuple[float, float, float]:
    """(Q N m, dQ/dq N m/rad, V J) of a section's imbalances at q: each unbalanced inertia
    at angle phi_i (a_i = dphi_i/dq, b_i = d2phi_i/dq2) has the potential
    V = m g e sin(phi_i + angle), so Q = -sum m g e cos(phi_i + angle) a_i and
    dQ/dq = sum m g e (sin(phi_i + angle) a_i^2 - cos(phi_i + angle) b_i)."""
    qf, dq, v = 0.0, 0.0, 0.0
    want = {k: (mge, ang) for k, mge, ang in imbs}
    phi, a, b = q, 1.0, 0.0
    for k, (_jv, fn) in enumerate(ops):
        if fn is None:
            if k in want:
                mge, ang = want[k]
                c, sn = math.cos(phi + ang), math.sin(phi + ang)
                qf -= mge * c * a
                dq += mge * (sn * a * a - c * b)
                v += mge * sn
        else:
            po, r, sl = fn(phi)
            b = sl * a * a + r * b
            a = r * a
            phi = po
    return qf, dq, v


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


def section_slopes(ops: tuple[Op, ...], q: float
                   ) -> tuple[float, float, float, float, float, float, bool]:
    """(phi_end, a_end, b_end, M, C, dM/dq, has a joint op) of one section's op list at q:
    :func:`section_kinematics` plus dM/dq = sum 2 J a b (kg m^2/rad), for the analytic
    Jacobians (a section without joints has constant M, C = 0)."""
    phi, a, b, m, c, dm = q, 1.0, 0.0, 0.0, 0.0, 0.0
    has_joint = False
    for jv, fn in ops:
        if fn is None:
            m += jv * a * a
            c += jv * a * b
            dm += 2.0 * jv * a * b
        else:
            has_joint = True
            po, r, s = fn(phi)
            b = s * a * a + r * b
            a = r * a
            phi = po
    return phi, a, b, m, c, dm, has_joint
