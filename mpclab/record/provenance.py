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
import time
from collections.abc import Sequence
from pathlib import Path

#: the repository's top folder (the stamp names commands relative to it)
ROOT = Path(__file__).resolve().parents[2]
#: when this process imported the module: about when the command started
STARTED = time.time()


#: suffixes of what a page shows (text, tables, figures): a page or a result file written by
#: another command changes nothing a command computes
PAGE_SUFFIXES = frozenset({".md", ".png", ".svg"})


def commit() -> str:
    """The checked-out commit (short), ``+dirty`` when tracked files differed from it before
    this command started (a result file the command itself rewrote does not count, nor a
    page or a result another command wrote: :func:`computes`)."""
    def git(*args: str) -> str:
        try:
            return subprocess.run(["git", "-C", str(ROOT), *args], capture_output=True,
                                  text=True, check=False, timeout=10).stdout
        except (OSError, subprocess.TimeoutExpired):
            return ""

    head = git("rev-parse", "--short", "HEAD").strip() or "unknown"
    changed = git("diff", "--name-only", "HEAD").splitlines()
    dirty = any(computes(p) and _changed_before(ROOT / p) for p in changed)
    return head + ("+dirty" if dirty else "")


def computes(path: str) -> bool:
    """Whether a tracked file (relative to the repository) can change what a command computes:
    anything but a page, a figure or a table of results (under ``experiments/`` or ``docs/``,
    or the README). A CSV under ``conf/`` (a latency profile) is an input, and counts."""
    p = Path(path)
    if p.suffix in PAGE_SUFFIXES and (p.parts[0] in ("experiments", "docs") or path == "README.md"):
        return False
    return not (p.parts[0] == "experiments" and p.suffix == ".csv")


def _changed_before(path: Path) -> bool:
    """A tracked file that differs from the commit: changed before :data:`STARTED`?"""
    try:
        return path.stat().st_mtime < STARTED
    except OSError:
        return True  # deleted


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
    """``uv run python SCRIPT ARGS`` as typed from the repository's top folder (``-m MODULE``
    for a module of the package, run as ``python -m``)."""
    argv = list(sys.argv if argv is None else argv)
    script = Path(argv[0]).resolve()
    args = " ".join(shlex.quote(a) for a in argv[1:])
    if script.is_relative_to(ROOT / "mpclab") and script.suffix == ".py":
        parts = script.relative_to(ROOT).with_suffix("").parts
        module = ".".join(parts[:-1] if parts[-1] == "__main__" else parts)
        return f"uv run python -m {module} {args}".rstrip()
    shown = str(script.relative_to(ROOT)) if script.is_relative_to(ROOT) else argv[0]
    return "uv run python " + " ".join(shlex.quote(a) for a in [shown, *argv[1:]])


def stamp(argv: Sequence[str] | None = None) -> str:
    """``command · commit · CPU model, N cores · date (UTC)``, for the line under a table."""
    date = _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%d %H:%M UTC")
    return (f"`{command(argv)}` · commit {commit()} · {cpu_model()}, {os.cpu_count()} cores"
            f" · {date}")


def stamped(text: str, argv: Sequence[str] | None = None) -> str:
    """``text`` (a Markdown table, say) with :func:`stamp` on a line below it."""
    return f"{text.rstrip()}\n\n{stamp(argv)}\n"


def write_stamped(path: Path | str | None, text: str | Sequence[str],
                  argv: Sequence[str] | None = None) -> str:
    """Print ``text`` stamped (several tables: each under its own stamp); also write it to
    ``path`` (a ``--md`` option) when given."""
    parts = [text] if isinstance(text, str) else list(text)
    out = "\n".join(stamped(part, argv) for part in parts)
    print(out)
    if path is not None:
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        Path(path).write_text(out)
    return out
