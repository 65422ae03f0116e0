"""``instantiate.build``: a flat node is called directly, with what Hydra's instantiate passes.

Most component nodes have one ``_target_`` and plain options; for those ``build`` skips Hydra's
copy of the node and merge of the dependencies into it. The arguments must be the ones Hydra
would pass (plain Python containers, enum members, resolved interpolations, the dependencies
themselves), and a failing call must read as Hydra's does.
"""

from __future__ import annotations

from enum import Enum
from typing import Any

import pytest
from hydra.utils import instantiate
from omegaconf import OmegaConf

from mpclab.config.instantiate import _is_flat, build
from mpclab.config.registry import register_target
from mpclab.core.errors import ConfigError


class Colour(Enum):
    red = "red"


@register_target  # a config builds registered classes only
class Probe:
    """Keeps what it was called with."""

    def __init__(self, gain: float, bounds: Any = None, colour: Any = None, name: str = "",
                 plant: Any = None) -> None:
        if gain < 0:
            raise ValueError(f"controller.gain must be >= 0, got {gain}")
        self.args = dict(gain=gain, bounds=bounds, colour=colour, name=name, plant=plant)


TARGET = f"{__name__}.Probe"


def node(**extra: Any) -> Any:
    cfg = OmegaConf.create({"base": 2.0, "c": {"_target_": TARGET, "gain": "${base}",
                            "bounds": {"u": [-1, 1]}, "name": "x", **extra}})
    cfg.c.colour = Colour.red  # an enum member, as a structured config holds it
    return cfg.c


def test_a_flat_node_gets_what_hydra_passes() -> None:
    plant = object()
    assert _is_flat(node())
    got = build(node(), "c", plant=plant, rng=object()).args
    want = instantiate(node(), _convert_="all", plant=plant).args
    assert got == want
    assert type(got["bounds"]) is dict and type(got["bounds"]["u"]) is list
    assert got["colour"] is Colour.red and got["gain"] == 2.0 and got["plant"] is plant


def test_nested_targets_and_hydra_keys_go_through_hydra() -> None:
    assert not _is_flat(node(inner={"_target_": TARGET, "gain": 1.0}))
    assert not _is_flat(node(_partial_=True))
    nested = build(node(bounds={"_target_": TARGET, "gain": 1.0}), "c").args
    assert isinstance(nested["bounds"], Probe)


def test_a_failing_call_reads_as_hydras() -> None:
    with pytest.raises(ConfigError) as got:
        build(node(gain=-1.0), "c")
    with pytest.raises(ConfigError) as want:
        build(node(gain=-1.0, bounds=[{"_target_": TARGET, "gain": 1.0}]), "c")  # Hydra's
    assert str(got.value) == str(want.value) == "controller.gain must be >= 0, got -1.0"


def test_an_unregistered_target_is_refused_before_anything_is_built() -> None:
    built = []

    class Unregistered:
        def __init__(self, **kwargs: Any) -> None:
            built.append(kwargs)

    inner = {"_target_": f"{__name__}.Unregistered", "x": 1}
    with pytest.raises(ConfigError, match=r"c\.bounds\._target_: 'test_instantiate\."
                       r"Unregistered' is not a registered mpclab component"):
        build(node(bounds=inner), "c")
    with pytest.raises(ConfigError, match=r"c\._target_: 'builtins\.open' is not a regis"):
        build(OmegaConf.create({"c": {"_target_": "builtins.open", "file": "x"}}).c, "c")
    assert not built
