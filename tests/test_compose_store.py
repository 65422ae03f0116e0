"""Composed trees kept on disk (mpclab.sweeps.compose_store): Hydra's compose, or composed anew.

A stored tree is taken back only while every source it was composed from is unchanged; what
comes back must be what Hydra composes now, in this process (working directory, copied
environment variables).
"""

from __future__ import annotations

import shutil
from collections import OrderedDict
from pathlib import Path

import pytest
from hydra import initialize_config_dir
from hydra.core.config_store import ConfigStore
from hydra.core.global_hydra import GlobalHydra
from hydra.types import RunMode
from omegaconf import OmegaConf

from conftest import CONF
from mpclab.registry import register_all
from mpclab.sweeps import compose as compose_module
from mpclab.sweeps import compose_store
from mpclab.sweeps.compose import CachedComposeLoader

COMMANDS = [
    (["+experiment=zumo_bug2", "scenario=zumo_random", "seed=3", "recorder=none"], RunMode.RUN),
    (["+experiment=car_cvxpy", "controller=casadi", "seed=1,2"], RunMode.MULTIRUN),
    (["+experiment=car_cvxpy", "seed=2", "~figures", "controller.horizon=12"], RunMode.RUN),
]
PLANT = "plant/zumo.yaml"


@pytest.fixture
def store(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """An empty store in ``tmp_path``, and no tree kept in memory."""
    monkeypatch.setenv("MPCLAB_CACHE", str(tmp_path / "cache"))
    monkeypatch.delenv(compose_store.SWITCH_VAR, raising=False)
    monkeypatch.setattr(compose_module, "_BASES", OrderedDict())
    register_all()
    return tmp_path / "cache" / "compose"


def _compose(conf: Path, overrides: list[str], mode: RunMode) -> tuple[str, str]:
    """(Hydra's compose, the cached loader's compose) of ``overrides``, as YAML; the loader
    starts with no tree in memory, as a new command does."""
    with initialize_config_dir(config_dir=str(conf), version_base="1.3"):
        loader = GlobalHydra.instance().config_loader()
        compose_module._BASES.clear()
        got = CachedComposeLoader(loader).load_configuration("config", overrides, mode)
        want = loader.load_configuration("config", overrides, mode)
    return OmegaConf.to_yaml(got), OmegaConf.to_yaml(want)


@pytest.mark.parametrize(("overrides", "mode"), COMMANDS)
def test_a_stored_tree_is_hydras_compose(store, hydra_calls, tmp_path, monkeypatch,
                                         overrides, mode) -> None:
    got, want = _compose(CONF, overrides, mode)
    assert got == want
    assert len(list(store.glob("*.pkl"))) == 1
    hydra_calls.clear()
    monkeypatch.chdir(tmp_path)  # another command, from another folder
    got, want = _compose(CONF, overrides, mode)
    assert got == want and f"cwd: {tmp_path}" in got  # the working directory is this one
    assert hydra_calls == [mode]  # only the reference: the loader's tree came from the store


def test_a_changed_source_is_composed_again(store, hydra_calls, tmp_path) -> None:
    conf = tmp_path / "conf"
    shutil.copytree(CONF, conf)
    command = ["+experiment=zumo_bug2", "seed=3"]
    _compose(conf, command, RunMode.RUN)
    # a YAML file of the tree edited
    plant = conf / PLANT
    plant.write_text(plant.read_text().replace("  r: 0.02\n", "  r: 0.0217\n", 1))
    hydra_calls.clear()
    got, want = _compose(conf, command, RunMode.RUN)
    assert got == want and "r: 0.0217" in got
    assert len(hydra_calls) == 2  # composed anew, and the reference
    hydra_calls.clear()
    _compose(conf, command, RunMode.RUN)
    assert len(hydra_calls) == 1  # unchanged since: from the store
    # a schema added to the config store
    store_ = ConfigStore.instance()
    store_.store(group="schema/plant", name="store_test", node={"x": 1})
    try:
        hydra_calls.clear()
        _compose(conf, command, RunMode.RUN)
        assert len(hydra_calls) == 2
    finally:
        del store_.repo["schema"]["plant"]["store_test.yaml"]


def test_copied_environment_variables_are_read_again(store, tmp_path, monkeypatch) -> None:
    conf = tmp_path / "conf"
    shutil.copytree(CONF, conf)
    config = conf / "config.yaml"
    job = "  job:\n    chdir: false\n"
    config.write_text(config.read_text().replace(
        job, job + "    env_copy: [MPCLAB_STORE_TEST]\n"))
    monkeypatch.setenv("MPCLAB_STORE_TEST", "first")
    got, _ = _compose(conf, ["+experiment=car_cvxpy"], RunMode.RUN)
    assert "MPCLAB_STORE_TEST: first" in got
    monkeypatch.setenv("MPCLAB_STORE_TEST", "second")
    got, want = _compose(conf, ["+experiment=car_cvxpy"], RunMode.RUN)
    assert got == want and "MPCLAB_STORE_TEST: second" in got


def test_a_torn_entry_or_the_switch_composes_with_hydra(store, hydra_calls, monkeypatch) -> None:
    command = ["+experiment=car_cvxpy", "seed=1"]
    _compose(CONF, command, RunMode.RUN)
    (entry,) = store.glob("*.pkl")
    entry.write_bytes(entry.read_bytes()[:100])  # a write cut short
    hydra_calls.clear()
    got, want = _compose(CONF, command, RunMode.RUN)
    assert got == want and len(hydra_calls) == 2
    monkeypatch.setenv(compose_store.SWITCH_VAR, "0")
    entry.unlink()
    _compose(CONF, command, RunMode.RUN)
    assert not list(store.glob("*.pkl"))


def test_the_store_keeps_the_newest_entries(store, monkeypatch) -> None:
    monkeypatch.setattr(compose_store, "MAX_ENTRIES", 2)
    choices = ["scenario=car_to_origin", "controller=casadi", "recorder=none"]
    for choice in choices:  # three commands, three trees
        _compose(CONF, ["+experiment=car_cvxpy", choice], RunMode.RUN)
    assert len(list(store.glob("*.pkl"))) == 2
