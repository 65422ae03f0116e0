"""From nothing to dataset, trained net, DAgger rounds, evaluation table: one command.

    uv run python -m mpclab.approx.pipeline                       # the full study (long)
    uv run python -m mpclab.approx.pipeline --config conf/approx/zumo_nn_smoke.yaml
    uv run python -m mpclab.approx.pipeline train.hidden=[64,64] dagger.rounds=0

Stages (``--stages``, default all, in order):

``data``    a Hydra multirun of the expert experiment (``recorder=dataset``), one job per start
            seed, in parallel with the joblib launcher; merged into ``dataset.parquet``.
``train``   the MLP on the merged rows (:mod:`mpclab.approx.train`).
``dagger``  each round runs the current net from new starts, labels the states it visited
            with the expert, adds them to the data and retrains.
``eval``    NN and expert from the same held-out starts (seeds disjoint from training), and
            the NN on layouts it never saw; tables, figures, exported weights (.npz, .c).

Sweeps resume: a re-run skips jobs whose run record is complete.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from omegaconf import OmegaConf

from mpclab.approx import dataset, evaluate
from mpclab.approx.export_c import c_compiler, time_compiled, to_c
from mpclab.approx.train import TrainConf, require_trainer, train
from mpclab.core.errors import ConfigError, exit_on_bad_input
from mpclab.policy.mlp import MLP
from mpclab.record import files as record
from mpclab.record.files import jsonable
from mpclab.record.provenance import stamp, stamped
from mpclab.runner.single_run import build_run, compose

ROOT = Path(__file__).resolve().parents[2]
STAGES = ("data", "train", "dagger", "eval")


@dataclass
class DataConf:
    experiment: str = "zumo_nn_data"     # the expert, recording rows
    runs: int = 1000                     # the study: 1000 closed-loop runs
    seed0: int = 0
    overrides: list[str] = field(default_factory=list)


@dataclass
class DaggerConf:
    rounds: int = 3
    runs: int = 100                      # net runs per round whose states the expert labels
    seed0: int = 50_000


@dataclass
class EvalConf:
    nn_experiment: str = "zumo_nn"
    starts: int = 200                    # held-out starts (seeds disjoint from training)
    seed0: int = 100_000
    layouts: list[str] = field(default_factory=lambda: ["zumo_wall", "zumo_dead_end"])
    layout_starts: int = 50              # random starts per unseen layout
    figure_pairs: int = 6
    compiled_reps: int = 100             # C calls per visited state when timing the export


@dataclass
class PipelineConf:
    work_dir: str = "outputs/zumo_nn"        # sweeps, datasets, per-round weights
    publish_dir: str = "experiments/zumo_nn"  # C source, tables, figures
    weights_file: str = "conf/weights/zumo_nn.npz"  # the final net, run by +experiment=zumo_nn
    n_jobs: int = -1                          # joblib workers (-1: every core; 1: in-process)
    data: DataConf = field(default_factory=DataConf)
    train: TrainConf = field(default_factory=TrainConf)
    dagger: DaggerConf = field(default_factory=DaggerConf)
    eval: EvalConf = field(default_factory=EvalConf)


def load_conf(path: Path | None, overrides: list[str]) -> PipelineConf:
    """The schema, then the YAML file, then ``key=value`` overrides; typos are errors."""
    conf = OmegaConf.structured(PipelineConf)
    if path is not None:
        conf = OmegaConf.merge(conf, OmegaConf.load(path))
    conf = OmegaConf.merge(conf, OmegaConf.from_dotlist(overrides))
    return OmegaConf.to_object(conf)  # type: ignore[return-value]


def sweep(experiment: str, seeds: range, out: Path, n_jobs: int, extra: list[str]) -> Path:
    """A Hydra multirun of ``experiment`` over ``seeds`` into ``out`` (resumable).

    The experiment's own settings stay (a layout swapped with ``scenario=NAME`` keeps the
    experiment's random start region and time limit).
    """
    # one worker: Hydra's basic launcher runs the jobs in this process, no pool to start
    launcher = ["hydra/launcher=basic"] if n_jobs == 1 else [f"hydra.launcher.n_jobs={n_jobs}"]
    cmd = [
        sys.executable, "-m", "mpclab", "-m", f"+experiment={experiment}",
        f"seed=range({seeds.start},{seeds.stop})", f"hydra.sweep.dir={out}", *launcher,
        "figures.enabled=false", "progress=false", *extra,
    ]
    print("$", " ".join(cmd[1:]), flush=True)
    subprocess.run(cmd, cwd=ROOT, check=True)
    return out


def expert_cfg(conf: PipelineConf, extra: list[str] = ()) -> Any:
    """The expert's composed config (as its sweep jobs see it)."""
    return compose([f"+experiment={conf.data.experiment}", "recorder=none",
                    *conf.data.overrides, *extra])


def label(conf: PipelineConf, visited: pd.DataFrame) -> pd.DataFrame:
    """The expert's input at every visited state, warm-started along each visited run."""
    from mpclab.runner.loop import sense

    run = build_run(expert_cfg(conf))
    plant, ctrl = run.plant, run.controller
    ip = [plant.state_index(s) for s in (*plant.position, plant.heading)]
    out = visited.copy()
    for _, rows in visited.groupby("run", sort=False):
        ctrl.reset(None)
        for i, row in rows.iterrows():
            x = run.scenario.x0.copy()
            x[ip] = row[["x", "y", "theta"]].to_numpy(float)
            step = ctrl.step(float(row["t"]), x, sense(run, float(row["t"]), x))
            out.loc[i, list(plant.inputs)] = step.u
            out.loc[i, "status"] = step.status
            out.loc[i, "fallback"] = step.fallback
    return out


def fit(conf: PipelineConf, data: pd.DataFrame, meta: dict[str, Any]) -> tuple[MLP, dict]:
    p = build_run(expert_cfg(conf)).plant
    mlp, report = train(data, conf.train, list(p.inputs), p.u_lb, p.u_ub, meta)
    return mlp, asdict(report)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(prog="python -m mpclab.approx.pipeline",
                                 description=__doc__.splitlines()[0])
    ap.add_argument("--config", type=Path, default=ROOT / "conf/approx/zumo_nn.yaml")
    ap.add_argument("--stages", default=",".join(STAGES))
    ap.add_argument("overrides", nargs="*", help="KEY=VALUE, e.g. train.hidden=[64,64]")
    args = ap.parse_args(argv)
    try:  # a missing or broken --config, a typo'd or mistyped override
        conf = load_conf(args.config, args.overrides)
    except Exception as exc:  # noqa: BLE001  (bad input is one message; a bug re-raised)
        exit_on_bad_input(ap, exc)
    stages = args.stages.split(",")
    unknown = set(stages) - set(STAGES)
    if unknown:
        ap.error(f"--stages: unknown stage(s) {', '.join(sorted(unknown))}; stages: "
                 f"{', '.join(STAGES)}")
    if {"train", "dagger"} & set(stages):
        try:  # before the data stage's sweep, not after it
            require_trainer()
        except ConfigError as exc:
            exit_on_bad_input(ap, exc)
    work, pub = ROOT / conf.work_dir, ROOT / conf.publish_dir
    published = ROOT / conf.weights_file
    work.mkdir(parents=True, exist_ok=True)
    pub.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    data_path = work / "dataset.parquet"
    dcfg = conf.data
    if "data" in stages:
        sweep(dcfg.experiment, range(dcfg.seed0, dcfg.seed0 + dcfg.runs), work / "data",
              conf.n_jobs, list(dcfg.overrides))
        rep = dataset.merge([work / "data"], data_path)
        print(f"dataset: {rep.rows} rows from {rep.runs} runs, {len(rep.missing)} runs "
              f"without rows, configs {rep.config_hashes}", flush=True)
    data, meta = pd.DataFrame(), {}
    if {"train", "dagger"} & set(stages):  # the evaluation alone needs no dataset
        try:
            data, meta = dataset.read(data_path)
        except FileNotFoundError as exc:  # stages after data, without it
            exit_on_bad_input(ap, exc)
        data["source"] = "expert runs"
    history = []
    weights = work / "weights_round0.npz"
    if "train" in stages:
        mlp, report = fit(conf, data, {"config_hashes": meta.get("config_hashes")})
        mlp.save(weights)
        history.append({"round": 0, "rows": len(data), **report})
        print(f"round 0: {report}", flush=True)
    if "dagger" in stages:
        dg = conf.dagger
        for r in range(1, dg.rounds + 1):
            seeds = range(dg.seed0 + (r - 1) * dg.runs, dg.seed0 + r * dg.runs)
            nn_dir = sweep(conf.eval.nn_experiment, seeds, work / f"dagger{r}", conf.n_jobs,
                           [f"controller.weights={weights}", "recorder=dataset",
                            *dcfg.overrides])
            visited = dataset.read(_merged(nn_dir, work / f"visited{r}.parquet"))[0]
            labelled = label(conf, visited)
            labelled["source"] = f"DAgger round {r}"
            data = pd.concat([data, labelled], ignore_index=True)
            mlp, report = fit(conf, data, {"config_hashes": meta.get("config_hashes"),
                                           "dagger_rounds": r})
            weights = work / f"weights_round{r}.npz"
            mlp.save(weights)
            history.append({"round": r, "rows": len(data), **report})
            print(f"round {r}: {report}", flush=True)
    if history:
        shutil.copy(weights, published)
        (pub / "mpclab_nn.c").write_text(to_c(MLP.load(published)))
        pd.DataFrame(history).to_csv(pub / "training.csv", index=False)
        (pub / "training.md").write_text(stamped(pd.DataFrame(history).to_markdown(index=False)))
    if "eval" in stages:
        run_eval(conf, published, work / "eval", pub)
    print(f"done in {time.perf_counter() - t0:.0f} s; results in {pub}", flush=True)


def _merged(sweep_dir: Path, out: Path) -> Path:
    dataset.merge([sweep_dir], out)
    return out


def time_export(
    conf: PipelineConf, weights: Path, mpc: pd.DataFrame, cmp: evaluate.Comparison
) -> dict[str, Any] | None:
    """The exported C net timed on every state the expert visited in ``mpc``'s runs, against
    the expert's in-loop median; None without a C compiler or with ``compiled_reps: 0``."""
    if conf.eval.compiled_reps <= 0:
        return None
    if c_compiler() is None:
        print("no C compiler: the compiled net is not timed", file=sys.stderr)
        return None
    mlp = MLP.load(weights)
    rows = []
    for d, seed in zip(mpc["dir"], mpc["seed"], strict=True):
        run = build_run(expert_cfg(conf, [f"seed={seed}"]))
        steps = record.read_steps(Path(d)).dropna(subset=["solve_time_s"])
        if len(steps):
            rows.append(evaluate.visited_features(mlp, run, steps[list(run.plant.states)]))
    if not rows:
        return None
    flags = ("-O2",)
    t = time_compiled(mlp, np.concatenate(rows), conf.eval.compiled_reps, flags)
    table = cmp.table.set_index("controller")
    mpc_median = 1e-3 * float(table.loc["MPC expert", "step_median_ms"])
    command = " ".join([Path(c_compiler()).name, "-std=c99", *flags])
    return {"flags": command, "states": sum(len(r) for r in rows),
            "step_median_us": 1e6 * float(np.median(t)),
            "step_p95_us": 1e6 * float(np.percentile(t, 95)),
            "speedup_median": mpc_median / float(np.median(t))}


def run_eval(conf: PipelineConf, weights: Path, work: Path, pub: Path) -> None:
    ev, dcfg = conf.eval, conf.data
    seeds = range(ev.seed0, ev.seed0 + ev.starts)
    nn = [f"controller.weights={weights}", "recorder=none", *dcfg.overrides]
    mpc = evaluate.outcomes(sweep(dcfg.experiment, seeds, work / "mpc", conf.n_jobs,
                                  ["recorder=none", *dcfg.overrides]))
    net = evaluate.outcomes(sweep(ev.nn_experiment, seeds, work / "nn", conf.n_jobs, nn))
    cmp = evaluate.compare(mpc, net, evaluate.StageCost(expert_cfg(conf)))
    lines = ["## Single obstacle, held-out starts", "",
             cmp.table.to_markdown(index=False, floatfmt=".3g"), "",
             f"Per-step time, MPC median / NN median: **{cmp.speedup_median:.0f}x**", ""]
    summary = {"held_out": cmp.table.to_dict("records"), "speedup_median": cmp.speedup_median}
    compiled = time_export(conf, weights, mpc, cmp)
    if compiled is not None:
        lines += [
            f"Per-step time of the compiled net (the exported C, `{compiled['flags']}`, "
            f"timed in C on the {compiled['states']} states the expert visited): median "
            f"{compiled['step_median_us']:.2f} us, p95 {compiled['step_p95_us']:.2f} us; "
            f"MPC median / compiled NN median: **{compiled['speedup_median']:.0f}x**", ""]
        summary["compiled"] = compiled
    lines += [stamp(), ""]
    evaluate.plot_paths(cmp.pairs, expert_cfg(conf), pub / "paths.png", ev.figure_pairs)
    layout_rows = []
    for layout in ev.layouts:
        lseeds = range(ev.seed0 + 10_000, ev.seed0 + 10_000 + ev.layout_starts)
        for name, exp, ov in (("MPC expert", dcfg.experiment, ["recorder=none",
                                                               *dcfg.overrides]),
                              ("NN", ev.nn_experiment, nn)):
            out = evaluate.outcomes(sweep(exp, lseeds, work / f"{layout}_{name[:3].lower()}",
                                          conf.n_jobs, [*ov, f"scenario={layout}"]))
            k = int((out["status"] == "arrived").sum())
            lo, hi = evaluate.clopper_pearson(k, len(out))
            layout_rows.append({"layout": layout, "controller": name, "runs": len(out),
                                "arrived": k, "ci95_low": lo, "ci95_high": hi,
                                "collisions": int((out["status"] == "collision").sum()),
                                "stalled": int((out["status"] == "stalled").sum())})
    if layout_rows:
        lt = pd.DataFrame(layout_rows)
        lines += ["## Layouts the net never saw (random starts)", "",
                  lt.to_markdown(index=False, floatfmt=".3g"), "", stamp(), ""]
        summary["layouts"] = layout_rows
    (pub / "evaluation.md").write_text("\n".join(lines))  # each table under its stamp
    (pub / "evaluation.json").write_text(
        json.dumps(jsonable(summary), indent=2, allow_nan=False, default=str) + "\n"
    )
    cmp.pairs.drop(columns=["dir_mpc", "dir_nn"]).to_csv(pub / "pairs.csv", index=False)
    print("\n".join(lines), flush=True)


if __name__ == "__main__":
    main()
