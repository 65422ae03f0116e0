"""Input rate: ``sum_k sum_j w_j (u_j[k] - u_j[k-1])^2`` over ``k = 0..T-1``.

``u[-1]`` is the input applied at the previous step (the context's ``u_prev``), so the first
move is charged against what the plant is doing now: a weight here smooths the applied input
across samples, not only within one plan.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import casadi as ca
import numpy as np

from mpclab.core.errors import ConfigError, number
from mpclab.core.lazy_import import lazy_import
from mpclab.objectives.base import Term, TermContext

cp = lazy_import("cvxpy")


class InputRate(Term):
    """Quadratic penalty on input changes, the first against the previously applied input.

    Parameters
    ----------
    weights
        ``{input label: weight}`` on ``(u[k] - u[k-1])^2``; inputs not named are free to jump.
    """

    uses_input_before = True

    def __init__(self, weights: Mapping[str, float]) -> None:
        self.weights = dict(weights or {})
        if not self.weights:
            raise ConfigError("InputRate.weights is empty: name at least one input")
        for label, w in self.weights.items():
            self.weights[label] = number(w, f"weights.{label}", at_least=0)

    def bind(self, plant: Any) -> None:
        try:
            self._idx = [plant.input_index(label) for label in self.weights]
        except ValueError as exc:
            raise ConfigError(f"objective term {self.name!r}: {exc}") from None
        self._w = np.sqrt(np.array([float(w) for w in self.weights.values()]))

    def cvxpy_cost(self, X: Any, U: Any, ctx: TermContext) -> Any:
        Ui = U[self._idx, :]
        first = cp.multiply(self._w, Ui[:, 0] - ctx.u_prev[self._idx])
        cost = cp.sum_squares(first)
        if U.shape[1] > 1:
            cost += cp.sum_squares(cp.multiply(self._w[:, None], Ui[:, 1:] - Ui[:, :-1]))
        return cost

    def casadi_cost(self, X: Any, U: Any, ctx: TermContext) -> Any:
        before = ctx.u_before
        if before is None:
            before = ca.horzcat(ctx.u_prev, U[:, :-1])
        du = U[self._idx, :] - before[self._idx, :]
        return ca.sumsqr(ca.diag(self._w) @ du)
