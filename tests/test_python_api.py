"""The README's Python API example runs as written (``mpclab.compose``, ``mpclab.run``)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

import mpclab
from conftest import ROOT

pytestmark = pytest.mark.slow


def readme_example() -> str:
    text = (ROOT / "README.md").read_text()
    section = text[text.index("**The Python API**"):]
    return re.search(r"```python\n(.*?)```", section, re.S).group(1)


def test_the_readme_example_runs(tmp_path: Path, monkeypatch, capsys) -> None:
    monkeypatch.chdir(tmp_path)
    exec(compile(readme_example(), "README.md", "exec"), {})
    out = capsys.readouterr().out.splitlines()
    assert out[0].startswith("arrived ")
    assert [line.split()[0] for line in out[-3:]] == ["0", "1", "2"]
    assert len(list((tmp_path / "outputs" / "car_cvxpy").glob("*/summary.json"))) == 4


def test_a_user_folder_from_python(tmp_path: Path) -> None:
    (tmp_path / "experiment").mkdir()
    (tmp_path / "experiment" / "mine.yaml").write_text(
        "# @package _global_\ndefaults:\n  - car_cvxpy\n  - _self_\nname: mine\nseed: 5\n")
    cfg = mpclab.compose(["+experiment=mine"], config_dir=tmp_path)
    assert cfg.name == "mine" and cfg.seed == 5 and cfg.controller.horizon == 10
    with pytest.raises(AttributeError, match="no attribute 'nope'"):
        mpclab.nope  # noqa: B018
