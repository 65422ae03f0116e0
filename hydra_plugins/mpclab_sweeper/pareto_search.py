"""mpclab's multi-objective search: NSGA-II or TPE (optuna) over a space too big for a grid.

    python -m mpclab -m +experiment=zumo_bug2 +sweep=pareto_zumo_search \
        hydra/sweeper=pareto_search

Each trial asks optuna for one value per searched key (``search_space``, in Hydra's sweep
syntax: ``choice(casadi_fatrop,casadi)``, ``range(6,15,2)``, ``interval(0.02,0.1)``; a sweep
override on the command line joins it; Hydra's ``choice`` takes no null, so ``'null'``
quoted stands for it), runs that point on every seed of ``seeds`` as one
batch of jobs through the sweep's launcher, and tells optuna the point's objectives as the
front computes them (``hydra.callbacks.sweep.pareto.objectives``, each minimized:
:mod:`mpclab.tables.pareto`) with its feasibility as a constraint (every seed arrived, none
collided or failed, none missed a deadline), which both samplers honour. A point none of
whose seeds arrived has no arrival time: its trial is ``FAIL``, finished all the same.

The study lives in ``storage`` (default: SQLite ``optuna.db`` in the sweep folder), so the
same command resumes it: finished trials stay, a trial an interrupt cut short is run again
with its parameters and its job folders (its finished jobs are skipped, as in any sweep), and
the search goes on until ``n_trials`` trials have finished. A point asked again reuses its
job folders (their records are complete, so nothing runs twice). When it ends the multirun callback
writes the front from every trial's runs, as for a grid (:mod:`mpclab.sweeps.pareto`).
Written on Hydra's public ``Sweeper`` interface (Hydra's own optuna sweeper pins optuna < 3);
``conf/hydra/sweeper/pareto_search.yaml`` selects it.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from hydra.core.override_parser.overrides_parser import OverridesParser
from hydra.core.override_parser.types import ChoiceSweep, IntervalSweep, Override, RangeSweep
from hydra.core.plugins import Plugins
from hydra.plugins.launcher import Launcher
from hydra.plugins.sweeper import Sweeper
from hydra.types import HydraContext, TaskFunction
from omegaconf import DictConfig, OmegaConf

from mpclab import tables
from mpclab.core.errors import ConfigError
from mpclab.sweeps.expand import sweep_dir_override
from mpclab.tables.pareto import override_value, pareto_points, parse_objectives

try:  # the `search` extra; without it this module still imports (Hydra scans every plugin)
    import optuna
except ImportError:
    optuna = None


log = logging.getLogger(__name__)
#: where the sweep's config names the front's objectives
OBJECTIVES_KEY = "hydra.callbacks.sweep.pareto.objectives"
STORAGE_FILE = "optuna.db"


class SearchSampler:
    """The samplers: ``nsga2`` (genetic, multi-objective) and ``tpe`` (Bayesian)."""

    nsga2 = "nsga2"
    tpe = "tpe"


def constraint(trial: optuna.trial.FrozenTrial) -> Sequence[float]:
    """Optuna's constraint of a trial: above 0 where its point is infeasible."""
    return trial.user_attrs.get("constraint", [1.0])


class ParetoSearchSweeper(Sweeper):
    """A multi-objective search on optuna, each trial one point on several seeds.

    Parameters
    ----------
    search_space
        ``{key: sweep}``: ``choice(...)``, ``range(start,stop[,step])`` or
        ``interval(lo,hi)`` (``tag(log, interval(...))`` for a log scale).
    seeds
        The seeds (layouts) every point runs on.
    n_trials
        Trials to finish, counting those of an earlier, interrupted run of the same sweep.
    sampler
        ``nsga2`` or ``tpe``.
    sampler_seed
        The sampler's random seed (the same sweep asks the same points).
    population_size
        NSGA-II's population.
    storage
        The study's SQLite file (``sqlite:///PATH``); None: ``optuna.db`` in the sweep folder.
    study_name
        The study's name in the storage.
    """

    def __init__(
        self, search_space: dict[str, str] | None = None, seeds: Sequence[int] = (0, 1, 2, 3, 4),
        n_trials: int = 40, sampler: str = SearchSampler.nsga2, sampler_seed: int = 0,
        population_size: int = 10, storage: str | None = None, study_name: str = "pareto",
    ) -> None:
        super().__init__()
        self.search_space = dict(search_space or {})
        self.seeds = [int(s) for s in seeds]
        self.n_trials = int(n_trials)
        if sampler not in (SearchSampler.nsga2, SearchSampler.tpe):
            raise ConfigError(f"hydra.sweeper.sampler must be nsga2 or tpe, got {sampler!r}")
        if not self.seeds or self.n_trials < 1:
            raise ConfigError(f"hydra.sweeper: seeds must not be empty and n_trials >= 1 (got "
                              f"seeds={self.seeds}, n_trials={self.n_trials})")
        self.sampler, self.sampler_seed = sampler, int(sampler_seed)
        self.population_size = int(population_size)
        if storage is not None and not str(storage).startswith("sqlite:///"):
            raise ConfigError(f"hydra.sweeper.storage must be null or sqlite:///PATH (a file "
                              f"of the study), got {storage!r}")
        self.storage, self.study_name = storage, study_name
        self.config: DictConfig | None = None
        self.launcher: Launcher | None = None
        self.hydra_context: HydraContext | None = None

    def setup(self, *, hydra_context: HydraContext, task_function: TaskFunction,
              config: DictConfig) -> None:
        if optuna is None:
            raise ConfigError("hydra/sweeper=pareto_search needs optuna: uv sync --extra search")
        self.hydra_context, self.config = hydra_context, config
        self.launcher = Plugins.instance().instantiate_launcher(
            hydra_context=hydra_context, task_function=task_function, config=config)

    def sweep(self, arguments: list[str]) -> None:
        assert self.config is not None and self.launcher is not None
        assert self.hydra_context is not None
        objectives = parse_objectives(OmegaConf.select(self.config, OBJECTIVES_KEY),
                                      OBJECTIVES_KEY)
        parser = OverridesParser.create(config_loader=self.hydra_context.config_loader)
        lines = [f"{k}={v}" for k, v in self.search_space.items()] + list(arguments)
        space: dict[str, optuna.distributions.BaseDistribution] = {}
        fixed: list[str] = []
        for ov in parser.parse_overrides(lines):
            if ov.is_sweep_override():
                space[ov.get_key_element()] = distribution(ov)
            else:
                fixed.append(ov.input_line)
        if not space:
            raise ConfigError("hydra.sweeper.search_space is empty: name at least one key "
                              "to search (e.g. controller.horizon: range(6,15,2))")
        sweep_dir = Path(str(self.config.hydra.sweep.dir))
        sweep_dir.mkdir(parents=True, exist_ok=True)
        OmegaConf.save(self.config, sweep_dir / "multirun.yaml")
        study = self._study(sweep_dir, len(objectives))
        finished = self._resume(study)
        log.info("pareto search: %d of %d trials finished in %s", finished, self.n_trials,
                 sweep_dir)
        while finished < self.n_trials:
            trial = study.ask(space)
            start = trial.user_attrs.get("first_job", _same_point(study, trial))
            if start is None:  # a new point: new job folders
                start = int(study.user_attrs.get("next_job", 0))
                study.set_user_attr("next_job", start + len(self.seeds))
            trial.set_user_attr("first_job", start)
            point = [f"{k}={override_value(v)}" for k, v in trial.params.items()]
            batch = [[*fixed, *point, f"seed={s}", sweep_dir_override(sweep_dir)]
                     for s in self.seeds]
            self.launcher.launch(batch, initial_job_idx=start)
            self._tell(study, trial, objectives, [sweep_dir / str(start + i)
                                                  for i in range(len(self.seeds))])
            finished += 1
            log.info("pareto search: trial %d (%s) done, %d of %d", trial.number,
                     " ".join(point), finished, self.n_trials)

    def _study(self, sweep_dir: Path, n_objectives: int) -> optuna.Study:
        if self.sampler == SearchSampler.nsga2:
            sampler = optuna.samplers.NSGAIISampler(
                population_size=self.population_size, seed=self.sampler_seed,
                constraints_func=constraint)
        else:
            sampler = optuna.samplers.TPESampler(seed=self.sampler_seed,
                                                 constraints_func=constraint)
        storage = self.storage or f"sqlite:///{(sweep_dir / STORAGE_FILE).resolve()}"
        optuna.logging.set_verbosity(optuna.logging.WARNING)
        return optuna.create_study(storage=storage, study_name=self.study_name,
                                   sampler=sampler, directions=["minimize"] * n_objectives,
                                   load_if_exists=True)

    @staticmethod
    def _resume(study: optuna.Study) -> int:
        """Queue again the trials an interrupt cut short (with their job folders); return
        how many trials have finished (an interrupted one is not)."""
        for t in study.get_trials(deepcopy=False, states=(optuna.trial.TrialState.RUNNING,)):
            study.tell(t.number, state=optuna.trial.TrialState.FAIL)
            attrs = {"rerun_of": t.number}
            if "first_job" in t.user_attrs:
                attrs["first_job"] = t.user_attrs["first_job"]
            study.enqueue_trial(t.params, user_attrs=attrs)
        trials = study.get_trials(deepcopy=False)
        cut = {t.user_attrs["rerun_of"] for t in trials if "rerun_of" in t.user_attrs}
        return sum(1 for t in trials if t.number not in cut
                   and t.state in (optuna.trial.TrialState.COMPLETE, optuna.trial.TrialState.FAIL))

    @staticmethod
    def _tell(study: optuna.Study, trial: optuna.Trial, objectives: Sequence[Any],
              run_dirs: list[Path]) -> None:
        """The point's objectives and feasibility, from its runs' records."""
        df, step_ms = tables.collect_runs([d for d in run_dirs if d.exists()])
        row = pareto_points(df, objectives, step_ms).iloc[0] if len(df) else None
        if row is None:
            study.tell(trial, state=optuna.trial.TrialState.FAIL)
            return
        bad = row["runs"] - row["arrived"] + row["deadline_misses"]
        trial.set_user_attr("constraint", [float(bad)])
        trial.set_user_attr("overrides", " ".join(f"{k}={override_value(v)}"
                                                  for k, v in trial.params.items()))
        values = [float(row[o.value]) for o in objectives]
        if all(math.isfinite(v) for v in values):
            study.tell(trial, values)
        else:  # no seed arrived: no arrival time to tell
            study.tell(trial, state=optuna.trial.TrialState.FAIL)


def _same_point(study: optuna.Study, trial: optuna.Trial) -> int | None:
    """The first job of a finished trial of the same point (asked again: its jobs are
    complete and skip, so the point is not run twice), or None."""
    done = (optuna.trial.TrialState.COMPLETE, optuna.trial.TrialState.FAIL)
    for t in study.get_trials(deepcopy=False, states=done):
        if t.params == trial.params and "first_job" in t.user_attrs:
            return int(t.user_attrs["first_job"])
    return None


def distribution(ov: Override) -> optuna.distributions.BaseDistribution:
    """The optuna distribution of a sweep override (choice, range or interval)."""
    value = ov.value()
    key = ov.get_key_element()
    if isinstance(value, ChoiceSweep):
        return optuna.distributions.CategoricalDistribution(
            [_plain(v, key) for v in value.list])
    if isinstance(value, RangeSweep) and not value.shuffle:
        start, stop, step = value.start, value.stop, value.step
        if all(float(v).is_integer() for v in (start, stop, step)):
            return optuna.distributions.IntDistribution(int(start), int(stop - step),
                                                        step=int(step))
        return optuna.distributions.FloatDistribution(start, stop, step=step)
    if isinstance(value, IntervalSweep):
        log_scale = "log" in (value.tags or set())
        return optuna.distributions.FloatDistribution(float(value.start), float(value.end),
                                                      log=log_scale)
    raise ConfigError(f"hydra.sweeper.search_space.{key}: {ov.input_line!r} is not a "
                      "choice(...), range(...) or interval(...)")


def _plain(value: Any, key: str) -> Any:
    """A choice as optuna stores it: None, a bool, a number or a string (a list as its
    override text)."""
    if value is None or isinstance(value, bool | int | float | str):
        return value
    return override_value(value)
