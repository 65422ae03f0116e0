"""Append-only JSON-lines files that several sweep workers write at once.

Each record is one ``write`` of one line to a file opened with ``O_APPEND``: on a local file
system the kernel appends every such write whole, so workers need no lock, and a sweep that
dies at job 900 leaves 899 whole lines (at worst one torn last line, which readers skip).
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any


def append(path: Path, record: dict[str, Any]) -> None:
    """Append ``record`` as one JSON line to ``path`` (created if missing)."""
    data = (json.dumps(record, allow_nan=False) + "\n").encode()
    fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
    try:
        os.write(fd, data)
    finally:
        os.close(fd)


def read(path: Path) -> list[dict[str, Any]]:
    """Every whole record of ``path`` (none if it does not exist); a torn line is skipped."""
    try:
        text = Path(path).read_text()
    except FileNotFoundError:
        return []
    out = []
    for line in text.splitlines():
        try:
            out.append(json.loads(line))
        except ValueError:
            continue
    return out
