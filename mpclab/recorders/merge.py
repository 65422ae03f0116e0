"""Merge a sweep's recordings into one file for side-by-side comparison.

Each run's entities move under their own prefix (``/<run>/world/...``); the merged file
carries a blueprint with one map per run side by side and time-series panels that overlay
the runs. The command is ``python -m mpclab.cli.merge``.

A folder argument stands for every ``run.rrd`` below it. A run's prefix is made from the
Hydra overrides (``.hydra/overrides.yaml``, else the ``overrides`` in ``summary.json``) that
differ between the runs, e.g. ``controller_casadi``; without them, from the experiment and
the run folder's name.
"""

from __future__ import annotations

import json
import re
import uuid
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from mpclab.recorders import rerun_blueprint as ent
from mpclab.recorders.rerun import RRD

#: Rerun application id of merged recordings (its blueprint differs from a single run's)
SWEEP_APP_ID = "mpclab_sweep"
#: default file name of a merged recording, next to the runs
MERGED = "sweep.rrd"


def find_recordings(paths: Sequence[Path | str]) -> list[Path]:
    """The ``.rrd`` files named, and every ``run.rrd`` below each folder named (sorted)."""
    found: list[Path] = []
    for p in map(Path, paths):
        if p.is_dir():
            found += sorted(p.rglob(RRD), key=_natural)
        elif p.is_file():
            found.append(p)
        else:
            raise FileNotFoundError(f"no recording or folder at {p}")
    if not found:
        raise FileNotFoundError(f"no {RRD} found in {[str(p) for p in paths]}")
    return found


def run_labels(rrds: Sequence[Path]) -> list[str]:
    """One entity-path-safe prefix per recording, unique, from the overrides that differ."""
    overrides = [run_overrides(p.parent) for p in rrds]
    common = set.intersection(*(set(o) for o in overrides)) if overrides else set()
    labels = []
    for rrd, over in zip(rrds, overrides, strict=True):
        differing = [o for o in over if o not in common]
        labels.append(entity_name("_".join(differing) if differing else _fallback_name(rrd)))
    seen: dict[str, int] = {}
    for i, label in enumerate(labels):
        if labels.count(label) > 1:
            seen[label] = seen.get(label, 0) + 1
            labels[i] = f"{label}_{seen[label]}"
    return labels


def merge(rrds: Sequence[Path], out: Path, labels: Sequence[str] | None = None) -> Path:
    """Write ``out``: every recording in ``rrds`` under its prefix in ``labels``."""
    import rerun as rr
    from rerun.chunk import RrdReader

    labels = list(labels) if labels is not None else run_labels(rrds)
    if len(labels) != len(rrds) or len(set(labels)) != len(labels):
        raise ValueError(f"need one unique label per recording, got {labels} for {len(rrds)}")
    runs = []
    for rrd in rrds:
        chunks = [c for c in RrdReader(rrd).stream()
                  if not c.entity_path.startswith("/__properties")]
        runs.append(chunks)
    paths = sorted({c.entity_path for chunks in runs for c in chunks})
    states = _labels_under(paths, ent.STATES)
    inputs = _labels_under(paths, ent.INPUTS)
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    rec = rr.RecordingStream(SWEEP_APP_ID, recording_id=uuid.uuid4())
    bounds = _bounds([c for chunks in runs for c in chunks])
    rec.save(out, default_blueprint=ent.sweep_blueprint(labels, states, inputs, bounds))
    rec.send_recording_name(f"sweep of {len(rrds)} runs")
    for label, chunks in zip(labels, runs, strict=True):
        rec.send_chunks([c.with_entity_path(f"/{label}{c.entity_path}") for c in chunks])
        # legends of the overlaid panels name the run
        for path in sorted({c.entity_path for c in chunks}):
            if path.startswith("/series/"):
                leaf = path.split("/", 3)[-1]
                rec.log(f"/{label}{path}", rr.SeriesLines(names=f"{label}: {leaf}"), static=True)
    rec.flush()
    rec.disconnect()
    return out


def _labels_under(paths: Sequence[str], root: str) -> list[str]:
    """Signal labels directly under ``/root`` (``/series/states/px`` -> ``px``), in order."""
    labels: list[str] = []
    for path in paths:
        parts = path.strip("/").split("/")
        depth = len(root.split("/"))
        if "/".join(parts[:depth]) == root and len(parts) == depth + 1:
            if parts[depth] not in labels:
                labels.append(parts[depth])
    return labels


#: static and per-step entities whose points outline a run's map
_OUTLINE = {f"/{e}" for e in (ent.START, ent.GOAL, ent.OBSTACLES, ent.REFERENCE_PATH, ent.PATH)}


def _bounds(chunks: Sequence[Any]) -> tuple[float, float, float, float] | None:
    """``(x_min, x_max, y_min, y_max)`` over every run's start, goal, obstacles, path, 10 % out."""
    pts: list[np.ndarray] = []
    for c in chunks:
        if c.entity_path not in _OUTLINE:
            continue
        data = c.to_record_batch().to_pydict()
        for key in ("Arrows2D:origins", "Points2D:positions", "LineStrips2D:strips"):
            for row in data.get(key, []):
                if row:
                    pts.append(np.asarray(row, dtype=float).reshape(-1, 2))
        for centres, radii in zip(data.get("Points2D:positions", []),
                                  data.get("Points2D:radii", []), strict=False):
            if centres and radii:  # obstacle discs: their rims
                P, r = np.asarray(centres).reshape(-1, 2), np.asarray(radii)[:, None]
                pts += [P - r, P + r]
    if not pts:
        return None
    P = np.concatenate(pts)
    lo, hi = P.min(axis=0), P.max(axis=0)
    m = 0.1 * max(float(np.linalg.norm(hi - lo)), 0.1)
    return lo[0] - m, hi[0] + m, lo[1] - m, hi[1] + m


def run_overrides(run_dir: Path) -> list[str]:
    """A run's Hydra overrides: ``.hydra/overrides.yaml``, else ``summary.json``'s list."""
    path = run_dir / ".hydra" / "overrides.yaml"
    if path.is_file():
        from omegaconf import OmegaConf

        return [str(o) for o in OmegaConf.load(path)]
    summary = run_dir / "summary.json"
    if summary.is_file():
        return [str(o) for o in json.loads(summary.read_text()).get("overrides") or []]
    return []


def _fallback_name(rrd: Path) -> str:
    summary = rrd.parent / "summary.json"
    if summary.is_file():
        s = json.loads(summary.read_text())
        return f"{s.get('experiment', 'run')}_{rrd.parent.name}"
    return rrd.parent.name or rrd.stem


def entity_name(text: str) -> str:
    """An entity path part: letters, digits, ``_``, ``-`` and ``.`` only."""
    text = re.sub(r"[^A-Za-z0-9_.-]+", "_", text.lstrip("+~")).strip("_")
    return text or "run"


def _natural(p: Path) -> list[object]:
    return [int(s) if s.isdigit() else s for s in re.split(r"(\d+)", str(p))]

