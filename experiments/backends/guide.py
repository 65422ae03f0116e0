"""Which backend for which plant: every backend that can drive each plant, measured in one run.

    uv run python experiments/backends/guide.py --md docs/backends_table.md

For each plant and each backend (a ``controller=`` choice, or one of its modes) the closed
loops of the plant's task run one after another in this process, each backend built (and
compiled) before its timed runs. Per backend, over the controller calls of all its runs:
the fraction whose status is ``converged``, the median and p95 of the wall time of
``controller.step`` and the median of its CPU time (``solve_cpu_s``: on a machine shared with
other work the wall time includes waits for a core, the CPU time does not), and how many runs
arrived and how many touched an obstacle. The cost gap to the tight IPOPT reference comes
from experiments/agreement (its ``compare`` for the car, the bicycle and the unicycle,
cold-started at a few states of one closed loop; ``zumo_nlp.compare`` for the Zumo's NLP as
BUG2 poses it). Generated-C and Cortex-M4 figures are not measured here: they are read from
the stamped results of experiments/embedded and experiments/zumo_nn, and the table names the
file.
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "experiments" / "agreement"))
import agreement  # noqa: E402
import zumo_nlp  # noqa: E402

from mpclab.core.native_output import c_stdout_silenced  # noqa: E402
from mpclab.record import files as record  # noqa: E402
from mpclab.record.provenance import write_stamped  # noqa: E402
from mpclab.runner.loop import CPU_COLUMN, simulate  # noqa: E402
from mpclab.runner.single_run import build_run, compose  # noqa: E402

QUIET = ["recorder=none", "progress=false", "figures.enabled=false", "sim=nominal"]
BIKE = ["plant=dynamic_bicycle", "objective=bicycle_tracking", "controller.horizon=32",
        "controller.dt=0.02"]
ZUMO_SEEDS = (0, 1, 2, 3)
NN_SEEDS = (0, 1, 2, 3, 4)


@dataclass
class PlantCase:
    """One plant, its task (closed loops) and the backends that can drive it."""

    plant: str
    task: str
    #: closed loops of the task: overrides appended to every backend's
    runs: list[list[str]]
    #: backend label -> overrides (the label is the ``controller=`` choice, or its mode)
    backends: dict[str, list[str]]
    #: backends with a task of their own: label -> (task, closed loops)
    own_runs: dict[str, tuple[str, list[list[str]]]] = field(default_factory=dict)
    #: agreement states: scenario -> steps of the sampling closed loop (None: the Zumo's NLP)
    samples: dict[str, list[int]] | None = None
    sampler: list[str] = field(default_factory=list)


CASES = [
    PlantCase(
        plant="kinematic_car", task="car_to_origin (Study A), 1 run",
        runs=[[]],
        backends={
            "cvxpy": ["+experiment=car_cvxpy"],
            "cvxpy (sl=one_pass)": ["+experiment=car_cvxpy", "controller.sl=one_pass"],
            "casadi": ["+experiment=car_casadi", "controller=casadi"],
            "casadi_sqp": ["+experiment=car_casadi"],
            "casadi_fatrop": ["+experiment=car_casadi", "controller=casadi_fatrop"],
            "casadi_rti": ["+experiment=car_casadi", "controller=casadi_rti"],
        },
        samples={"car_to_origin": [0, 6, 15]}, sampler=["+experiment=car_casadi"],
    ),
    PlantCase(
        plant="zumo", task="zumo_bug2 on zumo_dead_end and zumo_random_easy seeds "
                           + ", ".join(map(str, ZUMO_SEEDS)),
        runs=[["scenario=zumo_dead_end"]] + [["scenario=zumo_random_easy", f"seed={s}"]
                                             for s in ZUMO_SEEDS],
        backends={
            "casadi_fatrop": ["+experiment=zumo_bug2"],
            "casadi": ["+experiment=zumo_bug2", "controller=casadi"],
            "casadi_sqp_capped (3 SQP steps)": [
                "+experiment=zumo_bug2", "controller=casadi_sqp_capped",
                "controller.solve.sqp_iterations=3"],
            "casadi_rti": ["+experiment=zumo_bug2", "controller=casadi_rti"],
            "casadi_sqp": ["+experiment=zumo_bug2", "controller=casadi_sqp"],
            "nn": ["+experiment=zumo_nn"],
        },
        own_runs={"nn": ("zumo_nn: one obstacle, random starts (seeds "
                         + ", ".join(map(str, NN_SEEDS)) + ")",
                         [[f"seed={s}"] for s in NN_SEEDS])},
    ),
    PlantCase(
        plant="dynamic_bicycle", task="turn at 20 ms, horizon 32 (Study C), 1 run",
        runs=[["scenario=turn"]],
        backends={
            "scheduled (switched)": ["+experiment=bicycle_scheduled"],
            "scheduled (interpolated)": ["+experiment=bicycle_interpolated"],
            "scheduled (adaptive)": ["+experiment=bicycle_adaptive"],
            "cvxpy": ["controller=cvxpy", *BIKE],
            "casadi": ["controller=casadi", *BIKE],
            "casadi_sqp": ["controller=casadi_sqp", *BIKE],
            "casadi_fatrop": ["controller=casadi_fatrop", *BIKE],
        },
        samples={"turn": [120, 250, 400]},
        sampler=["+experiment=bicycle_scheduled", "scenario={scenario}"],
    ),
    PlantCase(
        plant="unicycle", task="unicycle_goal (the extension guide's), 1 run",
        runs=[[]],
        backends={c: ["+experiment=unicycle_goal", f"controller={c}"]
                  for c in ("casadi", "casadi_sqp", "casadi_fatrop", "casadi_uno")},
        samples={"unicycle_goal": [0, 10, 30]}, sampler=["+experiment=unicycle_goal"],
    ),
]

#: zumo_nlp's backend labels -> this guide's
ZUMO_LABELS = {"fatrop": "casadi_fatrop", "ipopt": "casadi",
               "sqp_capped3": "casadi_sqp_capped (3 SQP steps)", "nn": "nn"}


def closed_loops(case: PlantCase, label: str) -> dict[str, Any]:
    """Run the backend's closed loops; pool its controller calls."""
    task, runs = case.own_runs.get(label, (case.task, case.runs))
    base = case.backends[label]
    calls, summaries, problem = [], [], None
    for extra in runs:
        run = build_run(compose([*base, *extra, *QUIET]))
        problem = getattr(run.controller.solved_problem, "value", None)
        with c_stdout_silenced():  # qpOASES' messages
            res = simulate(run)
        calls.append(record.controller_steps(res.steps))
        summaries.append(res.summary)
        print(f"  {case.plant} {label} {' '.join(extra)}: {res.summary['status']}, "
              f"{res.summary['n_steps']} steps", file=sys.stderr, flush=True)
    steps = pd.concat(calls)
    ms = steps["solve_time_s"].to_numpy() * 1e3
    arrived = [s["arrival_time_s"] for s in summaries if s["arrived"]]
    return {
        "plant": case.plant, "backend": label, "task": task, "problem": problem,
        "runs": len(runs), "arrived": len(arrived),
        "collisions": sum(s["status"] == "collision" for s in summaries),
        "arrival_median_s": float(np.median(arrived)) if arrived else None,
        "steps": len(steps),
        "converged": float((steps["status"] == "converged").mean()),
        "median_ms": float(np.median(ms)), "p95_ms": float(np.percentile(ms, 95)),
        "cpu_median_ms": float(np.nanmedian(pd.to_numeric(steps[CPU_COLUMN])) * 1e3),
        "statuses": ", ".join(f"{k} {v}" for k, v in steps["status"].value_counts().items()),
    }


def gaps(case: PlantCase) -> pd.DataFrame:
    """Per backend: states, median and largest cost gap to the tight IPOPT reference."""
    if case.samples is None:  # the Zumo: the NLP BUG2 poses, per mode
        df = zumo_nlp.compare(per_mode=2, perturbed=0, n_random=1)
        df["backend"] = df["backend"].map(ZUMO_LABELS).fillna(df["backend"])
    else:
        acase = agreement.Case(
            name=case.plant, samples=case.samples, sampler=case.sampler,
            backends={b: [*o, "scenario={scenario}"] for b, o in case.backends.items()},
            dt=0.02 if case.plant == "dynamic_bicycle" else 0.1)
        df = agreement.compare(acase)
    df = df[~df["backend"].str.startswith("reference")]
    g = df.groupby("backend", sort=False)["gap"]
    return pd.DataFrame({"gap_states": g.size(), "gap_median": g.median(), "gap_max": g.max()})


def generated_c() -> dict[tuple[str, str], str]:
    """(plant, backend) -> the generated-C and Cortex-M4 figures of the other experiments."""
    out: dict[tuple[str, str], str] = {}
    emb = ROOT / "experiments" / "embedded"
    sched = pd.read_csv(emb / "results.csv")
    r = sched[(sched.H == 32) & (sched.M == 1)].iloc[0]
    out[("dynamic_bicycle", "scheduled (switched)")] = (
        f"Cortex-M4 at 84 MHz {r['single_ms_central']:.3f} ms single / "
        f"{r['double_ms_central']:.2f} ms double (cycle model, central), "
        f"{r.single_flash_B / 1024:.1f} KB flash "
        f"([embedded](../experiments/embedded/README.md))")
    cas = emb / "results_casadi.csv"
    if cas.exists():
        c = pd.read_csv(cas).set_index("key")
        for (plant, backend), key in {("kinematic_car", "casadi_sqp"): "car_codegen_O1",
                                      ("zumo", "casadi_fatrop"): "zumo_codegen"}.items():
            if key in c.index:
                out[(plant, backend)] = (
                    f"whole solver as C: {c.loc[key, 'median_ms']:.2f} ms median, desktop "
                    f"([embedded](../experiments/embedded/README.md)); no M4 build")
    ev = ROOT / "experiments" / "zumo_nn" / "evaluation.json"
    if ev.exists():
        comp = json.loads(ev.read_text()).get("compiled")
        if comp:
            out[("zumo", "nn")] = (
                f"exported C net: {comp['step_median_us']:.2f} µs median, desktop "
                f"([zumo_nn](../experiments/zumo_nn/README.md))")
    return out


def markdown(df: pd.DataFrame) -> str:
    head = ("| plant | backend | solves | task | runs arrived | collided | arrival median s "
            "| converged "
            "| median ms | p95 ms | CPU median ms | gap median | gap max (states) | "
            "generated C, Cortex-M4 |")
    lines = [head, "|" + "---|" * head.count(" | ") + "---|"]

    def f(v: Any, fmt: str) -> str:
        return "-" if v is None or (isinstance(v, float) and np.isnan(v)) else format(v, fmt)

    for _, r in df.iterrows():
        gap_max = f(r.gap_max, ".2g") + (f" ({int(r.gap_states)})"
                                         if not pd.isna(r.gap_states) else "")
        lines.append(
            f"| {r.plant} | {r.backend} | {r.problem} | {r.task} | {r.arrived} of {r.runs} | "
            f"{r.collisions} | {f(r.arrival_median_s, '.1f')} | {r.converged:.2f} | "
            f"{r.median_ms:.3g} | {r.p95_ms:.3g} | {r.cpu_median_ms:.3g} | "
            f"{f(r.gap_median, '.2g')} | {gap_max} | "
            f"{'-' if pd.isna(r.generated_c) else r.generated_c} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    argv = list(sys.argv if argv is None else argv)
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--plant", action="append", choices=[c.plant for c in CASES],
                    help="only these plants (default: all)")
    ap.add_argument("--no-gap", action="store_true", help="skip the agreement references")
    ap.add_argument("--md", type=Path, help="also write the stamped table here")
    ap.add_argument("--csv", type=Path, help="write the rows here")
    args = ap.parse_args(argv[1:])
    rows = []
    code = generated_c()
    for case in CASES:
        if args.plant and case.plant not in args.plant:
            continue
        print(f"{case.plant}:", file=sys.stderr, flush=True)
        part = pd.DataFrame([closed_loops(case, b) for b in case.backends])
        g = pd.DataFrame(columns=["gap_states", "gap_median", "gap_max"]) if args.no_gap \
            else gaps(case)
        part = part.join(g, on="backend")
        part["generated_c"] = [code.get((case.plant, b)) for b in part["backend"]]
        rows.append(part)
    df = pd.concat(rows, ignore_index=True)
    if args.csv:
        df.to_csv(args.csv, index=False)
    write_stamped(args.md, markdown(df), argv)


if __name__ == "__main__":
    main()
