"""Objective terms and the objective that composes them.

A term is data (weights, targets) plus a way to express itself for each backend that can
take it: ``cvxpy_cost`` builds a DPP-compliant CVXPY expression, ``casadi_cost`` a CasADi one.
Both receive the predicted horizon and a :class:`TermContext`, the per-step quantities as the
backend's own parameters. A backend asks :meth:`Term.require`; one that a term does not
support refuses at construction, naming the term and the backends that accept it.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from mpclab.config.expressible import Expressible
from mpclab.config.registry import component
from mpclab.constraints.base import Constraint
from mpclab.core.errors import ConfigError

#: backend name -> the Term method that expresses a term for it
BACKEND_METHODS = {"cvxpy": "cvxpy_cost", "casadi": "casadi_cost"}


@dataclass(frozen=True)
class TermContext:
    """What a term may use besides the predicted horizon, as the backend's parameters.

    The CasADi backend hands symbols (column vectors), the CVXPY backend ``cp.Parameter``
    objects; a field a backend does not provide is None, and a term that needs it refuses
    that backend (it does not override the backend's method).

    Attributes
    ----------
    x0
        The measured state ``(nx,)``.
    target
        The reference over the horizon ``(nx, T+1)``.
    u_prev
        The input applied at the previous step ``(nu,)`` (zero before the first).
    goal
        The goal state ``(nx,)``.
    detections, mask
        Detected points ``(2, M)`` and ``(M,)`` with 1 for a real point, 0 for padding.
    u_before
        The input in force before each predicted step ``(nu, T)``: ``u_prev``, then the plan's
        own ``u_0 .. u_{T-2}``. None: a term builds it from ``u_prev`` and ``U``. A
        stage-structured NLP (fatrop) gives lifted variables here, so that a term using it
        stays local to each stage.
    """

    x0: Any
    target: Any
    u_prev: Any
    goal: Any = None
    detections: Any = None
    mask: Any = None
    u_before: Any = None


class Term(Expressible):
    """Base class of objective terms. ``name`` is set by the objective from its config key."""

    backend_methods = BACKEND_METHODS
    kind = "objective term"

    #: whether the term reads ``TermContext.u_before`` (couples each step to the one before)
    uses_input_before: bool = False

    def bind(self, plant: Any) -> None:
        """Resolve state/input labels against ``plant``; called once by the backend."""

    def cvxpy_cost(self, X: Any, U: Any, ctx: TermContext) -> Any:
        """CVXPY expression (DPP) over ``X (nx, T+1)``, ``U (nu, T)``."""
        raise NotImplementedError

    def casadi_cost(self, X: Any, U: Any, ctx: TermContext) -> Any:
        """CasADi expression over ``X (nx, T+1)``, ``U (nu, T)``."""
        raise NotImplementedError

@dataclass
class ObjectiveConf:
    _target_: str = "mpclab.objectives.base.Objective"
    terms: dict[str, Any] = field(default_factory=dict)
    constraints: dict[str, Any] = field(default_factory=dict)


@component("objective", "objective", ObjectiveConf)
class Objective:
    """A named set of terms; the cost is their sum (or the sum of the active ones).

    ``constraints`` (:mod:`mpclab.constraints`) hold in every mode, whichever terms are on.
    """

    def __init__(self, terms: Mapping[str, Term],
                 constraints: Mapping[str, Constraint] | None = None) -> None:
        if not terms:
            raise ConfigError("objective.terms is empty: an objective needs at least one term")
        self.terms: dict[str, Term] = {}
        for name, term in terms.items():
            if not isinstance(term, Term):
                raise ConfigError(
                    f"objective.terms.{name} is not an objective term (got "
                    f"{type(term).__name__}); give it a _target_ naming a Term class"
                )
            term.name = name
            self.terms[name] = term
        self.constraints: dict[str, Constraint] = {}
        for name, con in (constraints or {}).items():
            if not isinstance(con, Constraint):
                raise ConfigError(
                    f"objective.constraints.{name} is not a constraint (got "
                    f"{type(con).__name__}); give it a _target_ naming a Constraint class "
                    "(e.g. mpclab.constraints.obstacle.ObstacleDistance)"
                )
            con.name = name
            self.constraints[name] = con

    def bind(self, plant: Any, backend: str) -> None:
        for term in self.terms.values():
            term.require(backend)
            term.bind(plant)
        for con in self.constraints.values():
            con.require(backend)
            con.bind(plant)

    def __iter__(self):
        return iter(self.terms.values())
