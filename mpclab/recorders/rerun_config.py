"""The run's config and package versions as a Markdown document for its recording."""

from __future__ import annotations

import enum
import functools
from collections.abc import Mapping
from typing import Any

import yaml
from omegaconf import DictConfig, OmegaConf


def config_document(cfg: Mapping[str, Any] | DictConfig | None) -> str:
    """The resolved config as a YAML block and the package versions as a table (Markdown)."""
    if isinstance(cfg, DictConfig):
        cfg = OmegaConf.to_container(cfg, resolve=True)
    if cfg is None:
        text = "# (no config given)\n"
    else:  # PyYAML's C dumper: OmegaConf's own dump costs ~10x more per run
        text = yaml.dump(_plain(cfg), Dumper=getattr(yaml, "CSafeDumper", yaml.SafeDumper),
                         sort_keys=False)
    rows = "\n".join(f"| {k} | {v} |" for k, v in _versions().items())
    return (f"# Run config\n\n```yaml\n{text}```\n\n# Versions\n\n"
            f"| package | version |\n| --- | --- |\n{rows}\n")


def _plain(value: Any) -> Any:
    """Config data as YAML-safe builtins (enums by name)."""
    if isinstance(value, Mapping):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    if isinstance(value, enum.Enum):
        return value.name
    return value


@functools.cache
def _versions() -> dict[str, str]:
    """Package versions, looked up once per process (reading package metadata is slow)."""
    from mpclab.record.files import versions

    return versions()
