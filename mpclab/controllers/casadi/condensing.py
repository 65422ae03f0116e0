"""The QP of one SQP step on a multiple-shooting NLP, condensed: the states eliminated.

Under multiple shooting the QP's step ``d`` splits into the states' part ``d_D`` and the rest
``d_I`` (the moves and the soft constraints' slacks). The dynamics rows (the initial value
and the gaps, :attr:`OCP.dynamics_rows`) fix the states: ``E_D d_D + E_I d_I = r``, with
``E_D`` square and invertible (each row fixes one state of the next stage). So
``d = Z d_I + z0`` with ``Z = [-E_D^-1 E_I; I]`` and ``z0 = [E_D^-1 r; 0]`` (in the NLP's
variable order), and the QP in ``d_I`` alone is dense and small:

    min 1/2 d_I' (Z' H Z) d_I + (Z' (c + H z0))' d_I
    s.t. l_O - J_O z0 <= J_O Z d_I <= u_O - J_O z0     (every other row: the obstacles')
         l_D - z0_D  <= Z_D d_I     <= u_D - z0_D      (the states' finite bounds)
         l_I <= d_I <= u_I

(full condensing, as acados' ``FULL_CONDENSING_QPOASES``). ``Z`` and ``Z' H Z`` need only the
Hessian and the dynamics rows, which do not depend on the sample's parameters: they are
made in the preparation. The feedback forms ``z0`` from the sample's initial value, the
gradient and the other rows (the sensed points' constraints) and solves the dense QP with
qpOASES, hot-started from the previous sample's active set. The multipliers of the dynamics
rows come back from the stationarity of the Lagrangian in ``d_D``.
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np
import numpy.typing as npt
from scipy.sparse import csr_matrix

from mpclab.controllers.casadi.ocp import OCP
from mpclab.controllers.casadi.solvers import CasadiQpSolver, bind_buffers, qp_options, read_status
from mpclab.core.native_output import c_stdout_silenced
from mpclab.core.status import SolveStatus

FloatArray = npt.NDArray[np.float64]


@dataclass
class CondensedStep:
    """The step of the full QP from the condensed one; the full QP's multipliers follow
    from it (:meth:`Condenser.multipliers`) once the input is out."""

    d: FloatArray
    status: SolveStatus
    raw: str
    lam_a: FloatArray   # the condensed QP's multipliers (its rows, then its bounds)
    lam_xI: FloatArray
    c: FloatArray       # the gradient the QP had


@dataclass
class Elimination:
    """What the preparation makes: ``Z``, ``E_D^-1`` and the condensed Hessian."""

    Z: FloatArray       # (n, nI)
    E_inv: FloatArray   # (nD, nD)
    Hc: FloatArray      # Z' H Z, column-major nonzeros of the dense QP
    ZT: FloatArray      # Z', contiguous
    HZT: FloatArray     # (H Z)', contiguous
    H: FloatArray       # the full Hessian (dense)


class Condenser:
    """Eliminates the states of an OCP's QP and solves the dense rest (module docstring).

    Parameters
    ----------
    ocp
        A multiple-shooting OCP.
    jacobian
        The pattern of its constraints' Jacobian (the nonzeros :meth:`eliminate` and
        :meth:`solve` take are in its order).
    qp_solver
        A dense QP solver of ``conic`` (``qpoases`` hot-starts from its last active set).
    """

    def __init__(self, ocp: OCP, jacobian: ca.Sparsity, qp_solver: CasadiQpSolver) -> None:
        if ocp.x_idx is None:
            raise ValueError("condensing needs multiple shooting (the states as variables)")
        n, m = ocp.lbw.size, ocp.lbg.size
        states = [ocp.x_idx.ravel()] + ([ocp.s_idx.ravel()] if ocp.s_idx is not None else [])
        self.D = np.sort(np.concatenate(states))
        self.I = np.setdiff1d(np.arange(n), self.D)
        self.R = np.asarray(ocp.dynamics_rows, dtype=int)
        self.O = np.setdiff1d(np.arange(m), self.R)
        if self.R.size != self.D.size:
            raise ValueError(f"{self.R.size} dynamics rows for {self.D.size} states")
        self.ocp = ocp
        self._rows, self._cols = (np.asarray(a) for a in jacobian.get_triplet())
        self._dense_j = np.zeros((m, n))
        # the other rows as a sparse matrix whose values the feedback refreshes in place
        other = np.isin(self._rows, self.O)
        where = np.searchsorted(self.O, self._rows[other])
        order = np.lexsort((self._cols[other], where))
        self._o_nz = np.flatnonzero(other)[order]
        self._j_o = csr_matrix((np.zeros(order.size), (where[order], self._cols[other][order])),
                               shape=(self.O.size, n))
        self._j_o.sort_indices()
        # the states' finite bounds become rows of the dense QP, but for a state that an
        # equality row fixes alone (a terminal constraint): the same row twice would make the
        # working set singular
        lo, hi = ocp.lbw[self.D], ocp.ubw[self.D]
        fixed = [self._cols[self._rows == r] for r in self.O if ocp.lbg[r] == ocp.ubg[r]]
        pinned = {int(c[0]) for c in fixed if c.size == 1}
        self.bounded = np.flatnonzero((np.isfinite(lo) | np.isfinite(hi))
                                      & ~np.isin(self.D, list(pinned)))
        self._qp_solver = qp_solver
        # qpOASES keeps equality rows (a terminal constraint) in its working set from the
        # start; without it, the car's QP failed its factorization on 5 of 32 steps
        self._equalities = ({"enableEqualities": True} if qp_solver is CasadiQpSolver.qpoases
                            else {})
        self._new_solver()

    def _new_solver(self) -> None:
        """A fresh QP solver (qpOASES cannot hot-start from a QP it failed to solve)."""
        nI, nA = self.I.size, self.O.size + self.bounded.size
        with c_stdout_silenced():  # qpOASES prints its banner whenever one is built
            self.qp = ca.conic("rti_condensed_qp", self._qp_solver.value,
                               {"h": ca.Sparsity.dense(nI, nI),
                                "a": ca.Sparsity.dense(nA, nI)},
                               qp_options(self._qp_solver) | self._equalities)
            self._buf, self._go, self._io = bind_buffers(self.qp, {})

    def _dense(self, j_nz: FloatArray) -> FloatArray:
        J = self._dense_j
        J[self._rows, self._cols] = j_nz
        return J

    def eliminate(self, j_nz: FloatArray, H: FloatArray) -> Elimination:
        """``Z`` and the condensed Hessian from the dynamics rows of the Jacobian ``j_nz``
        and the (convex) Hessian ``H`` (dense)."""
        J = self._dense(j_nz)
        E = J[self.R]
        E_inv = np.linalg.inv(E[:, self.D])
        Z = np.zeros((self.ocp.lbw.size, self.I.size))
        Z[self.D] = -E_inv @ E[:, self.I]
        Z[self.I, np.arange(self.I.size)] = 1.0
        HZ = H @ Z
        Hc = Z.T @ HZ
        return Elimination(Z, E_inv, ((Hc + Hc.T) / 2).ravel("F"), np.ascontiguousarray(Z.T),
                           np.ascontiguousarray(HZ.T), H.copy())

    def solve(self, el: Elimination, j_nz: FloatArray, c: FloatArray, lba: FloatArray,
              uba: FloatArray, lbx: FloatArray, ubx: FloatArray) -> CondensedStep:
        """The full QP's step (``lba <= J d <= uba``, ``lbx <= d <= ubx``, gradient ``c``,
        Jacobian nonzeros ``j_nz``), through the condensed QP."""
        D, I, R, O, b = self.D, self.I, self.R, self.O, self.bounded
        J_O = self._j_o
        J_O.data[:] = j_nz[self._o_nz]
        z0 = np.zeros(self.ocp.lbw.size)
        z0[D] = el.E_inv @ lba[R]  # the dynamics rows are equalities: lba = uba there
        off = J_O @ z0
        io = self._io
        io["h"][:] = el.Hc
        io["g"][:] = el.ZT @ c + el.HZT @ z0
        if b.size:
            io["a"][:] = np.vstack([J_O @ el.Z, el.Z[D[b]]]).ravel("F")
            io["lba"][:] = np.concatenate([lba[O] - off, lbx[D[b]] - z0[D[b]]])
            io["uba"][:] = np.concatenate([uba[O] - off, ubx[D[b]] - z0[D[b]]])
        else:
            io["a"][:] = (J_O @ el.Z).ravel("F")
            io["lba"][:], io["uba"][:] = lba[O] - off, uba[O] - off
        io["lbx"][:], io["ubx"][:] = lbx[I], ubx[I]
        self._go()
        status, raw, _ = read_status(self._buf)
        if status is not SolveStatus.converged:  # the next QP starts cold (``io`` stays
            self._new_solver()                   # this one's)
        return CondensedStep(el.Z @ io["x"] + z0, status, raw, io["lam_a"].copy(),
                             io["lam_x"].copy(), c.copy())

    def multipliers(self, el: Elimination, step: CondensedStep) -> tuple[FloatArray, FloatArray]:
        """The full QP's ``(lam_x, lam_g)`` of ``step``: the condensed QP's, and the dynamics
        rows' from the Lagrangian stationary in the states."""
        D, I, R, O, b = self.D, self.I, self.R, self.O, self.bounded
        lam_x = np.zeros(step.d.size)
        lam_x[I] = step.lam_xI
        lam_x[D[b]] = step.lam_a[O.size:]
        lam_g = np.zeros(self.ocp.lbg.size)
        lam_g[O] = step.lam_a[:O.size]
        rest = (el.H @ step.d + step.c + self._j_o.T @ lam_g[O])[D] + lam_x[D]
        lam_g[R] = -el.E_inv.T @ rest
        return lam_x, lam_g
