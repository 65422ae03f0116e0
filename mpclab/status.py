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

#: the summary's key for the count of solves with each status (``solves_converged``, ...)
SOLVE_KEYS = {st: f"solves_{st}" for st in SolveStatus}
