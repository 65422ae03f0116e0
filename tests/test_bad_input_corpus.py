"""Bad input, as a new user would give it: one message naming the key or the value, exit 2,
no traceback, no run record.

Every case composes its config as the app does and builds the run (every check refuses
before the loop starts, and before the expensive build, a CasADi NLP's compile); the error
goes through the command line's reporter (:func:`mpclab.cli.app.report`). A sample of the
cases runs the whole command line in-process (:func:`mpclab.cli.app.cli`, what
``python -m mpclab`` calls), and a few run as real subprocesses to prove the exit code and
the absence of a traceback end to end. Add a case whenever an option appears.
"""

from __future__ import annotations

import contextlib
import io
import multiprocessing
import subprocess
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
import pytest
from hydra import compose as hydra_compose
from hydra import initialize_config_dir
from hydra.core.hydra_config import HydraConfig

from conftest import ROOT
from mpclab.cli.app import EXIT_BAD_INPUT, cli, report
from mpclab.core.errors import ConfigError
from mpclab.record import files as record
from mpclab.runner.single_run import CONF_DIR, build_run, compose

CAR, CASADI_CAR, ZUMO, BUG2, BUG2_STUDY = (
    f"+experiment={n}" for n in
    ("car_cvxpy", "car_casadi", "zumo_potential", "zumo_bug2", "zumo_bug2_study"))
BICYCLE, NN = "+experiment=bicycle_scheduled", "+experiment=zumo_nn"
WEIGHTS = ROOT / "conf" / "weights" / "zumo_nn.npz"

#: (overrides, strings the message must contain: the key and/or the value)
CASES: list[tuple[list[str], list[str]]] = [
    # ---- composing: typos, wrong types, unknown choices (Hydra and the schemas)
    ([CAR, "controller.horizn=5"], ["horizn"]),
    ([CAR, "controller.horizon=ten"], ["controller.horizon", "ten"]),
    ([CAR, "controller.horizon=1.5"], ["controller.horizon", "1.5"]),
    ([CAR, "controller.solver=ECOS"], ["ECOS", "CLARABEL"]),
    ([CAR, "plant=kinematic_cr"], ["kinematic_cr", "kinematic_car"]),
    ([CAR, "plant.params.wheelbase=2"], ["wheelbase"]),
    ([CAR, "plant.params.l=long"], ["plant.params.l", "long"]),
    ([CAR, "plant.substeps=1.5"], ["plant.substeps", "1.5"]),
    (["+experiment=car_cvxq"], ["car_cvxq", "car_cvxpy"]),
    ([CAR, "controller=cvxpi"], ["cvxpi", "cvxpy"]),
    ([CAR, "objective=car_quadratc"], ["car_quadratc"]),
    ([CAR, "recorder=tape"], ["tape"]),
    ([CAR, "seed=abc"], ["seed", "abc"]),
    ([CAR, "scenario.t_max=long"], ["scenario.t_max", "long"]),
    ([CAR, "figures.enabled=maybe"], ["figures.enabled", "maybe"]),
    ([CAR, "progress=sometimes"], ["progress", "sometimes"]),
    ([CAR, "controller.dt=fast"], ["controller.dt", "fast"]),
    ([CAR, "scenario.start.px=left"], ["scenario.start.px", "left"]),
    ([CAR, "sim=perfect"], ["perfect"]),
    ([ZUMO, "scenario=zumo_nowhere"], ["zumo_nowhere", "zumo_dead_end"]),
    ([ZUMO, "plant.params.r=abc"], ["plant.params.r", "abc"]),
    ([BUG2, "supervisor=bug3"], ["bug3", "bug2"]),
    ([BUG2, "supervisor.block_range=far"], ["supervisor.block_range", "far"]),
    ([ZUMO, "scenario.arrival.threshold=small"], ["scenario.arrival.threshold", "small"]),
    ([BICYCLE, "controller.schedule.mode=hybrid"], ["hybrid", "switched"]),
    ([CASADI_CAR, "controller.solver=ipot"], ["ipot", "ipopt"]),
    # ---- objective weights: finite, in range, numbers
    ([CAR, "objective.terms.tracking.state_weights.px=-100"], ["state_weights.px", "-100"]),
    ([CAR, "objective.terms.tracking.state_weights.px=nan"], ["state_weights.px", "nan"]),
    ([CAR, "objective.terms.tracking.state_weights.py=inf"], ["state_weights.py", "inf"]),
    ([CAR, "objective.terms.tracking.input_weights.a=-1"], ["input_weights.a", "-1"]),
    ([CAR, "objective.terms.tracking.input_weights.a=.nan"], ["input_weights.a", "nan"]),
    ([CAR, "+objective.terms.tracking.stat_weights={px: 1}"], ["stat_weights", "state_weights"]),
    ([CAR, "+objective.terms.tracking.state_weights.speed=1"], ["'tracking'", "speed"]),
    ([BUG2, "objective.terms.J1.C1=high"], ["objective.terms.J1", "C1", "high"]),
    ([BUG2, "objective.terms.J1.C1=nan"], ["C1", "nan"]),
    ([BUG2, "objective.terms.J1.C1=inf"], ["C1", "inf"]),
    ([BUG2, "objective.terms.J1.C1=-5500"], ["C1", "-5500"]),
    ([BUG2, "objective.terms.J1.L1=0"], ["L1", "0"]),
    ([BUG2, "objective.terms.J3.C2=nan"], ["C2", "nan"]),
    ([BUG2, "objective.terms.J3.L2=-0.04"], ["L2", "-0.04"]),
    ([BUG2_STUDY, "objective.terms.J4.C3=inf"], ["C3", "inf"]),
    ([BUG2_STUDY, "objective.terms.J4.L3=0"], ["L3", "0"]),
    ([BUG2_STUDY, "objective.terms.J5f.C4=nan"], ["C4", "nan"]),
    ([BUG2_STUDY, "objective.terms.J5f.L4=-1"], ["L4", "-1"]),
    ([BUG2_STUDY, "objective.terms.J5f.angle_deg=inf"], ["angle_deg", "inf"]),
    ([BUG2, "objective.terms.dU.weights.u1=nan"], ["weights.u1", "nan"]),
    ([BUG2, "objective.terms.dU.weights.u2=-1"], ["weights.u2", "-1"]),
    ([BUG2, "objective.terms.J2.input_weights.u1=nan"], ["input_weights.u1", "nan"]),
    ([BUG2, "+objective.terms.J1.eps=0"], ["objective.terms.J1", "eps", "0"]),
    ([CAR, "objective.terms.tracking._target_=mpclab.nothing.Here"],
     ["objective.terms.tracking._target_", "mpclab.nothing.Here"]),
    # ---- a plant that does not match the objective or the backend
    ([CAR, "objective=zumo_potential"], ["cvxpy"]),
    ([BICYCLE, "objective=car_quadratic"], ["phi"]),
    ([BUG2, "plant=kinematic_car"], ["scenario.start", "'x'"]),
    # ---- physical parameters: positive, finite
    ([ZUMO, "plant.params.r=0"], ["params.r", "0"]),
    ([ZUMO, "plant.params.d=0"], ["params.d", "0"]),
    ([ZUMO, "plant.params.r=-0.02"], ["params.r", "-0.02"]),
    ([ZUMO, "plant.params.d=nan"], ["params.d", "nan"]),
    ([CAR, "plant.params.l=0"], ["params.l", "0"]),
    ([CAR, "plant.params.l=inf"], ["params.l", "inf"]),
    ([BICYCLE, "plant.params.m=0"], ["params.m", "0"]),
    ([BICYCLE, "plant.params.Kf=-1"], ["params.Kf", "-1"]),
    ([BICYCLE, "plant.params.v_min=0"], ["params.v_min", "0"]),
    ([CAR, "plant.substeps=0"], ["substeps", "0"]),
    ([CAR, "plant.input_bounds.a=[10,-10]"], ["input_bounds.a", "10"]),
    # ---- scenario: an arrival rule that can be met, times, geometry
    ([CAR, "scenario.arrival.threshold=-1"], ["scenario.arrival.threshold", "-1"]),
    ([CAR, "scenario.arrival.threshold=0"], ["scenario.arrival.threshold", "0"]),
    ([ZUMO, "scenario.arrival.threshold=nan"], ["scenario.arrival.threshold", "nan"]),
    ([CAR, "scenario.arrival.weights.px=-1"], ["scenario.arrival.weights.px", "-1"]),
    ([CAR, "scenario.arrival.weights={px: 0, py: 0, v: 0}"], ["scenario.arrival.weights"]),
    ([CAR, "scenario.t_max=0"], ["scenario.t_max", "0"]),
    ([CAR, "scenario.t_max=-5"], ["scenario.t_max", "-5"]),
    ([CAR, "scenario.t_max=inf"], ["scenario.t_max", "inf"]),
    ([CAR, "scenario.start.px=nan"], ["scenario.start.px", "nan"]),
    ([CAR, "scenario.goal.px=inf"], ["scenario.goal.px", "inf"]),
    ([CAR, "+scenario.start.speed=1"], ["scenario.start", "speed"]),
    ([ZUMO, "scenario=zumo_one_obstacle", "scenario.goal.y=0.6"], ["scenario.goal", "0.6"]),
    ([ZUMO, "scenario=zumo_one_obstacle", "scenario.start.y=0.62"], ["scenario.start", "0.62"]),
    ([BUG2, "scenario.goal.x=0.4", "scenario.goal.y=0.6"], ["scenario.goal", "obstacle"]),
    ([ZUMO, "scenario.robot_radius=-0.1"], ["scenario.robot_radius", "-0.1"]),
    ([ZUMO, "scenario.layout.obstacle_radius=0"], ["scenario.layout.obstacle_radius", "0"]),
    ([ZUMO, "scenario.sensor.n_rays=0"], ["n_rays", "0"]),
    ([ZUMO, "scenario.sensor.max_range=0"], ["max_range", "0"]),
    ([ZUMO, "scenario.stall.window_s=0"], ["scenario.stall.window_s", "0"]),
    ([ZUMO, "scenario.sensor.offset_deg=nan"], ["scenario.sensor.offset_deg", "nan"]),
    ([ZUMO, "scenario=zumo_one_obstacle", "scenario.layout.discs=[[0.4,nan]]"],
     ["scenario.layout.discs[0][1]", "nan"]),
    # ---- the run and the controller
    ([CAR, "seed=-1"], ["seed", "-1"]),
    ([CAR, "controller.horizon=-1"], ["controller.horizon", "-1"]),
    ([CASADI_CAR, "controller.horizon=0"], ["controller.horizon", "0"]),
    ([CAR, "controller.dt=0"], ["controller.dt", "0"]),
    ([CAR, "controller.dt=nan"], ["controller.dt", "nan"]),
    ([BUG2, "controller.dt=-0.2"], ["controller.dt", "-0.2"]),
    ([BICYCLE, "controller.control_horizon=40"], ["control_horizon", "40"]),
    ([CAR, "controller.control_horizon=0"], ["controller.control_horizon", "0"]),
    ([CASADI_CAR, "controller.control_horizon=abc"], ["controller.control_horizon", "abc"]),
    ([BUG2, "controller.control_horizon=[2,0]"], ["controller.control_horizon", "[2, 0]"]),
    ([BICYCLE, "+controller.schedule.operating_points.speed=[1]"], ["operating_points", "speed"]),
    ([BICYCLE, "+controller.schedule.hysteresis.px=0.1"], ["hysteresis", "px"]),
    ([BICYCLE, "+controller.schedule.hysteresis.V=-1"], ["hysteresis.V", "-1"]),
    ([BICYCLE, "sim.latency=-5"], ["sim.latency", "-5"]),
    ([BICYCLE, "sim=realistic", "sim.noise.range_std=-1"], ["sim.noise.range_std", "-1"]),
    # ---- the supervisor's modes against the objective's terms
    ([BUG2, "supervisor.modes.go_to_goal=[J1,J2,J9]"], ["supervisor.modes.go_to_goal", "J9"]),
    ([BUG2_STUDY, "supervisor.modes.wall_follow=[J3,J4,dU]"], ["J5f", "supervisor.modes"]),
    ([BUG2, "supervisor.boundary.path_speed=-1"], ["supervisor.boundary.path_speed", "-1"]),
    ([BUG2, "supervisor.boundary.side=up"], ["supervisor.boundary.side", "up", "right", "left"]),
    ([BUG2, "+objective.terms.J5={_target_: mpclab.objectives.potential.LeftHandPull}"],
     ["'J5'", "supervisor.modes"]),
    ([BUG2, "supervisor.block_range=0"], ["supervisor.block_range", "0"]),
    ([BUG2, "supervisor.corridor_half_width=-1"], ["supervisor.corridor_half_width", "-1"]),
    ([BUG2, "supervisor.goal_sight_range=-1"], ["supervisor.goal_sight_range", "-1"]),
    ([BUG2, "supervisor.mline_tolerance=nan"], ["supervisor.mline_tolerance", "nan"]),
    # ---- NN weights files
    ([NN, "controller.weights=README.md"], ["controller.weights", "README.md"]),
    ([NN, "controller.weights=experiments/nowhere.npz"], ["controller.weights", "nowhere.npz"]),
    ([NN, "scenario.sensor.n_rays=12"], ["controller.weights", "20", "12"]),
    ([NN, "plant=kinematic_car"], ["scenario.start", "'x'"]),
]


def _id(case: tuple[list[str], list[str]]) -> str:
    return " ".join(case[0]).replace("+experiment=", "")


def run_cli(capsys: pytest.CaptureFixture, out: Path, overrides: list[str]) -> tuple[int, str]:
    """``python -m mpclab +ci=smoke OVERRIDES`` in this process: (exit code, its output)."""
    code = cli(["+ci=smoke", f"hydra.run.dir={out}", *overrides])
    captured = capsys.readouterr()
    return code, captured.out + captured.err


def check(out: Path, overrides: list[str]) -> tuple[int, str]:
    """Compose and build as the app does (not the loop), reporting as the command line does:
    (exit code, what it printed)."""
    printed = io.StringIO()
    with contextlib.redirect_stderr(printed), contextlib.redirect_stdout(printed):
        try:
            build_run(compose(["+ci=smoke", *overrides]), out)
        except Exception as exc:  # noqa: BLE001  (the reporter sorts it)
            code = report(exc, full_error=False)
        else:
            code = 0
    return code, printed.getvalue()


def _check_case(args: tuple[Path, list[str]]) -> tuple[int, str]:
    return check(*args)


@pytest.fixture(scope="module")
def checked(tmp_path_factory: pytest.TempPathFactory) -> dict[str, tuple[int, str, Path]]:
    """Every case of CASES checked once, on two worker processes (composing is most of the
    time, about 0.3 s a case, and one core does it): ``{case id: (code, text, folder)}``."""
    root = tmp_path_factory.mktemp("corpus")
    jobs = [(root / f"case{i}", overrides) for i, (overrides, _) in enumerate(CASES)]
    with ProcessPoolExecutor(2, mp_context=multiprocessing.get_context("fork")) as pool:
        results = list(pool.map(_check_case, jobs))
    return {_id(c): (*r, j[0]) for c, r, j in zip(CASES, results, jobs, strict=True)}


def assert_one_clear_message(code: int, text: str, wanted: list[str], out: Path) -> None:
    assert code == EXIT_BAD_INPUT, text
    assert "Traceback" not in text, text
    message = [ln for ln in text.splitlines() if ln.startswith("mpclab: error:")]
    assert message, text
    for w in wanted:
        assert w in text, f"{w!r} not in the message:\n{text}"
    assert not (out / record.SUMMARY).exists()  # nothing claims a result


@pytest.mark.parametrize("case", CASES, ids=[_id(c) for c in CASES])
def test_bad_input_gives_one_clear_message(case, checked) -> None:
    code, text, out = checked[_id(case)]
    assert_one_clear_message(code, text, case[1], out)


@pytest.mark.parametrize("case", CASES[::20], ids=[_id(c) for c in CASES[::20]])
def test_the_command_line_gives_the_same_message(case, capsys, tmp_path: Path) -> None:
    overrides, wanted = case
    code, text = run_cli(capsys, tmp_path / "run", overrides)
    assert_one_clear_message(code, text, wanted, tmp_path / "run")


def test_the_corpus_is_large_enough() -> None:
    assert len(CASES) + len(FILE_CASES) >= 80
    assert len({_id(c) for c in CASES}) == len(CASES)  # one entry per case in `checked`


# ---- broken files: YAML syntax, NN weights cut short or of something else

def _broken_yaml(d: Path) -> Path:
    (d / "experiment").mkdir(parents=True)
    (d / "experiment" / "broken.yaml").write_text(
        "# @package _global_\ndefaults:\n  - override /controller: cvxpy\nname: broken\n"
        "controller:\n  horizon: [1, 2\n  dt: 0.1\n")
    return d


def _typo_yaml(d: Path) -> Path:
    (d / "experiment").mkdir(parents=True)
    (d / "experiment" / "broken.yaml").write_text(
        "# @package _global_\ndefaults:\n  - override /controller: cvxpy\nname: broken\n"
        "controller:\n  horizom: 12\n")
    return d


def _tab_yaml(d: Path) -> Path:
    (d / "experiment").mkdir(parents=True)
    (d / "experiment" / "broken.yaml").write_text(
        "# @package _global_\nname: broken\ncontroller:\n\thorizon: 12\n")
    return d


def _truncated_npz(d: Path) -> Path:
    data = WEIGHTS.read_bytes()
    (d / "cut.npz").write_bytes(data[: len(data) // 2])
    return d / "cut.npz"


def _other_npz(d: Path) -> Path:
    np.savez(d / "other.npz", a=np.zeros(3))
    return d / "other.npz"


def _empty_npz(d: Path) -> Path:
    (d / "empty.npz").write_bytes(b"")
    return d / "empty.npz"


#: (what it makes in a folder, overrides given that path, strings the message must contain)
FILE_CASES = [
    (_broken_yaml, lambda p: [f"hydra.searchpath=[file://{p}]", "+experiment=broken"],
     ["broken.yaml", "line 7"]),
    (_typo_yaml, lambda p: [f"hydra.searchpath=[file://{p}]", "+experiment=broken"],
     ["horizom"]),
    (_tab_yaml, lambda p: [f"hydra.searchpath=[file://{p}]", "+experiment=broken"],
     ["broken.yaml", "line 4"]),
    (_truncated_npz, lambda p: [NN, f"controller.weights={p}"], ["controller.weights", "cut.npz"]),
    (_other_npz, lambda p: [NN, f"controller.weights={p}"], ["controller.weights", "header"]),
    (_empty_npz, lambda p: [NN, f"controller.weights={p}"], ["controller.weights", "empty.npz"]),
]


@pytest.mark.parametrize("make, overrides, wanted", FILE_CASES,
                         ids=[f[0].__name__.lstrip("_") for f in FILE_CASES])
def test_broken_files_give_one_clear_message(make, overrides, wanted, capsys,
                                             tmp_path: Path) -> None:
    path = make(tmp_path / "files" if make.__name__.endswith("yaml") else tmp_path)
    code, text = check(tmp_path / "run", overrides(path))
    assert_one_clear_message(code, text, wanted, tmp_path / "run")


def test_an_output_folder_that_cannot_be_made_is_named(capsys, tmp_path: Path) -> None:
    blocker = tmp_path / "a_file"
    blocker.write_text("not a folder")
    out = blocker / "run"
    code, text = run_cli(capsys, out, [CAR])
    assert_one_clear_message(code, text, [str(out)], out)


# ---- a sweep's launcher options: checked when composing (types, choices) or by the
# launcher's constructor (ranges), before any job starts

LAUNCHER_CASES = [
    ("n_jobs=two", ["hydra.launcher.n_jobs", "two"]),
    ("n_jobs=1.5", ["hydra.launcher.n_jobs", "1.5"]),
    ("n_jobs=0", ["hydra.launcher.n_jobs: expected a whole number >= 1, or -1", "got 0"]),
    ("threads_per_worker=0", ["hydra.launcher.threads_per_worker: expected", "got 0"]),
    ("start_method=thread", ["hydra.launcher.start_method", "thread", "forkserver"]),
    ("job_timeout_s=abc", ["hydra.launcher.job_timeout_s", "abc"]),
    ("job_timeout_s=-1", ["hydra.launcher.job_timeout_s: expected seconds > 0", "got -1"]),
    ("n_job=2", ["unknown key 'n_job' in hydra.launcher", "Did you mean 'n_jobs'?"]),
]


@pytest.mark.parametrize("option, wanted", LAUNCHER_CASES, ids=[c[0] for c in LAUNCHER_CASES])
def test_a_bad_launcher_option_is_one_message(option, wanted, capsys, tmp_path: Path) -> None:
    code = cli(["-m", CAR, "+ci=smoke", "seed=0,1", f"hydra.sweep.dir={tmp_path}",
                f"hydra.launcher.{option}"])
    captured = capsys.readouterr()
    text = captured.out + captured.err
    assert_one_clear_message(code, text, wanted, tmp_path)
    assert "hydra.launcher: hydra.launcher" not in text  # the key once
    assert not list(tmp_path.glob("*/summary.json"))  # no job ran


def test_an_output_folder_that_is_a_file_is_named(capsys, tmp_path: Path) -> None:
    blocker = tmp_path / "a_file"
    blocker.write_text("not a folder")
    code, text = run_cli(capsys, blocker, [CAR])
    assert_one_clear_message(code, text, [f"not a folder (a file is there): {blocker}"],
                             tmp_path)


def test_hydra_full_error_shows_the_traceback(capsys, tmp_path: Path, monkeypatch) -> None:
    monkeypatch.setenv("HYDRA_FULL_ERROR", "1")
    with pytest.raises(ValueError, match="seed"):
        cli(["+ci=smoke", f"hydra.run.dir={tmp_path}", CAR, "seed=-1"])


# ---- end to end, as real processes: the exit code and stderr as the user sees them

END_TO_END = [
    ([BUG2, "objective.terms.J1.C1=nan"], "C1"),
    ([ZUMO, "plant.params.r=0"], "params.r"),
    ([CAR, "controller.horizn=5"], "horizn"),
]


def test_subprocess_exit_code_and_no_traceback(tmp_path: Path) -> None:
    """``python -m mpclab`` as a user runs it, a few bad inputs at once (side by side)."""
    procs = []
    for i, (overrides, _) in enumerate(END_TO_END):
        out = tmp_path / f"run{i}"
        procs.append((out, subprocess.Popen(
            [sys.executable, "-m", "mpclab", "+ci=smoke", f"hydra.run.dir={out}", *overrides],
            cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        )))
    for (out, proc), (_, wanted) in zip(procs, END_TO_END, strict=True):
        stdout, stderr = proc.communicate(timeout=300)
        assert proc.returncode == EXIT_BAD_INPUT, stderr
        assert "Traceback" not in stdout + stderr
        assert wanted in stderr and stderr.startswith("mpclab: error:")
        assert not (out / record.SUMMARY).exists()


@pytest.mark.parametrize("overrides, wanted", [
    # an experiment that reuses another plant's objective: the key came from that file
    (["+experiment=unicycle_goal", "objective=car_quadratic"],
     ["objective term 'tracking'", "'phi_dot'", "(set in conf/objective/car_quadratic.yaml)"]),
    (["+experiment=car_cvxpy", "plant=unicycle", "controller=casadi"],
     ["scenario.start", "'phi'", "(set in conf/scenario/car_to_origin.yaml)"]),
    # a group's file, then the command line
    ([BUG2, "supervisor.modes.go_to_goal=[J1,J9]"],
     ["(set in conf/supervisor/bug2.yaml, then the command line "
      "(supervisor.modes.go_to_goal=[J1,J9]))"]),
])
def test_the_message_says_where_the_key_came_from(overrides, wanted, capsys, tmp_path) -> None:
    code, text = run_cli(capsys, tmp_path / "run", overrides)
    assert_one_clear_message(code, text, wanted, tmp_path / "run")


def test_the_message_names_a_users_file_and_a_part_set_on_the_command_line(
        capsys, tmp_path, monkeypatch) -> None:
    """The value a user's own experiment file (a folder added with ``-cd``) sets is named in
    that file, after the group's file it overrides; a part of a key set on the command line
    (``scenario.start.y``) names the command line."""
    mine = tmp_path / "my_confs" / "experiment" / "mine.yaml"
    mine.parent.mkdir(parents=True)
    mine.write_text("# @package _global_\ndefaults:\n  - zumo_bug2\n  - _self_\n"
                    "supervisor:\n  modes:\n    go_to_goal: [J1, J2, J3, dU, Jx]\n")
    monkeypatch.chdir(tmp_path)
    code = cli(["-cd", str(mine.parents[1]), "+ci=smoke", f"hydra.run.dir={tmp_path / 'run'}",
                "+experiment=mine"])
    text = "".join(capsys.readouterr())
    assert_one_clear_message(code, text, [
        "'Jx'", f"(set in {CONF_DIR / 'supervisor' / 'bug2.yaml'}, then "
                "my_confs/experiment/mine.yaml)"], tmp_path / "run")
    code, text = run_cli(capsys, tmp_path / "run", [BUG2, "scenario.start.y=0.6"])
    assert_one_clear_message(code, text, [
        "scenario.start:", "(set in ", "then the command line (scenario.start.y=0.6))"],
        tmp_path / "run")


def test_a_library_run_names_no_other_runs_command_line() -> None:
    """Hydra's global config may hold another run (a task function calling mpclab, a test):
    a library call's message must not cite that run's command line (a run's origin comes
    with the run, not from the global)."""
    bad = "supervisor.modes.go_to_goal=[J1,J9]"
    saved = HydraConfig.instance().cfg
    try:
        with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
            other = hydra_compose("config", [BUG2, bad], return_hydra_config=True)
        HydraConfig.instance().set_config(other)
        with pytest.raises(ConfigError) as err:
            build_run(compose([BUG2, "+ci=smoke", "supervisor.modes.go_to_goal=[J1,J8]"]))
        assert "J8" in str(err.value) and "command line" not in str(err.value)
    finally:
        HydraConfig.instance().cfg = saved
