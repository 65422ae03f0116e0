"""Study C on the F401RE by a cycle model: every step of a whole run, double and single.

    uv run python experiments/embedded/cycles_bench.py               # horizon 32, M = 1 and 4
    uv run python experiments/embedded/cycles_bench.py --configs 32x1

Per configuration (horizon H, control horizon M; 8 operating points, switched) and precision:

1. the closed loop of ``+experiment=bicycle_scheduled scenario=turn`` with the generated C in
   the loop (``controller.codegen=true``, ``controller.codegen_precision=double|single``):
   arrival, tracking RMS, every step's inputs; the single run's inputs against the double
   run's, step by step;
2. every controller call of the double run (its states and previewed references) run again
   on the emulated Cortex-M4F (QEMU), in chunks, and every executed instruction weighed by
   the cycle model (``mpclab/codegen/cycles.py``: low, central, high timings): instructions,
   cycles and CPI per step, their median, p95 and maximum;
3. the controller's step model (``mpclab/codegen/step_model.py``: base + per-iteration x
   active-set iterations, from 24 calibration states; what ``sim=embedded_m4`` applies)
   beside the traced steps: its largest value over the run, how far the traced steps came
   to it, and its value at the active-set cap (200 iterations).

Writes ``results_cycles.md`` (stamped tables) and ``results_cycles.csv`` beside this file.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd

from mpclab.codegen import cycles, pil
from mpclab.codegen.step_model import ITERATION_CAP
from mpclab.record import files as record
from mpclab.record.provenance import write_stamped
from mpclab.runner.loop import simulate
from mpclab.runner.single_run import build_run
from mpclab.runner.single_run import compose as compose_cfg

HERE = Path(__file__).resolve().parent
QUIET = ("recorder=none", "progress=false", "figures.enabled=false")
CHUNK = 100  # recorded states per firmware (the exec log of a chunk stays below 1.5 GB)
MHZ = pil.F401RE_CLOCK_HZ / 1e6


def closed_loop(H: int, M: int, precision: str):
    cfg = compose_cfg(["+experiment=bicycle_scheduled", "scenario=turn",
                       f"controller.horizon={H}", f"controller.control_horizon={M}",
                       "controller.codegen=true", f"controller.codegen_precision={precision}",
                       *QUIET])
    run = build_run(cfg)
    result = simulate(run)
    return run, result, result.summary | run.scenario.metrics(result.steps, result.summary)


def traced(library, x: np.ndarray, ref: np.ndarray, precision: pil.Precision) -> pd.DataFrame:
    """Every recorded state on the emulated board: iterations, instructions, cycles."""
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for start in range(0, len(x), CHUNK):
            part = slice(start, start + CHUNK)
            elf, _ = pil.cross_build(pil.harness_source(library.source, x[part], ref[part]),
                                     precision, Path(tmp) / f"{precision}_{start}")
            for s in pil.run(elf, True, timeout_s=3600, timings=cycles.BOUNDS):
                rows.append({"iterations": s.iterations, "code": s.code,
                             "instructions": s.instructions, **s.cycles})
            print(f"  {precision}: {min(start + CHUNK, len(x))}/{len(x)} states", flush=True)
    return pd.DataFrame(rows)


def bench(H: int, M: int) -> tuple[list[dict], dict]:
    loops = {p: closed_loop(H, M, p) for p in pil.Precision}
    run_d, res_d, sum_d = loops[pil.Precision.double]
    calls_d = record.controller_steps(res_d.steps)
    inputs = list(run_d.plant.inputs)
    calls_s = record.controller_steps(loops[pil.Precision.single][1].steps)
    n = min(len(calls_d), len(calls_s))
    du = np.abs(calls_s[inputs].to_numpy()[:n] - calls_d[inputs].to_numpy()[:n]).max(axis=0)
    loop_row = {"H": H, "M": M, "steps_double": len(calls_d), "steps_single": len(calls_s),
                **{f"max_du_{lab}": float(v) for lab, v in zip(inputs, du, strict=True)}}
    for p, (_, _, s) in loops.items():
        loop_row |= {f"{p}_arrival_s": s["arrival_time_s"], f"{p}_rms_position": s["rms_position"],
                     f"{p}_converged": s["converged_fraction"]}
    ctrl = run_d.controller
    target = lambda t: run_d.scenario.target(t, H, ctrl.dt)  # noqa: E731
    x, ref = pil.recorded_states(res_d.steps, run_d.plant.states, target, len(calls_d))
    rows = []
    for p, (run, _, _) in loops.items():
        model = run.controller._sil.step_model()
        tr = traced(run.controller._sil.library, x, ref, p)
        modelled = model.base + model.per_iteration * tr["iterations"].to_numpy()
        c = tr["central"].to_numpy()
        rows.append({
            "H": H, "M": M, "precision": str(p), "steps": len(tr),
            "converged": bool((tr["code"] == 0).all()),
            "iterations_max": int(tr["iterations"].max()),
            "insn_median": float(tr["instructions"].median()),
            "insn_max": int(tr["instructions"].max()),
            **{f"{b}_median": float(tr[b].median()) for b in cycles.BOUNDS},
            **{f"{b}_p95": float(np.percentile(tr[b], 95)) for b in cycles.BOUNDS},
            **{f"{b}_max": float(tr[b].max()) for b in cycles.BOUNDS},
            **{f"cpi_{b}": float(tr[b].sum() / tr["instructions"].sum())
               for b in cycles.BOUNDS},
            "model_base": model.base, "model_per_iteration": model.per_iteration,
            "model_iterations_traced": f"{model.iterations_traced[0]}-{model.iterations_traced[1]}",
            "model_max": float(modelled.max()),
            "traced_over_model_max": float((c / modelled).max()),
            "model_at_cap": model.cycles(ITERATION_CAP),
        })
    return rows, loop_row


def tables(df: pd.DataFrame, loops: pd.DataFrame) -> list[str]:
    lines = ["| H | M | precision | steps | instructions (median / max) | cycles low / central "
             "/ high (max) | CPI low / central / high | central ms @84 MHz (median / p95 / "
             "max) | high ms (max) |", "|---|---|---|---|---|---|---|---|---|"]
    for _, r in df.iterrows():
        lines.append(
            f"| {r.H} | {r.M} | {r.precision} | {r.steps} | {r.insn_median:.0f} / {r.insn_max} "
            f"| {r.low_max:.0f} / {r.central_max:.0f} / {r.high_max:.0f} | "
            f"{r.cpi_low:.2f} / {r.cpi_central:.2f} / {r.cpi_high:.2f} | "
            f"{r.central_median / MHZ / 1e3:.3f} / {r.central_p95 / MHZ / 1e3:.3f} / "
            f"{r.central_max / MHZ / 1e3:.3f} | {r.high_max / MHZ / 1e3:.3f} |")
    model = ["| H | M | precision | active-set iterations (run max; calibration) | model: base + "
             "per iteration [cycles] | model max over the run [ms] | traced / model (max) | "
             f"model at the cap ({ITERATION_CAP} iterations) [ms] |",
             "|---|---|---|---|---|---|---|---|"]
    for _, r in df.iterrows():
        model.append(
            f"| {r.H} | {r.M} | {r.precision} | {r.iterations_max}; {r.model_iterations_traced} "
            f"| {r.model_base:.0f} + {r.model_per_iteration:.0f} | "
            f"{r.model_max / MHZ / 1e3:.3f} | {r.traced_over_model_max:.3f} | "
            f"{r.model_at_cap / MHZ / 1e3:.2f} |")
    loop = ["| H | M | steps double / single | max input difference (steer rad, accel m/s²) "
            "| arrival double / single [s] | RMS position double / single [m] | converged "
            "double / single |", "|---|---|---|---|---|---|---|"]
    for _, r in loops.iterrows():
        du = [c for c in loops.columns if c.startswith("max_du_")]
        loop.append(
            f"| {r.H:.0f} | {r.M:.0f} | {r.steps_double:.0f} / {r.steps_single:.0f} | "
            f"{', '.join(f'{r[c]:.1e}' for c in du)} | {r.double_arrival_s} / "
            f"{r.single_arrival_s} | {r.double_rms_position:.5f} / {r.single_rms_position:.5f} | "
            f"{r.double_converged:.0%} / {r.single_converged:.0%} |")
    return ["\n".join(lines), "\n".join(model), "\n".join(loop)]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--configs", nargs="*", default=["32x1", "32x4"], help="HxM")
    args = ap.parse_args()
    missing = pil.missing_tools()
    if missing:
        raise SystemExit(f"PIL needs {', '.join(missing)} (see .ci/run)")
    rows, loops = [], []
    for cfg in args.configs:
        H, M = (int(v) for v in cfg.split("x"))
        r, loop = bench(H, M)
        rows += r
        loops.append(loop)
        print(r, loop, flush=True)
    df, lp = pd.DataFrame(rows), pd.DataFrame(loops)
    df.to_csv(HERE / "results_cycles.csv", index=False)
    lp.to_csv(HERE / "results_cycles_loop.csv", index=False)
    write_stamped(HERE / "results_cycles.md", tables(df, lp), sys.argv)


if __name__ == "__main__":
    main()
