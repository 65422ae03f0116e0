"""Study C embedded benchmark: the scheduled MPC in Python, as generated C on the desktop, and
on an emulated Cortex-M4F (modelled cycles -> time at 84 MHz), side by side in one run.

    uv run python experiments/embedded/bench.py               # all configurations
    uv run python experiments/embedded/bench.py --quick       # horizon 32, control horizon 1

Per configuration (horizon H, control horizon M; 8 operating points; switched, no hysteresis):
a closed loop of ``regular_circle_turn`` (every heading) is run once with the Python
controller; its controller calls are the recorded states. Then, interleaved state by state,
``step()`` of the Python controller and of the same controller with ``codegen=true`` (the C
through ctypes, inside the same Python step: ControlStep, prediction, cost); the generated C
alone in a C loop (``clock_gettime``, the controller's step without the prediction); and the
PIL check in double and single precision (footprint, agreement with the desktop C,
instructions and modelled cycles per step: mpclab/codegen/cycles.py, low/central/high).
Writes ``results.md`` (the table with its stamp: command, commit, CPU, date) and
``results.csv`` beside this file.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

from mpclab.codegen import cycles, pil
from mpclab.codegen.build import find_compiler
from mpclab.codegen.loader import DEFAULT_FLAGS
from mpclab.controllers.base import StepContext
from mpclab.record.provenance import write_stamped
from mpclab.runner.loop import simulate
from mpclab.runner.single_run import build_run
from mpclab.runner.single_run import compose as compose_cfg

HERE = Path(__file__).resolve().parent
CONFIGS = ((32, 1), (16, 1), (32, 4), (16, 4))
QUIET = ("recorder=none", "progress=false", "figures.enabled=false")
#: the study's board figures (Nucleo F401RE, MATLAB Embedded Coder): ms per step
STUDY_MS = {32: 33.8, 16: 14.5}

C_LOOP = """
#include <stdio.h>
#include <time.h>
int main(void)
{
    static mpc_real z[MPC_NZ];
    volatile mpc_real sink = 0;
    struct timespec a, b;
    int r, n, op, it, best = -1;
    double ns, best_ns = 1e300;
    for (r = 0; r < 7; ++r) {
        clock_gettime(CLOCK_MONOTONIC, &a);
        for (it = 0; it < REPEAT; ++it)
            for (n = 0; n < PIL_N; ++n) {
                int iters;
                mpc_step(pil_x[n], pil_ref[n], z, &op, &iters);
                sink += z[0];
            }
        clock_gettime(CLOCK_MONOTONIC, &b);
        ns = ((b.tv_sec - a.tv_sec) * 1e9 + (b.tv_nsec - a.tv_nsec)) / ((double)REPEAT * PIL_N);
        printf("%.1f\\n", ns);
        if (ns < best_ns) { best_ns = ns; best = r; }
    }
    (void)best;
    return 0;
}
"""


def controller_run(H: int, M: int, codegen: bool):
    cfg = compose_cfg(["+experiment=bicycle_scheduled", "scenario=regular_circle_turn",
                       f"controller.horizon={H}", f"controller.control_horizon={M}",
                       f"controller.codegen={str(codegen).lower()}", *QUIET])
    return build_run(cfg)


def desktop_c_ns(source: str, x: np.ndarray, ref: np.ndarray, repeat: int) -> float:
    """Median ns per step of ``mpc_step`` in a C loop over the recorded states (7 rounds)."""
    cc = find_compiler()
    with tempfile.TemporaryDirectory() as tmp:
        c, exe = Path(tmp) / "bench.c", Path(tmp) / "bench"
        c.write_text(f"#define _POSIX_C_SOURCE 199309L\n#define REPEAT {repeat}\n"
                     + pil.harness_source(source, x, ref, C_LOOP))
        subprocess.run([cc, *DEFAULT_FLAGS, str(c), "-o", str(exe), "-lm"], check=True)
        out = subprocess.run([str(exe)], check=True, capture_output=True, text=True).stdout
    return float(np.median([float(v) for v in out.split()]))


def python_vs_c_us(py, c, x: np.ndarray, ref: np.ndarray, rounds: int) -> tuple[float, float]:
    """Median µs of ``step()``: the Python controller and the codegen one, interleaved."""
    T = py.horizon
    ctxs = [StepContext(goal=r.reshape(T + 1, -1)[-1], target=r.reshape(T + 1, -1)) for r in ref]
    tp, tc = [], []
    for _ in range(rounds):
        for xi, ci in zip(x, ctxs, strict=True):
            t0 = time.perf_counter()
            py.step(0.0, xi, ci)
            t1 = time.perf_counter()
            c.step(0.0, xi, ci)
            t2 = time.perf_counter()
            tp.append(t1 - t0)
            tc.append(t2 - t1)
    return float(np.median(tp)) * 1e6, float(np.median(tc)) * 1e6


def bench(H: int, M: int, n_pil: int, rounds: int, repeat: int) -> dict:
    run = controller_run(H, M, codegen=False)
    steps = simulate(run).steps
    py = run.controller
    c = controller_run(H, M, codegen=True).controller
    target = lambda t: run.scenario.target(t, H, py.dt)  # noqa: E731
    x, ref = pil.recorded_states(steps, run.plant.states, target, 200)
    py_us, c_us = python_vs_c_us(py, c, x, ref, rounds)
    row = {"H": H, "M": M, "n_ops": len(py.grid), "python_step_us": py_us,
           "codegen_step_us": c_us, "desktop_c_us": desktop_c_ns(c._sil.library.source, x, ref,
                                                                repeat) / 1e3}
    xp, rp = pil.recorded_states(steps, run.plant.states, target, n_pil)
    with tempfile.TemporaryDirectory() as tmp:
        for prec in pil.Precision:
            chk = pil.pil_check(c._sil.library, xp, rp, prec, Path(tmp),
                                timings=cycles.BOUNDS)
            ins = np.array(chk.instructions)
            row |= {
                f"{prec}_flash_B": chk.footprint.flash, f"{prec}_ram_B": chk.footprint.ram,
                f"{prec}_fits": chk.fits_f401re, f"{prec}_ops_agree": chk.ops_agree,
                f"{prec}_max_du": chk.max_input_difference,
                f"{prec}_converged": all(s.code == 0 for s in chk.steps),
                f"{prec}_insn_median": float(np.median(ins)), f"{prec}_insn_max": int(ins.max()),
                **{f"{prec}_ms_{b}": max(s.cycles[b] for s in chk.steps)
                   / pil.F401RE_CLOCK_HZ * 1e3 for b in cycles.BOUNDS},
            }
    return row


def table(df: pd.DataFrame) -> str:
    lines = ["| H | M | Python step | codegen step (ctypes) | C loop | M4 single: insn (max) | "
             "M4 single ms low/central/high | M4 double: insn (max) | M4 double ms "
             "low/central/high | "
             "flash / RAM single | flash / RAM double | study (F401RE) |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for _, r in df.iterrows():
        s = "/".join(f"{r[f'single_ms_{b}']:.3f}" for b in cycles.BOUNDS)
        d = "/".join(f"{r[f'double_ms_{b}']:.3f}" for b in cycles.BOUNDS)
        study = f"{STUDY_MS[r.H]} ms" if r.M == 1 else "-"
        lines.append(
            f"| {r.H} | {r.M} | {r.python_step_us:.1f} µs | {r.codegen_step_us:.1f} µs | "
            f"{r.desktop_c_us:.2f} µs | {r.single_insn_max} | {s} | {r.double_insn_max} | {d} | "
            f"{r.single_flash_B / 1024:.1f} / {r.single_ram_B / 1024:.1f} KB | "
            f"{r.double_flash_B / 1024:.1f} / {r.double_ram_B / 1024:.1f} KB | {study} |")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="horizon 32, control horizon 1 only")
    ap.add_argument("--pil-states", type=int, default=12)
    ap.add_argument("--rounds", type=int, default=5, help="passes of the in-process timing")
    ap.add_argument("--repeat", type=int, default=500, help="passes of the C loop")
    args = ap.parse_args()
    missing = pil.missing_tools()
    if missing:
        raise SystemExit(f"PIL needs {', '.join(missing)} (see .ci/run)")
    rows = []
    for H, M in CONFIGS[:1] if args.quick else CONFIGS:
        rows.append(bench(H, M, args.pil_states, args.rounds, args.repeat))
        print({k: (round(v, 4) if isinstance(v, float) else v) for k, v in rows[-1].items()},
              flush=True)
    df = pd.DataFrame(rows)
    df.to_csv(HERE / "results.csv", index=False)
    write_stamped(HERE / "results.md", table(df), sys.argv)


if __name__ == "__main__":
    main()
