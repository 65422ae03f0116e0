"""The CasADi backend's option groups: how its solver runs (``controller.solve``) and how its
NLPs are built (``controller.build``); :class:`~mpclab.controllers.casadi.mpc.CasadiMPC`
takes one of each."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from mpclab.controllers.casadi.compile import DEFAULT_FLAGS
from mpclab.controllers.casadi.ocp import Shooting
from mpclab.controllers.casadi.rti import RtiHessian
from mpclab.controllers.casadi.solvers import CasadiQpSolver


@dataclass(frozen=True)
class CasadiSolve:
    """How the chosen solver runs each step (``controller.solve``).

    Parameters
    ----------
    max_iter
        Iteration limit of ``fatrop``, ``ipopt`` and ``sqp`` (a solve stopped here is
        ``truncated``).
    tol
        Tolerance of ``fatrop``, ``ipopt`` and ``sqp``; also the KKT tolerance of
        ``sqp_rti``'s ``converged``.
    time_cap_ms
        Wall-clock cap of one solve [ms] (null: none) for ``ipopt``, ``sqp`` and
        ``sqp_capped``: the solve stops with its last iterate, ``truncated`` (it may overrun
        by one iteration).
    warm_start
        Start from the previous solution (primal and multipliers) shifted by one step.
    qp_solver
        QP solver of ``sqp``, ``sqp_rti`` and ``sqp_capped``: ``qpoases`` (dense), ``osqp``,
        ``qrqp``, ``hpipm`` (multiple shooting only), ``daqp``, ``piqp``, ``proxqp``.
    sqp_iterations
        SQP steps per sample of ``sqp_capped`` (fewer if converged first); ``sqp_rti``
        takes one.
    hessian
        The Hessian of ``sqp_rti``'s QP: ``gauss_newton`` (the cost's alone: exact for the
        least-squares terms under multiple shooting, no constraint curvature) or ``exact``
        (the Lagrangian's at the last multipliers), each clipped to be convex (:mod:`.rti`).
        ``conf/controller/casadi_rti.yaml`` sets ``exact``: without the curvature of the
        obstacle constraint the steps swing between the input bounds near an obstacle.
    options
        Extra options for ``nlpsol``, nested or dotted: ``{"fatrop": {"max_soc": 0}}`` is
        ``{"fatrop.max_soc": 0}`` (nested, each can be set from the command line:
        ``controller.solve.options.fatrop.max_soc=2``).
    """

    max_iter: int = 100
    tol: float = 1e-6
    time_cap_ms: float | None = None
    warm_start: bool = True
    qp_solver: CasadiQpSolver | str = CasadiQpSolver.qpoases
    sqp_iterations: int = 1
    hessian: RtiHessian | str = RtiHessian.gauss_newton
    options: Mapping[str, Any] | None = None


@dataclass(frozen=True)
class CasadiBuild:
    """How the NLPs are built, once, before the run (``controller.build``).

    Parameters
    ----------
    shooting
        ``multiple`` (states and inputs are variables, in stage order, the dynamics equality
        constraints; fatrop needs it) or ``single`` (inputs only, the states their rollout).
    jit
        Compile the NLP's functions to C (cached on disk; uncompiled with a warning if no
        C compiler is found).
    jit_flags
        The C compiler's flags for ``jit`` and ``codegen`` (``-O1``: see
        experiments/zumo/SOLVERS.md).
    active_sets
        Sets of term names a supervisor switches between (e.g. BUG2's): each gets an NLP
        of its terms only (cheaper per iteration than the NLP of all terms with the others
        weighted 0, which serves any other set).
    """

    shooting: Shooting | str = Shooting.multiple
    jit: bool = False
    jit_flags: Sequence[str] = DEFAULT_FLAGS
    active_sets: Sequence[Sequence[str]] = ()
