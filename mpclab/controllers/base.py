"""The controller interface every backend implements, and the shared failure fallback.

``step(t, x, ctx)`` returns a :class:`ControlStep` whose ``status`` is a :class:`SolveStatus`:
what the solver did (converged, truncated at a cap, infeasible, failed, raised), with the
solver's own return string and iteration count beside it. A backend implements ``_solve``;
the base class turns an exception, an unusable status or a non-finite result into the
fallback (the previous plan shifted by one step, or zero input when there is none or when
the solver's step was found unsafe on a plant that holds at rest) and records the status, so
a failed solve never ends a run.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
import numpy.typing as npt

from mpclab.controllers.blocking import Blocking
from mpclab.core.errors import ConfigError, number
from mpclab.core.signals import interrupted
from mpclab.core.status import USABLE, Problem, SolveStatus
from mpclab.plants.base import Plant

FloatArray = npt.NDArray[np.float64]


@dataclass
class StepContext:
    """What the controller may know at one step besides the state.

    Attributes
    ----------
    goal
        Goal state ``(nx,)`` (labels the scenario does not set are 0).
    target
        Reference over the horizon ``(T+1, nx)``: the goal repeated, or a preview.
    detections
        Detected obstacle points ``(n, 2)`` from the range sensor (empty without one).
    ranges
        The range sensor's reading per ray ``(n_rays,)``, ``inf`` where a ray sees nothing
        (empty without a sensor).
    active
        Names of the objective terms the supervisor has switched on (None: all).
    mode
        The supervisor's mode name (for logging).
    applied
        The input acting on the plant until this step's input does (None: not known).
    latency_s
        When this step's input is expected to act, after the measurement [s].
    predict
        Compute from the state predicted over ``latency_s`` (``sim.timing.delay_compensation``:
        :meth:`Controller.step` does it for every backend).
    """

    goal: FloatArray
    target: FloatArray
    detections: FloatArray = field(default_factory=lambda: np.zeros((0, 2)))
    ranges: FloatArray = field(default_factory=lambda: np.zeros(0))
    active: frozenset[str] | None = None
    mode: str = ""
    applied: FloatArray | None = None
    latency_s: float = 0.0
    predict: bool = False


#: ``ControlStep.info``'s key of the part of a call from its start to the input [s], for a
#: controller that works on after its input is known (the real-time iteration prepares its
#: next solve): the loop's ``measured`` latency is that part, not the whole call
FEEDBACK_KEY = "feedback_s"


@dataclass
class ControlStep:
    """One controller call's result.

    ``x_pred (T+1, nx)`` and ``u_pred (T, nu)`` are the predicted horizon; ``u`` is applied.
    ``status`` says what the solver did; ``solver_status`` is the solver's own return string
    (``"Solve_Succeeded"``, ``"Maximum_Iterations_Exceeded"``, Clarabel's ``"Solved"``, ...)
    and ``iterations`` its iteration count (None where it has none).
    """

    u: FloatArray
    x_pred: FloatArray
    u_pred: FloatArray
    status: SolveStatus
    cost: float = float("nan")
    fallback: bool = False
    solver_status: str = ""
    iterations: int | None = None
    info: dict[str, Any] = field(default_factory=dict)
    #: the solver's step broke a safety check (the real-time iteration's): the fallback
    #: stops a plant that holds at rest instead of following the previous plan
    unsafe: bool = False

    @property
    def ok(self) -> bool:
        """Whether the result is usable (converged or truncated)."""
        return self.status in USABLE

    @property
    def finite(self) -> bool:
        """Whether the input and the plan are finite numbers (what is applied now, what a
        fallback would apply later and the predicted states the next solve starts from)."""
        # a NaN or inf anywhere makes the sum non-finite: cheaper than isfinite().all() for a
        # controller that steps in microseconds
        return (all(map(math.isfinite, self.u.tolist())) and math.isfinite(self.u_pred.sum())
                and math.isfinite(self.x_pred.sum()))


class Controller(ABC):
    """Base class of all backends.

    Subclasses build their problem once in ``__init__`` and implement :meth:`_solve`.
    """

    #: registered backend name (set by the registry decorator)
    registered_name: str = ""
    #: keys of ``ControlStep.info`` the runner writes as extra columns of steps.parquet
    log_columns: tuple[str, ...] = ()

    #: the shortest horizon the backend accepts (0 for controllers that predict nothing)
    min_horizon: int = 1
    #: a filter of the applied input (:mod:`mpclab.controllers.safety_filter`), or None
    safety_filter: Any = None
    #: the blocks of the plan's moves (:mod:`mpclab.controllers.blocking`), recorded in the
    #: summary; None for a backend without a control horizon
    blocking: Blocking | None = None

    def __init__(self, plant: Plant, horizon: int, dt: float) -> None:
        if int(horizon) < self.min_horizon:
            raise ConfigError(f"controller.horizon must be >= {self.min_horizon}, got {horizon}")
        self.plant = plant
        self.horizon = int(horizon)
        self.dt = number(dt, "controller.dt", above=0)
        self._plan: ControlStep | None = None
        self._received: FloatArray | None = None

    def reset(self, x0: npt.ArrayLike) -> None:
        """Forget the previous plan before a new run from ``x0``."""
        self._plan, self._received = None, None

    def received(self, u: npt.ArrayLike) -> None:
        """Tell the controller the input the plant received after its last call (on a
        missed deadline not its own): :attr:`previous_input` from then on."""
        self._received = np.asarray(u, dtype=float).copy()

    def step(self, t: float, x: npt.ArrayLike, ctx: StepContext) -> ControlStep:
        """Solve at time ``t`` from state ``x``; never raises for a failed solve.

        When the loop asks for it (``ctx.predict``: ``sim.timing.delay_compensation``) and an
        expected latency ``ctx.latency_s``, it solves from the state the plant's own step
        predicts at ``t + latency_s`` under the input in effect (``ctx.applied``), with the
        reference shifted by the same time: the input is computed for when it acts.
        """
        x = np.asarray(x, dtype=float)
        if ctx.predict and ctx.latency_s > 0 and ctx.applied is not None:
            x = self.plant.step(x, ctx.applied, ctx.latency_s)
            ctx = replace(ctx, target=shift_by(ctx.target, ctx.latency_s / self.dt))
            t = t + ctx.latency_s
        try:
            res = self._solve(t, x, ctx)
        except Exception as exc:  # a solver crash must not end a sweep: record and fall back
            stop = interrupted(exc)  # Ctrl-C inside native code, handed back as another error
            if stop is not None:
                raise stop from exc
            res = self._failed(SolveStatus.exception, x, type(exc).__name__, str(exc))
        if not isinstance(res.status, SolveStatus):  # a backend's word outside the vocabulary
            res = _known_status(res) or self._failed(
                SolveStatus.failed, x, f"unknown_status({res.status!r})",
                f"the backend returned status {res.status!r}, not one of "
                f"{', '.join(SolveStatus)}", res.iterations)
        if res.ok and not res.finite:  # a "success" with NaN or inf in it is a failure
            res = self._failed(SolveStatus.failed, x, f"non_finite({res.solver_status})",
                               "the solver returned non-finite values", res.iterations)
        res = res if res.ok else self._fallback(x, res)
        if self.safety_filter is not None:  # the backstop on what is applied
            sf = self.safety_filter
            u, code = sf.filter(x, res.u, ctx.detections)
            short = sf.shortfall(x, u, ctx.detections) if code else 0.0  # 0: checked exactly
            res = replace(res, u=u, info={**res.info, "safety_filter": code,
                                          "safety_filter_shortfall": short})
            self._plan = res if res.ok else replace(res)
        elif res.ok:
            self._plan = res
        return res

    #: what a ``converged`` call solved (each backend says; None: not said)
    solved_problem: Problem | None = None

    def metrics(self, steps: Any) -> dict[str, Any]:
        """Backend-specific figures for ``summary.json`` computed from the step log."""
        return {}

    def board_time_model(self) -> Callable[[ControlStep], float] | None:
        """The time a call takes on the board the backend models, as a function of its
        result [s] (``sim.latency=modelled``); None: the backend models none."""
        return None

    @abstractmethod
    def _solve(self, t: float, x: FloatArray, ctx: StepContext) -> ControlStep:
        """Solve the problem at ``x``; return the result with the solver's status."""

    def _failed(
        self, status: SolveStatus, x: FloatArray, solver_status: str = "", message: str = "",
        iterations: int | None = None,
    ) -> ControlStep:
        """A failed solve's result; :meth:`step` replaces it with the fallback."""
        T, nu = self.horizon, self.plant.nu
        return ControlStep(
            u=np.zeros(nu), x_pred=np.tile(x, (T + 1, 1)), u_pred=np.zeros((T, nu)),
            status=SolveStatus(status), solver_status=solver_status, iterations=iterations,
            info={"error": message} if message else {},
        )

    @property
    def previous_plan(self) -> ControlStep | None:
        """The last plan applied (optimal or fallback), for warm starts."""
        return self._plan

    @property
    def previous_input(self) -> FloatArray:
        """The input the plant received after the last step (:meth:`received`; else the
        last step's own; zero, clipped to the bounds, before the first), for input-rate
        terms and warm starts."""
        if self._received is not None:
            return self._received
        if self._plan is None:
            return self.plant.clip_input(np.zeros(self.plant.nu))
        return np.asarray(self._plan.u, dtype=float)

    def _fallback(self, x: FloatArray, failed: ControlStep) -> ControlStep:
        prev = self._plan
        zero = self.plant.clip_input(np.zeros(self.plant.nu))
        stop = failed.unsafe and self.plant.holds_at_rest
        if prev is None or self.horizon == 0 or stop:
            u_pred, u = np.tile(zero, (self.horizon, 1)), zero
        else:
            u_pred = shift(prev.u_pred)
            u = u_pred[0].copy()
        x_pred = self.plant.rollout(x, u_pred, self.dt)
        res = replace(failed, u=u, x_pred=x_pred, u_pred=u_pred, fallback=True)
        self._plan = replace(res)
        return res


def _known_status(res: ControlStep) -> ControlStep | None:
    """``res`` with its status as a :class:`SolveStatus` where it is one's value (a plain
    ``"converged"``), else None."""
    try:
        return replace(res, status=SolveStatus(res.status))
    except ValueError:
        return None


def input_vector(plant: Plant, values: Mapping[str, float] | None, key: str) -> FloatArray:
    """``{input label: value}`` as an input vector (others 0), clipped to the input bounds."""
    u = np.zeros(plant.nu)
    for label, value in dict(values or {}).items():
        try:
            u[plant.input_index(label)] = float(value)
        except ValueError as exc:
            raise ConfigError(f"{key}: {exc}") from None
    return plant.clip_input(u)


def terminal_rows(plant: Plant, terminal: Any) -> list[tuple[int, float]]:
    """``controller.terminal_constraint`` (``{state label: value}``) as (state index, value)."""
    rows = []
    for label, value in dict(terminal or {}).items():
        try:
            rows.append((plant.state_index(label), float(value)))
        except ValueError as exc:
            raise ConfigError(f"controller.terminal_constraint: {exc}") from None
    return rows


def shift(a: FloatArray) -> FloatArray:
    """Drop the first row of a trajectory and repeat the last one."""
    return np.concatenate([a[1:], a[-1:]], axis=0)


def shift_by(a: FloatArray, steps: float) -> FloatArray:
    """A trajectory sampled ``steps`` (a fraction of) rows later: linear between rows, the
    last row held beyond the end."""
    rows = np.arange(len(a)) + steps
    grid = np.arange(len(a))
    return np.stack([np.interp(rows, grid, a[:, i]) for i in range(a.shape[1])], axis=1)
