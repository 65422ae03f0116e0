"""Plans scored on a posed CasADi NLP (its own objective and constraints) and the NLP's
multi-start tight IPOPT reference: the scoring of :mod:`zumo_nlp`."""

from __future__ import annotations

from typing import Any

import casadi as ca
import numpy as np

from mpclab.controllers.base import Controller

#: the reference: tight (tol 1e-10, acceptable 1e-8), up to 3000 iterations
REF_OPTIONS = {
    "print_time": False, "ipopt.print_level": 0, "ipopt.sb": "yes", "ipopt.tol": 1e-10,
    "ipopt.acceptable_tol": 1e-8, "ipopt.constr_viol_tol": 1e-10, "ipopt.max_iter": 3000,
}
#: a plan violating a constraint or bound by more than this is flagged
VIOL_FLAG = 1e-6
#: costs within this (relative) are one optimum: the backends' own tolerance is 1e-6
SAME = 1e-6
#: a backend's plan replaces the reference only if it is as feasible as the reference: at an
#: active constraint a violation of 1e-7 (a solver at tol 1e-6) can buy 1e-6 of the cost
REF_FEAS = 1e-8


def posed_nlp(ctrl: Controller) -> tuple[Any, np.ndarray]:
    """``(OCP, parameter vector)`` of the NLP a CasADi backend solved in its last step.

    Reads the backend's current NLP and its parameter array (``_nlp``, ``io["p"]``): the
    problem exactly as the controller posed it (active set, detections, constraints), without
    repeating how it packs its parameters."""
    nlp = ctrl._nlp
    return nlp.ocp, np.asarray(nlp.io["p"], dtype=float).copy()


class NlpScorer:
    """Costs of plans on one posed NLP, and its multi-start tight IPOPT reference."""

    def __init__(self, ocp: Any, plant: Any, dt: float) -> None:
        self.ocp, self.plant, self.dt = ocp, plant, dt
        nlp = ocp.nlp
        self.f = ca.Function("f", [nlp["x"], nlp["p"]], [nlp["f"]])
        self.g = ca.Function("g", [nlp["x"], nlp["p"]], [nlp["g"]])
        self.solver = ca.nlpsol("reference", "ipopt", nlp, REF_OPTIONS)
        known = [ocp.u_idx.ravel()]
        known += [i.ravel() for i in (ocp.x_idx, ocp.s_idx) if i is not None]
        self.known = np.concatenate(known)
        #: variables a plan does not give (slacks, ...): minimized with the plan held
        self.free = np.setdiff1d(np.arange(ocp.lbw.size), self.known)

    def w_of(self, x: np.ndarray, U: np.ndarray, u_prev: np.ndarray) -> np.ndarray:
        ocp = self.ocp
        w = np.zeros(ocp.lbw.size)
        w[ocp.u_idx] = U
        if ocp.x_idx is not None:
            w[ocp.x_idx] = self.plant.rollout(x, U, self.dt)
        if ocp.s_idx is not None:
            w[ocp.s_idx] = np.vstack([u_prev, U])
        return w

    def violation(self, w: np.ndarray, p: np.ndarray) -> float:
        o = self.ocp
        g = np.asarray(self.g(w, p)).ravel()
        with np.errstate(invalid="ignore"):
            v = [np.maximum(o.lbg - g, 0), np.maximum(g - o.ubg, 0),
                 np.maximum(o.lbw - w, 0), np.maximum(w - o.ubw, 0)]
        return float(max((np.nanmax(a) for a in v if a.size), default=0.0))

    def active_inequalities(self, w: np.ndarray, p: np.ndarray, tol: float = 1e-6) -> int:
        """How many inequality constraints (not bounds) hold with equality at ``w``."""
        o = self.ocp
        g = np.asarray(self.g(w, p)).ravel()
        ineq = o.lbg < o.ubg
        with np.errstate(invalid="ignore"):
            near = (np.abs(g - o.lbg) < tol) | (np.abs(o.ubg - g) < tol)
        return int(np.sum(ineq & near))

    def cost(self, x: np.ndarray, U: np.ndarray, u_prev: np.ndarray,
             p: np.ndarray) -> tuple[float, float]:
        """``(NLP objective, violation)`` of the input sequence ``U`` ``(T, nu)`` from ``x``."""
        w = self.w_of(x, U, u_prev)
        if self.free.size:  # the plan held, the rest (slacks) at their best
            lb, ub = self.ocp.lbw.copy(), self.ocp.ubw.copy()
            lb[self.known] = ub[self.known] = w[self.known]
            w = self._solve(w, p, lb, ub)[0]
        return float(self.f(w, p)), self.violation(w, p)

    def _solve(self, w0: np.ndarray, p: np.ndarray, lb: np.ndarray,
               ub: np.ndarray) -> tuple[np.ndarray, bool, str]:
        o = self.ocp
        sol = self.solver(x0=np.clip(w0, lb, ub), lbx=lb, ubx=ub, lbg=o.lbg, ubg=o.ubg, p=p)
        st = self.solver.stats()
        return np.asarray(sol["x"]).ravel(), bool(st.get("success")), st.get("return_status", "")

    def reference(self, x: np.ndarray, u_prev: np.ndarray, p: np.ndarray,
                  starts: dict[str, np.ndarray], u0: np.ndarray | None = None) -> dict[str, Any]:
        """The best converged IPOPT solution over ``starts`` (name -> inputs ``(T, nu)``);
        with ``u0`` the first input is held there. ``costs``: each start's converged cost."""
        lb, ub = self.ocp.lbw.copy(), self.ocp.ubw.copy()
        if u0 is not None:
            lb[self.ocp.u_idx[0]] = ub[self.ocp.u_idx[0]] = u0
        best, costs, failed = None, {}, {}
        for name, U in starts.items():
            U = np.clip(U, self.plant.u_lb, self.plant.u_ub)
            if u0 is not None:
                U = U.copy()
                U[0] = u0
            w, ok, why = self._solve(self.w_of(x, U, u_prev), p, lb, ub)
            if not ok:
                failed[name] = why
                continue
            Ur = w[self.ocp.u_idx]
            J, viol = self.cost(x, Ur, u_prev, p)
            costs[name] = J
            if best is None or J < best["cost"] - SAME * max(abs(J), 1.0):
                best = {"cost": J, "u_pred": Ur, "viol": viol, "start": name,
                        "active": self.active_inequalities(w, p)}
        if best is None:
            if u0 is not None:  # no feasible continuation of that first move
                return {"cost": np.nan, "viol": np.nan, "failed": failed}
            raise RuntimeError(f"the reference IPOPT converged from no start: {failed}")
        return best | {"costs": costs, "tried": len(starts), "failed": failed}
