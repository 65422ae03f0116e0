"""The Pareto front of a sweep (mpclab/tables/pareto.py, mpclab/sweeps/pareto.py): points,
feasibility, domination, the knee and the shipped default; the files a sweep and
``python -m mpclab.cli.tables --pareto`` write."""

from __future__ import annotations

import subprocess
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from omegaconf import OmegaConf
from rerun.chunk import RrdReader

from conftest import ROOT, compose_cfg
from mpclab.cli.tables import main as tables_main
from mpclab.core.errors import ConfigError
from mpclab.record import files as record
from mpclab.recorders import rerun_blueprint as ent
from mpclab.recorders.merge import entity_name
from mpclab.sweeps.front_replay import FRONT_RECORDING, rerun_command
from mpclab.sweeps.pareto import point_label
from mpclab.tables import REPLAYED_RUNS
from mpclab.tables.pareto import (
    ParetoObjective,
    first_seed_runs,
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


def test_a_tie_within_the_tolerance_is_decided_by_the_other_objective() -> None:
    """Two builds of one controller that track alike to 3e-6 m (double and single precision)
    are told apart by their compute alone: the slower is off the front; a real difference in
    tracking (0.3 %) keeps a slower point on it."""
    rows, step_ms = [], {}
    points = {"double": (0.060053, 1.16), "single": (0.060056, 0.114), "other": (0.0602, 0.05)}
    for name, (rms, ms) in points.items():
        run = f"/nowhere/{name}"
        rows.append({"controller.codegen_precision": name, "seed": 0, "run_dir": run,
                     "status": "arrived", "rms_position": rms})
        step_ms[run] = np.full(20, ms)
    df = pd.DataFrame(rows)
    df.attrs["params"] = ["controller.codegen_precision", "seed"]
    objectives = (ParetoObjective.tracking_rms_m, ParetoObjective.step_p95_ms)
    pts = pareto_points(df, objectives, step_ms).set_index("controller.codegen_precision")
    assert pts["front"].to_dict() == {"double": False, "other": True, "single": True}


def test_objectives_and_override_values() -> None:
    assert parse_objectives(None) == OBJ
    assert parse_objectives("tracking_rms_m, step_cpu_p95_ms") == (
        ParetoObjective.tracking_rms_m, ParetoObjective.step_cpu_p95_ms)
    for bad in ("arrival_s", "arrival_s,arrival_s", "arrival_s,speed"):
        with pytest.raises(ConfigError, match="pareto.objectives|speed"):
            parse_objectives(bad)
    assert [override_value(v) for v in (None, float("nan"), 3.0, 2.5, [1, 2, 7], "casadi")] == [
        "null", "null", "3", "2.5", "[1,2,7]", "casadi"]


@pytest.fixture(scope="module")
def car_front_sweep(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A car sweep over horizon x control horizon (2 seeds, no recorder) asking for a front
    and its replay (``rerun: true``): its folder."""
    sweep = tmp_path_factory.mktemp("car_front")
    cmd = [sys.executable, "-m", "mpclab", "-m", "+experiment=car_cvxpy", "+ci=smoke",
           "scenario.t_max=4.0", "controller.horizon=6,10", "controller.control_horizon=null,3",
           "seed=0,1",
           "+hydra.callbacks.sweep.pareto.objectives=[arrival_s,step_cpu_p95_ms]",
           "+hydra.callbacks.sweep.pareto.rerun=true",
           "hydra.launcher.n_jobs=2", f"hydra.sweep.dir={sweep}"]
    proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, (proc.stdout + proc.stderr)[-4000:]
    return sweep


@pytest.mark.slow
def test_a_sweep_ends_with_its_front_and_the_tables_tool_writes_it_again(car_front_sweep: Path,
                                                                          capsys) -> None:
    """pareto.csv (the front's points, each with its overrides and its seeds' spread),
    pareto.png, and the shipped default (horizon 10, every move free) marked; ``--pareto``
    writes the same."""
    sweep = car_front_sweep
    points = pd.read_csv(sweep / "pareto_points.csv")
    on = pd.read_csv(sweep / "pareto.csv")
    assert len(points) == 4 and (points["runs"] == 2).all()
    assert set(on["overrides"]) <= set(points["overrides"]) and len(on) >= 1
    assert on["feasible"].all() and (on["arrived"] == on["runs"]).all()
    assert {"arrival_s_min", "arrival_s_max", "step_cpu_p95_ms_max"} <= set(on.columns)
    default = points[points["default"]]
    assert list(default["overrides"]) == [
        "controller.horizon=10 controller.control_horizon=null"]
    assert (sweep / "pareto.png").stat().st_size > 0
    first = on.set_index("overrides")["arrival_s"]
    (sweep / "pareto.csv").unlink()
    assert tables_main(["--pareto", "--no-figure", str(sweep)]) == 0
    again = pd.read_csv(sweep / "pareto.csv").set_index("overrides")["arrival_s"]
    pd.testing.assert_series_equal(again, first)  # the sweep's objectives, read back
    assert "## Pareto front" in capsys.readouterr().out
    assert tables_main(["--pareto", "--points", "--no-figure", str(sweep)]) == 0
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
    their summaries record tells them apart in the tables and on the front, in any table."""
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
    assert set(one["backend"]) == {"casadi:fatrop"}  # the same label in any table


@pytest.mark.slow
def test_the_front_replays_side_by_side_in_one_rerun_file(car_front_sweep: Path,
                                                          capsys) -> None:
    """The sweep recorded nothing (``+ci=smoke``): its end ran each front point's first seed
    again with a recording (the same outcome) and merged them under the points' prefixes;
    ``--rerun`` merges them again, reusing those runs, which the tables leave out."""
    sweep = car_front_sweep
    merged = sweep / FRONT_RECORDING
    on = pd.read_csv(sweep / "pareto.csv")
    keys = ["controller.horizon", "controller.control_horizon"]
    labels = {entity_name(point_label(r, keys)) for _, r in on.iterrows()}
    assert merged.is_file() and not list(sweep.glob("[0-9]*/run.rrd"))
    assert {p.name for p in (sweep / REPLAYED_RUNS).iterdir()} == labels
    recorded = {p.name: p.stat().st_mtime_ns for p in (sweep / REPLAYED_RUNS).glob("*/run.rrd")}
    merged.unlink()
    assert tables_main(["--pareto", "--rerun", "--no-figure", str(sweep)]) == 0
    out = capsys.readouterr().out
    assert f"front replay: {len(on)} points" in out and "differs" not in out
    assert {p.name: p.stat().st_mtime_ns
            for p in (sweep / REPLAYED_RUNS).glob("*/run.rrd")} == recorded  # reused
    assert len(pd.read_csv(sweep / "summary.csv")) == 8  # the sweep's runs only
    prefixes = defaultdict(set)
    for chunk in RrdReader(merged).stream():
        head, _, rest = chunk.entity_path.strip("/").partition("/")
        prefixes[head].add(rest)
    assert set(prefixes) - {"__properties"} == labels
    for label in labels:  # each point's map and signals under its prefix
        assert {ent.PATH, ent.HORIZON} <= prefixes[label]


def test_first_seed_runs_and_the_rerun_command(tmp_path: Path) -> None:
    """The front's runs of its first seed; the job run again as the sweep ran it, with a
    recorder, Hydra's own choices kept."""
    df, step_ms = runs_table()
    pts = pareto_points(df, OBJ, step_ms)
    assert first_seed_runs(df.iloc[::-1], pts) == {
        "controller.horizon=14": "/nowhere/h14/s0", "controller.horizon=10": "/nowhere/h10/s0",
        "controller.horizon=6": "/nowhere/h6/s0"}
    job = tmp_path / "3"
    (job / ".hydra").mkdir(parents=True)
    (job / ".hydra" / "overrides.yaml").write_text(
        "- +experiment=zumo_bug2\n- +sweep=pareto_zumo_search\n- recorder=none\n"
        "- controller.horizon=6\n- seed=0\n")
    (job / ".hydra" / "hydra.yaml").write_text(
        "hydra:\n  overrides:\n    hydra: [hydra/sweeper=pareto_search, hydra.mode=MULTIRUN]\n"
        f"  runtime:\n    cwd: {tmp_path}\n")
    args, cwd = rerun_command(job, tmp_path / "again")
    assert args == ["+experiment=zumo_bug2", "+sweep=pareto_zumo_search",
                    "controller.horizon=6", "seed=0", "recorder=rerun",
                    "hydra/sweeper=pareto_search", f"hydra.run.dir={tmp_path / 'again'}"]
    assert cwd == tmp_path


def test_the_bicycle_front_is_configured_on_the_cortex_m4_estimate() -> None:
    """``+sweep=pareto_bicycle``: the scheduled controller's generated C on the turn under
    ``sim=embedded_m4``, its grid, and the objectives; the Cortex-M4 estimate is read from
    each run's summary (none recorded: no value, no front)."""
    cfg = compose_cfg(["+experiment=bicycle_scheduled", "+sweep=pareto_bicycle"])
    assert cfg.controller.codegen is True and cfg.scenario.name == "turn"
    assert cfg.sim.name == "embedded_m4" and cfg.recorder._target_.endswith("base.Recorder")
    sweep = OmegaConf.load(ROOT / "conf" / "sweep" / "pareto_bicycle.yaml").hydra
    assert set(sweep.sweeper.params) == {"controller.horizon", "controller.dt",
                                         "controller.control_horizon",
                                         "controller.codegen_precision"}
    objectives = parse_objectives(list(sweep.callbacks.sweep.pareto.objectives))
    assert objectives == (ParetoObjective.tracking_rms_m, ParetoObjective.step_m4_p95_ms)
    rows = [{"controller.horizon": h, "seed": 0, "run_dir": f"/nowhere/{h}", "status": "arrived",
             "rms_position": rms, "step_m4_p95_ms": m4}
            for h, rms, m4 in ((8, 0.3, 0.2), (16, 0.2, 0.4), (32, 0.25, 0.8))]
    df = pd.DataFrame(rows)
    df.attrs["params"] = ["controller.horizon", "seed"]
    pts = pareto_points(df, objectives).set_index("controller.horizon")
    assert pts["front"].to_dict() == {8: True, 16: True, 32: False}
    assert pts.loc[32, "step_m4_p95_ms"] == pytest.approx(0.8)
    none = pareto_points(df.drop(columns="step_m4_p95_ms"), objectives)
    assert none["step_m4_p95_ms"].isna().all() and not none["front"].any()


def test_the_time_to_the_input_is_the_rti_feedback_and_any_other_call_whole(tmp_path) -> None:
    """``input_cpu_p95_ms`` reads a real-time iteration's feedback CPU time (its preparation
    runs after the input) and the whole call's CPU time of any other controller; the RTI's
    ``step_cpu_p95_ms`` stays the whole call."""
    rows = []
    for name, calls in (("rti", {"solve_cpu_s": 1e-3, "feedback_cpu_s": 3e-4}),
                        ("fatrop", {"solve_cpu_s": 2e-3})):
        run = tmp_path / name
        run.mkdir()
        steps = pd.DataFrame({"status": ["truncated"] * 10 + [record.FINAL],
                              **{k: [v] * 10 + [np.nan] for k, v in calls.items()}})
        steps.to_parquet(run / record.STEPS)
        rows.append({"controller": name, "seed": 0, "run_dir": str(run), "status": "arrived",
                     "arrival_time_s": 5.0})
    df = pd.DataFrame(rows)
    df.attrs["params"] = ["controller", "seed"]
    objectives = (ParetoObjective.arrival_s, ParetoObjective.input_cpu_p95_ms,
                  ParetoObjective.step_cpu_p95_ms)
    pts = pareto_points(df, objectives, {}).set_index("controller")
    assert pts.loc["rti", "input_cpu_p95_ms"] == pytest.approx(0.3)
    assert pts.loc["rti", "step_cpu_p95_ms"] == pytest.approx(1.0)
    assert pts.loc["fatrop", "input_cpu_p95_ms"] == pytest.approx(2.0)
