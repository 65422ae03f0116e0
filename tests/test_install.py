"""The built wheel installs into a fresh virtual environment and runs outside the checkout.

The wheel carries the configs (``conf/`` as ``mpclab/conf``, :data:`mpclab.config.root.CONF_DIR`),
so ``python -m mpclab`` runs every experiment its ``--help`` lists with no source tree in sight
(the files the configs name, such as the net's weights, ship with them), and a user's own
folder added with ``-cd`` composes an experiment from the shipped groups.
"""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import pytest

from conftest import ROOT

pytestmark = pytest.mark.slow
UV = shutil.which("uv")


def _run(cmd: list[str], cwd: Path, timeout: float = 600) -> subprocess.CompletedProcess:
    proc = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True, timeout=timeout)
    assert proc.returncode == 0, (cmd, proc.stdout[-3000:], proc.stderr[-3000:])
    return proc


@pytest.mark.skipif(UV is None, reason="needs uv to build the wheel and make the environment")
def test_the_wheel_runs_outside_the_checkout(tmp_path: Path) -> None:
    assert UV is not None
    dist, env, work = tmp_path / "dist", tmp_path / "env", tmp_path / "work"
    _run([UV, "build", "--wheel", "--out-dir", str(dist)], ROOT)
    wheel = next(dist.glob("mpclab-*.whl"))
    _run([UV, "venv", "--quiet", str(env)], tmp_path)
    python = env / "bin" / "python"
    _run([UV, "pip", "install", "--quiet", "--python", str(python), str(wheel)], tmp_path)
    user = tmp_path / "my_confs"
    (user / "experiment").mkdir(parents=True)
    (user / "experiment" / "mine.yaml").write_text(
        "# @package _global_\ndefaults:\n  - car_cvxpy\n  - _self_\nname: mine\n"
        "scenario:\n  t_max: 1.0\n")
    work.mkdir()
    where = _run([str(python), "-c", "import mpclab.config.root as c; print(c.CONF_DIR)"], work)
    assert Path(where.stdout.strip()).is_relative_to(env)  # the shipped configs, not ours
    helped = _run([str(python), "-m", "mpclab", "--help"], work).stdout
    listed = re.findall(r"^  (\w+) ", helped.split("Experiments")[1].split("\n\n")[0], re.M)
    assert "zumo_nn" in listed and "car_cvxpy" in listed, helped
    for name in listed:
        _run([str(python), "-m", "mpclab", f"+experiment={name}", "+ci=smoke"], work)
    out = _run([str(python), "-m", "mpclab", "-cd", str(user), "+experiment=mine",
                "+ci=smoke"], work)
    assert "run record" in out.stdout + out.stderr
    assert list((work / "outputs" / "mine").glob("*/summary.json"))
