"""Building a qpOASES-backed controller prints nothing (its C banner is silenced)."""

from __future__ import annotations

import os
import subprocess
import sys

from conftest import ROOT
from mpclab.core.native_output import c_stdout_silenced


def test_c_level_output_is_silenced_and_restored(capfd) -> None:
    with c_stdout_silenced():
        os.write(1, b"hidden from C\n")
    os.write(1, b"visible again\n")
    out = capfd.readouterr().out
    assert "hidden" not in out and "visible again" in out


def test_the_main_experiment_prints_no_banner(tmp_path) -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "mpclab", "+experiment=zumo_bug2", "+ci=smoke",
         f"hydra.run.dir={tmp_path}"],
        cwd=ROOT, capture_output=True, text=True, timeout=300,
    )
    assert proc.returncode == 0, proc.stderr
    assert "qpOASES" not in proc.stdout and "qpOASES" not in proc.stderr
