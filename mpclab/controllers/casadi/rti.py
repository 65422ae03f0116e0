"""Real-time iteration of the CasADi backend's NLP: a preparation and a feedback phase.

Diehl's real-time iteration (RTI) takes one SQP step per sample, split at the measurement:

* **preparation** (:meth:`RealTimeIteration.prepare`, between two samples): at a guess ``w``
  (the plan shifted by one step) with the parameters predicted for the next sample, the QP's
  Hessian, made convex by clipping its eigenvalues block by block (as CasADi's ``sqpmethod``
  does with ``convexify_strategy=eigen-clip``). :class:`RtiHessian`: ``gauss_newton`` is the
  cost's Hessian alone. Under multiple shooting the least-squares terms (tracking, effort,
  input rate) are quadratic in the variables, so that this is their Gauss-Newton Hessian;
  the constraints' curvature is left out, and a term that is not least squares (the
  potentials) keeps its own Hessian, clipped. ``exact`` is the Lagrangian's
  ``f + lam' g`` at the last multipliers.
* **feedback** (:meth:`RealTimeIteration.feedback`, at the measurement): the constraints,
  their Jacobian and the cost's gradient at ``w`` with *this* sample's parameters (the
  measured state, the input in flight, the sensed points and their constraint data, the
  supervisor's reference), then the one QP in the step ``d``

      min 1/2 d' H d + grad' d   s.t.  lbg - g <= J d <= ubg - g,  lbw - w <= d <= ubw - w

  solved (``conic`` with ``controller.solve.qp_solver``); ``w + d`` and the QP's multipliers
  are the new iterate. Nothing the QP holds is one sample old but the Hessian. The
  linearization is a few microseconds of CasADi's virtual machine; CasADi's QP solvers
  factor their matrices inside each call, so the QP's solve is the feedback's cost.

Under multiple shooting a dense QP solver (qpOASES, as ``casadi_rti`` ships) gets the QP
condensed (:mod:`.condensing`): the preparation also eliminates the states through the
dynamics rows, and the feedback solves the small dense QP in the moves and the slacks,
hot-started from the previous sample's active set. HPIPM (``qp_solver=hpipm``) takes the
uncondensed QP stage by stage, its rows in its stage order (:mod:`.stages`).

Convergence (:attr:`RtiResult`, :meth:`RealTimeIteration.refine`) is read at the
linearization point: the constraint violation ``g`` and the bounds at ``w``, and the gradient
of the Lagrangian with the QP's multipliers, ``grad + J' lam_a + lam_x``, which the QP's
optimality makes ``-H d``; both within ``tol`` (sqpmethod's ``tol_pr``, ``tol_du``) means ``w``
was a KKT point of the NLP with this sample's parameters, and the step vanishes.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable
from dataclasses import dataclass
from enum import StrEnum
from typing import Any

import casadi as ca
import numpy as np
import numpy.typing as npt
from scipy.sparse import csc_matrix
from scipy.sparse.csgraph import connected_components

from mpclab.controllers.base import FEEDBACK_KEY, ControlStep
from mpclab.controllers.casadi.condensing import CondensedStep, Condenser, Elimination
from mpclab.controllers.casadi.ocp import OCP
from mpclab.controllers.casadi.solvers import CasadiQpSolver, bind_buffers, qp_options, read_status
from mpclab.controllers.casadi.stages import StageLayout
from mpclab.core.native_output import c_stdout_silenced
from mpclab.core.status import USABLE, SolveStatus

FloatArray = npt.NDArray[np.float64]

#: the smallest eigenvalue a convexified Hessian block keeps (sqpmethod's
#: ``convexify_margin`` default)
MARGIN = 1e-7


class RtiHessian(StrEnum):
    """The Hessian of the real-time iteration's QP (module docstring)."""

    #: the cost's alone: Gauss-Newton for least-squares terms, no constraint curvature
    gauss_newton = "gauss_newton"
    #: the Lagrangian's at the last multipliers
    exact = "exact"


@dataclass
class Prepared:
    """One preparation: the linearization point and the QP's Hessian there."""

    owner: RealTimeIteration
    w: FloatArray        # the linearization point
    h: FloatArray        # the convexified Hessian's nonzeros (the QP's pattern)
    lam_x0: FloatArray   # the QP's multiplier guesses
    lam_a0: FloatArray
    elimination: Elimination | None = None  # the condensed QP's (dense QP solvers)


@dataclass
class RtiResult:
    """The feedback's new iterate and how its QP went (its multipliers after
    :meth:`RealTimeIteration.complete`, between samples, for the condensed QP)."""

    w: FloatArray
    lam_x: FloatArray | None
    lam_g: FloatArray | None  # the constraints' multipliers, in the NLP's row order
    p: FloatArray        # the parameters the QP was linearized with (the sample's)
    status: SolveStatus  # ``truncated`` (one SQP step; ``converged`` after :meth:`refine`
    #                      found a KKT point), or the QP's failure
    raw: str             # the QP solver's return string
    g: FloatArray        # the constraints at the linearization point
    c: FloatArray        # the cost's gradient there
    a: FloatArray        # the constraints' Jacobian there (its nonzeros)
    condensed: CondensedStep | None = None  # the condensed QP's step, to complete


class RealTimeIteration:
    """The preparation and feedback of one SQP step on an :class:`OCP`.

    Parameters
    ----------
    ocp
        The NLP and its bounds.
    qp_solver
        The QP solver of ``conic``; ``hpipm`` needs multiple shooting.
    tol
        The KKT tolerance of ``converged``.
    hessian
        The QP's Hessian (:class:`RtiHessian`).
    """

    def __init__(self, ocp: OCP, qp_solver: CasadiQpSolver, tol: float,
                 hessian: RtiHessian = RtiHessian.gauss_newton) -> None:
        nlp = ocp.nlp
        w, p, f, g = nlp["x"], nlp["p"], nlp["f"], nlp["g"]
        self.ocp, self.tol, self.hessian = ocp, float(tol), hessian
        lam = ca.SX.sym("lam_g", g.shape[0])
        lagrangian = f + ca.dot(lam, g) if hessian is RtiHessian.exact else f
        H, _ = ca.hessian(lagrangian, w)
        J = ca.jacobian(g, w)
        self._lin = ca.Function("rti_linearization", [w, p], [g, ca.gradient(f, w), J],
                                ["w", "p"], ["g", "grad", "J"])
        self._hess = ca.Function("rti_hessian", [w, p, lam], [H], ["w", "p", "lam_g"], ["H"])
        self._cost = ca.Function("rti_cost", [w, p], [f])
        n = int(w.shape[0])
        # the Hessian's blocks: the connected parts of its pattern with the diagonal, each
        # clipped on its own and held dense in the QP
        hs = H.sparsity() + ca.Sparsity.diag(n)
        rows, cols = (np.asarray(a) for a in hs.get_triplet())
        _, label = connected_components(
            csc_matrix((np.ones(rows.size), (rows, cols)), shape=(n, n)), directed=False)
        self._blocks = [np.flatnonzero(label == b) for b in range(label.max() + 1)]
        # the blocks grouped by size: index arrays (k, s, s) for one batched eigh each
        self._batches = []
        for size in sorted({b.size for b in self._blocks}):
            idx = np.array([b for b in self._blocks if b.size == size])
            self._batches.append((idx[:, :, None], idx[:, None, :]))
        pattern = np.zeros((n, n), dtype=bool)
        for b in self._blocks:
            pattern[np.ix_(b, b)] = True
        qr, qc = np.nonzero(pattern.T)  # column-major: CasADi's order of nonzeros
        h_sp = ca.Sparsity.triplet(n, n, qc.tolist(), qr.tolist())
        self._h_rows, self._h_cols = (np.asarray(a) for a in h_sp.get_triplet())
        self._hess_at = tuple(np.asarray(a) for a in H.sparsity().get_triplet())
        self._j_rows, self._j_cols = (np.asarray(a) for a in J.sparsity().get_triplet())
        # the QP's rows: the NLP's, in the stage order a stage-wise solver reads
        structure: dict[str, Any] = {}
        order = np.arange(J.shape[0])
        if qp_solver is CasadiQpSolver.hpipm:
            layout = StageLayout.of(ocp, J.sparsity())
            order, structure = layout.row_order, layout.conic_options()
        a_sp = J[order.tolist(), :].sparsity()
        numbered = ca.DM(J.sparsity(), np.arange(J.nnz(), dtype=float))
        self._a_from_j = np.asarray(numbered[order.tolist(), :].nonzeros(), dtype=int)
        self._order = order
        self._silent = qp_solver is CasadiQpSolver.hpipm  # it prints from C on every call
        with c_stdout_silenced():  # qpOASES prints its banner whenever one is built
            # a dense QP solver on multiple shooting: the condensed QP (states eliminated)
            self._condenser = (Condenser(ocp, J.sparsity(), qp_solver)
                               if ocp.x_idx is not None and qp_solver is not CasadiQpSolver.hpipm
                               else None)
            self.qp = self._condenser.qp if self._condenser else ca.conic(
                "rti_qp", qp_solver.value, {"h": h_sp, "a": a_sp},
                qp_options(qp_solver) | structure)
            self._lin_buf, self._lin_go, self._lin_io = bind_buffers(self._lin, {})
            self._hess_buf, self._hess_go, self._hess_io = bind_buffers(self._hess, {})
            self._qp_buf, self._qp_go, self._qp_io = bind_buffers(self.qp, {})
        self._dense_h = np.zeros((n, n))

    # ---------------------------------------------------------------- preparation
    def prepare(self, w: FloatArray, p: FloatArray, lam_g: FloatArray | None = None,
                lam_x: FloatArray | None = None) -> Prepared:
        """The QP's Hessian at ``w`` with the parameters ``p`` (and, for ``exact``, the
        multipliers ``lam_g``; None: zero), convexified; the multipliers kept as the QP's
        guesses."""
        io = self._hess_io
        ng = self.ocp.lbg.size
        io["w"][:], io["p"][:] = w, p
        io["lam_g"][:] = 0.0 if lam_g is None else lam_g
        self._hess_go()
        h = self._convexified(io["H"])
        elimination = None
        if self._condenser is not None:  # the dynamics rows do not depend on p
            lin = self._lin_io
            lin["w"][:], lin["p"][:] = w, p
            self._lin_go()
            elimination = self._condenser.eliminate(lin["J"], self._dense_h)
        return Prepared(
            self, np.array(w, dtype=float), h,
            np.zeros(w.size) if lam_x is None else np.array(lam_x, dtype=float),
            np.zeros(ng) if lam_g is None else np.array(lam_g, dtype=float)[self._order],
            elimination)

    def _convexified(self, h_nz: FloatArray) -> FloatArray:
        """The Hessian's nonzeros with each block's eigenvalues clipped at :data:`MARGIN`,
        as the QP's nonzeros (every block dense); the blocks of one size in one batch."""
        Hd = self._dense_h
        Hd[:] = 0.0
        Hd[self._hess_at] = h_nz
        for rows, cols in self._batches:
            blocks = Hd[rows, cols]  # (k, s, s)
            vals, vecs = np.linalg.eigh(blocks)
            clip = vals[:, 0] < MARGIN
            if clip.any():
                v, q = np.maximum(vals[clip], MARGIN), vecs[clip]
                Hd[rows[clip], cols[clip]] = (q * v[:, None, :]) @ q.transpose(0, 2, 1)
        return Hd[self._h_rows, self._h_cols]

    # ---------------------------------------------------------------- feedback
    def feedback(self, prep: Prepared, p: FloatArray) -> RtiResult:
        """The QP at ``prep``'s point linearized with this sample's parameters ``p``,
        solved: the new iterate."""
        ocp, lin, qp, order = self.ocp, self._lin_io, self._qp_io, self._order
        lin["w"][:], lin["p"][:] = prep.w, p
        self._lin_go()
        g = lin["g"]
        if self._condenser is not None and prep.elimination is not None:
            step = self._condenser.solve(prep.elimination, lin["J"], lin["grad"], ocp.lbg - g,
                                         ocp.ubg - g, ocp.lbw - prep.w, ocp.ubw - prep.w)
            return RtiResult(prep.w + step.d, None, None, np.array(p, dtype=float),
                             sqp_step(step.status), step.raw, g.copy(), lin["grad"].copy(),
                             lin["J"].copy(), condensed=step)
        qp["h"][:], qp["a"][:], qp["g"][:] = prep.h, lin["J"][self._a_from_j], lin["grad"]
        qp["lba"][:], qp["uba"][:] = (ocp.lbg - g)[order], (ocp.ubg - g)[order]
        qp["lbx"][:], qp["ubx"][:] = ocp.lbw - prep.w, ocp.ubw - prep.w
        qp["x0"][:] = 0.0
        qp["lam_x0"][:], qp["lam_a0"][:] = prep.lam_x0, prep.lam_a0
        with c_stdout_silenced() if self._silent else contextlib.nullcontext():
            self._qp_go()
        status, raw, _ = read_status(self._qp_buf)
        status = sqp_step(status)
        lam_g = np.empty(order.size)
        lam_g[order] = qp["lam_a"]
        return RtiResult(prep.w + qp["x"], qp["lam_x"].copy(), lam_g, np.array(p, dtype=float),
                         status, raw, g.copy(), lin["grad"].copy(), lin["J"].copy())

    def complete(self, prep: Prepared, sol: RtiResult) -> None:
        """The full QP's multipliers of a condensed step (after the input is out)."""
        if sol.condensed is not None and prep.elimination is not None:
            assert self._condenser is not None
            sol.lam_x, sol.lam_g = self._condenser.multipliers(prep.elimination, sol.condensed)
            sol.condensed = None

    def kkt(self, prep: Prepared, sol: RtiResult) -> tuple[float, float]:
        """(primal violation, dual residual) at the linearization point with the QP's
        multipliers (module docstring)."""
        ocp, w, g = self.ocp, prep.w, sol.g
        with np.errstate(invalid="ignore"):  # inf - inf of an unbounded side
            viol = np.concatenate([ocp.lbg - g, g - ocp.ubg, ocp.lbw - w, w - ocp.ubw, [0.0]])
        primal = float(np.nanmax(viol))
        jt_lam = np.zeros(w.size)  # J' lam_g from J's nonzeros
        np.add.at(jt_lam, self._j_cols, sol.a * sol.lam_g[self._j_rows])
        dual = float(np.abs(sol.c + jt_lam + sol.lam_x).max()) if w.size else 0.0
        return primal, dual

    def refine(self, prep: Prepared, sol: RtiResult) -> None:
        """``sol`` converged if its linearization point was a KKT point within ``tol``."""
        if sol.status is SolveStatus.truncated and max(self.kkt(prep, sol)) <= self.tol:
            sol.status = SolveStatus.converged

    def cost(self, w: FloatArray, p: FloatArray) -> float:
        """The NLP's cost at ``w`` (the iterate the feedback gave)."""
        return float(self._cost(w, p))


def sqp_step(qp: SolveStatus) -> SolveStatus:
    """The iterate's status from its QP's: a solved QP is one SQP step (``truncated``, not
    the NLP's solution); a QP stopped short of its solution (an iteration cap) or failed
    gives no SQP step at all (``failed``: the loop falls back)."""
    return SolveStatus.truncated if qp is SolveStatus.converged else (
        qp if qp is SolveStatus.infeasible else SolveStatus.failed)


#: the start of an iterate's return string when no SQP step made it safe
UNSAFE = "unsafe"
#: the most SQP steps a sample adds to make an unsafe iterate safe (:meth:`RtiLoop.step`)
SAFETY_ITERATIONS = 4


#: what the preparation starts from: ``(w, p, lam_g, lam_x)`` (None multipliers: zero)
Point = tuple[Any, ...]
#: ``(w, status, raw) -> (w, status, raw)``: an iterate outside its bounds clipped or failed
Check = Callable[[FloatArray, SolveStatus, str], tuple[FloatArray, SolveStatus, str]]


class RtiLoop:
    """When the two phases run in the closed loop, which calls the controller once per
    sample: the feedback at the measurement on the QP prepared for it, then (the input
    known, between samples) the next sample's preparation. A call with no QP prepared for
    it (the first, one on another NLP, one after a failure) prepares first, after the
    measurement: a *late* preparation, counted in its feedback time.

    The step log gets :attr:`columns`: ``feedback_s`` (from the call to the input: the
    parameters packed, the QP linearized with them and solved, its iterate checked against
    its bounds; the latency; ``feedback_cpu_s`` its CPU time, which waits for a core do not
    inflate), ``prep_s`` (after the input: the convergence check, the plan and its cost, the
    next sample's preparation), ``late_prep`` and ``prep_overrun``: the feedback and the
    preparation together took longer than the period, so that on a target the next sample's
    QP would not be ready when its measurement comes.
    """

    columns = ("prep_s", FEEDBACK_KEY, "feedback_cpu_s", "late_prep", "prep_overrun",
               "safety_qps")

    def __init__(self, period: float) -> None:
        self.period = float(period)
        self.prepared: Prepared | None = None

    def reset(self) -> None:
        self.prepared = None

    def step(self, rti: RealTimeIteration, params: Callable[[], FloatArray],
             start: Callable[[FloatArray], Point], check: Check,
             finish: Callable[[RtiResult], ControlStep],
             next_point: Callable[[ControlStep], Point],
             safe: Callable[[FloatArray], bool] = lambda w: True) -> ControlStep:
        """One sample: ``params()`` are the measured sample's parameters, ``start(p)`` a
        late preparation's point, ``check(w, status, raw)`` decides whether the feedback's
        iterate is applied (its bounds), ``finish`` makes the step of it (the plan, the
        multipliers kept), ``next_point(step)`` the next preparation's point.

        ``safe(w)`` says whether an iterate may be applied as it is (:meth:`CasadiMPC`: its
        first predicted state no deeper inside an obstacle's margin than the robot is now).
        An iterate that is not takes up to :data:`SAFETY_ITERATIONS` more SQP steps at this
        sample, each linearized at the last iterate, before its input goes out (their time
        is the feedback's); if none is safe, the step fails, ``unsafe``, and the fallback
        stops a plant that holds at rest (else follows the previous plan)."""
        t0, c0 = time.perf_counter(), time.thread_time()
        p = params()
        prep = self.prepared
        late = prep is None or prep.owner is not rti
        if late:
            prep = rti.prepare(*start(p))
        sol = rti.feedback(prep, p)
        sol.w, sol.status, sol.raw = check(sol.w, sol.status, sol.raw)
        extra = 0
        while sol.status in USABLE and not safe(sol.w):
            if extra == SAFETY_ITERATIONS:
                sol.status, sol.raw = SolveStatus.failed, f"{UNSAFE} after {extra + 1} QPs"
                break
            rti.complete(prep, sol)
            prep = rti.prepare(sol.w, p, sol.lam_g, sol.lam_x)
            sol = rti.feedback(prep, p)
            sol.w, sol.status, sol.raw = check(sol.w, sol.status, sol.raw)
            extra += 1
        t1, c1 = time.perf_counter(), time.thread_time()  # the input is known
        rti.complete(prep, sol)
        if sol.status in USABLE:
            rti.refine(prep, sol)
        res = finish(sol)
        res.iterations = 1 + extra
        res.unsafe = sol.raw.startswith(UNSAFE)
        self.prepared = None
        if res.ok:
            res.cost = rti.cost(sol.w, sol.p)
            self.prepared = rti.prepare(*next_point(res))
        prep_s = time.perf_counter() - t1
        res.info |= {"prep_s": prep_s, FEEDBACK_KEY: t1 - t0, "feedback_cpu_s": c1 - c0,
                     "late_prep": late, "prep_overrun": t1 - t0 + prep_s > self.period,
                     "safety_qps": extra}
        return res

    @staticmethod
    def metrics(steps: Any) -> dict[str, Any]:
        """The phases over a run's step log: median and largest times [ms], how many calls
        prepared late and how many overran the period."""
        out: dict[str, Any] = {}
        for col in ("prep_s", "feedback_s"):
            v = np.asarray(steps[col], dtype=float) if col in steps else np.zeros(0)
            v = v[np.isfinite(v)] * 1e3
            name = col.removesuffix("_s")
            out[f"{name}_median_ms"] = float(np.median(v)) if v.size else None
            out[f"{name}_max_ms"] = float(v.max()) if v.size else None
        for col, key in (("late_prep", "late_preps"), ("prep_overrun", "prep_overruns")):
            flags = steps[col] if col in steps else []
            out[key] = int(sum(bool(v) for v in flags if v is not None and v == v))
        extra = steps["safety_qps"] if "safety_qps" in steps else []
        out["safety_qps"] = int(sum(int(v) for v in extra if v is not None and v == v))
        out["samples_with_safety_qps"] = int(sum(1 for v in extra if v == v and v))
        return out
