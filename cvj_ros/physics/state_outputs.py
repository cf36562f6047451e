"""Per-exchange outputs of one driveline state: the joint state (every named
shaft's angle rad, speed rad/s, torque N m, intermediate members filled) and the reaction
wrench of every joint that has one (housing frame, ``cvj_ros/physics/joints/wrench.py``).

Implementations of one interface, chosen by :func:`make_state_outputs`:

* :class:`PythonStateOutputs`: ``Driveline.joint_states_fast`` + ``fill_mid``,
  ``Driveline.reactions`` + ``wrench_from_reactions`` - the readable reference (oracle).
* :class:`KernelStateOutputs`: the same walk, member angles and reactions compiled
  (``kernel/outputs_nb.py`` ``joint_state_one``, ``wrenches_one``; exact tripod reactions
  in ``kernel/reactions_nb.py``), one call each. A member or joint without a compiled form
  stays on the Python formula (the rest is compiled); a compiled tripod Newton that fails
  hands that sample to the Python model, which raises its own SolverError.
* :class:`TreeKernelStateOutputs`: a vehicle scene's joint state (``TreeDriveline._walk``
  over every branch) compiled in ``kernel/tree_outputs_nb.py``; the reaction wrenches of
  every branch's joints from that joint state by the chain's ``wrenches_one`` (a joint's
  reaction needs only its input shaft's angle, speed and torque).

Measured per call (this machine, load average 2.8, one run): kavz685_lever joint state
77 -> 3.5 us, reaction wrench 17 -> 1.7 us; fwd_halfshaft joint state 309 -> 7.7 us (of it
fill_mid ~140 us), reaction wrenches 12.6 ms -> 11 us (the Python exact tripod solves its
Newton and the 10 x 10 balance through fixed_order's numpy elimination).
test/physics/kernel/test_state_outputs.py holds the compiled values to the Python ones
(bit-identical on this machine).
"""
from __future__ import annotations

from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from cvj_ros.physics.joints.wrench import wrench_from_reactions

FloatArray = NDArray[np.float64]
Vector3 = tuple[float, float, float]
Wrench = tuple[Vector3, Vector3]


class StateOutputs(Protocol):
    """What the coupling node needs per exchange."""

    backend: str
    joints: list[str]

    def joint_states(self, x: FloatArray, T_engine: float, T_load: float
                     ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """(position rad, velocity rad/s, effort N m) per ``driveline.shaft_names``."""
        ...

    def wrenches(self, x: FloatArray, T_engine: float, T_load: float,
                 joint_state: tuple[FloatArray, FloatArray, FloatArray]) -> dict[str, Wrench]:
        """Reaction wrench (force N, torque N m, housing frame) per joint of ``joints``
        that has one; ``joint_state`` is :meth:`joint_states` of the same arguments."""
        ...


class PythonStateOutputs:
    """The Python reference (see module docstring); ``joints`` = reaction joints."""

    backend = 'python'

    def __init__(self, driveline: Any, joints: list[str]) -> None:
        self.driveline = driveline
        self.joints = list(joints)
        self._kind = {j: driveline.joint_models[j].kind for j in self.joints}
        self._has_mid = bool(driveline._mid_index)

    def joint_states(self, x: FloatArray, T_engine: float, T_load: float
                     ) -> tuple[FloatArray, FloatArray, FloatArray]:
        pos, vel, eff = self.driveline.joint_states_fast(x, T_engine, T_load)
        if self._has_mid:
            self.driveline.fill_mid(pos[None, :], vel[None, :])
        return pos, vel, eff

    def wrenches(self, x: FloatArray, T_engine: float, T_load: float,
                 joint_state: tuple[FloatArray, FloatArray, FloatArray]) -> dict[str, Wrench]:
        reactions = self.driveline.reactions(x, T_engine, T_load)
        out: dict[str, Wrench] = {}
        for j in self.joints:
            values = reactions.get(j)
            if values:
                out[j] = wrench_from_reactions(self._kind[j], values)
        return out


class KernelStateOutputs:
    """Compiled outputs (see module docstring). Building it compiles or loads the numba
    functions (seconds when cold; ``python -m cvj_ros.physics.kernel.warmup`` fills the cache)
    and evaluates once, so a node pays that before its loop starts."""

    backend = 'kernel'

    def __init__(self, driveline: Any, joints: list[str]) -> None:
        from cvj_ros.physics.kernel import outputs_nb as O
        from cvj_ros.physics.kernel.layout import build_model
        self._O = O
        self.driveline = driveline
        self.joints = list(joints)
        self.model = build_model(driveline)     # torques from the input block
        ip = self.model.ip
        from cvj_ros.physics.kernel.layout import H_INPUT_F, IN_TE, IN_TL
        self._i_te = int(ip[H_INPUT_F]) + IN_TE
        self._i_tl = int(ip[H_INPUT_F]) + IN_TL
        self._tab = O.shaft_table(driveline)
        self._mtab, self._mfp, self._mid_python = O.mid_table(driveline)
        self._rtab, self._rfp, self._react_python = O.reaction_table(driveline, self.joints)
        self._kind = {j: driveline.joint_models[j].kind for j in self.joints}
        n = len(driveline.shaft_names)
        self._n = n
        self._wrench = np.empty((len(self.joints), 6))
        # compiled rows only (python rows are answered by the model's reactions())
        self._rtab_c = self._rtab[self._rtab[:, 1] >= 0] if len(self._rtab) else self._rtab
        self._row_joint = [self.joints[k] for k in range(len(self.joints))
                           if k not in self._react_python]
        self._ws = np.empty((len(self._rtab_c), 6))
        # compile / load now, not in the first exchange; then call the entry points (same
        # argument types every exchange: no dispatch)
        from cvj_ros.physics.kernel import entry_point
        x0 = np.array(driveline.x0, dtype=np.float64)
        pos, vel, eff = np.empty(n), np.empty(n), np.empty(n)
        self._joint_state_one = entry_point(
            O.joint_state_one, (x0, self.model.ip, self.model.fp, self._tab, self._mtab, self._mfp,
                                pos, vel, eff))
        self._wrenches_one = entry_point(O.wrenches_one, (pos, vel, eff, self._rtab_c, self._rfp, self._ws)) \
            if len(self._rtab_c) else O.wrenches_one
        pos, vel, eff = self.joint_states(x0, 0.0, 0.0)
        self.wrenches(x0, 0.0, 0.0, (pos, vel, eff))

    def joint_states(self, x: FloatArray, T_engine: float, T_load: float
                     ) -> tuple[FloatArray, FloatArray, FloatArray]:
        fp = self.model.fp
        fp[self._i_te] = T_engine
        fp[self._i_tl] = T_load
        pos = np.empty(self._n)
        vel = np.empty(self._n)
        eff = np.empty(self._n)
        y = np.ascontiguousarray(x, dtype=np.float64)    # the entry point's C layout
        if not self._joint_state_one(y, self.model.ip, fp, self._tab, self._mtab, self._mfp,
                                     pos, vel, eff):
            # non-finite state: the Python path gives the same NaN/inf propagation
            return PythonStateOutputs(self.driveline, self.joints).joint_states(x, T_engine, T_load)
        if self._mid_python:
            self._fill_mid_python(pos, vel)
        return pos, vel, eff

    def _fill_mid_python(self, pos: FloatArray, vel: FloatArray) -> None:
        """Driveline.fill_mid's formula for the members without a compiled form."""
        self.driveline.fill_mid(pos[None, :], vel[None, :], members=self._mid_python)

    def wrenches(self, x: FloatArray, T_engine: float, T_load: float,
                 joint_state: tuple[FloatArray, FloatArray, FloatArray]) -> dict[str, Wrench]:
        pos, vel, eff = joint_state
        asc = np.ascontiguousarray      # the entry point's C-layout float64 arrays
        pos, vel, eff = asc(pos, dtype=np.float64), asc(vel, dtype=np.float64), asc(eff, dtype=np.float64)
        out: dict[str, Wrench] = {}
        failed = 0
        if len(self._rtab_c):
            failed = self._wrenches_one(pos, vel, eff, self._rtab_c, self._rfp, self._ws)
        for row, j in enumerate(self._row_joint):
            w = self._ws[row].tolist()
            if failed and w[5] != w[5]:
                # compiled Newton did not converge: the Python model answers (or raises)
                w = self._python_wrench(j, pos, vel, eff)
                if w is None:
                    continue
                out[j] = w
                continue
            out[j] = ((w[0], w[1], w[2]), (w[3], w[4], w[5]))
        for k in self._react_python:
            j = self.joints[k]
            w = self._python_wrench(j, pos, vel, eff)
            if w is not None:
                out[j] = w
        if len(out) > 1 and self._react_python:
            out = {j: out[j] for j in self.joints if j in out}     # the joints' order
        return out

    def _python_wrench(self, joint: str, pos: FloatArray, vel: FloatArray,
                       eff: FloatArray) -> Wrench | None:
        """The model's reactions() at the joint's input shaft (what Driveline._walk passes)."""
        col = self.driveline.shaft_names.index(f'{joint}_input')
        values = self.driveline.joint_models[joint].reactions(float(pos[col]), float(vel[col]),
                                                              float(eff[col]))
        return wrench_from_reactions(self._kind[joint], values) if values else None


class TreeKernelStateOutputs:
    """Compiled joint state of a vehicle scene's TreeDriveline (``kernel/tree_outputs_nb.py``:
    ``TreeDriveline._walk`` on the kernel's tree tables, members by ``fill_mid_one``), with
    the driveline's outside wheel torques (``set_wheel_torques``) read at every call. The
    reaction wrenches of ``joints`` are :class:`KernelStateOutputs`'s (``wrenches_one`` on
    the joint state's ``<joint>_input`` columns; a joint without a compiled form asks its
    model). Building it compiles or loads the numba functions and evaluates once."""

    backend = 'kernel'

    def __init__(self, driveline: Any, joints: list[str]) -> None:
        from cvj_ros.physics.kernel import entry_point
        from cvj_ros.physics.kernel import outputs_nb as O
        from cvj_ros.physics.kernel import tree_outputs_nb as TO
        from cvj_ros.physics.kernel.layout import build_model
        self.driveline = driveline
        self.joints = list(joints)
        # the tables only: outside wheel torques come with each call, not from the model
        held, driveline.wheel_torques = driveline.wheel_torques, None
        try:
            self.model = build_model(driveline)
        finally:
            driveline.wheel_torques = held
        self._tab, self._ends = TO.tree_tables(driveline)
        self._mtab, self._mfp, self._mid_python = O.mid_table(driveline)
        self._n = len(driveline.shaft_names)
        self._wheel_t = np.zeros(max(driveline.n_wheel, 1))
        x0 = np.array(driveline.x0, dtype=np.float64)
        n = self._n
        self._fn = entry_point(TO.tree_joint_state,
                               (x0, self.model.ip, self.model.fp, 0.0, 0, self._wheel_t, self._tab,
                                self._ends, self._mtab, self._mfp, np.empty(n), np.empty(n),
                                np.empty(n)))
        # reaction wrenches: the chain's tables and entry point (KernelStateOutputs.wrenches)
        self._rtab, self._rfp, self._react_python = O.reaction_table(driveline, self.joints)
        self._kind = {j: driveline.joint_models[j].kind for j in self.joints}
        self._rtab_c = self._rtab[self._rtab[:, 1] >= 0] if len(self._rtab) else self._rtab
        self._row_joint = [self.joints[k] for k in range(len(self.joints))
                           if k not in self._react_python]
        self._ws = np.empty((len(self._rtab_c), 6))
        pos, vel, eff = self.joint_states(x0, 0.0, 0.0)
        self._wrenches_one = entry_point(O.wrenches_one, (pos, vel, eff, self._rtab_c, self._rfp, self._ws)) \
            if len(self._rtab_c) else O.wrenches_one
        self.wrenches(x0, 0.0, 0.0, (pos, vel, eff))

    wrenches = KernelStateOutputs.wrenches
    _python_wrench = KernelStateOutputs._python_wrench

    def joint_states(self, x: FloatArray, T_engine: float, T_load: float
                     ) -> tuple[FloatArray, FloatArray, FloatArray]:
        pos = np.empty(self._n)
        vel = np.empty(self._n)
        eff = np.empty(self._n)
        outside = self.driveline.wheel_torques
        if outside is not None:
            self._wheel_t[:len(outside)] = outside
        y = np.ascontiguousarray(x, dtype=np.float64)
        if not self._fn(y, self.model.ip, self.model.fp, float(T_engine), 0 if outside is None else 1,
                        self._wheel_t, self._tab, self._ends, self._mtab, self._mfp, pos, vel, eff):
            return PythonStateOutputs(self.driveline, self.joints).joint_states(x, T_engine, T_load)
        if self._mid_python:
            self.driveline.fill_mid(pos[None, :], vel[None, :], members=self._mid_python)
        return pos, vel, eff


def make_state_outputs(driveline: Any, joints: list[str], *, compiled: bool) -> StateOutputs:
    """When ``compiled`` (the stepper runs the kernel, or a vehicle scene with outside wheel
    loads) and the driveline packs into kernel data: :class:`KernelStateOutputs`, for a
    vehicle scene's TreeDriveline :class:`TreeKernelStateOutputs`; else
    :class:`PythonStateOutputs`."""
    if compiled:
        try:
            if getattr(driveline, 'is_tree', False):
                return TreeKernelStateOutputs(driveline, joints)
            return KernelStateOutputs(driveline, joints)
        except NotImplementedError:
            pass
    return PythonStateOutputs(driveline, joints)
