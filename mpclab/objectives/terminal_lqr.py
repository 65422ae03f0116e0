"""Terminal cost from the LQR of the linearization at the target: ``(x_T - r_T)' P (x_T - r_T)``.

``P`` solves the discrete algebraic Riccati equation of the plant's own step linearized at
the target (``at``, with the input ``input_at``), ``x+ = A x + B u + c``, with the stage
weights ``Q = diag(state_weights)`` and ``R = diag(input_weights)``: the cost-to-go of the
LQR that takes over after the horizon, the terminal ingredient of the stability argument for
MPC (Rawlings, Mayne, Diehl, *Model Predictive Control*, ch. 2). The weights must be the
stage cost's for that argument; the term does not read the other terms, so state them alike
(a YAML anchor or interpolation does it).

The theory needs ``(A, B)`` stabilizable and ``(A, Q^1/2)`` detectable at the target. Where
it is not (a car at rest: its lateral position and heading do not move without speed), the
term is refused when it is bound, naming the modes, rather than giving a ``P`` that means
nothing.
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
linalg = lazy_import("scipy.linalg")


def unreachable_modes(A: np.ndarray, B: np.ndarray, C: np.ndarray | None = None,
                      ) -> list[tuple[complex, np.ndarray]]:
    """Each eigenvalue of ``A`` on or outside the unit circle that ``B`` cannot move (PBH:
    ``[A - lambda I, B]`` loses rank), or, with ``C``, that ``C`` cannot see
    (``[A - lambda I; C]``), with the directions (columns, in state space) of the lost rank:
    the left null space of the first, the null space of the second."""
    n = A.shape[0]
    seen: list[complex] = []
    out = []
    for lam in np.linalg.eigvals(A):
        if abs(lam) < 1 - 1e-9 or any(abs(lam - s) < 1e-7 for s in seen):
            continue
        seen.append(lam)
        M = (np.hstack([A - lam * np.eye(n), B]).conj().T if C is None
             else np.vstack([A - lam * np.eye(n), C]))
        _, sv, Vh = np.linalg.svd(M)
        rank = int(np.sum(sv > 1e-9 * max(1.0, sv.max())))
        if rank < n:
            out.append((lam, Vh[rank:].conj().T))
    return out


class TerminalLQR(Term):
    """The LQR's cost-to-go at the horizon's end (module docstring).

    Parameters
    ----------
    state_weights, input_weights
        ``{label: weight}``: the diagonal ``Q`` and ``R`` of the Riccati equation (states
        not named: 0; every input needs a positive weight).
    at, input_at
        The linearization point: ``{state label: value}`` (others 0) and ``{input label:
        value}`` (others 0).
    dt
        The step the plant is discretized over [s] (the controller's period).
    """

    def __init__(self, state_weights: Mapping[str, float], input_weights: Mapping[str, float],
                 dt: float, at: Mapping[str, float] | None = None,
                 input_at: Mapping[str, float] | None = None) -> None:
        self.state_weights = {k: number(v, f"state_weights.{k}", at_least=0)
                              for k, v in dict(state_weights or {}).items()}
        self.input_weights = {k: number(v, f"input_weights.{k}", above=0)
                              for k, v in dict(input_weights or {}).items()}
        self.dt = number(dt, "dt", above=0)
        self.at = dict(at or {})
        self.input_at = dict(input_at or {})
        self.P: np.ndarray | None = None

    def bind(self, plant: Any) -> None:
        try:
            Q = np.diag([float(self.state_weights.get(s, 0.0)) for s in plant.states])
            R = np.diag([float(self.input_weights.get(u, 0.0)) for u in plant.inputs])
            x = np.zeros(plant.nx)
            u = np.zeros(plant.nu)
            for label, value in self.at.items():
                x[plant.state_index(label)] = float(value)
            for label, value in self.input_at.items():
                u[plant.input_index(label)] = float(value)
            for label in (*self.state_weights, *self.input_weights):
                if label not in plant.states and label not in plant.inputs:
                    raise ValueError(f"no state or input {label!r}")
        except ValueError as exc:
            raise ConfigError(f"objective term {self.name!r}: {exc}") from None
        if not np.all(np.diag(R) > 0):
            missing = [u for u, r in zip(plant.inputs, np.diag(R), strict=True) if r <= 0]
            raise ConfigError(f"objective term {self.name!r}: input_weights needs a positive "
                              f"weight on every input; missing: {', '.join(missing)}")
        A, B = plant.jacobians(x, u, self.dt)
        self._refuse(plant, unreachable_modes(A, B), "not stabilizable: B cannot move")
        self._refuse(plant, unreachable_modes(A, B, np.sqrt(Q)),
                     "not detectable: the state weights do not see")
        self.P = np.asarray(linalg.solve_discrete_are(A, B, Q, R), dtype=float)
        self.P = (self.P + self.P.T) / 2
        self._L = np.linalg.cholesky(self.P + 1e-12 * np.eye(plant.nx)).T  # P = L' L

    def _refuse(self, plant: Any, modes: list[tuple[complex, np.ndarray]], what: str) -> None:
        if not modes:
            return
        words = []
        for lam, directions in modes:
            weight = np.abs(directions).max(axis=1)
            labels = ", ".join(s for s, w in zip(plant.states, weight, strict=True)
                               if w > 0.3 * weight.max())
            words.append(f"eigenvalue {complex(lam).real:.3g} along {labels}")
        raise ConfigError(
            f"objective term {self.name!r} (TerminalLQR): the linearization at {self.at or 0} "
            f"is {what} {'; '.join(words)}; the LQR terminal cost does not exist there "
            "(linearize elsewhere with at=..., or leave the term out)")

    def cvxpy_cost(self, X: Any, U: Any, ctx: TermContext) -> Any:
        return cp.sum_squares(self._L @ (X[:, -1] - ctx.target[:, -1]))

    def casadi_cost(self, X: Any, U: Any, ctx: TermContext) -> Any:
        e = X[:, -1] - ctx.target[:, -1]
        return ca.bilin(ca.DM(self.P), e, e)
