"""Per-run figures: ``path.png`` (the path driven, every predicted horizon, the world; a
supervisor's modes in colour with its switch points) and ``series.png`` (states and inputs
over time in their units; under ``sim`` latency the inputs as the plant received them).

Both are written by :func:`mpclab.record.figure_file.save_figure`, which keeps their legends and
axis labels in the file for tests to read back.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from mpclab.core.lazy_import import pyplot
from mpclab.record.figure_file import save_figure

PATH_PNG = "path.png"
SERIES_PNG = "series.png"
#: colours of a supervisor's modes, by name in alphabetical order (blue is the horizons')
MODE_COLOURS = ("tab:red", "tab:green", "tab:purple", "tab:orange", "tab:brown", "tab:pink")
#: the path figure's data box is drawn to scale when its height / width is within this range
SCALE_RATIO = (0.25, 4.0)
#: the larger side of the path figure's data box [in]
PATH_BOX_IN = 6.0
#: legend entries of the hit and leave points of a BUG2-like supervisor
HIT, LEAVE = "hit point", "leave point"


def plot_run(result: Any, run: Any, out_dir: Path, dpi: int = 110) -> list[Path]:
    """Write ``path.png`` and ``series.png`` into ``out_dir``; return their paths."""
    out_dir = Path(out_dir)
    return [
        plot_path(result, run, out_dir / PATH_PNG, dpi),
        plot_series(result, run, out_dir / SERIES_PNG, dpi),
    ]


def mode_runs(steps: pd.DataFrame) -> list[tuple[str, int, int]]:
    """``(mode, first, last)``: the step log's stretches of one mode (step indices, the final
    row, which has no mode, left out); empty when the run had fewer than two modes."""
    if "mode" not in steps:
        return []
    modes = steps["mode"].astype("string").fillna("").to_numpy(dtype=object)
    runs: list[tuple[str, int, int]] = []
    for i, mode in enumerate(modes):
        if not mode:
            continue
        if runs and runs[-1][0] == mode and runs[-1][2] == i - 1:
            runs[-1] = (mode, runs[-1][1], i)
        else:
            runs.append((mode, i, i))
    return runs if len({r[0] for r in runs}) > 1 else []


def mode_colours(runs: list[tuple[str, int, int]]) -> dict[str, str]:
    """A colour per mode (by name, so that a mode has one colour in every run's figures)."""
    names = sorted({r[0] for r in runs})
    return {m: MODE_COLOURS[i % len(MODE_COLOURS)] for i, m in enumerate(names)}


def switch_points(steps: pd.DataFrame, supervisor: Any, position: tuple[str, str]
                  ) -> dict[str, list[tuple[float, float]]]:
    """Where the supervisor switched mode, by legend entry.

    A supervisor that records its hits (BUG2: ``hits``, every switch into following a wall,
    the first step's too) gives :data:`HIT` points, and its switches back out of that mode in
    the step log are :data:`LEAVE` points; for any other, each switch in the step log is a
    ``switch to MODE`` point.
    """
    runs = mode_runs(steps)
    px, py = position
    xy = steps[[px, py]].to_numpy(dtype=float)
    hits = getattr(supervisor, "hits", None)
    out: dict[str, list[tuple[float, float]]] = {}
    if hits is not None:
        out[HIT] = [(float(x), float(y)) for _, x, y in hits]
        if hits and runs:
            t0 = hits[0][0]
            at = int(np.argmin(np.abs(steps["t"].to_numpy(dtype=float) - t0)))
            followed = next((m for m, a, b in runs if a <= at <= b), None)
            out[LEAVE] = [tuple(xy[a]) for (prev, _, _), (_, a, _)
                          in zip(runs, runs[1:], strict=False) if prev == followed]
    else:
        for mode, a, _ in runs[1:]:  # every stretch but the first begins with a switch
            out.setdefault(f"switch to {mode}", []).append(tuple(xy[a]))
    return {k: v for k, v in out.items() if v}


def plot_path(result: Any, run: Any, path: Path, dpi: int = 110) -> Path:
    """The path driven (coloured by mode when the supervisor switched) with the predicted
    horizon of every step, the world, start and goal; to scale unless far from square."""
    plant, scen = run.plant, run.scenario
    px, py = plant.position
    steps, hz = result.steps, result.horizons
    plt = pyplot()
    fig, ax = plt.subplots()
    for _, h in hz.groupby("step", sort=True):
        ax.plot(h[px], h[py], "-", color="tab:blue", lw=0.7, alpha=0.5)
    ax.plot([], [], "-", color="tab:blue", lw=0.7, label="predicted horizons")
    draw_world(ax, scen)
    mline = getattr(run.supervisor, "mline", None)
    if mline is not None:
        (x0, y0), (x1, y1) = mline
        ax.plot([x0, x1], [y0, y1], "--", color="tab:gray", lw=1.2, label="m-line")
    runs = mode_runs(steps)
    if runs:
        colours = mode_colours(runs)
        seen: set[str] = set()
        for mode, a, b in runs:
            seg = steps.iloc[a: b + 2]  # to the next step's state: the stretch it drove
            ax.plot(seg[px], seg[py], "-", color=colours[mode], lw=2.0,
                    label=None if mode in seen else f"path: {mode}")
            seen.add(mode)
    else:
        ax.plot(steps[px], steps[py], "-", color="tab:red", lw=1.8, label="path")
    markers = {HIT: ("D", "tab:orange"), LEAVE: ("s", "tab:cyan")}
    for i, (label, points) in enumerate(switch_points(steps, run.supervisor, (px, py)).items()):
        marker, colour = markers.get(label, ("^v<>"[i % 4], "tab:olive"))
        ax.plot(*np.asarray(points).T, marker, color=colour, mec="k", ms=7, ls="none",
                zorder=7, label=label)  # above the start: BUG2 may switch at its first step
    ix, iy = plant.state_index(px), plant.state_index(py)
    ax.plot(scen.x0[ix], scen.x0[iy], "o", mfc="white", mec="k", mew=1.8, ms=12, ls="none",
            zorder=6, label="start")
    ax.plot(scen.goal[ix], scen.goal[iy], "x", color="k", ms=11, mew=2.5, ls="none",
            zorder=6, label="goal")
    to_scale = _size_to_data(fig, ax)
    ax.set_title(_path_title(result.summary, scen.name)
                 + ("" if to_scale else "\n(x and y not to the same scale)"))
    ax.set_xlabel(plant.axis_label(px))
    ax.set_ylabel(plant.axis_label(py))
    ax.grid(True, alpha=0.3)
    ax.legend(loc="upper left", bbox_to_anchor=(1.02, 1.0), borderaxespad=0.0, fontsize=8)
    return save_figure(fig, path, dpi)


def _path_title(s: dict[str, Any], scenario: str) -> str:
    when = (f"arrived in {s['arrival_time_s']:.2f} s" if s.get("arrived")
            else f"{s['status']} at {s.get('sim_time_s') or 0:.2f} s")
    latency = s.get("sim_latency")
    world = (f", sim {s['sim']}" if s.get("sim") not in (None, "nominal") else "") + (
        f", latency {latency}" if latency not in (None, "none") else "")
    return f"{s.get('experiment', '')} on {scenario}: {when}{world}"


def _size_to_data(fig: Any, ax: Any) -> bool:
    """Size ``fig`` to ``ax``'s data box: to scale (equal aspect) when the box's height /
    width is within :data:`SCALE_RATIO`, else a wide (or tall) box; True when to scale."""
    ax.autoscale_view()
    (x0, x1), (y0, y1) = ax.get_xlim(), ax.get_ylim()
    ratio = abs(y1 - y0) / max(abs(x1 - x0), 1e-12)
    lo, hi = SCALE_RATIO
    to_scale = lo <= ratio <= hi
    if to_scale:
        ax.set_aspect("equal", adjustable="box")
        w, h = (PATH_BOX_IN, PATH_BOX_IN * ratio) if ratio <= 1 else (PATH_BOX_IN / ratio,
                                                                      PATH_BOX_IN)
    else:
        w, h = (PATH_BOX_IN * 1.4, PATH_BOX_IN * 0.5) if ratio < lo else (PATH_BOX_IN * 0.6,
                                                                          PATH_BOX_IN * 1.2)
    fig.set_size_inches(w + 1.2, h + 1.0)  # the legend outside is added by the tight crop
    fig.subplots_adjust(left=1.0 / (w + 1.2), right=1 - 0.2 / (w + 1.2),
                        bottom=0.6 / (h + 1.0), top=1 - 0.4 / (h + 1.0))
    return to_scale


def draw_world(ax: Any, scen: Any) -> None:
    """Obstacles and other static features a scenario may have (drawn if present)."""
    draw = getattr(scen, "draw", None)
    if callable(draw):
        draw(ax)


def applied_input(steps: pd.DataFrame, label: str) -> tuple[np.ndarray, np.ndarray] | None:
    """``(t, u)`` of the input ``label`` as the plant received it, a step function that
    changes at each input's switch (``switch_t``; at the step's own time where a deadline was
    missed), or None when the step log has no ``applied_<label>`` (the ideal loop)."""
    col = f"applied_{label}"
    if col not in steps:
        return None
    rows = steps[steps[col].notna()]
    t = rows["switch_t"].fillna(rows["t"]).to_numpy(dtype=float)
    u = rows[col].to_numpy(dtype=float)
    end = float(steps["t"].iloc[-1])
    return np.append(t, end), np.append(u, u[-1] if len(u) else np.nan)


#: latency drawn as a separate applied input from this share of the control period on
LATE_SHARE = 0.02


def received_late(steps: pd.DataFrame, dt: float) -> bool:
    """Whether the plant received inputs visibly later than requested: a missed deadline, or
    a latency of at least :data:`LATE_SHARE` of the control period ``dt``."""
    if "latency_s" not in steps:
        return False
    missed = bool(steps["deadline_miss"].fillna(False).astype(bool).any())
    return missed or bool(steps["latency_s"].max() >= LATE_SHARE * dt)


def plot_series(result: Any, run: Any, path: Path, dpi: int = 110) -> Path:
    """Selected states and every input over time in their units, bounds dotted; inputs as
    applied (solid) and as requested (dashed) when the plant received them late
    (:func:`received_late`); a supervisor's modes shaded."""
    plant = run.plant
    steps = result.steps
    labels = [(s, "state") for s in plant.plot_states] + [(u, "input") for u in plant.inputs]
    plt = pyplot()
    fig, axes = plt.subplots(len(labels), 1, figsize=(7.5, 1.7 * len(labels) + 0.8),
                             sharex=True, layout="constrained")
    axes = np.atleast_1d(axes)
    runs = mode_runs(steps)
    colours = mode_colours(runs)
    t = steps["t"].to_numpy(dtype=float)
    handles: dict[str, Any] = {}
    late = received_late(steps, run.controller.dt)
    for ax, (label, kind) in zip(axes, labels, strict=True):
        for mode, a, b in runs:  # when each mode was active, shaded
            span = ax.axvspan(t[a], t[min(b + 1, len(t) - 1)], color=colours[mode], alpha=0.08,
                              lw=0)
            handles.setdefault(f"mode: {mode}", span)
        if kind == "state":
            (line,) = ax.plot(t, steps[label], color="tab:red")
            handles.setdefault("state", line)
            lo, hi = plant.x_lb[plant.state_index(label)], plant.x_ub[plant.state_index(label)]
        else:
            applied = applied_input(steps, label) if late else None
            if applied is None:
                (line,) = ax.step(t, steps[label], where="post", color="tab:green")
                handles.setdefault("input", line)
            else:
                (line,) = ax.step(*applied, where="post", color="tab:green")
                handles.setdefault("input as applied", line)
                (req,) = ax.step(t, steps[label], where="post", color="k", ls="--", lw=0.8,
                                 alpha=0.7)
                handles.setdefault("input as requested", req)
            lo, hi = plant.u_lb[plant.input_index(label)], plant.u_ub[plant.input_index(label)]
        for b in (lo, hi):
            if np.isfinite(b):
                handles.setdefault("bound", ax.axhline(b, color="gray", ls=":", lw=1.0))
        ax.set_ylabel(plant.axis_label(label))
        ax.grid(True, alpha=0.3)
    axes[-1].set_xlabel("t [s]")
    axes[0].set_title(_path_title(result.summary, run.scenario.name), fontsize=10)
    fig.legend(list(handles.values()), list(handles), loc="outside upper center",
               ncol=min(len(handles), 4), fontsize=8)
    return save_figure(fig, path, dpi)
