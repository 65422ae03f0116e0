"""The dynamic window approach (Fox, Burgard, Thrun, "The Dynamic Window Approach to Collision
Avoidance", IEEE RAM 1997), the classic local planner, as a backend on mpclab's harness.

Each step searches a grid of inputs inside the *dynamic window*: the inputs the plant can
reach within one sample from the input it received (``max_rate`` per second; the whole input
box without one), within its bounds. Every candidate is held over the ``horizon`` and rolled
out with the plant's own RK4 step (all candidates at once, a CasADi map), ``substeps`` steps
per sample. A candidate whose trajectory, at any of those steps, comes closer than ``margin``
to a sensed point (the same detected points the MPC sees) is inadmissible: checked at the
samples alone, a trajectory could cut a corner between them. Among the admissible ones the
step takes the one of the highest weighted score: progress to the reference (the distance of
the trajectory's end to the last point of the reference over the horizon: the goal, or a
supervisor's target), clearance (the trajectory's least, capped at ``clearance_cap``) and
speed (the end's displacement along the robot's heading), each scaled to [0, 1] over the
admissible candidates.

There is no optimization to converge: the search over the finite grid is exhaustive and exact
(``Problem.sampled``). A step with no admissible candidate is ``infeasible`` and takes the
base class's fallback.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from mpclab.config.registry import component
from mpclab.controllers.base import Controller, ControlStep, FloatArray, SolveStatus, StepContext
from mpclab.core.errors import ConfigError, number, whole_number
from mpclab.core.options import group
from mpclab.core.status import Problem
from mpclab.plants.base import Plant


@dataclass(frozen=True)
class DwaWeights:
    """The score's weights (``controller.weights``), each term scaled to [0, 1] first;
    chosen on BARN's training worlds (experiments/barn/README.md, "The peer").

    Parameters
    ----------
    goal
        Progress: the trajectory's end nearer the reference's last point.
    clearance
        The trajectory's least distance to the sensed points (capped at ``clearance_cap``).
    speed
        The end's displacement along the robot's heading.
    """

    goal: float = 1.0
    clearance: float = 0.3
    speed: float = 0.5


@component("controller", "dwa", injected=("plant",))
class DwaController(Controller):
    """The dynamic window approach (module docstring).

    Parameters
    ----------
    plant
        Injected; needs ``position`` and ``heading`` labels and finite input bounds.
    dt
        Sample time [s].
    horizon
        For how many samples each candidate input is held and rolled out.
    samples
        Grid points per input over the dynamic window (``samples ** nu`` candidates).
    substeps
        Rollout steps per sample, at each of which the clearance is checked (a robot at
        0.2 m/s moves 1 cm in a quarter of a 0.2 s sample).
    max_rate
        The largest change of an input per second (the plant's acceleration limit, in its
        input's units per second); None: any input of the bounds is reachable.
    robot_radius
        The robot's disc [m].
    margin
        A candidate whose trajectory comes closer than this to a sensed point, surface to
        surface, is inadmissible [m]: the NMPC's 1.5 cm beyond its robot radius, plus the
        5 mm of position noise and the 5 mm of range noise that ``sim=realistic`` states.
    clearance_cap
        Clearance beyond this scores no more [m].
    weights
        :class:`DwaWeights`: ``goal``, ``clearance``, ``speed``.
    """

    solved_problem = Problem.sampled

    def __init__(
        self,
        plant: Plant,
        dt: float = 0.2,
        horizon: int = 5,
        samples: int = 11,
        substeps: int = 4,
        max_rate: float | None = None,
        robot_radius: float = 0.05,
        margin: float = 0.025,
        clearance_cap: float = 0.1,
        weights: DwaWeights | Mapping[str, Any] = DwaWeights(),
    ) -> None:
        super().__init__(plant, whole_number(horizon, "controller.horizon", at_least=1), dt)
        if plant.heading is None:
            raise ConfigError("controller=dwa needs a plant with a heading")
        if not (np.isfinite(plant.u_lb).all() and np.isfinite(plant.u_ub).all()):
            raise ConfigError("controller=dwa needs finite input bounds (plant.input_bounds): "
                              "its window is a grid over them")
        self.samples = whole_number(samples, "controller.samples", at_least=2)
        self.substeps = whole_number(substeps, "controller.substeps", at_least=1)
        self.max_rate = None if max_rate is None else number(max_rate, "controller.max_rate",
                                                             above=0)
        self.robot_radius = number(robot_radius, "controller.robot_radius", at_least=0)
        self.margin = number(margin, "controller.margin", at_least=0)
        self.clearance_cap = number(clearance_cap, "controller.clearance_cap", above=0)
        w = group(DwaWeights, weights, "controller.weights")
        self.weights = np.array([number(v, f"controller.weights.{k}", at_least=0)
                                 for k, v in (("goal", w.goal), ("clearance", w.clearance),
                                              ("speed", w.speed))])
        self._ip = [plant.state_index(s) for s in plant.position]
        self._ih = plant.state_index(plant.heading)
        n = self.samples ** plant.nu
        self._rollout = plant.F.map(n)  # every candidate's step at once
        self._unit = np.stack(np.meshgrid(*[np.linspace(0.0, 1.0, self.samples)] * plant.nu,
                                          indexing="ij"), axis=-1).reshape(n, plant.nu)

    def _window(self) -> tuple[FloatArray, FloatArray]:
        """The inputs reachable within one sample from the one the plant received."""
        lo, hi = self.plant.u_lb.copy(), self.plant.u_ub.copy()
        if self.max_rate is not None:
            u = self.previous_input
            lo = np.maximum(lo, u - self.max_rate * self.dt)
            hi = np.minimum(hi, u + self.max_rate * self.dt)
        return lo, hi

    def _solve(self, t: float, x: FloatArray, ctx: StepContext) -> ControlStep:
        lo, hi = self._window()
        U = lo + self._unit * (hi - lo)  # (n, nu)
        n, T, m = len(U), self.horizon, self.substeps
        traj = np.empty((T * m + 1, n, self.plant.nx))  # every substep
        traj[0] = x
        X, Ut, h = np.tile(x, (n, 1)).T, U.T, self.dt / m
        for k in range(T * m):
            X = np.asarray(self._rollout(X, Ut, h))
            traj[k + 1] = X.T
        pos = traj[:, :, self._ip]  # (T m + 1, n, 2)
        points = np.asarray(ctx.detections, dtype=float).reshape(-1, 2)
        if len(points):
            gap = np.min(np.linalg.norm(pos[:, :, None, :] - points[None, None], axis=3),
                         axis=(0, 2)) - self.robot_radius
        else:
            gap = np.full(n, np.inf)
        admissible = gap > self.margin
        if not admissible.any():
            return self._failed(SolveStatus.infeasible, x, "no_admissible_input",
                                f"every one of {n} candidates comes within "
                                f"{self.margin:g} m of a sensed point", iterations=n)
        target = np.asarray(ctx.target, dtype=float)[-1, self._ip]
        heading = float(x[self._ih])
        ahead = np.array([math.cos(heading), math.sin(heading)])
        terms = np.stack([-np.linalg.norm(pos[-1] - target, axis=1),
                          np.minimum(gap, self.clearance_cap),
                          (pos[-1] - pos[0]) @ ahead], axis=1)[admissible]
        span = terms.max(axis=0) - terms.min(axis=0)
        scaled = (terms - terms.min(axis=0)) / np.where(span > 0, span, 1.0)
        score = scaled @ self.weights
        best = int(np.flatnonzero(admissible)[int(np.argmax(score))])
        u = U[best].copy()
        return ControlStep(u=u, x_pred=traj[::m, best, :].copy(), u_pred=np.tile(u, (T, 1)),
                           status=SolveStatus.converged, cost=-float(score.max()),
                           solver_status="searched", iterations=n,
                           info={"admissible": int(admissible.sum())})

