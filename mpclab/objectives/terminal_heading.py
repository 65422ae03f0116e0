"""Terminal heading: ``weight * (1 - cos(theta_T - theta_goal))`` on the last predicted state.

``1 - cos`` is smooth, periodic (no wrap-around at +-pi) and not convex, so the term has a
CasADi form only: the CVXPY backend refuses it at construction, naming the term.
"""

from __future__ import annotations

from typing import Any

import casadi as ca

from mpclab.core.errors import ConfigError
from mpclab.objectives.base import Term, TermContext


class TerminalHeading(Term):
    """Penalty on the heading error at the end of the horizon (the goal's heading)."""

    def __init__(self, weight: float = 1.0) -> None:
        if not float(weight) >= 0:
            raise ConfigError(f"TerminalHeading.weight must be >= 0, got {weight}")
        self.weight = float(weight)

    def bind(self, plant: Any) -> None:
        if plant.heading is None:
            raise ConfigError(f"objective term {self.name!r} needs a plant with a heading")
        self._ith = plant.state_index(plant.heading)

    def casadi_cost(self, X: Any, U: Any, ctx: TermContext) -> Any:
        return self.weight * (1 - ca.cos(X[self._ith, -1] - ctx.goal[self._ith]))
