"""Arrival time against compute time, causally: each input acts after its own solve time.

Every backend of Study A (the car) and of Study B (BUG2 on the dead end) runs with
``sim.latency=measured`` and the solve time scaled by 1, 10 and 100 (a target 10x or 100x
slower than the machine that runs it), beside its ideal loop (``sim=nominal``, scale 0 in the
table). Study C's scheduled controller runs at 20 ms and at 50 ms with the study's own measured
microcontroller time (``sim=embedded_stm32``: 33.8 ms at horizon 32), and at 20 ms from our
generated C with each call's modelled Cortex-M4 time (``sim=embedded_m4``: 0.433 ms a step at
horizon 32 in double precision). For the real-time iteration (``controller=casadi_rti``) the latency
is its feedback time, the preparation runs after the input is sent. One process, runs one after
another, so each solve time is measured on an otherwise idle core.

    uv run python experiments/latency/run_latency.py            # results.csv/.md, figure
    uv run python experiments/latency/run_latency.py --only car  # one study

Writes ``results.csv``, ``results.md`` (every column, then the page's views of Studies A and B
and of Study C, each under its stamp: command, commit, CPU, date) and
``figures/arrival_vs_latency.png`` here.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import pandas as pd  # noqa: E402

from mpclab.core.native_output import c_stdout_silenced  # noqa: E402
from mpclab.record.provenance import write_stamped  # noqa: E402
from mpclab.runner.loop import simulate  # noqa: E402
from mpclab.runner.single_run import build_run, compose  # noqa: E402

HERE = Path(__file__).resolve().parent
SCALES = (1, 10, 100)
#: study -> backend label -> overrides
BACKENDS = {
    "car": {
        "cvxpy SL converged": ["+experiment=car_cvxpy"],
        "cvxpy SL one pass (truncated)": ["+experiment=car_cvxpy", "controller.sl=one_pass"],
        "casadi SQP+qrqp": ["+experiment=car_casadi"],
        "casadi IPOPT": ["+experiment=car_casadi", "controller=casadi"],
    },
    "bug2": {
        "fatrop (jit)": ["+experiment=zumo_bug2"],
        "IPOPT": ["+experiment=zumo_bug2", "controller=casadi"],
        "SQP capped at 3 it. (truncated)": ["+experiment=zumo_bug2",
                                            "controller=casadi_sqp_capped",
                                            "controller.solve.sqp_iterations=3"],
        "SQP-RTI, one QP (truncated)": ["+experiment=zumo_bug2", "controller=casadi_rti"],
    },
}
#: Study C: label -> overrides (scheduled controller, horizon 32, the turn)
BICYCLE = {
    "20 ms, ideal": ["controller.dt=0.02"],
    "20 ms, embedded_stm32": ["controller.dt=0.02", "sim=embedded_stm32"],
    "20 ms, embedded_m4 (our C)": ["controller.dt=0.02", "sim=embedded_m4",
                                   "controller.codegen=true"],
    "50 ms, ideal": ["controller.dt=0.05"],
    "50 ms, embedded_stm32": ["controller.dt=0.05", "sim=embedded_stm32"],
}
KEYS = ("status", "arrival_time_s", "compute_median_ms", "compute_p95_ms", "latency_median_ms",
        "deadline_misses", "n_steps", "converged_fraction")


def run(overrides: list[str]) -> dict:
    cfg = compose(["recorder=none", "progress=false", "figures.enabled=false", *overrides])
    built = build_run(cfg)
    with c_stdout_silenced():
        result = simulate(built)
    summary = result.summary | built.scenario.metrics(result.steps, result.summary)
    return {k: summary.get(k) for k in (*KEYS, "rms_position", "error")}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", choices=["car", "bug2", "bicycle"], nargs="*")
    ap.add_argument("--plot", action="store_true", help="only redraw the figure from results.csv")
    a = ap.parse_args()
    if a.plot:
        plot(pd.read_csv(HERE / "results.csv"))
        return
    studies = a.only or ["car", "bug2", "bicycle"]
    rows = []
    for study in (s for s in studies if s in BACKENDS):
        for backend, base in BACKENDS[study].items():
            run(base)  # builds (and compiles) once, untimed
            for scale in (0, *SCALES):
                sim = (["sim.latency=measured", f"sim.timing.latency_scale={scale}"]
                       if scale else [])
                row = {"study": study, "backend": backend, "latency_scale": scale,
                       **run([*base, *sim])}
                rows.append(row)
                print(f"{study:7s} {backend:30s} x{scale:<4d} {row['status']:8s} "
                      f"arrival {row['arrival_time_s']}  misses {row['deadline_misses']}",
                      flush=True)
    if "bicycle" in studies:
        for label, extra in BICYCLE.items():
            row = {"study": "bicycle", "backend": f"scheduled H=32 {label}", "latency_scale": 0,
                   **run(["+experiment=bicycle_scheduled", "scenario=turn", *extra])}
            rows.append(row)
            print(f"bicycle {label:30s} {row['status']:8s} rms {row['rms_position']} m "
                  f"misses {row['deadline_misses']}", flush=True)
    df = pd.DataFrame(rows)
    df.to_csv(HERE / "results.csv", index=False)
    write_stamped(HERE / "results.md", [df.to_markdown(index=False, floatfmt=".3g"),
                                        *views(df)], sys.argv)
    plot(df)


def views(df: pd.DataFrame) -> list[str]:
    """The page's two tables: Studies A and B by latency scale; Study C's runs."""
    shown = df.assign(misses=[f"{m} / {n}" for m, n in zip(df["deadline_misses"], df["n_steps"],
                                                          strict=True)])
    ab = shown[shown["study"] != "bicycle"].rename(columns={
        "latency_scale": "scale", "arrival_time_s": "arrival [s]",
        "latency_median_ms": "latency median [ms]", "misses": "misses / steps",
        "converged_fraction": "converged"})
    c = shown[shown["study"] == "bicycle"].rename(columns={
        "backend": "run", "misses": "misses / steps", "rms_position": "position RMS error [m]"})
    ab_cols = ["study", "backend", "scale", "status", "arrival [s]", "latency median [ms]",
               "misses / steps", "converged"]
    c_cols = ["run", "status", "misses / steps", "position RMS error [m]"]
    return [table[cols].astype(object).where(table[cols].notna(), None)
            .to_markdown(index=False, floatfmt=".3g", missingval="")
            for table, cols in ((ab, ab_cols), (c, c_cols)) if len(table)]


def plot(df: pd.DataFrame) -> None:
    """Arrival time against the latency each run saw (its median), one line per backend from
    scale 1 to 100; a cross above the axes where the run did not arrive."""
    studies = [s for s in ("car", "bug2") if s in set(df["study"])]
    if not studies:
        return
    fig, axes = plt.subplots(1, len(studies), figsize=(5.5 * len(studies), 4.2), squeeze=False)
    for ax, study in zip(axes[0], studies, strict=True):
        part = df[df["study"] == study]
        top = part["arrival_time_s"].max() * 1.12
        for i, (backend, g) in enumerate(part.groupby("backend", sort=False)):
            g = g[g["latency_scale"] > 0]
            ok = (g["status"] == "arrived").to_numpy()
            x = g["latency_median_ms"].to_numpy(dtype=float)
            (line,) = ax.plot(x[ok], g["arrival_time_s"].to_numpy()[ok], "o-", label=backend)
            ax.plot(x[~ok], [top * (1 + 0.02 * i)] * int((~ok).sum()), "x",
                    color=line.get_color(), markersize=9)
            nominal = part[(part["backend"] == backend) & (part["latency_scale"] == 0)]
            if len(nominal) and nominal["status"].iloc[0] == "arrived":
                ax.axhline(nominal["arrival_time_s"].iloc[0], color=line.get_color(), lw=0.6,
                           ls=":")
        period = {"car": 100.0, "bug2": 200.0}[study]
        ax.axvline(period, color="0.5", lw=0.8, ls="--")
        ax.text(period, ax.get_ylim()[0], " control period", color="0.4", fontsize=7,
                va="bottom")
        ax.set_xscale("log")
        ax.set_xlabel("latency [ms], run median: solve time x 1, 10, 100\n"
                      "(the RTI: its feedback time)")
        ax.set_ylabel("arrival time [s] (x at the top: did not arrive)")
        ax.set_title({"car": "Study A: car to the origin", "bug2": "Study B: BUG2, dead end"}
                     [study] + " (dotted: ideal loop)", fontsize=10)
        ax.legend(fontsize=7)
    fig.tight_layout()
    (HERE / "figures").mkdir(exist_ok=True)
    fig.savefig(HERE / "figures" / "arrival_vs_latency.png", dpi=110)


if __name__ == "__main__":
    main()
