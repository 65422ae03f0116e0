"""``python -m mpclab.cli.board --out DIR OVERRIDES...``: a controller's generated C as
a standalone folder for a board (:mod:`mpclab.codegen.board`).

The overrides compose the config as for ``python -m mpclab`` (``+experiment=bicycle_scheduled
scenario=turn``); the controller must be the switched scheduled one (``controller=scheduled``,
``controller.schedule.mode=switched``, no hysteresis), built with ``controller.codegen=true``. The
example in ``main.c`` replays ``--steps`` states spread over a closed-loop run of the same
config, and ``expected_output.txt`` holds what the desktop build of the same C printed for
them. This command sits on the top floor: it builds a run from a config.

    python -m mpclab.cli.board --out board +experiment=bicycle_scheduled
    make -C board && make -C board run
"""

from __future__ import annotations

import argparse
import shlex
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from mpclab.codegen import board, pil
from mpclab.config.registry import target
from mpclab.controllers.scheduled.mpc import ScheduledMPC
from mpclab.core.errors import ConfigError, exit_on_bad_input
from mpclab.runner.loop import simulate
from mpclab.runner.single_run import build_run, compose

#: what the export adds to the user's overrides: no files of a run (and ``codegen``, once the
#: controller is known to have it)
FIXED = ("recorder=none", "progress=false", "figures.enabled=false")
EXPECTED = "expected_output.txt"


def export(overrides: Sequence[str], out_dir: Path, steps: int = 5) -> list[Path]:
    """Build the controller of ``overrides`` and write its board folder into ``out_dir``,
    with ``expected_output.txt``; the files written."""
    cfg = compose([*overrides, *FIXED])
    if cfg.controller.get("_target_") != target(ScheduledMPC):
        raise ConfigError(f"controller: {cfg.controller.get('_target_')} has no C for a board; "
                          "valid: controller=scheduled (mode switched), e.g. "
                          "+experiment=bicycle_scheduled")
    if steps < 1:
        raise ConfigError(f"--steps must be at least 1, got {steps}")
    cfg.controller.codegen = True
    run = build_run(cfg)
    ctrl = run.controller
    library = ctrl.c_library
    recorded = simulate(run).steps
    x, ref = pil.recorded_states(recorded, run.plant.states,
                                 lambda t: run.scenario.target(t, ctrl.horizon, ctrl.dt), steps)
    files = board.write_board(
        library.tables, out_dir, states=run.plant.states, inputs=run.plant.inputs,
        dt=ctrl.dt, x=x, ref=ref, title=f"{cfg.name}: its controller as C for a board",
        command=" ".join(shlex.quote(o) for o in overrides))
    lines = []
    for xi, ri in zip(x, ref, strict=True):
        code, z, op, iters = library.step(xi, ri)
        u = " ".join(f"{v:.9f}" for v in np.asarray(z)[: run.plant.nu])
        lines.append(f"step: code {code}, operating point {op}, iterations {iters}, u {u}")
    expected = Path(out_dir) / EXPECTED
    expected.write_text("\n".join([*lines, "done", ""]))
    return [*files, expected]


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m mpclab.cli.board", description=__doc__.split("\n\n")[0],
        epilog="example: python -m mpclab.cli.board --out board "
               "+experiment=bicycle_scheduled; then make -C board run")
    parser.add_argument("--out", type=Path, required=True, help="the folder to write")
    parser.add_argument("--steps", type=int, default=5,
                        help="recorded states the example in main.c replays (default 5)")
    parser.add_argument("overrides", nargs="*", help="as for python -m mpclab")
    args = parser.parse_args(argv)
    try:
        files = export(args.overrides, args.out, args.steps)
    except Exception as exc:  # noqa: BLE001  (bad input: one message; a bug: its traceback)
        exit_on_bad_input(parser, exc)
    print(f"wrote {args.out}: {', '.join(p.name for p in files)}")
    print(f"build: make -C {args.out}  (arm-none-eabi-gcc; PRECISION=single for float); "
          f"run on QEMU: make -C {args.out} run")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
