"""``python -m mpclab +experiment=NAME [group=choice ...] [key=value ...]``."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import hydra
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig

from mpclab.registry import register_all

register_all()  # every component's schema must be in the ConfigStore before composing

CONF_DIR = str(Path(__file__).resolve().parent.parent / "conf")
log = logging.getLogger("mpclab")


@hydra.main(config_path=CONF_DIR, config_name="config", version_base="1.3")
def main(cfg: DictConfig) -> None:
    from mpclab.experiment import run_experiment

    out_dir = Path(HydraConfig.get().runtime.output_dir)
    result = run_experiment(cfg, out_dir)
    s = result.summary
    keys = ("status", "arrival_time_s", "n_steps", "compute_median_ms", "rtf", "solver_failures")
    log.info("%s", json.dumps({k: s.get(k) for k in keys}))
    log.info("run record: %s", out_dir)


if __name__ == "__main__":
    main()
