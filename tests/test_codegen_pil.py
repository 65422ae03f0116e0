"""PIL: the scheduled controller's generated C on an emulated Cortex-M4F (QEMU netduinoplus2).

Needs Debian's gcc-arm-none-eabi, libnewlib-arm-none-eabi and qemu-system-arm (``.ci/run``
installs them); where they are missing, skipped with the command that installs them. About
5 s. The board folder of ``python -m mpclab.cli.board`` is built with its own Makefile and
run the same way.
"""

from __future__ import annotations

import shutil
import subprocess

import numpy as np
import pandas as pd
import pytest
from test_bicycle import controller

from conftest import compose_cfg
from mpclab.codegen import cycles, pil
from mpclab.runner.loop import simulate
from mpclab.runner.single_run import build_run

pytestmark = pytest.mark.needs("pil")

#: board against desktop: the double build is the same IEEE arithmetic in the same order (its
#: doubles in libgcc's software routines); the single build rounds every table and operation
#: to float, on inputs of order 1
TOL = {pil.Precision.double: 1e-12, pil.Precision.single: 1e-3}

#: a firmware's step markers and console, for a hand-written main
MARKERS = """\
void pil_puts(const char *s);
__attribute__((noinline)) void pil_begin(void) { __asm__ volatile("" ::: "memory"); }
__attribute__((noinline)) void pil_end(void) { __asm__ volatile("" ::: "memory"); }
"""
COUNTED = MARKERS + """\
int main(void)
{
    pil_begin();
    __asm__ volatile(".rept 100\\n\\tnop\\n\\t.endr\\n\\tmovs r0, #0\\n\\tmovs r1, #10\\n"
                     "1:\\n\\tadds r0, r0, #1\\n\\tcmp r0, r1\\n\\tbne 1b" ::: "r0", "r1", "cc");
    pil_end();
    pil_puts("00 00 0000 0000000000000000\\ndone\\n");
    return 0;
}
"""


def test_the_instruction_count_is_exact(tmp_path) -> None:
    """100 nops, 2 moves and a 10-pass loop of 3 instructions: 132 instructions."""
    elf, _ = pil.cross_build(COUNTED, pil.Precision.single, tmp_path)
    (step,) = pil.run(elf, count_instructions=True)
    assert step.instructions == 100 + 2 + 10 * 3


@pytest.fixture(scope="module")
def recorded() -> tuple[np.ndarray, np.ndarray]:
    """12 controller calls of a whole closed loop (every heading): states and previews."""
    cfg = compose_cfg(["+experiment=bicycle_scheduled", "scenario=regular_circle_turn",
                       "recorder=none", "progress=false", "figures.enabled=false"])
    run = build_run(cfg)
    steps: pd.DataFrame = simulate(run).steps
    ctrl = run.controller
    return pil.recorded_states(
        steps, run.plant.states, lambda t: run.scenario.target(t, ctrl.horizon, ctrl.dt), 12)


@pytest.mark.parametrize("precision", list(pil.Precision))
def test_pil_on_the_emulated_board_matches_the_desktop_c(recorded, precision, tmp_path) -> None:
    """Horizon 32, control horizon 1, all 8 operating points: fits the F401RE, gives the
    desktop C's moves, and its modelled cycles (the upper bound) put a step well inside the
    20 ms sample."""
    x, ref = recorded
    sil = controller(horizon=32, control_horizon=1, codegen=True)._sil
    check = pil.pil_check(sil.library, x, ref, precision, tmp_path,
                          timings={"high": cycles.HIGH})
    assert len(check.steps) == len(x) and check.ops_agree
    assert len({s.op for s in check.steps}) >= 4
    assert all(s.code == 0 for s in check.steps)
    assert check.max_input_difference <= TOL[precision]
    assert check.fits_f401re
    worst = max(s.cycles["high"] for s in check.steps) / pil.F401RE_CLOCK_HZ
    assert 0 < worst < 0.020  # the cycle model's upper bound


def test_the_exported_board_folder_builds_and_prints_what_the_desktop_c_does(tmp_path) -> None:
    """``python -m mpclab.cli.board``: the folder builds with its own Makefile
    (arm-none-eabi-gcc) and its example, run on the emulated board, prints the inputs the
    desktop build of the same C gave (``expected_output.txt``)."""
    if shutil.which("make") is None:
        pytest.skip("the board folder's Makefile needs make")
    from mpclab.cli import board as board_command

    board = tmp_path / "board"
    assert board_command.main(["--out", str(board), "--steps", "4",
                               "+experiment=bicycle_scheduled",
                               "scenario=regular_circle_turn"]) == 0
    assert {p.name for p in board.iterdir()} >= {"mpc_controller.c", "mpc_controller.h",
                                                  "main.c", "Makefile", "README.md"}
    subprocess.run(["make", "-C", str(board)], check=True, capture_output=True, text=True)
    assert (board / "controller.elf").is_file()
    proc = subprocess.run(["make", "-s", "-C", str(board), "run"], check=True,
                          capture_output=True, text=True, timeout=120,
                          stdin=subprocess.DEVNULL)
    printed = [ln for ln in (proc.stdout + proc.stderr).splitlines()
               if ln.startswith("step:") or ln == "done"]
    expected = (board / "expected_output.txt").read_text().splitlines()
    assert len(printed) == len(expected) == 5 and printed[-1] == "done"
    for got, want in zip(printed[:-1], expected[:-1], strict=True):
        head, _, u = got.partition(", u ")
        want_head, _, want_u = want.partition(", u ")
        assert head == want_head  # return code, operating point, iterations
        # the same double arithmetic; the two printers may round the 9th decimal apart
        np.testing.assert_allclose(np.array(u.split(), dtype=float),
                                   np.array(want_u.split(), dtype=float), atol=2e-9)
