"""The figures answer their run's question, checked by reading each PNG back: its size, that
it is not blank, the legend entries it must have, units on its axes, no empty panel.

The legends and labels are read from the text chunk :func:`mpclab.record.figure_file.save_figure`
writes into every figure.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from mpclab import tables
from mpclab.config.registry import COMPONENTS, register_all
from mpclab.record.figure_file import FigureFile, read_figure
from mpclab.record.figures import HIT, LEAVE, PATH_PNG, SERIES_PNG
from mpclab.sweeps.figure import plot_arrival_vs_compute


def drawn(fig: FigureFile, min_px: int = 300) -> None:
    """A real picture: big enough, with ink, every panel with data."""
    assert fig.width >= min_px and fig.height >= min_px, (fig.width, fig.height)
    assert fig.ink > 0.02, fig.ink
    assert fig.panels and all(p.artists > 0 for p in fig.panels), fig.panels


def test_every_shipped_plant_names_the_unit_of_each_label() -> None:
    register_all()
    shipped = {n: c for n, c in COMPONENTS["plant"].items()
               if c.__module__.startswith("mpclab.plants.")}
    assert len(shipped) >= 4
    for name, cls in shipped.items():
        missing = [lab for lab in (*cls.states, *cls.inputs) if not cls.units.get(lab)]
        assert not missing, f"plant {name}: no unit for {missing}"


def test_a_bug2_run_shows_its_modes_and_the_input_the_plant_received(run_cfg) -> None:
    # a fixed 50 ms latency (a quarter of the 0.2 s period): the inputs act late, visibly
    _, out = run_cfg(["+experiment=zumo_bug2", "sim.latency=50"], figures=True)
    path = read_figure(out / PATH_PNG)
    drawn(path)
    (panel,) = path.panels
    assert {"path: go_to_goal", "path: wall_follow", HIT, LEAVE, "m-line", "start", "goal",
            "obstacles"} <= path.labels
    assert (panel.xlabel, panel.ylabel) == ("x [m]", "y [m]")
    assert not panel.legend_inside  # the legend covers no data
    assert "latency 50 ms" in panel.title
    series = read_figure(out / SERIES_PNG)
    drawn(series)
    assert {"input as applied", "input as requested", "mode: go_to_goal",
            "mode: wall_follow", "bound"} <= series.labels
    assert [p.ylabel for p in series.panels] == ["theta [rad]", "u1 [rad/s]", "u2 [rad/s]"]
    assert series.panels[-1].xlabel == "t [s]"


def test_an_ideal_loop_draws_the_input_once(run_cfg) -> None:
    _, out = run_cfg(["+experiment=car_cvxpy"], figures=True)
    series = read_figure(out / SERIES_PNG)
    drawn(series)
    assert "input" in series.labels and not {"input as requested"} & series.labels
    assert all("[" in p.ylabel for p in series.panels)  # units on every axis
    path = read_figure(out / PATH_PNG)
    assert {"path", "start", "goal", "predicted horizons"} <= path.labels
    assert not any(lab.startswith("path:") for lab in path.labels)  # one mode: one colour


def test_the_bicycles_lane_change_is_drawn_wide_with_the_legend_outside(run_cfg) -> None:
    _, out = run_cfg(["+experiment=bicycle_scheduled", "scenario.t_max=4.0"], figures=True)
    path = read_figure(out / PATH_PNG)
    drawn(path)
    (panel,) = path.panels
    assert {"reference", "path", "start", "goal"} <= path.labels
    assert not panel.legend_inside
    # 25 m by 3 m: stretched (and said so), not 75 % white space around a thin strip
    assert "not to the same scale" in panel.title
    assert 1.8 < path.width / path.height < 4.0, (path.width, path.height)


# ------------------------------------------------------------------ the sweep figure


def _job(folder: Path, horizon: int, seed: int, status: str, wall_ms: float, cpu_ms: float,
         arrival: float | None) -> None:
    """A sweep job's folder as a run writes it (overrides and summary; no step log)."""
    (folder / ".hydra").mkdir(parents=True)
    (folder / ".hydra" / "overrides.yaml").write_text(
        f"- controller.horizon={horizon}\n- seed={seed}\n")
    (folder / "summary.json").write_text(json.dumps({
        "experiment": "car_cvxpy", "controller": "cvxpy", "scenario": "car_to_origin",
        "seed": seed, "status": status, "arrived": status == "arrived",
        "arrival_time_s": arrival, "sim_time_s": arrival or 4.0,
        "compute_median_ms": wall_ms, "compute_cpu_median_ms": cpu_ms, "rtf": wall_ms / 100,
        "compute_cpu_total_s": cpu_ms * 0.04, "compute_cpu_share": cpu_ms / wall_ms,
    }))


@pytest.fixture
def horizon_sweep(tmp_path: Path) -> Path:
    """controller.horizon=8,10 x seed=0,1,2; the machine was loaded (CPU 60 % of wall time);
    one run of horizon 8 timed out."""
    (tmp_path / "multirun.yaml").write_text("hydra: {}\n")
    num = 0
    for horizon in (8, 10):
        for seed in range(3):
            late = horizon == 8 and seed == 2
            _job(tmp_path / str(num), horizon, seed, "timeout" if late else "arrived",
                 wall_ms=2.0 + horizon / 10, cpu_ms=(2.0 + horizon / 10) * 0.6,
                 arrival=None if late else 2.5 + 0.1 * seed)
            num += 1
    return tmp_path


def test_a_horizon_sweep_tells_the_horizons_apart_in_cpu_time(horizon_sweep: Path) -> None:
    df = tables.collect([horizon_sweep], root=horizon_sweep)
    assert df["contended"].all()
    fig = read_figure(plot_arrival_vs_compute(df, horizon_sweep / "a.png"))
    drawn(fig)
    top, strip = fig.panels
    assert top.legend == ("controller.horizon=8", "controller.horizon=10")
    assert top.xlabel == "" and "CPU time" in strip.xlabel and "6 of 6 runs contended" in \
        strip.xlabel
    assert strip.ylabel == "did not arrive"
    assert not top.legend_inside


def test_the_sweep_figure_has_no_empty_panel(horizon_sweep: Path) -> None:
    df = tables.collect([horizon_sweep], root=horizon_sweep)
    arrived = df[df["status"] == "arrived"]
    arrived.attrs = df.attrs
    fig = read_figure(plot_arrival_vs_compute(arrived, horizon_sweep / "a.png"))
    drawn(fig)
    (only,) = fig.panels  # every run arrived: no "did not arrive" strip
    assert only.ylabel == "arrival time [s]" and "CPU time" in only.xlabel
    idle = df.assign(compute_cpu_share=1.0, contended=False)
    fig = read_figure(plot_arrival_vs_compute(idle, horizon_sweep / "b.png"))
    assert "wall" in fig.panels[-1].xlabel and "contended" not in fig.panels[-1].xlabel


def test_the_sweep_figure_names_backend_and_swept_key_together(horizon_sweep: Path) -> None:
    df = tables.collect([horizon_sweep], root=horizon_sweep)
    df.loc[df["seed"] == 0, "backend"] = "casadi"
    fig = read_figure(plot_arrival_vs_compute(df, horizon_sweep / "a.png"))
    labels = fig.panels[0].legend
    assert len(labels) == 4 and len(set(labels)) == 4
    assert "casadi, controller.horizon=10" in labels and "cvxpy, controller.horizon=8" in labels
    assert np.isfinite(pd.to_numeric(df["compute_cpu_median_ms"])).all()


def test_a_sweep_whose_every_job_failed_draws_a_note_not_a_crash(tmp_path: Path) -> None:
    (tmp_path / "multirun.yaml").write_text("hydra: {}\n")
    for num in range(2):  # error rows: no compute columns at all
        (tmp_path / str(num) / ".hydra").mkdir(parents=True)
        (tmp_path / str(num) / ".hydra" / "overrides.yaml").write_text(
            f"- controller.horizon={num + 5}\n")
        (tmp_path / str(num) / "summary.json").write_text(json.dumps(
            {"status": "error", "controller": "cvxpy", "error": "ValueError: no"}))
    df = tables.collect([tmp_path], root=tmp_path)
    fig = read_figure(plot_arrival_vs_compute(df, tmp_path / "a.png"))
    assert fig.ink > 0 and "0 of 2 runs arrived" in fig.panels[0].title
