"""Constraints as backend-independent objects, like objective terms.

A constraint is data (distances, a mode) plus a way to express itself for each backend that
can take it: ``casadi_rows`` writes its rows ``g <= 0`` at one stage of a CasADi NLP,
``cvxpy_rows`` its convex (linearized) form over the horizon of the CVXPY backend's QP. A
backend asks :meth:`Constraint.require`; one that a constraint does not support refuses at
construction, naming the constraint and the backends that accept it.

The OCP calls ``casadi_rows`` with ``x_next`` each predicted state ``x_k`` (``k = 1..T``, and
``x`` None), or, for a constraint that :attr:`Constraint.couples_stages`, once per stage
``k = 0..T-1`` with ``x = x_k`` and ``x_next`` its successor written ``F(x_k, u_k)`` (so that
the rows stay local to stage ``k``, the form fatrop needs); with the state's slack (a
variable ``>= 0`` of its stage when :attr:`Constraint.soft`, else None) and the per-step
quantities (:class:`~mpclab.objectives.base.TermContext`, plus the constraint's own
parameters, declared by :meth:`Constraint.declare` and filled each step by
:meth:`Constraint.values`). A soft constraint adds ``penalty * slack_k`` to the cost.

The CVXPY backend calls ``cvxpy_rows`` once, on the whole predicted horizon, with the
slacks ``(T,)`` of a soft constraint; a constraint that is not convex writes its
linearization about a trajectory, as CVXPY parameters (:meth:`Constraint.cvxpy_declare`)
that the backend fills wherever it linearizes (:meth:`Constraint.cvxpy_values`), so that the
problem is compiled once. :meth:`Constraint.violation` judges a plan in numbers, the same
for every backend: a warm start that breaks a constraint is cut there, and successive
linearization weighs a rollout by it.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from mpclab.config.expressible import Expressible

#: backend name -> the Constraint method that expresses a constraint for it
BACKEND_METHODS = {"casadi": "casadi_rows", "cvxpy": "cvxpy_rows"}
#: a predicted state closer than this to breaking a constraint still keeps it [m]
KEPT = 1e-9


class Constraint(Expressible):
    """Base class of constraints. ``name`` is set by the objective from its config key."""

    backend_methods = BACKEND_METHODS
    kind = "constraint"

    #: one slack variable >= 0 per stage, penalised by ``penalty * slack`` (exact L1)
    soft: bool = False
    penalty: float = 0.0
    #: whether the rows couple a state and its successor (else they read ``x_next`` alone)
    couples_stages: bool = False

    def bind(self, plant: Any) -> None:
        """Resolve state labels against ``plant``; called once by the backend."""

    def declare(self, params: Any, n_points: int) -> dict[str, Any]:
        """Declare this constraint's per-step parameters on ``params`` (a
        :class:`~mpclab.controllers.casadi.ocp.Params`); return ``{name: symbol}``."""
        return {}

    def values(self, x0: Any, detections: Any, mask: Any) -> dict[str, Any]:
        """The per-step values of the parameters :meth:`declare` named, from the measured
        state ``x0 (nx,)``, the padded detections ``(2, M)`` and their mask ``(M,)``."""
        return {}

    def casadi_rows(self, x: Any, x_next: Any, slack: Any, ctx: Any, par: Mapping[str, Any],
                    first: bool) -> Any:
        """Rows ``g <= 0`` (a CasADi column) at one stage; ``first``: stage 0."""
        raise NotImplementedError

    def cvxpy_declare(self, params: Any, n_points: int, horizon: int) -> dict[str, Any]:
        """Declare the CVXPY parameters of :meth:`cvxpy_rows` on ``params`` (``add(name, rows,
        cols)``, as :meth:`declare`'s); return ``{name: parameter}``."""
        return {}

    def cvxpy_values(self, x0: Any, X: Any, detections: Any, mask: Any) -> dict[str, Any]:
        """The values of the parameters :meth:`cvxpy_declare` named, linearized about the
        trajectory ``X (T+1, nx)`` (numbers), at the measured state ``x0`` and the padded
        detections ``(2, M)`` with their mask ``(M,)``."""
        return {}

    def cvxpy_rows(self, X: Any, slack: Any, ctx: Any, par: Mapping[str, Any]) -> list[Any]:
        """CVXPY constraints (DPP) on the predicted states ``X[:, 1:]`` of ``X (nx, T+1)``;
        ``slack``: the stages' slacks ``(T,)`` (a variable ``>= 0``) when soft, else None."""
        raise NotImplementedError

    def violation(self, x0: Any, X: Any, detections: Any, mask: Any) -> np.ndarray | None:
        """How far each predicted state ``x_k`` (``k = 1..T``) of the plan ``X (T+1, nx)``
        (numbers) breaks this constraint at the current detections, ``(T,)``, 0 where it
        holds; None (the default): never judged."""
        return None

    def first_violation(self, x0: Any, X: Any, detections: Any, mask: Any) -> int | None:
        """The first step ``k >= 1`` at which the plan ``X (T+1, nx)`` (numbers) breaks this
        constraint at the current detections, or None (also when never judged)."""
        v = self.violation(x0, X, detections, mask)
        bad = np.flatnonzero(v > KEPT) if v is not None else np.zeros(0)
        return int(bad[0]) + 1 if bad.size else None

    def info(self) -> dict[str, Any]:
        """What the run record shows of this constraint."""
        return {"type": type(self).__name__}
