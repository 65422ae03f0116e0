"""What each CasADi solve starts from: its parameters, and a plan shifted or a cold guess.

:class:`StepParameters` fills the NLP's parameter vector at a step (the measured state, goal,
reference, the detected points padded to ``max_detections`` with their mask, the active
terms' weights, the input in effect, the constraints' data). :class:`StartingPoints` turns
a plan (the previous solution, or the one just found when the real-time iteration prepares
the next sample) into the NLP's variable vector: its inputs re-blocked into the free moves,
its states, lifted inputs and slacks shifted; a plan that was a fallback or all zero input
gives the cold guess instead (``initial_input`` held over the horizon and its rollout), so
that the solver leaves the zero-input stationary point of a robot at rest facing sideways to
its goal. It also shifts the bound multipliers and says whether an iterate keeps its bounds.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from mpclab.constraints.base import Constraint
from mpclab.controllers.base import USABLE, ControlStep, FloatArray, SolveStatus, StepContext, shift
from mpclab.controllers.blocking import Blocking
from mpclab.controllers.casadi.ocp import OCP
from mpclab.controllers.constrained import pad_detections
from mpclab.plants.base import Plant


class StepParameters:
    """The parameter vector of a step for the NLP of some of the objective's terms.

    Parameters
    ----------
    plant
        The model (the detections are cut to the ones nearest its position).
    names
        The objective's terms, in order.
    max_detections
        The detected points the NLP has room for.
    constraints
        The objective's constraints (each fills its own parameters).
    """

    def __init__(self, plant: Plant, names: Sequence[str], max_detections: int,
                 constraints: Sequence[Constraint]) -> None:
        self.plant, self.names, self.max_detections = plant, list(names), max_detections
        self.constraints = list(constraints)

    def detections(self, x: FloatArray, det: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Detections ``(2, M)`` and their mask ``(M,)``."""
        return pad_detections(self.plant, x, det, self.max_detections)

    def vector(self, ocp: OCP, names: Sequence[str], x: FloatArray, ctx: StepContext,
               u_prev: FloatArray) -> FloatArray:
        """The parameters of ``ocp`` (the NLP of the terms ``names``) at state ``x``."""
        det, mask = self.detections(x, np.asarray(ctx.detections, dtype=float))
        act = np.ones(len(names))
        if ctx.active is not None:
            unknown = set(ctx.active) - set(self.names)
            if unknown:
                raise ValueError(
                    f"active terms {sorted(unknown)} are not in the objective; "
                    f"its terms: {', '.join(self.names)}"
                )
            act = np.array([1.0 if n in ctx.active else 0.0 for n in names])
        values = {
            "x0": x, "goal": np.asarray(ctx.goal, dtype=float),
            "target": np.asarray(ctx.target, dtype=float).T, "detections": det, "mask": mask,
            "active": act, "u_prev": u_prev,
        }
        for c in self.constraints:
            values |= c.values(x, det, mask)
        return ocp.params.pack(**values)


class StartingPoints:
    """Guesses and multiplier shifts on one OCP layout.

    Parameters
    ----------
    plant, ocp, blocking, dt
        The model, the NLP's layout, its moves and the sample time.
    u_guess
        The input a cold guess holds.
    warm_start
        Whether a previous plan is shifted at all.
    constraints, detections
        The objective's constraints and ``detections(x, ctx) -> (det, mask)``, with which a
        shifted plan is cut where it breaks one (:meth:`repaired`).
    """

    def __init__(self, plant: Plant, ocp: OCP, blocking: Blocking, dt: float,
                 u_guess: FloatArray, warm_start: bool, constraints: Sequence[Constraint],
                 detections: Callable[[FloatArray, StepContext], tuple[Any, Any]]) -> None:
        self.plant, self.ocp, self.blocking, self.dt = plant, ocp, blocking, dt
        self.u_guess, self.warm_start = u_guess, warm_start
        self.constraints, self.detections = list(constraints), detections

    def guess(self, x: FloatArray, prev: ControlStep | None, ctx: StepContext | None,
              u_before: FloatArray, w_prev: FloatArray | None) -> tuple[FloatArray, bool]:
        """The primal guess from ``x`` and whether it is ``prev`` shifted (a warm start), its
        inputs re-blocked into the free moves; ``u_before`` is the input before the first
        step, ``w_prev`` the last solution (its slacks shifted).

        A shifted plan that breaks a constraint at the current detections (a point seen
        only now, on the far side of which the plan runs) is cut at the first such step and
        holds still from the step before (zero input): a guess on the near side, from which
        the solver does not tunnel through the newly seen boundary.
        """
        warm = (self.warm_start and prev is not None and not prev.fallback
                and bool(np.any(np.abs(prev.u_pred) > 1e-6)))
        T = self.blocking.horizon
        if warm:
            X, U = shift(prev.x_pred), shift(prev.u_pred)
            X[0] = x
            if self.constraints and ctx is not None:
                X, U = self.repaired(x, X, U, ctx)
        else:  # cold, after a fallback or from the zero plan: off the stationary point
            U = np.tile(self.u_guess, (T, 1))
            X = self.plant.rollout(x, U, self.dt)
        V = self.blocking.reblock(U)  # the moves, and the inputs they hold
        U = self.blocking.expand(V)
        ocp = self.ocp
        w = np.zeros(ocp.lbw.size)
        w[ocp.u_idx] = V
        if ocp.x_idx is not None:
            w[ocp.x_idx] = X
        if ocp.s_idx is not None:  # the lifted input before each step
            w[ocp.s_idx] = np.vstack([u_before, U])
        if ocp.slack_idx is not None and warm and w_prev is not None:
            w[ocp.slack_idx] = shift(w_prev[ocp.slack_idx])
        return w, warm

    def repaired(self, x: FloatArray, X: FloatArray, U: FloatArray, ctx: StepContext,
                 ) -> tuple[FloatArray, FloatArray]:
        """``X, U`` held still from the step before the first that breaks a constraint."""
        det, mask = self.detections(x, ctx)
        ks = [c.first_violation(x, X, det, mask) for c in self.constraints]
        ks = [k for k in ks if k is not None]
        if not ks:
            return X, U
        k = min(ks)
        X, U = X.copy(), U.copy()
        U[k - 1:] = 0.0
        X[k:] = X[k - 1]
        return X, U

    def shift_lam_x(self, lam: FloatArray) -> FloatArray:
        """The bound multipliers of a solution, shifted by one step as its plan is."""
        ocp = self.ocp
        out = np.zeros_like(lam)
        out[ocp.u_idx] = self.blocking.shift(self.blocking.expand(lam[ocp.u_idx]))
        for idx in (ocp.x_idx, ocp.s_idx, ocp.slack_idx):
            if idx is not None:
                out[idx] = shift(lam[idx])
        return out

    def checked(self, w: FloatArray, status: SolveStatus, raw: str,
                ) -> tuple[FloatArray, SolveStatus, str]:
        """A usable iterate outside its bounds: a capped one clipped (``:clipped``), else
        failed (``:out_of_bounds``)."""
        if status not in USABLE or (np.all(np.isfinite(w)) and self.within_bounds(w)):
            return w, status, raw
        if status is SolveStatus.truncated and np.all(np.isfinite(w)):
            # a capped iterate need not keep its bounds yet (fatrop's interior point meets
            # them only at convergence, an SQP's state bounds after a few iterations):
            # usable once clipped, and it says so
            return np.clip(w, self.ocp.lbw, self.ocp.ubw), status, f"{raw}:clipped"
        # far outside, or "converged" outside: a step whose QP failed silently
        return w, SolveStatus.failed, f"{raw}:out_of_bounds"

    def within_bounds(self, w: FloatArray, tol: float = 1e-6) -> bool:
        """Whether ``w`` keeps its variable bounds up to ``tol`` relative to the bound (a QP
        solved to success always does)."""
        lo, hi = self.ocp.lbw, self.ocp.ubw
        with np.errstate(invalid="ignore"):  # inf - inf where a side is unbounded
            return bool(np.all(w >= lo - tol * (1.0 + np.abs(lo)))
                        and np.all(w <= hi + tol * (1.0 + np.abs(hi))))
