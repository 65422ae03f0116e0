"""The Pareto front of a sweep (mpclab/tables/pareto.py, mpclab/sweeps/pareto.py): points,
feasibility, domination, the knee and the shipped default; the files a sweep and
``python -m mpclab.tables --pareto`` write."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from conftest import ROOT
from mpclab.errors import ConfigError
from mpclab.sweeps.report import main as tables_main
from mpclab.tables.pareto import (
    ParetoObjective,
    front,
    override_value,
    pareto_points,
    parse_objectives,
)

OBJ = (ParetoObjective.arrival_s, ParetoObjective.step_p95_ms)


def runs_table() -> tuple[pd.DataFrame, dict[str, np.ndarray]]:
    """Five horizons, two seeds each: (arrival s, compute ms per call) per point; horizon 8
    is dominated by 10, horizon 12 would dominate everything but one seed collided."""
    points = {6: (12.0, 1.0), 8: (11.0, 4.0), 10: (10.0, 3.0), 12: (8.0, 0.5), 14: (9.0, 10.0)}
    rows, step_ms = [], {}
    for h, (arrival, ms) in points.items():
        for seed in (0, 1):
            run = f"/nowhere/h{h}/s{seed}"
            collided = h == 12 and seed == 1
            rows.append({"controller.horizon": h, "seed": seed, "run_dir": run,
                         "status": "collision" if collided else "arrived",
                         "arrival_time_s": None if collided else arrival + 0.2 * seed})
            step_ms[run] = np.full(20, ms * (1 + 0.1 * seed))
    df = pd.DataFrame(rows)
    df.attrs["params"] = ["controller.horizon", "seed"]
    return df, step_ms


def test_points_front_knee_and_default() -> None:
    df, step_ms = runs_table()
    pts = pareto_points(df, OBJ, step_ms, default={"controller.horizon": 10}).set_index(
        "controller.horizon")
    assert list(pts.index) == [6, 8, 10, 12, 14]
    assert pts.loc[12, "feasible"] is np.False_ and pts.loc[12, "collisions"] == 1
    assert pts["front"].to_dict() == {6: True, 8: False, 10: True, 12: False, 14: True}
    # the median over seeds, and the seeds' spread
    assert pts.loc[10, "arrival_s"] == pytest.approx(10.1)
    assert (pts.loc[10, "arrival_s_min"], pts.loc[10, "arrival_s_max"]) == pytest.approx(
        (10.0, 10.2))
    assert pts.loc[10, "step_p95_ms"] == pytest.approx(3.15)
    assert pts.loc[10, "overrides"] == "controller.horizon=10"
    # the knee: nearest the ideal corner of the front scaled to [0, 1]
    assert pts["knee"].to_dict() == {6: False, 8: False, 10: True, 12: False, 14: False}
    assert pts["default"].to_dict() == {6: False, 8: False, 10: True, 12: False, 14: False}
    on = front(pareto_points(df, OBJ, step_ms))
    assert list(on["controller.horizon"]) == [14, 10, 6]  # by the first objective


def test_objectives_and_override_values() -> None:
    assert parse_objectives(None) == OBJ
    assert parse_objectives("tracking_rms_m, step_cpu_p95_ms") == (
        ParetoObjective.tracking_rms_m, ParetoObjective.step_cpu_p95_ms)
    for bad in ("arrival_s", "arrival_s,arrival_s", "arrival_s,speed"):
        with pytest.raises(ConfigError, match="pareto.objectives|speed"):
            parse_objectives(bad)
    assert [override_value(v) for v in (None, float("nan"), 3.0, 2.5, [1, 2, 7], "casadi")] == [
        "null", "null", "3", "2.5", "[1,2,7]", "casadi"]


@pytest.mark.slow
def test_a_sweep_ends_with_its_front_and_the_tables_tool_writes_it_again(tmp_path: Path,
                                                                          capsys) -> None:
    """A car sweep over horizon x control horizon (2 seeds) asking for a front: pareto.csv
    (the front's points, each with its overrides and its seeds' spread), pareto.png, and the
    shipped default (horizon 10, every move free) marked; ``--pareto`` writes the same."""
    cmd = [sys.executable, "-m", "mpclab", "-m", "+experiment=car_cvxpy", "+ci=smoke",
           "scenario.t_max=4.0", "controller.horizon=6,10", "controller.control_horizon=null,3",
           "seed=0,1",
           "+hydra.callbacks.sweep.pareto.objectives=[arrival_s,step_cpu_p95_ms]",
           "hydra.launcher.n_jobs=2", f"hydra.sweep.dir={tmp_path}"]
    proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, (proc.stdout + proc.stderr)[-4000:]
    points = pd.read_csv(tmp_path / "pareto_points.csv")
    on = pd.read_csv(tmp_path / "pareto.csv")
    assert len(points) == 4 and (points["runs"] == 2).all()
    assert set(on["overrides"]) <= set(points["overrides"]) and len(on) >= 1
    assert on["feasible"].all() and (on["arrived"] == on["runs"]).all()
    assert {"arrival_s_min", "arrival_s_max", "step_cpu_p95_ms_max"} <= set(on.columns)
    default = points[points["default"]]
    assert list(default["overrides"]) == [
        "controller.horizon=10 controller.control_horizon=null"]
    assert (tmp_path / "pareto.png").stat().st_size > 0
    first = on.set_index("overrides")["arrival_s"]
    (tmp_path / "pareto.csv").unlink()
    assert tables_main(["--pareto", "--no-figure", str(tmp_path)]) == 0
    again = pd.read_csv(tmp_path / "pareto.csv").set_index("overrides")["arrival_s"]
    pd.testing.assert_series_equal(again, first)  # the sweep's objectives, read back
    assert "## Pareto front" in capsys.readouterr().out
    assert tables_main(["--pareto", "--points", "--no-figure", str(tmp_path)]) == 0
    out = capsys.readouterr().out  # every point with its spread, then the stamp
    assert "## Every point" in out and "arrival_s_min" in out
    assert "· commit " in out.split("## Every point")[1]


def test_tables_tool_refuses_a_bad_objective(tmp_path: Path) -> None:
    run = tmp_path / "r"
    run.mkdir()
    (run / "summary.json").write_text('{"status": "arrived", "arrival_time_s": 1.0}')
    with pytest.raises(SystemExit) as err:
        tables_main(["--pareto", "--objectives", "arrival_s,speed", "--no-figure",
                     str(tmp_path)])
    assert err.value.code == 2


def test_two_choices_of_one_controller_are_two_backends_and_two_points() -> None:
    """``controller=casadi_fatrop,casadi``: both record controller ``casadi``; the solver
    their summaries record tells them apart in the tables and on the front."""
    from mpclab.tables import _frame

    rows = [{"controller": "casadi", "solver": s, "controller.horizon": h, "seed": 0,
             "status": "arrived", "arrival_time_s": 10.0, "run_dir": f"/nowhere/{s}{h}",
             "sweep_dir": ".", "job": "0"}
            for s in ("fatrop", "ipopt") for h in (6, 10)]
    df = _frame(rows, ["controller", "controller.horizon", "seed"])
    assert sorted(df["backend"].unique()) == ["casadi:fatrop", "casadi:ipopt"]
    pts = pareto_points(df, (ParetoObjective.arrival_s, ParetoObjective.step_p95_ms), {})
    assert pts.attrs["keys"] == ["backend", "controller.horizon"] and len(pts) == 4
    one = _frame([r for r in rows if r["solver"] == "fatrop"], ["controller.horizon", "seed"])
    assert set(one["backend"]) == {"casadi"}  # one solver: the name alone, as before
