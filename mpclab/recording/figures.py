"""Per-run figures like the studies': the path with every predicted horizon, and time series."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from mpclab.lazy import pyplot

PATH_PNG = "path.png"
SERIES_PNG = "series.png"


def plot_run(result: Any, run: Any, out_dir: Path, dpi: int = 110) -> list[Path]:
    """Write ``path.png`` and ``series.png`` into ``out_dir``; return their paths."""
    out_dir = Path(out_dir)
    return [
        plot_path(result, run, out_dir / PATH_PNG, dpi),
        plot_series(result, run, out_dir / SERIES_PNG, dpi),
    ]


def plot_path(result: Any, run: Any, path: Path, dpi: int = 110) -> Path:
    """The path driven (red) with the predicted horizon of every step (blue)."""
    plant, scen = run.plant, run.scenario
    px, py = plant.position
    steps, hz = result.steps, result.horizons
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(6.4, 6.4))
    for _, h in hz.groupby("step", sort=True):
        ax.plot(h[px], h[py], "-", color="tab:blue", lw=0.7, alpha=0.5)
    ax.plot([], [], "-", color="tab:blue", lw=0.7, label="predicted horizons")
    draw_world(ax, scen)
    mline = getattr(run.supervisor, "mline", None)
    if mline is not None:
        (x0, y0), (x1, y1) = mline
        ax.plot([x0, x1], [y0, y1], "--", color="tab:gray", lw=1.2, label="m-line")
    ax.plot(steps[px], steps[py], "-", color="tab:red", lw=1.8, label="path")
    ax.plot(*scen.x0[[plant.state_index(px), plant.state_index(py)]], "o", color="k",
            label="start")
    ax.plot(*scen.goal[[plant.state_index(px), plant.state_index(py)]], "x", color="k", ms=10,
            mew=2, label="goal")
    s = result.summary
    when = f"{s['arrival_time_s']:.2f} s" if s.get("arrived") else s["status"]
    ax.set_title(f"{s.get('experiment', '')} on {scen.name}: {when}")
    ax.set_xlabel(f"{px} [m]")
    ax.set_ylabel(f"{py} [m]")
    ax.set_aspect("equal", adjustable="box")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="best", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
    return path


def draw_world(ax: Any, scen: Any) -> None:
    """Obstacles and other static features a scenario may have (drawn if present)."""
    draw = getattr(scen, "draw", None)
    if callable(draw):
        draw(ax)


def plot_series(result: Any, run: Any, path: Path, dpi: int = 110) -> Path:
    """Selected states and every input over time, input bounds dashed."""
    plant = run.plant
    steps = result.steps
    labels = [(s, "state") for s in plant.plot_states] + [(u, "input") for u in plant.inputs]
    plt = pyplot()
    fig, axes = plt.subplots(len(labels), 1, figsize=(7.0, 1.8 * len(labels)), sharex=True)
    axes = np.atleast_1d(axes)
    for ax, (label, kind) in zip(axes, labels, strict=True):
        if kind == "state":
            ax.plot(steps["t"], steps[label], color="tab:red")
            lo, hi = plant.x_lb[plant.state_index(label)], plant.x_ub[plant.state_index(label)]
        else:
            ax.step(steps["t"], steps[label], where="post", color="tab:green")
            lo, hi = plant.u_lb[plant.input_index(label)], plant.u_ub[plant.input_index(label)]
        for b in (lo, hi):
            if np.isfinite(b):
                ax.axhline(b, color="gray", ls="--", lw=0.8)
        ax.set_ylabel(label)
        ax.grid(True, alpha=0.3)
    axes[-1].set_xlabel("t [s]")
    fig.tight_layout()
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
    return path
