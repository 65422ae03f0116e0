"""Plain quadratic tracking: ``sum_k sum_i w_i (x_i[k] - r_i[k])^2 + sum_k sum_j r_j u_j[k]^2``.

States are weighted over prediction steps ``k = 1..T`` (the initial state is fixed), inputs
over ``k = 0..T-1``. The reference ``r`` is the backend's ``target`` parameter: the goal
repeated, or a scenario's reference sampled over the horizon.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import casadi as ca
import numpy as np

from mpclab.core.errors import ConfigError, number
from mpclab.core.lazy_import import lazy_import
from mpclab.objectives.base import Term, TermContext

cp = lazy_import("cvxpy")  # about 0.6 s to import: paid only by runs that use it


class QuadraticTracking(Term):
    """Quadratic tracking of the target plus quadratic input effort.

    Parameters
    ----------
    state_weights
        ``{state label: weight}`` on ``(x - target)^2`` over steps 1..T.
    input_weights
        ``{input label: weight}`` on ``u^2`` over steps 0..T-1.
    terminal_weights
        ``{state label: weight}`` added on the last predicted state only.
    """

    def __init__(
        self,
        state_weights: Mapping[str, float] | None = None,
        input_weights: Mapping[str, float] | None = None,
        terminal_weights: Mapping[str, float] | None = None,
    ) -> None:
        self.state_weights = dict(state_weights or {})
        self.input_weights = dict(input_weights or {})
        self.terminal_weights = dict(terminal_weights or {})
        for what, weights in (
            ("state_weights", self.state_weights),
            ("input_weights", self.input_weights),
            ("terminal_weights", self.terminal_weights),
        ):
            for label, w in weights.items():
                weights[label] = number(w, f"{what}.{label}", at_least=0)

    def bind(self, plant: Any) -> None:
        def split(weights: dict[str, float], index: Any) -> tuple[list[int], np.ndarray]:
            try:
                idx = [index(label) for label in weights]
            except ValueError as exc:
                raise ConfigError(f"objective term {self.name!r}: {exc}") from None
            return idx, np.sqrt(np.array([float(w) for w in weights.values()]))

        self._qi, self._q = split(self.state_weights, plant.state_index)
        self._ri, self._r = split(self.input_weights, plant.input_index)
        self._ti, self._t = split(self.terminal_weights, plant.state_index)

    def cvxpy_cost(self, X: Any, U: Any, ctx: TermContext) -> Any:
        cost = 0
        target = ctx.target
        if self._qi:
            err = X[self._qi, 1:] - target[self._qi, 1:]
            cost += cp.sum_squares(cp.multiply(self._q[:, None], err))
        if self._ri:
            cost += cp.sum_squares(cp.multiply(self._r[:, None], U[self._ri, :]))
        if self._ti:
            cost += cp.sum_squares(cp.multiply(self._t, X[self._ti, -1] - target[self._ti, -1]))
        return cost

    def casadi_cost(self, X: Any, U: Any, ctx: TermContext) -> Any:
        cost = 0
        target = ctx.target
        if self._qi:
            err = X[self._qi, 1:] - target[self._qi, 1:]
            cost += ca.sumsqr(ca.diag(self._q) @ err)
        if self._ri:
            cost += ca.sumsqr(ca.diag(self._r) @ U[self._ri, :])
        if self._ti:
            cost += ca.sumsqr(ca.diag(self._t) @ (X[self._ti, -1] - target[self._ti, -1]))
        return cost
