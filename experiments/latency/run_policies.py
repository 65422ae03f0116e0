"""Deadline policies, the one-sample delay and delay compensation, side by side.

Study C's 20 ms against 50 ms question (the scheduled controller on the turn, the study's
33.8 ms per step: ``sim=embedded_stm32``) under ``hold``, ``plan`` and ``late_apply``, the
one-sample delay and ``sim.timing.delay_compensation``; the car and BUG2 with fixed
latencies with and without compensation; and whether ``sim=realistic`` repeats exactly.

    uv run python experiments/latency/run_policies.py

Prints the table and the repeat check, each under its stamp (command, commit, CPU, date), and
writes them to ``policies.md`` beside this file.
"""

from __future__ import annotations

import sys
from pathlib import Path

import pandas as pd
from run_latency import run

from mpclab.core.native_output import c_stdout_silenced
from mpclab.record.files import TIMING_COLUMNS
from mpclab.record.provenance import write_stamped
from mpclab.runner.loop import simulate
from mpclab.runner.single_run import build_run, compose

TURN = ["+experiment=bicycle_scheduled", "scenario=turn"]
STM32 = "sim=embedded_stm32"
COMP = "sim.timing.delay_compensation=true"
#: study -> [(label, overrides)]
CASES = {
    "Study C, 20 ms": [
        ("ideal", [*TURN, "controller.dt=0.02"]),
        ("33.8 ms, hold", [*TURN, "controller.dt=0.02", STM32]),
        ("33.8 ms, plan", [*TURN, "controller.dt=0.02", STM32, "sim.timing.deadline_policy=plan"]),
        ("33.8 ms, late_apply", [*TURN, "controller.dt=0.02", STM32,
                                 "sim.timing.deadline_policy=late_apply"]),
        ("33.8 ms, late_apply, compensated", [*TURN, "controller.dt=0.02", STM32,
                                              "sim.timing.deadline_policy=late_apply", COMP]),
    ],
    "Study C, 50 ms": [
        ("ideal", [*TURN, "controller.dt=0.05"]),
        ("33.8 ms, hold", [*TURN, "controller.dt=0.05", STM32]),
        ("33.8 ms, compensated", [*TURN, "controller.dt=0.05", STM32, COMP]),
        ("one-sample delay (50 ms)", [*TURN, "controller.dt=0.05", "sim.latency=one_sample"]),
    ],
    "car (casadi SQP)": [
        ("ideal", ["+experiment=car_casadi"]),
        ("60 ms", ["+experiment=car_casadi", "sim.latency=60"]),
        ("60 ms, compensated", ["+experiment=car_casadi", "sim.latency=60", COMP]),
        ("90 ms", ["+experiment=car_casadi", "sim.latency=90"]),
        ("90 ms, compensated", ["+experiment=car_casadi", "sim.latency=90", COMP]),
        ("one-sample delay (100 ms)", ["+experiment=car_casadi", "sim.latency=one_sample"]),
    ],
    "car (cvxpy SL)": [
        ("ideal", ["+experiment=car_cvxpy"]),
        ("90 ms", ["+experiment=car_cvxpy", "sim.latency=90"]),
        ("90 ms, compensated", ["+experiment=car_cvxpy", "sim.latency=90", COMP]),
    ],
    "BUG2 (fatrop)": [
        ("ideal", ["+experiment=zumo_bug2"]),
        ("150 ms", ["+experiment=zumo_bug2", "sim.latency=150"]),
        ("150 ms, compensated", ["+experiment=zumo_bug2", "sim.latency=150", COMP]),
        ("200 ms", ["+experiment=zumo_bug2", "sim.latency=200"]),
        ("one-sample delay (200 ms)", ["+experiment=zumo_bug2", "sim.latency=one_sample"]),
    ],
}
#: run twice with the same seed: the step logs must be equal
REPEAT = ["+experiment=zumo_bug2", "scenario=zumo_random", "seed=94", "sim=realistic"]


def step_log(overrides: list[str]) -> pd.DataFrame:
    cfg = compose(["recorder=none", "progress=false", "figures.enabled=false", *overrides])
    built = build_run(cfg)
    with c_stdout_silenced():
        steps = simulate(built).steps
    return steps.drop(columns=[c for c in TIMING_COLUMNS if c in steps])  # times differ


def main() -> None:
    rows = []
    for study, cases in CASES.items():
        for label, overrides in cases:
            r = run(overrides)
            rms, arrival = r["rms_position"], r["arrival_time_s"]
            rows.append({"study": study, "loop": label, "status": r["status"],
                         "arrival [s]": "" if arrival is None else f"{arrival:g}",
                         "misses / steps": f"{r['deadline_misses']} / {r['n_steps']}",
                         "position RMS [m]": "" if rms is None else f"{rms:.3f}"})
            print(rows[-1], flush=True)
    a, b = step_log(REPEAT), step_log(REPEAT)
    repeat = (f"`{' '.join(REPEAT)}` twice: {len(a) - 1} steps each, step logs equal: "
              f"{a.equals(b)} (latency median {1e3 * a['latency_s'].median():.2f} ms)")
    print()
    write_stamped(Path(__file__).resolve().parent / "policies.md",
                  [pd.DataFrame(rows).to_markdown(index=False), repeat], sys.argv)


if __name__ == "__main__":
    main()
