"""A whole offline run in one compiled call for the efficient RK pairs ('tsit5', 'vern6'):
``run_nb``'s protocol (the packs, the stepper's buffers, per-run outputs; see its
docstring) over ``steppers_rk_nb``'s landing and sampled loops, then ``sample_outputs`` and
the intermediate members (``run_nb._outputs``).
The pack's method entries (from ``run_nb.E_M0``): C, A, B, E, P of ``erk_tableaux``."""
from __future__ import annotations

from numba import njit

from .borrow_nb import borrowed_all
from .run_nb import E_M0, _common, _f1, _f2, _gather, _outputs, _start, _to_breakpoint
from .steppers_nb import ST_OK
from .steppers_rk_nb import erk_land, erk_sample

__all__ = ['erk_run']


@njit(cache=True)
def erk_run(fpk, ipk, fbuf, ibuf, y, ip, fp, mfp, h0, rtol, max_step, order, e0, X, XG, pos, vel,
            eff, te, tl, res):
    """erk_land or erk_sample / erk_land, then the outputs (as run_nb.dopri5_run)."""
    (fpk, ipk, fbuf, ibuf, y, ip, fp, mfp, X, XG) = borrowed_all((fpk, ipk, fbuf, ibuf, y, ip,
                                                                 fp, mfp, X, XG))
    (x0, times, grid, brk, tb, two, atol, fs, y_old, K, work, rows, seg, tab,
     cnt) = _common(fpk, ipk, fbuf, ibuf)
    C, A = _f1(E_M0, fpk, ipk, fbuf), _f2(E_M0 + 1, fpk, ipk, fbuf)
    B, E = _f1(E_M0 + 2, fpk, ipk, fbuf), _f1(E_M0 + 3, fpk, ipk, fbuf)
    P = _f2(E_M0 + 4, fpk, ipk, fbuf)
    _start(x0, h0, X, fbuf, ibuf, y, y_old, fs)
    if grid.shape[0] > 0:
        st, _k = erk_land(grid, XG, y, y_old, ip, fp, fs, cnt, rtol, atol, max_step, order, C,
                          A, B, E, K, work)
        if st != ST_OK:
            return st, -1
        _gather(X, XG, rows)
    else:
        for i in range(seg.shape[0]):
            k, k_end = seg[i, 0], seg[i, 1]
            if k_end > k:
                st, _k = erk_sample(times[k:k_end], X[k:k_end], y, y_old, ip, fp, fs, cnt, rtol,
                                    atol, max_step, order, C, A, B, E, P, K, work)
                if st != ST_OK:
                    return st, -1
            if _to_breakpoint(brk[i], fs, tb):
                st, _k = erk_land(tb, two, y, y_old, ip, fp, fs, cnt, rtol, atol, max_step,
                                  order, C, A, B, E, K, work)
                if st != ST_OK:
                    return st, -1
    return ST_OK, _outputs(times, X, ip, fp, tab, e0, pos, vel, eff, te, tl, res, ipk, ibuf,
                           mfp)
