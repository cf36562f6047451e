"""Least squares on order amplitudes, confidence intervals and identifiability.

Residuals r = model - measured over [mean, A_1 .. A_n] (N m, unweighted: all in the same unit
and of the same measurement), or over a chosen subset of those entries. The parameters are
solved in normalised coordinates u = (p - LO)/(HI - LO) in [0, 1] by
``scipy.optimize.least_squares`` (trust-region reflective, bounds [0, 1], start at the middle
of every range, optionally also at more fixed points, the lowest cost kept; two-point
differences of step 1e-3 in u), which makes the result a deterministic function of the inputs.

At the optimum, with J the Jacobian in u and J = U S V^T its singular value decomposition:

* a singular value below ``ident_tol`` * s_max (or every one when s_max = 0) is a direction
  the data do not see; a parameter whose share of such directions, sum_k V[j, k]^2, exceeds
  1/2 is reported as not identifiable and given no value;
* the residual variance s^2 = |r|^2 / (m - q) (m residuals, q identifiable directions) and
  Cov(u) = s^2 V S^+2 V^T over the identifiable directions; the confidence interval of
  p_j is +- t_{0.975, m - q} sqrt(Cov_jj) (HI - LO) (Student t, 95 %). With m - q = 0 the
  parameters fit exactly and no interval follows.
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from cvj_ros.fit.problem import FitProblem

__all__ = ['FitResult', 'ParameterEstimate', 'solve_fit', 'start_points', 'IDENT_TOL', 'DIFF_STEP']

FloatArray = NDArray[np.float64]
IDENT_TOL = 1e-6
DIFF_STEP = 1e-3
LEVEL = 0.95
AT_BOUND = 1e-3          # u within this of 0 or 1: the optimum is on the range's bound


@dataclass(frozen=True)
class ParameterEstimate:
    """One fitted parameter: ``value`` (None when not identifiable), the half width of its
    95 % confidence interval ``ci`` (None when none follows), ``at_bound`` when the optimum
    sits on LO or HI."""

    path: str
    field: str
    value: float | None
    ci: float | None
    identifiable: bool
    at_bound: bool
    lo: float
    hi: float


@dataclass(frozen=True)
class FitResult:
    """The fit: ``estimates`` per parameter, ``measured``/``fitted`` [mean, A_1..A_n] (N m),
    ``singular_values`` of the normalised Jacobian, the solver's ``status``/``message``,
    ``evaluations`` of the model, ``dof`` = m - q."""

    estimates: tuple[ParameterEstimate, ...]
    measured: FloatArray
    fitted: FloatArray
    used: tuple[int, ...]         # the entries of measured/fitted the residuals held
    singular_values: FloatArray
    dof: int
    sigma: float | None
    evaluations: int
    status: int
    message: str
    values: FloatArray            # every parameter at the optimum (also the unidentifiable)

    @property
    def residuals(self) -> FloatArray:
        return self.fitted - self.measured


def start_points(n: int, starts: int) -> list[FloatArray]:
    """``starts`` starting points in [0, 1]^n: the middle, then the unscrambled Halton
    sequence (bases 2, 3, 5, ...) from its second point on, so the same on every machine."""
    if starts < 1:
        raise ValueError(f'starts: must be >= 1, got {starts}')
    points = [np.full(n, 0.5)]
    if starts > 1:
        from scipy.stats import qmc
        points += list(qmc.Halton(d=n, scramble=False).random(starts)[1:])
    return points


def solve_fit(problem: FitProblem, measured: FloatArray, *, use: Sequence[int] | None = None,
              starts: int = 1, ident_tol: float = IDENT_TOL,
              max_nfev: int | None = None) -> FitResult:
    """Fit ``problem`` to ``measured`` ([mean, A_1..A_n], N m). ``use``: the entries of that
    vector the residuals hold (default all; e.g. the mean and the even orders, the only ones a
    model can produce); the result reports every entry. ``starts``: local fits from that many
    starting points (:func:`start_points`), the lowest cost kept (the least squares is local:
    a cost with several minima needs more than one)."""
    from scipy.optimize import least_squares
    from scipy.stats import t as student_t
    params = list(problem.params)
    n = len(params)
    meas = np.asarray(measured, dtype=float)
    sel = np.arange(meas.size) if use is None else np.asarray(sorted(set(use)), dtype=int)
    if sel.size == 0 or sel[0] < 0 or sel[-1] >= meas.size:
        raise ValueError(f'use: entries must lie in 0..{meas.size - 1}, got {list(sel)}')

    def to_values(u: FloatArray) -> list[float]:
        return [p.value(float(x)) for p, x in zip(params, u)]

    def resid(u: FloatArray) -> FloatArray:
        return (problem.predict(to_values(u)) - meas)[sel]

    sol = None
    for u0 in start_points(n, starts):
        trial = least_squares(resid, u0, bounds=(np.zeros(n), np.ones(n)), method='trf',
                              diff_step=DIFF_STEP, x_scale=1.0, max_nfev=max_nfev or 100 * n)
        if sol is None or trial.cost < sol.cost:      # first start wins a tie: deterministic
            sol = trial
    u = sol.x
    r = resid(u)
    J = _jacobian(resid, u, r)
    _U, s, Vt = np.linalg.svd(J, full_matrices=False)
    s_max = float(s[0]) if s.size else 0.0
    keep = s > ident_tol * s_max if s_max > 0 else np.zeros_like(s, dtype=bool)
    V = Vt.T
    share_lost = np.sum(V[:, ~keep] ** 2, axis=1) if np.any(~keep) else np.zeros(n)
    ident = share_lost <= 0.5
    q = int(np.count_nonzero(keep))
    m = sel.size
    dof = m - q
    sigma = math.sqrt(float(r @ r) / dof) if dof > 0 else None
    cov = None
    if sigma is not None and q:
        Vk = V[:, keep]
        cov = sigma ** 2 * (Vk / s[keep] ** 2) @ Vk.T
    tq = float(student_t.ppf(0.5 + LEVEL / 2, dof)) if dof > 0 else math.nan
    values = np.array(to_values(u))
    est = []
    for j, p in enumerate(params):
        ci = None
        if cov is not None and ident[j]:
            ci = tq * math.sqrt(max(float(cov[j, j]), 0.0)) * (p.hi - p.lo)
        est.append(ParameterEstimate(
            path=p.path, field=p.field, value=float(values[j]) if ident[j] else None, ci=ci,
            identifiable=bool(ident[j]), at_bound=bool(u[j] <= AT_BOUND or u[j] >= 1 - AT_BOUND),
            lo=p.lo, hi=p.hi))
    fitted = problem.predict(values.tolist())
    return FitResult(estimates=tuple(est), measured=meas, fitted=fitted,
                     used=tuple(int(i) for i in sel), singular_values=s, dof=dof, sigma=sigma,
                     evaluations=problem.evaluations, status=int(sol.status),
                     message=str(sol.message), values=values)


def _jacobian(resid, u: FloatArray, r0: FloatArray) -> FloatArray:
    """Two-point differences of step DIFF_STEP in u at ``u``, stepping inward at a bound."""
    J = np.empty((r0.size, u.size))
    for j in range(u.size):
        h = DIFF_STEP if u[j] + DIFF_STEP <= 1.0 else -DIFF_STEP
        du = u.copy()
        du[j] += h
        J[:, j] = (resid(du) - r0) / h
    return J
