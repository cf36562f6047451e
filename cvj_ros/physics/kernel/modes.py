"""Chain drivelines with clutch, gearbox and brake on the compiled kernel.

:class:`KernelHybridSimulation` is :class:`cvj_ros.physics.hybrid.HybridSimulation` (the
Python reference, the oracle) with the continuous part compiled: each mode becomes
``ip``/``fp`` arrays (``kernel/modes_nb.py`` layout, no per-scene or per-mode compile) and
:func:`segment_nb.mode_segment` integrates it (dopri5, dop853, a RODAS method, tsit5 or
vern6), checks the witnesses after every step and locates the earliest crossing on the dense output (Brent), all in one
compiled call per mode. The discrete decisions at an event (stick or slip, release, gear commands and their
refusals, the momentum-conserving locks, the stall) are the oracle's own methods, so the
two backends differ only by the rounding of the compiled arithmetic.

``carry_step=True`` starts each mode with the step size the previous mode ended with
instead of Hairer's initial-step estimate (an option: the oracle restarts with the
estimate, and equality with it needs the same).
"""
from __future__ import annotations

import functools
import math
from typing import Any

import numpy as np

from cvj_ros.physics.hybrid.chain import Assembly, Mode
from cvj_ros.physics.hybrid.friction import FORWARD, STUCK
from cvj_ros.physics.hybrid.simulate import HybridResult, HybridSimulation
from cvj_ros.physics.kernel import layout as L

__all__ = ['KERNEL_MODE_METHODS', 'KernelHybridSimulation']

KERNEL_MODE_METHODS = ('dopri5', 'dop853', 'rodas3', 'rodas4', 'rosenbrock', 'tsit5', 'vern6',
                       'vern7', 'vern8')

# codes of kernel/modes_nb.py (repeated here so building the arrays does not import numba)
OP_COUPLING = -1
LINK_SPRING, LINK_CLUTCH, LINK_OPEN = 0, 1, 2
(W_STALL, W_SLIP, W_CLUTCH_FWD, W_CLUTCH_BWD, W_BRAKE_SPEED, W_BRAKE_FWD,
 W_BRAKE_BWD) = range(7)
N_MHEADER = 17
(MH_N, MH_OPS, MH_LINKS, MH_ENGINE, MH_ENGINE_F, MH_LOAD, MH_LOAD_F, MH_PINNED, MH_BRAKE,
 MH_NWIT, MH_WIT, MH_NSTUCK, MH_STUCK, MH_CHAN_F, MH_RAMP_T, MH_RAMP_C, MH_RAMP_B) = range(17)
N_CHAN = 12
_STATUS = {1: 'a state or derivative is not finite', 2: 'the step size underflowed',
           3: 'the matrix I/(h gamma) - J is singular or not finite'}


_ENTRY: list[Any] = []
KIND_CHAIN, KIND_TREE = 0, 1          # segment_nb's right-hand sides
# segment_nb's method codes: the Rosenbrock family shares one, the explicit pairs with
# interpolants (erk_tableaux) another; their tableaux are passed in
_METHOD_CODE = {'dopri5': 0, 'dop853': 1, 'rodas3': 2, 'rodas4': 2, 'rosenbrock': 2,
                'tsit5': 3, 'vern6': 3, 'vern7': 3, 'vern8': 3}


def _segment_entry(args: tuple) -> Any:
    """segment_nb.mode_segment's compiled entry point (chains and vehicle trees), found once
    per process from the disk cache without numba's full start-up (kernel.entry_point). A
    compile on a cache miss runs the function once: it gets copies of the arrays, which the
    segment overwrites."""
    if not _ENTRY:
        from cvj_ros.physics.kernel import entry_point, segment_nb
        spare = tuple(a.copy() if isinstance(a, np.ndarray) else a for a in args)
        _ENTRY.append(entry_point(segment_nb.mode_segment, spare))
    return _ENTRY[0]


@functools.lru_cache(maxsize=None)
def _coefficients(method: str) -> tuple:
    """The coefficient arguments of segment_nb.mode_segment for ``method``: DOP853's
    (C, A, B, E5, E3, D, A_EXTRA, C_EXTRA), then the Rosenbrock tableau (A, C, M, E, alpha,
    gamma_sum, H; H without rows for the Hermite dense output of rodas3/rodas4) and
    (gamma, order, fac_max); a method that does not use them gets RODAS3's (same types:
    one compiled code). tsit5, vern6, vern7 and vern8 (erk_tableaux) pass their pair in DOP853's slots:
    C, A, B, E, DOP853's E3, then P and the rows of A and C of the interpolant's extra
    stages; their embedded order in the second entry of the last array."""
    from cvj_ros.physics.kernel.stepper import _dop853_args, _rosenbrock_args
    (c8, a8, b8, e5, e3), (d8, ax, cx) = _dop853_args()
    tab, H = _rosenbrock_args(method if _METHOD_CODE[method] == 2 else 'rodas3')
    gamma, A, C, M, E, alpha, gsum, order, fac_max = tab
    if H is None:
        H = np.zeros((0, M.shape[0]))
    ros = tuple(np.ascontiguousarray(a, dtype=np.float64) for a in (A, C, M, E, alpha, gsum, H))
    if _METHOD_CODE[method] == 3:
        from cvj_ros.physics.erk_tableaux import erk_tableau
        et = erk_tableau(method)
        s = int(et['S'])
        c8, a8, b8, e5, d8, ax, cx = (
            np.array(a, dtype=np.float64, order='C') for a in
            (et['C'], et['A'], et['B'], et['E'], et['P'], et['A'][s:], et['C'][s:]))
        order = int(et['error_order'])
    return (c8, a8, b8, e5, e3, d8, ax, cx, ros,
            np.array([gamma, float(order), fac_max], dtype=np.float64))


def run_segment(kind: int, method: str, t: float, t_stop: float, y: np.ndarray,
                ip: np.ndarray, fp: np.ndarray, rtol: float, atol: np.ndarray,
                max_step: float, h_in: float, times: np.ndarray, k_sample: int,
                Y: np.ndarray, hlog: np.ndarray, out_i: np.ndarray, out_f: np.ndarray) -> None:
    """One compiled call of segment_nb.mode_segment (its docstring: the arguments, y and the
    out arrays overwritten) with ``method``'s coefficients."""
    args = (int(kind), _METHOD_CODE[method], float(t), float(t_stop), y, ip, fp, float(rtol),
            atol, float(max_step), float(h_in), times, int(k_sample), Y, hlog, out_i, out_f,
            *_coefficients(method))
    _segment_entry(args)(*args)


class KernelHybridSimulation(HybridSimulation):
    """:class:`HybridSimulation` integrated by the compiled kernel (KERNEL_MODE_METHODS); same arguments,
    plus ``carry_step`` (module docstring) and ``step_log`` (keep every accepted step size
    per mode segment in ``self.step_log``, to replay the run's mesh in the reference)."""

    def __init__(self, *args: Any, carry_step: bool = False, step_log: bool = False,
                 **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        # per mode segment, the size of every accepted step (s) when asked for
        self.step_log: list[np.ndarray] | None = [] if step_log else None
        self._hlog_size = 4096
        if self.method not in KERNEL_MODE_METHODS:
            raise NotImplementedError(
                f'compiled kernel: mode scenes run with {", ".join(KERNEL_MODE_METHODS)}, '
                f'not {self.method!r} (use the Python backend)')
        self.carry_step = bool(carry_step)
        self._base: tuple[list[float], list[list[tuple[int, int]]], list[int], list[int]] | None = None

    @classmethod
    def from_reference(cls, sim: HybridSimulation, *, carry_step: bool = False,
                       step_log: bool = False) -> KernelHybridSimulation:
        """The kernel twin of a (not yet run) Python-reference simulation."""
        return cls(sim.chain, engine=sim.engine, load=sim.load, schedule=sim.schedule,
                   duration=sim.duration, sample_dt=sim.sample_dt,
                   initial_speed=sim.initial_speed, initial_speeds=sim.initial_speeds,
                   stall_speed=sim.stall_speed, method=sim.method, rtol=sim.rtol,
                   atol=sim.atol, max_step=sim.max_step, carry_step=carry_step,
                   step_log=step_log)

    # --- arrays --------------------------------------------------------------------------

    def _build_base(self) -> None:
        """fp shared by every mode: section ops, springs, engine, load, packs, ramps."""
        ch = self.chain
        fp: list[float] = [0.0]
        sec_ops: list[list[tuple[int, int]]] = []
        for ops in ch.sections:
            row: list[tuple[int, int]] = []
            for jv, fn in ops:
                if fn is None:
                    fp.append(float(jv))
                    row.append((L.OP_INERTIA, len(fp) - 1))
                    continue
                model = getattr(fn, '__self__', None)
                if model is None:
                    raise NotImplementedError('compiled kernel: a joint without its model')
                for stage in (model.joints if model.kind == 'chain' else [model]):
                    row.append(L._joint_op(model.kind, stage, fp))
            sec_ops.append(row)
        spring_f = [0] * len(ch.boundaries)
        for b, bd in enumerate(ch.boundaries):
            if bd.kind == 'spring':
                sp = bd.spring
                spring_f[b] = len(fp)
                fp.extend([sp.c, sp.d, sp.k2, sp.gap, sp.width])
        e_code, e_f = L._engine_block(self.engine, fp)
        l_code, l_f = L._load_block(self.load, fp, self.duration)
        chan = len(fp)
        block = [0.0] * N_CHAN
        block[0] = 1.0 if self._throttle else 0.0
        if ch.clutches:
            pack = next(iter(ch.clutches.values()))[0].pack
            block[1] = 1.0
            block[3:7] = [pack.mu_s, pack.mu_k, pack.cgeo, pack.fn_max]
        if ch.brake is not None:
            pack = ch.brake.pack
            block[2] = 1.0
            block[7:11] = [pack.mu_s, pack.mu_k, pack.cgeo, pack.fn_max]
        block[11] = float(self.stall_speed) if self.stall_speed is not None else 0.0
        fp.extend(block)
        ramps = []
        for c in ('throttle', 'clutch', 'brake'):
            r = self.schedule.channels[c]
            ramps.append(len(fp))
            fp.append(float(len(r.times)))
            fp.extend(float(v) for v in r.times)
            fp.extend(float(v) for v in r.values)
            fp.append(math.inf)     # the segment's end (modes_nb.ramp), set by each segment
        head = [0] * N_MHEADER
        head[MH_ENGINE], head[MH_ENGINE_F], head[MH_LOAD], head[MH_LOAD_F] = e_code, e_f, l_code, l_f
        head[MH_CHAN_F], head[MH_RAMP_T], head[MH_RAMP_C], head[MH_RAMP_B] = chan, *ramps
        self._base = (fp, sec_ops, spring_f, head)

    def mode_arrays(self, asm: Assembly, mode: Mode) -> tuple[np.ndarray, np.ndarray, int]:
        """(ip, fp, state length) of one mode (kernel/modes_nb.py layout)."""
        if self._base is None:
            self._build_base()
        fp0, sec_ops, spring_f, head0 = self._base
        ch = self.chain
        fp = list(fp0)
        n = len(asm.groups)
        starts = [0]
        ops: list[tuple[int, int]] = []
        stuck: list[tuple[int, int]] = []
        slot: dict[int, int] = {}
        for g, grp in enumerate(asm.groups):
            couplings = list(grp.couplings)
            for j, s in enumerate(grp.sections):
                if j > 0:
                    _k, b = couplings[j - 1]
                    fp.extend([ch.coupling_ratio(mode, b), float(mode.offsets[b])])
                    if ch.boundaries[b].kind == 'clutch':
                        slot[b] = len(stuck)
                        stuck.append((g, len(ops)))
                    ops.append((OP_COUPLING, len(fp) - 2))
                ops.extend(sec_ops[s])
            starts.append(len(ops))
        links: list[int] = []
        link_of: dict[int, int] = {}
        for g, b in enumerate(asm.links):
            bd = ch.boundaries[b]
            link_of[b] = g
            if bd.kind == 'spring':
                links += [LINK_SPRING, spring_f[b], 0]
            elif bd.kind == 'clutch':
                links += [LINK_CLUTCH, 0, int(mode.clutch[bd.name])]
            else:
                links += [LINK_OPEN, 0, 0]
        wit: list[int] = []
        for w in self._witnesses(asm, mode):
            kind, name, target = w.key
            if kind == 'stall':
                row = [W_STALL, 0]
            elif kind == 'clutch':
                b = ch.clutches[name][1]
                if target == STUCK:
                    row = [W_SLIP, link_of[b]]
                else:
                    row = [W_CLUTCH_FWD if target == FORWARD else W_CLUTCH_BWD, slot[b]]
            else:
                row = [W_BRAKE_SPEED, 0] if target == STUCK else \
                      [W_BRAKE_FWD if target == FORWARD else W_BRAKE_BWD, 0]
            wit += row + [int(w.direction)]
        head = list(head0)
        head[MH_N] = n
        head[MH_PINNED] = 1 if asm.pinned else 0
        head[MH_BRAKE] = 0 if (ch.brake is None or asm.pinned) else int(mode.brake)
        ip = head
        head[MH_OPS] = len(ip)
        ip += starts + [v for op in ops for v in op]
        head[MH_LINKS] = len(ip)
        ip += links
        head[MH_NWIT], head[MH_WIT] = len(wit) // 3, len(ip)
        ip += wit
        head[MH_NSTUCK], head[MH_STUCK] = len(stuck), len(ip)
        ip += [v for r in stuck for v in r]
        return np.asarray(ip, dtype=np.int64), np.asarray(fp, dtype=np.float64), 2 * n + 4

    def _segment(self, asm: Assembly, mode: Mode, t: float, t_stop: float, y0: np.ndarray,
                 times: np.ndarray, k_sample: int
                 ) -> tuple[np.ndarray, float, int, int, np.ndarray]:
        """Integrate one mode from (t, y0) towards t_stop up to its earliest witness
        crossing: (state at the end, end time, witness index or -1, next sample index,
        the sampled states from ``k_sample`` on). Counters go to ``self.stats``."""
        ip, fp, ns = self.mode_arrays(asm, mode)
        y = np.array(y0, dtype=np.float64)
        atol = np.full(ns, float(self.atol)) if np.ndim(self.atol) == 0 else \
            np.asarray(self.atol, dtype=np.float64)
        Y = np.zeros((times.size, ns))
        out_i = np.zeros(7, np.int64)
        hlog = np.zeros(self._hlog_size if self.step_log is not None else 0)
        out_f = np.zeros(2)
        h_in = self._h_carry if self.carry_step else 0.0
        run_segment(KIND_CHAIN, self.method, t, t_stop, y, ip, fp, self.rtol, atol,
                    self.max_step, h_in, times, k_sample, Y, hlog, out_i, out_f)
        if out_i[0] != 0:
            raise RuntimeError(f'compiled kernel: integration failed near t={t:.6f} s: '
                               f'{_STATUS.get(int(out_i[0]), "status " + str(int(out_i[0])))}')
        self.stats['steps'] += int(out_i[3])
        self.stats['nfev'] += int(out_i[4])
        self._h_carry = float(out_f[1])
        if self.step_log is not None:
            if out_i[6] < out_i[3]:
                self._hlog_size = 2 * int(out_i[3])      # too small: again with room
                self.stats['steps'] -= int(out_i[3])
                self.stats['nfev'] -= int(out_i[4])
                self._h_carry = h_in
                return self._segment(asm, mode, t, t_stop, y0, times, k_sample)
            self.step_log.append(hlog[:int(out_i[6])].copy())
        k_new = int(out_i[2])
        return y, float(out_f[0]), int(out_i[1]), k_new, Y[k_sample:k_new]

    # --- the run -------------------------------------------------------------------------

    def run(self) -> HybridResult:
        """As HybridSimulation.run, each mode's integration one compiled call."""
        ch = self.chain
        mode, st = self._initial()
        st.lock_loss = 0.0
        kin, el = ch.energy(st)
        e0 = kin + el
        names = [nm for nm, (_s, _k, _role) in ch.shafts.items()]
        times = np.arange(0.0, self.duration + 0.5 * self.sample_dt, self.sample_dt)
        times = times[times <= self.duration + 1e-12]
        speed = np.full((times.size, len(names)), np.nan)
        resid = np.full(times.size, np.nan)
        gears = np.zeros(times.size, dtype=int)
        gb_name = next(iter(ch.gearboxes), None)
        k_sample = 0
        stats = {'steps': 0, 'nfev': 0, 'events': 0, 'restarts': 0}
        stall: str | None = None
        self._h_carry = 0.0
        self.stats = stats

        js = ((np.full((times.size, len(names)), np.nan), np.full((times.size, len(names)), np.nan),
               np.full(times.size, np.nan)) if self.joint_samples else None)

        def record(s, i: int) -> None:
            if js is not None:
                p_, _v, e_, te_ = self.joint_state(mode, s, float(times[i]))
                js[0][i], js[1][i], js[2][i] = p_, e_, te_
            speed[i] = [ch.shaft_speed(s, nm) for nm in names]
            kin_, el_ = ch.energy(s)
            we, wl, wd, wf = (float(x) for x in s.work)
            scale = max(abs(kin_ + el_), abs(e0), abs(we), abs(wl), abs(wd), abs(wf),
                        abs(s.lock_loss), 1e-12)
            resid[i] = (kin_ + el_ - e0 - we + wl + wd + wf + s.lock_loss) / scale
            gears[i] = mode.gear[gb_name] if gb_name else 0

        t = 0.0
        mode, st = self._shift(0.0, mode, st)
        while t < self.duration and stall is None:
            t_stop = min(self.schedule.next_breakpoint(t), self.duration)
            if t_stop - t <= 1e-12 * max(1.0, abs(t)):
                t = t_stop
                if t < self.duration:
                    mode, st = self._shift(t, mode, st)
                    mode, st = self._settle(t, mode, st)
                continue
            asm = ch.assemble(mode)
            y0, _loss = ch.to_mode(asm, st)
            n = len(asm.groups)
            stats['restarts'] += 1
            if self.stall_speed is not None and float(y0[n]) < self.stall_speed:
                stall = (f'engine stalled at t={t:.6f} s: {float(y0[n]):.2f} rad/s below the '
                         f'stall speed {self.stall_speed:.2f} rad/s')
                break
            y, t_end, ev_i, k_new, Y = self._segment(asm, mode, t, t_stop, y0, times, k_sample)
            for k in range(k_sample, k_new):
                record(ch.to_sections(asm, Y[k - k_sample], st), k)
            k_sample = k_new
            st = ch.to_sections(asm, y, st)
            if ev_i >= 0:
                t = t_end
                stats['events'] += 1
                ws = self._witnesses(asm, mode)
                kind, name, target = ws[ev_i].key
                if kind == 'stall':
                    stall = (f'engine stalled at t={t:.6f} s: speed fell below the stall '
                             f'speed {self.stall_speed:.2f} rad/s '
                             f'({self.stall_speed * 30 / math.pi:.0f} rpm)')
                    break
                if target == STUCK:
                    mode, st = self._try_stick(t, mode, st, kind, name, 'zero slip')
                else:
                    mode = self._release(t, mode, kind, name, target,
                                         'torque above static capacity')
                mode, st = self._settle(t, mode, st, (name,))
                if t >= t_stop and t < self.duration:
                    mode, st = self._shift(t, mode, st)
                    mode, st = self._settle(t, mode, st, (name,))
                continue
            t = t_stop
            if t < self.duration:
                mode, st = self._shift(t, mode, st)
                mode, st = self._settle(t, mode, st)
        if stall is not None:
            self.statuses.append(stall)
        keep = k_sample
        res = HybridResult(times[:keep], names, speed[:keep], resid[:keep], gears[:keep],
                           list(self.events), list(self.statuses), stall, st, mode, t, stats)
        if js is not None:
            res.position, res.effort, res.engine_torque = (a[:keep] for a in js)
        return res


