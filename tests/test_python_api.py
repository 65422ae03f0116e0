"""The guide's Python API example runs as written (``mpclab.compose``, ``mpclab.run``):
the first ``python`` block of docs/configs.md that calls ``mpclab.run``."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

import mpclab
from conftest import ROOT

pytestmark = pytest.mark.slow


GUIDE = ROOT / "docs" / "configs.md"


def guide_example() -> str:
    blocks = re.findall(r"```python\n(.*?)```", GUIDE.read_text(), re.S)
    return next(b for b in blocks if "mpclab.run(" in b)


def test_the_guide_example_runs(tmp_path: Path, monkeypatch, capsys) -> None:
    monkeypatch.chdir(tmp_path)
    exec(compile(guide_example(), str(GUIDE), "exec"), {})
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
