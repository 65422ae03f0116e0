"""The tools' own command lines (tables, recording merge, the NN pipeline's steps): bad input
or a missing path is one message with the usage, exit 2, no traceback."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pytest

from mpclab.approx import dataset, export_c, pipeline, train
from mpclab.cli import merge
from mpclab.cli import tables as report

#: (command, its arguments, strings the message must hold); ``{tmp}``: a folder holding
#: ``empty/`` (a folder with nothing in it) and ``not_weights.npz`` (text)
CASES: list[tuple[Callable[[list[str]], object], list[str], list[str]]] = [
    (report.main, ["{tmp}/nope"], ["no such folder", "{tmp}/nope"]),
    (report.main, ["{tmp}/empty"], ["no run records"]),
    (merge.main, ["{tmp}/nope"], ["no recording or folder", "{tmp}/nope"]),
    (merge.main, ["{tmp}/empty"], ["no run.rrd found"]),
    (dataset.main, ["{tmp}/nope", "-o", "{tmp}/d.parquet"], ["no such folder", "{tmp}/nope"]),
    (dataset.main, ["{tmp}/empty", "-o", "{tmp}/d.parquet"], ["no run folders"]),
    (train.main, ["{tmp}/d.parquet", "-o", "{tmp}/w.npz"], ["no dataset at"]),
    (export_c.main, ["{tmp}/w.npz"], ["no NN weights at"]),
    (export_c.main, ["{tmp}/not_weights.npz"], ["is not an MLP weights file"]),
    (pipeline.main, ["--config", "{tmp}/nope.yaml"], ["nope.yaml"]),
    (pipeline.main, ["train.hiden=3"], ["train.hiden"]),
    (pipeline.main, ["train.max_iter=many"], ["train.max_iter", "many"]),
    (pipeline.main, ["--stages", "data,trian"], ["trian", "dagger"]),
]


@pytest.mark.parametrize(("main", "args", "wanted"), CASES,
                         ids=[f"{m.__module__}:{' '.join(a)}" for m, a, _ in CASES])
def test_a_tool_refuses_bad_input_with_one_message(main, args, wanted, tmp_path: Path,
                                                   capsys) -> None:
    (tmp_path / "empty").mkdir()
    (tmp_path / "not_weights.npz").write_text("text, not an npz")
    with pytest.raises(SystemExit) as stop:
        main([a.format(tmp=tmp_path) for a in args])
    assert stop.value.code == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and "error: " in err, err
    for w in wanted:
        assert w.format(tmp=tmp_path) in err, f"{w!r} not in:\n{err}"


def test_training_without_its_extra_is_one_message_before_any_work(tmp_path: Path, capsys,
                                                                   monkeypatch) -> None:
    """Without scikit-learn (the ``nn`` extra) the pipeline refuses a training stage at once,
    naming the command that installs it, before its data stage sweeps anything."""
    real = train.importlib.util.find_spec
    monkeypatch.setattr(train.importlib.util, "find_spec",
                        lambda name, *a: None if name == "sklearn" else real(name, *a))
    with pytest.raises(SystemExit) as stop:
        pipeline.main([f"work_dir={tmp_path / 'work'}", f"publish_dir={tmp_path / 'pub'}"])
    assert stop.value.code == 2
    err = capsys.readouterr().err
    assert "uv sync --extra nn" in err and "Traceback" not in err
    assert not (tmp_path / "work").exists()
