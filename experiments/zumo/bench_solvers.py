"""CasADi solvers side by side on recorded closed-loop states (experiments/zumo/SOLVERS.md).

Runs the experiment once with IPOPT to convergence and records what the controller was given
at every step (state, detections, the supervisor's active terms, target). Then every
candidate solver replays those steps in order, warm-starting from its own previous solution
as it would in the loop, and the table gives per candidate: the fraction of steps solved to
convergence, the median and p95 time of ``controller.step`` [ms], mean iterations, and how
often its first input agrees with a tight-tolerance IPOPT solve of the same step (1e-3).
Beside the wall time, the CPU time of the solving thread: on a loaded machine the wall time
includes waits for a core, the CPU time does not.
Rounds alternate the candidates so that a load change on the machine hits them alike.

    uv run python experiments/zumo/bench_solvers.py                      # Zumo BUG2, all
    uv run python experiments/zumo/bench_solvers.py --only fatrop-jit ipopt-single
    uv run python experiments/zumo/bench_solvers.py --experiment car_casadi

The table is printed with its stamp (command, commit, CPU, date); ``--md FILE`` also writes it.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from omegaconf import OmegaConf

from mpclab.controllers.base import SolveStatus, StepContext
from mpclab.controllers.casadi.mpc import CasadiMPC
from mpclab.core.native_output import c_stdout_silenced
from mpclab.record.provenance import write_stamped
from mpclab.runner.loop import simulate
from mpclab.runner.single_run import build_run, compose

QPS = ("qpoases", "osqp", "qrqp", "hpipm", "daqp", "piqp", "proxqp")


def fatrop_options() -> dict[str, Any]:
    """The fatrop options of ``controller=casadi_fatrop`` (conf/controller/casadi_fatrop.yaml)."""
    cfg = compose(["+experiment=zumo_bug2", "controller=casadi_fatrop"])
    return OmegaConf.to_container(cfg.controller.solve.options)


def candidates() -> dict[str, dict[str, Any]]:
    """Name -> controller options (on top of the experiment's controller config, which the
    recording run sets to IPOPT: ``fatrop*`` carry casadi_fatrop's options, except
    ``fatrop-jit-defaults``, fatrop as it comes)."""
    tuned = fatrop_options()
    c: dict[str, dict[str, Any]] = {
        "ipopt-single": {"solver": "ipopt", "shooting": "single"},
        "ipopt-multiple": {"solver": "ipopt", "shooting": "multiple"},
        "ipopt-multiple-jit": {"solver": "ipopt", "shooting": "multiple", "jit": True},
        "fatrop": {"solver": "fatrop", "shooting": "multiple"},
        "fatrop-jit": {"solver": "fatrop", "shooting": "multiple", "jit": True},
        "fatrop-jit-defaults": {"solver": "fatrop", "shooting": "multiple", "jit": True,
                                "solver_options": {}},  # without casadi_fatrop's options
        "fatrop-jit-sets": {"solver": "fatrop", "shooting": "multiple", "jit": True,
                            "active_sets": "recorded"},
        "fatrop-jit-tol1e-4": {"solver": "fatrop", "shooting": "multiple", "jit": True,
                               "tol": 1e-4},
        "fatrop-jit-O0": {"solver": "fatrop", "shooting": "multiple", "jit": True,
                          "jit_flags": ["-O0"]},
        "fatrop-jit-O2": {"solver": "fatrop", "shooting": "multiple", "jit": True,
                          "jit_flags": ["-O2"]},
    }
    for name, opts in c.items():
        if name.startswith("fatrop") and name != "fatrop-jit-defaults":
            opts["solver_options"] = tuned
    for shooting in ("single", "multiple"):
        for qp in QPS:
            if qp == "hpipm" and shooting == "single":
                continue  # crashes the process (segfault), refused by the controller
            c[f"sqp-{qp}-{shooting}"] = {"solver": "sqp", "qp_solver": qp, "shooting": shooting}
    c["sqp-qrqp-multiple-jit"] = {"solver": "sqp", "qp_solver": "qrqp", "shooting": "multiple",
                                  "jit": True}
    c["sqp-qrqp-single-jit"] = {"solver": "sqp", "qp_solver": "qrqp", "shooting": "single",
                                "jit": True}
    c["sqp_capped-3-qpoases-single"] = {"solver": "sqp_capped", "qp_solver": "qpoases",
                                     "shooting": "single", "sqp_iterations": 3}
    return c


@dataclass
class Recorded:
    t: float
    x: np.ndarray
    ctx: StepContext


def record(experiment: str, overrides: list[str]) -> tuple[Any, list[Recorded], str]:
    """Run ``experiment`` with IPOPT to convergence; the steps as the controller saw them."""
    cfg = compose([f"+experiment={experiment}", "controller=casadi", "recorder=none",
                   "controller.solver=ipopt", "controller.build.jit=false", *overrides])
    run = build_run(cfg)
    steps: list[Recorded] = []
    inner = run.controller.step

    def step(t: float, x: Any, ctx: StepContext) -> Any:
        steps.append(Recorded(t, np.array(x, dtype=float), ctx))
        return inner(t, x, ctx)

    run.controller.step = step
    res = simulate(run)
    return cfg, steps, str(res.summary["status"])


def build(cfg: Any, run: Any, opts: dict[str, Any],
          steps: list[Recorded] = ()) -> CasadiMPC:
    """The experiment's controller with ``opts``; ``active_sets: recorded`` gives one NLP
    to each set of terms the recorded steps used."""
    c = OmegaConf.to_container(cfg.controller, resolve=True)
    c.pop("_target_")
    c.update(opts)
    if c.get("active_sets") == "recorded":
        c["active_sets"] = sorted({tuple(sorted(s.ctx.active)) for s in steps
                                   if s.ctx.active is not None})
    return CasadiMPC(run.plant, run.controller.objective, **c)


def replay(ctrl: CasadiMPC, steps: list[Recorded]) -> list[tuple[float, float, Any]]:
    """``(wall time, CPU time of this thread, result)`` per step, replayed in order."""
    ctrl.reset(steps[0].x)
    out = []
    for s in steps:
        t0, c0 = time.perf_counter(), time.thread_time()
        res = ctrl.step(s.t, s.x, s.ctx)
        out.append((time.perf_counter() - t0, time.thread_time() - c0, res))
    return out


def reference(cfg: Any, run: Any, steps: list[Recorded]) -> list[np.ndarray]:
    """IPOPT at tol 1e-8 on each recorded step, each warm-started like the loop."""
    ref = build(cfg, run, {"solver": "ipopt", "shooting": "multiple", "tol": 1e-8,
                           "max_iter": 500})
    return [res.u for _, _, res in replay(ref, steps)]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--experiment", default="zumo_bug2")
    ap.add_argument("--only", nargs="*", help="candidate names (default: all)")
    ap.add_argument("--rounds", type=int, default=1, help="replays of every candidate")
    ap.add_argument("--md", type=Path, help="also write the stamped table here")
    ap.add_argument("overrides", nargs="*", help="Hydra overrides of the recorded run")
    a = ap.parse_args()
    cfg, steps, status = record(a.experiment, a.overrides)
    run = build_run(cfg)
    print(f"{a.experiment}: {len(steps)} recorded steps (IPOPT run: {status})")
    ref = reference(cfg, run, steps)
    table = candidates()
    names = a.only or list(table)
    ctrls = {}
    for name in names:
        t0 = time.perf_counter()
        try:
            with c_stdout_silenced():  # qpOASES' banner
                ctrls[name] = build(cfg, run, table[name], steps)
        except Exception as exc:  # a plugin that refuses this problem (hpipm's structure)
            print(f"  {name}: not built: {type(exc).__name__}: {str(exc).splitlines()[-1]}")
            continue
        if time.perf_counter() - t0 > 1:  # a compile (or a slow build) shows here
            print(f"  built {name} in {time.perf_counter() - t0:.1f} s")
    names = list(ctrls)
    rows: dict[str, list[tuple[float, float, Any]]] = {n: [] for n in names}
    for _ in range(a.rounds):
        for name in names:
            rows[name] += replay(ctrls[name], steps)
    lines = [f"| {'solver':26s} | converged | median ms | p95 ms | CPU median ms | CPU p95 ms "
             f"| mean iter | agree |", "|---|---|---|---|---|---|---|---|"]
    for name in names:
        times = np.array([t for t, _, _ in rows[name]]) * 1e3
        cpu = np.array([c for _, c, _ in rows[name]]) * 1e3
        res = [r for _, _, r in rows[name]]
        conv = np.mean([r.status is SolveStatus.converged for r in res])
        iters = np.mean([r.iterations or 0 for r in res])
        agree = np.mean([np.abs(r.u - ref[i % len(steps)]).max() < 1e-3
                         for i, r in enumerate(res)])
        lines.append(f"| {name:26s} | {conv:9.2f} | {np.median(times):9.2f} | "
                     f"{np.percentile(times, 95):6.2f} | {np.median(cpu):13.2f} | "
                     f"{np.percentile(cpu, 95):10.2f} | {iters:9.1f} | {agree:5.2f} |")
    write_stamped(a.md, "\n".join(lines), sys.argv)


if __name__ == "__main__":
    main()
