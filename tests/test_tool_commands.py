"""The tools' own command lines (tables, recording merge, the NN pipeline's steps): bad input
or a missing path is one message with the usage, exit 2, no traceback."""

from __future__ import annotations

from pathlib import Path

import pytest

from mpclab.approx import dataset, export_c, pipeline, train
from mpclab.recording import merge
from mpclab.sweeps import report


def _cases(tmp: Path) -> list[tuple[object, list[str], list[str]]]:
    """(main, arguments, strings the message must hold)."""
    (tmp / "empty").mkdir()
    (tmp / "not_weights.npz").write_text("text, not an npz")
    (tmp / "a_file").write_text("not a folder")
    nope = str(tmp / "nope")
    return [
        (report.main, [nope], ["no such folder", nope]),
        (report.main, [str(tmp / "empty")], ["no run records"]),
        (merge.main, [nope], ["no recording or folder", nope]),
        (merge.main, [str(tmp / "empty")], ["no run.rrd found"]),
        (dataset.main, [nope, "-o", str(tmp / "d.parquet")], ["no such folder", nope]),
        (dataset.main, [str(tmp / "empty"), "-o", str(tmp / "d.parquet")], ["no run folders"]),
        (train.main, [str(tmp / "d.parquet"), "-o", str(tmp / "w.npz")], ["no dataset at"]),
        (export_c.main, [str(tmp / "w.npz")], ["no NN weights at"]),
        (export_c.main, [str(tmp / "not_weights.npz")], ["is not an MLP weights file"]),
        (pipeline.main, ["--config", str(tmp / "nope.yaml")], ["nope.yaml"]),
        (pipeline.main, ["train.hiden=3"], ["train.hiden"]),
        (pipeline.main, ["train.max_iter=many"], ["train.max_iter", "many"]),
        (pipeline.main, ["--stages", "data,trian"], ["trian", "dagger"]),
    ]


N_CASES = 13


@pytest.mark.parametrize("case", range(N_CASES))
def test_a_tool_refuses_bad_input_with_one_message(case: int, tmp_path: Path, capsys) -> None:
    cases = _cases(tmp_path)
    assert len(cases) == N_CASES
    main, args, wanted = cases[case]
    with pytest.raises(SystemExit) as stop:
        main(args)
    assert stop.value.code == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and "error: " in err, err
    for w in wanted:
        assert w in err, f"{w!r} not in:\n{err}"
