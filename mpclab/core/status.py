"""What a solver did in one controller call: one vocabulary for every backend.

Lives on the bottom floor (no imports from mpclab) so that the loop, the run record, the
tables and the recordings can all name it without importing a backend.
"""

from __future__ import annotations

from enum import StrEnum


class SolveStatus(StrEnum):
    """What one controller call's solver did: one vocabulary for every backend."""

    #: met the solver's own tolerance (or an exact solve: closed form, a network evaluation)
    converged = "converged"
    #: stopped at an iteration or time cap with a usable iterate (real-time iteration by
    #: design), or at a reduced accuracy; applied, never called converged
    truncated = "truncated"
    #: the solver proved the problem infeasible
    infeasible = "infeasible"
    #: the solver stopped without a usable iterate (or gave a non-finite one)
    failed = "failed"
    #: the solver raised
    exception = "exception"


#: statuses whose result is applied; anything else triggers the fallback
USABLE = frozenset({SolveStatus.converged, SolveStatus.truncated})


class Problem(StrEnum):
    """What problem a backend's calls solve, so that ``converged`` can be read: it means the
    solver met its tolerance *on this problem*, which is the MPC's nonlinear OCP only for
    ``nonlinear``. The run record's ``problem`` field (``summary.json``) holds it."""

    #: the NLP over the plant's own nonlinear model, solved to the solver's tolerance (an
    #: interior point or SQP method, or a successive linearization iterated to convergence)
    nonlinear = "nonlinear"
    #: one QP of the model linearized about a guess or the current state, not iterated: exact
    #: for that QP, not for the nonlinear OCP
    linearized = "linearized"
    #: a QP of a fixed linear model from an operating point (or a blend of several): exact for
    #: that QP, away from the operating point not for the nonlinear OCP
    scheduled_linear = "scheduled_linear"
    #: no optimization: a learned approximation of a controller's law, evaluated
    policy = "policy"
    #: no optimization: a finite set of candidate inputs searched exhaustively (the dynamic
    #: window approach): exact over its candidates, not a solution of the OCP
    sampled = "sampled"


#: the summary's key of the :class:`Problem` a backend solves
PROBLEM_KEY = "problem"

#: the summary's key for the count of solves with each status (``solves_converged``, ...)
SOLVE_KEYS = {st: f"solves_{st}" for st in SolveStatus}
