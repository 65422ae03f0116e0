"""NN against its MPC expert from the same starts: outcomes, costs, per-step times, figures.

Both sides are sweeps over the same seeds (a seed fixes the random start), so run ``i`` of
one and run ``i`` of the other start from the same pose in the same world.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import casadi as ca
import numpy as np
import pandas as pd
from omegaconf import OmegaConf

from mpclab.approx.dataset import run_dirs
from mpclab.objectives.base import TermContext
from mpclab.policy.features import features
from mpclab.record import files as record
from mpclab.record.stats import clopper_pearson
from mpclab.runner.single_run import build_run


def outcomes(sweep: Path) -> pd.DataFrame:
    """One row per run of a sweep: seed, status, arrival time, clearance, folder."""
    rows = []
    for d in run_dirs([sweep]):
        seed = int(OmegaConf.load(d / ".hydra" / "config.yaml").seed)
        try:
            s = record.read_summary(d)
        except FileNotFoundError:
            s = {"status": "error", "error": "no summary.json"}
        except ValueError as exc:
            s = {"status": "error", "error": f"unreadable summary.json: {exc}"}
        rows.append({
            "seed": seed, "status": s.get("status"), "arrival_time_s": s.get("arrival_time_s"),
            "min_clearance_m": s.get("min_clearance_m"), "n_steps": s.get("n_steps"),
            "dir": str(d),
        })
    return pd.DataFrame(rows).sort_values("seed").reset_index(drop=True)


def visited_features(mlp: Any, run: Any, states: np.ndarray) -> np.ndarray:
    """The net's input rows at ``states`` ``(N, nx)`` of ``run``'s plant, each sensed in
    ``run``'s scenario (its sensor and obstacles) with its goal."""
    plant, scen = run.plant, run.scenario
    ip = [plant.state_index(s) for s in (*plant.position, plant.heading)]
    states = np.atleast_2d(np.asarray(states, dtype=float))
    ranges = np.array([scen.sense(x)[1] for x in states])
    goal = np.tile(np.asarray(scen.goal, dtype=float)[ip], (len(states), 1))
    return features(mlp.meta.get("features", "study"), states[:, ip], goal, ranges,
                    mlp.meta.get("min_range", 0.05))


def step_times(dirs: list[str]) -> np.ndarray:
    """Every controller call's measured time [s] over the runs in ``dirs``."""
    times = [record.read_steps(Path(d))["solve_time_s"].dropna().to_numpy() for d in dirs]
    return np.concatenate(times) if times else np.zeros(0)


class StageCost:
    """The expert's objective evaluated on a closed-loop trajectory, one stage per step.

    Stage ``k`` is the objective over a one-step horizon ``X = [x_k, x_k+1]``, ``U = [u_k]``
    with the detections seen at ``x_k``: what the expert charges for the step actually taken,
    less what it charges for a step resting at the goal with nothing in sight. The offset
    makes every stage >= 0 (J1 is ``-C1 exp(-d/L1)``, negative, so a raw sum would reward
    slow runs for their many steps); it changes no optimum.
    """

    def __init__(self, expert_cfg: Any, max_detections: int = 20) -> None:
        self.run = build_run(expert_cfg)
        plant, obj = self.run.plant, self.run.controller.objective
        nx, nu, M = plant.nx, plant.nu, max_detections
        X, U = ca.SX.sym("X", nx, 2), ca.SX.sym("U", nu, 1)
        goal, det, mask = ca.SX.sym("goal", nx), ca.SX.sym("det", 2, M), ca.SX.sym("mask", M)
        p = TermContext(x0=X[:, 0], goal=goal, target=ca.repmat(goal, 1, 2),
                        u_prev=ca.DM.zeros(nu), detections=det, mask=mask)
        cost = sum(term.casadi_cost(X, U, p) for term in obj)
        self.f = ca.Function("stage", [X, U, goal, det, mask], [cost])
        self.M = M
        self._ip = [plant.state_index(s) for s in plant.position]
        g = self.run.scenario.goal
        self._rest = float(self.f(np.column_stack([g, g]), np.zeros(nu), g,
                                  np.zeros((2, M)) + 1e3, np.zeros(M)))

    def __call__(self, steps: pd.DataFrame) -> float:
        plant, scen = self.run.plant, self.run.scenario
        xs = steps[list(plant.states)].to_numpy(float)
        us = steps[list(plant.inputs)].to_numpy(float)
        total = 0.0
        for k in range(len(steps) - 1):  # the last row is the final state
            det = scen.detect(xs[k])[: self.M]
            pad = np.tile(xs[k][self._ip] + 1e3, (self.M, 1))
            pad[: len(det)] = det
            mask = np.zeros(self.M)
            mask[: len(det)] = 1.0
            X = np.column_stack([xs[k], xs[k + 1]])
            total += float(self.f(X, us[k], scen.goal, pad.T, mask)) - self._rest
        return total


@dataclass
class Comparison:
    table: pd.DataFrame          # one row per controller
    pairs: pd.DataFrame          # one row per start: both outcomes and costs
    speedup_median: float        # MPC median per-step time / NN median per-step time


def compare(mpc: pd.DataFrame, nn: pd.DataFrame, cost: StageCost | None) -> Comparison:
    """Success, collisions, arrival, cost ratio and per-step time, NN against MPC."""
    pairs = mpc.merge(nn, on="seed", suffixes=("_mpc", "_nn"))
    rows, medians = [], {}
    for name, df in (("MPC expert", mpc), ("NN", nn)):
        n = len(df)
        k = int((df["status"] == "arrived").sum())
        lo, hi = clopper_pearson(k, n)
        t = step_times(list(df["dir"]))
        medians[name] = float(np.median(t)) if len(t) else float("nan")
        rows.append({
            "controller": name, "runs": n, "arrived": k, "success_rate": k / n if n else None,
            "ci95_low": lo, "ci95_high": hi,
            "collisions": int((df["status"] == "collision").sum()),
            "stalled": int((df["status"] == "stalled").sum()),
            "timeouts": int((df["status"] == "timeout").sum()),
            "arrival_median_s": df.loc[df["status"] == "arrived", "arrival_time_s"].median(),
            "step_median_ms": 1e3 * medians[name],
            "step_p95_ms": 1e3 * float(np.percentile(t, 95)) if len(t) else None,
        })
    both = (pairs["status_mpc"] == "arrived") & (pairs["status_nn"] == "arrived")
    if cost is not None and both.any():
        for side in ("mpc", "nn"):
            pairs.loc[both, f"cost_{side}"] = [
                cost(record.read_steps(Path(d))) for d in pairs.loc[both, f"dir_{side}"]
            ]
        ratio = pairs.loc[both, "cost_nn"] / pairs.loc[both, "cost_mpc"]
        rows[1]["cost_ratio_median"] = float(ratio.median())
        rows[1]["both_arrived"] = int(both.sum())
    return Comparison(pd.DataFrame(rows), pairs, medians["MPC expert"] / medians["NN"])


def plot_paths(pairs: pd.DataFrame, expert_cfg: Any, out: Path, n: int = 6) -> Path:
    """NN (red) and MPC (blue) paths from the same starts over the expert's world."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    run = build_run(expert_cfg)
    px, py = run.plant.position
    fig, ax = plt.subplots(figsize=(6.4, 6.4))
    run.scenario.draw(ax)
    for i, row in enumerate(pairs.head(n).itertuples()):
        for side, color in (("mpc", "tab:blue"), ("nn", "tab:red")):
            s = record.read_steps(Path(getattr(row, f"dir_{side}")))
            label = {"mpc": "MPC expert", "nn": "NN"}[side] if i == 0 else None
            ax.plot(s[px], s[py], "-", color=color, lw=1.4, label=label)
        ax.plot(s[px].iloc[0], s[py].iloc[0], "o", color="k", ms=4)
    g = run.scenario.goal
    ax.plot(g[run.plant.state_index(px)], g[run.plant.state_index(py)], "x", color="k",
            ms=10, mew=2, label="goal")
    ax.set_aspect("equal")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="upper right", fontsize=8)
    ax.set_title("NN and MPC expert from the same starts")
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out
