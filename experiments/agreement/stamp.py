"""The line that stamps a result table: the command, the commit, the CPU model, its cores and
the date, as the script that made the table sees them."""

from __future__ import annotations

import datetime as _dt
import os
import platform
import shlex
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def commit() -> str:
    """The checked-out commit (short), ``+dirty`` when tracked files differ from it."""
    def git(*args: str) -> str:
        return subprocess.run(["git", "-C", str(ROOT), *args], capture_output=True,
                              text=True, check=False).stdout.strip()

    head = git("rev-parse", "--short", "HEAD") or "unknown"
    return head + ("+dirty" if git("status", "--porcelain", "--untracked-files=no") else "")


def cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def stamp(argv: list[str] | None = None) -> str:
    """``command · commit · CPU model, N cores · date (UTC)``, for the line under a table."""
    argv = sys.argv if argv is None else argv
    cmd = "uv run python " + " ".join(shlex.quote(a) for a in
                                      [str(Path(argv[0]).resolve().relative_to(ROOT)),
                                       *argv[1:]])
    date = _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%d %H:%M UTC")
    return (f"`{cmd}` · commit {commit()} · {cpu_model()}, {os.cpu_count()} cores · {date}")
