"""Shared fixtures: compose configs exactly as the app does, and run them into tmp folders.

A test that needs something beyond ``uv run pytest``'s environment (an extra, a toolchain)
is marked ``@pytest.mark.needs("ray")`` (a name of :data:`SETUPS`): where that is missing it is
skipped with the command that provides it; where ``MPCLAB_REQUIRE`` names it (``.ci/run``'s
second stage, after installing it) a missing one fails the test instead.
"""

from __future__ import annotations

import dataclasses
import importlib.util
import inspect
import os
import subprocess
import time
import typing
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import pytest

from mpclab.codegen.pil import missing_tools
from mpclab.runner.single_run import CONF_DIR as CONF
from mpclab.runner.single_run import compose as compose_cfg  # the config the app runs with

ROOT = CONF.parent

#: PIL's cross compiler, its C library and the emulator (Debian's packages)
PIL_PACKAGES = "gcc-arm-none-eabi libnewlib-arm-none-eabi qemu-system-arm"


def grouped(cls: type, **options: Any) -> dict[str, Any]:
    """``cls``'s keyword arguments from flat ``options``: each field of one of its option
    groups (:mod:`mpclab.core.options`) moved into that group's mapping (tests name the
    option, ``max_iter=1``, not its group)."""
    hints = typing.get_type_hints(cls.__init__)
    out: dict[str, Any] = {}
    for name in inspect.signature(cls.__init__).parameters:
        kinds = typing.get_args(hints.get(name)) or (hints.get(name),)
        group = next((k for k in kinds if dataclasses.is_dataclass(k)), None)
        if group is None:
            continue
        fields = {f.name for f in dataclasses.fields(group)}
        moved = {k: options.pop(k) for k in list(options) if k in fields and k != name}
        if moved:
            out[name] = moved
    return out | options


def _have(*modules: str) -> Callable[[], bool]:
    return lambda: all(importlib.util.find_spec(m) for m in modules)


#: what a ``needs`` marker may name: (is it here?, what is missing, the command that adds it)
SETUPS: dict[str, tuple[Callable[[], bool], str, str]] = {
    "ray": (_have("ray", "hydra_plugins.hydra_ray_launcher"),
            "the `ray` extra (Hydra's Ray launcher)", "uv sync --extra ray"),
    "nn": (_have("sklearn"), "the `nn` extra (scikit-learn, to train the net)",
           "uv sync --extra nn"),
    "search": (_have("optuna"), "the `search` extra (optuna, for the search sweeper)",
               "uv sync --extra search"),
    "pil": (lambda: not missing_tools(), "the Cortex-M4 toolchain and emulator",
            f"sudo apt-get install {PIL_PACKAGES}"),
}
REQUIRE_ENV = "MPCLAB_REQUIRE"

# The suite starts many `python -m mpclab` processes. Where PYTHONDONTWRITEBYTECODE is set
# (CI machines often set it), each would compile every import from source (about 1.5 s of
# start-up); the suite's own processes may write bytecode into the project's environment once.
os.environ.pop("PYTHONDONTWRITEBYTECODE", None)


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line(
        "markers", "needs(name): needs an extra or a toolchain (tests/conftest.py SETUPS)")


def pytest_runtest_setup(item: pytest.Item) -> None:
    required = {n for n in os.environ.get(REQUIRE_ENV, "").split(",") if n}
    for marker in item.iter_markers("needs"):
        for name in marker.args:
            if name not in SETUPS:
                raise ValueError(f"needs({name!r}): not one of {', '.join(SETUPS)}")
            present, what, command = SETUPS[name]
            if present():
                continue
            message = f"needs {what}: `{command}`"
            if name in required:
                pytest.fail(f"{REQUIRE_ENV} names {name!r} but it is missing: {message}")
            pytest.skip(message)


@pytest.fixture
def run_cfg(tmp_path: Path) -> Callable[..., tuple[object, Path]]:
    """``run_cfg(overrides, name="run")`` -> (RunResult, run folder).

    No figures, no recorder and no progress line unless the overrides ask for them
    (later overrides win: pass ``recorder=rerun`` to record).
    """
    from mpclab.runner.single_run import run_experiment

    def _run(overrides: Sequence[str], name: str = "run", figures: bool = False):
        base = ["recorder=none", "progress=false", f"figures.enabled={str(figures).lower()}"]
        cfg = compose_cfg([*base, *overrides])
        out = tmp_path / name
        return run_experiment(cfg, out), out

    return _run


def wait_for(check: Callable[[], bool], proc: subprocess.Popen, limit_s: float = 240.0) -> None:
    """Wait until ``check()`` holds, while ``proc`` (a command to be stopped) still runs; if
    it never does, ``proc`` is killed (a failed test leaves no run going on)."""
    t0 = time.time()
    while not check():
        if proc.poll() is not None:
            raise AssertionError("ended before it could be stopped")
        if time.time() - t0 >= limit_s:
            proc.kill()
            proc.wait()
            raise AssertionError("never got under way")
        time.sleep(0.2)
