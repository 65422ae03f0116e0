"""Components a warm sweep worker keeps between jobs: plant, objective and controller.

Building a controller is the expensive part of setting up a run: CVXPY compiles its problem,
CasADi builds its NLP solver and loads (or compiles) its generated functions (0.4 s for the
Zumo NLP, against 0.2-0.4 s for the whole closed loop). Between the seeds of a sweep only
parameters change (start, world, goal); the problem's structure is fixed by the plant, the
objective and the controller's config. :class:`ComponentCache` keys what it built by those
three config parts, resolved, and hands the same objects to the next job with the same key.
Every controller's ``reset`` forgets its previous run (plan, warm start, multipliers, a
persistent solver's state), so a reused controller repeats the run a fresh one makes
(tests/test_sweep_warm.py compares both).
"""

from __future__ import annotations

import json
from collections import OrderedDict
from typing import Any

from omegaconf import DictConfig, OmegaConf

#: the config parts that shape the built components
SHAPING = ("plant", "objective", "controller")


def structure_key(cfg: DictConfig) -> str:
    """The resolved plant, objective and controller config as one canonical text."""
    parts = {g: OmegaConf.to_container(cfg[g], resolve=True) for g in SHAPING}
    return json.dumps(parts, sort_keys=True, default=str)


class ComponentCache:
    """The last ``size`` sets of (plant, objective, controller), by :func:`structure_key`."""

    def __init__(self, size: int = 4) -> None:
        self.size = size
        self._built: OrderedDict[str, tuple[Any, Any, Any]] = OrderedDict()
        self.hits = 0
        self.misses = 0

    def lookup(self, cfg: DictConfig) -> tuple[Any, Any, Any] | None:
        """The components built before for ``cfg``'s structure, or None (counted)."""
        key = structure_key(cfg)
        if key in self._built:
            self.hits += 1
            self._built.move_to_end(key)
            return self._built[key]
        self.misses += 1
        return None

    def store(self, cfg: DictConfig, made: tuple[Any, Any, Any]) -> None:
        """Keep ``made`` for ``cfg``'s structure (the oldest beyond ``size`` go)."""
        self._built[structure_key(cfg)] = made
        while len(self._built) > self.size:
            self._built.popitem(last=False)


#: the cache of this process (a sweep worker); used only by sweep jobs (mpclab.sweeps.jobs)
WORKER_CACHE = ComponentCache()
