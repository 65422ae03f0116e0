"""Faults: injected solver failures in every backend, a controller that never solves, Ctrl-C,
an output folder that cannot be written or fills up, and the long-run notice."""

from __future__ import annotations

import errno
import json
import logging
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow.parquet as pq
import pytest
from matplotlib.figure import Figure

from conftest import compose_cfg
from mpclab.cli.app import EXIT_BAD_INPUT, EXIT_INTERRUPTED, EXIT_RUN_FAILED, cli
from mpclab.controllers.casadi.mpc import CasadiMPC
from mpclab.controllers.cvxpy.mpc import CvxpyMPC
from mpclab.controllers.nn.controller import NNController
from mpclab.controllers.scheduled.mpc import ScheduledMPC
from mpclab.plants.base import Plant
from mpclab.record import files as record
from mpclab.recorders.rerun import RerunRecorder
from mpclab.runner import progress as progress_module
from mpclab.runner.progress import RunProgress
from mpclab.runner.single_run import run_experiment
from mpclab.sweeps.jobs import run_job

BACKENDS = [
    ("car_cvxpy", CvxpyMPC),
    ("car_casadi", CasadiMPC),
    ("bicycle_scheduled", ScheduledMPC),
    ("zumo_nn", NNController),
]


def inject(monkeypatch, cls: type, plan: dict[int, str]) -> None:
    """Make ``cls._solve`` fail on the calls named in ``plan`` (1-based): ``raise`` raises,
    ``nan`` returns the real result labelled as it was but with a NaN input, ``ctrl-c``
    raises KeyboardInterrupt (``ctrl-c-casadi-*``: as CasADi hands it back), ``always``
    raises on every call."""
    real = cls._solve
    calls = {"n": 0}

    def faulty(self, t, x, ctx):
        calls["n"] += 1
        what = plan.get(calls["n"], plan.get("always"))
        if what == "raise":
            raise RuntimeError("injected failure")
        if what == "ctrl-c":
            raise KeyboardInterrupt
        if what == "ctrl-c-casadi-solver":  # CasADi's KeyboardInterruptException
            raise RuntimeError("KeyboardInterrupt")
        if what == "ctrl-c-casadi-function":  # SIGINT inside a generated function's call
            try:
                raise KeyboardInterrupt
            except KeyboardInterrupt as exc:
                raise SystemError("<built-in function _function_buffer_eval> returned a "
                                  "result with an exception set") from exc
        res = real(self, t, x, ctx)
        if what == "nan":
            res.u = np.full_like(res.u, np.nan)
        return res

    monkeypatch.setattr(cls, "_solve", faulty)


@pytest.mark.parametrize("experiment, cls", BACKENDS, ids=[b[0] for b in BACKENDS])
def test_every_backend_falls_back_on_injected_failures(experiment, cls, run_cfg,
                                                       monkeypatch) -> None:
    """A raise and a 'success' with a NaN input are failures: fallback, counted, run goes on."""
    inject(monkeypatch, cls, {2: "raise", 3: "nan", 4: "raise"})
    result, out = run_cfg([f"+experiment={experiment}", "+ci=smoke"])
    s = result.summary
    assert s["status"] not in ("error", "solver_failed"), s.get("error")
    steps = record.read_steps(out)
    calls = record.controller_steps(steps)
    fell_back = list(calls.index[calls["fallback"]])
    # the injected three, and any failure of the solver's own that they caused (a SQP warm
    # started from a fallback plan may fail too): every one counted
    assert fell_back[:3] == [1, 2, 3] and s["solver_failures"] == len(fell_back)
    assert list(calls.loc[[1, 2, 3], "status"]) == ["exception", "failed", "exception"]
    # the status counts hold them too: the NaN "success" is a failed solve, not converged
    assert s["solves_failed"] == (calls["status"] == "failed").sum() >= 1
    assert s["solves_exception"] == (calls["status"] == "exception").sum() >= 2
    assert calls.loc[2, "solver_status"].startswith("non_finite")
    inputs = calls[list(result.steps.columns[result.steps.columns.isin(
        ["a", "phi_dot", "delta", "u1", "u2"])])]
    assert np.isfinite(inputs.to_numpy(dtype=float)).all()  # no NaN was ever applied


def test_a_controller_that_never_solves_ends_solver_failed(run_cfg, monkeypatch) -> None:
    inject(monkeypatch, CvxpyMPC, {"always": "raise"})
    result, out = run_cfg(["+experiment=car_cvxpy", "scenario.t_max=0.5"])
    s = json.loads((out / record.SUMMARY).read_text())
    assert s["status"] == "solver_failed" and not s["arrived"]
    assert s["solver_failures"] == s["n_steps"] == 5
    assert "no usable solve in 5 controller calls" in s["error"]


def test_solver_failed_exits_non_zero_for_a_single_run(monkeypatch, capsys, tmp_path) -> None:
    inject(monkeypatch, CvxpyMPC, {"always": "raise"})
    out = tmp_path / "run"
    code = cli(["+experiment=car_cvxpy", "+ci=smoke", "scenario.t_max=0.3",
                f"hydra.run.dir={out}"])
    err = capsys.readouterr().err
    assert code == EXIT_RUN_FAILED
    assert "solver_failed" in err and "Traceback" not in err
    assert record.read_summary(out)["status"] == "solver_failed"


def test_solver_failed_is_a_row_in_a_sweep(monkeypatch, tmp_path: Path) -> None:
    inject(monkeypatch, CvxpyMPC, {"always": "raise"})
    overrides = ["+experiment=car_cvxpy", "scenario.t_max=0.3"]
    cfg = compose_cfg([*overrides, "+ci=smoke"])
    s = run_job(cfg, tmp_path / "0", overrides, {})  # returns, does not raise
    assert s["status"] == "solver_failed"
    assert record.read_summary(tmp_path / "0")["overrides"] == overrides


def test_ctrl_c_writes_the_partial_record(monkeypatch, tmp_path: Path) -> None:
    inject(monkeypatch, CvxpyMPC, {4: "ctrl-c"})
    cfg = compose_cfg(["+experiment=car_cvxpy", "+ci=smoke"])
    with pytest.raises(KeyboardInterrupt):
        run_experiment(cfg, tmp_path)
    s = record.read_summary(tmp_path)
    assert s["status"] == "interrupted" and s["n_steps"] == 3
    steps = record.read_steps(tmp_path)
    assert len(steps) == 4 and steps["status"].iloc[-1] == record.FINAL


@pytest.mark.parametrize("shape", ["ctrl-c-casadi-solver", "ctrl-c-casadi-function"])
def test_ctrl_c_inside_casadi_stops_the_run(shape, monkeypatch, tmp_path: Path) -> None:
    # a real SIGINT during a CasADi solve comes back in one of these shapes (seen with
    # car_casadi and zumo_bug2); it used to count as a failed solve, and the run went on
    inject(monkeypatch, CasadiMPC, {4: shape})
    cfg = compose_cfg(["+experiment=car_casadi", "+ci=smoke"])
    with pytest.raises(KeyboardInterrupt):
        run_experiment(cfg, tmp_path)
    s = record.read_summary(tmp_path)
    assert s["status"] == "interrupted" and s["n_steps"] == 3
    assert not s.get("solves_exception")


def test_an_interrupt_handed_back_by_the_plant_stops_the_run(monkeypatch,
                                                             tmp_path: Path) -> None:
    # a stop signal inside CasADi's numpy conversion of the plant's step comes back as a
    # SystemError raised from the KeyboardInterrupt: the run is interrupted, not an error
    real = Plant.step
    calls = {"n": 0}

    def step(self, x, u, dt):
        calls["n"] += 1
        if calls["n"] == 3:
            try:
                raise KeyboardInterrupt
            except KeyboardInterrupt as exc:
                raise SystemError("<method '__array__' of 'DM' objects> returned a result "
                                  "with an exception set") from exc
        return real(self, x, u, dt)

    monkeypatch.setattr(Plant, "step", step)
    cfg = compose_cfg(["+experiment=car_cvxpy", "+ci=smoke"])
    with pytest.raises(KeyboardInterrupt):
        run_experiment(cfg, tmp_path)
    s = record.read_summary(tmp_path)
    assert s["status"] == "interrupted" and s["error"] == "KeyboardInterrupt (Ctrl-C)"


def test_ctrl_c_on_the_command_line(monkeypatch, capsys, tmp_path: Path) -> None:
    inject(monkeypatch, CvxpyMPC, {3: "ctrl-c"})
    out = tmp_path / "run"
    code = cli(["+experiment=car_cvxpy", "+ci=smoke", f"hydra.run.dir={out}"])
    assert code == EXIT_INTERRUPTED
    assert "Traceback" not in capsys.readouterr().err
    assert record.read_summary(out)["status"] == "interrupted"
    assert (out / record.STEPS).exists()


def test_a_full_output_folder_is_one_message_naming_it(monkeypatch, capsys, tmp_path) -> None:
    def full(self, *args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(pq, "write_table", full)  # how mpclab.record.files writes the step log
    out = tmp_path / "run"
    code = cli(["+experiment=car_cvxpy", "+ci=smoke", "scenario.t_max=0.2",
                f"hydra.run.dir={out}"])
    err = capsys.readouterr().err
    assert code == EXIT_BAD_INPUT
    assert str(out) in err and "No space left on device" in err and "Traceback" not in err
    assert not (out / record.SUMMARY).exists()


def _full(*args, **kwargs):
    raise OSError(errno.ENOSPC, "No space left on device")


@pytest.mark.parametrize("write", ["figures", "recording"])
def test_a_folder_that_fills_up_after_the_record_is_one_message(write, monkeypatch, capsys,
                                                                tmp_path) -> None:
    """The record is written first; the figures or the recording that no longer fit are
    one message naming the folder, and the record stays."""
    if write == "figures":
        monkeypatch.setattr(Figure, "savefig", _full)
    else:
        monkeypatch.setattr(RerunRecorder, "close", _full)
    out = tmp_path / "run"
    code = cli(["+experiment=car_cvxpy", "+ci=smoke", "scenario.t_max=0.2", "recorder=rerun",
                "figures.enabled=true", f"hydra.run.dir={out}"])
    err = capsys.readouterr().err
    assert code == EXIT_BAD_INPUT
    assert f"cannot write the {write} (the run record is written) (No space left on device)" \
           f": {out}" in err
    assert "Traceback" not in err and err.count("mpclab: error:") == 1
    assert record.read_summary(out)["n_steps"] == 2 and (out / record.STEPS).is_file()


class _Clock:
    """A stand-in for ``time.perf_counter`` that the test advances."""

    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


def test_a_long_run_says_so_with_an_estimate(monkeypatch, caplog) -> None:
    clock = _Clock()
    monkeypatch.setattr(progress_module.time, "perf_counter", clock)
    p = RunProgress("slow", live=False, long_after_s=60.0)
    with caplog.at_level(logging.INFO, logger="mpclab"):
        for k in range(1, 301):  # 300 steps of 0.1 s simulated, 1.8 s of compute each
            clock.now = 1.8 * k
            p(0.1 * k, 30.0)
    warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warnings) == 1 and "a long run" in warnings[0]
    assert "18.00 s of compute per simulated second" in warnings[0]
    assert "about 0:09:00 in all" in warnings[0]
    lines = [r.getMessage() for r in caplog.records if r.levelno == logging.INFO]
    assert len(lines) == 10 and "left" in lines[0]  # every tenth of the way


@pytest.mark.parametrize("wall_at_step", [
    lambda k: 0.01 * k,               # a short run
    lambda k: 12.0 + 0.1 * (k - 1),   # the first step builds and compiles (12 s), then short
], ids=["short", "slow_first_step"])
def test_a_short_run_stays_quiet(monkeypatch, caplog, wall_at_step) -> None:
    clock = _Clock()
    monkeypatch.setattr(progress_module.time, "perf_counter", clock)
    p = RunProgress("quick", live=False, long_after_s=60.0)
    with caplog.at_level(logging.INFO, logger="mpclab"):
        for k in range(1, 301):
            clock.now = wall_at_step(k)
            p(0.1 * k, 30.0)
    assert not caplog.records


def test_ctrl_c_in_a_sweep_says_how_to_resume(monkeypatch, capsys, tmp_path: Path) -> None:
    # the second job's third controller call is interrupted (jobs run in this process)
    inject(monkeypatch, CvxpyMPC, {13: "ctrl-c"})
    code = cli(["-m", "+experiment=car_cvxpy", "+ci=smoke", "seed=0,1,2",
                "hydra.launcher.n_jobs=1", f"hydra.sweep.dir={tmp_path}"])
    assert code == EXIT_INTERRUPTED
    err = capsys.readouterr().err
    assert "Traceback" not in err
    assert f"1 of 3 jobs of the sweep in {tmp_path} are done" in err, err
    assert "the same command resumes it" in err and "their tables" in err
    assert record.read_summary(tmp_path / "1")["status"] == "interrupted"
    rows = pd.read_parquet(tmp_path / "summary.parquet")  # the tables of what was done
    assert len(rows) == 2 and (rows["status"] == "interrupted").sum() == 1
    # the next command in this process is no sweep: its own message
    inject(monkeypatch, CvxpyMPC, {3: "ctrl-c"})
    assert cli(["+experiment=car_cvxpy", "+ci=smoke", f"hydra.run.dir={tmp_path / 'run'}"]) \
        == EXIT_INTERRUPTED
    assert "the steps so far are in" in capsys.readouterr().err
