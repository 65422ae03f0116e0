"""Tracking scenarios: time-varying references with preview (Study C).

A reference is built from three pieces, all in config:

* ``speed``: a piecewise-linear speed profile ``V_ref(t)`` (repeat a time for a step);
* ``path``: straight and arc segments laid from the start pose; the reference point moves
  along it by ``s(t) = integral of V_ref`` and carries the path's heading as ``theta_ref``;
  past its end the path continues straight;
* ``lateral``: a piecewise-linear offset ``d(t)`` to the left of the path (a lane change).

``target(t, horizon, dt)`` samples the reference at ``t, t + dt, ..., t + horizon dt`` (the
preview the controller sees); ``reference_table()`` gives it on a time grid for recordings and
figures; ``metrics(steps)`` adds the tracking figures to ``summary.json``. The goal is the
reference at ``t_end``: the run arrives when the vehicle reaches the end of the reference.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Any

import numpy as np
import pandas as pd

from mpclab.config.registry import component
from mpclab.core.errors import ConfigError
from mpclab.plants.base import Plant
from mpclab.record import files as record
from mpclab.world.scenario import ArrivalConf, FloatArray, Scenario

#: times or arc lengths: a scalar, a sequence or an array
npt_like = float | Sequence[float] | FloatArray


class SegmentKind(StrEnum):
    straight = "straight"
    arc = "arc"


@dataclass
class ProfileConf:
    """Piecewise-linear profile through ``(t[i], value[i])``; held before and after."""

    t: list[float] = field(default_factory=lambda: [0.0])
    value: list[float] = field(default_factory=lambda: [0.0])


@dataclass
class SegmentConf:
    """A straight of ``length`` [m], or an arc of ``radius`` [m] turning ``angle`` [rad]
    (positive: to the left)."""

    kind: SegmentKind = SegmentKind.straight
    length: float = 0.0
    radius: float = 0.0
    angle: float = 0.0


@dataclass
class TrackingConf:
    _target_: str = "mpclab.world.references.TrackingScenario"
    name: str = "???"
    start: dict[str, float] = field(default_factory=dict)
    speed: ProfileConf = field(default_factory=ProfileConf)
    path: list[SegmentConf] = field(default_factory=list)
    lateral: ProfileConf = field(default_factory=ProfileConf)
    references: list[str] = field(default_factory=lambda: ["px", "py", "theta", "V"])
    arrival: ArrivalConf = field(
        default_factory=lambda: ArrivalConf(weights={"px": 1.0, "py": 1.0}, threshold=0.25)
    )
    t_end: float = 10.0
    t_max: float = 15.0
    overshoot: list[str] = field(default_factory=list)
    table_dt: float = 0.02


class Profile:
    """Piecewise-linear ``v(t)`` and its exact integral from 0."""

    def __init__(self, t: Sequence[float], value: Sequence[float], where: str) -> None:
        t_arr = np.asarray(t, dtype=float)
        v = np.asarray(value, dtype=float)
        if t_arr.ndim != 1 or t_arr.size == 0 or t_arr.shape != v.shape:
            raise ConfigError(
                f"{where}: t and value must be equally long non-empty lists, got "
                f"{len(t)} times and {len(value)} values"
            )
        if np.any(np.diff(t_arr) < 0):
            raise ConfigError(f"{where}.t must be non-decreasing, got {list(t)}")
        # a repeated time is a step: give it a 1 ns ramp so that interpolation is defined
        for i in range(1, t_arr.size):
            if t_arr[i] <= t_arr[i - 1]:
                t_arr[i] = t_arr[i - 1] + 1e-9
        self.t, self.v = t_arr, v
        self._S = np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * np.diff(t_arr))])
        slope = np.diff(v) / np.diff(t_arr) if t_arr.size > 1 else np.zeros(0)
        self._slope = np.concatenate([slope, [0.0]])

    def __call__(self, t: npt_like) -> FloatArray:
        return np.interp(t, self.t, self.v)

    def integral(self, t: npt_like) -> FloatArray:
        """``integral_0^t v`` (the profile is held constant before ``t[0]``)."""
        t = np.asarray(t, dtype=float)
        i = np.clip(np.searchsorted(self.t, t, side="right") - 1, 0, self.t.size - 1)
        d = t - self.t[i]
        slope = np.where(d > 0, self._slope[i], 0.0)
        return self._S[i] + self.v[i] * d + 0.5 * slope * d**2 + self.v[0] * self.t[0]


class Path:
    """Straight and arc segments from a start pose; continued straight past both ends."""

    def __init__(self, x0: float, y0: float, h0: float, segments: Sequence[Mapping[str, Any]]):
        self.kind: list[SegmentKind] = []
        self.pose0: list[tuple[float, float, float]] = []
        self.s0: list[float] = []
        self.radius: list[float] = []
        self.sign: list[float] = []
        x, y, h, s = float(x0), float(y0), float(h0), 0.0
        for i, seg in enumerate(segments):
            where = f"scenario.path[{i}]"
            kind = SegmentKind(seg.get("kind", "straight"))
            self.kind.append(kind)
            self.pose0.append((x, y, h))
            self.s0.append(s)
            if kind is SegmentKind.straight:
                length = float(seg.get("length", 0.0))
                if length <= 0:
                    raise ConfigError(f"{where}.length must be > 0 for a straight, got {length}")
                self.radius.append(np.inf)
                self.sign.append(0.0)
                x, y = x + length * np.cos(h), y + length * np.sin(h)
            else:
                radius, angle = float(seg.get("radius", 0.0)), float(seg.get("angle", 0.0))
                if radius <= 0 or angle == 0:
                    raise ConfigError(
                        f"{where}: an arc needs radius > 0 and angle != 0, got radius {radius}, "
                        f"angle {angle}"
                    )
                sg = float(np.sign(angle))
                self.radius.append(radius)
                self.sign.append(sg)
                cx, cy = x - sg * radius * np.sin(h), y + sg * radius * np.cos(h)
                h = h + angle
                x, y = cx + sg * radius * np.sin(h), cy - sg * radius * np.cos(h)
                length = radius * abs(angle)
            s += length
        self.end_pose = (x, y, h)
        self.length = s

    def __call__(self, s: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Position and heading ``(x, y, h)`` at arc lengths ``s``."""
        s = np.asarray(s, dtype=float)
        x0, y0, h0 = self.pose0[0] if self.pose0 else self.end_pose
        # before the start and past the end: straight lines along the end headings
        out_h = np.full(s.shape, h0)
        out_x = x0 + np.minimum(s, 0.0) * np.cos(h0)
        out_y = y0 + np.minimum(s, 0.0) * np.sin(h0)
        ends = self.s0[1:] + [self.length]
        for kind, (xa, ya, ha), sa, sb, R, sg in zip(
            self.kind, self.pose0, self.s0, ends, self.radius, self.sign, strict=True
        ):
            m = (s >= sa) & (s < sb)
            if not m.any():
                continue
            d = s[m] - sa
            if kind is SegmentKind.straight:
                out_x[m], out_y[m], out_h[m] = xa + d * np.cos(ha), ya + d * np.sin(ha), ha
            else:
                cx, cy = xa - sg * R * np.sin(ha), ya + sg * R * np.cos(ha)
                h = ha + sg * d / R
                out_x[m], out_y[m], out_h[m] = cx + sg * R * np.sin(h), cy - sg * R * np.cos(h), h
        m = s >= self.length
        xe, ye, he = self.end_pose
        d = s[m] - self.length
        out_x[m], out_y[m], out_h[m] = xe + d * np.cos(he), ye + d * np.sin(he), he
        return out_x, out_y, out_h


@component("scenario", "tracking", TrackingConf)
class TrackingScenario(Scenario):
    """Track a time-varying reference for ``px, py, theta, V`` with preview.

    Parameters
    ----------
    plant
        Injected; needs the state labels in ``references`` (and ``px, py, theta, V``
        for the path and speed profile).
    name
        Scenario name.
    start
        Initial state ``{label: value}``; its ``px, py, theta`` are the path's start pose.
    speed, path, lateral
        The reference (see the module docstring).
    references
        State labels the target holds (others are 0 in the target).
    arrival
        Arrived when the weighted squared distance to the reference at ``t_end`` is below
        ``threshold``.
    t_end
        Duration of the reference [s]; ``t_max``: simulated time limit [s].
    overshoot
        Labels whose overshoot past their final reference value goes into the metrics.
    table_dt
        Time step of :meth:`reference_table` [s].
    """

    def __init__(
        self,
        plant: Plant,
        name: str,
        start: Mapping[str, float],
        speed: Mapping[str, Any],
        path: Sequence[Mapping[str, Any]],
        lateral: Mapping[str, Any] | None = None,
        references: Sequence[str] = ("px", "py", "theta", "V"),
        arrival: Mapping[str, Any] | None = None,
        t_end: float = 10.0,
        t_max: float = 15.0,
        overshoot: Sequence[str] = (),
        table_dt: float = 0.02,
    ) -> None:
        arrival = dict(arrival or {"weights": {"px": 1.0, "py": 1.0}, "threshold": 0.25})
        super().__init__(plant, name, start, {}, arrival, t_max)
        try:
            self._i = {lab: plant.state_index(lab) for lab in ("px", "py", "theta", "V")}
            self.ref_labels = tuple(references)
            self._ref_idx = np.array([plant.state_index(lab) for lab in self.ref_labels], int)
            self._overshoot = tuple(overshoot)
            for lab in self._overshoot:
                plant.state_index(lab)
        except ValueError as exc:
            raise ConfigError(f"scenario {name}: {exc}") from None
        self.speed = Profile(speed["t"], speed["value"], "scenario.speed")
        lat = lateral or {"t": [0.0], "value": [0.0]}
        self.lateral = Profile(lat["t"], lat["value"], "scenario.lateral")
        i = self._i
        self.path = Path(self.x0[i["px"]], self.x0[i["py"]], self.x0[i["theta"]], path)
        if float(t_end) <= 0 or float(table_dt) <= 0:
            raise ConfigError(f"scenario.t_end and table_dt must be > 0, got {t_end}, {table_dt}")
        self.t_end, self.table_dt = float(t_end), float(table_dt)
        self.goal = self.reference(np.array([self.t_end]))[0]

    def reference(self, t: FloatArray) -> FloatArray:
        """Reference states ``(len(t), nx)`` at times ``t`` (labels not referenced are 0)."""
        t = np.asarray(t, dtype=float)
        x, y, h = self.path(self.speed.integral(t))
        d = self.lateral(t)
        full = np.zeros((t.size, self.plant.nx))
        i = self._i
        full[:, i["px"]] = x - d * np.sin(h)
        full[:, i["py"]] = y + d * np.cos(h)
        full[:, i["theta"]] = h
        full[:, i["V"]] = self.speed(t)
        out = np.zeros_like(full)
        out[:, self._ref_idx] = full[:, self._ref_idx]
        return out

    def target(self, t: float, horizon: int, dt: float) -> FloatArray:
        """The reference previewed over the horizon, ``(horizon+1, nx)``."""
        return self.reference(t + dt * np.arange(horizon + 1))

    def reference_table(self) -> pd.DataFrame:
        """Column ``t`` plus one column per referenced state label, from 0 to ``t_max``."""
        t = np.arange(0.0, self.t_max + 0.5 * self.table_dt, self.table_dt)
        ref = self.reference(t)
        table = pd.DataFrame({"t": t})
        for lab, j in zip(self.ref_labels, self._ref_idx, strict=True):
            table[lab] = ref[:, j]
        return table

    def draw(self, ax: Any) -> None:
        """The reference path, dashed (called by the per-run path figure)."""
        ref = self.reference_table()
        if {"px", "py"} <= set(ref.columns):
            ax.plot(ref["px"], ref["py"], "--", color="k", lw=0.9, label="reference")

    def metrics(self, steps: pd.DataFrame, outcome: Mapping[str, Any]) -> dict[str, Any]:
        """RMS error per referenced state, overshoots, input jumps and bound excess."""
        plant = self.plant
        t = steps["t"].to_numpy()
        ref = self.reference(t)
        out: dict[str, Any] = {}
        sq_pos = 0.0
        for lab, j in zip(self.ref_labels, self._ref_idx, strict=True):
            err = steps[lab].to_numpy() - ref[:, j]
            out[f"rms_{lab}"] = float(np.sqrt(np.mean(err**2)))
            if lab in ("px", "py"):
                sq_pos = sq_pos + err**2
        if {"px", "py"} <= set(self.ref_labels):
            out["rms_position"] = float(np.sqrt(np.mean(sq_pos)))
        r0, r_end = self.reference(np.array([0.0, self.t_end]))
        for lab in self._overshoot:
            j = plant.state_index(lab)
            change = r_end[j] - r0[j]
            past = np.sign(change) * (steps[lab].to_numpy() - r_end[j]) if change else np.zeros(1)
            out[f"overshoot_{lab}"] = float(max(0.0, np.nanmax(past)))
            if change:
                out[f"overshoot_{lab}_pct"] = 100.0 * out[f"overshoot_{lab}"] / abs(change)
        U = record.controller_steps(steps)[list(plant.inputs)].to_numpy(dtype=float)
        span = plant.u_ub - plant.u_lb
        if len(U) > 1:
            jump = np.abs(np.diff(U, axis=0)).max(axis=0)
            for lab, v in zip(plant.inputs, jump, strict=True):
                out[f"input_jump_max_{lab}"] = float(v)
            rel = jump / np.where(np.isfinite(span), span, np.inf)
            out["input_jump_max_rel"] = float(rel.max())
        excess = np.maximum(U - plant.u_ub, plant.u_lb - U)
        out["input_bound_excess"] = float(max(0.0, np.nanmax(excess))) if len(U) else 0.0
        return out
