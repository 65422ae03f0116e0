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
    return _records(text)


def _records(text: str) -> list[dict[str, Any]]:
    out = []
    for line in text.splitlines():
        try:
            out.append(json.loads(line))
        except ValueError:
            continue
    return out


class Tail:
    """The records appended to ``path`` since the last :meth:`new`, read from where that call
    stopped: following a file that grows by a line per job costs each job its new lines, not
    the whole file (which made a sweep's progress quadratic in its jobs)."""

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        self.offset = 0

    def new(self) -> tuple[list[dict[str, Any]], bool]:
        """The whole lines appended since the last call (a line still being written waits for
        the next), and whether they are read from the file's start: on the first call, and
        when the file was started anew (shorter than what was read before)."""
        from_start = self.offset == 0
        try:
            with open(self.path, "rb") as f:
                if os.fstat(f.fileno()).st_size < self.offset:
                    self.offset, from_start = 0, True
                f.seek(self.offset)
                data = f.read()
        except FileNotFoundError:
            self.offset = 0
            return [], True
        end = data.rfind(b"\n") + 1
        self.offset += end
        return _records(data[:end].decode()), from_start
