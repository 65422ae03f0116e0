"""Every config route Hydra documents gives each job the config Hydra's own ``main()`` gives.

A differential test: each command line of :data:`COMMANDS` runs twice in this process, once
through ``python -m mpclab``'s entry point (:func:`mpclab.cli.app.cli`: mpclab's sweeper and
pool launcher) and once through a plain ``@hydra.main`` over the same config folder with
Hydra's basic sweeper and launcher. The task function is replaced in both by one that writes
what it received (the config, the overrides, the group choices, the job number) into its
job folder. Both must give the same jobs with the same configs, print the same for
``--cfg``/``--info``, or refuse the command with the same cause; and mpclab's preflight
(:mod:`mpclab.cli.preflight`) must have composed and checked every command that ran (a single
run: the very config it ran) before Hydra acted on it. A user folder made by the
test holds an experiment, a layout and a group that exist only there.
"""

from __future__ import annotations

import io
import json
import sys
from contextlib import redirect_stderr, redirect_stdout
from pathlib import Path

import hydra
import pytest
from hydra.core.global_hydra import GlobalHydra
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig, OmegaConf

import mpclab.cli.app as app
from conftest import CONF
from mpclab.cli import preflight

#: group choices that differ by design: the plain path runs Hydra's own sweeper and launcher
PLUGIN_GROUPS = ("hydra/launcher", "hydra/sweeper")
PLAIN_PLUGINS = ["hydra/launcher=basic", "hydra/sweeper=basic"]
JOB_FILE = "job.json"


def capture(cfg: DictConfig) -> dict:
    """The task function of both paths: what the job received, written into its folder."""
    hc = HydraConfig.get()
    job = {
        "cfg": OmegaConf.to_container(cfg, resolve=False),
        "num": hc.job.get("num"),
        "task": list(hc.overrides.task),
        # mpclab's sweepers pin each job's hydra.sweep.dir to the sweep's folder, resolved once
        # (the jobs of a sweep over experiments would resolve it apart): a designed difference
        "hydra": [o for o in hc.overrides.hydra
                  if o.split("=")[0] not in (*PLUGIN_GROUPS, "hydra.sweep.dir")],
        "dirname": hc.job.override_dirname,
        "choices": {k: v for k, v in hc.runtime.choices.items()
                    if not any(g in k for g in PLUGIN_GROUPS)},
        "mode": str(hc.mode),
    }
    out = Path(hc.runtime.output_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / JOB_FILE).write_text(json.dumps(job, sort_keys=True, default=str))
    return {}


@hydra.main(config_path=str(CONF), config_name="config", version_base="1.3")
def plain_main(cfg: DictConfig) -> dict:
    return capture(cfg)


def user_folder(root: Path) -> Path:
    """A researcher's own config folder: an experiment with its own layout, a group."""
    files = {
        "experiment/my_exp.yaml": "# @package _global_\ndefaults:\n  - zumo_bug2\n"
                                  "  - override /scenario: my_layout\n  - _self_\nname: my_exp\n",
        "experiment/my_car.yaml": "# @package _global_\ndefaults:\n  - car_cvxpy\n  - _self_\n"
                                  "name: my_car\nseed: 11\n",
        "experiment/with_searchpath.yaml": "# @package _global_\ndefaults:\n  - car_cvxpy\n"
                                           "  - _self_\nhydra:\n  searchpath:\n"
                                           f"    - file://{root / 'nowhere'}\n",
        "scenario/my_layout.yaml": "defaults:\n  - zumo_one_obstacle\n  - _self_\n"
                                   "name: my_layout\ndiscs: [[0.4, 0.6]]\n",
        "mygroup/a.yaml": "value: 1\n",
        "mygroup/b.yaml": "value: 2\nlabel: bee\n",
        "my_primary.yaml": "defaults:\n  - config\n  - override /plant: zumo\n  - _self_\n"
                           "hydra:\n  searchpath:\n"
                           f"    - file://{CONF}\nname: mine\n",
    }
    user = root / "user"
    for name, text in files.items():
        (user / name).parent.mkdir(parents=True, exist_ok=True)
        (user / name).write_text(text)
    return user


U = "{user}"  # stands for the user folder in the command lines below
CAR = "+experiment=car_cvxpy"
COMMANDS: list[list[str]] = [
    # single runs
    [CAR],
    [CAR, "seed=3", "controller.horizon=12"],
    [f"hydra.searchpath=[file://{U}]", "+experiment=my_exp"],
    ["-cd", U, "+experiment=my_exp"],
    ["--config-dir", U, "+experiment=my_exp", "scenario=zumo_wall"],
    [f"--config-dir={U}", "+experiment=my_car", "seed=4"],
    [f"hydra.searchpath=[file://{U}]", CAR, "+mygroup=a"],
    ["-cd", U, CAR, "+mygroup@extra=b"],
    [CAR, "~recorder"],
    [CAR, "+sim@sim_b=realistic"],
    [CAR, "controller={horizon: 7}"],
    [CAR, "++seed=8", "+tag=x", "~figures"],
    ["--config-path", U, "--config-name", "my_primary", CAR],
    ["--config-path", U, "--config-name=my_primary", "seed=2"],
    ["--config-name=config", CAR],
    [f"hydra.searchpath=[file://{U}]", "+experiment=with_searchpath"],
    ["hydra.job.chdir=true", CAR],
    [CAR, "+mygroup=a"],  # no such group without the user folder: a value
    # multiruns
    ["-m", f"hydra.searchpath=[file://{U}]", "+experiment=my_exp", "seed=0,1"],
    ["-cd", U, "-m", "+experiment=my_exp", "seed=0,1"],
    ["-m", f"hydra.searchpath=[file://{U}]", CAR, "+mygroup=a,b"],
    ["-cd", U, "-m", CAR, "+mygroup=a,b", "seed=1", "mygroup.value=5"],
    ["-m", CAR, "~recorder", "seed=0,1"],
    ["-m", CAR, "+sim@sim_b=realistic,nominal"],
    ["-m", CAR, "controller=cvxpy,casadi", "controller.horizon=8"],
    ["-m", "+experiment=car_cvxpy,car_casadi", "seed=0"],
    ["-m", "+experiment=zumo_bug2", "scenario=zumo_wall,zumo_cup", "seed=0,1"],
    ["-m", "hydra/launcher=joblib", "hydra.launcher.n_jobs=1", CAR, "seed=0,1"],
    ["-m", "hydra/sweeper=basic", CAR, "seed=0,1"],
    ["-m", CAR, "seed=range(0,3)"],
    ["-m", CAR, "seed=choice(4,5)", "controller.horizon=9"],
    ["-m", CAR, "++seed=7", "controller.horizon=8,9"],
    ["-m", CAR, "+tag=a,b", "seed=2", "seed=3"],
    ["-m", "--config-path", U, "--config-name", "my_primary", "seed=0,1"],
    ["-m", "hydra.job.chdir=true", CAR, "seed=0,1"],
    ["-m", CAR, "seed=0,1", "hydra.sweep.subdir=job${hydra.job.num}"],
    ["-m", CAR, "'controller={horizon: 6}'", "seed=0,1"],
    ["-m", "-cd", U, "+experiment=my_exp", "scenario=zumo_wall,my_layout"],
    # printed, not run
    ["--cfg", "job", CAR],
    ["--cfg", "job", "-p", "controller", CAR],
    ["--cfg", "job", "-cd", U, "+experiment=my_exp"],
    ["--cfg", "job", f"hydra.searchpath=[file://{U}]", CAR, "+mygroup=b"],
    ["--info", "searchpath", f"hydra.searchpath=[file://{U}]"],
    ["--info", "defaults", "-cd", U, "+experiment=my_exp"],
    # refused
    ["+experiment=nope"],
    [CAR, "controller.horizn=5"],
    [CAR, "+seed=1"],
    [CAR, "nope@pkg=a"],
    ["-m", "+experiment=nope", "seed=0,1"],
    ["-m", CAR, "controller.horizn=5,6"],
    ["-m", CAR, "seed=range(0,"],
]


def _fill(args: list[str], user: Path) -> list[str]:
    return [a.replace(U, str(user)).strip("'") for a in args]


def _plain_args(args: list[str]) -> list[str]:
    """The command for plain Hydra: its own sweeper and launcher unless the command names
    one of Hydra's."""
    if "-m" not in args and "--multirun" not in args:
        return args
    keep = [a for a in args if not (a.startswith("hydra/launcher=local")
                                    or a.startswith("hydra/sweeper=tolerant"))]
    extra = [p for p in PLAIN_PLUGINS if not any(a.startswith(p.split("=")[0] + "=")
                                                 for a in keep)]
    return [*keep, *extra]


def _run(main, args: list[str], cwd: Path, monkeypatch) -> dict:
    """Run one path in ``cwd``; what it printed, raised and what its jobs received."""
    cwd.mkdir(parents=True)
    monkeypatch.chdir(cwd)
    GlobalHydra.instance().clear()
    out, err = io.StringIO(), io.StringIO()
    raised: BaseException | None = None
    with redirect_stdout(out), redirect_stderr(err):
        try:
            code = main(args)
        except SystemExit as exc:
            code = exc.code
        except Exception as exc:  # noqa: BLE001  (compared below)
            raised, code = exc, "raised"
    jobs = sorted((json.loads(p.read_text()) for p in cwd.rglob(JOB_FILE)),
                  key=lambda j: (j["num"] is None, j["num"] or 0))
    return {"code": code, "raised": raised, "stdout": out.getvalue(), "stderr": err.getvalue(),
            "jobs": jobs}


def _mpclab(args: list[str]) -> int:
    return app.cli(args)


def _plain(args: list[str]) -> int | None:
    saved = sys.argv
    sys.argv = ["plain", *args]
    try:
        plain_main()
    finally:
        sys.argv = saved
    return 0


def _normalized(text: str, user: Path) -> str:
    """Printed text without what names the entry point (its job name, its module)."""
    lines = [line for line in text.splitlines()
             if not any(w in line for w in ("name:", "App:", "Task name", "module", "provider:"))]
    return "\n".join(lines).replace(str(user), "USER")


def test_the_corpus_covers_every_route() -> None:
    flat = [" ".join(c) for c in COMMANDS]
    assert len(COMMANDS) >= 40
    for route in ("hydra.searchpath", "-cd", "--config-dir", "--config-path", "--config-name",
                  "+mygroup", "~recorder", "@", "hydra/launcher=", "hydra/sweeper=", "--cfg",
                  "--info", "-p"):
        assert any(route in c for c in flat), route
    assert sum("-m" in c for c in COMMANDS) >= 15


@pytest.mark.parametrize("args", COMMANDS, ids=[" ".join(c)[:60] for c in COMMANDS])
def test_every_job_gets_the_config_hydra_gives(args, tmp_path, monkeypatch) -> None:
    user = user_folder(tmp_path)
    cmd = _fill(args, user)
    monkeypatch.setenv("HYDRA_FULL_ERROR", "1")  # both raise their error, to compare causes
    monkeypatch.setattr(app, "_task", capture)
    checked: list[DictConfig] = []  # what mpclab's preflight composed and checked
    monkeypatch.setattr(preflight, "check_config", checked.append)
    want = _run(_plain, _plain_args(cmd), tmp_path / "plain", monkeypatch)
    got = _run(_mpclab, cmd, tmp_path / "mpclab", monkeypatch)
    if want["raised"] is not None:  # refused: refused with the same cause
        cause = str(want["raised"]).strip().splitlines()[0].rstrip(".")
        if got["raised"] is not None:
            assert type(got["raised"]) is type(want["raised"])
            assert str(got["raised"]).strip().splitlines()[0].rstrip(".") == cause
        else:  # a sweep whose every job failed: its first error, said once
            assert got["code"] not in (0, None)
            assert got["stderr"].count(cause) == 1, got["stderr"]
        assert not got["jobs"]
        return
    assert got["raised"] is None, got["raised"]
    assert got["code"] in (0, None)
    if "--cfg" in cmd or "--info" in cmd:  # printed, nothing run
        assert _normalized(got["stdout"], user) == _normalized(want["stdout"], user)
    assert len(got["jobs"]) == len(want["jobs"])
    for mine, hydras in zip(got["jobs"], want["jobs"], strict=True):
        assert mine == hydras
    if got["jobs"]:  # checked before Hydra acted on it; a single run: the config it ran
        assert len(checked) == 1
        if "-m" not in cmd:
            app_part = {k: v for k, v in OmegaConf.to_container(checked[0]).items()
                        if k != "hydra"}
            assert app_part == got["jobs"][0]["cfg"]
