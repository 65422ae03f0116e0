"""``python -m mpclab +experiment=NAME [group=choice ...] [key=value ...]``.

:func:`cli` is the one place where an error reaches the user: bad input (a typo, a wrong
type, an impossible value, a broken file, an unwritable folder) is one short message on
stderr and exit code 2, with no traceback unless ``HYDRA_FULL_ERROR=1``; a single run that
ends ``solver_failed`` or ``error`` exits 1; Ctrl-C, SIGTERM or SIGHUP write the partial run
record (a sweep: every running job's, and the tables of the jobs done) and exit 130. Before
Hydra acts on any of the config, :mod:`mpclab.cli.preflight` checks that it builds nothing but
registered components.
"""

from __future__ import annotations

import gc
import logging
import math
import os
import sys
import traceback
from collections.abc import Sequence
from pathlib import Path

import hydra
from hydra.core.hydra_config import HydraConfig
from hydra.types import RunMode
from omegaconf import DictConfig

from mpclab.cli.help import text as help_text
from mpclab.cli.preflight import check_command_line
from mpclab.config.key_origin import RunOrigin
from mpclab.config.registry import register_all
from mpclab.config.root import BARE_DEFAULTS, CONF_DIR
from mpclab.core.errors import bad_input_message
from mpclab.core.signals import Terminated, signals_interrupt
from mpclab.core.status import SOLVE_KEYS, SolveStatus
from mpclab.runner.loop import RunInterrupted
from mpclab.sweeps.callbacks import failed_sweep, forget_sweep, interrupted_sweep

register_all()  # every component's schema must be in the ConfigStore before composing
# Ray (hydra/launcher=ray_cluster) would otherwise re-create a driver started by `uv run` in
# a new virtual environment per worker, without the `ray` extra; workers use this Python.
os.environ.setdefault("RAY_ENABLE_UV_RUN_RUNTIME_ENV", "0")

log = logging.getLogger("mpclab")

#: run statuses of a single run that make the process exit non-zero
FAILED_RUN_STATUSES = ("solver_failed", "error")
EXIT_BAD_INPUT, EXIT_RUN_FAILED, EXIT_INTERRUPTED = 2, 1, 130
_FULL_ERROR = "HYDRA_FULL_ERROR"


class RunFailed(Exception):
    """A single run that ended without a result (its run record says why)."""

    def __init__(self, status: str, error: str | None, out_dir: Path) -> None:
        super().__init__(f"run ended with status {status}" + (f": {error}" if error else "")
                         + f"; run record: {out_dir}")
        self.status = status


class SweepFailed(Exception):
    """A sweep none of whose jobs has a result (each job's row says why), or that found no
    run record at all."""


class _TaskError(BaseException):
    """Carries an error out of the task past Hydra's job wrapper (which would print
    ``Error executing job with overrides`` before re-raising it) to :func:`cli`."""

    def __init__(self, error: Exception) -> None:
        super().__init__(str(error))
        self.error = error


@hydra.main(config_path=str(CONF_DIR), config_name="config", version_base="1.3")
def main(cfg: DictConfig) -> dict:
    """One run; in a multirun, one job that resumes or records its error as a row."""
    try:
        return _task(cfg)
    except Exception as exc:  # noqa: BLE001  (reported by cli)
        raise _TaskError(exc) from None


def _task(cfg: DictConfig) -> dict:
    from mpclab.runner.single_run import run_experiment

    hc = HydraConfig.get()
    out_dir = Path(hc.runtime.output_dir)
    if hc.runtime.choices.get("experiment") is None:
        names = sorted(p.stem for p in (CONF_DIR / "experiment").glob("*.yaml"))
        log.warning("no +experiment=NAME given: running %s. Experiments: %s", BARE_DEFAULTS,
                    ", ".join(names))
    if hc.mode == RunMode.MULTIRUN:
        from mpclab.sweeps.jobs import run_job

        s = run_job(cfg, out_dir, list(hc.overrides.task), dict(hc.runtime.choices))
    else:
        try:
            s = run_experiment(cfg, out_dir, origin=RunOrigin.from_hydra()).summary
        except RunInterrupted as exc:  # its partial record is written: say where
            exc.out_dir = out_dir
            raise
    log.info("%s", summary_line(s))
    log.info("run record: %s", out_dir)
    if s.get("generated_c"):  # controller.codegen=true: the C it ran, kept with its library
        log.info("generated C (beside its compiled library): %s", ", ".join(s["generated_c"]))
        if s.get("controller") == "scheduled":
            log.info("as a folder for a board: python -m mpclab.cli.board --out DIR "
                     "<the same overrides>")
    if hc.mode != RunMode.MULTIRUN and s.get("status") in FAILED_RUN_STATUSES:
        raise RunFailed(s["status"], s.get("error"), out_dir)
    return s


def summary_line(s: dict) -> str:
    """The end of a run in words: how it ended, what the solver did, the compute per step,
    and the ``sim`` world when it is not the ideal loop (its preset, the latency and how many
    deadlines were missed). Times to 3 significant digits (10 ms and above: whole ms)."""
    status = s.get("status")
    if status == "arrived":
        head = f"arrived in {seconds(s['arrival_time_s'])} s"
    elif status in ("timeout", "collision", "stalled"):
        head = f"{status} at {seconds(s.get('sim_time_s') or 0)} s"
    else:
        head = f"{status}" + (f" ({s['error']})" if s.get("error") else "")
    calls = sum(int(s.get(key) or 0) for key in SOLVE_KEYS.values())
    converged = int(s.get(SOLVE_KEYS[SolveStatus.converged]) or 0)
    others = ", ".join(f"{int(s[key])} {st.value}" for st, key in SOLVE_KEYS.items()
                       if st is not SolveStatus.converged and s.get(key))
    parts = [head, f"{converged} of {calls} solves converged" + (f" ({others})" if others
                                                                  else "")]
    if s.get("solver_failures"):
        parts.append(f"{s['solver_failures']} fell back")
    if s.get("compute_median_ms") is not None:
        p95 = s.get("compute_p95_ms")
        parts.append(f"{milliseconds(s['compute_median_ms'])} ms per step (p95 "
                     f"{'?' if p95 is None else milliseconds(p95)} ms)")
    delayed = s.get("sim_latency") not in (None, "none")
    if s.get("sim") not in (None, "nominal") or delayed:
        world = f"sim {s['sim']}"
        if s.get("latency_median_ms") is not None:
            world += (f": latency {milliseconds(s['latency_median_ms'])} ms median, "
                      f"{int(s.get('deadline_misses') or 0)} deadline misses")
        parts.append(world)
    return " | ".join(parts)


def milliseconds(v: float) -> str:
    """``v`` to 3 significant digits without an exponent (10 and above: whole numbers)."""
    v = float(f"{v:.3g}")  # 9.996 -> 10.0: rounded before the digits are chosen
    if not math.isfinite(v) or v == 0:
        return f"{v:g}"
    if abs(v) >= 10:
        return f"{v:.0f}"
    return f"{v:.{2 - math.floor(math.log10(abs(v)))}f}"


def seconds(v: float) -> str:
    """A simulated time to the hundredth of a second, trailing zeros dropped."""
    return f"{v:.2f}".rstrip("0").rstrip(".")


def cli(argv: Sequence[str] | None = None) -> int:
    """Run ``python -m mpclab ARGV...`` and return its exit code (0: the run has a result).

    Hydra prints errors raised outside the task with their traceback; here every error comes
    back (Hydra re-raises with ``HYDRA_FULL_ERROR`` set, restored afterwards) and bad input
    becomes one message. With ``HYDRA_FULL_ERROR=1`` set by the user, bad input raises.
    """
    args = list(sys.argv[1:] if argv is None else argv)
    if "--help" in args or "-h" in args:  # mpclab's help; Hydra's is --hydra-help
        try:
            sys.stdout.write(help_text([a for a in args if a not in ("--help", "-h")]))
        except Exception as exc:  # noqa: BLE001  (a command line that does not compose)
            return report(exc, os.environ.get(_FULL_ERROR) is not None)
        return 0
    user_full_error = os.environ.get(_FULL_ERROR)
    saved_argv = sys.argv
    root = logging.getLogger()
    saved_logging = (list(root.handlers), root.level)  # Hydra configures the root logger
    if argv is not None:
        sys.argv = [saved_argv[0] if saved_argv else "mpclab", *argv]
    os.environ[_FULL_ERROR] = "1"
    error: Exception | None = None
    try:
        check_command_line(args)  # before Hydra acts on the config (logging, callbacks)
        with signals_interrupt():  # SIGTERM, SIGHUP: as Ctrl-C, the steps so far recorded
            main()
    except _TaskError as wrapped:
        error = wrapped.error
    except KeyboardInterrupt as exc:
        where = getattr(exc, "out_dir", None)
        sweep = interrupted_sweep()
        by = getattr(exc, "how", exc.args[0] if isinstance(exc, Terminated) and exc.args else "")
        how = f" by {by}" if by and by != "Ctrl-C" else ""
        sys.stderr.write(f"mpclab: interrupted{how}" + (
            f"; {sweep}\n" if sweep else
            f"; the steps so far are in {where} (status 'interrupted')\n" if where else "\n"))
        return EXIT_INTERRUPTED
    except SystemExit as exc:  # --help, --cfg, Hydra's own usage errors
        return exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
    except Exception as exc:  # noqa: BLE001  (composing, Hydra's folders: sorted below)
        error = exc
    finally:
        forget_sweep()
        sys.argv = saved_argv
        for handler in root.handlers:
            if handler not in saved_logging[0]:
                handler.close()
        root.handlers[:] = saved_logging[0]
        root.setLevel(saved_logging[1])
        if user_full_error is None:
            os.environ.pop(_FULL_ERROR, None)
        else:
            os.environ[_FULL_ERROR] = user_full_error
    if error is None and (message := failed_sweep()) is not None:
        error = SweepFailed(message)
    # outside the handlers, so that a re-raised error is not shown as raised in one
    return 0 if error is None else report(error, user_full_error is not None)


def report(exc: Exception, full_error: bool) -> int:
    """Write ``exc`` for the user: one message for bad input, a traceback for a bug."""
    if isinstance(exc, RunFailed | SweepFailed):
        sys.stderr.write(f"mpclab: {exc}\n")
        return EXIT_RUN_FAILED
    if full_error:
        raise exc
    message = bad_input_message(exc)
    if message is None:
        traceback.print_exception(exc)
        return 1
    sys.stderr.write(f"mpclab: error: {message}\n(set {_FULL_ERROR}=1 to see the traceback)\n")
    return EXIT_BAD_INPUT


def exit_now(code: int) -> None:
    """End the process with ``code``, leaving its objects to the operating system: the
    collector's last pass over what a sweep built (configs, solvers, frames; 0.2 s after a
    pool of workers) would only delay the exit. Exit handlers and stream flushing run."""
    gc.freeze()
    sys.exit(code)
