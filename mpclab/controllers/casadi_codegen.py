"""The CasADi backend's whole solver as generated C (``controller.codegen=true``).

CasADi writes the ``nlpsol`` itself as C (``Function.generate``): for ``solver=sqp`` the SQP
iteration, the QP solver (qrqp) and the NLP's functions, self-contained. It is compiled with
the machine's C compiler, cached by a hash of the C source, the compiler, its flags and the
CasADi version (:func:`mpclab.codegen.build.compile_shared`), and loaded with
``ca.external``; the controller then calls it on the same arrays as the library solver.

A generated solver returns no statistics, so its status is established independently: the
returned point is ``converged`` when it meets sqpmethod's own termination test, primal
infeasibility (bound and constraint violation) at most ``tol`` and the infinity norm of the
Lagrangian's gradient ``grad f + J_g' lam_g + lam_x`` at most ``tol``; otherwise ``failed``
(its iteration count is unknown, so a capped iterate is not told from a failed one, and is
not applied).
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from mpclab.codegen.build import CompileError, compile_shared
from mpclab.controllers.casadi_compile import generated_c
from mpclab.controllers.casadi_ocp import OCP
from mpclab.controllers.casadi_solvers import bind_buffers
from mpclab.errors import ConfigError
from mpclab.status import SolveStatus


class GeneratedSolver:
    """``solver`` (a symbolic ``nlpsol``) as compiled generated C, with its KKT test.

    Parameters
    ----------
    solver
        The ``nlpsol`` built from ``ocp.nlp``.
    ocp
        Its problem (for the KKT test).
    flags
        C compiler flags.
    tol
        The solver's ``tol_pr`` and ``tol_du``.
    """

    def __init__(self, solver: ca.Function, ocp: OCP, flags: tuple[str, ...], tol: float):
        try:
            source = generated_c(solver.generate)
        except RuntimeError as exc:
            raise ConfigError(f"controller.codegen=true: CasADi cannot generate this solver "
                              f"as C ({str(exc).strip().splitlines()[-1][:200]})") from None
        try:
            lib = compile_shared(source, "nlpsol", flags, extra_key=(ca.__version__,))
        except CompileError as exc:
            raise ConfigError(f"controller.codegen=true: {exc}") from None
        self.library = lib
        self.fn = ca.external(solver.name(), str(lib))
        self.tol = float(tol)
        nlp = ocp.nlp
        w, p = nlp["x"], nlp["p"]
        lam_g = ca.SX.sym("lam_g", nlp["g"].shape[0])
        grad = ca.gradient(nlp["f"], w) + ca.jtimes(nlp["g"], w, lam_g, True)
        kkt = ca.Function("kkt", [w, p, lam_g], [nlp["g"], grad], ["x", "p", "lam_g"],
                          ["g", "grad"])
        self._kkt_buffer, self._kkt, self._kkt_io = bind_buffers(kkt, {})

    def status(self, io: dict[str, np.ndarray]) -> tuple[SolveStatus, str, int | None]:
        """``(status, word, None)`` of the point in the solver's arrays ``io``."""
        k = self._kkt_io
        for name in ("x", "p", "lam_g"):
            k[name][:] = io[name]
        self._kkt()
        g, grad, w = k["g"], k["grad"], io["x"]
        with np.errstate(invalid="ignore"):  # inf - inf on unbounded sides
            viol = np.concatenate([io["lbx"] - w, w - io["ubx"], io["lbg"] - g, g - io["ubg"]])
        pr_inf = float(np.nanmax(np.append(viol, 0.0)))
        du_inf = float(np.max(np.abs(grad + io["lam_x"]), initial=0.0))
        if not (np.isfinite(pr_inf) and np.isfinite(du_inf)):
            return SolveStatus.failed, "kkt_not_finite", None
        if pr_inf <= self.tol and du_inf <= self.tol:
            return SolveStatus.converged, "kkt_met", None
        return SolveStatus.failed, f"kkt_not_met(pr={pr_inf:.1e},du={du_inf:.1e})", None
