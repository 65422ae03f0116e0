"""A small sweep on a local Ray cluster through Hydra's Ray launcher (``--extra ray``).

Skipped where the extra is not installed (``.ci/run``'s second stage installs it and requires
it, see tests/conftest.py).
"""

from __future__ import annotations

from pathlib import Path

import pandas as pd
import pytest
from test_sweep import sweep

pytestmark = pytest.mark.slow

@pytest.mark.needs("ray")
def test_sweep_on_a_local_ray_cluster(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("RAY_ADDRESS", raising=False)  # no cluster given: a local one
    out = sweep("+experiment=car_cvxpy", "+ci=smoke", "seed=0,1", "controller.horizon=10,-1",
                "hydra/launcher=ray_cluster", f"hydra.sweep.dir={tmp_path}", timeout=400)
    assert "Ray Launcher is launching 4 jobs" in out
    assert "Started a local Ray instance" in out
    df = pd.read_parquet(tmp_path / "summary.parquet")
    assert len(df) == 4
    ok = df[df["controller.horizon"] == 10]
    assert (ok["status"] != "error").all() and sorted(ok["seed"]) == [0, 1]
    bad = df[df["controller.horizon"] == -1]
    assert (bad["status"] == "error").all()
    assert bad["error"].str.startswith("controller.horizon must be >= 1").all()
    assert "4/4 jobs done, 2 failed" in out
