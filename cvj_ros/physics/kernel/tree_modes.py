"""Vehicle scenes with clutch, gearbox, wheel brakes or a clutch-pack differential on the
compiled kernel.

:class:`KernelHybridTreeSimulation` is :class:`cvj_ros.physics.hybrid.HybridTreeSimulation`
(the Python reference, the oracle) with the continuous part compiled: each mode's
:class:`~cvj_ros.physics.hybrid.tree.ModeTree` becomes ``ip``/``fp`` arrays (the event-free
tree tables of ``kernel/layout.py`` plus the mode block of ``kernel/tree_modes_nb.py``; no
per-scene or per-mode compile) and :func:`tree_modes_nb.tree_mode_segment` integrates it
(dopri5, dop853, a RODAS method, tsit5, vern6, vern7 or vern8), checks the witnesses after every step and
locates the earliest crossing on the dense output (Brent), in one compiled call per mode. The discrete decisions (stick or
slip, release, the shift schedule's triggers, gear commands and their refusals, the
momentum-conserving locks, the stall) and the samples are the oracle's own methods, so the
two backends differ only by the rounding of the compiled arithmetic.
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np

from cvj_ros.physics.hybrid.chain import Mode
from cvj_ros.physics.hybrid.friction import FORWARD, STUCK
from cvj_ros.physics.hybrid.simulate import HybridResult
from cvj_ros.physics.hybrid.tree import ModeTree
from cvj_ros.physics.hybrid.tree_sim import HybridTreeSimulation
from cvj_ros.physics.kernel import layout as L
from cvj_ros.physics.kernel.modes import _STATUS, KIND_TREE, run_segment

__all__ = ['KernelHybridTreeSimulation', 'mode_state', 'tree_mode_arrays']

# codes of kernel/tree_modes_nb.py (repeated so building the arrays does not import numba)
OP_COUPLING = -1
N_MB = 13
(MB_NLINK, MB_LINK, MB_NBRAKE, MB_BRAKE, MB_NPACK, MB_PACK, MB_NWIT, MB_WIT, MB_SECX,
 MB_CHAN_F, MB_RAMP_T, MB_RAMP_C, MB_RAMP_B) = range(13)
END_NONE, END_WHEEL, END_SPRING, END_DIFF, END_LINK = 0, 1, 2, 3, 4
(TW_STALL, TW_SLIP, TW_CLUTCH_FWD, TW_CLUTCH_BWD, TW_BRAKE_SPEED, TW_BRAKE_FWD, TW_BRAKE_BWD,
 TW_PACK_SLIP, TW_PACK_FWD, TW_PACK_BWD, TW_SHIFT) = range(11)
_ENDS = {'wheel': END_WHEEL, 'spring': END_SPRING, 'diff': END_DIFF, 'link': END_LINK}
KERNEL_TREE_MODE_METHODS = ('dopri5', 'dop853', 'rodas3', 'rodas4', 'rosenbrock', 'tsit5',
                            'vern6', 'vern7', 'vern8')


class _Gear:
    """Stand-in joint model of a locked link for layout's packing (its op is replaced)."""
    kind = 'gear'

    def __init__(self, k: float) -> None:
        self._k = k


class _Shim:
    """A ModeTree seen by layout._tree_model: locked links as gear joints."""

    def __init__(self, mt: ModeTree) -> None:
        self._mt = mt
        self.joint_models = dict(mt.joint_models)
        for lk in mt.links:
            if lk.locked:
                self.joint_models[lk.element.name] = _Gear(lk.k)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._mt, name)


def _ramp_rows(schedule: Any, channel: str) -> tuple[list[float], list[float]]:
    """(times, values) of a command channel: a CommandSchedule's ramp, or a held
    schedule's (lockstep) value as one row."""
    chans = getattr(schedule, 'channels', None)
    if chans is not None:
        r = chans[channel]
        return list(r.times), list(r.values)
    if channel == 'throttle':
        return [], []
    return [0.0], [float(schedule.value(channel, 0.0))]


def _base_tables(mt: ModeTree, engine: Any) -> tuple[list[int], list[float]]:
    """ip, fp of the mode's tree (layout's tree tables), couplings as OP_COUPLING ops."""
    md = L._tree_model(_Shim(mt), engine)
    ip = md.ip.tolist()
    fp = md.fp.tolist()
    tb = ip[L.H_TREE]
    sec, ops = ip[tb + L.TB_SEC], ip[tb + L.TB_OPS]
    for idx, lk in enumerate(mt.links):
        if not lk.locked:
            continue
        k = ip[sec + L.SEC_STRIDE * lk.left + 1] - 1        # the left section's last op
        fp.extend([float(lk.k), float(mt.mode.offsets[idx])])
        ip[ops + 2 * k] = OP_COUPLING
        ip[ops + 2 * k + 1] = len(fp) - 2
    return ip, fp


def tree_mode_arrays(sim: HybridTreeSimulation, mt: ModeTree, mode: Mode, engine: Any = None
                     ) -> tuple[np.ndarray, np.ndarray]:
    """(ip, fp) of one mode of ``sim`` (kernel/tree_modes_nb.py layout): the tree tables,
    the mode block, the witnesses of ``sim._witnesses(mode)`` in their order; ``engine``
    instead of ``sim.engine`` when given."""
    ip, fp = _base_tables(mt, sim.engine if engine is None else engine)
    tb = ip[L.H_TREE]
    head = [0] * N_MB
    mb = len(ip)
    ip += head
    links: list[int] = []
    for lk in mt.links:
        clutch = lk.element.name in mt.clutch_link
        sign = int(mode.clutch[lk.element.name]) if clutch and not lk.locked else 0
        links += [lk.left, lk.right, 1 if lk.locked else 0, 1 if clutch else 0, sign]
    brakes: list[int] = []
    brake_index: dict[str, int] = {}
    for name, (br, w) in mt.brakes.items():
        brake_index[name] = len(brake_index)
        pk = br.pack
        fp.extend([pk.mu_s, pk.mu_k, pk.cgeo, pk.fn_max])
        pinned = name in mt.pinned
        brakes += [w, mt.wheels[w].section, 1 if pinned else 0,
                   0 if pinned else int(mode.brakes[name]), len(fp) - 4]
    packs: list[int] = []
    pack_index: dict[str, int] = {}
    for name, (el, d) in mt.packs.items():
        pack_index[name] = len(pack_index)
        di = mt.diffs[d]
        fp.extend([float(el.preload), float(el.torque_bias), float(el.static_ratio)])
        stuck = di.coord < 0
        packs += [di.left, di.right, 1 if stuck else 0, 0 if stuck else int(mode.packs[name]),
                  len(fp) - 3]
    wit: list[int] = []
    for w in sim._witnesses(mode):
        kind, name, target = w.key
        f_off = 0
        if kind == 'stall':
            row = [TW_STALL, 0]
        elif kind == 'clutch':
            i = mt.clutch_link[name]
            row = [TW_SLIP, i] if target == STUCK else \
                [TW_CLUTCH_FWD if target == FORWARD else TW_CLUTCH_BWD, i]
        elif kind == 'brake':
            i = brake_index[name]
            row = [TW_BRAKE_SPEED, i] if target == STUCK else \
                [TW_BRAKE_FWD if target == FORWARD else TW_BRAKE_BWD, i]
        elif kind == 'pack':
            i = pack_index[name]
            row = [TW_PACK_SLIP, i] if target == STUCK else \
                [TW_PACK_FWD if target == FORWARD else TW_PACK_BWD, i]
        else:                                               # shift
            g = mode.gear[name]
            lim = sim.auto.schedule.up(g) if target > g else sim.auto.schedule.down(g)
            fp.extend([float(sim.gearboxes[name].ratio(g)), float(lim)])
            f_off = len(fp) - 2
            row = [TW_SHIFT, mt.gearbox_link[name]]
        wit += row + [int(w.direction), f_off]
    # per section: end, group size and coordinates, angle offset
    grp_at: list[int] = []
    p = ip[tb + L.TB_GRP]
    for _g in range(ip[tb + L.TB_NG]):
        grp_at.append(p + 3)
        k, nsec, nsp = ip[p], ip[p + 1], ip[p + 2]
        p += 3 + k + nsec + 2 * nsp
    secx: list[int] = []
    for s, sec in enumerate(mt.sections):
        kind, idx = sec.end if sec.end else ('', 0)
        qo = -1
        if sec.parent >= 0 and mt._sec_local[s] < 0 and mt._lock_delta \
                and sec.diff in mt._lock_delta:
            fp.append(float(sec.sign * mt._lock_delta[sec.diff]))
            qo = len(fp) - 1
        g = mt._group_of[s]
        secx += [_ENDS.get(kind, END_NONE), int(idx), len(mt._groups[g][0]), grp_at[g], qo]
    chan = len(fp)
    cp = sim._clutch_pack
    auto = sim.auto
    seq = auto.seq if auto is not None else None
    ss = auto.schedule if auto is not None else None
    fp.extend([1.0 if sim._throttle else 0.0, 1.0 if cp is not None else 0.0,
               cp.mu_s if cp else 0.0, cp.mu_k if cp else 0.0, cp.cgeo if cp else 0.0,
               cp.fn_max if cp else 0.0,
               float(sim.stall_speed) if sim.stall_speed is not None else 0.0,
               1.0 if seq is not None else 0.0, float(seq[0]) if seq else 0.0,
               ss.open_time if ss else 1.0, ss.neutral_time if ss else 0.0,
               ss.close_time if ss else 1.0, ss.duration if ss else 0.0])
    base = auto.base if auto is not None else sim.schedule
    ramps = []
    for c in ('throttle', 'clutch', 'brake'):
        times, values = _ramp_rows(base, c)
        ramps.append(len(fp))
        fp.append(float(len(times)))
        fp.extend(float(v) for v in times)
        fp.extend(float(v) for v in values)
        fp.append(math.inf)         # the segment's end (modes_nb.ramp), set by each segment
    vals = {MB_NLINK: len(mt.links), MB_NBRAKE: len(brake_index), MB_NPACK: len(pack_index),
            MB_NWIT: len(wit) // 4, MB_CHAN_F: chan, MB_RAMP_T: ramps[0], MB_RAMP_C: ramps[1],
            MB_RAMP_B: ramps[2]}
    for field, rows in ((MB_LINK, links), (MB_BRAKE, brakes), (MB_PACK, packs), (MB_WIT, wit),
                        (MB_SECX, secx)):
        vals[field] = len(ip)
        ip += rows
    for field, v in vals.items():
        ip[mb + field] = v
    ip.append(mb)
    return np.asarray(ip, dtype=np.int64), np.asarray(fp, dtype=np.float64)


def mode_state(mt: ModeTree, st: Any) -> np.ndarray:
    """ModeTree.from_state(st, fresh=False)'s mode state x (the same values) without its
    two kinetic-energy evaluations, which a restart without a lock does not use."""
    n = mt.n_dof
    x = np.zeros(mt._n_state)
    for s, sec in enumerate(mt.sections):
        if sec.coord >= 0:
            x[sec.coord] = st.q[s]
            x[n + sec.coord] = st.qd[s]
    for d_i, d in enumerate(mt.diffs):
        if d.coord >= 0:
            x[d.coord] = st.delta[d_i]
            x[n + d.coord] = st.ddelta[d_i]
    x[2 * n:] = st.tail
    for c in mt._pinned_coords:
        x[n + c] = 0.0
    return x


class KernelHybridTreeSimulation(HybridTreeSimulation):
    """:class:`HybridTreeSimulation` integrated by the compiled kernel (KERNEL_TREE_MODE_METHODS); same
    arguments, plus ``step_log`` (keep every accepted step size per mode segment in
    ``self.step_log``, to replay the run's mesh in the reference)."""

    def __init__(self, *args: Any, step_log: bool = False, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        if self.method not in KERNEL_TREE_MODE_METHODS:
            raise NotImplementedError(
                f'compiled kernel: vehicle mode scenes run with '
                f'{", ".join(KERNEL_TREE_MODE_METHODS)}, not {self.method!r} (use the Python '
                'backend)')
        self.step_log: list[np.ndarray] | None = [] if step_log else None
        self._hlog_size = 4096
        _base_tables(self.probe, self.engine)       # NotImplementedError when it does not pack

    @classmethod
    def from_reference(cls, sim: HybridTreeSimulation, *, step_log: bool = False
                       ) -> KernelHybridTreeSimulation:
        """The kernel twin of a (not yet run) Python-reference simulation; a shift
        schedule is copied (its sequence state is the run's)."""
        import copy
        return cls(sim.scene, sim.levels, engine=copy.deepcopy(sim.engine),
                   schedule=copy.deepcopy(sim.schedule), duration=sim.duration,
                   sample_dt=sim.sample_dt, stall_speed=sim.stall_speed, method=sim.method,
                   rtol=sim.rtol, atol=sim.atol, max_step=sim.max_step, step_log=step_log)

    def _segment(self, mt: ModeTree, mode: Mode, t: float, t_stop: float, y0: np.ndarray,
                 times: np.ndarray, k_sample: int, stats: dict[str, int]
                 ) -> tuple[np.ndarray, float, int, int, np.ndarray]:
        """One mode from (t, y0) towards t_stop up to its earliest witness crossing: (state
        at the end, end time, witness index or -1, next sample index, sampled states)."""
        ip, fp = tree_mode_arrays(self, mt, mode)
        ns = y0.size
        y = np.array(y0, dtype=np.float64)
        atol = np.full(ns, float(self.atol)) if np.ndim(self.atol) == 0 else \
            np.asarray(self.atol, dtype=np.float64)
        Y = np.zeros((times.size, ns))
        out_i = np.zeros(7, np.int64)
        hlog = np.zeros(self._hlog_size if self.step_log is not None else 0)
        out_f = np.zeros(2)
        run_segment(KIND_TREE, self.method, t, t_stop, y, ip, fp, self.rtol, atol,
                    self.max_step, 0.0, times, k_sample, Y, hlog, out_i, out_f)
        if out_i[0] != 0:
            raise RuntimeError(f'compiled kernel: integration failed near t={t:.6f} s: '
                               f'{_STATUS.get(int(out_i[0]), "status " + str(int(out_i[0])))}')
        if self.step_log is not None and out_i[6] < out_i[3]:
            self._hlog_size = 2 * int(out_i[3])          # too small: again with room
            return self._segment(mt, mode, t, t_stop, y0, times, k_sample, stats)
        stats['steps'] += int(out_i[3])
        stats['nfev'] += int(out_i[4])
        if self.step_log is not None:
            self.step_log.append(hlog[:int(out_i[6])].copy())
        k_new = int(out_i[2])
        return y, float(out_f[0]), int(out_i[1]), k_new, Y[k_sample:k_new]

    def run(self) -> HybridResult:
        """As HybridTreeSimulation.run, each mode's integration one compiled call."""
        self._t_now = 0.0
        mode, mt, x = self._initial()
        st = mt.to_state(x, 0.0)
        om = mt.evaluate(0.0, x, self.engine, 0.0, {b: 0.0 for b in self.brake_els},
                         torques=False).wheel_speed
        for name in self.brake_els:
            mode.brakes[name] = -1 if om[name] < 0 else FORWARD
        mode, st = self._settle(0.0, mode, st)
        mt = self.tree(mode)
        x0, _l = mt.from_state(st, False)
        e0 = mt.energy_total(x0)
        names = self.shaft_names
        times = np.arange(0.0, self.duration + 0.5 * self.sample_dt, self.sample_dt)
        times = times[times <= self.duration + 1e-12]
        speed = np.full((times.size, len(names)), np.nan)
        resid = np.full(times.size, np.nan)
        gears = np.zeros(times.size, dtype=int)
        vel = np.full(times.size, np.nan)
        gb_name = next(iter(self.gearboxes), None)
        k_sample = 0
        stats = {'steps': 0, 'nfev': 0, 'events': 0, 'restarts': 0}
        stall: str | None = None

        js = self._joint_arrays(times.size, len(names)) if self.joint_samples else None

        def record(m: ModeTree, xx: np.ndarray, lock_loss: float, md: Mode, i: int) -> None:
            speed[i] = m.shaft_speeds(xx)
            tot = m.energy_total(xx)
            we, wd, ws, wr, wf = m.works(xx)
            scale = max(abs(tot), abs(e0), abs(we), abs(wd), abs(ws), abs(wr), abs(wf),
                        abs(lock_loss), 1e-12)
            resid[i] = (tot - e0 - we + wd + ws + wr + wf + lock_loss) / scale
            gears[i] = md.gear[gb_name] if gb_name else 0
            vel[i] = m.vehicle_speed(xx)
            if js is not None:
                p_, _v, e_, te_ = self.joint_state(m, float(times[i]), xx)
                js[0][i], js[1][i], js[2][i] = p_, e_, te_

        t = 0.0
        mode, st = self._shift(0.0, mode, st)
        while t < self.duration and stall is None:
            self._t_now = t
            t_stop = min(self.schedule.next_breakpoint(t), self.duration)
            if t_stop - t <= 1e-12 * max(1.0, abs(t)):
                t = t_stop
                if t < self.duration:
                    mode, st = self._shift(t, mode, st)
                    mode, st = self._settle(t, mode, st)
                continue
            mt = self.tree(mode)
            y0 = mode_state(mt, st)
            stats['restarts'] += 1
            ws = self._witnesses(mode)
            if any(w.key[0] == 'shift' for w in ws) or self.stall_speed is not None:
                need_t = any(w.key[0] == 'clutch' and w.key[2] != STUCK for w in ws)
                ev0 = self._eval(mt, t, y0, need_t)
                late = [w for w in ws if w.key[0] == 'shift'
                        and self._g(w, ev0, t, mode) * w.direction >= 0.0]
                if late:        # as the reference: the shift starts now
                    _k, name, target = late[0].key
                    g = mode.gear[name]
                    self.auto.start(t, target)
                    stats['events'] += 1
                    self._log(t, name, f'gear {g}', f'shift to {target}',
                              'up-shift speed' if target > g else 'down-shift speed')
                    continue
                if self.stall_speed is not None and ev0.engine_speed < self.stall_speed:
                    stall = (f'engine stalled at t={t:.6f} s: {ev0.engine_speed:.2f} rad/s below '
                             f'the stall speed {self.stall_speed:.2f} rad/s')
                    break
            y, t_end, ev_i, k_new, Y = self._segment(mt, mode, t, t_stop, y0, times, k_sample,
                                                     stats)
            for k in range(k_sample, k_new):
                record(mt, Y[k - k_sample], st.lock_loss, mode, k)
            k_sample = k_new
            if ev_i >= 0:
                st = mt.to_state(y, st.lock_loss)
                t = t_end
                self._t_now = t
                stats['events'] += 1
                kind, name, target = ws[ev_i].key
                if kind == 'stall':
                    stall = (f'engine stalled at t={t:.6f} s: speed fell below the stall '
                             f'speed {self.stall_speed:.2f} rad/s '
                             f'({self.stall_speed * 30 / math.pi:.0f} rpm)')
                    break
                if kind == 'shift':
                    g = mode.gear[name]
                    self.auto.start(t, target)
                    self._log(t, name, f'gear {g}', f'shift to {target}',
                              'up-shift speed' if target > g else 'down-shift speed')
                    continue
                if target == STUCK:
                    mode, st = self._try_stick(t, mode, st, kind, name,
                                               'zero speed' if kind == 'brake' else 'zero slip')
                else:
                    mode = self._release(t, mode, kind, name, target,
                                         'torque above static capacity')
                mode, st = self._settle(t, mode, st, (name,))
                if t >= t_stop and t < self.duration:
                    mode, st = self._shift(t, mode, st)
                    mode, st = self._settle(t, mode, st, (name,))
                continue
            t = t_stop
            st = mt.to_state(y, st.lock_loss)
            if t < self.duration:
                self._t_now = t
                mode, st = self._shift(t, mode, st)
                mode, st = self._settle(t, mode, st)
        if stall is not None:
            self.statuses.append(stall)
        keep = k_sample
        res = HybridResult(times[:keep], list(names), speed[:keep], resid[:keep], gears[:keep],
                           list(self.events), list(self.statuses), stall, st, mode, t, stats)
        res.vehicle_speed = vel[:keep]          # type: ignore[attr-defined]
        if js is not None:
            res.position, res.effort, res.engine_torque = (a[:keep] for a in js)
        return res
