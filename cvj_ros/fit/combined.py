"""Several operating conditions fitted at once: the same parameters, one residual block each.

:class:`CombinedProblem` stacks the predictions of :class:`~cvj_ros.fit.problem.FitProblem`
instances that share their parameter paths (each may hold its own base scene: another rubber
stiffness, another shaft), so :func:`cvj_ros.fit.solve.solve_fit` fits one parameter vector to
all of them against the concatenated measured vectors.
"""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from cvj_ros.fit.problem import FitParameter, FitProblem

__all__ = ['CombinedProblem']


class CombinedProblem:
    """``problems`` with the same parameter paths; ``predict`` concatenates theirs."""

    def __init__(self, problems: Sequence[FitProblem]) -> None:
        if not problems:
            raise ValueError('problems: need at least one')
        paths = [p.path for p in problems[0].params]
        for pr in problems[1:]:
            if [p.path for p in pr.params] != paths:
                raise ValueError('problems: every problem must fit the same parameters')
        self.problems = list(problems)
        self.params: list[FitParameter] = list(problems[0].params)

    @property
    def evaluations(self) -> int:
        return sum(p.evaluations for p in self.problems)

    def predict(self, values: Sequence[float]) -> NDArray[np.float64]:
        return np.concatenate([p.predict(values) for p in self.problems])
