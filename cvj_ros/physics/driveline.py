"""Driveline equations of motion (Lagrange, second kind; Davidbaev et al. 2023, eq. 3.17).

A scene's chain (engine -> elements -> load) is split at its elastic springs into
*rigid sections*. Each section is one degree of freedom q (rad): the angle of the
section's first shaft (the shaft just right of the spring, or the first inertia).
Every other shaft angle in the section follows through the joints' position functions,
phi_i = f(q), with a_i = dphi_i/dq and b_i = d2phi_i/dq2 obtained by the chain rule
from each joint's ``scalar()`` (phi_out, ratio, ratio_slope):

    a <- ratio * a,   b <- ratio_slope * a^2 + ratio * b.

Kinetic energy T = 1/2 M(q) qdot^2 with M(q) = sum J_i a_i^2, so Lagrange gives

    M(q) qddot + C(q) qdot^2 = Q,     C(q) = sum J_i a_i b_i  (= M'(q)/2).

Springs act between neighbouring sections on a *bounded* twist
theta = phi_end(q_left) - q_right, where phi_end is the angle of the last shaft of the
left section (through any joints that sit between its last inertia and the spring).
This replaces Davidbaev et al. 2023's 1/2 c (phi1 - U12 phi2)^2, which grows with every revolution
(README "Errors in the source documents"). Spring torque T_s = dV/dtheta + damping; it acts with -T_s a_end
on the left section and +T_s on the right one.

External torques: the engine torque acts on the first inertia (positive drives), the
load torque on the last inertia (positive resists), each times that shaft's a.

Imperfections (docs/imperfections.md): a spring with ``stiffness_variation`` has the
potential s(phi) V(theta) over the angle phi = q_right of the section to its right, which
also gets -s'(phi) V; an inertia with ``imbalance`` adds the potential m g e sin(phi_i +
angle), i.e. -m g e cos(phi_i + angle) a_i to its section's force (section_imbalance).

State ``x = [q_0..q_{n-1}, qdot_0..qdot_{n-1}]`` (rad, rad/s), optionally followed by the
work integrals ``[W_engine, W_load, W_damp]`` (J) when built with
``track_energy=True``: then ``energy_residual(x, E0)`` closes the balance
E_kin + E_el - E0 - W_engine + W_load + W_damp = 0.

JointState names (stable, ordered engine -> load): every inertia name; for each joint
``<joint>_input``, ``<joint>_<mid>`` (when the model has an intermediate member:
cage, spider, yoke, earring) and ``<joint>_output``.
"""
from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from cvj_ros.errors import SceneError
from cvj_ros.physics.fidelity import choose_fidelity
from cvj_ros.physics.scene import Scene, Spring
from cvj_ros.physics.sections import (  # noqa: F401  (SpringLaw, Shaft re-exported)
    ScalarFn, Shaft, SpringLaw, build_sections, section_imbalance, section_kinematics,
    section_slopes)

FloatArray = NDArray[np.float64]


class Driveline:
    """Equations of motion of a scene's chain; see the module docstring.

    Build with :meth:`from_scene`. ``levels`` maps element names to the fidelity used:
    joints 'ideal' | 'closed' | 'exact', springs 'elastic' | 'rigid'.
    """

    def __init__(self, scene: Scene, levels: Mapping[str, str], *, track_energy: bool = False) -> None:
        if scene.is_tree:
            raise SceneError('driveline', 'a vehicle scene (wheels, differentials) is not a '
                                          'chain: build it with build_driveline or TreeDriveline')
        self.scene = scene
        self.levels = dict(levels)
        self.track_energy = track_energy
        chain = build_sections(scene, self.levels)
        self.joint_models: dict[str, Any] = chain.joint_models
        sections, names, springs, shafts = chain.ops, chain.names, chain.springs, chain.shafts
        self._ops = sections
        self._section_names = names
        self._imbalances = chain.imbalances      # per section: (op index, m g e, angle)
        self.springs = springs
        self.shafts = shafts
        self.shaft_names = [s.name for s in shafts]
        # (mid column, its joint's input column)
        self._mid_index = [(i, i - 1) for i, sh in enumerate(shafts) if sh.role == 'mid']
        self.n_dof = len(sections)
        self._n_state = 2 * self.n_dof + (3 if track_energy else 0)
        self.x0 = self._initial_state()
        self._fast_rhs: Callable[..., FloatArray] | None = None   # built on first use

    @property
    def _fast(self) -> Callable[..., FloatArray]:
        """The generated Python right-hand side (:meth:`_generate_rhs`), built on first use:
        the compiled kernel never calls it, and generating it (``compile``) costs ~0.3 ms
        per driveline, a few per cent of a sweep variant."""
        if self._fast_rhs is None:
            # varying spring stiffness or an imbalance: the readable reference (not generated)
            plain = not any(sp.variation for sp in self.springs) and not any(self._imbalances)
            self._fast_rhs = self._generate_rhs() if plain else self._rhs
        return self._fast_rhs

    # --- construction -------------------------------------------------------------------

    @classmethod
    def from_scene(cls, scene: Scene, *, fidelity: Mapping[str, str] | None = None,
                   track_energy: bool = False) -> Driveline:
        """Resolve per-element fidelity (cvj_ros.physics.fidelity) and build the equations.

        ``fidelity`` forces levels by element name (joints: ideal|closed|exact, springs:
        elastic|rigid); the rest follows the scene (auto -> accuracy_target rule).
        """
        if scene.has_modes:
            from cvj_ros.physics.hybrid.scene_keys import mode_gap
            field, reason = mode_gap(scene)
            raise SceneError(field, reason)
        report = choose_fidelity(scene, overrides=fidelity)
        dl = cls(scene, report.levels, track_energy=track_energy)
        dl.fidelity_report = report
        return dl

    def _initial_state(self) -> FloatArray:
        """Rigid-body start: first inertia at scene angle/speed, each spring at its
        initial twist with zero twist rate."""
        sc = self.scene
        twist0 = {el.name: el.initial_twist for el in sc.driveline if isinstance(el, Spring)}
        x = np.zeros(self._n_state)
        n = self.n_dof
        q, v = sc.initial_angle, sc.initial_speed
        for g in range(n):
            x[g], x[n + g] = q, v
            phi, a, _b, _m, _c = self._section(g, q)
            if g < n - 1:
                q = phi - twist0[self.springs[g].name]
                v = a * v
        return x

    # --- kinematics of one section ------------------------------------------------------

    def _section(self, g: int, q: float) -> tuple[float, float, float, float, float]:
        """(phi_end, a_end, b_end, M, C) of section g at q (rad, -, 1/rad, kg m^2, kg m^2/rad)."""
        return section_kinematics(self._ops[g], q)

    def mass(self, x: FloatArray) -> FloatArray:
        """Generalised inertias M_g(q_g) (kg m^2)."""
        return np.array([self._section(g, float(x[g]))[3] for g in range(self.n_dof)])

    # --- right-hand side ----------------------------------------------------------------

    def rhs(self, t: float, x: FloatArray, T_engine: float, T_load: float) -> FloatArray:
        """dx/dt for engine torque ``T_engine`` and resisting load torque ``T_load`` (N m)."""
        return self._fast(t, x, T_engine, T_load, None, None)

    def rhs_sources(self, t: float, x: FloatArray, engine: Any, load: Any) -> FloatArray:
        """dx/dt with the torque sources evaluated inside (one kinematics pass):
        T_e = engine.torque(t, omega_first, phi_first), T_l = load.torque(t, omega_last, phi_last)."""
        return self._fast(t, x, 0.0, 0.0, engine.torque, load.torque)

    def _generate_rhs(self) -> Callable[..., FloatArray]:
        """Straight-line Python for this chain (loops unrolled, constants inlined, a section's
        inertias before its first joint summed at build time); same arithmetic as
        :meth:`_rhs`, which stays the readable reference (tests compare the two)."""
        n = self.n_dof
        ns: dict[str, Any] = {'np_array': np.array}
        L = ['def rhs(t, x, T_engine, T_load, engine_fn, load_fn):', ' xl = x.tolist()']
        for g, ops in enumerate(self._ops):
            L.append(f' q{g} = xl[{g}]; v{g} = xl[{n + g}]')
            m0 = 0.0
            k0 = len(ops)
            for k, (jv, fn) in enumerate(ops):
                if fn is not None:
                    k0 = k
                    break
                m0 += jv
            L.append(f' m{g} = {m0!r}; c{g} = 0.0')
            if k0 == len(ops):
                L.append(f' p{g} = q{g}; a{g} = 1.0; b{g} = 0.0')
                continue
            ns[f'F{g}_{k0}'] = ops[k0][1]
            L.append(f' p{g}, a{g}, b{g} = F{g}_{k0}(q{g})')
            for k in range(k0 + 1, len(ops)):
                jv, fn = ops[k]
                if fn is None:
                    L.append(f' m{g} += {jv!r} * a{g} * a{g}; c{g} += {jv!r} * a{g} * b{g}')
                else:
                    ns[f'F{g}_{k}'] = fn
                    L.append(f' p{g}, r, s = F{g}_{k}(p{g}); b{g} = s * a{g} * a{g} + r * b{g}; '
                             f'a{g} = r * a{g}')
        last = n - 1
        L.append(' if engine_fn is not None:')
        L.append(f'  T_engine = engine_fn(t, v0, q0); T_load = load_fn(t, a{last} * v{last}, p{last})')
        L.append(' Q0 = T_engine')
        for g in range(1, n):
            L.append(f' Q{g} = 0.0')
        L.append(f' Q{last} -= T_load * a{last}')
        L.append(' pd = 0.0')
        for k, sp in enumerate(self.springs):
            L.append(f' th = p{k} - q{k + 1}; thd = a{k} * v{k} - v{k + 1}')
            if sp.gap == 0.0:
                el = f'{sp.c!r} * th' if sp.k2 == 0.0 else f'{sp.c!r} * (th + {sp.k2!r} * th * th * th)'
                L.append(f' ts = {el} + {sp.d!r} * thd; pd += {sp.d!r} * thd * thd')
            else:
                ns[f'SP{k}'] = sp.evaluate
                L.append(f' ts, _k, _kd, _v, pdk = SP{k}(th, thd); pd += pdk')
            L.append(f' Q{k} -= ts * a{k}; Q{k + 1} += ts')
        out = [f'v{g}' for g in range(n)] + [f'(Q{g} - c{g} * v{g} * v{g}) / m{g}' for g in range(n)]
        if self.track_energy:
            out += ['T_engine * v0', f'T_load * a{last} * v{last}', 'pd']
        L.append(f' return np_array([{", ".join(out)}])')
        exec(compile('\n'.join(L), f'<driveline rhs {self.scene.name}>', 'exec'), ns)  # noqa: S102
        return ns['rhs']

    def _rhs(self, t: float, x: FloatArray, T_engine: float, T_load: float,
             engine_fn: Callable[..., float] | None, load_fn: Callable[..., float] | None
             ) -> FloatArray:
        n = self.n_dof
        xl = x.tolist()
        out = [0.0] * self._n_state
        ends = []
        q_force = [0.0] * n
        for g in range(n):
            phi, a, _b, m, c = self._section(g, xl[g])
            ends.append((phi, a, m, c))
        a_load = ends[-1][1]
        if engine_fn is not None:
            T_engine = engine_fn(t, xl[n], xl[0])
            T_load = load_fn(t, a_load * xl[2 * n - 1], ends[-1][0])
        q_force[0] += T_engine
        q_force[-1] -= T_load * a_load
        for g, imbs in enumerate(self._imbalances):
            if imbs:
                q_force[g] += section_imbalance(self._ops[g], imbs, xl[g])[0]
        p_damp = 0.0
        for k, sp in enumerate(self.springs):
            phi_l, a_l = ends[k][0], ends[k][1]
            th = phi_l - xl[k + 1]
            thd = a_l * xl[n + k] - xl[n + k + 1]
            extra = 0.0
            if sp.variation:
                vs = sp.evaluate_varying(th, thd, xl[k + 1])
                ts, extra = vs.torque, vs.extra
                p_damp += vs.p_damp
            elif sp.gap == 0.0:
                ts = sp.c * (th + sp.k2 * th * th * th) + sp.d * thd
                p_damp += sp.d * thd * thd
            else:
                ts, _k, _kd, _v, pd = sp.evaluate(th, thd)
                p_damp += pd
            q_force[k] -= ts * a_l
            q_force[k + 1] += ts + extra
        for g in range(n):
            v = xl[n + g]
            out[g] = v
            out[n + g] = (q_force[g] - ends[g][3] * v * v) / ends[g][2]
        if self.track_energy:
            out[2 * n] = T_engine * xl[n]
            out[2 * n + 1] = T_load * a_load * xl[2 * n - 1]
            out[2 * n + 2] = p_damp
        return np.array(out)

    def jacobian(self, t: float, x: FloatArray, T_engine: float, T_load: float, *,
                 dTe_domega: float = 0.0, dTl_domega: float = 0.0,
                 dTe_dphi: float = 0.0, dTl_dphi: float = 0.0) -> FloatArray:
        """Analytic d(rhs)/dx; torque slopes dT/domega (N m s/rad) and dT/dphi (N m/rad,
        firing ripple, Fourier load over shaft angle) of engine and load close the loop.
        Only dC/dq (third derivative of the joint position functions, which the joint
        contract does not give) is a central difference of C(q)."""
        n = self.n_dof
        ns = self._n_state
        n2 = 2 * n
        xl = x.tolist()
        sec = []
        for g in range(n):
            q = xl[g]
            phi, a, b, m, c, mp, has_joint = section_slopes(self._ops[g], q)
            if has_joint:
                h = 1e-6 * max(1.0, abs(q))
                cp = (self._section(g, q + h)[4] - self._section(g, q - h)[4]) / (2.0 * h)
            else:
                cp = 0.0
            sec.append((phi, a, b, m, c, mp, cp))
        qf = [0.0] * n
        dq = [[0.0] * n2 for _ in range(n)]      # dQ_g / d[q, v]
        qf[0] += T_engine
        dq[0][n] += dTe_domega
        dq[0][0] += dTe_dphi
        al, bl = sec[-1][1], sec[-1][2]
        vl = xl[n2 - 1]
        qf[-1] -= T_load * al
        dq[n - 1][n - 1] += -T_load * bl - dTl_domega * bl * vl * al - dTl_dphi * al * al
        dq[n - 1][n2 - 1] += -dTl_domega * al * al
        for g, imbs in enumerate(self._imbalances):
            if imbs:
                qi, dqi, _v = section_imbalance(self._ops[g], imbs, xl[g])
                qf[g] += qi
                dq[g][g] += dqi
        dpd = [0.0] * n2                         # d(p_damp)/d[q, v]
        for k, sp in enumerate(self.springs):
            phi_l, a_l, b_l = sec[k][0], sec[k][1], sec[k][2]
            th = phi_l - xl[k + 1]
            thd = a_l * xl[n + k] - xl[n + k + 1]
            # partials: dtheta/dq_k = a_l, dtheta/dq_k+1 = -1; dthetadot/dq_k = b_l v_k,
            # dthetadot/dv_k = a_l, dthetadot/dv_k+1 = -1
            dthd_qk = b_l * xl[n + k]
            if sp.variation:     # stiffness over phi = q_k+1, extra torque on the right only
                vs = sp.evaluate_varying(th, thd, xl[k + 1])
                ts, k_th, k_d = vs.torque, vs.dt_dth, vs.dt_dthd
                qf[k + 1] += vs.extra
                dq[k + 1][k] += vs.dx_dth * a_l
                dq[k + 1][k + 1] += vs.dx_dphi - vs.dx_dth
                explicit = vs.dt_dphi
            else:
                ts, k_th, k_d, _v, _pd = sp.evaluate(th, thd)
                explicit = 0.0
            d_qk = k_th * a_l + k_d * dthd_qk
            d_qk1 = explicit - k_th
            d_vk = k_d * a_l
            d_vk1 = -k_d
            qf[k] -= ts * a_l
            qf[k + 1] += ts
            rk, rk1 = dq[k], dq[k + 1]
            rk[k] -= d_qk * a_l + ts * b_l
            rk[k + 1] -= d_qk1 * a_l
            rk[n + k] -= d_vk * a_l
            rk[n + k + 1] -= d_vk1 * a_l
            rk1[k] += d_qk
            rk1[k + 1] += d_qk1
            rk1[n + k] += d_vk
            rk1[n + k + 1] += d_vk1
            if self.track_energy and sp.d != 0.0:
                # dissipation power p = d e' thd^2 (theta dependence through e')
                _e, de, dde = sp.deflection(th)
                dp_dth = sp.d * dde * thd * thd
                dp_dthd = 2.0 * sp.d * de * thd
                dpd[k] += dp_dth * a_l + dp_dthd * dthd_qk
                dpd[k + 1] -= dp_dth
                dpd[n + k] += dp_dthd * a_l
                dpd[n + k + 1] -= dp_dthd
        pad = [0.0] * (ns - n2)
        rows: list[list[float]] = []
        for g in range(n):
            row = [0.0] * ns
            row[n + g] = 1.0
            rows.append(row)
        for g in range(n):
            _phi, _a, _b, m, c, mp, cp = sec[g]
            v = xl[n + g]
            inv = 1.0 / m
            row = [d * inv for d in dq[g]]
            row[g] += -cp * v * v * inv - (qf[g] - c * v * v) * mp * inv * inv
            row[n + g] += -2.0 * c * v * inv
            rows.append(row + pad)
        if self.track_energy:
            we = [0.0] * ns
            we[n] = T_engine + dTe_domega * xl[n]
            we[0] = dTe_dphi * xl[n]               # W_e' = T_e(q_0, v_0) v_0
            wl = [0.0] * ns
            wl[n - 1] = (T_load * bl * vl + dTl_domega * bl * vl * al * vl
                         + dTl_dphi * al * al * vl)  # W_l' = T_l(phi_l(q), a v) a v
            wl[n2 - 1] = T_load * al + dTl_domega * al * al * vl
            rows += [we, wl, dpd + pad]
        return np.array(rows)

    # --- views ----------------------------------------------------------------------------

    @property
    def state_names(self) -> list[str]:
        """Names of the entries of x: '<first shaft of section g>.angle' (rad), then '.speed'
        (rad/s), then with track_energy 'W_engine', 'W_load', 'W_damp' (J)."""
        first = [next(sh.name for sh in self.shafts if sh.section == g) for g in range(self.n_dof)]
        names = [f'{f}.angle' for f in first] + [f'{f}.speed' for f in first]
        return names + (['W_engine', 'W_load', 'W_damp'] if self.track_energy else [])

    def engine_omega(self, x: FloatArray) -> float:
        """Speed of the first inertia (rad/s), where the engine acts."""
        return float(x[self.n_dof])

    def engine_phi(self, x: FloatArray) -> float:
        """Angle of the first inertia (rad)."""
        return float(x[0])

    def load_omega(self, x: FloatArray) -> float:
        """Speed of the last inertia (rad/s), where the load acts."""
        _phi, a, _b, _m, _c = self._section(self.n_dof - 1, float(x[self.n_dof - 1]))
        return a * float(x[2 * self.n_dof - 1])

    def load_phi(self, x: FloatArray) -> float:
        """Angle of the last inertia (rad)."""
        return self._section(self.n_dof - 1, float(x[self.n_dof - 1]))[0]

    def load_state(self, x: FloatArray) -> tuple[float, float]:
        """(angle rad, speed rad/s) of the last inertia in one pass."""
        phi, a, _b, _m, _c = self._section(self.n_dof - 1, float(x[self.n_dof - 1]))
        return phi, a * float(x[2 * self.n_dof - 1])

    def spring_twists(self, x: FloatArray) -> dict[str, tuple[float, float, float]]:
        """Per elastic spring: (twist rad, twist rate rad/s, torque N m)."""
        n = self.n_dof
        out = {}
        for k, sp in enumerate(self.springs):
            phi_l, a_l, _b, _m, _c = self._section(k, float(x[k]))
            th = phi_l - float(x[k + 1])
            thd = a_l * float(x[n + k]) - float(x[n + k + 1])
            if sp.variation:
                out[sp.name] = (th, thd, sp.evaluate_varying(th, thd, float(x[k + 1])).torque)
            else:
                out[sp.name] = (th, thd, sp.evaluate(th, thd)[0])
        return out

    def spring_torques_right(self, x: FloatArray) -> list[float]:
        """Per elastic spring: the torque it puts on the section to its right (N m): the
        spring torque, plus -ds/dphi V for a spring with varying stiffness."""
        n = self.n_dof
        out = []
        for k, sp in enumerate(self.springs):
            phi_l, a_l, _b, _m, _c = self._section(k, float(x[k]))
            th = phi_l - float(x[k + 1])
            thd = a_l * float(x[n + k]) - float(x[n + k + 1])
            if sp.variation:
                vs = sp.evaluate_varying(th, thd, float(x[k + 1]))
                out.append(vs.torque + vs.extra)
            else:
                out.append(sp.evaluate(th, thd)[0])
        return out

    def energy(self, x: FloatArray) -> dict[str, float]:
        """Kinetic and potential energy (J): 'elastic' holds the springs' and the
        imbalances' gravity potential."""
        n = self.n_dof
        kin = 0.0
        for g in range(n):
            m = self._section(g, float(x[g]))[3]
            v = float(x[n + g])
            kin += 0.5 * m * v * v    # v * v gives inf on overflow; float ** 2 would raise
        el = 0.0
        for g, imbs in enumerate(self._imbalances):   # imbalances' gravity potential
            if imbs:
                el += section_imbalance(self._ops[g], imbs, float(x[g]))[2]
        for k, sp in enumerate(self.springs):
            phi_l = self._section(k, float(x[k]))[0]
            if sp.variation:
                el += sp.evaluate_varying(phi_l - float(x[k + 1]), 0.0, float(x[k + 1])).potential
            else:
                el += sp.evaluate(phi_l - float(x[k + 1]), 0.0)[3]
        return {'kinetic': kin, 'elastic': el}

    def energy_residual(self, x: FloatArray, e0: float) -> float:
        """(E_kin + E_el - E0 - W_engine + W_load + W_damp) / max(energy scale), needs
        ``track_energy``. Scale: max of |E|, |E0|, |W_engine|, |W_load|, |W_damp|, 1e-12 J."""
        if not self.track_energy:
            raise ValueError('energy_residual needs a Driveline built with track_energy=True')
        n = self.n_dof
        e = self.energy(x)
        tot = e['kinetic'] + e['elastic']
        we, wl, wd = (float(v) for v in x[2 * n:2 * n + 3])
        scale = max(abs(tot), abs(e0), abs(we), abs(wl), abs(wd), 1e-12)
        return (tot - e0 - we + wl + wd) / scale

    def joint_states(self, x: FloatArray, T_engine: float, T_load: float
                     ) -> tuple[list[str], FloatArray, FloatArray, FloatArray]:
        """(names, position rad, velocity rad/s, effort N m) of every named shaft.

        Effort is the torque transmitted by that shaft towards the load: for an inertia
        its output side (the last inertia's equals the load torque), for a joint's input
        and output shafts the torque in them (lossless joint: T_out = T_in / ratio). The
        intermediate member (cage, spider ...) carries no single shaft torque: effort 0.
        """
        pos, vel, eff, _react = self._walk(x, T_engine, T_load, reactions=False)
        if self._mid_index:
            self.fill_mid(pos[None, :], vel[None, :])
        return list(self.shaft_names), pos, vel, eff

    def joint_states_fast(self, x: FloatArray, T_engine: float, T_load: float
                          ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """As :meth:`joint_states` but intermediate members left as their joint's input
        (fill them for many samples at once with :meth:`fill_mid`)."""
        pos, vel, eff, _react = self._walk(x, T_engine, T_load, reactions=False)
        return pos, vel, eff

    def fill_mid(self, position: FloatArray, velocity: FloatArray, *,
                 members: Sequence[tuple[int, int]] | None = None) -> None:
        """In place: intermediate-member columns of (samples, shafts) arrays from their
        joint's input column, vectorised (phi_mid, and dphi_mid/dphi_in * omega_in by a
        Richardson-extrapolated central difference, h = 1e-3 rad: truncation O(h^4) ~ 1e-13,
        round-off ~ 1e-16 |phi| / h, i.e. 4e-7 relative after 1e5 revolutions, where
        h = 1e-6 gave 6e-5). ``members``: (mid column, input column) pairs to fill
        (default all; the compiled outputs pass those they have no form for)."""
        h = 1e-3
        for i_mid, i_in in (self._mid_index if members is None else members):
            model = self.shafts[i_mid].joint
            phi = position[:, i_in]
            m = phi.size
            points = np.concatenate([phi, phi + h, phi - h, phi + h / 2, phi - h / 2])
            # one call; a model with mid_angle() gives phi_mid alone (same numbers, a third
            # of the lever hinge's evaluate() time)
            mid_angle = getattr(model, 'mid_angle', None)
            mid = mid_angle(points) if mid_angle is not None else model.evaluate(points).phi_mid
            if mid is None:
                continue
            position[:, i_mid] = mid[:m]
            d_h = (mid[m:2 * m] - mid[2 * m:3 * m]) / (2 * h)
            d_h2 = (mid[3 * m:4 * m] - mid[4 * m:]) / h
            velocity[:, i_mid] = (4.0 * d_h2 - d_h) / 3.0 * velocity[:, i_in]

    def reactions(self, x: FloatArray, T_engine: float, T_load: float) -> dict[str, dict[str, float]]:
        """Per joint whose model has ``reactions(phi_in, omega_in, torque_in)``: its dict."""
        return self._walk(x, T_engine, T_load, reactions=True)[3]

    def _walk(self, x: FloatArray, T_engine: float, T_load: float, *, reactions: bool
              ) -> tuple[FloatArray, FloatArray, FloatArray, dict[str, dict[str, float]]]:
        n = self.n_dof
        xdot = self.rhs(0.0, x, T_engine, T_load)
        spring_t = self.spring_torques_right(x)
        pos = np.zeros(len(self.shafts))
        vel = np.zeros(len(self.shafts))
        eff = np.zeros(len(self.shafts))
        react: dict[str, dict[str, float]] = {}
        # per section and op: (state before, state after), state = (phi, omega, torque)
        states: list[list[tuple[tuple[float, float, float], tuple[float, float, float]]]] = []
        for g in range(n):
            q, v, acc = float(x[g]), float(x[n + g]), float(xdot[n + g])
            phi, a, b = q, 1.0, 0.0
            torque = T_engine if g == 0 else spring_t[g - 1]
            st = []
            imb = {k: (mge, ang) for k, mge, ang in self._imbalances[g]}
            for k, (jv, fn) in enumerate(self._ops[g]):
                before = (phi, a * v, torque)
                if fn is None:
                    torque -= jv * (a * acc + b * v * v)
                    if k in imb:        # the weight of the unbalanced mass resists
                        torque -= imb[k][0] * math.cos(phi + imb[k][1])
                else:
                    name = self._section_names[g][k]
                    model = self.joint_models[name]
                    if reactions and hasattr(model, 'reactions'):
                        react[name] = dict(model.reactions(phi, a * v, torque))
                    po, r, s = fn(phi)
                    b = s * a * a + r * b
                    a = r * a
                    phi = po
                    torque = torque / r
                st.append((before, (phi, a * v, torque)))
            states.append(st)
        for i, sh in enumerate(self.shafts):
            before, after = states[sh.section][sh.op_index]
            phi, om, tq = before if sh.role in ('input', 'mid') else after
            if sh.role == 'mid':
                pos[i], vel[i], eff[i] = phi, om, 0.0     # filled by fill_mid
            else:
                pos[i], vel[i], eff[i] = phi, om, tq
        return pos, vel, eff, react


def build_driveline(scene: Scene, *, fidelity: Mapping[str, str] | None = None,
                    track_energy: bool = False) -> Any:
    """The equations of ``scene``: a :class:`Driveline` for a chain, a
    :class:`cvj_ros.physics.tree.TreeDriveline` for a vehicle scene (wheels, differentials)."""
    if scene.is_tree:
        from cvj_ros.physics.tree import TreeDriveline
        return TreeDriveline.from_scene(scene, fidelity=fidelity, track_energy=track_energy)
    return Driveline.from_scene(scene, fidelity=fidelity, track_energy=track_energy)
