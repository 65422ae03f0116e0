"""The objective's constraints in the CVXPY backend's QP, linearized about a trajectory.

:class:`QPConstraints` writes every constraint's CVXPY rows once (``cvxpy_rows``) on the
QP's predicted states, with one slack variable ``s_k >= 0`` per stage for a soft constraint
and ``penalty * sum_k s_k`` in the cost, as the CasADi backend's NLP has them. What changes
per step (the detected points, their mask, the measured state) and per linearization (the
trajectory a non-convex constraint is linearized about) reaches the QP only as CVXPY
parameter values (:class:`CvxpyParams`): the problem stays DPP and is compiled once. The
detections enter already combined with the linearization (a distance's normal
``n_{k,i}`` and ``n_{k,i}' p_i + R_i``): a product of two parameters is not DPP.

It also judges a rollout in numbers (:meth:`QPConstraints.judge`): how far it breaks each
constraint at each stage, what successive linearization weighs a candidate by.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from mpclab.constraints.base import Constraint
from mpclab.controllers.base import FloatArray
from mpclab.controllers.constrained import SlackLog, pad_detections
from mpclab.core.lazy_import import lazy_import
from mpclab.plants.base import Plant

cp = lazy_import("cvxpy")  # about 0.6 s to import: paid only by runs that use it


def assign(param: cp.Parameter, value: Any) -> None:
    """Set a parameter's value without CVXPY's per-assignment validation (it projects the
    value onto the parameter's attributes, of which ours have none: about 0.1 ms each, a
    dozen times a step); the shape and finiteness are checked here."""
    value = np.array(value, dtype=float)
    if value.shape != param.shape or not np.all(np.isfinite(value)):
        raise ValueError(f"parameter {param.name()}: bad value of shape {value.shape}")
    param.save_value(value)


class CvxpyParams:
    """Named CVXPY parameters: ``add`` declares one (as the CasADi ``Params.add``),
    ``assign`` sets values by name."""

    def __init__(self) -> None:
        self.by_name: dict[str, cp.Parameter] = {}

    def add(self, name: str, rows: int, cols: int = 1) -> cp.Parameter:
        if name in self.by_name:
            raise ValueError(f"parameter {name!r} declared twice")
        shape = (rows,) if cols == 1 else (rows, cols)
        self.by_name[name] = p = cp.Parameter(shape, name=name)
        return p

    def assign(self, values: Mapping[str, Any]) -> None:
        for name, value in values.items():
            assign(self.by_name[name], value)


class QPConstraints:
    """The constraints of one CVXPY backend: rows, parameters, slacks and judgement.

    Parameters
    ----------
    plant
        The plant (its position labels place the detections).
    constraints
        The objective's constraints, bound to ``plant`` and accepted by ``cvxpy``.
    horizon
        Prediction steps ``T``.
    max_detections
        Detected points the QP has room for; more are cut to the nearest.
    """

    def __init__(self, plant: Plant, constraints: Sequence[Constraint], horizon: int,
                 max_detections: int) -> None:
        self.plant, self.constraints = plant, list(constraints)
        self.horizon, self.max_detections = horizon, max_detections
        self.params = CvxpyParams()
        M = max(max_detections, 1)
        self._par = [c.cvxpy_declare(self.params, M, horizon) for c in self.constraints]
        #: one slack variable (T,) per soft constraint, by position in ``constraints``
        self.slacks = {j: cp.Variable(horizon, nonneg=True, name=f"{c.name}_slack")
                       for j, c in enumerate(self.constraints) if c.soft}
        self.log = SlackLog()
        self._x0 = np.zeros(plant.nx)
        self._det, self._mask = pad_detections(plant, self._x0, np.zeros((0, 2)),
                                               max_detections)

    def __bool__(self) -> bool:
        return bool(self.constraints)

    def rows(self, X: Any, ctx: Any) -> tuple[list[Any], Any]:
        """The constraints on the QP's states ``X (nx, T+1)`` and the slacks' penalty."""
        rows: list[Any] = []
        for j, (c, par) in enumerate(zip(self.constraints, self._par, strict=True)):
            rows += c.cvxpy_rows(X, self.slacks.get(j), ctx, par)
        penalty = sum((self.constraints[j].penalty * cp.sum(s) for j, s in self.slacks.items()),
                      start=cp.Constant(0.0))
        return rows, penalty

    def at_step(self, x: FloatArray, detections: Any) -> None:
        """Keep this step's measured state and detections ``(n, 2)`` (padded)."""
        self._x0 = np.asarray(x, dtype=float)
        self._det, self._mask = pad_detections(self.plant, self._x0, detections,
                                                  self.max_detections)

    def linearize(self, X: FloatArray) -> None:
        """Set the parameters for a QP linearized about the trajectory ``X (T+1, nx)``."""
        for c in self.constraints:
            self.params.assign(c.cvxpy_values(self._x0, X, self._det, self._mask))

    def judge(self, X: FloatArray) -> list[tuple[float | None, FloatArray]]:
        """How far the plan ``X (T+1, nx)`` breaks each constraint at each stage [m]
        ``(T,)``, with the constraint's ``penalty`` when it is soft (else None)."""
        out = []
        for c in self.constraints:
            v = c.violation(self._x0, X, self._det, self._mask)
            if v is not None:
                out.append((c.penalty if c.soft else None, v))
        return out

    def record(self, X: FloatArray) -> None:
        """Log the largest distance a soft constraint gives up over the plan ``X``."""
        soft = [c.violation(self._x0, X, self._det, self._mask) for c in self.constraints
                if c.soft]
        soft = [v for v in soft if v is not None]
        if soft:
            self.log.add(max(float(v.max(initial=0.0)) for v in soft))

    def metrics(self) -> dict[str, Any]:
        """The constraints and their slacks, for the summary."""
        return self.log.metrics(self.constraints)
