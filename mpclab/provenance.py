"""The line that stamps a result table: command, commit, CPU model and cores, date.

A benchmark script prints :func:`stamp` under each table it makes, so that a number in an
experiment page says what made it and where (nobody types a machine description by hand).
"""

from __future__ import annotations

import datetime as _dt
import os
import platform
import shlex
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path

#: the repository's top folder (the stamp names commands relative to it)
ROOT = Path(__file__).resolve().parents[1]


def commit() -> str:
    """The checked-out commit (short), ``+dirty`` when tracked files differ from it."""
    def git(*args: str) -> str:
        try:
            return subprocess.run(["git", "-C", str(ROOT), *args], capture_output=True,
                                  text=True, check=False, timeout=10).stdout.strip()
        except (OSError, subprocess.TimeoutExpired):
            return ""

    head = git("rev-parse", "--short", "HEAD") or "unknown"
    return head + ("+dirty" if git("status", "--porcelain", "--untracked-files=no") else "")


def cpu_model() -> str:
    """The CPU's model name (``/proc/cpuinfo``), or what the platform says."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def command(argv: Sequence[str] | None = None) -> str:
    """``uv run python SCRIPT ARGS`` (``-m PACKAGE ARGS`` for a package's ``__main__``) as
    typed from the repository's top folder."""
    argv = list(sys.argv if argv is None else argv)
    script = Path(argv[0]).resolve()
    shown = str(script.relative_to(ROOT)) if script.is_relative_to(ROOT) else argv[0]
    if script.name == "__main__.py" and script.is_relative_to(ROOT):  # python -m PACKAGE
        shown = "-m " + ".".join(script.parent.relative_to(ROOT).parts)
    return "uv run python " + " ".join([shown, *(shlex.quote(a) for a in argv[1:])])


def stamp(argv: Sequence[str] | None = None) -> str:
    """``command · commit · CPU model, N cores · date (UTC)``, for the line under a table."""
    date = _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%d %H:%M UTC")
    return (f"`{command(argv)}` · commit {commit()} · {cpu_model()}, {os.cpu_count()} cores"
            f" · {date}")
