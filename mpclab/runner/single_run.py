"""From a composed config to a run record: build the objects, close the loop, write files."""

from __future__ import annotations

import logging
import sys
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from omegaconf import DictConfig, OmegaConf

from mpclab.config.allowed_targets import check_config
from mpclab.config.instantiate import build
from mpclab.config.key_origin import RunOrigin, where_set
from mpclab.config.registry import require_registered
from mpclab.config.root import CONF_DIR
from mpclab.constraints.obstacle import ObstacleDistance
from mpclab.core.errors import ConfigError, number
from mpclab.core.status import PROBLEM_KEY
from mpclab.record import files as record
from mpclab.runner.component_cache import ComponentCache
from mpclab.runner.loop import Run, RunInterrupted, RunResult, simulate
from mpclab.runner.progress import RunProgress
from mpclab.world import margin
from mpclab.world.zumo_world import ObstacleScenario

log = logging.getLogger("mpclab")


def compose(overrides: Sequence[str] = (), config_dir: str | Path | None = None) -> DictConfig:
    """The config ``python -m mpclab OVERRIDES...`` runs with (Hydra's compose API).

    ``config_dir``: a folder of the user's own configs (``experiment/``, ``scenario/``, ...),
    searched after mpclab's, as ``-cd DIR`` on the command line.
    """
    from hydra import compose as hydra_compose
    from hydra import initialize_config_dir

    from mpclab.config.registry import register_all

    register_all()
    extra = [] if config_dir is None else [
        f"hydra.searchpath=[file://{Path(config_dir).expanduser().resolve()}]"]
    with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
        return hydra_compose(config_name="config", overrides=[*extra, *overrides])


def run(cfg: DictConfig, out_dir: str | Path | None = None,
        cache: ComponentCache | None = None) -> RunResult:
    """Run the experiment ``cfg`` (from :func:`compose`) and write its run record.

    ``out_dir`` defaults to ``outputs/<name>/<date>_<time>`` below the working directory, as
    for ``python -m mpclab``. The result holds the step log (``steps``), every predicted
    horizon (``horizons``) and the summary (``summary``). ``cache``: a
    :class:`~mpclab.runner.component_cache.ComponentCache` kept between calls reuses plant,
    objective and controller across runs of the same structure (seeds of one experiment).
    """
    if out_dir is None:
        out_dir = Path("outputs") / str(cfg.name) / time.strftime("%Y-%m-%d_%H-%M-%S")
        suffix, base = 1, out_dir
        while out_dir.exists():
            out_dir, suffix = base.with_name(f"{base.name}_{suffix}"), suffix + 1
    return run_experiment(cfg, Path(out_dir), cache)


def build_run(
    cfg: DictConfig, out_dir: Path | None = None, cache: ComponentCache | None = None,
    origin: RunOrigin | None = None,
) -> Run:
    """Instantiate plant, objective, scenario, supervisor, sim world, controller, recorder.

    Every ``_target_`` in ``cfg`` is checked first
    (:func:`mpclab.config.allowed_targets.check_config`: only registered components are built). The
    controller comes after the others but the recorder: it is the expensive one to build (a CasADi
    NLP compiles), so bad input anywhere else is refused before it. With a ``cache``, plant,
    objective and controller are reused from an earlier run of the same structure
    (:mod:`mpclab.runner.component_cache`). With the run's ``origin`` (Hydra's choices and command
    line), a bad-input message also says which file or override set the key it names.
    """
    try:
        return _build_run(cfg, out_dir, cache)
    except ConfigError as exc:  # say which file (or override) set the key it names
        where = where_set(cfg, str(exc), CONF_DIR, origin)
        if not where:
            raise
        raise ConfigError(f"{exc}{where}") from exc


def _build_run(cfg: DictConfig, out_dir: Path | None, cache: ComponentCache | None) -> Run:
    check_config(cfg)  # the whole tree, before anything in it is built
    if cfg.seed < 0:
        raise ConfigError(f"seed: expected an integer >= 0, got {cfg.seed}")
    rng = np.random.default_rng(cfg.seed)
    dt = number(cfg.controller.dt, "controller.dt", above=0)
    plant = (cache.plant(cfg) if cache is not None else None) or build(cfg.plant, "plant")
    scenario = build(cfg.scenario, "scenario", plant=plant, rng=rng)
    world = build(cfg.sim, "sim", plant=plant, seed=int(cfg.seed), dt=dt)
    # the obstacle margin from the world's stated bounds, before the controller that keeps it
    budget = (margin.derive(plant, scenario, world, dt)
              if isinstance(scenario, ObstacleScenario) and _keeps_a_margin(cfg) else None)
    reused = cache.lookup(cfg, budget) if cache is not None else None
    if reused is not None:
        objective, controller = reused
    else:
        objective = build(cfg.objective, "objective")
    obstacles = [c for c in objective.constraints.values() if isinstance(c, ObstacleDistance)]
    no_room = None
    for con in obstacles:
        if budget is not None:
            con.keep(budget)
            no_room = margin.check_room(scenario, con.distance, con.budget, con.no_room,
                                        int(cfg.seed))
    if no_room:
        log.warning("%s", no_room)
    supervisor = build(cfg.supervisor, "supervisor", plant=plant, objective=objective)
    if reused is None:
        controller = build(cfg.controller, "controller", plant=plant, objective=objective,
                           scenario=scenario)
        if cache is not None:
            cache.store(cfg, budget, plant, (objective, controller))
    # the input filter (+safety_filter=cbf), set on every run: a reused controller too
    sf = cfg.get("safety_filter")
    controller.safety_filter = build(sf, "safety_filter", plant=plant) if sf else None
    if controller.safety_filter is not None and budget is not None:
        controller.safety_filter.keep(budget)
    filter_cols = ("safety_filter", "safety_filter_shortfall")
    cols = tuple(c for c in controller.log_columns if c not in filter_cols)
    controller.log_columns = (*cols, *filter_cols) if sf else cols
    recorder = build(cfg.recorder, "recorder", out_dir=out_dir, cfg=cfg)
    keeper = next(iter(obstacles), controller.safety_filter)  # what keeps the margin
    kept = budget if keeper is not None else None
    return Run(plant, controller, scenario, supervisor, recorder, world, kept, no_room, keeper)


def _keeps_a_margin(cfg: DictConfig) -> bool:
    """Whether the run keeps an obstacle margin: an obstacle distance constraint in the
    objective, or a safety filter."""
    if cfg.get("safety_filter"):
        return True
    constraints = cfg.objective.get("constraints") or {}
    targets = [require_registered(node["_target_"], f"objective.constraints.{name}")
               for name, node in constraints.items()
               if isinstance(node, DictConfig) and "_target_" in node]
    return any(isinstance(t, type) and issubclass(t, ObstacleDistance) for t in targets)


def run_experiment(
    cfg: DictConfig, out_dir: Path, cache: ComponentCache | None = None,
    origin: RunOrigin | None = None,
) -> RunResult:
    """Run the experiment ``cfg`` and write its run record (and figures) into ``out_dir``.

    ``summary["timing"]`` holds the wall seconds of building, the closed loop and writing.
    Ctrl-C during the loop writes the record of the steps so far (status ``interrupted``)
    and raises :class:`~mpclab.runner.loop.RunInterrupted` (a ``KeyboardInterrupt``) again. The
    record is written before the recording is closed and the figures drawn; a folder that
    cannot take one of them (full, read-only) is an ``OSError`` naming it.
    """
    out_dir = Path(out_dir)
    t0 = time.perf_counter()
    run = build_run(cfg, out_dir, cache, origin)
    progress = RunProgress(cfg.name, live=sys.stderr.isatty()) if cfg.progress else None
    interrupted = None
    t1 = time.perf_counter()
    try:
        result = simulate(run, progress=progress)
    except RunInterrupted as exc:
        result, interrupted = exc.result, exc
    except BaseException:
        run.recorder.close()
        raise
    finally:
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
        **run.scenario.metrics(result.steps, result.summary),
        **run.controller.metrics(result.steps),
        **(run.controller.safety_filter.metrics(result.steps)
           if run.controller.safety_filter is not None else {}),
        **(run.controller.blocking.summary() if run.controller.blocking else {}),
        PROBLEM_KEY: getattr(run.controller.solved_problem, "value", None),
        # the obstacle margin's parts (mpclab.world.margin), and why there was no room
        "margin": _margin_record(run),
        "margin_no_room": run.no_room,
        "versions": record.versions(),
    }
    result.summary["timing"] = {"build_s": t1 - t0, "simulate_s": t2 - t1}
    # the record first: a full disk costs the recording or the figures, not the record
    try:
        record.write(out_dir, result.steps, result.horizons, result.summary)
    except BaseException:
        run.recorder.close()
        raise
    with record.writing(out_dir, "the recording (the run record is written)"):
        run.recorder.close()
    if interrupted is not None:
        raise interrupted
    if cfg.figures.enabled:
        from mpclab.record.figures import plot_run

        with record.writing(out_dir, "the figures (the run record is written)"):
            plot_run(result, run, out_dir, dpi=cfg.figures.dpi)
    result.summary["timing"]["write_s"] = time.perf_counter() - t2
    return result


def _margin_record(run: Run) -> dict | None:
    """The summary's ``margin``: the derived budget's parts, and the distance the obstacle
    constraint (else the safety filter) kept: the derived total, or one stated by hand."""
    if run.margin is None or run.keeper is None:
        return None
    return {**run.margin.describe(), "kept_m": run.keeper.distance,
            "stated": bool(run.keeper.stated)}


def resolved_yaml(cfg: DictConfig) -> str:
    return OmegaConf.to_yaml(cfg, resolve=True)
