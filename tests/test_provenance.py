"""The stamp under a result table: command, commit, CPU model and cores, date."""

from __future__ import annotations

import os
import re

from mpclab.record import provenance


def test_stamp_names_command_commit_cpu_and_date() -> None:
    argv = [str(provenance.ROOT / "experiments" / "x" / "bench.py"), "--md", "a b.md"]
    s = provenance.stamp(argv)
    assert s.startswith("`uv run python experiments/x/bench.py --md 'a b.md'` · commit ")
    assert provenance.cpu_model() in s
    assert f"{os.cpu_count()} cores" in s
    assert re.search(r"\d{4}-\d{2}-\d{2} \d{2}:\d{2} UTC$", s)


def test_a_module_of_the_package_is_named_as_run_with_dash_m() -> None:
    argv = [str(provenance.ROOT / "mpclab" / "approx" / "pipeline.py"), "--stages", "eval"]
    assert provenance.command(argv) == "uv run python -m mpclab.approx.pipeline --stages eval"


def test_write_stamped_prints_and_writes_the_table_with_its_stamp(tmp_path, capsys) -> None:
    table = "| a |\n|---|\n| 1 |"
    out = provenance.write_stamped(tmp_path / "sub" / "t.md", table, ["bench.py"])
    assert (tmp_path / "sub" / "t.md").read_text() == out
    assert out.startswith(table + "\n\n`uv run python bench.py` · commit ")
    assert out in capsys.readouterr().out
    assert provenance.write_stamped(None, table, ["bench.py"]).startswith(table)
    two = provenance.write_stamped(None, [table, "| b |\n|---|\n| 2 |"], ["bench.py"])
    first, second = two.split("| b |")
    assert first.startswith(table + "\n\n`uv run python bench.py` · commit ")
    assert second.count("· commit ") == 1  # each table under its own stamp


def test_a_file_this_command_rewrote_does_not_make_the_stamp_dirty(tmp_path, monkeypatch) -> None:
    path = tmp_path / "results.csv"
    path.write_text("x\n")
    monkeypatch.setattr(provenance, "STARTED", path.stat().st_mtime - 10)
    assert not provenance._changed_before(path)  # written after the command started
    monkeypatch.setattr(provenance, "STARTED", path.stat().st_mtime + 10)
    assert provenance._changed_before(path)
    assert provenance._changed_before(tmp_path / "deleted.csv")


def test_pages_and_results_do_not_make_the_stamp_dirty_code_and_inputs_do() -> None:
    for page in ("README.md", "docs/sweeps.md", "experiments/latency/results.md",
                 "experiments/pareto/zumo_grid.png", "experiments/bicycle/results.csv"):
        assert not provenance.computes(page), page
    for source in ("mpclab/runner/loop.py", "conf/controller/casadi.yaml",
                   "conf/sim/profiles/zumo_bug2_fatrop.csv", "experiments/latency/run_latency.py",
                   "pyproject.toml", "uv.lock", "conf/weights/zumo_nn.npz"):
        assert provenance.computes(source), source


def test_the_package_s_own_command_is_named_as_typed() -> None:
    argv = [str(provenance.ROOT / "mpclab" / "__main__.py"), "-m", "+experiment=car_cvxpy"]
    assert provenance.command(argv) == "uv run python -m mpclab -m +experiment=car_cvxpy"
