"""The odometry study's table: BUG2 with a 5 % larger wheel, localized by the truth, by
odometry, by odometry with an absolute fix, behind an actuator lag.

One row per world (localization, fix period, actuator time constant) of the run records
found below the given sweep folders: runs, how they ended, the success rate with its exact
(Clopper-Pearson) 95 % interval, the median arrival time of the runs that arrived, the
median over runs of the largest position error of the estimate, and the least clearance.
A second table looks into the runs that did not arrive under odometry: in how many the
estimate met the scenario's arrival rule (from the step log's ``meas_*`` columns) and how far
the robot truly was from the goal then, and the estimate's error at the end.

    uv run python experiments/odometry/table.py outputs/odometry/truth \\
        outputs/odometry/odometry outputs/odometry/lag --md experiments/odometry/results.md

Prints the Markdown tables with their stamp lines (and writes them to ``--md`` when given).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pandas as pd
from omegaconf import OmegaConf

from mpclab import tables
from mpclab.config.instantiate import build
from mpclab.config.registry import register_all
from mpclab.record.provenance import write_stamped
from mpclab.record.stats import clopper_pearson

#: the world of a run: its summary's fields (absent or empty: none)
WORLD = {"localization": "sim_localization", "fix every [s]": "sim_localization_fix.period_s",
         "actuator lag [s]": "sim_actuator.time_constant_s"}


def world_columns(df: pd.DataFrame) -> pd.DataFrame:
    out = pd.DataFrame(index=df.index)
    for label, field in WORLD.items():
        values = df[field] if field in df else pd.Series(None, index=df.index, dtype=object)
        out[label] = values.map(lambda v: "-" if v is None or v != v else f"{v:g}"
                                if isinstance(v, float) else str(v))
    return out


def with_worlds(df: pd.DataFrame) -> pd.DataFrame:
    """``df`` with the :data:`WORLD` columns first, in order: the truth first, then odometry
    without a fix, with one; without a lag, then with one."""
    df = pd.concat([world_columns(df), df], axis=1)
    return df.sort_values(["actuator lag [s]", "localization", "fix every [s]"],
                          key=lambda c: c.map(lambda v: (v not in ("-", "truth"), v)),
                          kind="stable")


def table(df: pd.DataFrame) -> pd.DataFrame:
    rows = []
    for world, g in with_worlds(df).groupby(list(WORLD), sort=False):
        status = g["status"]
        arrived = int((status == "arrived").sum())
        low, high = clopper_pearson(arrived, len(g))
        error = pd.to_numeric(g.get("localization_error_max_m"), errors="coerce")
        arrival = pd.to_numeric(g["arrival_time_s"], errors="coerce").dropna()
        rows.append({
            **dict(zip(WORLD, world, strict=True)),
            "runs": len(g),
            "arrived": arrived,
            "collisions": int((status == "collision").sum()),
            "timeouts": int((status == "timeout").sum()),
            "stalled": int((status == "stalled").sum()),
            "success rate (95 % interval)": f"{arrived / len(g):.2f} ({low:.3g}-{high:.3g})",
            "median arrival [s]": f"{arrival.median():.3g}" if len(arrival) else "-",
            "estimate's largest error, median [m]": (f"{error.median():.3g}"
                                                     if error.notna().any() else "-"),
            "least clearance [m]": float(pd.to_numeric(g["min_clearance_m"]).min()),
        })
    return pd.DataFrame(rows)


def believed_arrival(run_dir: Path) -> tuple[bool, float]:
    """Whether the run's estimate met its scenario's arrival rule, and the robot's true
    distance from the goal (the square root of the rule's weighted squared distance) at the
    first step it did."""
    register_all()  # the components a config may build
    cfg = OmegaConf.load(run_dir / ".hydra" / "config.yaml")
    plant = build(cfg.plant, "plant")
    scenario = build(cfg.scenario, "scenario", plant=plant,
                     rng=np.random.default_rng(int(cfg.seed)))
    steps = pd.read_parquet(run_dir / "steps.parquet").dropna(subset=["meas_x"])
    believed = steps[[f"meas_{s}" for s in plant.states]].to_numpy()
    true = steps[list(plant.states)].to_numpy()
    for x_hat, x in zip(believed, true, strict=True):
        if scenario.arrived(x_hat):
            return True, float(np.sqrt(scenario.arrival_distance(x)))
    return False, float("nan")


def failures(df: pd.DataFrame) -> pd.DataFrame:
    """Per odometry world, the runs that did not arrive (see the module docstring)."""
    df = with_worlds(df)
    rows = []
    for world, g in df[(df["localization"] == "odometry") & (df["status"] != "arrived")
                       ].groupby(list(WORLD), sort=False):
        seen = [believed_arrival(Path(r)) for r in g["run_dir"]]
        gap = np.array([d for ok, d in seen if ok])
        final = pd.to_numeric(g["localization_error_final_m"], errors="coerce")
        rows.append({
            **dict(zip(WORLD, world, strict=True)),
            "not arrived": len(g),
            "estimate arrived": sum(ok for ok, _ in seen),
            "true goal distance then, least / median [m]":
                f"{gap.min():.3g} / {np.median(gap):.3g}" if len(gap) else "-",
            "estimate's error at the end, median (range) [m]":
                f"{final.median():.3g} ({final.min():.3g}-{final.max():.3g})",
        })
    return pd.DataFrame(rows)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("paths", nargs="+", type=Path, help="sweep folders")
    parser.add_argument("--md", type=Path, help="also write the stamped table here")
    args = parser.parse_args()
    runs, _ = tables.collect_runs(args.paths)
    if runs.empty:
        parser.error(f"no run records below {', '.join(map(str, args.paths))}")
    texts = [table(runs).to_markdown(index=False, floatfmt=".3g")]
    failed = failures(runs)
    if not failed.empty:
        texts.append(failed.to_markdown(index=False))
    write_stamped(args.md, texts)


if __name__ == "__main__":
    main()
