"""Shared fixtures: compose configs exactly as the app does, and run them into tmp folders."""

from __future__ import annotations

import subprocess
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import pytest

from mpclab.experiment import CONF_DIR as CONF
from mpclab.experiment import compose as compose_cfg  # the config the app runs with

ROOT = CONF.parent


@pytest.fixture
def run_cfg(tmp_path: Path) -> Callable[..., tuple[object, Path]]:
    """``run_cfg(overrides, name="run")`` -> (RunResult, run folder).

    No figures, no recorder and no progress line unless the overrides ask for them
    (later overrides win: pass ``recorder=rerun`` to record).
    """
    from mpclab.experiment import run_experiment

    def _run(overrides: Sequence[str], name: str = "run", figures: bool = False):
        base = ["recorder=none", "progress=false", f"figures.enabled={str(figures).lower()}"]
        cfg = compose_cfg([*base, *overrides])
        out = tmp_path / name
        return run_experiment(cfg, out), out

    return _run


def wait_for(check: Callable[[], bool], proc: subprocess.Popen, limit_s: float = 240.0) -> None:
    """Wait until ``check()`` holds, while ``proc`` (a command to be stopped) still runs."""
    t0 = time.time()
    while not check():
        assert proc.poll() is None, "ended before it could be stopped"
        assert time.time() - t0 < limit_s, "never got under way"
        time.sleep(0.2)
