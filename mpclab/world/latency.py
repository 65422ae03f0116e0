"""When a controller's input acts (``sim.latency``, ``sim.timing.deadline_policy``): the choices and
the recorded latency profiles they draw from (the loop's timing itself is
:class:`mpclab.world.sim_world.SimWorld`'s)."""

from __future__ import annotations

from enum import StrEnum
from typing import Any

import numpy as np
import pandas as pd

from mpclab.config.root import CONF_DIR, config_file
from mpclab.core.errors import ConfigError, number, parse_choice
from mpclab.plants.base import FloatArray


class Latency(StrEnum):
    none = "none"
    measured = "measured"
    fixed = "fixed"  # given as a number of ms
    one_sample = "one_sample"  # computed from the predicted next state, acts one period late
    recorded = "recorded"  # drawn, seeded, from latency_profile
    modelled = "modelled"  # the controller's model of its time on a board, per call


class DeadlinePolicy(StrEnum):
    hold = "hold"  # the input applied before holds for the period
    plan = "plan"  # the next input of the last plan that met its deadline
    late_apply = "late_apply"  # acts when ready; the solves it overran are skipped


def parse_latency(value: Any) -> tuple[Latency, float]:
    """``sim.latency`` as its kind and, for a number of ms, the fixed latency [s]."""
    if isinstance(value, bool):
        raise ConfigError(f"sim.latency must be none, measured, one_sample, recorded, "
                          f"modelled or a number of ms, got {value}")
    if isinstance(value, int | float):
        return Latency.fixed, number(value, "sim.latency", at_least=0) / 1e3
    text = str(value)
    try:
        ms = float(text)
    except ValueError:
        ms = None
    if ms is not None:  # a number given as text (the command line): checked as a number
        return Latency.fixed, number(ms, "sim.latency", at_least=0) / 1e3
    if text == Latency.fixed.value:
        raise ConfigError("sim.latency: give the fixed latency as a number of ms, e.g. 33.8")
    return parse_choice(Latency, text, "sim.latency"), 0.0


def latency_profile_s(path: str | None) -> FloatArray:
    """The latencies [s] of ``sim.timing.latency_profile``: the ``latency_s`` column of a CSV or
    Parquet file (NaN rows, as a step log's final one, dropped). A relative path is read
    from the working folder, else from the config folder (the shipped profiles)."""
    key = "sim.timing.latency_profile"
    if not path:
        raise ConfigError(f"{key}: sim.latency=recorded needs a file with a latency_s column "
                          f"(e.g. {key}=sim/profiles/zumo_bug2_fatrop.csv)")
    file = config_file(path)
    if file is None:
        raise ConfigError(f"{key}: no file {str(path)!r} (from the working folder or {CONF_DIR})")
    if file.suffix not in (".csv", ".parquet"):
        raise ConfigError(f"{key}: {str(path)!r} must be a .csv or .parquet file")
    table = pd.read_parquet(file) if file.suffix == ".parquet" else \
        pd.read_csv(file, comment="#")
    if "latency_s" not in table:
        raise ConfigError(f"{key}: {str(path)!r} has no latency_s column; columns: "
                          f"{', '.join(map(str, table.columns))}")
    values = pd.to_numeric(table["latency_s"], errors="coerce").dropna().to_numpy(dtype=float)
    if not len(values) or not np.all(np.isfinite(values)) or values.min() < 0:
        raise ConfigError(f"{key}: {str(path)!r}: latency_s must hold finite values >= 0 "
                          f"(at least one)")
    return values
