"""docs/extending.md is run: its files are the repo's, and its three examples work.

The guide includes each example file verbatim between ``<!-- include: PATH -->`` and
``<!-- end include -->``; every include must equal the file, and every ``mpclab/`` or
``conf/`` path the guide names must exist. The examples (a plant, an objective term, a
backend, a term of one's own outside mpclab) then run closed loop as the guide says they do.
"""

from __future__ import annotations

import re

import casadi as ca
import numpy as np
import pytest

from conftest import ROOT
from mpclab.cli.app import EXIT_BAD_INPUT, cli
from mpclab.controllers.base import StepContext
from mpclab.core.errors import ConfigError
from mpclab.objectives.base import TermContext
from mpclab.objectives.terminal_heading import TerminalHeading
from mpclab.record import files as record
from mpclab.runner.loop import simulate
from mpclab.runner.single_run import build_run, compose

GUIDE = ROOT / "docs" / "extending.md"
INCLUDE = re.compile(
    r"<!-- include: (?P<path>\S+) -->\n```[a-z]*\n(?P<body>.*?)```\n<!-- end include -->", re.S
)
BASE = ["+experiment=unicycle_goal", "recorder=none", "progress=false", "figures.enabled=false"]
GOAL_HEADING = np.pi / 2


def run(*overrides: str):
    cfg = compose([*BASE, *overrides])
    r = build_run(cfg)
    return r, simulate(r)


def test_guide_includes_equal_the_files() -> None:
    text = GUIDE.read_text()
    includes = list(INCLUDE.finditer(text))
    assert len(includes) >= 8  # 3 examples x (.py + .yaml) + the scenario and experiment
    assert text.count("<!-- include:") == len(includes), "an include marker is malformed"
    for m in includes:
        path = ROOT / m["path"]
        assert path.is_file(), f"docs/extending.md includes {m['path']}, which does not exist"
        assert m["body"] == path.read_text(), f"docs/extending.md's copy of {m['path']} differs"


def test_guide_paths_exist() -> None:
    paths = set(re.findall(r"\b((?:mpclab|conf|tests)/[\w/]+\.(?:py|yaml))\b", GUIDE.read_text()))
    assert paths
    missing = sorted(p for p in paths if not (ROOT / p).is_file())
    assert not missing, f"docs/extending.md names files that do not exist: {missing}"


def test_plant_reaches_goal_pose() -> None:
    """Example 1 + 2: the unicycle driven to (3, 2) heading +y by the CasADi backend."""
    _, res = run()
    last = res.steps.iloc[-1]
    assert res.summary["status"] == "arrived"
    assert res.summary["converged_fraction"] == 1.0
    assert [last.px, last.py] == pytest.approx([3.0, 2.0], abs=0.1)
    assert abs(last.theta - GOAL_HEADING) < 0.1


def test_terminal_heading_is_what_turns_the_unicycle() -> None:
    """Without the term the unicycle reaches the position with the wrong heading."""
    _, res = run("objective.terms.heading.weight=0")
    last = res.steps.iloc[-1]
    assert res.summary["status"] == "timeout"
    assert [last.px, last.py] == pytest.approx([3.0, 2.0], abs=0.01)
    assert abs(last.theta - GOAL_HEADING) > 0.5


def test_terminal_heading_casadi_matches_numpy() -> None:
    r = build_run(compose(BASE))
    term = TerminalHeading(weight=2.5)
    term.name = "heading"
    term.bind(r.plant)
    rng = np.random.default_rng(0)
    X, U = rng.normal(size=(4, 6)) * 3, rng.normal(size=(2, 5))
    goal = rng.normal(size=4) * 3
    ctx = TermContext(x0=X[:, 0], target=np.zeros((4, 6)), u_prev=np.zeros(2), goal=goal)
    got = float(ca.DM(term.casadi_cost(ca.DM(X), ca.DM(U), ctx)))
    assert got == pytest.approx(2.5 * (1 - np.cos(X[2, -1] - goal[2])), rel=1e-12)
    assert TerminalHeading.backends() == ["casadi"]


def test_terminal_heading_refuses_cvxpy() -> None:
    with pytest.raises(ConfigError, match="'heading'.*cvxpy backend.*accept it: casadi"):
        build_run(compose([*BASE, "controller=cvxpy"]))


@pytest.mark.parametrize("preset", ["filtersqp", "ipopt"])
def test_uno_backend_matches_ipopt(preset: str) -> None:
    """Example 3: Uno on the CasADi OCP converges to IPOPT's optimum, and the closed loop
    follows the same path."""
    r_uno, uno = run("controller=casadi_uno", f"controller.preset={preset}")
    r_ipopt, ipopt = run()
    assert uno.summary["status"] == "arrived"
    assert uno.summary["converged_fraction"] == 1.0
    assert set(uno.steps.solver_status) - {""} == {"Converged with feasible KKT point"}
    first = []
    for r in (r_uno, r_ipopt):
        x0, T = r.scenario.x0, r.controller.horizon
        r.controller.reset(x0)
        ctx = StepContext(goal=r.scenario.goal, target=np.tile(r.scenario.goal, (T + 1, 1)))
        first.append(r.controller.step(0.0, x0, ctx))
    assert [s.status for s in first] == ["converged", "converged"]
    assert first[0].cost == pytest.approx(first[1].cost, rel=1e-6)
    cols = ["px", "py", "theta", "v"]
    assert np.allclose(uno.steps[cols].to_numpy(), ipopt.steps[cols].to_numpy(), atol=1e-4)


def test_a_term_of_ones_own_outside_mpclab_caps_the_speed(tmp_path, monkeypatch, capsys
                                                           ) -> None:
    """Section 5: ``plugins: [speed_cap]`` registers the term; without it, one message."""
    folder = ROOT / "docs" / "plugin_example"
    monkeypatch.syspath_prepend(str(folder))  # python -m mpclab run from that folder
    monkeypatch.chdir(tmp_path)
    base = ["-cd", str(folder), "+experiment=unicycle_capped", "recorder=none",
            "figures.enabled=false"]
    assert cli([*base, "plugins=[]", f"hydra.run.dir={tmp_path}/refused"]) == EXIT_BAD_INPUT
    assert ("objective.terms.cap._target_: 'speed_cap.SpeedCap' is not a registered mpclab "
            "component") in capsys.readouterr().err
    assert cli([*base, f"hydra.run.dir={tmp_path}/run"]) == 0
    s = record.read_summary(tmp_path / "run")
    top = record.read_steps(tmp_path / "run")["v"].max()
    assert s["status"] == "arrived" and s["arrival_time_s"] == pytest.approx(8.0, abs=0.15)
    assert top == pytest.approx(1.2, abs=0.05)  # section 4's run: 2.0 m/s
