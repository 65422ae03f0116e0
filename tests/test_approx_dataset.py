"""Dataset rows per run, and a merge that keeps every run's rows and drops none silently."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from omegaconf import OmegaConf

from conftest import compose_cfg
from mpclab.approx import dataset
from mpclab.record import files as record
from mpclab.runner.single_run import run_experiment


def fake_sweep(root: Path, seeds: list[int], extra: list[str] = ()) -> list[Path]:
    """Real runs laid out like a Hydra sweep (run folder with .hydra/config.yaml)."""
    dirs = []
    for i, seed in enumerate(seeds):
        cfg = compose_cfg(
            [
                "+experiment=car_cvxpy",
                "recorder=dataset",
                "figures.enabled=false",
                "progress=false",
                f"seed={seed}",
                "scenario.t_max=0.5",
                *extra,
            ]
        )
        d = root / str(i)
        (d / ".hydra").mkdir(parents=True)
        OmegaConf.save(cfg, d / ".hydra" / "config.yaml")
        run_experiment(cfg, d)
        dirs.append(d)
    return dirs


def test_recorder_writes_one_row_per_controller_call(tmp_path: Path) -> None:
    (d,) = fake_sweep(tmp_path, [0])
    rows = pd.read_parquet(d / dataset.ROWS)
    steps = pd.read_parquet(d / "steps.parquet")
    calls = record.controller_steps(steps)
    assert len(rows) == len(calls) == 5
    np.testing.assert_array_equal(rows[["x", "y", "theta"]], calls[["px", "py", "theta"]])
    np.testing.assert_array_equal(rows[["a", "phi_dot"]], calls[["a", "phi_dot"]])
    assert (rows["run_status"] == "timeout").all() and (rows["status"] == "converged").all()


def test_merge_keeps_every_run_and_reports_runs_without_rows(tmp_path: Path) -> None:
    sweep = tmp_path / "sweep"
    dirs = fake_sweep(sweep, [3, 4, 5])
    # a job that failed before writing rows: its folder has a config but no dataset
    failed = sweep / "9"
    (failed / ".hydra").mkdir(parents=True)
    (failed / ".hydra" / "config.yaml").write_text((dirs[0] / ".hydra" / "config.yaml").read_text())
    out = tmp_path / "data.parquet"
    report = dataset.merge([sweep], out)
    data, meta = dataset.read(out)
    per_run = [len(pd.read_parquet(d / dataset.ROWS)) for d in dirs]
    assert report.rows == len(data) == sum(per_run)
    assert report.runs == 3 and meta["runs"] == 3
    assert sorted(data["seed"].unique()) == [3, 4, 5]
    assert data.groupby("run").size().to_dict() == {
        str(d): n for d, n in zip(dirs, per_run, strict=True)
    }
    assert report.missing == [str(failed)] and meta["missing"] == [str(failed)]
    assert len(report.config_hashes) == 1  # seeds differ, the generating config does not


def test_rows_keep_the_hash_of_the_config_that_made_them(tmp_path: Path) -> None:
    """A resumed sweep rewrites .hydra/config.yaml; the rows keep their generating config."""
    sweep = tmp_path / "sweep"
    old, new = fake_sweep(sweep, [1, 2])
    made = dataset.config_hash(old)
    assert set(pd.read_parquet(old / dataset.ROWS)["config_hash"]) == {made}
    # what Hydra does when a later sweep with a changed config passes over a finished job
    cfg = OmegaConf.load(new / ".hydra" / "config.yaml")
    cfg.controller.horizon = 7
    OmegaConf.save(cfg, new / ".hydra" / "config.yaml")
    assert dataset.config_hash(new) != made
    report = dataset.merge([sweep], tmp_path / "data.parquet")
    assert report.config_hashes == [made]
    # rows written without a hash (an older recorder) fall back to the saved config's
    legacy = pd.read_parquet(new / dataset.ROWS).drop(columns="config_hash")
    legacy.to_parquet(new / dataset.ROWS, index=False)
    report = dataset.merge([sweep], tmp_path / "data2.parquet")
    assert report.config_hashes == sorted({made, dataset.config_hash(new)})


def test_merge_of_nothing_is_an_error(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match="no run folders"):
        dataset.merge([tmp_path], tmp_path / "x.parquet")
