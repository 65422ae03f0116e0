"""CasADi's NLP solvers as the backend's choices: their options and what their stats mean.

``read_status`` maps any ``nlpsol``'s stats (or a solver buffer's) to :class:`SolveStatus`;
``nlpsol_options`` gives the plugin and its options for ``controller.solver`` (and
``controller.solve.qp_solver`` under SQP, :func:`qp_options`; the real-time iteration,
``sqp_rti``, solves its QPs itself: :mod:`mpclab.controllers.casadi.rti`).
"""

from __future__ import annotations

from collections.abc import Mapping
from enum import StrEnum
from typing import Any

import casadi as ca
import numpy as np

from mpclab.controllers.base import SolveStatus
from mpclab.controllers.casadi.ocp import Shooting
from mpclab.core.errors import ConfigError, number


class CasadiSolver(StrEnum):
    ipopt = "ipopt"
    fatrop = "fatrop"
    sqp = "sqp"
    #: the real-time iteration: one QP per sample, prepared before the measurement
    sqp_rti = "sqp_rti"
    #: sqpmethod stopped after ``sqp_iterations`` SQP steps, all after the measurement
    sqp_capped = "sqp_capped"


#: the solvers whose solve ``controller.solve.time_cap_ms`` can stop at a wall-clock deadline
#: (IPOPT's ``max_wall_time``; sqpmethod through an iteration callback)
TIME_CAPPED = ("ipopt", "sqp", "sqp_capped")


class CasadiQpSolver(StrEnum):
    qpoases = "qpoases"
    osqp = "osqp"
    qrqp = "qrqp"
    hpipm = "hpipm"
    daqp = "daqp"
    piqp = "piqp"
    proxqp = "proxqp"


#: solvers' own return strings that mean a stop short of the full tolerance with a usable
#: iterate (an iteration or time cap, IPOPT's reduced "acceptable" tolerance). Not
#: sqpmethod's "Search_Direction_Becomes_Too_Small": a stalled line search, whose iterate was
#: measured violating the car's terminal constraint by 5 m/s (failed, then)
_TRUNCATED = frozenset({
    "Solved_To_Acceptable_Level", "Maximum_Iterations_Exceeded", "Maximum_CpuTime_Exceeded",
    "Maximum_WallTime_Exceeded",
})
#: the return string of a solver call that returned an error code (see :func:`read_status`)
CALL_FAILED = "call_failed"
#: fatrop's numeric return codes (its ``return_status``) for a cap: 1 is MaxIterExceeded
_FATROP_TRUNCATED = frozenset({"1"})
#: CasADi's unified return status -> ours (``SOLVER_RET_SUCCESS`` is refined by _TRUNCATED)
_UNIFIED = {
    "SOLVER_RET_SUCCESS": SolveStatus.converged,
    "SOLVER_RET_LIMITED": SolveStatus.truncated,
    "SOLVER_RET_INFEASIBLE": SolveStatus.infeasible,
    "SOLVER_RET_NAN": SolveStatus.failed,
    "SOLVER_RET_EXCEPTION": SolveStatus.exception,
}


def read_status(fn: ca.Function) -> tuple[SolveStatus, str, int | None]:
    """What an ``nlpsol`` did in its last call: ``(status, return string, iterations)``.

    ``stats()`` raises for some plugins when they stop without a status string (sqpmethod
    after a failed QP); that is a failed solve, not a crash. A buffer's call that returned
    an error code is failed too (:data:`CALL_FAILED`): sqpmethod returns one when an
    evaluation (a NaN in the Hessian) or the Hessian's convexification fails, without
    writing a status, so that ``return_status`` still holds the previous call's (an
    iteration cap, a stop on time) and would otherwise pass for it. IPOPT's "acceptable"
    level and an iteration cap count as truncated; fatrop's ``return_status`` is a number: 0
    with its ``success`` flag is converged, 1 its iteration cap (truncated), others failed.
    """
    try:
        stats = fn.stats()
    except RuntimeError:
        return SolveStatus.failed, "no_status", None
    raw = str(stats.get("return_status", ""))
    iters = stats.get("iter_count")
    iters = int(iters) if iters is not None else None
    returned = getattr(fn, "ret", None)  # a buffer's: the call's own return code
    if returned is not None and returned() != 0:
        return SolveStatus.failed, f"{CALL_FAILED} (return_status, maybe stale: {raw})", iters
    if raw in _TRUNCATED or raw in _FATROP_TRUNCATED:
        return SolveStatus.truncated, raw, iters
    if stats.get("success"):
        return SolveStatus.converged, raw or "success", iters
    unified = str(stats.get("unified_return_status", ""))
    status = _UNIFIED.get(unified, SolveStatus.failed)
    if status is SolveStatus.converged:  # success is False: the flag and the code disagree
        status = SolveStatus.failed
    return status, raw or unified or "unknown", iters


def checked_choices(
    solver: CasadiSolver, qp_solver: CasadiQpSolver, shooting: Shooting, sqp_iterations: int,
    jit: bool, codegen: bool, time_cap_ms: Any,
) -> float | None:
    """The combinations of ``controller.*`` choices that cannot work, refused (a
    :class:`ConfigError` naming the key, the value and what is valid); the time cap [ms]
    as a number (None: none)."""
    if solver is CasadiSolver.fatrop and shooting is not Shooting.multiple:
        raise ConfigError("controller.solver=fatrop needs controller.build.shooting=multiple "
                          f"(got {shooting.value}): it exploits the stage structure")
    if (solver not in (CasadiSolver.ipopt, CasadiSolver.fatrop)
            and qp_solver is CasadiQpSolver.hpipm and shooting is Shooting.single):
        raise ConfigError("controller.solve.qp_solver=hpipm needs "
                          "controller.build.shooting=multiple (on the single-shooting QP it "
                          "crashes the process)")
    rti = solver is CasadiSolver.sqp_rti
    if rti and int(sqp_iterations) != 1:
        raise ConfigError(
            f"controller.solve.sqp_iterations={sqp_iterations} applies to "
            "controller.solver=sqp_capped (sqpmethod stopped after that many SQP steps); "
            "solver=sqp_rti takes one QP per sample: for the capped SQP use "
            f"controller=casadi_sqp_capped controller.solve.sqp_iterations={sqp_iterations}")
    if rti and jit:
        raise ConfigError("controller.build.jit=true is not available with controller.solver="
                          "sqp_rti (its linearization and QP run uncompiled); valid: "
                          "jit=false, or a solver that compiles: ipopt, fatrop, sqp, "
                          "sqp_capped")
    if codegen and solver not in (CasadiSolver.sqp, CasadiSolver.fatrop):
        raise ConfigError(f"controller.codegen=true needs controller.solver=sqp or fatrop "
                          f"(got {solver.value}): the solvers whose generated C "
                          "mpclab compiles and reads a status from")
    if time_cap_ms is None:
        return None
    cap = number(time_cap_ms, "controller.solve.time_cap_ms", above=0)
    if solver.value not in TIME_CAPPED or codegen:
        why = ("generated C cannot stop at a deadline" if codegen else {
            "fatrop": "fatrop has no time limit (cap its iterations: controller.solve.max_iter)",
            "sqp_rti": "it solves one QP per sample",
        }[solver.value])
        raise ConfigError(
            f"controller.solve.time_cap_ms={time_cap_ms} needs controller.solver one of "
            f"{', '.join(TIME_CAPPED)}, without controller.codegen (got "
            f"solver={solver.value}{', codegen=true' if codegen else ''}: {why})")
    return cap


def nlpsol_options(
    solver: CasadiSolver, qp_solver: CasadiQpSolver, *, max_iter: int, tol: float,
    sqp_iterations: int, warm_start: bool, equality: list[bool],
    time_cap_s: float | None = None,
) -> tuple[str, dict[str, Any]]:
    """The ``nlpsol`` plugin name and options of a solver choice (quiet, status-robust);
    ``time_cap_s`` is IPOPT's ``max_wall_time`` (sqpmethod's cap is an iteration callback,
    :mod:`mpclab.controllers.casadi.time_cap`, added by the caller)."""
    opts: dict[str, Any] = {"print_time": False}
    if solver is CasadiSolver.ipopt:
        opts |= {"ipopt.print_level": 0, "ipopt.sb": "yes",
                 "ipopt.max_iter": max_iter, "ipopt.tol": tol}
        if warm_start:
            opts["ipopt.warm_start_init_point"] = "yes"
        if time_cap_s is not None:
            opts["ipopt.max_wall_time"] = time_cap_s
        name = "ipopt"
    elif solver is CasadiSolver.fatrop:
        opts |= {"structure_detection": "auto", "equality": equality,
                 "fatrop.print_level": 0, "fatrop.max_iter": max_iter,
                 "fatrop.tol": tol}
        name = "fatrop"
    else:
        capped = solver is CasadiSolver.sqp_capped
        opts |= {
            "print_header": False, "print_iteration": False, "print_status": False,
            "max_iter": sqp_iterations if capped else max_iter,
            "tol_pr": tol, "tol_du": tol,
            "qpsol": qp_solver.value, "qpsol_options": qp_options(qp_solver),
            "convexify_strategy": "eigen-clip",
            "max_iter_eig": 500,  # the default 50 left dense Hessians undecomposed
            "error_on_fail": False,
        }
        name = "sqpmethod"
    return name, opts


def qp_options(qp_solver: CasadiQpSolver) -> dict[str, Any]:
    """A QP solver's options for ``conic`` (or sqpmethod's ``qpsol_options``): quiet, and a
    failed QP a status, not an exception."""
    return {
        CasadiQpSolver.qpoases: {"printLevel": "none"},
        CasadiQpSolver.osqp: {"osqp": {"verbose": False}},
        CasadiQpSolver.qrqp: {"print_iter": False, "print_header": False,
                              "print_info": False},
        CasadiQpSolver.piqp: {"piqp": {"verbose": False}},
        CasadiQpSolver.proxqp: {"proxqp": {"verbose": False}},
    }.get(qp_solver, {}) | {"error_on_fail": False}


def bind_buffers(
    fn: ca.Function, fixed: dict[str, np.ndarray]
) -> tuple[Any, Any, dict[str, np.ndarray]]:
    """``(buffer, trigger, arrays)``: NumPy arrays the solver reads its inputs from and
    writes its outputs into, by name; ``fixed`` inputs get their values once.

    CasADi's buffer interface: converting the eight inputs and six outputs of a call to and
    from ``DM`` costs more than a car's solve (experiments/zumo/SOLVERS.md). ``trigger()``
    solves; ``buffer.stats()`` says how.
    """
    buffer, trigger = fn.buffer()
    io: dict[str, np.ndarray] = {}
    for i, name in enumerate(fn.name_in()):
        a = np.array(fixed[name], dtype=float) if name in fixed else np.zeros(fn.nnz_in(i))
        io[name] = a
        buffer.set_arg(i, memoryview(a))
    for i, name in enumerate(fn.name_out()):
        io[name] = a = np.zeros(fn.nnz_out(i))
        buffer.set_res(i, memoryview(a))
    return buffer, trigger, io


def dotted(options: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """``nlpsol`` options with nested dicts written as CasADi's dotted names
    (``{"fatrop": {"max_soc": 0}}`` -> ``{"fatrop.max_soc": 0}``)."""
    flat: dict[str, Any] = {}
    for key, value in options.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping):
            flat.update(dotted(value, name + "."))
        else:
            flat[name] = value
    return flat
