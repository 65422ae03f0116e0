"""A one-step control-barrier-function safety filter on the applied input (a backstop).

Whatever produced the input ``u_nom`` (an NLP solved to convergence, a truncated iteration,
a neural network), the filter applies the input nearest to it that keeps the discrete-time
CBF condition on the next state, linearized in the input::

    min |u - u_nom|^2   s.t.   h_i(p_1(u_nom)) + dh_i J (u - u_nom) >= (1 - gamma) h_i(p_0),
                               u_lb <= u <= u_ub

(linearized at ``u_nom``, then again at each answer, ``iterations`` times at most) with
``h_i(p) = |p - q_i|^2 - R_i^2`` for each detected point ``q_i``, ``R_i = min(R,
|p_0 - q_i|)`` (standing still always keeps the condition), ``p_1(u)`` the position one
model step ahead and ``J = dp_1/du`` the plant's step Jacobian. The QP has as many variables as
the plant has inputs; it is solved exactly by enumerating active sets of at most ``nu``
constraints (every candidate feasible, the nearest taken). The step's ``info`` says whether
the filter changed the input (``safety_filter``: 0 untouched, 1 modified, 2 no input kept
the linearized condition: the one violating it least is applied) and how far the applied
input falls short of the condition on the model's next state, not linearized
(``safety_filter_shortfall``, 0 where it holds; counted in the summary).
"""

from __future__ import annotations

from functools import cache
from itertools import combinations
from typing import Any

import casadi as ca
import numpy as np

from mpclab.config.registry import component
from mpclab.core.errors import ConfigError, number

FloatArray = np.ndarray
#: the step log's columns of the filter: its code and the applied input's shortfall
CODE, SHORTFALL = "safety_filter", "safety_filter_shortfall"
#: a shortfall above this counts [m^2] (the condition's values are ~1e-3 m^2 near a point;
#: an input placed on the linearized boundary falls short by round-off, ~1e-14)
SHORTFALL_TOL = 1e-10


@component("safety_filter", "cbf", injected=("plant",))
class SafetyFilter:
    """The one-step CBF filter of a plant's input.

    Parameters
    ----------
    plant
        Injected; its ``position`` labels locate the robot, its ``step`` predicts.
    distance
        ``R`` [m] kept from every detected point; None (the default): the run's obstacle
        margin, derived from the world's stated bounds (:mod:`mpclab.world.margin`).
    gamma
        The barrier's decay rate per step, ``0 < gamma <= 1``.
    dt
        The control period [s] the next state is predicted over.
    iterations
        Linearizations at most, each at the last answer (the first at ``u_nom``): ``h`` is
        convex in the position, so each linearized set lies inside the true one for a
        position affine in the input, and the answer approaches the nearest input.
    """

    def __init__(self, plant: Any, distance: float | None = None, gamma: float = 0.5,
                 dt: float = 0.2, iterations: int = 5) -> None:
        self.plant = plant
        self.stated = distance is not None
        self._distance = None if distance is None else number(
            distance, "safety_filter.distance", above=0)
        self.gamma = number(gamma, "safety_filter.gamma", above=0)
        if self.gamma > 1:
            raise ConfigError(f"safety_filter.gamma must be in (0, 1], got {gamma}")
        self.dt = number(dt, "safety_filter.dt", above=0)
        self.iterations = int(number(iterations, "safety_filter.iterations", at_least=1))
        self._ip = [plant.state_index(s) for s in plant.position]
        # the position one step ahead and its Jacobian in the input, one call (from the
        # plant's step, derived from its rhs)
        xs, us = ca.SX.sym("x", plant.nx), ca.SX.sym("u", plant.nu)
        p1 = plant.F(xs, us, self.dt)[self._ip]
        self._ahead = ca.Function("position_ahead", [xs, us], [p1, ca.jacobian(p1, us)])

    @property
    def distance(self) -> float:
        """The distance kept [m]: stated, or the run's derived obstacle margin."""
        if self._distance is None:
            raise ConfigError("safety_filter.distance: derived from the scenario's obstacle "
                              "margin, and this run has none (a scenario without a range "
                              "sensor); state it with safety_filter.distance=<metres>")
        return self._distance

    def keep(self, budget: Any) -> None:
        """Keep the run's derived margin (a :class:`mpclab.world.margin.MarginBudget`)
        unless a distance was stated."""
        if not self.stated:
            self._distance = budget.total

    def shortfall(self, x: FloatArray, u: FloatArray, points: FloatArray) -> float:
        """How far the input ``u`` falls short of the CBF condition on the model's next
        state, not linearized: ``max_i ((1 - gamma) h_i(p_0) - h_i(p_1(u)))``, 0 where it
        holds [m^2]."""
        q = np.asarray(points, float).reshape(-1, 2)
        if len(q) == 0:
            return 0.0
        x = np.asarray(x, float)
        p0, p1 = x[self._ip], self._p1_and_jacobian(x, np.asarray(u, float))[0]
        R = np.minimum(self.distance, np.linalg.norm(q - p0, axis=1))
        h0 = np.sum((p0 - q) ** 2, axis=1) - R**2
        h1 = np.sum((p1 - q) ** 2, axis=1) - R**2
        return float(max(np.max((1 - self.gamma) * h0 - h1), 0.0))

    def metrics(self, steps: Any) -> dict[str, Any]:
        """The run's filtered steps: modified (code 1), without an input that kept the
        linearized condition (code 2), and whose applied input fell short of the condition
        on the model's next state (``safety_filter_shortfall`` above :data:`SHORTFALL_TOL`)."""
        codes = steps[CODE].dropna().astype(int) if CODE in steps else []
        short = steps[SHORTFALL].dropna() if SHORTFALL in steps else []
        return {"safety_filter_modified": int(sum(c == 1 for c in codes)),
                "safety_filter_unkept": int(sum(c == 2 for c in codes)),
                "safety_filter_shortfalls": int(sum(v > SHORTFALL_TOL for v in short))}

    def _p1_and_jacobian(self, x: FloatArray, u: FloatArray) -> tuple[FloatArray, FloatArray]:
        """The position one model step ahead ``(2,)`` and ``dp_1/du`` ``(2, nu)``."""
        p1, J = self._ahead(x, u)
        return np.asarray(p1, dtype=float).ravel(), np.asarray(J, dtype=float)

    def filter(self, x: FloatArray, u_nom: FloatArray, points: FloatArray,
               ) -> tuple[FloatArray, int]:
        """``(u, code)``: the filtered input and 0 (untouched), 1 (modified) or 2 (no input
        kept the linearized condition; the least violating one)."""
        x, u_nom = np.asarray(x, float), np.asarray(u_nom, float)
        q = np.asarray(points, float).reshape(-1, 2)
        if len(q) == 0:
            return u_nom, 0
        p0 = x[self._ip]
        R = np.minimum(self.distance, np.linalg.norm(q - p0, axis=1))
        h = lambda p: np.sum((p - q) ** 2, axis=1) - R**2  # noqa: E731
        p1, J = self._p1_and_jacobian(x, u_nom)
        if np.all(h(p1) >= (1 - self.gamma) * h(p0)):
            return u_nom, 0
        nu = len(u_nom)
        lb, ub = self.plant.u_lb - u_nom, self.plant.u_ub - u_nom
        d, code = np.zeros(nu), 2
        for k in range(self.iterations):  # linearized at the last answer, from u_nom
            if k:
                p1, J = self._p1_and_jacobian(x, u_nom + d)
            A = 2 * (p1 - q) @ J                                 # (n, nu)
            b = (1 - self.gamma) * h(p0) - h(p1) + A @ d         # A du >= b
            new, code = self._qp(A, b, lb, ub)
            done = float(np.max(np.abs(new - d))) < 1e-6
            d = new
            if done:
                break
        return u_nom + d, code

    @staticmethod
    def _qp(A: FloatArray, b: FloatArray, lb: FloatArray, ub: FloatArray,
            ) -> tuple[FloatArray, int]:
        """``min |d|^2 s.t. A d >= b, lb <= d <= ub`` by enumerating active sets of at most
        ``nu`` rows, every set of one size at once; ``(d, 1)``, or ``(d, 2)`` the least
        violating ``d`` within the bounds when none holds."""
        nu = A.shape[1]
        near = b > -np.abs(A).sum(axis=1) * np.max(ub - lb)   # rows that can bind
        eye = np.eye(nu)
        lower, upper = np.isfinite(lb), np.isfinite(ub)
        Ar = np.vstack([A[near], eye[lower], -eye[upper]])    # d_j >= lb_j, -d_j >= -ub_j
        br = np.concatenate([b[near], lb[lower], -ub[upper]])
        candidates = [np.zeros((1, nu))]                        # the empty set first
        for size in range(1, min(nu, len(br)) + 1):
            S = _sets(len(br), size)
            AS = Ar[S]                                          # (sets, size, nu)
            G = AS @ AS.transpose(0, 2, 1)
            scale = np.prod(np.diagonal(G, axis1=1, axis2=2), axis=1)
            ok = np.abs(np.linalg.det(G)) > 1e-12 * scale       # independent rows only
            if ok.any():
                lam = np.linalg.solve(G[ok], br[S[ok]][..., None])
                candidates.append((AS[ok].transpose(0, 2, 1) @ lam)[..., 0])
        D = np.vstack(candidates)                               # (candidates, nu)
        viol = np.max(br[None] - D @ Ar.T, axis=1)
        norm = np.sum(D * D, axis=1)
        feasible = viol <= 1e-9
        if feasible.any():
            return D[np.flatnonzero(feasible)[np.argmin(norm[feasible])]], 1
        within = np.all((D >= lb - 1e-9) & (D <= ub + 1e-9), axis=1)
        if not within.any():
            return np.zeros(nu), 2
        return D[np.flatnonzero(within)[np.argmin(viol[within])]], 2


@cache
def _sets(n: int, size: int) -> np.ndarray:
    """Every set of ``size`` of ``n`` rows ``(sets, size)``, in ``combinations``' order."""
    return np.array(list(combinations(range(n), size)), dtype=int).reshape(-1, size)
