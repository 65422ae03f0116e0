"""The NN pipeline end to end at smoke size: dataset, training, DAgger, evaluation files."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pandas as pd
import pytest

from conftest import ROOT
from mpclab.approx import dataset
from mpclab.approx.pipeline import load_conf, main
from mpclab.policy.mlp import MLP


@pytest.mark.slow
@pytest.mark.needs("nn")
def test_smoke_pipeline_goes_from_nothing_to_an_evaluation(tmp_path: Path) -> None:
    work, pub = tmp_path / "work", tmp_path / "pub"
    main(["--config", str(ROOT / "conf/approx/zumo_nn_smoke.yaml"),
          f"work_dir={work}", f"publish_dir={pub}", f"weights_file={pub / 'weights.npz'}"])
    data, meta = dataset.read(work / "dataset.parquet")
    assert meta["runs"] == 4 and meta["missing"] == [] and len(data) > 0
    # the hash each Hydra job's recorder wrote is the hash of the config Hydra saved for it
    for run_dir, rows in data.groupby("run"):
        assert set(rows["config_hash"]) == {dataset.config_hash(Path(run_dir))}
    assert len(meta["config_hashes"]) == 1
    mlp = MLP.load(pub / "weights.npz")
    assert mlp.sizes == [26, 16, 2] and mlp.meta["dagger_rounds"] == 1
    assert "void mpclab_nn(" in (pub / "mpclab_nn.c").read_text()
    history = pd.read_csv(pub / "training.csv")
    assert list(history["round"]) == [0, 1]
    assert history["rows"].iloc[1] > history["rows"].iloc[0]  # DAgger added labelled states
    ev = json.loads((pub / "evaluation.json").read_text())
    assert [r["controller"] for r in ev["held_out"]] == ["MPC expert", "NN"]
    assert all(r["runs"] == 3 for r in ev["held_out"])
    if shutil.which("cc") or shutil.which("gcc"):  # the exported net, compiled and timed
        assert ev["compiled"]["states"] > 0 and ev["compiled"]["speedup_median"] > 1
        assert "compiled net" in (pub / "evaluation.md").read_text()
    assert {r["layout"] for r in ev["layouts"]} == {"zumo_wall"}
    assert (pub / "paths.png").stat().st_size > 10_000
    for table in ("training.md", "evaluation.md"):  # stamped: command, commit, CPU, date
        text = (pub / table).read_text()
        assert " · commit " in text and " cores · " in text
    evaluation = (pub / "evaluation.md").read_text()  # each table under its own stamp
    assert evaluation.count(" · commit ") == evaluation.count("\n## ") + 1 == 2
    # the evaluation alone re-runs on the published net, with no dataset in its work folder
    (pub / "evaluation.md").unlink()
    main(["--config", str(ROOT / "conf/approx/zumo_nn_smoke.yaml"), "--stages", "eval",
          f"work_dir={tmp_path / 'eval_only'}", f"publish_dir={pub}",
          f"weights_file={pub / 'weights.npz'}"])
    assert not (tmp_path / "eval_only" / "dataset.parquet").exists()
    assert "## Single obstacle, held-out starts" in (pub / "evaluation.md").read_text()


def test_pipeline_config_typos_are_errors() -> None:
    from omegaconf.errors import ConfigKeyError

    with pytest.raises(ConfigKeyError, match="hiden"):
        load_conf(ROOT / "conf/approx/zumo_nn.yaml", ["train.hiden=[3]"])
    conf = load_conf(ROOT / "conf/approx/zumo_nn.yaml", ["train.hidden=[64,64]"])
    assert conf.train.hidden == [64, 64] and conf.data.runs == 1000
