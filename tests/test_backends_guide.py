"""experiments/backends/guide.py: a backend's closed loops pooled, its cost gap from the
agreement harness, and docs/backends.md quoting the table the script wrote."""

from __future__ import annotations

import dataclasses
import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
_spec = importlib.util.spec_from_file_location(
    "backends_guide", ROOT / "experiments" / "backends" / "guide.py")
guide = importlib.util.module_from_spec(_spec)
sys.modules["backends_guide"] = guide  # dataclasses look their module up there
_spec.loader.exec_module(guide)

UNICYCLE = next(c for c in guide.CASES if c.plant == "unicycle")


def test_closed_loops_pool_the_backend_s_calls() -> None:
    row = guide.closed_loops(UNICYCLE, "casadi")
    assert row["problem"] == "nonlinear"
    assert row["runs"] == 1 and row["arrived"] == 1 and row["arrival_median_s"] > 0
    assert row["steps"] > 10 and 0.9 <= row["converged"] <= 1.0
    assert 0 < row["median_ms"] <= row["p95_ms"]


def test_gaps_come_from_the_agreement_harness() -> None:
    case = dataclasses.replace(UNICYCLE, samples={"unicycle_goal": [5]},
                               backends={b: UNICYCLE.backends[b] for b in ("casadi",
                                                                             "casadi_sqp")})
    g = guide.gaps(case)
    assert set(g.index) == {"casadi", "casadi_sqp"}
    assert (g["gap_states"] == 1).all()
    assert np.all(np.abs(g["gap_max"]) < 1e-5)  # converged NLP solvers reach the reference


def test_markdown_row_says_what_was_measured() -> None:
    import pandas as pd
    row = guide.closed_loops(UNICYCLE, "casadi") | {
        "gap_states": 3, "gap_median": 1e-9, "gap_max": 2e-9, "generated_c": None}
    text = guide.markdown(pd.DataFrame([row]))
    header, rule, line = text.splitlines()
    assert header.count("|") == rule.count("|") == line.count("|")
    assert "| unicycle | casadi | nonlinear |" in line and "1 of 1 | 0 |" in line


@pytest.mark.skipif(not (ROOT / "experiments" / "backends" / "results.md").exists(),
                    reason="the guide has not been run")
def test_docs_quote_the_table_the_guide_wrote() -> None:
    table = (ROOT / "experiments" / "backends" / "results.md").read_text().strip()
    assert table.splitlines()[-1].startswith("`uv run python experiments/backends/guide.py")
    assert table in (ROOT / "docs" / "backends.md").read_text()


def test_every_zumo_nlp_backend_has_a_row_label() -> None:
    """The Zumo gaps are read by zumo_nlp's labels: a renamed backend there must not lose
    its gap here."""
    assert set(guide.zumo_nlp.BACKENDS) | {"nn"} == set(guide.ZUMO_LABELS)
