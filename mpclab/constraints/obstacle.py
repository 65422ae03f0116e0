"""Keep the robot a margin away from the sensed obstacle points (and optionally its plan
inside the sensed region).

:class:`ObstacleDistance` keeps every predicted position ``p_{k+1}`` (``k = 0..T-1``) at least
``R`` from every detected point ``p_i``, ``R`` the margin: by default derived at build time
from the bounds the world states (the robot's radius, the rays' geometric error, the motion
between samples, noise, latency, model mismatch: :mod:`mpclab.world.margin`, each part in
``summary.json``'s ``margin``), or ``distance`` stated by hand. Its rows, scaled to metres
near the boundary::

    g_i(p) = (R_i^2 - |p - p_i|^2) / (2 R)          (<= 0: at least R_i away)

Modes (:class:`ObstacleMode`):

* ``hard``: ``g_i(p_{k+1}) <= 0`` with ``R_i = min(R, |p_0 - p_i|)``: a point already nearer
  than ``R`` may not be approached further, so that standing still stays feasible;
* ``soft``: ``g_i(p_{k+1}) <= s_k``, one slack ``s_k >= 0`` per stage, ``penalty * sum s_k``
  added to the cost, ``R_i = R``: an exact (L1) penalty, so the solve never becomes
  infeasible and equals the hard solution where that is feasible and ``penalty`` exceeds its
  multipliers;
* ``cbf``: a discrete-time control barrier function ``h(x_{k+1}) >= (1 - gamma) h(x_k)`` with
  ``h_i = -g_i`` and ``R_i`` as in ``hard``.

Padding points (mask 0) give rows that always hold. :class:`SensedRegion` bounds the plan to
the sensor's disc around the measured position, ``|p_{k+1} - p_0| <= range``.

On CVXPY (``cvxpy_rows``), where a constraint must be convex, the distance is linearized
about the trajectory the successive linearization linearizes the dynamics about: with
``pbar_k`` its position at step ``k`` and ``n_{k,i}`` the unit vector from ``p_i`` to
``pbar_k``, ::

    n_{k,i}' (p_k - p_i) >= R_i          (hard; soft: >= R - s_k, one slack s_k >= 0 a stage)

the tangent of ``|p - p_i| >= R_i`` at ``pbar_k``. As ``|p - p_i| >= n' (p - p_i)`` for every
unit ``n``, the halfspace lies outside the disc: a QP plan that keeps its linearized rows
keeps the distance at its predicted positions, however far ``pbar`` is from the plan (an
inner approximation), and where the plan is its own linearization trajectory (converged
successive linearization, whose plan is the rollout of the QP's inputs, judged by the true
distance to 1e-5 m) the rows are the constraint itself. The soft slack is in metres of
distance given up (CasADi's, ``g``, is that to first order at the boundary). ``cbf`` has no
such form: the barrier's decay side ``-(1 - gamma) h(x_k)`` is concave, its tangent is no
inner approximation, so ``cbf`` is CasADi's only (:meth:`ObstacleDistance.accepted_by`).
:class:`SensedRegion` is convex and written as it is (one second-order cone a stage).
"""

from __future__ import annotations

from enum import StrEnum
from typing import Any

import casadi as ca
import numpy as np

from mpclab.constraints.base import Constraint
from mpclab.core.errors import ConfigError, number, parse_choice
from mpclab.core.lazy_import import lazy_import

cp = lazy_import("cvxpy")  # about 0.6 s to import: paid only by runs that use it


class ObstacleMode(StrEnum):
    hard = "hard"
    soft = "soft"
    cbf = "cbf"


class NoRoom(StrEnum):
    """What a run does whose derived margin leaves no way from the start to the goal."""

    refuse = "refuse"  # a ConfigError with the margin's parts (nothing runs)
    run = "run"        # run anyway (to see what happens), with a warning


class _Positions(Constraint):
    def bind(self, plant: Any) -> None:
        self._ix, self._iy = (plant.state_index(s) for s in plant.position)

    def _d2(self, x: Any, pts: Any) -> Any:
        """Squared distances ``(M,)`` from the position of state ``x`` to ``pts (2, M)``."""
        return (x[self._ix] - pts[0, :].T) ** 2 + (x[self._iy] - pts[1, :].T) ** 2

    def _plan_positions(self, X: Any) -> tuple[np.ndarray, np.ndarray]:
        """The predicted positions ``x (T,), y (T,)`` of a plan ``X (T+1, nx)`` (numbers)."""
        X = np.asarray(X, dtype=float)
        return X[1:, self._ix], X[1:, self._iy]


class ObstacleDistance(_Positions):
    """Distance to the detected points: hard, soft (exact L1 penalty) or discrete-time CBF.

    Parameters
    ----------
    mode
        ``hard``, ``soft`` or ``cbf`` (module docstring).
    distance
        The distance kept [m]; None (the default): derived from the world's stated bounds
        when the run is built (:meth:`keep`).
    no_room
        ``refuse`` (default) or ``run``: what a run does whose derived margin leaves no way
        from the start to the goal.
    penalty
        ``soft``: weight of the slack (per metre of violation, per stage).
    gamma
        ``cbf``: the barrier's decay rate per step, ``0 < gamma <= 1``.
    """

    def __init__(
        self,
        mode: ObstacleMode | str = ObstacleMode.soft,
        distance: float | None = None,
        no_room: NoRoom | str = NoRoom.refuse,
        penalty: float = 1.0e6,
        gamma: float = 0.5,
    ) -> None:
        self.mode = parse_choice(ObstacleMode, mode, "mode")
        self.stated = distance is not None
        self._distance = None if distance is None else number(distance, "distance", above=0)
        #: the derived margin's parts (:meth:`keep`), None while stated or not yet derived
        self.budget: Any = None
        self.no_room = parse_choice(NoRoom, no_room, "no_room")
        self.penalty = number(penalty, "penalty", above=0)
        self.gamma = number(gamma, "gamma", above=0)
        if self.gamma > 1:
            raise ConfigError(f"gamma must be in (0, 1], got {gamma}")
        self.soft = self.mode is ObstacleMode.soft
        self.couples_stages = self.mode is ObstacleMode.cbf

    @property
    def distance(self) -> float:
        """``R`` [m]: stated, or derived when the run was built."""
        if self._distance is None:
            raise ConfigError(
                f"objective.constraints.{self.name}: the margin is derived when a run is built "
                "(mpclab.runner.single_run.build_run) and this one was not; state it with "
                f"objective.constraints.{self.name}.distance=<metres>")
        return self._distance

    @property
    def known_distance(self) -> float | None:
        """``R`` [m] if stated or derived yet, else None."""
        return self._distance

    def keep(self, budget: Any) -> None:
        """Keep the derived margin ``budget`` (a :class:`mpclab.world.margin.MarginBudget`)
        unless a distance was stated."""
        if not self.stated:
            self.budget, self._distance = budget, budget.total

    def declare(self, params: Any, n_points: int) -> dict[str, Any]:
        return {"radius": params.add(f"{self.name}_radius", n_points)}

    def radius(self, x0: Any, detections: Any, mask: Any) -> np.ndarray:
        """``R_i`` ``(M,)``: ``min(R, |p_0 - p_i|)`` (hard, cbf) or ``R`` (soft); 0 for padding."""
        m = np.asarray(mask, dtype=float)
        if self.soft:
            return self.distance * m
        d0 = np.hypot(detections[0] - x0[self._ix], detections[1] - x0[self._iy])
        return np.minimum(self.distance, d0) * m

    def values(self, x0: Any, detections: Any, mask: Any) -> dict[str, Any]:
        return {f"{self.name}_radius": self.radius(x0, detections, mask)}

    def accepted_by(self) -> list[str]:
        """Every backend of the class, less CVXPY in mode ``cbf`` (module docstring)."""
        return [b for b in self.backends()
                if not (b == "cvxpy" and self.mode is ObstacleMode.cbf)]

    def variant(self) -> str:
        return f"mode {self.mode.value}"

    def violation(self, x0: Any, X: Any, detections: Any, mask: Any) -> np.ndarray:
        """``max_i (R_i - |p_k - p_i|)`` over the detected points, 0 where all are kept."""
        R = self.radius(x0, detections, mask)
        px, py = self._plan_positions(X)
        d = np.hypot(px[:, None] - detections[0][None], py[:, None] - detections[1][None])
        short = np.where(np.asarray(mask)[None] > 0, R[None] - d, 0.0)    # (T, M)
        return np.maximum(short.max(axis=1, initial=0.0), 0.0)

    def cvxpy_declare(self, params: Any, n_points: int, horizon: int) -> dict[str, Any]:
        return {k: params.add(f"{self.name}_{k}", n_points, horizon)
                for k in ("normal_x", "normal_y", "offset")}

    def cvxpy_values(self, x0: Any, X: Any, detections: Any, mask: Any) -> dict[str, Any]:
        """``n_{k,i}`` ``(M, T)`` by components and ``offset = n_{k,i}' p_i + R_i``, 0 for
        padding; a linearization point on a detected point takes the direction from it to
        the measured position (or +x)."""
        m = np.asarray(mask, dtype=float)[:, None]
        px, py = self._plan_positions(X)
        ox, oy = (np.asarray(detections[j], dtype=float)[:, None] for j in (0, 1))
        dx, dy = px[None] - ox, py[None] - oy                               # (M, T)
        d = np.hypot(dx, dy)
        near = d < 1e-9
        if near.any():
            fx, fy = x0[self._ix] - ox, x0[self._iy] - oy
            fd = np.hypot(fx, fy)
            far = fd >= 1e-9
            fx, fy, fd = np.where(far, fx, 1.0), np.where(far, fy, 0.0), np.where(far, fd, 1.0)
            dx, dy = np.where(near, fx, dx), np.where(near, fy, dy)
            d = np.where(near, fd, d)
        nx, ny = dx / d * m, dy / d * m
        R = self.radius(x0, detections, mask)[:, None]
        return {f"{self.name}_normal_x": nx, f"{self.name}_normal_y": ny,
                f"{self.name}_offset": (nx * ox + ny * oy + R) * m}

    def cvxpy_rows(self, X: Any, slack: Any, ctx: Any, par: Any) -> list[Any]:
        M, T = par["offset"].shape
        ones = np.ones((M, 1))
        px = ones @ cp.reshape(X[self._ix, 1:], (1, T), order="F")          # (M, T)
        py = ones @ cp.reshape(X[self._iy, 1:], (1, T), order="F")
        lhs = cp.multiply(par["normal_x"], px) + cp.multiply(par["normal_y"], py)
        if slack is None:
            return [lhs >= par["offset"]]
        return [lhs >= par["offset"] - ones @ cp.reshape(slack, (1, T), order="F")]

    def g(self, x: Any, ctx: Any, radius: Any) -> Any:
        """``g_i`` ``(M,)`` at state ``x`` (<= 0 where ``x`` keeps its distance)."""
        return (radius**2 - self._d2(x, ctx.detections) * ctx.mask) / (2 * self.distance)

    def casadi_rows(self, x: Any, x_next: Any, slack: Any, ctx: Any, par: Any,
                    first: bool) -> Any:
        R = par["radius"]
        if self.mode is ObstacleMode.hard:
            return self.g(x_next, ctx, R)
        if self.mode is ObstacleMode.soft:
            return self.g(x_next, ctx, R) - slack
        return self.g(x_next, ctx, R) - (1 - self.gamma) * self.g(x, ctx, R)  # cbf

    def info(self) -> dict[str, Any]:
        out: dict[str, Any] = {"type": type(self).__name__, "mode": self.mode.value,
                               "distance_m": self.distance,
                               "margin": "stated" if self.stated else "derived"}
        if self.soft:
            out["penalty"] = self.penalty
        if self.mode is ObstacleMode.cbf:
            out["gamma"] = self.gamma
        return out


class SensedRegion(_Positions):
    """Keep every predicted position within ``max_range`` of the measured one (hard).

    Parameters
    ----------
    max_range
        The sensor's range [m]: the plan stays where the sensor has looked.
    """

    def __init__(self, max_range: float = 0.3) -> None:
        self.max_range = number(max_range, "max_range", above=0)

    def casadi_rows(self, x: Any, x_next: Any, slack: Any, ctx: Any, par: Any,
                    first: bool) -> Any:
        p0 = ca.vertcat(ctx.x0[self._ix], ctx.x0[self._iy])
        d2 = self._d2(x_next, p0)
        return (d2 - self.max_range**2) / (2 * self.max_range)

    def cvxpy_rows(self, X: Any, slack: Any, ctx: Any, par: Any) -> list[Any]:
        rel = cp.vstack([X[self._ix, 1:] - ctx.x0[self._ix], X[self._iy, 1:] - ctx.x0[self._iy]])
        return [cp.norm(rel, 2, axis=0) <= self.max_range]

    def violation(self, x0: Any, X: Any, detections: Any, mask: Any) -> np.ndarray:
        """How far beyond ``max_range`` from the measured position each predicted one is."""
        px, py = self._plan_positions(X)
        return np.maximum(np.hypot(px - x0[self._ix], py - x0[self._iy]) - self.max_range, 0.0)

    def info(self) -> dict[str, Any]:
        return {"type": type(self).__name__, "max_range_m": self.max_range}
