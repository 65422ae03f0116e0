"""One multirun job in-process: an exception becomes an error row; resume skips complete records."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from hydra.core.override_parser.overrides_parser import OverridesParser

from conftest import compose_cfg
from mpclab.sweeps import jobs
from mpclab.sweeps.expand import sweep_dir_override

BASE = ["+experiment=car_cvxpy", "+ci=smoke"]
CHOICES = {"plant": "kinematic_car", "controller": "cvxpy", "scenario": "car_to_origin"}


def run(out: Path, *overrides: str) -> dict:
    return jobs.run_job(compose_cfg([*BASE, *overrides]), out, [*BASE, *overrides], CHOICES)


def mtime(out: Path) -> int:
    return (out / "steps.parquet").stat().st_mtime_ns


def test_a_raising_job_writes_an_error_row(tmp_path: Path) -> None:
    s = run(tmp_path, "controller.horizon=-1")
    on_disk = json.loads((tmp_path / "summary.json").read_text())
    assert s["status"] == on_disk["status"] == "error"
    assert on_disk["error"] == ("controller.horizon must be >= 1, got -1 "
                                "(set in the command line (controller.horizon=-1))")
    assert on_disk["controller"] == "cvxpy" and on_disk["experiment"] == "car_cvxpy"
    assert on_disk["overrides"] == [*BASE, "controller.horizon=-1"]
    assert not (tmp_path / "steps.parquet").exists()


def test_resume_skips_only_a_complete_record_of_the_same_job(tmp_path: Path) -> None:
    first = run(tmp_path, "seed=1")
    assert first["status"] != "error" and "skipped" not in first
    t0 = mtime(tmp_path)
    again = run(tmp_path, "seed=1", "progress=true")  # how it runs is not what it computes
    assert again["skipped"] and mtime(tmp_path) == t0
    assert {k: v for k, v in again.items() if k != "skipped"} == json.loads(
        (tmp_path / "summary.json").read_text())
    forced = run(tmp_path, "seed=1", "resume=false")
    assert "skipped" not in forced and mtime(tmp_path) > t0
    t1 = mtime(tmp_path)
    other = run(tmp_path, "seed=2")  # a different job in the same folder: run, not reused
    assert "skipped" not in other and other["seed"] == 2 and mtime(tmp_path) > t1


def test_an_error_row_is_run_again(tmp_path: Path) -> None:
    assert run(tmp_path, "controller.horizon=-1")["status"] == "error"
    # the same folder and overrides, the cause fixed (as after editing a config)
    s = jobs.run_job(compose_cfg(BASE), tmp_path, [*BASE, "controller.horizon=-1"], CHOICES)
    assert s["status"] != "error" and (tmp_path / "steps.parquet").is_file()


def test_a_torn_summary_is_not_complete(tmp_path: Path) -> None:
    (tmp_path / "summary.json").write_text('{"status": "arr')
    assert jobs.complete_summary(tmp_path, BASE) is None
    # whole JSON, but not a run's summary: run again too
    (tmp_path / "summary.json").write_text(json.dumps({"overrides": list(BASE)}))
    assert jobs.complete_summary(tmp_path, BASE) is None
    (tmp_path / "summary.json").write_text("[]")
    assert jobs.complete_summary(tmp_path, BASE) is None


def test_an_error_row_names_its_backend_as_a_finished_run_does() -> None:
    # zumo_bug2 chooses controller=casadi_fatrop, a CasadiMPC: a finished run's row says
    # "casadi", and a failed one must too, or the tables put it in a group of its own
    base = ["+experiment=zumo_bug2", "+ci=smoke"]
    cfg = compose_cfg(base)
    choices = {"plant": "zumo", "controller": "casadi_fatrop", "scenario": "zumo_dead_end"}
    exc = ValueError("boom")
    from_job = jobs.error_summary(exc, base, cfg, choices)
    assert (from_job["controller"], from_job["plant"]) == ("casadi", "zumo")
    # a job whose config did not compose: named from the sweep's config...
    bad_value = jobs.error_summary(exc, [*base, "controller.horizon=ten"], None, choices, cfg)
    assert bad_value["controller"] == "casadi"
    # ...unless the job chose that group itself: then by its choice
    bad_group = jobs.error_summary(exc, [*base, "controller=nope"], None, choices, cfg)
    assert bad_group["controller"] == "nope" and bad_group["plant"] == "zumo"
    assert jobs.error_summary(exc, base, None, choices)["controller"] == "casadi_fatrop"


@pytest.mark.parametrize("folder", ["outputs/multirun/run/2026-11-28_10-00-00",
                                    "/tmp/my sweeps/it's here", "/tmp/a=b,c"])
def test_the_pinned_sweep_folder_parses_back_to_itself(folder: str) -> None:
    """Every job of a sweep is pinned to the sweep's folder by an override; Hydra's parser
    reads that override back as the same path, spaces, quotes and commas included."""
    (override,) = OverridesParser.create().parse_overrides([sweep_dir_override(folder)])
    assert override.key_or_group == "hydra.sweep.dir"
    assert not override.is_sweep_override() and override.value() == folder
