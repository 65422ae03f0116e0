"""The closed loop: measure -> sense -> supervise -> control -> integrate -> log.

:func:`simulate` is the only place where simulated time advances. It times only the
controller call, stops on arrival, collision, stall, time-out or error, and returns the step
log as tidy tables plus the summary every run record holds. How the simulated world differs
from the controller's model (latency, noise, disturbance, plant parameters) is the run's
:class:`~mpclab.world.sim_world.SimWorld`; without one the loop is the ideal one.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd

from mpclab.controllers.base import FEEDBACK_KEY, Controller, ControlStep, StepContext
from mpclab.core.signals import interrupted, received, stopped_by
from mpclab.core.status import SOLVE_KEYS, USABLE, SolveStatus
from mpclab.plants.base import Plant
from mpclab.record import files as record
from mpclab.recorders.base import Recorder
from mpclab.supervisors.base import NoSupervisor, Supervisor
from mpclab.world.clearance import ContinuousClearance
from mpclab.world.margin import MarginBudget
from mpclab.world.scenario import Scenario
from mpclab.world.sim_world import SimWorld, Timing

#: run statuses, in the run record's ``status`` field; ``solver_failed``: the run did not
#: arrive and no controller call gave a usable solve (every input applied was a fallback);
#: ``interrupted``: stopped by Ctrl-C (the record holds the steps until then)
STATUSES = ("arrived", "stalled", "timeout", "collision", "error", "solver_failed",
            "interrupted")
#: the controller call's CPU time (this thread), beside its wall time ``solve_time_s``
CPU_COLUMN = "solve_cpu_s"
#: the CPU time of a step's sensing and the supervisor's decision (its map, its plan)
SENSE_CPU_COLUMN = "sense_cpu_s"
#: the least clearance over the period from a row's ``t`` to the next (continuous time)
PATH_CLEARANCE = "clearance_path_m"


class RunInterrupted(KeyboardInterrupt):
    """Ctrl-C (or SIGTERM, SIGHUP) during :func:`simulate`, carrying the partial result
    (status ``interrupted``)."""

    def __init__(self, result: RunResult, how: str = "Ctrl-C") -> None:
        super().__init__("interrupted")
        self.result = result
        #: what stopped it: ``Ctrl-C`` or the signal's name
        self.how = how


@dataclass
class Run:
    """The objects one closed-loop run is made of (built from config by ``experiment``)."""

    plant: Plant
    controller: Controller
    scenario: Scenario
    supervisor: Supervisor = field(default_factory=NoSupervisor)
    recorder: Recorder = field(default_factory=Recorder)
    world: SimWorld | None = None  # None: the ideal loop (sim=nominal)
    #: the obstacle margin kept (mpclab.world.margin), None where nothing keeps one
    margin: MarginBudget | None = None
    #: why the margin left no way to the goal, for a run made anyway (no_room=run)
    no_room: str | None = None
    #: what keeps the margin: the obstacle constraint, else the safety filter (its
    #: ``distance``, derived or ``stated``)
    keeper: Any = None


@dataclass
class RunResult:
    steps: pd.DataFrame
    horizons: pd.DataFrame
    summary: dict[str, Any]


def simulate(run: Run, progress: Callable[[float, float], None] | None = None) -> RunResult:
    """Run the closed loop until arrival, collision, stall, time-out or error.

    Parameters
    ----------
    run
        Plant, controller, scenario, supervisor and recorder.
    progress
        Called as ``progress(t, t_max)`` after every step (for a progress bar).
    """
    plant, ctrl, scen, sup, rec = (
        run.plant, run.controller, run.scenario, run.supervisor, run.recorder
    )
    dt, H = ctrl.dt, ctrl.horizon
    world = run.world or SimWorld(plant, dt=dt)
    world.reset(plant.nu)
    x = scen.x0.copy()  # the true state
    ctrl.reset(x)
    # the arrival rule the supervisor sees: with an EKF, with the estimate's doubt to spare
    sup.reset(x, scen.goal, scen.arrived if world.ekf is None
              else lambda xm: scen.arrived(xm, world.arrival_doubt()))
    board_time = world.board_time(ctrl)  # sim.latency=modelled: the controller's model
    log = _StepLog(plant, H, (CPU_COLUMN, SENSE_CPU_COLUMN, *ctrl.log_columns), world, dt)
    # the closest approach between samples, along the path the simulated plant drives
    guard = ContinuousClearance(world.plant, scen.obstacles, scen.robot_radius)
    status, error, k, touched = "error", None, 0, False
    n_max = int(np.floor(scen.t_max / dt + 1e-9))
    rec.start(run)
    try:
        while True:
            t = k * dt
            if (stop := received()) is not None:  # a stop signal whose interrupt was lost
                raise stop  # where it was raised (a __del__ the garbage collector ran, a
                #             native callback that drops errors): taken here, a step late
            if touched or scen.collided(x):  # before arrival: touching on the way fails
                status = "collision"
                break
            if scen.arrived(x):
                status = "arrived"
                break
            if scen.stalled(log.t, log.xs):
                status = "stalled"
                break
            if k >= n_max:
                status = "timeout"
                break
            measured = world.measure(x)
            s0 = time.thread_time()
            ctx = sense(run, t, x, measured)
            sense_cpu = time.thread_time() - s0
            # what acts until this step's input does, and when that is expected
            ctx.applied, ctx.latency_s = world.applied, world.expected_latency_s()
            ctx.predict = world.predicts
            mode = ctx.mode
            c0, t0 = time.thread_time(), time.perf_counter()
            cs = ctrl.step(t, measured, ctx)
            solve_time = time.perf_counter() - t0
            timing = world.timing(cs.u, cs.u_pred, cs.info.get(FEEDBACK_KEY, solve_time),
                                  None if board_time is None else board_time(cs))
            ctrl.received(timing.applied)  # the input-rate term's previous input
            cs.info["solve_time_s"] = solve_time  # recorders see it with the step
            cs.info[CPU_COLUMN] = time.thread_time() - c0  # unlike wall time, not inflated
            # when other processes take the core (parallel sweeps)
            cs.info[SENSE_CPU_COLUMN] = sense_cpu
            if world.estimated:  # noise or odometry: what the robot believed
                cs.info["x_measured"] = measured
            if world.delayed:
                cs.info["latency_s"] = timing.latency_s
            path_gap = guard.interval(x, world.pieces(timing))
            touched = path_gap < 0
            log.add(t, x, cs, solve_time, mode, (scen.clearance(x), path_gap), measured,
                    timing)
            rec.log_step(k, t, x, cs, ctx)
            x = world.advance(x, timing)
            k += timing.periods  # more than one: the board was busy (late_apply)
            if not np.all(np.isfinite(x)):
                raise FloatingPointError(f"state became non-finite at t={k * dt:.3f}: {x}")
            if progress is not None:
                progress(k * dt, scen.t_max)
    except (Exception, KeyboardInterrupt) as exc:  # the record is still written
        # Ctrl-C, SIGTERM/SIGHUP (mpclab.core.signals.Terminated), or one of them handed back
        # by native code (a solver, CasADi's numpy conversion) as an error of its own
        stop = exc if isinstance(exc, KeyboardInterrupt) else interrupted(exc)
        if stop is None:
            status, error = "error", f"{type(exc).__name__}: {exc}"
        else:
            by = stopped_by(stop)
            status, error = "interrupted", f"KeyboardInterrupt ({by})"
    t_end = k * dt
    log.final(t_end, x, scen.clearance(x))
    steps, horizons = log.tables()
    summary = (_summary(steps, status, error, t_end, scen) | _world_summary(steps, world)
               | _clearance_summary(steps, guard))
    rec.finish(x, t_end, summary)
    result = RunResult(steps, horizons, summary)
    if status == "interrupted":
        raise RunInterrupted(result, by)
    return result


def sense(run: Run, t: float, x: np.ndarray, measured: np.ndarray | None = None) -> StepContext:
    """What the controller is given at ``(t, x)``: sensor readings, the supervisor's choice
    of objective terms (its state advances) and the target over the horizon (the
    supervisor's, if it sets one this step, else the scenario's).

    ``x`` is the true state the sensor sees the world from; ``measured`` (default ``x``) the
    state the robot believes it is in: detected points are placed from it, and the
    supervisor decides on it. The world's range noise, if any, is added to the readings.
    """
    scen, ctrl = run.scenario, run.controller
    measured = x if measured is None else measured
    perturb = None if run.world is None else run.world.perturb_ranges
    detections, ranges = scen.sense(x, believed=measured, perturb=perturb)
    mode, active = run.supervisor.update(t, measured, detections)
    target = run.supervisor.target(t, ctrl.horizon, ctrl.dt)
    return StepContext(
        goal=scen.goal,
        target=scen.target(t, ctrl.horizon, ctrl.dt) if target is None else target,
        detections=detections,
        ranges=ranges, active=active, mode=mode,
    )


class _StepLog:
    """Accumulates one row per controller call (plus the final state) and every horizon."""

    def __init__(
        self, plant: Plant, horizon: int, extra: tuple[str, ...] = (),
        world: SimWorld | None = None, dt: float = 0.0,
    ) -> None:
        self.plant = plant
        self.horizon = horizon
        self.dt = dt  # the control period, between a horizon's nodes
        #: what the world adds to the log: the measured state, the input's timing, the
        #: actuators' output
        self.world = world
        self.estimated = world is not None and world.estimated
        self.delayed = world is not None and world.delayed
        self.actuated = world is not None and world.actuated
        self.measured: list[np.ndarray] = []
        self.timing: list[Timing] = []
        self.actual: list[np.ndarray] = []
        self.extra: dict[str, list[Any]] = {key: [] for key in extra}
        self.t: list[float] = []
        self.xs: list[np.ndarray] = []
        self.us: list[np.ndarray] = []
        self.meta: list[tuple[float, str, bool, str, float, float, str, float]] = []
        self.path_gap: list[float] = []
        self.x_pred: list[np.ndarray] = []
        self.u_pred: list[np.ndarray] = []

    def add(
        self, t: float, x: np.ndarray, cs: ControlStep, solve_time: float, mode: str,
        clearance: tuple[float, float], measured: np.ndarray | None = None,
        timing: Timing | None = None,
    ) -> None:
        """``clearance``: at ``t``, and the least over the period that starts at ``t``."""
        if self.estimated:
            self.measured.append(np.asarray(measured, dtype=float).copy())
        if self.delayed:
            self.timing.append(timing)
        if self.actuated:
            self.actual.append(self.world.actuator.output.copy())
        self.t.append(t)
        self.xs.append(x.copy())
        self.us.append(np.asarray(cs.u, dtype=float).copy())
        iters = np.nan if cs.iterations is None else float(cs.iterations)
        self.meta.append((solve_time, str(cs.status), cs.fallback, mode, cs.cost, clearance[0],
                          cs.solver_status, iters))
        self.path_gap.append(clearance[1])
        self.x_pred.append(np.asarray(cs.x_pred, dtype=float))
        self.u_pred.append(np.asarray(cs.u_pred, dtype=float))
        for key, values in self.extra.items():
            values.append(cs.info.get(key))

    def final(self, t: float, x: np.ndarray, clearance: float) -> None:
        self.t.append(t)
        self.xs.append(x.copy())
        self.us.append(np.full(self.plant.nu, np.nan))
        self.meta.append((np.nan, record.FINAL, False, "", np.nan, clearance, "", np.nan))
        self.path_gap.append(np.nan)
        for values in self.extra.values():
            values.append(None)

    def tables(self) -> tuple[pd.DataFrame, pd.DataFrame]:
        p = self.plant
        n = len(self.t)
        steps = pd.DataFrame({"step": np.arange(n), "t": np.asarray(self.t)})
        xs, us = np.asarray(self.xs), np.asarray(self.us)
        for i, label in enumerate(p.states):
            steps[label] = xs[:, i]
        for j, label in enumerate(p.inputs):
            steps[label] = us[:, j]
        solve, status, fallback, mode, cost, clearance, raw, iters = zip(*self.meta, strict=True)
        steps["solve_time_s"] = np.asarray(solve, dtype=float)
        steps["status"] = pd.Series(status, dtype="string")
        steps["fallback"] = np.asarray(fallback, dtype=bool)
        steps["mode"] = pd.Series(mode, dtype="string")
        steps["cost"] = np.asarray(cost, dtype=float)
        steps["clearance_m"] = np.asarray(clearance, dtype=float)
        steps[PATH_CLEARANCE] = np.asarray(self.path_gap, dtype=float)
        steps["solver_status"] = pd.Series(raw, dtype="string")
        steps["iterations"] = np.asarray(iters, dtype=float)  # NaN: the solver has no count
        for key, values in self.extra.items():
            steps[key] = pd.Series(values)
        self._world_columns(steps)
        return steps, self._horizons()

    def _world_columns(self, steps: pd.DataFrame) -> None:
        """The state the controller saw (``meas_<label>``: with noise or odometry), under
        latency when each input acted: ``latency_s``, ``deadline_miss``, ``switch_t`` (NaN:
        never) and the input in effect after it (``applied_<label>``), and with actuators
        their output at the row's time (``actual_<label>``; the commanded input is
        ``<label>``). NaN in the final row."""
        p, n = self.plant, len(self.t)

        def padded(values: list[Any], width: int) -> np.ndarray:
            out = np.full((n, width), np.nan)
            if values:
                out[: len(values)] = np.asarray(values, dtype=float).reshape(len(values), width)
            return out

        if self.estimated:
            meas = padded(self.measured, p.nx)
            for i, label in enumerate(p.states):
                steps[f"meas_{label}"] = meas[:, i]
        if self.delayed:
            lat = padded([tm.latency_s for tm in self.timing], 1)[:, 0]
            miss = np.zeros(n, dtype=bool)
            miss[: len(self.timing)] = [tm.missed for tm in self.timing]
            steps["latency_s"] = lat
            steps["deadline_miss"] = miss
            switch = padded([tm.switch_s for tm in self.timing], 1)[:, 0]
            steps["switch_t"] = steps["t"].to_numpy() + switch
            applied = padded([tm.applied for tm in self.timing], p.nu)
            for j, label in enumerate(p.inputs):
                steps[f"applied_{label}"] = applied[:, j]
        if self.actuated:
            actual = padded(self.actual, p.nu)
            for j, label in enumerate(p.inputs):
                steps[f"actual_{label}"] = actual[:, j]

    def _horizons(self) -> pd.DataFrame:
        p, H = self.plant, self.horizon
        m = len(self.x_pred)
        if m == 0:
            cols = ["step", "k", "t"] + list(p.states) + list(p.inputs)
            return pd.DataFrame({c: pd.Series(dtype=float) for c in cols})
        X = np.stack(self.x_pred)  # (m, H+1, nx)
        U = np.concatenate([np.stack(self.u_pred), np.full((m, 1, p.nu), np.nan)], axis=1)
        dt = self.dt
        step = np.repeat(np.arange(m), H + 1)
        k = np.tile(np.arange(H + 1), m)
        hz = pd.DataFrame({"step": step, "k": k, "t": np.asarray(self.t[:m])[step] + k * dt})
        for i, label in enumerate(p.states):
            hz[label] = X[:, :, i].ravel()
        for j, label in enumerate(p.inputs):
            hz[label] = U[:, :, j].ravel()
        return hz


def solve_counts(status: pd.Series) -> dict[SolveStatus, int]:
    """How many controller calls ended in each :class:`SolveStatus` (every status, zeros too)."""
    seen = status.value_counts()
    return {st: int(seen.get(str(st), 0)) for st in SolveStatus}


def _summary(
    steps: pd.DataFrame, status: str, error: str | None, t_end: float, scen: Scenario
) -> dict[str, Any]:
    calls = record.controller_steps(steps)
    solve = calls["solve_time_s"].to_numpy()
    cpu = pd.to_numeric(calls[CPU_COLUMN], errors="coerce").to_numpy(dtype=float)
    sensing = pd.to_numeric(calls[SENSE_CPU_COLUMN], errors="coerce").to_numpy(dtype=float)
    total = float(solve.sum())
    ms = solve * 1e3
    counts = solve_counts(calls["status"])
    failures = int(sum(n for st, n in counts.items() if st not in USABLE))
    iters = calls["iterations"].dropna().to_numpy()
    if status in ("stalled", "timeout", "collision") and len(calls) and failures == len(calls):
        status = "solver_failed"  # what ended the run was a controller that never solved
        error = error or f"no usable solve in {len(calls)} controller calls"
    return {
        "status": status,
        "arrived": status == "arrived",
        "arrival_time_s": round(t_end, 9) if status == "arrived" else None,
        "n_steps": int(len(calls)),
        "sim_time_s": round(t_end, 9),
        "compute_total_s": total,
        "compute_median_ms": float(np.median(ms)) if len(ms) else None,
        "compute_p95_ms": float(np.percentile(ms, 95)) if len(ms) else None,
        "compute_max_ms": float(ms.max()) if len(ms) else None,
        "rtf": total / t_end if t_end > 0 else None,
        "compute_cpu_total_s": float(np.nansum(cpu)),
        "compute_cpu_median_ms": float(np.nanmedian(cpu) * 1e3) if len(cpu) else None,
        # CPU over wall time of the controller calls: about 1 on an idle core, lower when
        # the process waited for a core (a loaded machine) and its wall times are inflated
        "compute_cpu_share": float(np.nansum(cpu) / total) if total > 0 else None,
        # sensing and the supervisor, outside the controller call (a planner's search)
        "sense_cpu_median_ms": float(np.nanmedian(sensing) * 1e3) if len(sensing) else None,
        "sense_cpu_p95_ms": float(np.nanpercentile(sensing, 95) * 1e3) if len(sensing) else None,
        "solver_failures": failures,
        "converged_fraction": counts[SolveStatus.converged] / len(calls) if len(calls) else None,
        **{SOLVE_KEYS[st]: n for st, n in counts.items()},
        "iterations_median": float(np.median(iters)) if len(iters) else None,
        "iterations_max": int(iters.max()) if len(iters) else None,
        "final_state": dict(zip(scen.plant.states, steps.iloc[-1][list(scen.plant.states)]
                                .astype(float), strict=True)),
        "error": error,
    }


def _clearance_summary(steps: pd.DataFrame, guard: ContinuousClearance) -> dict[str, Any]:
    """``min_clearance_m`` in continuous time: the least of the sampled clearances and of
    every period's path (``None`` without obstacles); the sampled least beside it, and how
    far the path's could lie above the exact one (0: exact arcs)."""
    sampled = steps["clearance_m"].to_numpy(dtype=float)
    both = np.concatenate([sampled, steps[PATH_CLEARANCE].to_numpy(dtype=float)])
    if not np.isfinite(both).any():
        return {"min_clearance_m": None, "min_clearance_sampled_m": None,
                "min_clearance_tol_m": None}
    return {"min_clearance_m": float(np.nanmin(both)),
            "min_clearance_sampled_m": (float(np.nanmin(sampled))
                                        if np.isfinite(sampled).any() else None),
            "min_clearance_tol_m": guard.tolerance_m}


def _world_summary(steps: pd.DataFrame, world: SimWorld) -> dict[str, Any]:
    """The world the run was simulated in, and how often an input came too late."""
    out: dict[str, Any] = world.describe()
    if "latency_s" in steps:
        lat = steps["latency_s"].dropna().to_numpy() * 1e3
        out |= {"deadline_misses": int(steps["deadline_miss"].sum()),
                "latency_median_ms": float(np.median(lat)) if len(lat) else None,
                "latency_max_ms": float(lat.max()) if len(lat) else None}
    else:
        out |= {"deadline_misses": 0, "latency_median_ms": None, "latency_max_ms": None}
    return out
