"""The controller interface every backend implements, and the shared failure fallback.

``step(t, x, ctx)`` returns a :class:`ControlStep`. A backend implements ``_solve``; the
base class turns an exception or a non-optimal status into the fallback (the previous plan
shifted by one step, or zero input when there is none) and records the status, so a failed
solve never ends a run.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
import numpy.typing as npt

from mpclab.plants.base import Plant

FloatArray = npt.NDArray[np.float64]

#: statuses that count as a successful solve; anything else triggers the fallback
OK_STATUSES = frozenset({"optimal"})


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
    """

    goal: FloatArray
    target: FloatArray
    detections: FloatArray = field(default_factory=lambda: np.zeros((0, 2)))
    ranges: FloatArray = field(default_factory=lambda: np.zeros(0))
    active: frozenset[str] | None = None
    mode: str = ""


@dataclass
class ControlStep:
    """One controller call's result.

    ``x_pred (T+1, nx)`` and ``u_pred (T, nu)`` are the predicted horizon; ``u`` is applied.
    """

    u: FloatArray
    x_pred: FloatArray
    u_pred: FloatArray
    status: str
    cost: float = float("nan")
    fallback: bool = False
    info: dict[str, Any] = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        return self.status in OK_STATUSES


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

    def __init__(self, plant: Plant, horizon: int, dt: float) -> None:
        if int(horizon) < self.min_horizon:
            raise ValueError(f"horizon must be >= {self.min_horizon}, got {horizon}")
        if float(dt) <= 0:
            raise ValueError(f"dt must be > 0, got {dt}")
        self.plant = plant
        self.horizon = int(horizon)
        self.dt = float(dt)
        self._plan: ControlStep | None = None

    def reset(self, x0: npt.ArrayLike) -> None:
        """Forget the previous plan before a new run from ``x0``."""
        self._plan = None

    def step(self, t: float, x: npt.ArrayLike, ctx: StepContext) -> ControlStep:
        """Solve at time ``t`` from state ``x``; never raises for a failed solve."""
        x = np.asarray(x, dtype=float)
        try:
            res = self._solve(t, x, ctx)
        except Exception as exc:  # a solver crash must not end a sweep: record and fall back
            res = self._failed(f"exception:{type(exc).__name__}", x, str(exc))
        if res.ok:
            self._plan = res
            return res
        return self._fallback(x, res.status, res.info)

    def metrics(self, steps: Any) -> dict[str, Any]:
        """Backend-specific figures for ``summary.json`` computed from the step log."""
        return {}

    @abstractmethod
    def _solve(self, t: float, x: FloatArray, ctx: StepContext) -> ControlStep:
        """Solve the problem at ``x``; return the result with the solver's status."""

    def _failed(self, status: str, x: FloatArray, message: str = "") -> ControlStep:
        """A failed solve's result; :meth:`step` replaces it with the fallback."""
        T, nu = self.horizon, self.plant.nu
        return ControlStep(
            u=np.zeros(nu), x_pred=np.tile(x, (T + 1, 1)), u_pred=np.zeros((T, nu)),
            status=status, info={"error": message} if message else {},
        )

    @property
    def previous_plan(self) -> ControlStep | None:
        """The last plan applied (optimal or fallback), for warm starts."""
        return self._plan

    def _fallback(self, x: FloatArray, status: str, info: dict[str, Any]) -> ControlStep:
        prev = self._plan
        zero = self.plant.clip_input(np.zeros(self.plant.nu))
        if prev is None or self.horizon == 0:
            u_pred, u = np.tile(zero, (self.horizon, 1)), zero
        else:
            u_pred = shift(prev.u_pred)
            u = u_pred[0].copy()
        x_pred = self.plant.rollout(x, u_pred, self.dt)
        res = ControlStep(
            u=u, x_pred=x_pred, u_pred=u_pred, status=status,
            fallback=True, info=info,
        )
        self._plan = replace(res)
        return res


def terminal_rows(plant: Plant, terminal: Any) -> list[tuple[int, float]]:
    """``controller.terminal_constraint`` (``{state label: value}``) as (state index, value)."""
    from mpclab.errors import ConfigError

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
