"""The CasADi backend's whole solver as generated C (``controller.codegen=true``).

CasADi writes the ``nlpsol`` itself as C (``Function.generate``): the solver's iteration,
its QP solver and the NLP's functions. For ``solver=sqp`` (sqpmethod + qrqp) the C is
self-contained; for ``solver=fatrop`` it is CasADi's glue and the NLP's functions around the
fatrop library (compiled against the headers and ``libfatrop`` that CasADi's wheel ships).
It is compiled with the machine's C compiler, cached by a hash of the C source, the compiler,
its flags and the CasADi version (:func:`mpclab.codegen.build.compile_shared`; the source
and CasADi's header are kept beside the library), and loaded
with ``ca.external``; the controller calls it on the same arrays as the library solver.

A generated function returns no statistics, so the status comes another way:

* fatrop: the generated solver keeps fatrop's return flag, success flag and iteration count
  in its memory; a small accessor appended to the generated C reads them, and they are
  mapped exactly as the library solver's (:func:`~mpclab.controllers.casadi.solvers.read_status`);
* sqp: the generated loop keeps nothing, so the returned point is tested with sqpmethod's own
  termination test: primal infeasibility (bound and constraint violation) and the infinity
  norm of the Lagrangian's gradient ``grad f + J_g' lam_g + lam_x`` both at most ``tol``:
  ``converged``; otherwise ``failed`` (a capped iterate is not told from a failed one, and is
  not applied). Its iteration count is unknown.
"""

from __future__ import annotations

import ctypes
from pathlib import Path

import casadi as ca
import numpy as np

from mpclab.codegen.build import CompileError, compile_shared, kept_source
from mpclab.controllers.casadi.compile import generated_c_and_h
from mpclab.controllers.casadi.ocp import OCP
from mpclab.controllers.casadi.solvers import bind_buffers, read_status
from mpclab.core.errors import ConfigError
from mpclab.core.status import SolveStatus

#: the generated solver's entry point, and what is inserted to remember its memory slot
_ENTRY = ("static int casadi_f0(const casadi_real** arg, casadi_real** res, casadi_int* iw, "
          "casadi_real* w, int mem) {")
_FATROP_STATUS = """
CASADI_SYMBOL_EXPORT void mpclab_fatrop_status(int* success, int* flag, int* iterations) {
  const struct casadi_fatrop_data* d = &casadi_f0_mem[mpclab_last_mem];
  *success = d->success;
  *flag = d->return_status;
  *iterations = d->stats.iterations_count;
}
"""


class _Stats:
    """What ``read_status`` reads from a solver: ``stats()``."""

    def __init__(self, stats: dict) -> None:
        self._stats = stats

    def stats(self) -> dict:
        return self._stats


#: the generated solver's memory objects, one per controller alive in a process at once
MEMORY_SLOTS = 64


class GeneratedSolver:
    """``solver`` (a symbolic ``nlpsol``) as compiled generated C, with its status.

    Parameters
    ----------
    solver
        The ``nlpsol`` built from ``ocp.nlp`` (plugin sqpmethod or fatrop).
    ocp
        Its problem (for sqpmethod's termination test).
    flags
        C compiler flags.
    tol
        sqpmethod's ``tol_pr`` and ``tol_du``.
    """

    def __init__(self, solver: ca.Function, ocp: OCP, flags: tuple[str, ...], tol: float):
        try:
            source, header = generated_c_and_h(
                lambda name: solver.generate(name, {"with_header": True}))
        except RuntimeError as exc:
            raise ConfigError(f"controller.codegen=true: CasADi cannot generate this solver "
                              f"as C ({str(exc).strip().splitlines()[-1][:200]})") from None
        self.fatrop = "casadi_fatrop_solve" in source
        # CasADi's generated functions keep their memory in a static pool of
        # CASADI_MAX_NUM_THREADS (1 unless defined): a second controller of the same library
        # in one process (a sweep's warm worker, a test) would check out memory -1 and index
        # the pool out of bounds; room for as many as a process builds
        flags = (*flags, f"-DCASADI_MAX_NUM_THREADS={MEMORY_SLOTS}")
        libs: tuple[str, ...] = ()
        if self.fatrop:
            if _ENTRY not in source:
                raise ConfigError("controller.codegen=true: this CasADi version's generated "
                                  "fatrop solver has an unknown entry point; cannot read its "
                                  "status")
            source = source.replace(_ENTRY, "static int mpclab_last_mem = 0;\n"
                                    + _ENTRY + " mpclab_last_mem = mem;") + _FATROP_STATUS
            home = Path(ca.__file__).parent
            flags = (*flags, f"-I{home / 'include'}")
            libs = (f"-L{home}", "-lfatrop", f"-Wl,-rpath,{home}")
        try:
            lib = compile_shared(source, "nlpsol", flags, extra_key=(ca.__version__,),
                                 libs=libs, header=header, keep_source=True)
        except CompileError as exc:
            raise ConfigError(f"controller.codegen=true: {exc}") from None
        self.library = lib
        #: the generated C kept beside the library (the source as compiled, CasADi's header)
        self.generated = kept_source(lib)
        self.fn = ca.external(solver.name(), str(lib))
        self.tol = float(tol)
        if self.fatrop:
            self._status = ctypes.CDLL(str(lib)).mpclab_fatrop_status  # the same loaded copy
            self._flags = [ctypes.c_int() for _ in range(3)]
        else:
            nlp = ocp.nlp
            w, p = nlp["x"], nlp["p"]
            lam_g = ca.SX.sym("lam_g", nlp["g"].shape[0])
            grad = ca.gradient(nlp["f"], w) + ca.jtimes(nlp["g"], w, lam_g, True)
            kkt = ca.Function("kkt", [w, p, lam_g], [nlp["g"], grad], ["x", "p", "lam_g"],
                              ["g", "grad"])
            self._kkt_buffer, self._kkt, self._kkt_io = bind_buffers(kkt, {})

    def status(self, io: dict[str, np.ndarray]) -> tuple[SolveStatus, str, int | None]:
        """``(status, the solver's word, iterations)`` of the last solve, whose arrays are
        ``io``."""
        if self.fatrop:
            self._status(*(ctypes.byref(f) for f in self._flags))
            success, flag, iters = (f.value for f in self._flags)
            return read_status(_Stats({"success": bool(success), "return_status": flag,
                                       "iter_count": iters}))
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
