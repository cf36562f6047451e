"""Scene -> data for the compiled kernel (issue 9). Pure Python, no numba import.

A :class:`~cvj_ros.physics.driveline.Driveline` plus its torque sources become two flat
arrays that ``kernel/rhs_nb.py`` interprets: ``ip`` (int64 codes and offsets) and ``fp``
(float64 parameters). Layout (all offsets are indices into ip / fp):

ip header (``H_*`` indices):
    H_NDOF n sections (DOF), H_NSTATE state length (2n or 2n+3), H_ENERGY 1 = work integrals,
    H_ENGINE engine code, H_LOAD load code, H_ENGINE_I / H_ENGINE_F engine ip/fp offsets,
    H_LOAD_I / H_LOAD_F load ip/fp offsets, H_SEC section table offset, H_SPRING_F spring
    parameter offset (fp), H_INPUT_F input block offset (fp).
section table at ip[H_SEC]: n+1 op start indices (into the op list), then the op list
    follows at ip[H_SEC] + n + 1 as pairs (op code, fp offset).
ops: OP_INERTIA fp[off] = J (kg m^2); OP_JOINT_IDENTITY (ideal fidelity of any joint, ideal CV:
    phi_out = phi_in); OP_HOOKE fp[off] = cos(beta); OP_GEAR fp[off] = ratio k
    (phi_out = k phi_in).
springs (one per section boundary, 5 floats each): c (N m/rad), d (N m s/rad), k2 (1/rad^2),
    half gap g (rad), smoothing width w (rad) - the fields of driveline.SpringLaw.
input block (9 floats): t_k, Te, Te_rate, Ke, we, Tl, Tl_rate, Kl, wl (see set_torque_inputs).
engine: ENGINE_INPUTS (input block), ENGINE_LINEAR fp = [throttle, m1, k1] (seed 004 eq. 3.23).
load: LOAD_INPUTS (input block), LOAD_CONSTANT fp = [M_c, speed_scale (0 = none)].

Covered so far: Hooke (exact, ideal), gear, ideal CV, any joint whose 'ideal' fidelity is
    the identity (checked at build time), springs (linear,
progressive, backlash), work integrals, linear engine, constant load, input-block torques.
Anything else raises NotImplementedError naming the element (no silent fallback).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

# ip header
H_NDOF, H_NSTATE, H_ENERGY, H_ENGINE, H_LOAD = 0, 1, 2, 3, 4
H_ENGINE_I, H_ENGINE_F, H_LOAD_I, H_LOAD_F = 5, 6, 7, 8
H_SEC, H_SPRING_F, H_INPUT_F = 9, 10, 11
N_HEADER = 12

# op codes
OP_INERTIA = 0
OP_JOINT_IDENTITY = 1
OP_HOOKE = 2
OP_GEAR = 3

# torque source codes
ENGINE_INPUTS = 0
ENGINE_LINEAR = 1
LOAD_INPUTS = 0
LOAD_CONSTANT = 1

SPRING_STRIDE = 5
N_INPUT = 9
IN_TK, IN_TE, IN_TE_RATE, IN_KE, IN_WE, IN_TL, IN_TL_RATE, IN_KL, IN_WL = range(N_INPUT)


@dataclass(frozen=True)
class ModelData:
    """A driveline + torque sources as kernel data (see module docstring for the layout)."""

    ip: NDArray[np.int64]
    fp: NDArray[np.float64]
    n_dof: int
    n_state: int
    track_energy: bool
    x0: NDArray[np.float64]


def _joint_op(name: str, model: Any, fp: list[float]) -> tuple[int, int]:
    """(op code, fp offset) of one joint model; NotImplementedError if not yet compiled."""
    fid = getattr(model, 'fidelity', None)
    if model.kind == 'gear':
        fp.append(float(model._k))
        return OP_GEAR, len(fp) - 1
    if model.kind == 'ideal_cv' or (fid == 'ideal' and all(
            model.scalar(p) == (p, 1.0, 0.0) for p in (-2.3, 0.0, 0.7, 4.1))):
        return OP_JOINT_IDENTITY, 0
    if model.kind == 'hooke' and fid == 'exact':
        fp.append(math.cos(model.beta))
        return OP_HOOKE, len(fp) - 1
    raise NotImplementedError(f'compiled kernel: joint {name!r} kind {model.kind!r} '
                              f'fidelity {fid!r} is not covered yet')


def _engine_block(engine: Any, fp: list[float]) -> tuple[int, int]:
    if engine is None:
        return ENGINE_INPUTS, 0
    from cvj_ros.physics.engine import LinearEngine
    if type(engine) is LinearEngine:
        off = len(fp)
        fp.extend([float(engine.throttle), float(engine.m1), float(engine.k1)])
        return ENGINE_LINEAR, off
    raise NotImplementedError(f'compiled kernel: engine model {type(engine).__name__} '
                              'is not covered yet')


def _load_block(load: Any, fp: list[float]) -> tuple[int, int]:
    if load is None:
        return LOAD_INPUTS, 0
    from cvj_ros.physics.load import ConstantLoad
    if type(load) is ConstantLoad:
        off = len(fp)
        fp.extend([float(load.value), float(load.speed_scale or 0.0)])
        return LOAD_CONSTANT, off
    raise NotImplementedError(f'compiled kernel: load model {type(load).__name__} '
                              'is not covered yet')


def build_model(driveline: Any, *, engine: Any = None, load: Any = None,
                horizon: float | None = None) -> ModelData:
    """Pack ``driveline`` (a Driveline) and its torque sources into kernel arrays.

    engine/load None -> that port takes its torque from the input block
    (:func:`set_torque_inputs`). ``horizon`` (s) is reserved for pre-generated source
    sequences (seeded random load); unused by the models covered so far.
    """
    from cvj_ros.physics.scene import Inertia, Joint
    fp: list[float] = [0.0]          # fp[0] unused, so offset 0 never aliases a parameter
    ops: list[tuple[int, int]] = []
    sec_start = [0]
    by_name = {el.name: el for el in driveline.scene.driveline}
    for g, names in enumerate(driveline._section_names):
        for name in names:
            el = by_name[name]
            if isinstance(el, Inertia):
                fp.append(float(el.J))
                ops.append((OP_INERTIA, len(fp) - 1))
            elif isinstance(el, Joint):
                ops.append(_joint_op(name, driveline.joint_models[name], fp))
        sec_start.append(len(ops))
    spring_f = len(fp)
    for sp in driveline.springs:
        fp.extend([sp.c, sp.d, sp.k2, sp.gap, sp.width])
    input_f = len(fp)
    fp.extend([0.0] * N_INPUT)
    e_code, e_f = _engine_block(engine, fp)
    l_code, l_f = _load_block(load, fp)
    n = driveline.n_dof
    head = [0] * N_HEADER
    head[H_NDOF], head[H_NSTATE] = n, driveline._n_state
    head[H_ENERGY] = 1 if driveline.track_energy else 0
    head[H_ENGINE], head[H_ENGINE_F], head[H_ENGINE_I] = e_code, e_f, 0
    head[H_LOAD], head[H_LOAD_F], head[H_LOAD_I] = l_code, l_f, 0
    head[H_SEC], head[H_SPRING_F], head[H_INPUT_F] = N_HEADER, spring_f, input_f
    ip = head + sec_start + [v for op in ops for v in op]
    return ModelData(np.asarray(ip, dtype=np.int64), np.asarray(fp, dtype=np.float64),
                     n, driveline._n_state, bool(driveline.track_energy),
                     np.array(driveline.x0, dtype=np.float64))


def set_torque_inputs(model: ModelData, *, t_k: float, Te: float, Te_rate: float = 0.0,
                      Ke: float = 0.0, we: float = 0.0, Tl: float, Tl_rate: float = 0.0,
                      Kl: float = 0.0, wl: float = 0.0) -> None:
    """Write the input block (N m, N m/s, N m s/rad, rad/s). Law applied in rhs/jac:
    T_engine = Te + Te_rate (t - t_k) + Ke (omega_engine - we), same for the load."""
    o = int(model.ip[H_INPUT_F])
    model.fp[o:o + N_INPUT] = (t_k, Te, Te_rate, Ke, we, Tl, Tl_rate, Kl, wl)


def set_throttle(model: ModelData, x: float) -> None:
    """Set the throttle (0..1) of an engine evaluated inside the kernel."""
    if int(model.ip[H_ENGINE]) == ENGINE_LINEAR:
        model.fp[int(model.ip[H_ENGINE_F])] = float(x)
    else:
        raise ValueError('set_throttle: the model has no in-kernel engine with a throttle')
