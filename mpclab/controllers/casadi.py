"""CasADi backend: nonlinear MPC over the plant's RK4 step, solved to convergence or RTI.

The NLP (:mod:`mpclab.controllers.casadi_ocp`) is built once, with every per-step quantity
a named parameter: the measured state, the goal, the target over the horizon, up to
``max_detections`` detected points with a mask, the applied input and one activity weight
per objective term (so a supervisor switches objective sets without a rebuild). Solvers:

* ``fatrop``: interior point exploiting the stage structure of multiple shooting; solved
  to convergence;
* ``ipopt``: general interior point, solved to convergence;
* ``sqp``: CasADi's ``sqpmethod`` iterated to convergence (``max_iter`` SQP steps at most),
  one QP per step with ``qp_solver``, the Hessian of the Lagrangian made convex;
* ``sqp_rti``: real-time iteration, ``sqp_iterations`` SQP steps per sample from the shifted
  previous solution: ``truncated`` by design unless it converges within them.

``jit`` compiles the NLP's functions to C, cached on disk
(:mod:`mpclab.controllers.casadi_compile`). Warm starts shift the previous solution by one
step; a cold start, a previous plan that was all zero input or a fallback start from
``initial_input`` instead, so that the solver leaves the zero-input stationary point of a
robot at rest facing sideways to its goal.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import casadi as ca
import numpy as np

from mpclab.controllers.base import (
    USABLE,
    Controller,
    ControlStep,
    FloatArray,
    SolveStatus,
    StepContext,
    input_vector,
    parse_choice,
    shift,
    terminal_rows,
)
from mpclab.controllers.casadi_codegen import GeneratedSolver
from mpclab.controllers.casadi_compile import DEFAULT_FLAGS, compiled_nlp
from mpclab.controllers.casadi_ocp import OCP, Shooting, build_ocp
from mpclab.controllers.casadi_solvers import (
    CasadiSolver,
    QpSolver,
    bind_buffers,
    nlpsol_options,
    read_status,
)
from mpclab.errors import ConfigError
from mpclab.objectives.base import Objective
from mpclab.plants.base import Plant
from mpclab.quiet import c_stdout_silenced
from mpclab.registry import component

__all__ = ["CasadiMPC", "CasadiSolver", "QpSolver", "Shooting", "read_status"]



@dataclass
class _NLP:
    """One NLP of the controller: its terms, problem, solver and the solver's arrays."""

    names: list[str]
    ocp: OCP
    fn: ca.Function
    buffer: Any
    trigger: Any
    io: dict[str, FloatArray]
    compiled: bool
    #: the solver as generated C (``codegen``), which also says how its solves went
    generated: GeneratedSolver | None = None


@dataclass
class CasadiConf:
    _target_: str = "mpclab.controllers.casadi.CasadiMPC"
    horizon: int = 10
    dt: float = 0.1
    solver: CasadiSolver = CasadiSolver.ipopt
    qp_solver: QpSolver = QpSolver.qpoases
    sqp_iterations: int = 1
    shooting: Shooting = Shooting.multiple
    jit: bool = False
    jit_flags: list[str] = field(default_factory=lambda: list(DEFAULT_FLAGS))
    collision_distance: float = 0.0
    max_iter: int = 100
    tol: float = 1e-6
    warm_start: bool = True
    max_detections: int = 20
    initial_input: dict[str, float] = field(default_factory=dict)
    terminal_constraint: dict[str, float] = field(default_factory=dict)
    solver_options: dict[str, Any] = field(default_factory=dict)
    active_sets: list[list[str]] = field(default_factory=list)
    codegen: bool = False


@component("controller", "casadi", CasadiConf)
class CasadiMPC(Controller):
    """Nonlinear MPC with CasADi (fatrop, IPOPT, SQP to convergence, or SQP-RTI).

    Parameters
    ----------
    plant, objective
        Injected; every objective term must support CasADi.
    horizon, dt
        Prediction steps and sample time [s].
    solver
        ``fatrop``, ``ipopt``, ``sqp`` (solved to convergence) or ``sqp_rti``
        (``sqp_iterations`` QPs per step); module docstring.
    qp_solver
        QP solver of ``sqp`` and ``sqp_rti``: ``qpoases`` (dense), ``osqp``, ``qrqp``,
        ``hpipm`` (multiple shooting only), ``daqp``, ``piqp``, ``proxqp``.
    sqp_iterations
        SQP steps per sample of ``sqp_rti`` (fewer if converged first).
    shooting
        ``multiple`` (states and inputs are variables, in stage order, the dynamics equality
        constraints; fatrop needs it) or ``single`` (inputs only, the states their rollout).
    jit
        Compile the NLP's functions to C (cached on disk; uncompiled with a warning if no
        C compiler is found).
    jit_flags
        The C compiler's flags for ``jit`` (``-O1``: see experiments/zumo/SOLVERS.md).
    collision_distance
        ``R`` [m] of the hard collision constraint on detected points; 0 turns it off.
    max_iter, tol
        Iteration limit and tolerance of ``fatrop``, ``ipopt`` and ``sqp`` (not ``sqp_rti``).
    warm_start
        Start from the previous solution (primal and multipliers) shifted by one step.
    max_detections
        Detected points the NLP has room for; more are cut to the nearest ones.
    initial_input
        ``{input label: value}`` held over the horizon as the guess of a cold start, after
        a fallback or when the previous plan was all zero (others 0). A non-zero guess moves
        the solve off the stationary point of a robot at rest facing sideways to its goal.
    terminal_constraint
        ``{state label: value}`` imposed on the last predicted state.
    solver_options
        Extra options for ``nlpsol`` (e.g. ``{"ipopt.linear_solver": "ma27"}``).
    active_sets
        Sets of term names a supervisor switches between (e.g. BUG2's): each gets an NLP
        of its terms only (cheaper per iteration than the NLP of all terms with the others
        weighted 0, which serves any other set).
    codegen
        Run the whole solver as C generated by CasADi (``solver=sqp`` or ``fatrop``;
        compiled with ``jit_flags``, cached): :mod:`mpclab.controllers.casadi_codegen`.
    """

    def __init__(
        self,
        plant: Plant,
        objective: Objective,
        horizon: int = 10,
        dt: float = 0.1,
        solver: CasadiSolver | str = CasadiSolver.ipopt,
        qp_solver: QpSolver | str = QpSolver.qpoases,
        sqp_iterations: int = 1,
        shooting: Shooting | str = Shooting.multiple,
        jit: bool = False,
        jit_flags: Sequence[str] = DEFAULT_FLAGS,
        collision_distance: float = 0.0,
        max_iter: int = 100,
        tol: float = 1e-6,
        warm_start: bool = True,
        max_detections: int = 20,
        initial_input: Mapping[str, float] | None = None,
        terminal_constraint: Mapping[str, float] | None = None,
        solver_options: Mapping[str, Any] | None = None,
        active_sets: Sequence[Sequence[str]] = (),
        codegen: bool = False,
    ) -> None:
        super().__init__(plant, horizon, dt)
        self.solver = parse_choice(CasadiSolver, solver, "controller.solver")
        self.qp_solver = parse_choice(QpSolver, qp_solver, "controller.qp_solver")
        self.shooting = parse_choice(Shooting, shooting, "controller.shooting")
        if int(max_iter) < 1:
            raise ConfigError(f"controller.max_iter must be >= 1, got {max_iter}")
        if int(sqp_iterations) < 1:
            raise ConfigError(f"controller.sqp_iterations must be >= 1, got {sqp_iterations}")
        if not float(collision_distance) >= 0:
            raise ConfigError(
                f"controller.collision_distance must be >= 0 (0: off), got {collision_distance}"
            )
        if int(max_detections) < 0:
            raise ConfigError(f"controller.max_detections must be >= 0, got {max_detections}")
        if self.solver is CasadiSolver.fatrop and self.shooting is not Shooting.multiple:
            raise ConfigError("controller.solver=fatrop needs controller.shooting=multiple "
                              f"(got {self.shooting.value}): it exploits the stage structure")
        if (self.solver in (CasadiSolver.sqp, CasadiSolver.sqp_rti)
                and self.qp_solver is QpSolver.hpipm and self.shooting is Shooting.single):
            raise ConfigError("controller.qp_solver=hpipm needs controller.shooting=multiple "
                              "(on the single-shooting QP it crashes the process)")
        self.codegen = bool(codegen)
        if self.codegen and self.solver not in (CasadiSolver.sqp, CasadiSolver.fatrop):
            raise ConfigError(f"controller.codegen=true needs controller.solver=sqp or fatrop "
                              f"(got {self.solver.value}): the solvers whose generated C "
                              "mpclab compiles and reads a status from")
        self.sqp_iterations = int(sqp_iterations)
        self.jit = bool(jit)
        self.jit_flags = tuple(str(f) for f in jit_flags)
        self.collision_distance = float(collision_distance)
        self.max_iter, self.tol = int(max_iter), float(tol)
        self.warm_start = bool(warm_start)
        self.max_detections = int(max_detections)
        self._u_guess = input_vector(plant, initial_input, "controller.initial_input")
        self.objective = objective
        objective.bind(plant, "casadi")
        self._names = list(objective.terms)
        self._M = max(self.max_detections, 1)
        terminal = terminal_rows(plant, dict(terminal_constraint or {}))
        extra = dict(solver_options or {})
        sets = {}
        for names in active_sets:
            unknown = set(names) - set(self._names)
            if unknown:
                raise ConfigError(f"controller.active_sets: terms {sorted(unknown)} are not in "
                                  f"the objective; its terms: {', '.join(self._names)}")
            sets[frozenset(names)] = [n for n in self._names if n in names]
        self._full = self._make_nlp(self._names, terminal, extra)
        self._by_set = {key: self._make_nlp(names, terminal, extra)
                        for key, names in sets.items()}
        self.ocp: OCP = self._full.ocp  # the layout (variables, bounds) all NLPs share
        self.compiled = all(n.compiled for n in (self._full, *self._by_set.values()))
        self._nlp = self._full  # the one the current step solves
        self._lam_x: FloatArray | None = None
        self._lam_g: FloatArray | None = None

    # ------------------------------------------------------------------ build once
    def _make_nlp(self, names: list[str], terminal: Any, extra: dict[str, Any]) -> _NLP:
        """The OCP of the terms ``names``, its solver (compiled if ``jit``) and buffers."""
        ocp = build_ocp(self.plant, self.objective, names, self.horizon, self.dt,
                        self.shooting, self.max_detections, self.collision_distance, terminal)
        name, opts = nlpsol_options(
            self.solver, self.qp_solver, max_iter=self.max_iter, tol=self.tol,
            sqp_iterations=self.sqp_iterations, warm_start=self.warm_start,
            equality=ocp.equality,
        )
        opts.update(extra)
        with c_stdout_silenced():  # qpOASES prints its banner whenever one is built
            fn = ca.nlpsol("mpc", name, ocp.nlp, opts)
            gen = GeneratedSolver(fn, ocp, self.jit_flags, self.tol) if self.codegen else None
            lib = compiled_nlp(fn, self.jit_flags) if self.jit and gen is None else None
            if lib is not None:
                fn = ca.nlpsol("mpc", name, str(lib), opts)
            buffer, trigger, io = bind_buffers(gen.fn if gen else fn, {
                "lbx": ocp.lbw, "ubx": ocp.ubw, "lbg": ocp.lbg, "ubg": ocp.ubg})
        return _NLP(names, ocp, fn, buffer, trigger, io, lib is not None or gen is not None,
                    gen)

    # ------------------------------------------------------------------ per step
    def reset(self, x0: Any) -> None:
        super().reset(x0)
        self._lam_x = self._lam_g = None

    def _params(self, x: FloatArray, ctx: StepContext, nlp: _NLP | None = None) -> FloatArray:
        nlp = nlp or self._full
        det, mask = self._pad_detections(x, np.asarray(ctx.detections, dtype=float))
        act = np.ones(len(nlp.names))
        if ctx.active is not None:
            unknown = set(ctx.active) - set(self._names)
            if unknown:
                raise ValueError(
                    f"active terms {sorted(unknown)} are not in the objective; "
                    f"its terms: {', '.join(self._names)}"
                )
            act = np.array([1.0 if n in ctx.active else 0.0 for n in nlp.names])
        values = {
            "x0": x, "goal": np.asarray(ctx.goal, dtype=float),
            "target": np.asarray(ctx.target, dtype=float).T, "detections": det, "mask": mask,
            "active": act, "u_prev": self.previous_input,
        }
        if self.collision_distance > 0:  # R_i = min(R, |p_0 - p_i|), 0 for padding
            ix, iy = (self.plant.state_index(s) for s in self.plant.position)
            d0 = np.hypot(det[0] - x[ix], det[1] - x[iy])
            values["radius"] = np.minimum(self.collision_distance, d0) * mask
        return nlp.ocp.params.pack(**values)

    def _pad_detections(self, x: FloatArray, det: FloatArray) -> tuple[FloatArray, FloatArray]:
        M = self._M
        ix, iy = (self.plant.state_index(s) for s in self.plant.position)
        pos = np.array([x[ix], x[iy]])
        det = det.reshape(-1, 2)
        if len(det) > self.max_detections:  # keep the nearest
            order = np.argsort(np.linalg.norm(det - pos, axis=1))
            det = det[order[: self.max_detections]]
        out = np.tile(pos + 1e3, (M, 1))  # padding far away, masked out anyway
        out[: len(det)] = det
        mask = np.zeros(M)
        mask[: len(det)] = 1.0
        return out.T, mask

    def _initial_guess(self, x: FloatArray) -> tuple[FloatArray, bool]:
        """The primal guess and whether it is the previous solution shifted (a warm start)."""
        prev = self.previous_plan
        warm = (self.warm_start and prev is not None and not prev.fallback
                and bool(np.any(np.abs(prev.u_pred) > 1e-6)))
        if warm:
            X, U = shift(prev.x_pred), shift(prev.u_pred)
            X[0] = x
        else:  # cold, after a fallback or from the zero plan: off the stationary point
            U = np.tile(self._u_guess, (self.horizon, 1))
            X = self.plant.rollout(x, U, self.dt)
        w = np.zeros(self.ocp.lbw.size)
        w[self.ocp.u_idx] = U
        if self.ocp.x_idx is not None:
            w[self.ocp.x_idx] = X
        if self.ocp.s_idx is not None:  # the lifted input before each step
            w[self.ocp.s_idx] = np.vstack([self.previous_input, U])
        return w, warm

    def _solve(self, t: float, x: FloatArray, ctx: StepContext) -> ControlStep:
        key = frozenset(ctx.active) if ctx.active is not None else None
        self._nlp = nlp = self._by_set.get(key, self._full)
        io = nlp.io
        io["x0"][:], warm = self._initial_guess(x)
        io["p"][:] = self._params(x, ctx, nlp)
        if warm and self._lam_g is not None:
            io["lam_x0"][:], io["lam_g0"][:] = self._lam_x, self._lam_g
        else:
            io["lam_x0"][:] = io["lam_g0"][:] = 0.0
        self.call_solver()
        status, raw, iters = (nlp.generated.status(io) if nlp.generated
                              else read_status(nlp.buffer))
        w = io["x"].copy()
        if status in USABLE and not (
            np.all(np.isfinite(w)) and self._within_bounds(w)
        ):
            if status is SolveStatus.truncated and np.all(np.isfinite(w)):
                # a capped iterate need not keep its bounds yet (fatrop's interior point meets
                # them only at convergence, an SQP's state bounds after a few iterations):
                # usable once clipped, and it says so
                w = np.clip(w, self.ocp.lbw, self.ocp.ubw)
                raw = f"{raw}:clipped"
            else:  # far outside, or "converged" outside: a step whose QP failed silently
                status, raw = SolveStatus.failed, f"{raw}:out_of_bounds"
        if status not in USABLE:
            self._lam_x = self._lam_g = None
            return self._failed(status, x, raw, iterations=iters)
        ocp = self.ocp
        self._lam_x = self._shift_lam_x(io["lam_x"])
        self._lam_g = io["lam_g"].copy()
        U = w[ocp.u_idx]
        X = w[ocp.x_idx] if ocp.x_idx is not None else nlp.ocp.plan_fn(w, io["p"]).full().T
        return ControlStep(
            u=U[0].copy(), x_pred=X, u_pred=U, status=status, cost=float(io["f"][0]),
            solver_status=raw, iterations=iters,
        )

    def call_solver(self) -> None:
        """One call of the current NLP's solver on its arrays (in place, no conversions); wrap
        it to time the solver alone."""
        self._nlp.trigger()

    def _within_bounds(self, w: FloatArray, tol: float = 1e-6) -> bool:
        """Whether ``w`` keeps its variable bounds up to ``tol`` relative to the bound (a QP
        solved to success always does)."""
        lo, hi = self.ocp.lbw, self.ocp.ubw
        with np.errstate(invalid="ignore"):  # inf - inf where a side is unbounded
            return bool(np.all(w >= lo - tol * (1.0 + np.abs(lo)))
                        and np.all(w <= hi + tol * (1.0 + np.abs(hi))))

    def _shift_lam_x(self, lam: FloatArray) -> FloatArray:
        out = np.zeros_like(lam)
        out[self.ocp.u_idx] = shift(lam[self.ocp.u_idx])
        for idx in (self.ocp.x_idx, self.ocp.s_idx):
            if idx is not None:
                out[idx] = shift(lam[idx])
        return out

    def metrics(self, steps: Any) -> dict[str, Any]:
        return {"solver": self.solver.value, "jit": self.compiled, "codegen": self.codegen,
                "nlps": 1 + len(self._by_set), "collision_distance": self.collision_distance}

