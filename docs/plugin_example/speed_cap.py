"""A term of one's own, outside mpclab: a speed cap (the extension guide, docs/extending.md).

``weight * sum_k max(0, v_k - v_max)^2`` over the predicted speeds ``v_1..v_T``: free below
``v_max``, a quadratic penalty above. Subclassing :class:`~mpclab.objectives.base.Term`
registers the class, so a config may name it as ``_target_: speed_cap.SpeedCap`` once the
module is imported (``plugins: [speed_cap]``).
"""

from __future__ import annotations

from typing import Any

import casadi as ca

from mpclab.core.errors import ConfigError, number
from mpclab.objectives.base import Term, TermContext


class SpeedCap(Term):
    """Penalty on predicted speeds above ``v_max`` (the plant's state ``state``)."""

    def __init__(self, v_max: float, weight: float = 100.0, state: str = "v") -> None:
        self.v_max = number(v_max, "v_max", above=0)
        self.weight = number(weight, "weight", at_least=0)
        self.state = state

    def bind(self, plant: Any) -> None:
        if self.state not in plant.states:
            raise ConfigError(f"objective term {self.name!r}: the plant has no state "
                              f"{self.state!r}; its states: {', '.join(plant.states)}")
        self._i = plant.state_index(self.state)

    def casadi_cost(self, X: Any, U: Any, ctx: TermContext) -> Any:
        over = ca.fmax(0, X[self._i, 1:] - self.v_max)
        return self.weight * ca.sumsqr(over)
