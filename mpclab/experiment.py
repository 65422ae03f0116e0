"""From a composed config to a run record: build the objects, close the loop, write files."""

from __future__ import annotations

import sys
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from omegaconf import DictConfig, OmegaConf

from mpclab import record
from mpclab.instantiate import build
from mpclab.sim import Run, RunResult, simulate
from mpclab.warm import ComponentCache

CONF_DIR = Path(__file__).resolve().parent.parent / "conf"


def compose(overrides: Sequence[str] = ()) -> DictConfig:
    """The config ``python -m mpclab OVERRIDES...`` runs with (Hydra's compose API)."""
    from hydra import compose as hydra_compose
    from hydra import initialize_config_dir

    from mpclab.registry import register_all

    register_all()
    with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
        return hydra_compose(config_name="config", overrides=list(overrides))


def build_run(
    cfg: DictConfig, out_dir: Path | None = None, cache: ComponentCache | None = None,
) -> Run:
    """Instantiate plant, objective, controller, scenario, supervisor and recorder.

    With a ``cache``, plant, objective and controller are reused from an earlier run of the
    same structure (:mod:`mpclab.warm`).
    """
    rng = np.random.default_rng(cfg.seed)

    def components() -> tuple:
        plant = build(cfg.plant, "plant")
        objective = build(cfg.objective, "objective")
        return plant, objective, build(cfg.controller, "controller", plant=plant,
                                       objective=objective)

    plant, objective, controller = cache.get(cfg, components) if cache else components()
    scenario = build(cfg.scenario, "scenario", plant=plant, rng=rng)
    supervisor = build(cfg.supervisor, "supervisor", plant=plant)
    recorder = build(cfg.recorder, "recorder", out_dir=out_dir, cfg=cfg)
    return Run(plant, controller, scenario, supervisor, recorder)


def run_experiment(
    cfg: DictConfig, out_dir: Path, cache: ComponentCache | None = None,
) -> RunResult:
    """Run the experiment ``cfg`` and write its run record (and figures) into ``out_dir``.

    ``summary["timing"]`` holds the wall seconds of building, the closed loop and writing.
    """
    out_dir = Path(out_dir)
    t0 = time.perf_counter()
    run = build_run(cfg, out_dir, cache)
    progress = _ProgressLine(cfg.name) if cfg.progress and sys.stderr.isatty() else None
    t1 = time.perf_counter()
    try:
        result = simulate(run, progress=progress)
    finally:
        run.recorder.close()
        if progress is not None:
            progress.done()
    t2 = time.perf_counter()
    result.summary = {
        "experiment": cfg.name,
        "plant": getattr(run.plant, "registered_name", type(run.plant).__name__),
        "controller": getattr(run.controller, "registered_name", type(run.controller).__name__),
        "scenario": run.scenario.name,
        "seed": int(cfg.seed),
        **result.summary,
        **run.scenario.metrics(result.steps),
        **run.controller.metrics(result.steps),
        "versions": record.versions(),
    }
    result.summary["timing"] = {"build_s": t1 - t0, "simulate_s": t2 - t1}
    record.write(out_dir, result.steps, result.horizons, result.summary)
    if cfg.figures.enabled:
        from mpclab.recording.figures import plot_run

        plot_run(result, run, out_dir, dpi=cfg.figures.dpi)
    result.summary["timing"]["write_s"] = time.perf_counter() - t2
    return result


class _ProgressLine:
    """A one-line progress display on stderr for an interactive single run."""

    def __init__(self, name: str) -> None:
        self.name = name
        self._last = -1
        self._start = time.perf_counter()

    def __call__(self, t: float, t_max: float) -> None:
        pct = int(100 * t / t_max)
        if pct != self._last:
            self._last = pct
            wall = time.perf_counter() - self._start
            left = wall / t * (t_max - t) if t > 0 else float("nan")  # if it runs to t_max
            sys.stderr.write(
                f"\r{self.name}: t = {t:6.2f} s of at most {t_max:.1f} s"
                f" | elapsed {wall:5.1f} s, at most ~{left:5.1f} s left "
            )
            sys.stderr.flush()

    def done(self) -> None:
        sys.stderr.write("\n")


def resolved_yaml(cfg: DictConfig) -> str:
    return OmegaConf.to_yaml(cfg, resolve=True)
