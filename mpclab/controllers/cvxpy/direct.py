"""Clarabel on CVXPY's compiled problem, without ``Problem.solve``'s per-call path.

CVXPY compiles a DPP problem once into a *parameter-to-data map*: a sparse matrix that, times
the vector of parameter values, gives every nonzero of the solver's ``(P, q, A, b)``. The
sparsity pattern does not depend on the values. ``Problem.solve`` redoes, each call, work that
depends only on that pattern (building SciPy matrices, slicing, the solver interface, the
solution's inversion through the reduction chain): about 1 ms for Study A's QP, against
Clarabel's own 0.62 ms (``experiments/car_cvxpy``).

:class:`DirectClarabel` keeps what CVXPY compiled and, per solve, does only what depends on the
values: one sparse product, an in-place update of a persistent Clarabel solver (which keeps its
symbolic factorization), and slicing the variables out of the primal vector. The data it
builds is checked once, at construction, against CVXPY's own ``apply_parameters`` for random
parameter values, so a change inside CVXPY is caught there and not in a solution.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from enum import StrEnum
from typing import Any

import numpy as np

from mpclab.controllers.base import USABLE, SolveStatus
from mpclab.core.errors import ConfigError
from mpclab.core.lazy_import import lazy_import

cp = lazy_import("cvxpy")  # about 0.6 s to import: paid only by runs that use it
sp = lazy_import("scipy.sparse")

#: Clarabel's statuses in CVXPY's words (the strings ``Problem.status`` would show;
#: ``cp.OPTIMAL == "optimal"`` and so on, written out so that importing this module does not
#: import CVXPY)
_STATUS = {
    "Solved": "optimal",
    "AlmostSolved": "optimal_inaccurate",
    "PrimalInfeasible": "infeasible",
    "AlmostPrimalInfeasible": "infeasible_inaccurate",
    "DualInfeasible": "unbounded",
    "AlmostDualInfeasible": "unbounded_inaccurate",
    "MaxIterations": "user_limit",
    "MaxTime": "user_limit",
}
_SOLVER_ERROR = "solver_error"
#: CVXPY's words -> what the solver did; "optimal_inaccurate" met only a reduced tolerance
#: (usable, not converged); "user_limit" (a cap) returns no iterate through CVXPY: failed
SOLVE_STATUS = {
    "optimal": SolveStatus.converged,
    "optimal_inaccurate": SolveStatus.truncated,
    "infeasible": SolveStatus.infeasible,
    "infeasible_inaccurate": SolveStatus.infeasible,
}


@dataclass
class QPSolution:
    """One solve of a :class:`CompiledQP`.

    ``values`` (the variables' values) is None unless ``status`` is usable; ``raw`` is the
    status in CVXPY's words (``"optimal"``, ``"infeasible"``, ``"solver_error"``, ...).
    """

    status: SolveStatus
    raw: str
    values: list[np.ndarray] | None = None
    objective: float = float("nan")
    iterations: int | None = None
    message: str = ""


def solution(raw: str, values: list[np.ndarray] | None, objective: float,
             iterations: int | None, message: str = "") -> QPSolution:
    """A :class:`QPSolution` from CVXPY's status word; no values unless usable."""
    status = SOLVE_STATUS.get(raw, SolveStatus.failed)
    if status not in USABLE or values is None:
        status = status if status not in USABLE else SolveStatus.failed
        return QPSolution(status, raw, None, float("nan"), iterations, message)
    return QPSolution(status, raw, values, objective, iterations, message)


class SolveVia(StrEnum):
    """How a CVXPY-built problem is solved each step."""

    #: ``direct`` for Clarabel, ``problem`` for other solvers
    auto = "auto"
    #: the compiled data straight into a persistent Clarabel solver (Clarabel only)
    direct = "direct"
    #: ``Problem.solve`` every step
    problem = "problem"


def direct_solver(
    problem: cp.Problem,
    variables: Sequence[cp.Variable],
    solver: str,
    options: Mapping[str, Any] | None,
    via: SolveVia | str,
    key: str = "controller.solve.via",
) -> DirectClarabel | None:
    """The :class:`DirectClarabel` for ``problem``, or None where ``Problem.solve`` is used.

    ``auto`` takes the direct path for Clarabel and falls back to ``Problem.solve`` (with a
    warning) if the compiled data cannot be used; ``direct`` insists (a ConfigError if it
    cannot); ``problem`` never takes it.
    """
    via = SolveVia(via)
    clarabel = str(solver) == "CLARABEL"
    if via is SolveVia.problem or (via is SolveVia.auto and not clarabel):
        return None
    if not clarabel:
        raise ConfigError(
            f"{key}=direct needs solver CLARABEL, not {solver}; use {key}=problem (or auto) "
            "for other solvers"
        )
    try:
        return DirectClarabel(problem, variables, options)
    except ConfigError:
        raise
    # ValueError: the data check failed; the others: CVXPY's compiled problem is not shaped
    # as this CVXPY version's is (the path reads its attributes)
    except (ValueError, AttributeError, KeyError, IndexError, TypeError) as exc:
        if via is SolveVia.direct:
            raise ConfigError(f"{key}=direct is not possible: {exc}") from exc
        warnings.warn(f"solving through Problem.solve: {exc}", stacklevel=3)
        return None


class CompiledQP:
    """A CVXPY problem built once, solved at its parameters' current values: on the direct
    path (:class:`DirectClarabel`) where ``via`` allows, else through ``Problem.solve``
    (warm-started, except for the first solve after :meth:`reset`, so every run starts as a
    fresh one would).

    Parameters
    ----------
    problem, variables
        The DPP problem (its parameters with values) and the variables whose values
        :meth:`solve` returns.
    solver, options
        A CVXPY solver name and its options.
    warm_start
        Warm-start ``Problem.solve`` within a run (the direct path has nothing to warm).
    via, key
        See :func:`direct_solver`.
    """

    def __init__(
        self,
        problem: cp.Problem,
        variables: Sequence[cp.Variable],
        solver: str,
        options: Mapping[str, Any] | None = None,
        warm_start: bool = True,
        via: SolveVia | str = SolveVia.auto,
        key: str = "controller.solve.via",
    ) -> None:
        self.problem, self.variables = problem, list(variables)
        self.solver, self.options = str(solver), dict(options or {})
        self.warm_start = bool(warm_start)
        self.direct = direct_solver(problem, self.variables, self.solver, self.options, via, key)
        self._cold = True

    def reset(self) -> None:
        """Start the next solve as a fresh solver would: no warm start from another run."""
        self._cold = True
        if self.direct is not None:
            self.direct.reset()

    def solve(self) -> QPSolution:
        """Solve at the parameters' current values."""
        if self.direct is not None:
            return self.direct.solve()
        warm, self._cold = self.warm_start and not self._cold, False
        try:
            self.problem.solve(solver=self.solver, warm_start=warm, **self.options)
        except cp.error.SolverError as exc:
            return solution(_SOLVER_ERROR, None, float("nan"), None, str(exc))
        values = [v.value for v in self.variables]
        if any(v is None for v in values):
            return solution(str(self.problem.status), None, float("nan"), None)
        stats = self.problem.solver_stats
        iters = None if stats is None or stats.num_iters is None else int(stats.num_iters)
        return solution(str(self.problem.status), values, float(self.problem.value), iters)


class DirectClarabel:
    """A compiled DPP problem solved by one persistent Clarabel solver.

    Parameters
    ----------
    problem
        A DPP-compliant CVXPY problem whose parameters all have values.
    variables
        The variables whose values :meth:`solve` returns.
    options
        Clarabel settings by name (``max_iter``, ``tol_gap_rel``, ...).

    Raises
    ------
    ConfigError
        An unknown Clarabel setting (the message lists the valid ones).
    ValueError
        The problem cannot take this path (not a cone program with a condensed map, or the
        data built here disagrees with CVXPY's); the caller should use ``Problem.solve``.
    """

    def __init__(
        self,
        problem: cp.Problem,
        variables: Sequence[cp.Variable],
        options: Mapping[str, Any] | None = None,
    ) -> None:
        import clarabel
        from cvxpy.reductions.solvers.conic_solvers.clarabel_conif import dims_to_solver_cones
        from cvxpy.reductions.solvers.conic_solvers.conic_solver import ConicSolver

        self._clarabel = clarabel
        data, _, _ = problem.get_problem_data(cp.CLARABEL)
        pp = data[cp.settings.PARAM_PROB]
        self.parameters = list(problem.parameters())
        self._cols = [
            (p, pp.param_id_to_col[p.id], pp.param_id_to_size[p.id]) for p in self.parameters
        ]
        self._theta = np.zeros(pp.total_param_size + 1)
        self._theta[pp.param_id_to_col[cp.lin_ops.lin_op.CONSTANT_ID]] = 1.0
        n = pp.x.size
        self._vars = [(v, pp.var_id_to_col[v.id], v.shape) for v in variables]

        # A and b: one condensed map; columns 0..n-1 of its CSC pattern are A, column n is b
        pp.reduced_A.cache(keep_zeros=True)
        if pp.reduced_A.problem_data_index is None:
            raise ValueError("CVXPY did not condense the constraint map")
        self._mapA = sp.csr_array(pp.reduced_A.reduced_mat)
        idx, ptr, (m, ncols) = pp.reduced_A.problem_data_index
        if ncols != n + 1:
            raise ValueError(f"constraint map has {ncols} columns, expected {n + 1}")
        self._nA = int(ptr[n])
        self._b_rows = np.asarray(idx[self._nA :])
        self._b = np.zeros(m)
        # the A pattern, sorted within columns as Clarabel requires (the permutation is kept)
        A0 = sp.csc_array((np.arange(self._nA, dtype=float), idx[: self._nA], ptr[: n + 1]), (m, n))
        A0.has_sorted_indices = False
        A0.sort_indices()
        self._A_perm = A0.data.astype(np.intp)
        self._A_idx, self._A_ptr = A0.indices.copy(), A0.indptr.copy()

        # P: the upper triangle of a symmetric pattern (constant or parametric)
        self._q_map = sp.csr_array(pp.q)
        if pp.reduced_P.matrix_data is not None:
            pp.reduced_P.cache(keep_zeros=True)
            self._mapP = sp.csr_array(pp.reduced_P.reduced_mat)
            pidx, pptr, _ = pp.reduced_P.problem_data_index
            P0 = sp.csc_array((np.arange(len(pidx), dtype=float), pidx, pptr), (n, n))
            P0 = sp.triu(P0, format="csc")
            P0.has_sorted_indices = False
            P0.sort_indices()
            self._P_perm = P0.data.astype(np.intp)
            self._P_idx, self._P_ptr = P0.indices.copy(), P0.indptr.copy()
        else:
            self._mapP = None
            self._P_perm = np.zeros(0, dtype=np.intp)
            self._P_idx, self._P_ptr = np.zeros(0, dtype=np.int64), np.zeros(n + 1, dtype=np.int64)

        self._cones = dims_to_solver_cones(data[ConicSolver.DIMS])
        self._settings = clarabel.DefaultSettings()
        self._settings.verbose = False
        self._settings.presolve_enable = False  # presolve would forbid in-place updates
        self._settings.input_sparse_dropzeros = False
        valid = sorted(k for k in dir(self._settings) if not k.startswith("_") and k != "default")
        for key, value in (options or {}).items():
            if key not in valid:
                raise ConfigError(
                    f"unknown Clarabel setting {key!r}; valid settings: {', '.join(valid)}"
                )
            setattr(self._settings, key, value)
        self._check(pp)
        self._solver: Any = None

    # -- data ---------------------------------------------------------------------------------

    def _parameter_vector(self) -> np.ndarray:
        for p, col, size in self._cols:
            self._theta[col : col + size] = np.ravel(p.value, order="F")
        return self._theta

    def _values(self) -> tuple[np.ndarray, np.ndarray, float, np.ndarray, np.ndarray]:
        """The nonzeros of ``P`` and ``A`` (in their fixed patterns), ``q``, ``d`` and ``b``
        for the parameters' current values: all a solve needs, no matrices built."""
        theta = self._parameter_vector()
        qd = self._q_map @ theta
        vals = self._mapA @ theta
        b = self._b.copy()
        b[self._b_rows] = vals[self._nA :]
        Pv = (self._mapP @ theta)[self._P_perm] if self._mapP is not None else np.zeros(0)
        return Pv, qd[:-1], float(qd[-1]), -vals[: self._nA][self._A_perm], b

    def data(self) -> tuple[sp.csc_array, np.ndarray, float, sp.csc_array, np.ndarray]:
        """Clarabel's ``(P, q, d, A, b)`` (upper-triangular ``P``, ``A x + s = b``) for the
        parameters' current values; ``d`` is the objective's constant."""
        Pv, q, d, Av, b = self._values()
        n = len(q)
        A = sp.csc_array((Av, self._A_idx, self._A_ptr), (len(b), n))
        P = sp.csc_array((Pv, self._P_idx, self._P_ptr), (n, n))
        return P, q, d, A, b

    def _check(self, pp: Any) -> None:
        """Compare :meth:`data` with CVXPY's ``apply_parameters`` at random parameter values."""
        saved = [p.value for p in self.parameters]
        rng = np.random.default_rng(0)
        try:
            for p in self.parameters:
                p.value = rng.uniform(0.5, 1.5, p.shape)
            P, q, d, A, b = self.data()
            P_ref, q_ref, d_ref, A_ref, b_ref = pp.apply_parameters(quad_obj=True)
            gaps = {
                "P": abs(P - sp.triu(P_ref)).max() if P_ref.nnz else abs(P).max() if P.nnz else 0.0,
                "q": np.abs(q - q_ref).max(),
                "d": abs(d - d_ref),
                "A": abs(A + A_ref).max(),
                "b": np.abs(b - b_ref).max(),
            }
        finally:
            for p, v in zip(self.parameters, saved, strict=True):
                p.value = v
        bad = {k: float(v) for k, v in gaps.items() if not v <= 1e-9}
        if bad:
            raise ValueError(f"the compiled data disagree with CVXPY's: {bad}")

    # -- solve --------------------------------------------------------------------------------

    def reset(self) -> None:
        """Build the solver afresh at the next solve (its equilibration is set at build time
        and kept through updates, so a new run starts from the state a fresh one would)."""
        self._solver = None

    def solve(self) -> QPSolution:
        """Solve at the parameters' current values."""
        if self._solver is None:
            P, q, d, A, b = self.data()
            self._solver = self._clarabel.DefaultSolver(
                P, q, A, b, self._cones, self._settings
            )
        else:  # the patterns are fixed: only the values change
            Pv, q, d, Av, b = self._values()
            self._solver.update(P=Pv, q=q, A=Av, b=b)
        sol = self._solver.solve()
        raw = _STATUS.get(str(sol.status), _SOLVER_ERROR)
        x = np.asarray(sol.x)
        values = [
            x[col : col + int(np.prod(shape))].reshape(shape, order="F")
            for _, col, shape in self._vars
        ]
        return solution(raw, values, float(sol.obj_val) + d, int(sol.iterations))
