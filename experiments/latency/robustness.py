"""BUG2 on the dead end with 5 % larger wheels than its model and noisy measurements.

    uv run python experiments/latency/robustness.py

Runs two sweeps of ``+experiment=zumo_bug2 sim.plant_params.r=0.021`` (the controller's
model: 0.020 m): position noise 0.005 and 0.02 m on seeds 0-49, and heading noise 0.02 to
0.2 rad (at 0.005 m of position noise) on seeds 0-29. Each sweep writes its own tables into
``outputs/robustness/<position|heading>``; its ``summary.md`` is copied beside this file as
``robustness_<name>.md``. The page's table, one row per noise level with the exact (Clopper-
Pearson) 95 % interval of the success rate, goes to ``robustness.md`` under its stamp
(command, commit, CPU, date).
"""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pandas as pd

from mpclab.record.provenance import write_stamped

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent.parent
BASE = ["+experiment=zumo_bug2", "sim.plant_params.r=0.021", "recorder=none",
        "figures.enabled=false"]
POSITION = "sim.noise.state_std.position"
HEADING = "sim.noise.state_std.heading"
#: sweep name -> its overrides
SWEEPS = {
    "position": [f"{POSITION}=0.005,0.02", "seed=range(0,50)"],
    "heading": [f"{POSITION}=0.005", f"{HEADING}=0.02,0.05,0.1,0.2", "seed=range(0,30)"],
}


def sweep(name: str, overrides: list[str]) -> pd.DataFrame:
    """Run one sweep; its grouped table with both noise levels as columns."""
    folder = ROOT / "outputs" / "robustness" / name
    shutil.rmtree(folder, ignore_errors=True)
    cmd = [sys.executable, "-m", "mpclab", "-m", *BASE, *overrides,
           f"hydra.sweep.dir={folder}"]
    print(" ".join(cmd[1:]), flush=True)
    subprocess.run(cmd, cwd=ROOT, check=True)
    shutil.copyfile(folder / "summary.md", HERE / f"robustness_{name}.md")
    groups = pd.read_csv(folder / "groups.csv")
    if POSITION not in groups:
        groups[POSITION] = float(overrides[0].split("=")[1])
    if HEADING not in groups:
        groups[HEADING] = 0.0
    return groups


def main() -> None:
    groups = pd.concat([sweep(name, overrides) for name, overrides in SWEEPS.items()])
    table = pd.DataFrame({
        "position noise [m]": groups[POSITION],
        "heading noise [rad]": groups[HEADING],
        "runs": groups["runs"],
        "arrived": groups["arrived"],
        "collisions": groups["collisions"],
        "success rate (95 % interval)": [
            f"{r:.2f} ({lo:.3g}-{hi:.3g})" for r, lo, hi in
            zip(groups["success_rate"], groups["success_low"], groups["success_high"],
                strict=True)],
        "median arrival [s]": groups["arrival_median_s"],
        "smallest clearance [m]": groups["min_clearance_m"].round(4),
        "solves converged / truncated": [
            f"{c} / {t}" for c, t in zip(groups["solves_converged"], groups["solves_truncated"],
                                         strict=True)],
    })
    write_stamped(HERE / "robustness.md", table.to_markdown(index=False), sys.argv)


if __name__ == "__main__":
    main()
