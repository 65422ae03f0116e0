"""A sweep job's set-up, cold against warm, in one process, interleaved.

    uv run python experiments/sweeps/phases.py [--jobs 12] [OVERRIDE ...]

Runs the Zumo sweep job (``+experiment=zumo_bug2 scenario=zumo_random seed=K
recorder=none figures.enabled=false``) for K = 0, 1, ... twice each, alternating:

* *cold*, as Hydra's joblib launcher runs it: Hydra composes the config from its defaults
  tree, and plant, objective and controller are built anew;
* *warm*, as a job runs on a warm worker of mpclab's pool launcher: the config composed by
  Hydra as well, the components reused (:mod:`mpclab.runner.component_cache`).

Prints the median seconds of each phase (compose, build, closed loop, write) and the ratio.
Both variants share the process, so imports are not in either (``import`` is printed once).
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

T0 = time.perf_counter()
from hydra import initialize_config_dir  # noqa: E402
from hydra.core.global_hydra import GlobalHydra  # noqa: E402
from hydra.types import RunMode  # noqa: E402

from mpclab.config.registry import register_all  # noqa: E402
from mpclab.runner.component_cache import ComponentCache  # noqa: E402
from mpclab.runner.single_run import CONF_DIR, run_experiment  # noqa: E402

register_all()
IMPORT_S = time.perf_counter() - T0
JOB = ["+experiment=zumo_bug2", "scenario=zumo_random", "recorder=none",
       "figures.enabled=false", "progress=false"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--jobs", type=int, default=12)
    parser.add_argument("overrides", nargs="*")
    args = parser.parse_args()
    phases: dict[str, dict[str, list[float]]] = {"cold": {}, "warm": {}}
    cache = ComponentCache()
    with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"), \
            tempfile.TemporaryDirectory() as tmp:
        loader = GlobalHydra.instance().config_loader()
        master = loader.load_configuration("config", JOB, RunMode.MULTIRUN)
        for k in range(args.jobs):
            overrides = [*JOB, f"seed={k}", *args.overrides]
            for variant in ("cold", "warm") if k % 2 == 0 else ("warm", "cold"):
                t0 = time.perf_counter()
                cfg = loader.load_sweep_config(master, overrides)
                compose_s = time.perf_counter() - t0
                task = {key: cfg[key] for key in cfg if key != "hydra"}
                cfg = type(cfg)(task)
                out = Path(tmp) / f"{variant}{k}"
                timing = run_experiment(cfg, out, cache if variant == "warm" else None)
                timing = timing.summary["timing"]
                got = phases[variant]
                for name, value in (("compose", compose_s), ("build", timing["build_s"]),
                                    ("closed loop", timing["simulate_s"]),
                                    ("write", timing["write_s"])):
                    got.setdefault(name, []).append(value)
    print(f"imports (once per process): {IMPORT_S:.2f} s\n")
    print("| phase | cold [s] | warm [s] | cold / warm |")
    print("|---|---:|---:|---:|")
    for name in phases["cold"]:
        # the first warm job builds (and composes) like a cold one: medians leave it out
        cold = statistics.median(phases["cold"][name])
        warm = statistics.median(phases["warm"][name][1:])
        print(f"| {name} | {cold:.3f} | {warm:.3f} | {cold / warm:.1f} |")
    outside = {v: statistics.median(
        [sum(p[n][i] for n in p if n != "closed loop") for i in range(1, args.jobs)])
        for v, p in phases.items()}
    print(f"| outside the closed loop | {outside['cold']:.3f} | {outside['warm']:.3f} | "
          f"{outside['cold'] / outside['warm']:.1f} |")
    print(f"\n{args.jobs} jobs each, interleaved; medians (warm: without its first job)")


if __name__ == "__main__":
    main()
