"""A wall-clock cap on sqpmethod's solves: an iteration callback that stops it at a deadline.

CasADi's ``sqpmethod`` has an iteration cap (``max_iter``) but no time cap; every ``nlpsol``
calls its ``iteration_callback`` once per iteration, and a callback that returns non-zero
stops the solver with ``User_Requested_Stop`` and the last iterate. :class:`Deadline` is such
a callback: :meth:`Deadline.start` before a solve sets the deadline ``cap`` seconds ahead,
and the first iteration that begins after it stops the solve (:attr:`Deadline.fired`), so a
solve overruns its cap by at most one iteration. It reads no argument (CasADi's buffer
evaluation: the iterate is not converted), so it costs a clock read per iteration.

A stop is read by :meth:`Deadline.status`: ``truncated`` (``User_Requested_Stop:time_cap``).
A ``User_Requested_Stop`` the callback did not ask for is ``failed``: sqpmethod leaves its
previous call's status in place when a call ends in an error (a failed convexification of the
Hessian, seen a few times a run on the Zumo NLP after a stop on time), which
:func:`~mpclab.controllers.casadi.solvers.read_status` finds by the call's return code first.

IPOPT takes its own cap (``max_wall_time``, :func:`~mpclab.controllers.casadi.solvers.
nlpsol_options`); fatrop has neither a time limit nor an iteration callback.
"""

from __future__ import annotations

import time
from typing import Any

import casadi as ca

from mpclab.core.status import SolveStatus

#: what a solve stopped by the cap reports beside the solver's own return string
TIME_CAP = "time_cap"


class Deadline(ca.Callback):
    """``nlpsol``'s ``iteration_callback`` that stops the solve ``cap_s`` after :meth:`start`.

    Parameters
    ----------
    nlp
        The NLP (``x``, ``p``, ``g``): the callback's inputs are sized by it.
    cap_s
        The wall-clock budget of one solve [s].
    """

    def __init__(self, nlp: dict[str, Any], cap_s: float) -> None:
        ca.Callback.__init__(self)
        self.cap_s = float(cap_s)
        self.deadline = float("inf")
        self.fired = False
        self._sizes = {"x": nlp["x"].numel(), "lam_x": nlp["x"].numel(),
                       "g": nlp["g"].numel(), "lam_g": nlp["g"].numel(),
                       "p": nlp["p"].numel(), "lam_p": nlp["p"].numel(), "f": 1}
        self.construct("deadline", {})

    def start(self) -> None:
        """Set the deadline ``cap_s`` from now (before each solve)."""
        self.fired = False
        self.deadline = time.perf_counter() + self.cap_s

    def status(self, raw: str) -> tuple[SolveStatus, str]:
        """The status of a solve that ended in ``raw = "User_Requested_Stop"`` (module
        docstring)."""
        if self.fired:
            return SolveStatus.truncated, f"{raw}:{TIME_CAP}"
        return SolveStatus.failed, f"{raw}:unrequested"

    # CasADi's callback interface -------------------------------------------------------
    def get_n_in(self) -> int:
        return ca.nlpsol_n_out()

    def get_n_out(self) -> int:
        return 1

    def get_name_in(self, i: int) -> str:
        return ca.nlpsol_out(i)

    def get_name_out(self, i: int) -> str:
        return "stop"

    def get_sparsity_in(self, i: int) -> ca.Sparsity:
        return ca.Sparsity.dense(self._sizes[ca.nlpsol_out(i)])

    def has_eval_buffer(self) -> bool:
        return True

    def eval_buffer(self, arg: Any, res: Any) -> int:
        stop = time.perf_counter() >= self.deadline
        self.fired = self.fired or stop
        memoryview(res[0]).cast("d")[0] = 1.0 if stop else 0.0
        return 0
