"""Record every experiment (or those named) and check each ``run.rrd``.

For each experiment: one run with ``recorder=rerun`` (figures off) into a temporary folder,
then ``rerun rrd verify`` on the file, and a read-back with ``rerun.chunk.RrdReader`` that
counts predicted horizons (one per step), their points (horizon + 1), obstacles and the
blueprint. Prints one row per experiment; exits non-zero if any check fails.

    uv run python experiments/recording/verify_all.py [NAME ...] [--override KEY=VALUE ...]
        [--md FILE]

The table is printed with its stamp (command, commit, CPU, date); ``--md`` also writes it.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
from pathlib import Path

import pandas as pd
from bench import compose_run, timed_run
from rerun.chunk import RrdReader

from mpclab.config.registry import register_all
from mpclab.record.provenance import write_stamped
from mpclab.recorders import rerun_blueprint as ent
from mpclab.recorders.rerun import RRD
from mpclab.runner.single_run import CONF_DIR as CONF


def check(name: str, overrides: list[str], tmp: Path) -> dict:
    cfg = compose_run(name, "rerun", overrides)
    out = tmp / name
    seconds, summary = timed_run(cfg, out)
    rrd = out / RRD
    verify = subprocess.run([sys.executable, "-m", "rerun", "rrd", "verify", str(rrd)],
                            capture_output=True, text=True)
    reader = RrdReader(rrd)
    lengths, obstacles = [], None
    for chunk in reader.stream():
        data = chunk.to_record_batch().to_pydict()
        if chunk.entity_path == f"/{ent.HORIZON}":
            lengths += [len(s[0]) for s in data.get("LineStrips2D:strips", []) if s]
        elif chunk.entity_path == f"/{ent.OBSTACLES}":
            if data.get("Points2D:positions"):
                obstacles = len(data["Points2D:positions"][-1] or [])
    horizon = int(cfg.controller.get("horizon", 0))  # the NN predicts nothing: horizon 0
    n_obstacles = len(getattr(_scenario(cfg), "obstacles", []))
    row = {
        "experiment": name,
        "status": summary["status"],
        "steps": summary["n_steps"],
        "run_s": seconds,
        "rrd_kib": rrd.stat().st_size / 1024,
        "rrd_verify": "ok" if verify.returncode == 0 else "FAILED",
        "horizons": len(lengths),
        "points_per_horizon": sorted(set(lengths)),
        "obstacles": obstacles,
        "blueprint": len(reader.blueprints()) == 1,
    }
    row["checks"] = "ok" if (
        verify.returncode == 0 and len(lengths) == summary["n_steps"]
        and set(lengths) <= {horizon + 1} and obstacles == n_obstacles and row["blueprint"]
    ) else "FAILED"
    return row


def _scenario(cfg):
    """The scenario alone (as ``build_run`` makes it), for its obstacle count."""
    import numpy as np

    from mpclab.config.instantiate import build

    plant = build(cfg.plant, "plant")
    rng = np.random.default_rng(cfg.seed)
    return build(cfg.scenario, "scenario", plant=plant, rng=rng)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("experiments", nargs="*", help="default: every conf/experiment/*.yaml")
    parser.add_argument("--override", action="append", default=[],
                        help="Hydra override applied to every run (repeatable)")
    parser.add_argument("--md", type=Path, help="also write the stamped table here")
    argv = list(sys.argv if argv is None else argv)
    args = parser.parse_args(argv[1:])
    register_all()
    names = args.experiments or sorted(p.stem for p in (CONF / "experiment").glob("*.yaml"))
    rows = []
    with tempfile.TemporaryDirectory(prefix="mpclab_rec_verify_") as tmp:
        for name in names:
            try:
                rows.append(check(name, args.override, Path(tmp)))
            except Exception as exc:  # one broken experiment must not hide the others
                cause = exc.__cause__ or exc  # Hydra wraps the constructor's error
                first = (str(cause).strip().splitlines() or [""])[0][:100]
                rows.append({"experiment": name,
                             "checks": f"ERROR {type(cause).__name__}: {first}"})
            print(f"{name}: {rows[-1]['checks']}", file=sys.stderr)
    table = pd.DataFrame(rows)
    if "blueprint" in table:
        table["blueprint"] = table["blueprint"].astype("boolean")
    for col in ("steps", "horizons", "obstacles"):
        if col in table:
            table[col] = table[col].astype("Int64")
    write_stamped(args.md, table.to_markdown(index=False, floatfmt=".2f"), argv)
    return 0 if (table["checks"] == "ok").all() else 1


if __name__ == "__main__":
    raise SystemExit(main())
