"""Components a warm sweep worker keeps between jobs: plant, objective and controller.

Building a controller is the expensive part of setting up a run: CVXPY compiles its problem,
CasADi builds its NLP solver and loads (or compiles) its generated functions (0.4 s for the
Zumo NLP, against 0.2-0.4 s for the whole closed loop). Between the seeds of a sweep only
parameters change (start, world, goal); the problem's structure is fixed by the plant, the
objective and the controller's config, and the obstacle margin derived for the run
(:mod:`mpclab.world.margin`: the same for every seed of a scenario and sim). :class:`ComponentCache`
keys what it built by those, and hands the same objects to the next job with the same key.
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


def structure_key(cfg: DictConfig, margin: Any = None) -> str:
    """The resolved plant, objective and controller config as one canonical text, with the
    obstacle margin derived for the run (it is built into the controller's problem)."""
    parts = {g: OmegaConf.to_container(cfg[g], resolve=True) for g in SHAPING}
    parts["margin"] = None if margin is None else repr(margin.total)
    return json.dumps(parts, sort_keys=True, default=str)


def _plant_key(cfg: DictConfig) -> str:
    return json.dumps(OmegaConf.to_container(cfg.plant, resolve=True), sort_keys=True,
                      default=str)


class ComponentCache:
    """The last ``size`` sets of (objective, controller), by :func:`structure_key`, and the
    plant each was built for."""

    def __init__(self, size: int = 4) -> None:
        self.size = size
        self._built: OrderedDict[str, tuple[Any, Any]] = OrderedDict()
        self._plants: dict[str, Any] = {}
        self.hits = 0
        self.misses = 0

    def plant(self, cfg: DictConfig) -> Any:
        """The plant built before for ``cfg.plant``, or None."""
        return self._plants.get(_plant_key(cfg))

    def lookup(self, cfg: DictConfig, margin: Any = None) -> tuple[Any, Any] | None:
        """The (objective, controller) built before for ``cfg``'s structure and obstacle
        ``margin``, or None (counted)."""
        key = structure_key(cfg, margin)
        if key in self._built:
            self.hits += 1
            self._built.move_to_end(key)
            return self._built[key]
        self.misses += 1
        return None

    def store(self, cfg: DictConfig, margin: Any, plant: Any, made: tuple[Any, Any]) -> None:
        """Keep ``made`` for ``cfg``'s structure and ``margin``, and its ``plant`` (the oldest
        beyond ``size`` go)."""
        self._built[structure_key(cfg, margin)] = made
        self._plants.setdefault(_plant_key(cfg), plant)  # the one every entry was built on
        while len(self._built) > self.size:
            self._built.popitem(last=False)


#: the cache of this process (a sweep worker); used only by sweep jobs (mpclab.sweeps.jobs)
WORKER_CACHE = ComponentCache()
