"""Supervisors pick the active objective terms each step; ``none`` keeps them all on."""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from enum import StrEnum
from typing import TypeVar

import numpy as np
import numpy.typing as npt

from mpclab.config.registry import component
from mpclab.core.errors import ConfigError
from mpclab.objectives.base import Objective

FloatArray = npt.NDArray[np.float64]
#: a supervisor's modes
Mode = TypeVar("Mode", bound=StrEnum)
#: the scenario's arrival rule: whether a state is at the goal
Arrival = Callable[[FloatArray], bool]


class Supervisor:
    """Base class: chooses a mode and the objective terms active in it.

    :meth:`target` may replace the scenario's reference over the horizon for a step.
    """

    def reset(self, x0: FloatArray, goal: FloatArray, arrived: Arrival | None = None) -> None:
        """Start a new run toward ``goal``; ``arrived`` is the scenario's arrival rule (the
        loop ends a run on the true state meeting it; a supervisor sees measured states)."""

    def update(
        self, t: float, x: FloatArray, detections: FloatArray
    ) -> tuple[str, frozenset[str] | None]:
        """Return ``(mode, active term names)``; ``None`` means every term."""
        return "", None

    def target(self, t: float, horizon: int, dt: float) -> FloatArray | None:
        """After :meth:`update`: the reference over the horizon ``(horizon + 1, nx)`` the
        controller is given this step in place of the scenario's, or None (the scenario's)."""
        return None


@component("supervisor", "none")
class NoSupervisor(Supervisor):
    """Every objective term is always active."""


def mode_terms(
    modes: Mapping[str, Sequence[str]], kinds: type[Mode], objective: Objective | None,
) -> dict[Mode, frozenset[str]]:
    """A supervisor's ``modes`` option checked and read: exactly the modes ``kinds`` names,
    each naming only the objective's terms, and every term named by some mode."""
    given = dict(modes)
    valid = [m.value for m in kinds]
    if sorted(given) != sorted(valid):
        raise ConfigError(
            f"supervisor.modes must name exactly the modes {valid}, got {sorted(given)}")
    if objective is not None:
        check_modes(given, list(objective.terms))
    return {kinds(k): frozenset(str(t) for t in v) for k, v in given.items()}


def check_modes(modes: Mapping[str, Sequence[str]], terms: Sequence[str]) -> None:
    """Raise :class:`ConfigError` unless the modes name only the objective's terms and every
    term is named by some mode."""
    for mode, names in modes.items():
        for name in names:
            if name not in terms:
                raise ConfigError(
                    f"supervisor.modes.{mode} names the term {name!r}, which the objective does "
                    f"not have; objective terms: {', '.join(terms)}"
                )
    used = {str(n) for names in modes.values() for n in names}
    unused = [t for t in terms if t not in used]
    if unused:
        raise ConfigError(
            f"objective term(s) {', '.join(map(repr, unused))} named by no supervisor mode "
            f"would never be active; add them to supervisor.modes "
            f"({'; '.join(f'{m}: {list(n)}' for m, n in modes.items())}) or remove them "
            "from objective.terms"
        )
