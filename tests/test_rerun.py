"""Rerun recordings read back with ``rerun.chunk.RrdReader`` and checked against the run record.

The car run checks what every run holds (horizons, path, poses, series, blueprint, config);
a fake scenario stands in for the Zumo and bicycle hooks (obstacles, rays, detections,
reference, m-line, supervisor modes); the merge test checks a two-run sweep file.
"""

from __future__ import annotations

import json
import subprocess
import sys
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest
from rerun.chunk import RrdReader

from conftest import compose_cfg
from mpclab.cli.merge import main as merge_main
from mpclab.controllers.base import SolveStatus
from mpclab.core.errors import ConfigError
from mpclab.record import files as record
from mpclab.recorders import rerun_blueprint as ent
from mpclab.recorders.merge import run_labels
from mpclab.recorders.rerun import RRD, RerunRecorder
from mpclab.runner.loop import simulate
from mpclab.runner.single_run import build_run
from mpclab.supervisors.base import Supervisor
from mpclab.world.scenario import Scenario

TOL = 1e-5  # positions are stored as float32


def read_rrd(path: Path) -> dict[str, list[dict[str, Any]]]:
    """``{entity path: rows}``, each row a dict of its columns; temporal rows sorted by step."""
    rows: dict[str, list[dict[str, Any]]] = defaultdict(list)
    for chunk in RrdReader(path).stream():
        data = chunk.to_record_batch().to_pydict()
        for i in range(chunk.num_rows):
            rows[chunk.entity_path].append({k: v[i] for k, v in data.items()})
    for entity in rows:
        rows[entity].sort(key=lambda r: (r.get(ent.STEP) is not None, r.get(ent.STEP) or 0))
    return dict(rows)


def temporal(rows: dict[str, list[dict[str, Any]]], entity: str) -> list[dict[str, Any]]:
    return [r for r in rows[f"/{entity}"] if r.get(ent.STEP) is not None]


def static(rows: dict[str, list[dict[str, Any]]], entity: str, component: str) -> Any:
    values = [r[component] for r in rows[f"/{entity}"] if r.get(component) is not None]
    return values[-1]


def verify(path: Path) -> None:
    """``rerun rrd verify`` (the CLI that comes with rerun-sdk) accepts the file."""
    res = subprocess.run([sys.executable, "-m", "rerun", "rrd", "verify", str(path)],
                         capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stdout + res.stderr


def test_car_recording_matches_run_record(run_cfg):
    result, out = run_cfg(["+experiment=car_cvxpy", "recorder=rerun", "recorder.batch_steps=7"])
    rrd = out / RRD
    verify(rrd)
    reader = RrdReader(rrd)
    assert len(reader.recordings()) == 1 and len(reader.blueprints()) == 1
    rows = read_rrd(rrd)
    steps, hz = record.read_steps(out), pd.read_parquet(out / record.HORIZONS)
    n, H = result.summary["n_steps"], 10  # car_cvxpy: controller.horizon = 10
    assert n > 7  # several batches were sent

    horizons = temporal(rows, ent.HORIZON)
    assert [r[ent.STEP] for r in horizons] == list(range(n))
    for r in horizons:
        (strip,) = r["LineStrips2D:strips"]
        assert len(strip) == H + 1
        h = hz[hz["step"] == r[ent.STEP]]
        np.testing.assert_allclose(strip, h[["px", "py"]].to_numpy(), atol=TOL, rtol=TOL)

    path = temporal(rows, ent.PATH)
    assert len(path) == n + 1
    np.testing.assert_allclose(path[-1]["LineStrips2D:strips"][0][-1],
                               steps.iloc[-1][["px", "py"]].to_numpy(float), atol=TOL)
    # consecutive segments join: each starts where the previous ended
    for a, b in zip(path[:-1], path[1:], strict=True):
        assert a["LineStrips2D:strips"][0][1] == b["LineStrips2D:strips"][0][0]

    poses = temporal(rows, ent.VEHICLE)
    origins = np.array([r["Arrows2D:origins"][0] for r in poses])
    np.testing.assert_allclose(origins, steps[["px", "py"]].to_numpy(), atol=TOL)
    vec = np.array([r["Arrows2D:vectors"][0] for r in poses])
    np.testing.assert_allclose(np.arctan2(vec[:, 1], vec[:, 0]),
                               np.angle(np.exp(1j * steps["theta"].to_numpy())), atol=1e-5)
    assert [r["sim_time"] for r in poses] == [pd.Timedelta(seconds=t) for t in steps["t"]]

    solve = [r["Scalars:scalars"][0] for r in temporal(rows, ent.SOLVE_TIME)]
    np.testing.assert_allclose(solve, 1e3 * steps["solve_time_s"].to_numpy()[:n])
    a = [r["Scalars:scalars"][0] for r in temporal(rows, f"{ent.INPUTS}/a")]
    np.testing.assert_allclose(a, steps["a"].to_numpy()[:n])
    (end,) = temporal(rows, ent.RUN_LOG)
    arrival = result.summary["arrival_time_s"]
    assert end[ent.STEP] == n
    s = result.summary
    solves = ", ".join(f"{s[f'solves_{st}']} {st}" for st in SolveStatus if s[f"solves_{st}"])
    assert end["TextLog:text"] == [f"run ended: arrived at t = {arrival:.2f} s; "
                                   f"solves: {solves}"]
    quality = [r["Scalars:scalars"][0] for r in temporal(rows, ent.SOLVE_QUALITY)]
    calls = record.controller_steps(steps)
    expect = np.where(calls["fallback"], 0.0, np.where(calls["status"] == "converged", 2.0, 1.0))
    np.testing.assert_array_equal(quality, expect)
    assert len(static(rows, ent.OBSTACLES, "Points2D:positions")) == 0  # the car's world
    assert "name: car_cvxpy" in static(rows, ent.CONFIG, "TextDocument:text")[0]
    assert "rerun-sdk" in static(rows, ent.CONFIG, "TextDocument:text")[0]


class FakeWorld(Scenario):
    """Stand-in for the Zumo/bicycle hooks: discs, a 5-ray sensor, a reference."""

    obstacles = np.array([[-6.0, 9.0, 0.5], [-4.0, 12.0, 1.0], [5.0, 5.0, 0.3]])
    RANGE = 6.0

    def detect(self, x):
        c = self.obstacles[:, :2]
        d = np.linalg.norm(c - x[:2], axis=1)
        near = d < self.RANGE
        return c[near] - (self.obstacles[near, 2] / d[near])[:, None] * (c[near] - x[:2])

    def rays(self, x):
        ang = x[2] + np.deg2rad([-60, -30, 0, 30, 60])
        return x[:2] + 2.0 * np.stack([np.cos(ang), np.sin(ang)], axis=1)

    def reference_table(self):
        t = np.arange(0, 16) * 0.1
        return pd.DataFrame({"t": t, "px": -10 + t, "py": 10 - 0.5 * t, "v": np.ones_like(t)})


class FakeBug(Supervisor):
    mline = ((-10.0, 10.0), (0.0, 0.0))

    def update(self, t, x, detections):
        return ("goal" if t < 0.45 else "follow"), None


def test_hooks_are_recorded(tmp_path):
    cfg = compose_cfg(["+experiment=car_cvxpy", "controller.horizon=6", "progress=false"])
    out = tmp_path / "fake"
    run = build_run(cfg, out)
    assert isinstance(run.recorder, RerunRecorder)  # the default recorder
    run.scenario = FakeWorld(run.plant, "fake", start={"px": -10.0, "py": 10.0},
                             goal={"px": 0.0, "py": 0.0}, arrival={"weights": {"px": 1.0}},
                             t_max=1.0)
    run.supervisor = FakeBug()
    try:
        res = simulate(run)
    finally:
        run.recorder.close()
    verify(out / RRD)
    rows = read_rrd(out / RRD)
    scen, n = run.scenario, res.summary["n_steps"]
    X = res.steps[list(run.plant.states)].to_numpy()

    np.testing.assert_allclose(static(rows, ent.OBSTACLES, "Points2D:positions"),
                               scen.obstacles[:, :2])
    np.testing.assert_allclose(static(rows, ent.OBSTACLES, "Points2D:radii"),
                               scen.obstacles[:, 2])
    np.testing.assert_allclose(static(rows, ent.MLINE, "LineStrips2D:strips")[0], FakeBug.mline)
    ref = scen.reference_table()
    np.testing.assert_allclose(static(rows, ent.REFERENCE_PATH, "LineStrips2D:strips")[0],
                               ref[["px", "py"]].to_numpy(), atol=TOL)
    v_ref = temporal(rows, f"{ent.STATES}/v/reference")
    assert [r[ent.STEP] for r in v_ref] == list(range(len(ref)))
    assert f"/{ent.STATES}/theta/reference" not in rows  # no theta column in the reference

    rays = temporal(rows, ent.RAYS)
    dets = temporal(rows, ent.DETECTIONS)
    assert len(rays) == len(dets) == n
    for k in range(n):
        strips = np.array(rays[k]["LineStrips2D:strips"])
        assert strips.shape == (5, 2, 2)
        np.testing.assert_allclose(strips[:, 0], np.tile(X[k, :2], (5, 1)), atol=TOL)
        np.testing.assert_allclose(strips[:, 1], scen.rays(X[k]), atol=TOL)
        got = np.array(dets[k]["Points2D:positions"] or np.zeros((0, 2))).reshape(-1, 2)
        np.testing.assert_allclose(got, scen.detect(X[k]), atol=TOL)
    assert any(len(d["Points2D:positions"] or []) for d in dets)

    modes = res.steps["mode"].iloc[:n]
    changes = [k for k in range(n) if k == 0 or modes.iloc[k] != modes.iloc[k - 1]]
    log = temporal(rows, ent.MODE_LOG)
    assert [r[ent.STEP] for r in log] == changes
    assert [r["TextLog:text"][0] for r in log] == ["mode: goal", "mode: follow"]


def test_plant_without_heading_is_drawn_as_points(tmp_path):
    cfg = compose_cfg(["+experiment=car_cvxpy", "controller.horizon=4", "scenario.t_max=0.5"])
    run = build_run(cfg, tmp_path)
    run.plant.heading = None  # as a plant without a heading state declares it
    try:
        res = simulate(run)
    finally:
        run.recorder.close()
    rows = read_rrd(tmp_path / RRD)
    poses = temporal(rows, ent.VEHICLE)
    assert len(poses) == res.summary["n_steps"] + 1
    assert all("Arrows2D:origins" not in r for r in poses)
    np.testing.assert_allclose([r["Points2D:positions"][0] for r in poses],
                               res.steps[["px", "py"]].to_numpy(), atol=TOL)
    np.testing.assert_allclose(static(rows, ent.GOAL, "Points2D:positions"), [[0.0, 0.0]])


def test_merge_with_nothing_to_merge_is_one_message(tmp_path, capsys):
    for args in ([str(tmp_path / "nope")], [str(tmp_path)]):  # no such path; no run.rrd below
        with pytest.raises(SystemExit) as stop:
            merge_main(args)
        assert stop.value.code == 2
        err = capsys.readouterr().err
        assert "error:" in err and str(tmp_path) in err and "Traceback" not in err


def test_merge_puts_each_run_under_its_prefix(run_cfg, tmp_path):
    runs = {}
    for horizon in (5, 8):
        result, out = run_cfg(["+experiment=car_cvxpy", "recorder=rerun",
                               f"controller.horizon={horizon}", "scenario.t_max=1.0"],
                              name=f"h{horizon}")
        runs[horizon] = (result, out)
    merged = tmp_path / "both.rrd"
    assert merge_main([str(runs[5][1]), str(runs[8][1] / RRD), "-o", str(merged)]) == 0
    verify(merged)
    reader = RrdReader(merged)
    assert [r.application_id for r in reader.recordings()] == ["mpclab_sweep"]
    assert len(reader.blueprints()) == 1
    rows = read_rrd(merged)
    labels = run_labels([runs[5][1] / RRD, runs[8][1] / RRD])  # no .hydra: folder names
    assert labels == ["car_cvxpy_h5", "car_cvxpy_h8"]
    assert {p.split("/")[1] for p in rows} == {*labels, "__properties"}
    for label, horizon in zip(labels, (5, 8), strict=True):
        hz = temporal(rows, f"{label}/{ent.HORIZON}")
        assert len(hz) == runs[horizon][0].summary["n_steps"]
        assert {len(r["LineStrips2D:strips"][0]) for r in hz} == {horizon + 1}


def test_labels_from_differing_overrides(tmp_path):
    rrds = []
    for i, over in enumerate(["controller=cvxpy", "controller=casadi", "controller=nn"]):
        d = tmp_path / str(i)
        d.mkdir()
        if i < 2:  # Hydra's record of the overrides, or the sweep's summary.json
            (d / ".hydra").mkdir()
            (d / ".hydra" / "overrides.yaml").write_text(f"- +experiment=zumo\n- {over}\n")
        else:
            (d / "summary.json").write_text(json.dumps(
                {"experiment": "zumo", "overrides": ["+experiment=zumo", over]}))
        rrds.append(d / RRD)
    assert run_labels(rrds) == ["controller_cvxpy", "controller_casadi", "controller_nn"]


def test_recorder_config():
    assert compose_cfg([]).recorder._target_ == "mpclab.recorders.rerun.RerunRecorder"
    smoke = compose_cfg(["+experiment=car_cvxpy", "+ci=smoke"])
    assert smoke.recorder._target_ == "mpclab.recorders.base.Recorder"
    with pytest.raises(ConfigError, match="batch_steps"):
        RerunRecorder(batch_steps=0)
