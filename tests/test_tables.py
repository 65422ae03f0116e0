"""Aggregation of run records into tables: mixed sweeps, missing files, grouped statistics.

The run records here are written by hand, so every expected number is known independently
of mpclab: pooled step times are checked against numpy on the same arrays.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml

from mpclab import tables
from mpclab.cli import tables as report
from mpclab.record import files as record


def _run(
    job_dir: Path, overrides: list[str], summary: dict | None, solve_ms: list[float] | None,
) -> None:
    """A Hydra-like job folder: .hydra/overrides.yaml, summary.json, steps.parquet."""
    (job_dir / ".hydra").mkdir(parents=True)
    (job_dir / ".hydra" / "overrides.yaml").write_text(yaml.safe_dump(overrides))
    if summary is not None:
        (job_dir / "summary.json").write_text(json.dumps(summary))
    if solve_ms is not None:
        n = len(solve_ms)
        pd.DataFrame({
            "t": np.arange(n + 1) * 0.1,
            "solve_time_s": [*(np.asarray(solve_ms) / 1e3), np.nan],
            "status": ["optimal"] * n + [record.FINAL],
        }).to_parquet(job_dir / "steps.parquet")


def _summary(controller: str, seed: int, status: str, arrival: float | None, **extra) -> dict:
    return {
        "experiment": "car", "plant": "kinematic_car", "controller": controller,
        "scenario": "to_origin", "seed": seed, "status": status, "arrived": status == "arrived",
        "arrival_time_s": arrival, "compute_median_ms": 2.0, "rtf": 0.02, "error": None,
        "final_state": {"px": 0.1, "py": -0.2}, "versions": {"numpy": "x"}, **extra,
    }


#: solve times (ms) of the hand-made runs, by (controller, seed)
SOLVE = {
    ("cvxpy", 0): [1.0, 2.0, 3.0], ("cvxpy", 1): [4.0, 5.0],
    ("casadi", 0): [10.0, 30.0, 20.0, 40.0], ("casadi", 1): [50.0],
}


@pytest.fixture
def outputs(tmp_path: Path) -> Path:
    """Two sweeps with different override keys, plus broken and unreadable job folders."""
    a = tmp_path / "multirun" / "a"
    a.mkdir(parents=True)
    (a / "multirun.yaml").write_text("hydra: {}\n")
    jobs = [("cvxpy", 1, 3.0), ("cvxpy", 0, 2.9), ("casadi", 0, 4.0), ("casadi", 1, None)]
    for num, (ctrl, seed, arrival) in enumerate(jobs):
        status = "arrived" if arrival is not None else "timeout"
        _run(a / str(num), [f"controller={ctrl}", f"seed={seed}"],
             _summary(ctrl, seed, status, arrival), SOLVE[(ctrl, seed)])
    # a job whose process died before writing summary.json
    _run(a / "4", ["controller=cvxpy", "seed=2"], None, None)
    choices = {"plant": "kinematic_car", "controller": "cvxpy", "scenario": "to_origin"}
    (a / "4" / ".hydra" / "hydra.yaml").write_text(
        yaml.safe_dump({"hydra": {"runtime": {"choices": choices}}}))
    # an error row written by the sweep (no steps at all)
    _run(a / "5", ["controller=cvxpy", "seed=3"],
         {**_summary("cvxpy", 3, "error", None), "error": "ValueError: horizon must be >= 1"},
         None)
    b = tmp_path / "multirun" / "b"
    b.mkdir(parents=True)
    (b / "multirun.yaml").write_text("hydra: {}\n")
    for num, horizon in enumerate([20, 5]):
        _run(b / str(num), [f"controller.horizon={horizon}"],
             _summary("cvxpy", 0, "arrived", 3.5 if horizon == 5 else 3.2), [1.0])
    (b / "2" / ".hydra").mkdir(parents=True)
    (b / "2" / "summary.json").write_text("{not json")
    return tmp_path


def test_collect_mixed_sweeps_and_missing_files(outputs: Path) -> None:
    df = tables.collect([outputs], root=outputs)
    assert len(df) == 9
    assert df.attrs["params"] == ["controller", "seed", "controller.horizon"]
    # sweep a sorted by its parameters (controller, then seed), not by job number
    a = df[df["sweep_dir"] == "multirun/a"]
    assert list(zip(a["controller"], a["seed"], strict=True)) == [
        ("casadi", 0), ("casadi", 1), ("cvxpy", 0), ("cvxpy", 1), ("cvxpy", 2), ("cvxpy", 3),
    ]
    assert list(a["job"]) == ["2", "3", "1", "0", "4", "5"]
    missing = a[a["seed"] == 2].iloc[0]
    assert missing["status"] == tables.INCOMPLETE and "no summary.json" in missing["error"]
    assert missing["scenario"] == "to_origin"  # from Hydra's record of the job
    assert a[a["seed"] == 3].iloc[0]["error"].startswith("ValueError")
    b = df[df["sweep_dir"] == "multirun/b"]
    assert list(b["controller.horizon"].iloc[:2]) == [5, 20]  # numeric, sorted numerically
    assert b["controller.horizon"].isna().iloc[2]  # the unreadable record has no overrides
    assert b.iloc[2]["status"] == tables.INCOMPLETE
    assert "unreadable summary.json" in b.iloc[2]["error"]
    assert a["controller.horizon"].isna().all()  # a key sweep a never overrode
    assert "final_state.px" in df and "versions" not in df
    assert df["backend"].tolist() == df["controller"].fillna("?").tolist()


def test_a_summary_that_is_not_a_run_record_is_an_incomplete_row(tmp_path: Path) -> None:
    # valid JSON that mpclab did not write as a run's summary: a list, a dict with no status
    for name, text in (("list", "[1, 2]"), ("other", '{"experiment": "zumo"}')):
        (tmp_path / name).mkdir()
        (tmp_path / name / "summary.json").write_text(text)
    df = tables.collect([tmp_path], root=tmp_path)
    assert len(df) == 2 and (df["status"] == tables.INCOMPLETE).all()
    assert df["error"].str.contains("not a run summary").all()


def test_group_table_pools_step_times(outputs: Path) -> None:
    df = tables.collect([outputs / "multirun" / "a"])
    groups = tables.group_table(df).set_index("backend")
    cas = groups.loc["casadi"]
    pooled = np.array(SOLVE[("casadi", 0)] + SOLVE[("casadi", 1)])
    assert cas["runs"] == 2 and cas["arrived"] == 1 and cas["success_rate"] == 0.5
    assert cas["arrival_median_s"] == 4.0
    assert cas["step_median_ms"] == pytest.approx(np.median(pooled))
    assert cas["step_p95_ms"] == pytest.approx(np.percentile(pooled, 95))
    cvx = groups.loc["cvxpy"]
    assert (cvx["runs"], cvx["arrived"], cvx["errors"]) == (4, 2, 1)
    assert cvx["arrival_median_s"] == pytest.approx(np.median([3.0, 2.9]))
    pooled = np.array(SOLVE[("cvxpy", 0)] + SOLVE[("cvxpy", 1)])
    assert cvx["step_p95_ms"] == pytest.approx(np.percentile(pooled, 95))


def test_backend_names_the_solver_when_it_varies(tmp_path: Path) -> None:
    for num, solver in enumerate(["OSQP", "CLARABEL"]):
        _run(tmp_path / str(num), [f"controller.solver={solver}"],
             _summary("cvxpy", 0, "arrived", 3.0), [1.0])
    df = tables.collect([tmp_path])
    assert sorted(df["backend"]) == ["cvxpy:CLARABEL", "cvxpy:OSQP"]


def test_command_writes_every_file(outputs: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = outputs / "tables"
    assert report.main([str(outputs / "multirun"), "--out", str(out), "--x", "rtf"]) == 0
    for name in tables.FILES.values():
        assert (out / name).is_file(), name
    back = pd.read_parquet(out / "summary.parquet")
    assert len(back) == 9 and len(pd.read_csv(out / "summary.csv")) == 9
    assert (out / "arrival_vs_compute.png").read_bytes()[:4] == b"\x89PNG"
    md = (out / "summary.md").read_text()
    # sweep b varies the horizon: a group of its own per horizon
    assert "## By backend, scenario, controller.horizon" in md and "## Runs (9)" in md
    *table, stamp_line = md.rstrip().splitlines()  # stamped: command, commit, CPU, date
    assert stamp_line.startswith("`uv run python ") and " · commit " in stamp_line
    assert "| casadi " in md and "nan" not in "\n".join(table)
    assert "casadi" in capsys.readouterr().out


def test_command_refuses_an_empty_folder(tmp_path: Path) -> None:
    with pytest.raises(SystemExit):
        report.main([str(tmp_path)])
    with pytest.raises(FileNotFoundError, match="no such folder"):
        tables.collect([tmp_path / "nope"])


def test_command_names_an_output_folder_it_cannot_make(outputs: Path, tmp_path: Path,
                                                       capsys) -> None:
    blocker = tmp_path / "a_file"
    blocker.write_text("not a folder")
    with pytest.raises(SystemExit) as stop:
        report.main([str(outputs / "multirun"), "--out", str(blocker / "tables")])
    assert stop.value.code == 2
    err = capsys.readouterr().err
    assert str(blocker / "tables") in err and "Traceback" not in err


def test_groups_split_every_swept_parameter_but_the_seed(tmp_path: Path) -> None:
    for num, (horizon, seed, arrival) in enumerate([(10, 0, 3.0), (10, 1, 3.4), (20, 0, 2.0),
                                                    (20, 1, 2.2)]):
        _run(tmp_path / str(num), [f"controller.horizon={horizon}", f"seed={seed}"],
             _summary("cvxpy", seed, "arrived", arrival), [float(horizon)])
    df = tables.collect([tmp_path])
    assert tables.group_keys(df) == ["backend", "scenario", "controller.horizon"]
    groups = tables.group_table(df).set_index("controller.horizon")
    assert groups.loc[10, "runs"] == 2 and groups.loc[20, "runs"] == 2
    assert groups.loc[10, "arrival_median_s"] == pytest.approx(3.2)
    assert groups.loc[20, "step_median_ms"] == pytest.approx(20.0)


def test_streamed_rows_give_the_same_tables_as_the_folders(outputs: Path) -> None:
    sweep = outputs / "multirun" / "a"
    (sweep / ".mpclab").mkdir()
    for job in ("0", "1", "2", "3", "5"):  # not 4: its process died; it is read from disk
        tables.stream_row(sweep, sweep / job)
    streamed, step_ms = tables.collect_runs([sweep], root=sweep)
    assert sorted(step_ms) == sorted(str((sweep / j).resolve()) for j in ("0", "1", "2", "3", "5"))
    (sweep / tables.ROWS_FILE).unlink()
    folders, _ = tables.collect_runs([sweep], root=sweep)
    pd.testing.assert_frame_equal(streamed, folders)
    pd.testing.assert_frame_equal(tables.group_table(streamed, step_ms),
                                  tables.group_table(folders))
    # a job that ran again after its row was streamed is read from its folder
    tables.stream_row(sweep, sweep / "0")
    summary = json.loads((sweep / "0" / "summary.json").read_text())
    (sweep / "0" / "summary.json").write_text(json.dumps({**summary, "arrival_time_s": 9.9}))
    again = tables.collect([sweep], root=sweep).set_index("job")
    assert again.loc["0", "arrival_time_s"] == 9.9


def test_contended_runs_are_flagged() -> None:
    df = pd.DataFrame({
        "compute_cpu_share": [0.98, 0.5, 0.97, 0.99, None],
        "load.cores": [2, 2, 2, 2, 2],
        "load.workers": [2, 2, 4, 1, 1],
        "load.load_1m_start": [0.5, 0.5, 0.5, 3.5, 0.1],
        "load.load_1m_end": [1.2, 1.0, 1.0, 0.5, 0.1],
    })
    assert tables.contended(df).tolist() == [False, True, True, True, pd.NA]
    assert tables.contended(pd.DataFrame({"x": [1]})).isna().all()  # no timing recorded


def test_solve_times_are_the_controller_steps_of_the_log(tmp_path: Path) -> None:
    steps = pd.DataFrame({"solve_time_s": [1e-3, np.nan, 3e-3, 4e-3, 0.0],
                          "status": ["converged", "failed", None, "truncated", record.FINAL]})
    steps.to_parquet(tmp_path / record.STEPS)
    want = record.controller_steps(record.read_steps(tmp_path))["solve_time_s"].to_numpy()
    got = record.read_solve_times_s(tmp_path)
    assert len(got) == len(want) == 4
    assert np.allclose(got, want, equal_nan=True)


def test_safety_bench_table_pairs_rates_and_lists_failed_seeds() -> None:
    """experiments/safety/bench.py: per variant, counts, both intervals and the failed seeds."""
    import importlib.util
    import sys

    from mpclab.record.stats import clopper_pearson

    path = Path(__file__).resolve().parents[1] / "experiments" / "safety" / "bench.py"
    spec = importlib.util.spec_from_file_location("safety_bench", path)
    bench = importlib.util.module_from_spec(spec)
    sys.modules["safety_bench"] = bench  # its dataclass looks its module up
    spec.loader.exec_module(bench)
    assert bench.seeds_of("3:6") == [3, 4, 5] and bench.seeds_of("94,284") == [94, 284]

    def outcome(variant, seed, status, clearance):
        return bench.Outcome(variant, "zumo_random", seed, status,
                             3.0 if status == "arrived" else None, clearance,
                             np.array([1.0, 2.0, 3.0]), np.array([0.5, 1.0, 1.5]), 3, 3)

    outcomes = [outcome("a", 0, "arrived", 0.01), outcome("a", 1, "collision", -0.002),
                outcome("a", 2, "timeout", 0.02), outcome("b", 0, "arrived", 0.012),
                outcome("b", 1, "arrived", 0.013), outcome("b", 2, "stalled", 0.02)]
    text = bench.table(outcomes, ["a", "b"])
    lo, hi = clopper_pearson(1, 3)
    assert f"| a | 3 | 1 | 0.333 [{lo:.3f}, {hi:.3f}] | 1 | 0.3333 [{lo:.4f}, {hi:.4f}] | 1 | 0 |" \
        in text
    assert "| b | 3 | 2 | 0.667" in text and "| -2.0 |" in text and "| 12.0 |" in text
    assert "| 2.00 | 3.00 | 1.00 | 1.50 |" in text  # CPU per call, then to the input
    assert "- a, collision: zumo_random 1" in text and "- b, stalled: zumo_random 2" in text
