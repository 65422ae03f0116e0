"""The Rerun recorder (``recorder=rerun``): one ``run.rrd`` per run, written without a viewer.

Each run gets its own ``RecordingStream`` (never the global one, so parallel jobs never mix)
that streams into ``<run folder>/run.rrd`` with a default blueprint: the 2D map beside stacked
time series. Entity paths and timelines are in :mod:`mpclab.recorders.rerun_blueprint`.

Static: obstacles, start, goal, BUG2's m-line, a tracking scenario's reference, the resolved
config with package versions. Per step, on the ``step`` and ``sim_time`` timelines: the
vehicle pose, the new path segment, the predicted horizon, sensor rays and hits, states,
inputs, solve time, solver status, cost; supervisor mode and solver status as text-log
entries on each change. Per-step data is buffered and sent in columns (``send_columns``)
every ``batch_steps`` steps and when the run ends, which keeps a step's cost to appending
a few arrays.

Optional hooks used when present: ``scenario.rays(x)`` (ray end points ``(n, 2)``),
``scenario.reference_table()`` (DataFrame: ``t`` and state-label columns),
``supervisor.mline`` (``((x0, y0), (x1, y1))`` or None).
"""

from __future__ import annotations

import uuid
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from mpclab.config.registry import component
from mpclab.core.errors import ConfigError
from mpclab.core.status import SOLVE_KEYS
from mpclab.recorders import rerun_blueprint as ent
from mpclab.recorders.base import Recorder
from mpclab.recorders.rerun_config import config_document

if TYPE_CHECKING:  # rerun is imported when a recording starts: importing it is slow
    import rerun as rr

#: file name of a run's recording inside its run folder
RRD = "run.rrd"
#: Rerun application id of single-run recordings (blueprints are stored per application)
APP_ID = "mpclab"

_RED, _BLUE, _GREY = (214, 39, 40), (31, 119, 180), (140, 140, 140)
_GREEN, _WHITE, _PURPLE = (44, 160, 44), (190, 190, 230), (148, 103, 189)
_YELLOW, _ORANGE = (230, 200, 60, 90), (255, 127, 14)
#: line and point radii in UI points (Rerun reads negative radii as UI points)
_THIN, _THICK = -1.0, -2.5


@component("recorder", "rerun", injected=("out_dir", "cfg"), hydra_keys={"_recursive_": False})
class RerunRecorder(Recorder):
    """Write the run into ``out_dir / filename`` as a Rerun recording.

    Parameters
    ----------
    out_dir
        Run folder (injected). Without one nothing is written.
    cfg
        The resolved run config (injected), stored as a text document in the recording.
    filename
        File name of the recording in ``out_dir``.
    batch_steps
        Per-step data is sent in columns every this many steps (and at the end).
    arrow_length
        Length of the heading arrows [m]; None: 6 % of the scene's extent.
    """

    def __init__(
        self,
        out_dir: Path | str | None = None,
        cfg: Mapping[str, Any] | None = None,
        filename: str = RRD,
        batch_steps: int = 100,
        arrow_length: float | None = None,
    ) -> None:
        if int(batch_steps) < 1:
            raise ConfigError(f"recorder.batch_steps must be >= 1, got {batch_steps}")
        if arrow_length is not None and float(arrow_length) <= 0:
            raise ConfigError(f"recorder.arrow_length must be > 0 or null, got {arrow_length}")
        self.path = Path(out_dir) / filename if out_dir is not None else None
        self.cfg = cfg
        self.batch_steps = int(batch_steps)
        self.arrow_length = None if arrow_length is None else float(arrow_length)
        self._rec: rr.RecordingStream | None = None
        self._buf = _StepBuffer()

    # ------------------------------------------------------------------ Recorder hooks
    def start(self, run: Any) -> None:
        import rerun as rr

        if self.path is None:
            return
        plant, scen = run.plant, run.scenario
        self._pos = [plant.state_index(label) for label in plant.position]
        self._head = None if plant.heading is None else plant.state_index(plant.heading)
        self._states, self._inputs = tuple(plant.states), tuple(plant.inputs)
        self._dt = float(run.controller.dt)
        self._rays = getattr(scen, "rays", None) if callable(getattr(scen, "rays", None)) else None
        self._scen = scen
        self._last_pos = scen.x0[self._pos].astype(float)
        self._mode: str | None = None
        self._status: str | None = None
        self._k = 0
        self._key_states = tuple(plant.plot_states) or self._states
        reference = _reference_table(scen)
        x0, x1, y0, y1 = _scene_box(scen, self._pos, reference)
        self._lo, self._hi = np.array([x0, y0]), np.array([x1, y1])
        self._arrow = self.arrow_length or 0.06 * _diagonal(self._lo, self._hi)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        rec = rr.RecordingStream(APP_ID, recording_id=uuid.uuid4())
        rec.save(self.path)  # the blueprint is sent at close, framing the whole path
        self._rec = rec
        name = self.cfg.get("name") if self.cfg is not None else None
        rec.send_recording_name(f"{name or 'run'} / {scen.name}")
        self._log_static(run, reference)

    def log_step(self, k: int, t: float, x: Any, step: Any, ctx: Any) -> None:
        if self._rec is None:
            return
        x = np.asarray(x, dtype=float)
        pos = self._pose_row(k, t, x)
        b = self._buf
        b.k.append(k)
        b.t.append(t)
        b.u.append(np.asarray(step.u, dtype=float).reshape(-1).copy())
        x_pred = np.asarray(step.x_pred, dtype=float)
        b.horizon.append(x_pred[:, self._pos] if x_pred.ndim == 2 else np.zeros((0, 2)))
        b.solve_time_ms.append(1e3 * float(step.info.get("solve_time_s", np.nan)))
        b.quality.append(0.0 if step.fallback else 2.0 if step.status == "converged" else 1.0)
        b.cost.append(float(step.cost))
        measured = step.info.get("x_measured")  # the sim's state noise: what the robot believed
        if measured is not None:
            b.measured.append((k, t, np.asarray(measured, dtype=float)[self._pos]))
        if "latency_s" in step.info:
            b.latency.append((k, t, 1e3 * float(step.info["latency_s"])))
        b.detections.append(np.asarray(ctx.detections, dtype=float).reshape(-1, 2))
        if self._rays is not None:
            ends = np.asarray(self._rays(x), dtype=float).reshape(-1, 2)
            b.rays.append(np.stack([np.broadcast_to(pos, ends.shape), ends], axis=1))
        if ctx.mode != self._mode:
            self._mode = ctx.mode
            b.events.append((ent.MODE_LOG, k, t, f"mode: {ctx.mode or '(none)'}", "INFO"))
        raw = f" ({step.solver_status})" if step.solver_status else ""
        status = f"{step.status}{raw}" + (", fallback" if step.fallback else "")
        if status != self._status:
            self._status = status
            level = "INFO" if step.status == "converged" else "WARN"
            b.events.append((ent.SOLVER_LOG, k, t, f"solver: {status}", level))
        self._k = k + 1
        if len(b.k) >= self.batch_steps:
            self._flush()

    def finish(self, x: Any, t: float, summary: dict[str, Any]) -> None:
        """Log the final pose, state and path segment at step ``n_steps``, and the outcome."""
        if self._rec is None:
            return
        self._pose_row(self._k, t, np.asarray(x, dtype=float))
        when = f" at t = {summary['arrival_time_s']:.2f} s" if summary.get("arrived") else ""
        solves = ", ".join(f"{summary[key]} {st}" for st, key in SOLVE_KEYS.items()
                           if summary.get(key))
        self._buf.events.append((ent.RUN_LOG, self._k, t, f"run ended: {summary.get('status')}"
                                 f"{when}; solves: {solves or 'none'}", "INFO"))
        self._flush()

    def close(self) -> None:
        if self._rec is None:
            return
        try:
            self._flush()
            m = 0.08 * _diagonal(self._lo, self._hi)
            bounds = (self._lo[0] - m, self._hi[0] + m, self._lo[1] - m, self._hi[1] + m)
            self._rec.send_blueprint(ent.run_blueprint(self._key_states, self._inputs, bounds))
        finally:
            self._rec.flush()
            self._rec.disconnect()  # closes the file sink, which writes the footer
            self._rec = None

    # ------------------------------------------------------------------ logging
    def _log_static(self, run: Any, reference: Any) -> None:
        import rerun as rr

        rec, scen = self._rec, self._scen
        assert rec is not None
        rec.log(ent.WORLD, rr.Transform3D(mat3x3=np.diag([1.0, -1.0, 1.0])), static=True)
        # styles of the per-step entities, logged once: a static value holds for every step
        vehicle = rr.Points2D if self._head is None else rr.Arrows2D
        for path, style in (
            (ent.PATH, rr.LineStrips2D.from_fields(colors=[_RED], radii=[_THICK])),
            (ent.HORIZON, rr.LineStrips2D.from_fields(colors=[_BLUE], radii=[_THIN])),
            (ent.RAYS, rr.LineStrips2D.from_fields(colors=[_YELLOW], radii=[_THIN])),
            (ent.DETECTIONS, rr.Points2D.from_fields(colors=[_ORANGE], radii=[_THICK])),
            (ent.MEASURED, rr.Points2D.from_fields(colors=[_BLUE], radii=[_THIN])),
            (ent.VEHICLE, vehicle.from_fields(colors=[_ORANGE], radii=[_THICK])),
        ):
            rec.log(path, style, static=True)
        rec.log(ent.CONFIG, rr.TextDocument(config_document(self.cfg),
                                            media_type=rr.MediaType.MARKDOWN), static=True)
        obstacles = np.asarray(scen.obstacles, dtype=float).reshape(-1, 3)
        rec.log(ent.OBSTACLES, rr.Points2D(obstacles[:, :2], radii=obstacles[:, 2],
                                           colors=_GREY), static=True)
        for path, state, color in ((ent.START, scen.x0, _WHITE), (ent.GOAL, scen.goal, _GREEN)):
            p = state[self._pos]
            label = path.rsplit("/", 1)[-1]
            if self._head is None:
                rec.log(path, rr.Points2D([p], colors=color, labels=label, radii=_THICK),
                        static=True)
            else:
                rec.log(path, rr.Arrows2D(origins=[p], vectors=[self._arrow_vec(state[self._head])],
                                          colors=color, labels=label, radii=_THIN), static=True)
        mline = getattr(run.supervisor, "mline", None)
        if mline is not None:
            rec.log(ent.MLINE, rr.LineStrips2D([np.asarray(mline, dtype=float).reshape(2, 2)],
                                               colors=_PURPLE, radii=_THIN, labels="m-line"),
                    static=True)
        if reference is not None:
            self._log_reference(reference)
        for label in self._inputs:  # unit-free names make the legends readable
            rec.log(f"{ent.INPUTS}/{label}", rr.SeriesLines(names=label), static=True)

    def _log_reference(self, ref: Any) -> None:
        import rerun as rr

        rec = self._rec
        assert rec is not None
        if "t" not in ref:
            raise ValueError(f"scenario.reference_table() needs a column 't', got {list(ref)}")
        px, py = self._scen.plant.position
        if px in ref and py in ref:
            rec.log(ent.REFERENCE_PATH, rr.LineStrips2D(
                [ref[[px, py]].to_numpy(dtype=float)], colors=_GREEN, radii=_THIN), static=True)
        t = ref["t"].to_numpy(dtype=float)
        k = t / self._dt
        idx = [rr.TimeColumn(ent.SIM_TIME, duration=t)]
        if np.allclose(k, np.round(k), atol=1e-6) and (k >= -0.5).all():
            idx.append(rr.TimeColumn(ent.STEP, sequence=np.round(k).astype(np.int64)))
        for label in self._states:
            if label in ref:
                rec.send_columns(f"{ent.STATES}/{label}/reference", idx, rr.Scalars.columns(
                    scalars=ref[label].to_numpy(dtype=float)))

    def _pose_row(self, k: int, t: float, x: np.ndarray) -> np.ndarray:
        """Buffer the pose, state and new path segment at step ``k``; return the position."""
        b = self._buf
        pos = x[self._pos]
        b.pk.append(k)
        b.pt.append(t)
        b.x.append(x.copy())
        b.heading.append(np.nan if self._head is None else x[self._head])
        b.segment.append(np.stack([self._last_pos, pos]))
        self._last_pos = pos.copy()
        self._lo, self._hi = np.minimum(self._lo, pos), np.maximum(self._hi, pos)
        return pos

    def _flush(self) -> None:
        import rerun as rr

        b, rec = self._buf, self._rec
        if rec is None or not (b.pk or b.events):
            return
        if b.pk:  # poses, path segments and states: every step and the final state
            idx = _indexes(b.pk, b.pt)
            self._send_pose(idx, np.stack([s[1] for s in b.segment]), np.asarray(b.heading))
            rec.send_columns(ent.PATH, idx, rr.LineStrips2D.columns(strips=_strips(b.segment)))
            X = np.stack(b.x)
            for i, label in enumerate(self._states):
                rec.send_columns(f"{ent.STATES}/{label}", idx,
                                 rr.Scalars.columns(scalars=X[:, i]))
        if b.k:  # what each controller call adds
            idx = _indexes(b.k, b.t)
            rec.send_columns(ent.HORIZON, idx,
                             rr.LineStrips2D.columns(strips=_strips(b.horizon)))
            _send_ragged(rec, ent.DETECTIONS, idx, b.detections, rr.Points2D, "positions")
            if self._rays is not None:
                _send_ragged(rec, ent.RAYS, idx, b.rays, rr.LineStrips2D, "strips")
            U = np.stack(b.u)
            for j, label in enumerate(self._inputs[: U.shape[1]]):
                rec.send_columns(f"{ent.INPUTS}/{label}", idx,
                                 rr.Scalars.columns(scalars=U[:, j]))
            for path, values in ((ent.SOLVE_TIME, b.solve_time_ms), (ent.SOLVE_QUALITY, b.quality),
                                 (ent.COST, b.cost)):
                rec.send_columns(path, idx, rr.Scalars.columns(scalars=values))
        if b.measured:
            ks, ts, ps = zip(*b.measured, strict=True)
            rec.send_columns(ent.MEASURED, _indexes(ks, ts),
                             rr.Points2D.columns(positions=np.stack(ps)))
        if b.latency:
            ks, ts, ms = zip(*b.latency, strict=True)
            rec.send_columns(ent.LATENCY, _indexes(ks, ts), rr.Scalars.columns(scalars=ms))
        for path in (ent.MODE_LOG, ent.SOLVER_LOG, ent.RUN_LOG):
            rows = [e for e in b.events if e[0] == path]
            if rows:
                _, ks, ts, text, level = zip(*rows, strict=True)
                rec.send_columns(path, _indexes(ks, ts),
                                 rr.TextLog.columns(text=text, level=level))
        self._buf = _StepBuffer()

    def _send_pose(self, idx: list[rr.TimeColumn], pos: np.ndarray, heading: np.ndarray) -> None:
        import rerun as rr

        assert self._rec is not None
        if self._head is None:
            cols = rr.Points2D.columns(positions=pos)
        else:
            cols = rr.Arrows2D.columns(origins=pos, vectors=self._arrow_vec(heading))
        self._rec.send_columns(ent.VEHICLE, idx, cols)

    def _arrow_vec(self, heading: Any) -> np.ndarray:
        h = np.asarray(heading, dtype=float)
        return self._arrow * np.stack([np.cos(h), np.sin(h)], axis=-1)


class _StepBuffer:
    """Per-step values waiting to be sent in columns."""

    def __init__(self) -> None:
        # poses, states, path segments: one row per step plus the final state
        self.pk: list[int] = []
        self.pt: list[float] = []
        self.x: list[np.ndarray] = []
        self.heading: list[float] = []
        self.segment: list[np.ndarray] = []
        # one row per controller call
        self.k: list[int] = []
        self.t: list[float] = []
        self.u: list[np.ndarray] = []
        self.horizon: list[np.ndarray] = []
        self.detections: list[np.ndarray] = []
        self.rays: list[np.ndarray] = []
        self.solve_time_ms: list[float] = []
        self.quality: list[float] = []  # 2 converged, 1 truncated, 0 fell back
        self.cost: list[float] = []
        self.measured: list[tuple[int, float, np.ndarray]] = []  # (k, t, position)
        self.latency: list[tuple[int, float, float]] = []  # (k, t, ms)
        self.events: list[tuple[str, int, float, str, str]] = []


def _indexes(ks: Any, ts: Any) -> list[rr.TimeColumn]:
    import rerun as rr

    return [
        rr.TimeColumn(ent.STEP, sequence=np.asarray(ks, dtype=np.int64)),
        rr.TimeColumn(ent.SIM_TIME, duration=np.asarray(ts, dtype=float)),
    ]


def _strips(strips: list[np.ndarray]) -> np.ndarray | list[np.ndarray]:
    """Strips of equal length as one ``(n, points, 2)`` array: Rerun converts it ~30x faster."""
    if strips and all(s.shape == strips[0].shape for s in strips):
        return np.stack(strips)
    return strips


def _send_ragged(
    rec: rr.RecordingStream, path: str, idx: list[rr.TimeColumn], rows: list[np.ndarray],
    archetype: Any, field: str,
) -> None:
    """Send a different number of items per step (rays, detections) as one column.

    ``rows`` are ``(n_k, 2)`` points or ``(n_k, 2, 2)`` segments; concatenated they convert in
    one go.
    """
    lengths = [len(r) for r in rows]
    flat = np.concatenate(rows)
    rec.send_columns(path, idx, archetype.columns(**{field: flat}).partition(lengths))


def _reference_table(scen: Any) -> Any:
    fn = getattr(scen, "reference_table", None)
    return fn() if callable(fn) else None


def _scene_box(scen: Any, pos: list[int], reference: Any) -> tuple[float, float, float, float]:
    """``(x_min, x_max, y_min, y_max)`` around start, goal, obstacles and reference [m]."""
    pts = [scen.x0[pos], scen.goal[pos]]
    obstacles = np.asarray(scen.obstacles, dtype=float).reshape(-1, 3)
    for cx, cy, r in obstacles:
        pts += [np.array([cx - r, cy - r]), np.array([cx + r, cy + r])]
    px, py = scen.plant.position
    if reference is not None and px in reference and py in reference:
        pts += list(reference[[px, py]].to_numpy(dtype=float))
    P = np.asarray(pts, dtype=float)
    (x0, y0), (x1, y1) = P.min(axis=0), P.max(axis=0)
    return float(x0), float(x1), float(y0), float(y1)


def _diagonal(lo: np.ndarray, hi: np.ndarray) -> float:
    return max(float(np.linalg.norm(hi - lo)), 0.1)
