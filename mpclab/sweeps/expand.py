"""A multirun's jobs from its override lines, as Hydra's basic sweeper makes them.

Every sweep (``a,b``, ``range(0,4)``, ``choice(...)``, ``glob(*)``) is expanded into its
values; an override given twice keeps the later; the jobs are the cartesian product in the
order the keys first appear, split into batches of ``max_batch_size`` (None: one batch).
"""

from __future__ import annotations

import itertools
import re
from collections.abc import Sequence
from pathlib import Path

from hydra.core.override_parser.types import Override
from hydra.errors import HydraException


def job_overrides(overrides: Sequence[Override],
                  max_batch_size: int | None = None) -> list[list[list[str]]]:
    """The batches of jobs, each job its list of override lines."""
    per_key: dict[str, list[str]] = {}
    for override in overrides:
        key = override.get_key_element()
        if not override.is_sweep_override():
            per_key[key] = [f"{key}={override.get_value_element_as_str()}"]
        elif override.is_discrete_sweep():
            per_key[key] = [f"{key}={value}" for value in override.sweep_string_iterator()]
        else:
            kind = override.value_type.name if override.value_type else "?"
            raise HydraException(f"a sweep of type {kind} ({override.input_line}) has no list "
                                 "of values: use a comma list, range(...) or choice(...)")
    jobs = [list(job) for job in itertools.product(*per_key.values())]
    if max_batch_size is None or max_batch_size == -1:
        return [jobs]
    if max_batch_size < 1:
        raise HydraException(f"hydra.sweeper.max_batch_size: expected a whole number >= 1 "
                             f"or null, got {max_batch_size}")
    return [jobs[i:i + max_batch_size] for i in range(0, len(jobs), max_batch_size)]


def sweep_dir_override(sweep_dir: Path | str) -> str:
    """The override that puts a job under the sweep's folder, resolved once from the sweep's
    config: each job's own config could resolve ``hydra.sweep.dir`` elsewhere (its default,
    ``outputs/multirun/${name}/...``, names each experiment of a sweep over experiments)."""
    text = str(sweep_dir)
    if re.fullmatch(r"[\w./-]+", text):
        return f"hydra.sweep.dir={text}"
    return "hydra.sweep.dir='" + text.replace("'", "\\'") + "'"  # Hydra's quoted string
