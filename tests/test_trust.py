"""A config builds mpclab's registered components and nothing else: the hostile corpus.

Each case is a command line (with a config folder of the attacker's own, added by ``-cd``
or ``hydra.searchpath``) that would, under plain Hydra, write to a file, import a module or
run a command: through a component's ``_target_``, a nested one, a sweep override, Hydra's
callbacks, logging, launcher or environment. Each must be refused with one message naming
the key, no traceback, and nothing on the file system touched (the test folder, which holds
the victim file and the working folder, is compared before and after). A component of the
user's own, registered the documented way (docs/extending.md), runs.
"""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

from mpclab.cli.app import EXIT_BAD_INPUT, cli
from mpclab.record import files as record

CAR = ["+experiment=car_cvxpy", "recorder=none", "figures.enabled=false", "scenario.t_max=0.2"]

#: attacker's experiment files: {name: body}; VICTIM and MARKER are filled in
EXPERIMENTS = {
    "open_plant": """
defaults:
  - car_cvxpy
  - override /plant: null
  - _self_
plant: {_target_: builtins.open, _args_: [VICTIM, w]}
""",
    "nested_write": """
defaults:
  - car_cvxpy
  - _self_
objective:
  terms:
    tracking:
      weights:
        _target_: pathlib.Path.write_text
        _args_: [{_target_: pathlib.Path, _args_: [VICTIM]}, gone]
""",
    "system_callback": """
defaults:
  - car_cvxpy
  - _self_
hydra:
  callbacks:
    evil: {_target_: logging.os.system, _args_: [touch MARKER]}
""",
    "open_callback": """
defaults:
  - car_cvxpy
  - _self_
hydra:
  callbacks:
    evil: {_target_: builtins.open, _args_: [VICTIM, w]}
""",
    "logging_open": """
defaults:
  - car_cvxpy
  - _self_
hydra:
  hydra_logging:
    handlers:
      console: {class: builtins.open, file: VICTIM, mode: w}
""",
    "log_to_victim": """
defaults:
  - car_cvxpy
  - _self_
hydra:
  job_logging:
    handlers:
      file: {filename: VICTIM, mode: w}
""",
}

#: (command line, the key the message names); "{conf}" is the attacker's folder
CASES = [
    (["-cd", "{conf}", "+experiment=open_plant"], "plant._target_: 'builtins.open'"),
    (["hydra.searchpath=[file://{conf}]", "+experiment=open_plant"],
     "plant._target_: 'builtins.open'"),
    (["-cd", "{conf}", "+experiment=nested_write"],
     "objective.terms.tracking.weights._target_: 'pathlib.Path.write_text'"),
    ([*CAR, "+objective.terms.x={_target_: importlib.import_module, name: antigravity}"],
     "objective.terms.x._target_: 'importlib.import_module'"),
    (["-cd", "{conf}", "+experiment=system_callback"],
     "hydra.callbacks.evil._target_: 'logging.os.system'"),
    (["-m", "-cd", "{conf}", "+experiment=system_callback", "seed=0,1"],
     "hydra.callbacks.evil._target_: 'logging.os.system'"),
    (["-cd", "{conf}", "+experiment=open_callback"],
     "hydra.callbacks.evil._target_: 'builtins.open'"),
    (["-m", *CAR, "seed=0,1", "plant._target_=builtins.open,pathlib.Path.touch"],
     "plant._target_: 'builtins.open'"),
    (["-cd", "{conf}", "+experiment=logging_open"],
     "hydra.hydra_logging.handlers.console.class: 'builtins.open'"),
    (["-cd", "{conf}", "+experiment=log_to_victim"], "hydra.job_logging.handlers.file.filename"),
    ([*CAR, "+hydra.job.env_set.LD_PRELOAD=/tmp/evil.so"], "hydra.job.env_set.LD_PRELOAD"),
    ([*CAR, "hydra.output_subdir=../../elsewhere"], "hydra.output_subdir: '../../elsewhere'"),
    (["-m", *CAR, "seed=0,1", "hydra/launcher=ray_cluster",
      "+hydra.launcher.ray.remote.evil={_target_: builtins.open, file: VICTIM, mode: w}"],
     "hydra.launcher.ray.remote.evil._target_: 'builtins.open'"),
    (["-m", *CAR, "seed=0,1", "hydra/launcher=ray_cluster",
      "+hydra.launcher.ray.init.runtime_env={pip: [evil]}"],
     "hydra.launcher.ray.init.runtime_env"),
    (["-m", *CAR, "seed=0,1", "hydra/sweeper=basic", "hydra/launcher=joblib"],
     "would apply each job's config unchecked"),
    ([*CAR, "plugins=[antigravity]"], "plugins[0]: 'antigravity' is a module of Python's"),
    (["--cfg", "job", *CAR, "hydra.searchpath=[pkg://antigravity]"],
     "hydra.searchpath[0]: 'antigravity' is a module of Python's"),
    (["--experimental-rerun", "{conf}/config.pickle"], "--experimental-rerun"),
]


def attacker(root: Path) -> tuple[Path, Path, Path]:
    """(the attacker's config folder, the victim file, where a command would leave a mark)."""
    victim, marker, conf = root / "victim.txt", root / "marker", root / "conf"
    victim.write_text("precious\n")
    for name, body in EXPERIMENTS.items():
        path = conf / "experiment" / f"{name}.yaml"
        path.parent.mkdir(parents=True, exist_ok=True)
        text = body.replace("VICTIM", str(victim)).replace("MARKER", str(marker))
        path.write_text("# @package _global_\n" + text.lstrip())
    return conf, victim, marker


def snapshot(root: Path) -> dict[str, tuple[int, bytes | None]]:
    return {str(p): (p.stat().st_mtime_ns, p.read_bytes() if p.is_file() else None)
            for p in sorted(root.rglob("*"))}


def _case(args: list[str], names: str):
    """A case; one that picks Hydra's Ray launcher needs the ``ray`` extra to compose."""
    marks = [pytest.mark.needs("ray")] if "hydra/launcher=ray_cluster" in args else []
    return pytest.param(args, names, marks=marks, id=" ".join(args)[:70])


@pytest.mark.parametrize(("args", "names"), [_case(*c) for c in CASES])
def test_a_hostile_config_is_refused_and_touches_nothing(args, names, tmp_path, monkeypatch,
                                                         capsys) -> None:
    conf, victim, marker = attacker(tmp_path)
    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)
    cmd = [a.replace("{conf}", str(conf)).replace("VICTIM", str(victim)) for a in args]
    cmd += [f"hydra.run.dir={work}/run", f"hydra.sweep.dir={work}/sweep"] if not args[
        0].startswith("--experimental") else []
    before = snapshot(tmp_path)
    code = cli(cmd)
    err = capsys.readouterr().err
    assert code == EXIT_BAD_INPUT, err
    assert names in err and err.count("mpclab: error:") == 1, err
    assert "Traceback" not in err
    assert snapshot(tmp_path) == before  # no file written, truncated or made; no folder
    assert not marker.exists() and victim.read_text() == "precious\n"
    assert "antigravity" not in sys.modules


def test_a_swept_experiment_that_may_not_run_is_its_jobs_error_row(tmp_path, monkeypatch
                                                                   ) -> None:
    """A job's own hydra node (from a swept experiment) is checked before Hydra applies it:
    that job is an error row naming the key, the other jobs run."""
    conf, victim, _ = attacker(tmp_path)
    monkeypatch.chdir(tmp_path)
    sweep = tmp_path / "sweep"
    code = cli(["-m", "-cd", str(conf), "+experiment=car_cvxpy,log_to_victim", "seed=0",
                "recorder=none", "figures.enabled=false", "scenario.t_max=0.2",
                f"hydra.sweep.dir={sweep}"])
    assert code == 0
    rows = {p.parent.name: record.read_summary(p.parent) for p in sweep.glob("*/summary.json")}
    assert rows["0"]["status"] == "timeout"
    assert rows["1"]["status"] == "error"
    assert "hydra.job_logging.handlers.file.filename" in rows["1"]["error"]
    assert victim.read_text() == "precious\n"


@pytest.fixture
def own_plant(tmp_path, monkeypatch) -> Path:
    """A user's plant in a module outside mpclab, and an experiment that uses it."""
    (tmp_path / "my_unicycle_plant.py").write_text(
        "from mpclab.plants.base import register_plant\n"
        "from mpclab.plants.unicycle import Unicycle\n\n\n"
        "@register_plant('my_unicycle')\n"
        "class MyUnicycle(Unicycle):\n"
        "    \"\"\"The guide's unicycle under a name of the user's own.\"\"\"\n")
    exp = tmp_path / "conf" / "experiment" / "mine.yaml"
    exp.parent.mkdir(parents=True)
    exp.write_text("# @package _global_\ndefaults:\n  - unicycle_goal\n"
                   "  - override /plant: null\n  - _self_\n"
                   "plugins: [my_unicycle_plant]\n"
                   "plant:\n  _target_: my_unicycle_plant.MyUnicycle\n"
                   "  params: {drag: 0.0}\n"
                   "  input_bounds: {a: [-2.0, 2.0], omega: [-2.0, 2.0]}\n"
                   "  state_bounds: {v: [-1.0, 2.0]}\n")
    monkeypatch.syspath_prepend(str(tmp_path))  # the folder python -m mpclab runs from
    monkeypatch.chdir(tmp_path)
    return tmp_path


def test_a_plant_of_ones_own_registered_by_its_decorator_runs(own_plant, capsys) -> None:
    out = own_plant / "run"
    code = cli(["-cd", str(own_plant / "conf"), "+experiment=mine", "recorder=none",
                "figures.enabled=false", f"hydra.run.dir={out}"])
    assert code == 0, capsys.readouterr().err
    s = record.read_summary(out)
    assert s["status"] == "arrived" and s["plant"] == "my_unicycle"
    assert s["arrival_time_s"] == pytest.approx(6.9, abs=0.15)  # the guide's unicycle


def test_a_plugin_that_is_not_on_the_path_is_one_message(own_plant, capsys) -> None:
    code = cli(["-cd", str(own_plant / "conf"), "+experiment=mine", "plugins=[my_typo]",
                f"hydra.run.dir={own_plant}/run"])
    err = capsys.readouterr().err
    assert code == EXIT_BAD_INPUT and "Traceback" not in err
    assert "plugins[0]: no module 'my_typo' on Python's path" in err
    assert not (own_plant / "run").exists()
