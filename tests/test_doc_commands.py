"""Every command README.md and docs/ show runs as shown, with smoke settings.

A command is a line of a code block (fenced, or indented by four spaces) that starts with
``uv run`` (or ``$ uv run``; a trailing ``\\`` continues it). Each block's commands run in
order, in a fresh working folder that sees the checkout's ``conf/``, ``docs/``,
``experiments/`` and ``tests/`` (so a page's relative paths resolve and nothing is written
into the checkout), with the project's Python in place of ``uv run``. The test fails on a
non-zero exit, and on an output that contradicts the page:

- lines shown under a ``$ command`` are its expected output (and then a non-zero exit is
  what the page shows);
- a run or sweep must write its record where it says (``run record: DIR``, ``sweep of N jobs
  into DIR``: a summary table of N rows there).

What the page leaves to the reader is filled in: ``<name>/<time>``-style placeholders with the
folder the block's last run or sweep announced; ``~/my_confs`` (or ``/home/me/my_confs``) with
a folder holding ``experiment/my_exp.yaml``. ``python -m mpclab`` runs get ``+ci=smoke``
(one simulated second, no recorder unless the block merges or views recordings: then
``recorder=rerun``). A page tunes a block for this test with an HTML comment right before
it: ``<!-- doc-test: ARGS -->`` appends ARGS to each of its mpclab runs (a smaller sweep),
``<!-- doc-test: skip REASON -->`` runs none of it (a benchmark that writes the page's stamped
results; the scripts it names must exist). ``uv run pytest`` is this suite, and ``uv run
rerun FILE`` opens a window: for those, the file must exist.
"""

from __future__ import annotations

import json
import re
import shlex
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

import pandas as pd
import pytest

from conftest import ROOT

pytestmark = pytest.mark.slow

PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
#: what a run or a sweep says about where its record went
ANNOUNCED = re.compile(r"(?:run record: |sweep of (\?|\d+) jobs into )(\S+)")
PLACEHOLDER = re.compile(r"\S*<[^>]+>\S*")
USER_FOLDERS = ("~/my_confs", "/home/me/my_confs")
DIRECTIVE = re.compile(r"<!--\s*doc-test:\s*(.*?)\s*-->")


@dataclass
class Block:
    page: Path
    line: int
    commands: list[tuple[str, list[str]]] = field(default_factory=list)  # (cmd, expected)
    directive: str = ""

    @property
    def id(self) -> str:
        return f"{self.page.relative_to(ROOT)}:{self.line}"


def _blocks(page: Path) -> list[Block]:
    """The code blocks of ``page`` that hold at least one ``uv run`` command."""
    lines = page.read_text().splitlines()
    blocks: list[Block] = []
    directive, fenced = "", False
    current: list[tuple[int, str]] = []

    def close() -> None:
        block = _parse(page, current, directive)
        if block.commands:
            blocks.append(block)

    for i, line in enumerate(lines, start=1):
        if line.strip().startswith("```"):
            if fenced:
                close()
                current, directive = [], ""
            fenced = not fenced
            continue
        if fenced:
            current.append((i, line))
            continue
        if line.startswith("    ") and (current or not line.strip().startswith("-")):
            current.append((i, line[4:]))
            continue
        if current and line.strip() == "":
            current.append((i, ""))
            continue
        if current:
            close()
            current, directive = [], ""
        m = DIRECTIVE.search(line)
        if m:
            directive = m.group(1)
        elif line.strip():
            directive = ""
    if current:
        close()
    return blocks


def _parse(page: Path, body: list[tuple[int, str]], directive: str) -> Block:
    """A block's commands; in a console session (``$ command`` lines), the lines below a
    command are its expected output."""
    block = Block(page, body[0][0] if body else 0, directive=directive)
    session = any(line.strip().startswith("$ ") for _, line in body)
    pending = ""
    for _, raw in body:
        text = pending + raw.strip()
        pending = ""
        if text.endswith("\\"):
            pending = text[:-1].strip() + " "
            continue
        shown = text.removeprefix("$ ") if session else text
        if shown.startswith("uv run ") and (text.startswith("$ ") or not session):
            block.commands.append((shown, []))
        elif session and block.commands and text:
            block.commands[-1][1].append(text)
    return block


BLOCKS = [b for page in PAGES for b in _blocks(page)]


def _user_folder(work: Path) -> Path:
    """The reader's own config folder the pages call ``~/my_confs``."""
    folder = work / "my_confs"
    (folder / "experiment").mkdir(parents=True, exist_ok=True)
    (folder / "experiment" / "my_exp.yaml").write_text(
        "# @package _global_\ndefaults:\n  - car_cvxpy\n  - _self_\nname: my_exp\n")
    return folder


def _argv(command: str, work: Path, last_dir: str | None, smoke: list[str]) -> list[str]:
    """The command as this test runs it."""
    for folder in USER_FOLDERS:
        command = command.replace(f"file://{folder}", f"file://{_user_folder(work)}")
        command = command.replace(folder, str(_user_folder(work)))

    def fill(m: re.Match[str]) -> str:
        assert last_dir is not None, f"{m.group(0)}: no run or sweep before it announced a folder"
        token = m.group(0)
        tail = token[token.rindex(">") + 1:]
        return last_dir + tail

    command = PLACEHOLDER.sub(fill, command)
    args = shlex.split(command, comments=True)
    assert args[:2] == ["uv", "run"], command
    args = args[2:]
    while args and args[0].startswith("--"):  # uv run's own options (--extra nn: marked)
        args = args[2:] if args[0] in ("--extra", "--group", "--with") else args[1:]
    if args[0] == "python":
        args[0] = sys.executable
        if args[1:3] == ["-m", "mpclab"]:
            args += [a for a in smoke if a not in args]  # a page's own +ci=smoke stays one
    return args


def _check_announced(output: str, cwd: Path) -> str | None:
    """The folder the output announced (absolute): a sweep's, else the last run's. A sweep's
    must hold a table of its jobs."""
    last_run = last_sweep = None
    for m in ANNOUNCED.finditer(output):
        folder = str(cwd / m.group(2))  # an absolute path stays itself
        if m.group(1) is None:
            last_run = folder
            continue
        last_sweep = folder  # a sweep: its table, under the folder it announced
        table = Path(folder) / "summary.parquet"
        assert table.is_file(), f"the sweep announced {folder} but wrote no table there"
        if m.group(1) != "?":
            rows = len(pd.read_parquet(table))
            assert rows == int(m.group(1)), f"{table}: {rows} rows, {m.group(1)} jobs"
    return last_sweep or last_run


#: what a command line needs beyond `uv run` (tests/conftest.py SETUPS), by what it holds
NEEDS = {"hydra/launcher=ray_cluster": "ray", "hydra/sweeper=pareto_search": "search",
         "mpclab.approx.pipeline": "nn", "mpclab.approx.train": "nn"}


def _marks(block: Block) -> list[pytest.MarkDecorator]:
    needed = {name for c, _ in block.commands for text, name in NEEDS.items() if text in c}
    needed |= {m for c, _ in block.commands for m in re.findall(r"--extra (\w+)", c)}
    return [pytest.mark.needs(*sorted(needed))] if needed else []


def _checkout_state() -> str:
    """What git sees changed in the checkout (a command must not write into it)."""
    proc = subprocess.run(["git", "status", "--porcelain"], cwd=ROOT, capture_output=True,
                          text=True)
    return proc.stdout if proc.returncode == 0 else ""


@pytest.mark.parametrize("block", [pytest.param(b, id=b.id, marks=_marks(b)) for b in BLOCKS])
def test_the_command_runs_as_shown(block: Block, tmp_path: Path) -> None:
    for name in ("conf", "docs", "experiments", "tests"):
        (tmp_path / name).symlink_to(ROOT / name)
    if block.directive.startswith("skip"):
        assert len(block.directive.split(maxsplit=1)) == 2, f"{block.id}: skip without a reason"
        for command, _ in block.commands:
            scripts = [a for a in shlex.split(command, comments=True) if a.endswith(".py")]
            for script in scripts:
                assert (ROOT / script).is_file(), f"{block.id}: no {script}"
        pytest.skip(f"{block.id}: {block.directive}")
    records = any("recording.merge" in c or "rerun " in c for c, _ in block.commands)
    smoke = ["+ci=smoke", *(["recorder=rerun"] if records else []),
             *shlex.split(block.directive)]
    last_dir: str | None = None
    before = _checkout_state()
    for command, expected in block.commands:
        program = _argv(command, tmp_path, last_dir, [])[0]
        if program == "pytest":
            continue  # this suite
        if program == "rerun":  # the viewer opens a window: the file it opens must exist
            viewed = _argv(command, tmp_path, last_dir, [])[-1]
            assert (tmp_path / viewed).exists() or Path(viewed).exists(), \
                f"{block.id}: `{command}` would open {viewed}, which does not exist"
            continue
        argv = _argv(command, tmp_path, last_dir, smoke)
        proc = subprocess.run(argv, cwd=tmp_path, capture_output=True, text=True, timeout=900)
        output = proc.stdout + proc.stderr
        if expected:  # a console session: the page shows what the command prints
            for line in expected:
                assert line in output, f"{block.id}: `{command}` did not print {line!r}:\n" \
                                       f"{output[-2000:]}"
            continue
        assert proc.returncode == 0, f"{block.id}: `{command}` exited {proc.returncode}:\n" \
                                     f"{output[-3000:]}"
        announced = _check_announced(output, tmp_path)
        if announced is not None:
            last_dir = announced
            summary = Path(last_dir) / "summary.json"
            if summary.is_file():
                json.loads(summary.read_text())  # a whole run record
    assert _checkout_state() == before, f"{block.id} wrote into the checkout (a page's " \
        "benchmark that writes its stamped results wants <!-- doc-test: skip REASON -->)"


def test_the_pages_show_commands() -> None:
    """The extraction finds the README's two commands (a page format it misses is no pass)."""
    readme = [c for b in BLOCKS if b.page.name == "README.md" and b.page.parent == ROOT
              for c, _ in b.commands]
    assert "uv run python -m mpclab +experiment=zumo_bug2" in readme
    assert "uv run pytest" in readme
