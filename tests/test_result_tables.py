"""A result table on a page is the table its script wrote, not a copy typed by hand.

A result table is a Markdown table followed (within two lines) by its stamp, the line with
`` · commit `` that the script printed under it (command, commit, CPU, date). The table must
appear, unchanged, in a results file beside the page (``experiments/<name>/*.md``) or in the
file its command wrote with ``--md``. The stamped tables whose script prints them without
writing a file are listed in :data:`UNBACKED` (by their stamp's command): the list may only
shrink, and a new stamped table without its file fails.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from conftest import ROOT

PAGES = [*sorted(ROOT.glob("experiments/*/README.md")), *sorted(ROOT.glob("docs/*.md"))]
STAMP = " · commit "

#: stamped tables printed by their command, with no results file to check them against
UNBACKED: set[tuple[str, str]] = set()


def stamped_tables(page: Path) -> list[tuple[str, str]]:
    """``(table, stamp)`` of every stamped table of ``page``."""
    lines = page.read_text().split("\n")
    out, i = [], 0
    while i < len(lines):
        if not lines[i].startswith("|"):
            i += 1
            continue
        j = i
        while j < len(lines) and lines[j].startswith("|"):
            j += 1
        stamp = next((lines[k] for k in range(j, min(j + 3, len(lines))) if STAMP in lines[k]),
                     None)
        if stamp is not None:
            out.append(("\n".join(lines[i:j]), stamp))
        i = j
    return out


def command_of(stamp: str) -> str:
    """The stamp's command up to its first argument (its script or module)."""
    command = re.search(r"`([^`]+)`", stamp)
    words = (command.group(1) if command else stamp).split()
    keep = 5 if words[:4] == ["uv", "run", "python", "-m"] else 4
    return " ".join(words[:keep])


@pytest.mark.parametrize("page", PAGES, ids=[str(p.relative_to(ROOT)) for p in PAGES])
def test_a_stamped_table_is_its_scripts_file(page: Path) -> None:
    rel = str(page.relative_to(ROOT))
    files = [f for f in sorted(page.parent.glob("*.md")) if f != page]
    unbacked = []
    for table, stamp in stamped_tables(page):
        written = re.search(r"--md\s+([^\s`]+)", stamp)
        sources = [*([ROOT / written.group(1)] if written else []), *files]
        if any(f.is_file() and table in f.read_text() for f in sources):
            continue
        if written:
            pytest.fail(f"{rel}: a table stamped `{command_of(stamp)}` differs from "
                        f"{written.group(1)}, the file its command wrote")
        unbacked.append((rel, command_of(stamp)))
    new = sorted(set(unbacked) - UNBACKED)
    assert not new, f"stamped tables with no results file to check them against: {new}"


def test_the_unbacked_list_holds_only_what_is_there() -> None:
    present = {(str(p.relative_to(ROOT)), command_of(s))
               for p in PAGES for _, s in stamped_tables(p)}
    gone = sorted(UNBACKED - present)
    assert not gone, f"remove from UNBACKED (no such stamped table): {gone}"
