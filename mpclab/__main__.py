"""``python -m mpclab +experiment=NAME [group=choice ...] [key=value ...]``."""

from __future__ import annotations

import json
import logging
import os
from pathlib import Path

import hydra
from hydra.core.hydra_config import HydraConfig
from hydra.types import RunMode
from omegaconf import DictConfig

from mpclab.registry import register_all
from mpclab.status import SOLVE_KEYS, SolveStatus

register_all()  # every component's schema must be in the ConfigStore before composing
# Ray (hydra/launcher=ray_cluster) would otherwise re-create a driver started by `uv run` in
# a new virtual environment per worker, without the `ray` extra; workers use this Python.
os.environ.setdefault("RAY_ENABLE_UV_RUN_RUNTIME_ENV", "0")

CONF_DIR = str(Path(__file__).resolve().parent.parent / "conf")
log = logging.getLogger("mpclab")


@hydra.main(config_path=CONF_DIR, config_name="config", version_base="1.3")
def main(cfg: DictConfig) -> dict:
    """One run; in a multirun, one job that resumes or records its error as a row."""
    from mpclab.experiment import run_experiment

    hc = HydraConfig.get()
    out_dir = Path(hc.runtime.output_dir)
    if hc.runtime.choices.get("experiment") is None:
        names = sorted(p.stem for p in (Path(CONF_DIR) / "experiment").glob("*.yaml"))
        log.warning("no +experiment=NAME given: running the bare defaults (Study A's car "
                    "without its terminal constraint). Experiments: %s", ", ".join(names))
    if hc.mode == RunMode.MULTIRUN:
        from mpclab.sweeps.jobs import run_job

        s = run_job(cfg, out_dir, list(hc.overrides.task), dict(hc.runtime.choices))
    else:
        s = run_experiment(cfg, out_dir).summary
    keys = ("status", "arrival_time_s", "n_steps", "compute_median_ms", "rtf", "solver_failures",
            "converged_fraction")
    line = {k: s.get(k) for k in keys}
    # every solve that did not converge, by what it did (truncated, infeasible, failed, ...)
    line |= {key: s[key] for st, key in SOLVE_KEYS.items()
             if st is not SolveStatus.converged and s.get(key)}
    if s.get("deadline_misses"):  # sim latency: inputs that came too late to act
        line["deadline_misses"] = s["deadline_misses"]
    log.info("%s", json.dumps(line))
    log.info("run record: %s", out_dir)
    return s


if __name__ == "__main__":
    main()
