"""The paths of a BARN sweep on a grid of worlds: each world's cylinders, start, goal, success
circle and the robot's path, coloured by how the run ended, with its score.

    uv run python experiments/barn/figure.py SWEEP_DIR --barn-dir DIR --out FILE.png

``SWEEP_DIR`` is a sweep over ``scenario.world`` (``+sweep=barn_train``; ``--experiment``
picks one of several in it); ``--worlds`` picks the worlds (default: twelve, up to half of
them failures, spread over the sweep's). The figure's caption is the script's stamp (command,
commit, CPU, date), printed and written beside it as ``FILE.md``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from mpclab.plants.zumo import Zumo  # noqa: E402
from mpclab.record.provenance import write_stamped  # noqa: E402
from mpclab.world.barn import SUCCESS_RADIUS, BarnScenario  # noqa: E402

COLOURS = {"arrived": "tab:green", "collision": "tab:red", "timeout": "tab:orange",
           "stalled": "tab:purple"}


def pick(df: pd.DataFrame, n: int) -> list[int]:
    """``n`` worlds of the sweep: up to half of them failures (spread over the failed ones),
    the rest spread over the worlds it arrived in."""
    failed = sorted(set(df.loc[df["status"] != "arrived", "scenario.world"].astype(int)))
    rest = sorted(set(df["scenario.world"].astype(int)) - set(failed))

    def spread(worlds: list[int], k: int) -> list[int]:
        k = min(k, len(worlds))
        return [worlds[i] for i in np.linspace(0, len(worlds) - 1, k).astype(int)] if k else []

    lost = spread(failed, n // 2)
    return sorted(lost + spread(rest, n - len(lost)))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("sweep", type=Path)
    parser.add_argument("--barn-dir", required=True)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--worlds", type=int, nargs="*")
    parser.add_argument("--count", type=int, default=12)
    parser.add_argument("--experiment", help="the runs of this experiment only")
    args = parser.parse_args()
    df = pd.read_parquet(args.sweep / "summary.parquet")
    if args.experiment:
        df = df[df["experiment"] == args.experiment]
        if df.empty:
            parser.error(f"--experiment {args.experiment}: no run of it in {args.sweep}")
    if "seed" in df:  # one run per world: the first seed's
        df = df.sort_values("seed").drop_duplicates("scenario.world")
    worlds = args.worlds or pick(df, args.count)
    plant = Zumo()
    cols = 6
    rows = -(-len(worlds) // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(2.1 * cols, 3.6 * rows), squeeze=False)
    for ax in axes.ravel():
        ax.set_axis_off()
    for ax, world in zip(axes.ravel(), worlds, strict=False):
        run = df.loc[df["scenario.world"].astype(int) == world].iloc[0]
        scen = BarnScenario(plant, barn_dir=args.barn_dir, world=world,
                            scale=float(run["barn_scale"]), top_speed=float(run["barn_top_speed"]))
        steps = pd.read_parquet(Path(run["run_dir"]) / "steps.parquet")
        for x, y, r in scen.obstacles:
            ax.add_patch(plt.Circle((x, y), r, color="0.25", lw=0))
        ax.plot(scen.path[:, 0], scen.path[:, 1], ":", color="0.5", lw=0.8)
        ax.plot(steps["x"], steps["y"], color=COLOURS.get(run["status"], "k"), lw=1.4)
        gx, gy = scen.goal[:2]
        ax.add_patch(plt.Circle((gx, gy), scen.barn_scale * SUCCESS_RADIUS, fill=False,
                                ls="--", color="0.4", lw=0.8))
        ax.plot(*scen.x0[:2], "o", color="k", ms=3)
        ax.set_xlim(scen.extent[0], scen.extent[1])
        ax.set_ylim(scen.extent[2], scen.extent[3])
        ax.set_aspect("equal")
        ax.set_axis_on()
        ax.set_xticks([])
        ax.set_yticks([])
        ax.set_title(f"world {world}: {run['status']}\nscore {float(run['barn_score']):.2f}",
                     fontsize=8)
    handles = [plt.Line2D([], [], color=c, label=s) for s, c in COLOURS.items()]
    handles.append(plt.Line2D([], [], color="0.5", ls=":", label="A* path"))
    fig.legend(handles=handles, loc="lower center", ncol=len(handles), fontsize=8)
    fig.tight_layout(rect=(0, 0.04, 1, 1))
    args.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=110)
    write_stamped(args.out.with_suffix(".md"), f"![paths]({args.out.name})")


if __name__ == "__main__":
    main()
