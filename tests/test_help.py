"""``--help`` describes the command line it is given; a mistyped key gets a did-you-mean."""

from __future__ import annotations

from pathlib import Path

import pytest

from mpclab.cli.app import cli


def help_of(capsys: pytest.CaptureFixture, *args: str) -> str:
    assert cli([*args, "--help"]) == 0
    return capsys.readouterr().out


def test_help_shows_the_experiment_chosen_and_its_controllers_options(capsys) -> None:
    text = help_of(capsys, "+experiment=car_cvxpy", "controller.horizon=7")
    assert "The config of: +experiment=car_cvxpy controller.horizon=7" in text
    assert "name: car_cvxpy" in text and "horizon: 7" in text
    assert "Options of controller mpclab.controllers.cvxpy.mpc.CvxpyMPC" in text
    line = next(ln for ln in text.splitlines() if ln.strip().startswith("solve.max_iterations"))
    assert "truncated" in line  # an option group's field, its meaning from the group's docstring
    line = next(ln for ln in text.splitlines() if ln.strip().startswith("sl "))
    assert "converge" in line  # its meaning, from the constructor's docstring
    assert not any(ln.strip().startswith("plant") for ln in text.splitlines()
                   if "Options of" not in ln and ln.startswith("  plant,"))


def test_help_lists_the_experiments_of_a_folder_added_with_cd(capsys, tmp_path: Path) -> None:
    (tmp_path / "experiment").mkdir()
    (tmp_path / "experiment" / "mine.yaml").write_text(
        "# @package _global_\n# My own car run.\ndefaults:\n  - car_cvxpy\n  - _self_\n"
        "name: mine\n")
    text = help_of(capsys, "-cd", str(tmp_path), "+experiment=mine")
    assert f"in {tmp_path}:" in text and "My own car run." in text
    assert "name: mine" in text


def test_a_mistyped_key_gets_mpclabs_did_you_mean(capsys) -> None:
    assert cli(["+experiment=car_cvxpy", "+ci=smoke", "controller.horizn=5"]) == 2
    err = capsys.readouterr().err
    assert "unknown key 'horizn' in controller. Did you mean 'horizon'?" in err
    assert "Traceback" not in err and "+controller.horizn" not in err


def test_the_end_of_run_line_is_in_words() -> None:
    from mpclab.cli.app import summary_line

    s = {"status": "arrived", "arrival_time_s": 10.4, "n_steps": 52, "solves_converged": 50,
         "solves_truncated": 2, "solver_failures": 0, "compute_median_ms": 1.6052524,
         "compute_p95_ms": 3.2, "sim": "realistic", "latency_median_ms": 2.16,
         "deadline_misses": 3}
    line = summary_line(s)
    assert line.startswith("arrived in 10.4 s | 50 of 52 solves converged (2 truncated)")
    assert "1.61 ms per step (p95 3.20 ms)" in line
    assert "sim realistic: latency 2.16 ms median, 3 deadline misses" in line
    nominal = summary_line({**s, "sim": "nominal", "status": "timeout", "sim_time_s": 60.0})
    assert nominal.startswith("timeout at 60 s") and "sim" not in nominal
    # the nominal preset with a latency set on the command line is not the ideal loop
    late = summary_line({**s, "sim": "nominal", "sim_latency": "50 ms", "deadline_misses": 0,
                         "latency_median_ms": 50.0})
    assert line.count("|") == late.count("|")
    assert "sim nominal: latency 50 ms median, 0 deadline misses" in late


def test_the_end_of_run_line_rounds_to_three_digits() -> None:
    from mpclab.cli.app import milliseconds, seconds

    assert [milliseconds(v) for v in (0.0163042, 0.004, 1.6052524, 9.996, 12.34, 123.4)] == [
        "0.0163", "0.00400", "1.61", "10", "12", "123"]
    assert [seconds(v) for v in (9.88, 10.2000000001, 10.0)] == ["9.88", "10.2", "10"]


def test_a_bad_constraint_option_names_its_key_and_where_it_was_set(capsys) -> None:
    assert cli(["+experiment=zumo_bug2", "+ci=smoke", "objective.constraints.obstacles.mode=sofft"]
               ) == 2
    err = capsys.readouterr().err
    assert "objective.constraints.obstacles: mode: unknown choice 'sofft'; valid: hard" in err
    assert "the command line (objective.constraints.obstacles.mode=sofft)" in err
