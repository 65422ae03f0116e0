"""Agreement on the Zumo NMPC: each backend's plan scored by the controller's own NLP at
recorded and perturbed states, against a multi-start tight IPOPT reference.

    uv run python experiments/agreement/zumo_nlp.py                  # zumo_bug2, dead end
    uv run python experiments/agreement/zumo_nlp.py --perturbed 1 --states 3   # smaller
    uv run python experiments/agreement/zumo_nlp.py --nn-weights PATH         # another net
    uv run python experiments/agreement/zumo_nlp.py scenario=zumo_random seed=94 \
        controller.collision_distance=0.065 --sampler controller.collision_distance=0

**States.** One closed loop of the experiment (``--experiment``, default ``zumo_bug2``,
``sim=nominal``; ``--sampler`` adds overrides for this run only) gives the states. Its step
log is replayed through the loop's own ``sense`` (range sensor on the scenario's world,
supervisor), so each state comes with the detections, ranges and BUG2 mode it had in the
run, and with the run's previous plan (the applied input the rate term reads, the backends'
warm start). ``--states`` steps are taken per BUG2 mode, evenly spread, and the
``--closest`` steps nearest an obstacle. At each, ``--perturbed`` more states add seeded
Gaussian noise to the pose (``--sigma``; redrawn if the robot would touch an obstacle),
sensed and supervised afresh from the supervisor's state at that step.

**Backends** (``BACKENDS``): the experiment composed with ``controller=casadi_fatrop``,
``casadi`` (IPOPT), ``casadi_sqp_capped`` (SQP truncated at ``sqp_iterations``; ``truncated`` when
it stops there) and ``nn`` (the net in ``--nn-weights``). Each is reset at the state, given
the run's previous plan and called once through ``controller.step``.

**One cost.** The NLP is the one the IPOPT backend poses at that state (whatever the composed
objective, constraints, supervisor mode and detections make it), read from the controller
(:func:`posed_nlp`). A plan's cost is that NLP's objective at the plan's inputs, its states
rolled out through the plant's step from the state (variables a plan does not give, such as
slacks, are minimized with the plan held); ``viol`` is its largest constraint or bound
violation. The reference is IPOPT on the same NLP at tol 1e-10 (acceptable 1e-8) from
several starts: the run's previous plan shifted (``warm``), the configured cold-start input,
zero input, ``--random`` uniform random inputs and every backend's plan; the best
converged start is kept, and a feasible backend plan cheaper than it replaces it
(``below_ref``). The net predicts no plan: its first move is scored by the NLP's optimum
with the first input held at that move.
"""

from __future__ import annotations

import argparse
import copy
import sys
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))
from nlp_score import REF_FEAS, SAME, VIOL_FLAG, NlpScorer, posed_nlp  # noqa: E402

from mpclab.config.instantiate import build  # noqa: E402
from mpclab.controllers.base import Controller, ControlStep, StepContext, input_vector  # noqa: E402
from mpclab.core.status import SolveStatus  # noqa: E402
from mpclab.record import files as record  # noqa: E402
from mpclab.record.provenance import stamp  # noqa: E402
from mpclab.runner.loop import Run, sense, simulate  # noqa: E402
from mpclab.runner.single_run import build_run, compose  # noqa: E402

#: backend label -> overrides on top of the experiment
BACKENDS: dict[str, list[str]] = {
    "fatrop": ["controller=casadi_fatrop"],
    "ipopt": ["controller=casadi"],
    "sqp_capped3": ["controller=casadi_sqp_capped", "controller.solve.sqp_iterations=3"],
}
NN_WEIGHTS = ROOT / "conf/weights/zumo_nn.npz"
QUIET = ["recorder=none", "progress=false", "figures.enabled=false", "sim=nominal"]


@dataclass
class Sample:
    """One state to score: what the controller is given there, and the run's previous plan."""

    kind: str  # "recorded" or "perturbed"
    step: int
    t: float
    x: np.ndarray
    ctx: StepContext
    prev: ControlStep | None


def with_previous(ctrl: Controller, x: np.ndarray, prev: ControlStep | None) -> None:
    """Reset ``ctrl`` at ``x`` and give it the run's previous plan (applied input, warm
    start), as if it had made it."""
    ctrl.reset(x)
    if prev is not None:
        ctrl._plan = replace(prev)


def record_samples(run: Run, steps: pd.DataFrame, horizons: pd.DataFrame, per_mode: int,
                   perturbed: int, sigma: np.ndarray, seed: int,
                   closest: int = 0) -> list[Sample]:
    """Recorded states (``per_mode`` steps per supervisor mode, evenly spread, and the
    ``closest`` steps nearest an obstacle) and ``perturbed`` noisy copies of each, with what
    the loop would give the controller."""
    plant, scen = run.plant, run.scenario
    calls = record.controller_steps(steps).reset_index(drop=True)
    X = calls[list(plant.states)].to_numpy(dtype=float)
    U = calls[list(plant.inputs)].to_numpy(dtype=float)
    ks: set[int] = set()
    for _, idx in calls.groupby("mode", sort=False).groups.items():
        idx = np.asarray(sorted(idx))
        ks |= {int(idx[i]) for i in np.linspace(0, len(idx) - 1, min(per_mode, len(idx)))
               .round().astype(int)}
    if closest and "clearance_m" in calls:  # where the obstacles matter most
        ks |= {int(k) for k in calls["clearance_m"].nsmallest(closest).index}
    rng = np.random.default_rng(seed)
    ipose = [plant.state_index(s) for s in (*plant.position, plant.heading)]
    run.supervisor.reset(scen.x0, scen.goal)
    out = []
    for k in range(max(ks) + 1):
        t = float(calls["t"].iloc[k])
        prev = _previous(plant, horizons, U, k)
        if k in ks:
            for _ in range(perturbed):
                xp = _perturbed(scen, X[k], ipose, sigma, rng)
                fresh = replace(run, supervisor=copy.deepcopy(run.supervisor))
                out.append(Sample("perturbed", k, t, xp, sense(fresh, t, xp), prev))
        ctx = sense(run, t, X[k])  # advances the supervisor as the run did
        if ctx.mode != calls["mode"].iloc[k]:
            raise RuntimeError(f"replay: step {k} mode {ctx.mode!r}, the run had "
                               f"{calls['mode'].iloc[k]!r}")
        if k in ks:
            out.append(Sample("recorded", k, t, X[k], ctx, prev))
    return out


def _previous(plant: Any, horizons: pd.DataFrame, U: np.ndarray, k: int) -> ControlStep | None:
    if k == 0:
        return None
    hz = horizons[horizons["step"] == k - 1]
    Xp = hz[list(plant.states)].to_numpy(dtype=float)
    Up = hz[list(plant.inputs)].to_numpy(dtype=float)[:-1]
    return ControlStep(u=U[k - 1].copy(), x_pred=Xp, u_pred=Up, status=SolveStatus.converged)


def _perturbed(scen: Any, x: np.ndarray, ipose: list[int], sigma: np.ndarray,
               rng: np.random.Generator) -> np.ndarray:
    for _ in range(100):
        xp = x.copy()
        xp[ipose] += rng.normal(0.0, sigma)
        if not scen.collided(xp):
            return xp
    raise RuntimeError(f"no perturbed state clear of the obstacles near {x}")


def compare(experiment: str = "zumo_bug2", extra: list[str] | None = None, per_mode: int = 6,
            perturbed: int = 3, sigma: tuple[float, float, float] = (0.01, 0.01, 0.1),
            n_random: int = 3, seed: int = 0, nn_weights: Path | None = NN_WEIGHTS,
            backends: list[str] | None = None, closest: int = 0,
            sampler: list[str] | None = None) -> pd.DataFrame:
    """One row per (state, backend) and one per state for the reference: module docstring.

    ``extra``: overrides of the experiment; ``sampler``: more overrides for the run that
    gives the states only, e.g. ``controller.collision_distance=0``: the states of an
    unconstrained run scored on the constrained NLP."""
    base = [f"+experiment={experiment}", *(extra or []), *QUIET]
    run = build_run(compose([*base, *(sampler or [])]))
    res = simulate(run)
    samples = record_samples(run, res.steps, res.horizons, per_mode, perturbed,
                             np.asarray(sigma), seed, closest)
    names = [b for b in BACKENDS if backends is None or b in backends]
    ctrls = {b: build_run(compose([*base, *BACKENDS[b]])).controller for b in names}
    ref_ctrl = ctrls.get("ipopt") or build_run(compose([*base, *BACKENDS["ipopt"]])).controller
    if nn_weights is not None and (backends is None or "nn" in backends):
        # the net's own experiment for its controller's config (the NMPC's horizon and
        # initial input are not its options); plant and sensor are the run's
        nn_cfg = compose(["+experiment=zumo_nn", f"controller.weights={nn_weights}", *QUIET])
        ctrls["nn"] = build(nn_cfg.controller, "controller", plant=run.plant,
                            scenario=run.scenario)
    cold = input_vector(run.plant, compose(base).controller.get("initial_input"),
                        "controller.initial_input")
    plant, T, dt = ref_ctrl.plant, ref_ctrl.horizon, ref_ctrl.dt
    span = np.where(np.isfinite(plant.u_ub - plant.u_lb), plant.u_ub - plant.u_lb, 1.0)
    rng = np.random.default_rng(seed + 1)
    lo = np.where(np.isfinite(plant.u_lb), plant.u_lb, -1.0)
    hi = np.where(np.isfinite(plant.u_ub), plant.u_ub, 1.0)
    scorers: dict[int, NlpScorer] = {}
    rows = []
    for s in samples:
        plans = {}
        for b, c in ctrls.items():
            with_previous(c, s.x, s.prev)
            plans[b] = c.step(s.t, s.x, s.ctx)
        with_previous(ref_ctrl, s.x, s.prev)
        u_prev = ref_ctrl.previous_input.copy()
        if "ipopt" not in ctrls:
            ref_ctrl.step(s.t, s.x, s.ctx)
        ocp, p = posed_nlp(ref_ctrl)
        sc = scorers.get(id(ocp)) or scorers.setdefault(id(ocp), NlpScorer(ocp, plant, dt))
        starts = {"cold": np.tile(cold, (T, 1)), "zero": np.zeros((T, plant.nu))}
        if s.prev is not None:
            starts["warm"] = np.vstack([s.prev.u_pred[1:], s.prev.u_pred[-1:]])
        for i in range(n_random):  # inside the bounds (in [-1, 1] where unbounded)
            starts[f"random{i}"] = rng.uniform(lo, hi, (T, plant.nu))
        starts |= {b: r.u_pred for b, r in plans.items() if r.ok and len(r.u_pred) == T}
        ref = sc.reference(s.x, u_prev, p, starts)
        at = {"kind": s.kind, "step": s.step, "t": s.t, "mode": s.ctx.mode,
              "n_detections": len(s.ctx.detections)}
        scored = {}
        for b, r in plans.items():
            if len(r.u_pred) == T:
                J, viol = sc.cost(s.x, r.u_pred, u_prev, p)
            else:  # no plan (the net): the NLP's best with the first move held at its move
                nn = sc.reference(s.x, u_prev, p, {"ref": ref["u_pred"], **starts}, u0=r.u)
                J, viol = nn["cost"], nn["viol"]
                if not np.isfinite(J):  # IPOPT's word on the held move: e.g. infeasible
                    print(f"{s.kind} step {s.step}: {b}'s first move has no converged "
                          f"continuation: {sorted(set(nn['failed'].values()))}", file=sys.stderr)
            scored[b] = (J, viol)
        # a backend plan cheaper than every IPOPT start, as feasible: the reference takes it
        beaten = {b: J for b, (J, v) in scored.items()
                  if v <= REF_FEAS and J < ref["cost"] - SAME * max(abs(ref["cost"]), 1.0)}
        ref_cost = min([ref["cost"], *beaten.values()])
        scale = max(abs(ref_cost), 1.0)
        spread = max(ref["costs"].values()) - ref["cost"]
        worse = sum(J > ref["cost"] + SAME * scale for J in ref["costs"].values())
        rows.append(at | {"backend": "reference", "status": "converged", "cost": ref_cost,
                          "gap": 0.0, "du0": 0.0, "viol": ref["viol"],
                          "ref_start": ref["start"], "starts_converged":
                          f"{len(ref['costs'])}/{ref['tried']}", "worse_optima": worse,
                          "active_ineq": ref["active"],
                          "local_spread": spread / scale})
        for b, r in plans.items():
            J, viol = scored[b]
            rows.append(at | {
                "backend": b, "status": str(r.status), "iterations": r.iterations,
                "cost": J, "gap": (J - ref_cost) / scale,
                "du0": float(np.max(np.abs(r.u - ref["u_pred"][0]) / span)),
                "viol": viol, "flagged": not viol <= VIOL_FLAG, "below_ref": b in beaten,
                # the backend's own objective value against this scoring of its plan: the
                # same NLP, so equal up to the solver's tolerance (no own value: the net)
                "own_cost_err": (r.cost - J) / scale,
            })
    return pd.DataFrame(rows)


def summarize(df: pd.DataFrame) -> pd.DataFrame:
    """Per backend: states, converged fraction, statuses, gaps, first-move difference,
    violations, and how often it beat the multi-start reference."""
    g = df.groupby("backend", sort=False)
    out = pd.DataFrame({
        "states": g.size(),
        "converged": g["status"].agg(lambda s: float((s == "converged").mean())),
        "gap_min": g["gap"].min(), "gap_median": g["gap"].median(), "gap_max": g["gap"].max(),
        "du0_max": g["du0"].max(), "viol_max": g["viol"].max(),
    })
    if "flagged" in df:
        out["flagged"] = g["flagged"].agg(lambda s: int(s.fillna(False).astype(bool).sum()))
        out["below_ref"] = g["below_ref"].agg(lambda s: int(s.fillna(False).astype(bool).sum()))
    out["statuses"] = g["status"].agg(
        lambda s: ", ".join(f"{k} {v}" for k, v in s.value_counts().items()))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--experiment", default="zumo_bug2")
    ap.add_argument("--states", type=int, default=6, help="recorded states per BUG2 mode")
    ap.add_argument("--perturbed", type=int, default=3, help="perturbed states per recorded one")
    ap.add_argument("--closest", type=int, default=3,
                    help="also the steps nearest an obstacle (clearance), this many")
    ap.add_argument("--sampler", action="append", default=[], metavar="OVERRIDE",
                    help="more overrides for the run that gives the states only (repeat)")
    ap.add_argument("--random", type=int, default=3, help="random starts of the reference")
    ap.add_argument("--seed", type=int, default=0, help="of the perturbations and random starts")
    ap.add_argument("--sigma", type=float, nargs=3, default=(0.01, 0.01, 0.1),
                    metavar=("X", "Y", "THETA"), help="pose noise [m, m, rad]")
    ap.add_argument("--nn-weights", type=Path, default=NN_WEIGHTS,
                    help="the net's weights (.npz); 'none' to leave the net out")
    ap.add_argument("--csv", type=Path, default=None, help="write the per-state rows here")
    ap.add_argument("overrides", nargs="*", help="more overrides of the experiment")
    args = ap.parse_args()
    weights = None if str(args.nn_weights) == "none" else args.nn_weights
    if weights is not None and not weights.exists():
        print(f"no weights at {weights}: the net is left out", file=sys.stderr)
        weights = None
    df = compare(args.experiment, args.overrides, args.states, args.perturbed, tuple(args.sigma),
                 n_random=args.random, seed=args.seed, nn_weights=weights,
                 closest=args.closest,
                 sampler=args.sampler)
    pd.set_option("display.width", 200)
    pd.set_option("display.max_columns", 20)
    cols = ["kind", "step", "mode", "backend", "status", "cost", "gap", "du0", "viol",
            "own_cost_err", "ref_start", "starts_converged", "worse_optima", "active_ineq"]
    print(df[[c for c in cols if c in df]].to_string(
        index=False, float_format=lambda v: f"{v:.4g}"))
    print(f"\n## {args.experiment}: summary\n")
    print(summarize(df).to_markdown(floatfmt=".3g"))
    for mode, part in df.groupby("mode", sort=False):
        print(f"\n### mode {mode}\n")
        print(summarize(part).to_markdown(floatfmt=".3g"))
    ref = df[df.backend == "reference"]
    print(f"\nreference: {int((ref.worse_optima > 0).sum())} of {len(ref)} states with a worse "
          f"local optimum among the starts; {int((ref.active_ineq > 0).sum())} with an active "
          "inequality constraint")
    print(f"\n{stamp()}")
    if args.csv:
        df.to_csv(args.csv, index=False)


if __name__ == "__main__":
    main()
