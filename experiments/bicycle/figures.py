"""Figures of the Study C benchmark, drawn from the run records ``bench.py`` wrote.

    uv run python experiments/bicycle/figures.py    # redraw from outputs/bicycle_bench/
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent.parent
from mpclab.runner.single_run import build_run  # noqa: E402
from mpclab.runner.single_run import compose as compose_cfg  # noqa: E402

SCENARIOS = ("control_y_V", "regular_circle_turn", "turn")
MODES = ("switched", "interpolated", "adaptive")
COLORS = {"switched": "tab:red", "interpolated": "tab:blue", "adaptive": "tab:green"}
DELTA_MAX = np.radians(30)


def reference(scenario: str) -> pd.DataFrame:
    cfg = compose_cfg(["+experiment=bicycle_scheduled", f"scenario={scenario}",
                       "recorder=none"])
    return build_run(cfg).scenario.reference_table()


def load(root: Path, scenario: str, mode: str, dt: float) -> pd.DataFrame:
    return pd.read_parquet(root / f"{scenario}_{mode}_{dt}" / "steps.parquet")


def switch_times(steps: pd.DataFrame) -> np.ndarray:
    calls = steps[steps["status"] != "final"]
    op = pd.to_numeric(calls["op"]).to_numpy()
    return calls["t"].to_numpy()[1:][op[1:] != op[:-1]]


def response(root: Path, scenario: str, out: Path, dt: float = 0.02) -> Path:
    """y and V with their references, and both inputs, for the three modes; switches of the
    switched mode marked by dotted lines."""
    ref = reference(scenario)
    fig, axes = plt.subplots(4, 1, figsize=(8, 9), sharex=True)
    rows = [("py", "y [m]"), ("V", "V [m/s]"), ("delta", "delta [rad]"), ("a", "a [m/s^2]")]
    for mode in MODES:
        steps = load(root, scenario, mode, dt)
        for ax, (col, _) in zip(axes, rows, strict=True):
            if col in ("delta", "a"):
                ax.step(steps["t"], steps[col], where="post", color=COLORS[mode], lw=1.1,
                        label=mode)
            else:
                ax.plot(steps["t"], steps[col], color=COLORS[mode], lw=1.3, label=mode)
        if mode == "switched":
            for ts in switch_times(steps):
                for ax in axes:
                    ax.axvline(ts, color="tab:red", ls=":", lw=1.0)
    t_end = load(root, scenario, "switched", dt)["t"].max()
    ref = ref[ref["t"] <= t_end + 1e-9]
    for ax, (col, label) in zip(axes, rows, strict=True):
        if col in ref:
            ax.plot(ref["t"], ref[col], "k--", lw=0.9, label="reference")
        ax.set_ylabel(label)
        ax.grid(True, alpha=0.3)
    for ax, bound in ((axes[2], DELTA_MAX), (axes[3], 2.0)):
        for b in (-bound, bound):
            ax.axhline(b, color="gray", ls="--", lw=0.7)
    axes[0].legend(loc="best", fontsize=8)
    axes[0].set_title(f"{scenario}, {dt * 1e3:.0f} ms: dotted lines = operating-point "
                      "switches (switched mode)")
    axes[-1].set_xlabel("t [s]")
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


def path(root: Path, scenario: str, out: Path, dt: float = 0.02) -> Path:
    ref = reference(scenario)
    fig, ax = plt.subplots(figsize=(6, 6))
    ax.plot(ref["px"], ref["py"], "k--", lw=0.9, label="reference")
    for mode in MODES:
        steps = load(root, scenario, mode, dt)
        ax.plot(steps["px"], steps["py"], color=COLORS[mode], lw=1.2, label=mode)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title(f"{scenario}, {dt * 1e3:.0f} ms")
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


def sample_time(root: Path, out: Path) -> Path:
    """control_y_V: y at 20 ms and 50 ms sample time (32-step preview: 0.64 s vs 1.6 s)."""
    ref = reference("control_y_V")
    fig, axes = plt.subplots(1, 3, figsize=(12, 3.6), sharey=True)
    for ax, mode in zip(axes, MODES, strict=True):
        for dt, ls in ((0.02, "-"), (0.05, "-.")):
            steps = load(root, "control_y_V", mode, dt)
            ax.plot(steps["t"], steps["py"], ls, color=COLORS[mode], lw=1.3,
                    label=f"{dt * 1e3:.0f} ms")
        r = ref[ref["t"] <= 10.0]
        ax.plot(r["t"], r["py"], "k--", lw=0.9, label="reference")
        ax.set_title(f"control_y_V, {mode}")
        ax.set_xlabel("t [s]")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8)
    axes[0].set_ylabel("y [m]")
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


def draw_all(root: Path, fig_dir: Path) -> list[Path]:
    fig_dir.mkdir(parents=True, exist_ok=True)
    done = [sample_time(root, fig_dir / "control_y_V_sample_time.png")]
    for scenario in SCENARIOS:
        done.append(response(root, scenario, fig_dir / f"{scenario}_response.png"))
        done.append(path(root, scenario, fig_dir / f"{scenario}_path.png"))
    return done


if __name__ == "__main__":
    for p in draw_all(ROOT / "outputs" / "bicycle_bench", HERE / "figures"):
        print(p)
