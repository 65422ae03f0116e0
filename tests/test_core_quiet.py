"""Building a qpOASES-backed controller prints nothing (its C banner is silenced)."""

from __future__ import annotations

import os

from conftest import compose_cfg
from mpclab.experiment import build_run
from mpclab.quiet import c_stdout_silenced


def test_c_level_output_is_silenced_and_restored(capfd) -> None:
    with c_stdout_silenced():
        os.write(1, b"hidden from C\n")
    os.write(1, b"visible again\n")
    out = capfd.readouterr().out
    assert "hidden" not in out and "visible again" in out


def test_building_the_sqp_backend_prints_no_banner(capfd) -> None:
    build_run(compose_cfg(["+experiment=zumo_bug2", "recorder=none"]))
    out = capfd.readouterr().out
    assert "qpOASES" not in out
