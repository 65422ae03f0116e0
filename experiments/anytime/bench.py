"""Anytime solves on the CasADi backend: the real-time iteration's phases beside a capped SQP
step, and solves stopped at a wall-clock cap.

    uv run python experiments/anytime/bench.py --md experiments/anytime/results.md

1. **Side by side** (one closed loop per experiment, driven by the real-time iteration,
   ``controller=casadi_rti``): at every sample the capped SQP with as many iterations
   (``controller=casadi_sqp_capped``, ``sqp_iterations=1``: one sqpmethod step after the
   measurement) is called on the same state and context, in alternating order, each call
   timed with ``perf_counter`` (wall) and ``thread_time`` (CPU: waits for a core do not
   count). The RTI's ``feedback_s`` (from its call to its input) is its latency;
   ``prep_s`` runs after the input (the next sample's preparation); the SQP's time is its
   whole call. Per step the ratio feedback / SQP, wall and CPU: medians (of the times and
   of the ratio), and the steps whose ratio is under one half.
2. **Closed loops** of each controller on its own: status, arrival, statuses counted.
3. **Time caps** (``controller.solve.time_cap_ms``): closed loops whose solves stop at the cap,
   their wall time beyond it (the overrun of each call after the first, which also builds
   the solver's memory: the solver's last iteration past the deadline and the call's own
   overhead; negative for a call that ended before the cap) and the truncated solves the
   summary counts.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[2]

from mpclab.controllers.base import Controller, ControlStep, StepContext  # noqa: E402
from mpclab.core.native_output import c_stdout_silenced  # noqa: E402
from mpclab.record import files as record  # noqa: E402
from mpclab.record.provenance import write_stamped  # noqa: E402
from mpclab.runner.loop import simulate  # noqa: E402
from mpclab.runner.single_run import build_run, compose  # noqa: E402

QUIET = ["recorder=none", "figures.enabled=false", "progress=false"]
RTI = ["controller=casadi_rti"]
SQP1 = ["controller=casadi_sqp_capped", "controller.solve.sqp_iterations=1"]
#: experiment -> its base overrides
EXPERIMENTS = {"car_casadi": ["+experiment=car_casadi"],
               "zumo_bug2 (dead end)": ["+experiment=zumo_bug2"]}
#: (experiment, controller label, overrides, cap [ms]) of the time-capped runs
CAPS = [
    ("car_casadi", "ipopt", ["controller=casadi"], 2.0),
    ("car_casadi", "ipopt", ["controller=casadi"], 5.0),
    ("car_casadi", "sqp (jit)", [], 0.5),
    ("car_casadi", "sqp (jit)", [], 1.0),
    ("zumo_bug2 (dead end)", "ipopt", ["controller=casadi"], 10.0),
    ("zumo_bug2 (dead end)", "sqp_capped 3 it.",
     ["controller=casadi_sqp_capped", "controller.solve.sqp_iterations=3"], 2.0),
]


class SideBySide(Controller):
    """The loop's controller (``main``, whose input is applied) and a ``shadow`` called on
    the same state and context at every sample, in alternating order, both timed."""

    def __init__(self, main: Controller, shadow: Controller) -> None:
        super().__init__(main.plant, main.horizon, main.dt)
        self.main, self.shadow = main, shadow
        self.log_columns = (*main.log_columns, "shadow_s", "shadow_cpu_s", "shadow_status",
                            "main_s")
        self._k = 0

    def reset(self, x0: Any) -> None:
        super().reset(x0)
        self.main.reset(x0)
        self.shadow.reset(x0)
        self._k = 0

    def received(self, u: Any) -> None:
        self.main.received(u)
        self.shadow.received(u)

    def _solve(self, t: float, x: Any, ctx: StepContext) -> ControlStep:
        raise NotImplementedError  # step is overridden

    def step(self, t: float, x: Any, ctx: StepContext) -> ControlStep:
        wall: dict[str, float] = {}
        cpu: dict[str, float] = {}
        order = ("main", "shadow") if self._k % 2 == 0 else ("shadow", "main")
        out: dict[str, ControlStep] = {}
        for who in order:
            t0, c0 = time.perf_counter(), time.thread_time()
            out[who] = getattr(self, who).step(t, x, ctx)
            wall[who], cpu[who] = time.perf_counter() - t0, time.thread_time() - c0
        self._k += 1
        res = out["main"]
        res.info |= {"shadow_s": wall["shadow"], "shadow_cpu_s": cpu["shadow"],
                     "shadow_status": str(out["shadow"].status), "main_s": wall["main"]}
        return res

    def metrics(self, steps: Any) -> dict[str, Any]:
        return self.main.metrics(steps)


def run(overrides: list[str]) -> Any:
    r = build_run(compose([*overrides, *QUIET]))
    with c_stdout_silenced():  # qpOASES' messages
        res = simulate(r)
    print(f"  {' '.join(overrides)}: {res.summary['status']}, {res.summary['n_steps']} steps",
          file=sys.stderr, flush=True)
    return res


def side_by_side(name: str, base: list[str]) -> dict[str, Any]:
    """One RTI closed loop with the 1-iteration capped SQP called beside it."""
    r = build_run(compose([*base, *RTI, *QUIET]))
    shadow = build_run(compose([*base, *SQP1, *QUIET])).controller
    r.controller = SideBySide(r.controller, shadow)
    with c_stdout_silenced():
        res = simulate(r)
    steps = record.controller_steps(res.steps)
    steps = steps[~steps["late_prep"].astype(bool)]  # the first call prepares late
    ms = {c: steps[c].to_numpy(float) * 1e3 for c in
          ("feedback_s", "feedback_cpu_s", "prep_s", "main_s", "shadow_s", "shadow_cpu_s")}
    ratio = ms["feedback_s"] / ms["shadow_s"]
    ratio_cpu = ms["feedback_cpu_s"] / ms["shadow_cpu_s"]
    print(f"  side by side {name}: {res.summary['status']}", file=sys.stderr, flush=True)
    return {
        "experiment": name, "steps": len(steps),
        "rti_feedback_ms": np.median(ms["feedback_s"]),
        "rti_prep_ms": np.median(ms["prep_s"]), "rti_call_ms": np.median(ms["main_s"]),
        "sqp1_call_ms": np.median(ms["shadow_s"]), "ratio": np.median(ratio),
        "under_half": f"{int((ratio < 0.5).sum())} of {len(ratio)}",
        "rti_feedback_cpu_ms": np.median(ms["feedback_cpu_s"]),
        "sqp1_call_cpu_ms": np.median(ms["shadow_cpu_s"]), "ratio_cpu": np.median(ratio_cpu),
        "under_half_cpu": f"{int((ratio_cpu < 0.5).sum())} of {len(ratio_cpu)}",
    }


def closed_loop(name: str, base: list[str], label: str, overrides: list[str]) -> dict:
    res = run([*base, *overrides])
    s, steps = res.summary, record.controller_steps(res.steps)
    fb = steps["feedback_s"].to_numpy(float) * 1e3 if "feedback_s" in steps else None
    return {
        "experiment": name, "controller": label, "status": s["status"],
        "arrival_s": s["arrival_time_s"], "steps": s["n_steps"],
        "converged": s["solves_converged"], "truncated": s["solves_truncated"],
        "failed": s["n_steps"] - s["solves_converged"] - s["solves_truncated"],
        "call_median_ms": s["compute_median_ms"],
        "feedback_median_ms": float(np.median(fb)) if fb is not None else None,
    }


def capped(name: str, label: str, overrides: list[str], cap_ms: float) -> dict[str, Any]:
    res = run([*EXPERIMENTS[name], *overrides, f"controller.solve.time_cap_ms={cap_ms}"])
    s, steps = res.summary, record.controller_steps(res.steps)
    ms = steps["solve_time_s"].to_numpy(float) * 1e3
    later = steps.iloc[1:]  # the first call also builds the solver's memory
    over = later["solve_time_s"].to_numpy(float) * 1e3 - cap_ms
    stopped = steps["solver_status"].astype(str).str.contains("WallTime|time_cap")
    return {
        "experiment": name, "controller": label, "cap_ms": cap_ms, "status": s["status"],
        "steps": s["n_steps"], "stopped_by_cap": int(stopped.sum()),
        "truncated": s["solves_truncated"], "converged": s["solves_converged"],
        "failed": s["n_steps"] - s["solves_converged"] - s["solves_truncated"],
        "call_median_ms": float(np.median(ms)), "call_max_ms": float(ms.max()),
        "overrun_median_ms": float(np.median(over)) if len(over) else None,
        "overrun_p95_ms": float(np.percentile(over, 95)) if len(over) else None,
        "overrun_max_ms": float(over.max()) if len(over) else None,
        "first_call_ms": float(ms[0]),
        # CPU over wall time of the calls: below 1 when the process waited for a core
        "cpu_share": float(steps["solve_cpu_s"].astype(float).sum() / (ms.sum() / 1e3)),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--md", type=Path, default=None, help="write the stamped tables here")
    args = ap.parse_args()
    side = pd.DataFrame([side_by_side(n, b) for n, b in EXPERIMENTS.items()])
    loops = pd.DataFrame([closed_loop(n, b, lab, o) for n, b in EXPERIMENTS.items()
                          for lab, o in (("casadi_rti", RTI), ("sqp_capped 1 it.", SQP1))])
    caps = pd.DataFrame([capped(*c) for c in CAPS])
    fmt = {"floatfmt": ".3g", "index": False}
    write_stamped(args.md, [side.to_markdown(**fmt), loops.to_markdown(**fmt),
                            caps.to_markdown(**fmt)], sys.argv)


if __name__ == "__main__":
    main()
