"""The plant: one CasADi definition of ``x' = f(x, u; params)``, everything else derived.

A concrete plant names its states and inputs, declares a parameter dataclass and writes
``rhs`` once with CasADi operations. From that single definition this class derives

* ``step``: the RK4 discrete step ``F(x, u, dt)`` (compiled once into a CasADi ``Function``),
* ``jacobians``: ``dF/dx`` and ``dF/du`` by algorithmic differentiation,
* ``linearize``: the affine LTV model ``x+ = A x + B u + c`` with
  ``c = F(xbar, ubar) - A xbar - B ubar``,

and the same functions are what the simulator integrates and what every backend predicts with.
"""

from __future__ import annotations

import copy
import dataclasses
import sys
from collections.abc import Mapping, Sequence
from typing import Any, ClassVar

import casadi as ca
import numpy as np
import numpy.typing as npt

from mpclab.core.errors import check_keys, number

FloatArray = npt.NDArray[np.float64]


class Plant:
    """Base class of every plant.

    Subclasses set ``states``, ``inputs``, ``Params`` and implement :meth:`rhs`.

    Parameters
    ----------
    params
        Physical parameters: an instance of ``Params`` or a mapping of its fields.
    state_bounds, input_bounds
        ``{label: [lower, upper]}``; labels not given are unbounded.
    substeps
        RK4 sub-intervals per call of :meth:`step` (the integrator's accuracy, not the
        controller's sample time).
    """

    states: ClassVar[tuple[str, ...]]
    inputs: ClassVar[tuple[str, ...]]
    Params: ClassVar[type]
    #: labels of the planar position, for figures, sensors and recordings
    position: ClassVar[tuple[str, str]] = ("px", "py")
    #: label of the heading angle, or None
    heading: ClassVar[str | None] = "theta"
    #: states drawn over time in the per-run figure (inputs are always drawn)
    plot_states: ClassVar[tuple[str, ...]] = ()
    #: the unit of each state and input label, for figures (``{"v": "m/s"}``)
    units: ClassVar[Mapping[str, str]] = {}
    #: zero input holds the state where it is (a kinematic plant whose inputs are speeds):
    #: the input a controller falls back to when its own step was found unsafe
    holds_at_rest: ClassVar[bool] = False

    def __init__(
        self,
        params: Any = None,
        state_bounds: Mapping[str, Sequence[float]] | None = None,
        input_bounds: Mapping[str, Sequence[float]] | None = None,
        substeps: int = 1,
    ) -> None:
        self.params = self._make_params(params)
        if int(substeps) < 1:
            raise ValueError(f"substeps must be >= 1, got {substeps}")
        self.substeps = int(substeps)
        self.x_lb, self.x_ub = self._bounds(state_bounds, self.states, "state_bounds")
        self.u_lb, self.u_ub = self._bounds(input_bounds, self.inputs, "input_bounds")
        self._build()

    # ------------------------------------------------------------------ definition
    def rhs(self, x: ca.SX, u: ca.SX) -> ca.SX:
        """Continuous-time dynamics ``x' = f(x, u)``; CasADi expressions in, out."""
        raise NotImplementedError

    @property
    def nx(self) -> int:
        return len(self.states)

    @property
    def nu(self) -> int:
        return len(self.inputs)

    def state_index(self, label: str) -> int:
        return _index(label, self.states, "state")

    def input_index(self, label: str) -> int:
        return _index(label, self.inputs, "input")

    def axis_label(self, label: str) -> str:
        """``label [unit]`` for an axis (the label alone when the plant names no unit)."""
        unit = self.units.get(label)
        return f"{label} [{unit}]" if unit else label

    # ------------------------------------------------------------------ derived
    def _build(self) -> None:
        x = ca.SX.sym("x", self.nx)
        u = ca.SX.sym("u", self.nu)
        dt = ca.SX.sym("dt")
        self.f = ca.Function("f", [x, u], [self.rhs(x, u)], ["x", "u"], ["xdot"])
        xn = x
        h = dt / self.substeps
        for _ in range(self.substeps):
            xn = rk4(self.f, xn, u, h)
        #: discrete step F(x, u, dt) -> x+
        self.F = ca.Function("F", [x, u, dt], [xn], ["x", "u", "dt"], ["xn"])
        A = ca.jacobian(xn, x)
        B = ca.jacobian(xn, u)
        c = xn - ca.mtimes(A, x) - ca.mtimes(B, u)
        #: Jacobians of the discrete step
        self.F_jac = ca.Function("F_jac", [x, u, dt], [A, B], ["x", "u", "dt"], ["A", "B"])
        #: affine LTV model: x+ = A x + B u + c, exact at the linearization point
        self.F_lin = ca.Function(
            "F_lin", [x, u, dt], [A, B, c], ["x", "u", "dt"], ["A", "B", "c"]
        )
        self._maps: dict[int, ca.Function] = {}

    def step(self, x: npt.ArrayLike, u: npt.ArrayLike, dt: float) -> FloatArray:
        """One RK4 step of length ``dt`` from ``x`` with ``u`` held."""
        return np.asarray(self.F(x, u, dt), dtype=float).reshape(self.nx)

    def jacobians(
        self, x: npt.ArrayLike, u: npt.ArrayLike, dt: float
    ) -> tuple[FloatArray, FloatArray]:
        """``(dF/dx, dF/du)`` of the discrete step, shapes ``(nx, nx)`` and ``(nx, nu)``."""
        A, B = self.F_jac(x, u, dt)
        return np.asarray(A, dtype=float), np.asarray(B, dtype=float)

    def linearize(
        self, x: npt.ArrayLike, u: npt.ArrayLike, dt: float
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """``(A, B, c)`` with ``F(x, u) == A x + B u + c`` at the linearization point."""
        A, B, c = self.F_lin(x, u, dt)
        return (
            np.asarray(A, dtype=float),
            np.asarray(B, dtype=float),
            np.asarray(c, dtype=float).reshape(self.nx),
        )

    def linearize_trajectory(
        self, X: npt.ArrayLike, U: npt.ArrayLike, dt: float
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Linearize along a trajectory in one call.

        Parameters
        ----------
        X, U
            Linearization points, shapes ``(T, nx)`` and ``(T, nu)``.

        Returns
        -------
        A, B, c
            Shapes ``(T, nx, nx)``, ``(T, nx, nu)``, ``(T, nx)``.
        """
        X = np.asarray(X, dtype=float)
        U = np.asarray(U, dtype=float)
        T = X.shape[0]
        if T not in self._maps:
            self._maps[T] = self.F_lin.map(T)
        A, B, c = self._maps[T](X.T, U.T, dt)
        nx, nu = self.nx, self.nu
        A = np.asarray(A, dtype=float).reshape(nx, T, nx).transpose(1, 0, 2)
        B = np.asarray(B, dtype=float).reshape(nx, T, nu).transpose(1, 0, 2)
        return A, B, np.asarray(c, dtype=float).T

    def rollout(self, x0: npt.ArrayLike, U: npt.ArrayLike, dt: float) -> FloatArray:
        """States ``(T+1, nx)`` reached from ``x0`` under the inputs ``U`` ``(T, nu)``."""
        U = np.asarray(U, dtype=float)
        X = np.empty((U.shape[0] + 1, self.nx))
        X[0] = np.asarray(x0, dtype=float)
        for k, uk in enumerate(U):
            X[k + 1] = self.step(X[k], uk, dt)
        return X

    def variant(self, params: Mapping[str, Any], substeps: int = 1, where: str = "params") -> Plant:
        """This plant with other ``params`` (by name) and ``substeps`` times as many RK4
        sub-intervals: the same ``rhs`` (a simulated plant that differs from the model).
        ``self`` when nothing changes."""
        if not params and substeps == 1:
            return self
        check_keys(params, [f.name for f in dataclasses.fields(self.Params)], where=where)
        other = copy.copy(self)
        other.params = dataclasses.replace(self.params, **{k: float(v) for k, v in params.items()})
        other.substeps = self.substeps * int(substeps)
        other._build()
        return other

    def clip_input(self, u: npt.ArrayLike) -> FloatArray:
        return np.clip(np.asarray(u, dtype=float), self.u_lb, self.u_ub)

    # ------------------------------------------------------------------ helpers
    @classmethod
    def _make_params(cls, params: Any) -> Any:
        if params is None:
            return cls.Params()
        if isinstance(params, cls.Params):
            return params
        if not isinstance(params, Mapping):
            raise TypeError(
                f"{cls.__name__} params must be a mapping or {cls.Params.__name__}, "
                f"got {type(params).__name__}"
            )
        valid = [f.name for f in dataclasses.fields(cls.Params)]
        check_keys(params, valid, where=f"plant {cls.__name__} params")
        # a physical parameter is a finite number >= 0; one whose default is > 0 (a length, a
        # mass, a stiffness) must stay > 0, one that may vanish (a drag) defaults to 0
        defaults = cls.Params()
        return cls.Params(**{
            k: number(v, f"params.{k}", **({"above": 0} if getattr(defaults, k) > 0
                                          else {"at_least": 0}))
            for k, v in params.items()
        })

    @staticmethod
    def _bounds(
        given: Mapping[str, Sequence[float]] | None, labels: tuple[str, ...], what: str
    ) -> tuple[FloatArray, FloatArray]:
        lb = np.full(len(labels), -np.inf)
        ub = np.full(len(labels), np.inf)
        given = given or {}
        check_keys(given, labels, where=what)
        for label, pair in given.items():
            if pair is None:
                continue
            if len(pair) != 2:
                raise ValueError(f"{what}.{label} must be [lower, upper], got {list(pair)}")
            lo, hi = (float(v) for v in pair)
            if lo != lo or hi != hi:  # NaN: no bound at all, silently
                raise ValueError(f"{what}.{label}: a bound is NaN, got {list(pair)}")
            if lo > hi:
                raise ValueError(f"{what}.{label}: lower bound {lo} exceeds upper bound {hi}")
            i = labels.index(label)
            lb[i], ub[i] = lo, hi
        return lb, ub


def rk4(f: ca.Function, x: ca.SX, u: ca.SX, h: ca.SX) -> ca.SX:
    """One classical Runge-Kutta step of ``x' = f(x, u)`` with ``u`` held."""
    k1 = f(x, u)
    k2 = f(x + h / 2 * k1, u)
    k3 = f(x + h / 2 * k2, u)
    k4 = f(x + h * k3, u)
    return x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)


def _index(label: str, labels: tuple[str, ...], what: str) -> int:
    try:
        return labels.index(label)
    except ValueError:
        raise ValueError(
            f"unknown {what} label {label!r}; valid {what}s: {', '.join(labels)}"
        ) from None


def register_plant(name: str) -> Any:
    """Class decorator: derive the plant's config schema from its ``Params`` and register it.

    The schema has ``params`` (typed by the plant's own ``Params`` dataclass, so a typo'd
    parameter fails at compose time), ``state_bounds``, ``input_bounds`` and ``substeps``.
    """
    from mpclab.config.registry import component, target

    def deco(cls: type[Plant]) -> type[Plant]:
        schema = dataclasses.make_dataclass(
            f"{cls.__name__}Conf",
            [
                ("_target_", str, dataclasses.field(default=target(cls))),
                ("params", cls.Params, dataclasses.field(default_factory=cls.Params)),
                ("state_bounds", dict[str, list[float]], dataclasses.field(default_factory=dict)),
                ("input_bounds", dict[str, list[float]], dataclasses.field(default_factory=dict)),
                ("substeps", int, dataclasses.field(default=1)),
            ],
        )
        # importable by name, so that configs holding it pickle (sweep workers copy them)
        schema.__module__ = cls.__module__
        setattr(sys.modules[cls.__module__], schema.__name__, schema)
        return component("plant", name, schema)(cls)

    return deco
