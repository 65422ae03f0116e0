"""The NN's training rows as a run records them: ``recorder=dataset``.

One row per controller call: pose, goal pose, every ray's range (``inf`` for none), the
input, the solver's status and the hash of the run's config. The rows hold what the features
are made of, not the features themselves, so one dataset serves every feature set; merging a
sweep's runs into one file is :mod:`mpclab.approx.dataset`.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from omegaconf import OmegaConf

from mpclab.config.registry import component
from mpclab.recorders.base import Recorder

ROWS = "dataset.parquet"
#: what is ignored when hashing a run's config: what differs between the jobs of one dataset
HASH_IGNORES = ("seed", "hydra")


@component("recorder", "dataset", injected=("out_dir", "cfg"), hydra_keys={"_recursive_": False})
class DatasetRecorder(Recorder):
    """Writes one row per controller call: pose, goal pose, ranges, input, solver status.

    Parameters
    ----------
    out_dir
        Injected run folder.
    cfg
        Injected run config; its hash goes into every row (``config_hash``).
    filename
        File written into it.
    """

    def __init__(
        self, out_dir: Path | None = None, cfg: Any = None, filename: str = ROWS
    ) -> None:
        self.path = Path(out_dir or ".") / filename
        # the generating config's hash, taken now: a resumed sweep may rewrite the run's
        # .hydra/config.yaml later, and the rows must keep the config that made them
        self.config_hash = hash_config(cfg) if cfg is not None else None
        self._rows: list[np.ndarray] = []
        self._status: list[str] = []
        self._fallback: list[bool] = []

    def start(self, run: Any) -> None:
        p = run.plant
        if p.heading is None:
            raise ValueError("the dataset recorder needs a plant with a heading")
        self._ip = [p.state_index(s) for s in (*p.position, p.heading)]
        self._inputs = p.inputs
        self._seed: int | None = None

    def log_step(self, k: int, t: float, x: Any, step: Any, ctx: Any) -> None:
        x = np.asarray(x, dtype=float)
        self._rows.append(np.concatenate(
            ([k, t], x[self._ip], ctx.goal[self._ip], ctx.ranges, step.u)
        ))
        self._status.append(step.status)
        self._fallback.append(bool(step.fallback))

    def finish(self, x: Any, t: float, summary: dict[str, Any]) -> None:
        n_rays = (len(self._rows[0]) - 8 - len(self._inputs)) if self._rows else 0
        cols = ["step", "t", "x", "y", "theta", "x0", "y0", "theta0"]
        cols += [f"d{i}" for i in range(n_rays)] + list(self._inputs)
        table = pd.DataFrame(np.array(self._rows).reshape(len(self._rows), len(cols)),
                             columns=cols)
        table["step"] = table["step"].astype(int)
        table["status"] = pd.Series(self._status, dtype="string")
        table["fallback"] = np.array(self._fallback, dtype=bool)
        table["run_status"] = summary.get("status", "")
        if self.config_hash is not None:
            table["config_hash"] = self.config_hash
        self.path.parent.mkdir(parents=True, exist_ok=True)
        table.to_parquet(self.path, index=False)


def hash_config(cfg: Any) -> str:
    """Short hash of a run's config (interpolations unresolved, as Hydra saves it) without
    what differs between a sweep's jobs."""
    data = dict(OmegaConf.to_container(OmegaConf.create(cfg), resolve=False))
    for key in HASH_IGNORES:
        data.pop(key, None)
    return hashlib.sha256(json.dumps(data, sort_keys=True).encode()).hexdigest()[:12]


def config_hash(run_dir: Path) -> str:
    """:func:`hash_config` of the config saved in a run folder's ``.hydra/config.yaml``."""
    return hash_config(OmegaConf.load(Path(run_dir) / ".hydra" / "config.yaml"))
