"""Cross-backend agreement: the same OCP solved by every backend that can express it, each
plan scored by ONE cost function against a tight-tolerance IPOPT reference.

    uv run python experiments/agreement/agreement.py                  # car and bicycle
    uv run python experiments/agreement/agreement.py --case car
    uv run python experiments/agreement/agreement.py --case bicycle --dt 0.05
    uv run python experiments/agreement/agreement.py --warm           # in each own closed loop
    uv run python experiments/agreement/agreement.py --case bicycle --control-horizon 3
    uv run python experiments/agreement/agreement.py --override cvxpy:controller.sl=one_pass

The Zumo NMPC (its NLP with detections, per BUG2 mode) has its own script, ``zumo_nlp.py``.

For each case a closed loop gives a few plausible states (with the scenario's target at that
time). At each state every backend is reset (cold start: no previous plan, previous input 0)
and called once through ``controller.step``, as the runner calls it. With ``--warm`` each
backend instead runs its own closed loop (warm-started from its previous plan, as in a run)
and is scored at its own states at those steps. Its input sequence
``u_pred`` is then rolled out through the plant's own nonlinear step from the state, and the
objective is evaluated on that rollout in CasADi (``true_cost``): the backend's own
``cost`` (on its own prediction model) is not used to compare. The reference solves the same
OCP (plant, objective, bounds, terminal constraint, horizon, dt) with its own multiple-
shooting IPOPT NLP at tol 1e-10, started from a zero-input rollout and from every backend's
plan, keeping the best feasible. For control-horizon-1 backends (the scheduled controller) a
second reference solves the same OCP with the input held over the horizon; with
``--control-horizon`` every backend is blocked so (``controller.control_horizon``) and the
second reference solves the OCP under the same blocking (:mod:`mpclab.controllers.blocking`).

Columns: ``gap`` = (true_cost - ref) / ref; ``gap_held`` the same against the held-input
reference; ``du0`` = max over inputs of |u0 - u0_ref| / (input range); ``viol`` = largest
violation of bounds or terminal constraint on the true rollout; ``pred_err`` = (own cost -
true_cost) / true_cost, the error of the backend's own prediction of its cost.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import casadi as ca
import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))
from mpclab.config.instantiate import build  # noqa: E402
from mpclab.controllers.base import StepContext, terminal_rows  # noqa: E402
from mpclab.controllers.blocking import Blocking  # noqa: E402
from mpclab.objectives.base import Objective, TermContext  # noqa: E402
from mpclab.plants.base import Plant  # noqa: E402
from mpclab.record.provenance import write_stamped  # noqa: E402
from mpclab.runner.loop import simulate  # noqa: E402
from mpclab.runner.single_run import build_run, compose  # noqa: E402

#: IPOPT for the reference: tight, never stopping at the "acceptable" level, many iterations
REF_OPTIONS = {
    "print_time": False, "ipopt.print_level": 0, "ipopt.sb": "yes", "ipopt.tol": 1e-10,
    "ipopt.acceptable_tol": 1e-10, "ipopt.acceptable_iter": 0, "ipopt.constr_viol_tol": 1e-10,
    "ipopt.max_iter": 5000,
}


@dataclass
class Case:
    """One plant + objective + scenario family and the backends that can express it."""

    name: str
    #: scenario -> steps of the sampling closed loop at which states are taken
    samples: dict[str, list[int]]
    #: the closed loop that gives the states (its overrides, ``{scenario}`` filled in)
    sampler: list[str]
    #: backend label -> overrides (``{scenario}`` and ``{dt}`` filled in)
    backends: dict[str, list[str]]
    #: backends whose inputs are held over the horizon (control horizon 1)
    held: tuple[str, ...] = ()
    dt: float = 0.1
    extra: list[str] = field(default_factory=list)


_BIKE = ["plant=dynamic_bicycle", "objective=bicycle_tracking", "scenario={scenario}",
         "controller.horizon=32", "controller.dt={dt}"]
CASES = {
    "car": Case(
        name="car",
        samples={"car_to_origin": [0, 3, 6, 10, 15, 20]},
        sampler=["+experiment=car_casadi"],
        backends={"casadi": ["+experiment=car_casadi"], "cvxpy": ["+experiment=car_cvxpy"]},
    ),
    "bicycle": Case(
        name="bicycle",
        # 20 ms steps: control_y_V's lane change starts at 1.0 s; the circle's heading
        # switches fall near 3.1, 9.4, 15.7, 22.0 s
        samples={"control_y_V": [25, 45, 50, 75, 150], "regular_circle_turn": [100, 157, 500],
                 "turn": [120, 250, 400]},
        sampler=["+experiment=bicycle_scheduled", "scenario={scenario}", "controller.dt={dt}"],
        backends={
            "scheduled": ["+experiment=bicycle_scheduled", "scenario={scenario}",
                          "controller.dt={dt}"],
            "interpolated": ["+experiment=bicycle_interpolated", "scenario={scenario}",
                             "controller.dt={dt}"],
            "adaptive": ["+experiment=bicycle_adaptive", "scenario={scenario}",
                         "controller.dt={dt}"],
            "cvxpy": ["controller=cvxpy", *_BIKE],
            "casadi": ["controller=casadi", *_BIKE],
        },
        held=("scheduled", "interpolated", "adaptive"),
        dt=0.02,
    ),
}
QUIET = ["recorder=none", "progress=false", "figures.enabled=false"]


def _fill(overrides: list[str], scenario: str, dt: float) -> list[str]:
    return [o.format(scenario=scenario, dt=dt) for o in overrides] + QUIET


class Scorer:
    """The true cost of an input sequence and a tight IPOPT reference, for one OCP;
    ``blocking`` is the held-input reference's (default: one move held over the horizon)."""

    def __init__(self, plant: Plant, objective: Objective, horizon: int, dt: float,
                 terminal: dict[str, float], blocking: Blocking | None = None) -> None:
        self.plant, self.T, self.dt = plant, horizon, dt
        self.blocking = blocking or Blocking.of(1, horizon)
        objective.bind(plant, "casadi")
        nx, nu, T = plant.nx, plant.nu, horizon
        self.term_rows = terminal_rows(plant, terminal)
        x0, U = ca.MX.sym("x0", nx), ca.MX.sym("U", nu, T)
        target, u_prev = ca.MX.sym("target", nx, T + 1), ca.MX.sym("u_prev", nu)
        cols = [x0]
        for k in range(T):
            cols.append(plant.F(cols[-1], U[:, k], dt))
        X = ca.horzcat(*cols)
        ctx = TermContext(x0=x0, target=target, u_prev=u_prev, goal=target[:, -1],
                          detections=ca.DM.zeros(2, 1), mask=ca.DM.zeros(1))
        cost = sum(term.casadi_cost(X, U, ctx) for term in objective)
        self._cost = ca.Function("true_cost", [x0, U, target, u_prev], [cost, X])
        self._ocp = {False: self._build_ocp(objective, None),
                     True: self._build_ocp(objective, self.blocking)}

    def true_cost(self, x0: np.ndarray, U: np.ndarray, target: np.ndarray,
                  u_prev: np.ndarray) -> tuple[float, float]:
        """``(cost of the nonlinear rollout of U (T, nu) from x0, its constraint violation)``."""
        J, X = self._cost(x0, U.T, target.T, u_prev)
        X = np.asarray(X).T
        return float(J), self.violation(X, U)

    def violation(self, X: np.ndarray, U: np.ndarray) -> float:
        p = self.plant
        v = [np.max(np.maximum(U - p.u_ub, 0.0)), np.max(np.maximum(p.u_lb - U, 0.0)),
             np.max(np.maximum(X[1:] - p.x_ub, 0.0)), np.max(np.maximum(p.x_lb - X[1:], 0.0))]
        v += [abs(X[-1, i] - value) for i, value in self.term_rows]
        return float(max(v))

    def _build_ocp(self, objective: Objective, blocking: Blocking | None) -> ca.Function:
        """Multiple shooting: variables (X, U) or (X, V), the moves V held in the blocks."""
        p, T = self.plant, self.T
        nx, nu = p.nx, p.nu
        X = ca.SX.sym("X", nx, T + 1)
        Uv = ca.SX.sym("U", nu, blocking.n_moves if blocking else T)
        U = ca.mtimes(Uv, ca.DM(blocking.matrix().T)) if blocking else Uv
        x0, target = ca.SX.sym("x0", nx), ca.SX.sym("target", nx, T + 1)
        u_prev = ca.SX.sym("u_prev", nu)
        ctx = TermContext(x0=x0, target=target, u_prev=u_prev, goal=target[:, -1],
                          detections=ca.DM.zeros(2, 1), mask=ca.DM.zeros(1))
        cost = sum(term.casadi_cost(X, U, ctx) for term in objective)
        g = [X[:, 0] - x0] + [X[:, k + 1] - p.F(X[:, k], U[:, k], self.dt) for k in range(T)]
        g += [X[i, T] - value for i, value in self.term_rows]
        nlp = {"x": ca.vertcat(ca.vec(X), ca.vec(Uv)), "f": cost, "g": ca.vertcat(*g),
               "p": ca.vertcat(x0, ca.vec(target), u_prev)}
        return ca.nlpsol("reference", "ipopt", nlp, REF_OPTIONS)

    def reference(self, x0: np.ndarray, target: np.ndarray, u_prev: np.ndarray,
                  guesses: dict[str, np.ndarray], held: bool = False) -> dict[str, Any]:
        """The best converged IPOPT solution from a zero-input rollout and from each guess
        (a backend's input sequence, by name); ``start`` names the start that won."""
        p, T, b = self.plant, self.T, self.blocking
        solver = self._ocp[held]
        ng = int(solver.size_in("lbg")[0])
        M = b.n_moves if held else T
        lbx = np.concatenate([np.full(p.nx, -np.inf), np.tile(p.x_lb, T)]
                             + [np.tile(p.u_lb, M)])
        ubx = np.concatenate([np.full(p.nx, np.inf), np.tile(p.x_ub, T)]
                             + [np.tile(p.u_ub, M)])
        best: dict[str, Any] | None = None
        starts = {"zero": np.tile(p.clip_input(np.zeros(p.nu)), (T, 1))} | guesses
        for i, U in starts.items():
            V = p.clip_input(U[list(b.starts)] if held else U)  # each block's first input
            U = b.expand(V) if held else V
            X = p.rollout(x0, U, self.dt)
            w0 = np.concatenate([X.ravel(), V.ravel()])
            sol = solver(x0=w0, lbx=lbx, ubx=ubx, lbg=np.zeros(ng), ubg=np.zeros(ng),
                         p=np.concatenate([x0, target.ravel(), u_prev]))
            stats = solver.stats()
            if not stats.get("success"):
                continue
            w = np.asarray(sol["x"]).ravel()
            Ur = w[p.nx * (T + 1):].reshape(-1, p.nu)
            Ur = b.expand(Ur) if held else Ur
            J, viol = self.true_cost(x0, Ur, target, u_prev)
            if best is None or J < best["cost"] - 1e-8 * abs(J):  # a better local optimum
                best = {"cost": J, "u_pred": Ur, "viol": viol, "start": i,
                        "iterations": stats.get("iter_count")}
        if best is None:
            raise RuntimeError("the reference IPOPT converged from no start")
        return best


def sample_states(case: Case, scenario: str, dt: float,
                  ks: list[int] | None = None) -> list[tuple[float, np.ndarray]]:
    """``(t, x)`` at steps ``ks`` (default: the case's) of one closed loop."""
    run = build_run(compose(_fill(case.sampler, scenario, dt)))
    steps = simulate(run).steps
    X = steps[list(run.plant.states)].to_numpy(dtype=float)
    ks = [k for k in (case.samples[scenario] if ks is None else ks) if k < len(X)]
    return [(float(steps["t"].iloc[k]), X[k]) for k in ks]


def compare(case: Case, dt: float | None = None, samples: dict[str, list[int]] | None = None,
            backends: list[str] | None = None, warm: bool = False,
            control_horizon: str | None = None,
            overrides: dict[str, list[str]] | None = None) -> pd.DataFrame:
    """One row per (scenario, state, backend): the measures in the module docstring.

    ``samples`` (scenario -> closed-loop steps) and ``backends`` restrict the case. ``warm``:
    each backend runs its own closed loop (warm-started from its previous plan, as in a
    run) and is scored at its own states at those steps; otherwise every backend is reset
    and solves cold at the states of one sampling closed loop. ``control_horizon`` (as on
    the command line: ``3``, ``[1,2,7]``) blocks every backend, and the held-input
    reference, so. ``overrides``: more Hydra overrides for a backend, by its name.
    """
    dt = case.dt if dt is None else dt
    rows: list[dict[str, Any]] = []
    samples = case.samples if samples is None else samples
    blocked = [] if control_horizon is None else [f"controller.control_horizon={control_horizon}"]
    overrides = overrides or {}
    for scenario in samples:
        runs = {b: build_run(compose(_fill([*o, *overrides.get(b, []), *blocked], scenario, dt)))
                for b, o in case.backends.items() if backends is None or b in backends}
        ctrls = {b: r.controller for b, r in runs.items()}
        T = {c.horizon for c in ctrls.values()}
        dts = {c.dt for c in ctrls.values()}
        if len(T) != 1 or len(dts) != 1:
            raise ValueError(f"backends disagree on horizon {T} or dt {dts}: not the same OCP")
        ref_cfg = compose(_fill([*case.backends["casadi"], *blocked], scenario, dt))
        first = next(iter(runs.values()))
        horizon = T.pop()
        blocking = (Blocking.of(ref_cfg.controller.control_horizon, horizon) if blocked
                    else None)
        scorer = Scorer(first.plant, build(ref_cfg.objective, "objective"), horizon, dts.pop(),
                        dict(ref_cfg.controller.get("terminal_constraint") or {}), blocking)
        scen = first.scenario
        score = _Scoring(scorer, scenario, bool(case.held or blocked))
        if warm:
            for b, run in runs.items():
                rows += _own_loop(score, b, run, scorer, samples[scenario])
            continue
        for t, x in sample_states(case, scenario, dt, samples[scenario]):
            ctx = StepContext(goal=scen.goal, target=scen.target(t, scorer.T, scorer.dt))
            u_prev = first.plant.clip_input(np.zeros(first.plant.nu))
            plans = {}
            for b, c in ctrls.items():
                c.reset(x)
                plans[b] = c.step(t, x, ctx)
            rows += score(t, x, ctx.target, u_prev, plans, with_references=True)
    return pd.DataFrame(rows)


def _own_loop(score: _Scoring, name: str, run: Any, scorer: Scorer,
              ks: list[int]) -> list[dict[str, Any]]:
    """A backend's own closed loop; its plan scored at steps ``ks`` (at its own states)."""
    c, scen, plant = run.controller, run.scenario, run.plant
    x = scen.x0.copy()
    c.reset(x)
    rows = []
    for k in range(max(ks) + 1):
        t = k * scorer.dt
        ctx = StepContext(goal=scen.goal, target=scen.target(t, scorer.T, scorer.dt))
        u_prev = c.previous_input.copy()
        step = c.step(t, x, ctx)
        if k in ks:
            rows += score(t, x, ctx.target, u_prev, {name: step}, with_references=False)
        x = plant.step(x, step.u, scorer.dt)
        if scen.arrived(x):
            break
    return rows


class _Scoring:
    """Rows for one state: the references (optional) and each backend's plan against them."""

    def __init__(self, scorer: Scorer, scenario: str, held: bool) -> None:
        self.scorer, self.scenario, self.held = scorer, scenario, held
        p = scorer.plant
        span = p.u_ub - p.u_lb
        self.span = np.where(np.isfinite(span), span, 1.0)

    def __call__(self, t: float, x: np.ndarray, target: np.ndarray, u_prev: np.ndarray,
                 plans: dict[str, Any], with_references: bool) -> list[dict[str, Any]]:
        sc, span = self.scorer, self.span
        guesses = {b: s.u_pred for b, s in plans.items() if s.ok}
        ref = sc.reference(x, target, u_prev, guesses)
        ref_held = sc.reference(x, target, u_prev, guesses, held=True) if self.held else None
        at = {"scenario": self.scenario, "t": t}
        rows = []
        if with_references:
            rows.append(at | {"backend": "reference", "status": "converged",
                              "true_cost": ref["cost"], "gap": 0.0, "du0": 0.0,
                              "viol": ref["viol"], "ref_start": ref["start"]})
            if ref_held is not None:
                rows.append(at | {"backend": "reference_held", "status": "converged",
                                  "true_cost": ref_held["cost"],
                                  "gap": (ref_held["cost"] - ref["cost"]) / ref["cost"],
                                  "gap_held": 0.0,
                                  "du0": _du0(ref_held["u_pred"][0], ref["u_pred"][0], span),
                                  "viol": ref_held["viol"], "ref_start": ref_held["start"]})
        for b, s in plans.items():
            J, viol = sc.true_cost(x, s.u_pred, target, u_prev)
            row = at | {"backend": b, "status": str(s.status), "true_cost": J,
                        "gap": (J - ref["cost"]) / ref["cost"],
                        "du0": _du0(s.u_pred[0], ref["u_pred"][0], span), "viol": viol,
                        "pred_err": (s.cost - J) / J, "iterations": s.iterations}
            if ref_held is not None:
                row["gap_held"] = (J - ref_held["cost"]) / ref_held["cost"]
            rows.append(row)
        return rows


def _du0(u: np.ndarray, u_ref: np.ndarray, span: np.ndarray) -> float:
    return float(np.max(np.abs(np.asarray(u) - u_ref) / span))


def summarize(df: pd.DataFrame) -> pd.DataFrame:
    """Per backend: median and worst gap, worst du0, violation, prediction error."""
    g = df.groupby("backend", sort=False)
    out = pd.DataFrame({
        "states": g.size(),
        "gap_median": g["gap"].median(), "gap_max": g["gap"].max(),
        "du0_max": g["du0"].max(), "viol_max": g["viol"].max(),
    })
    if "gap_held" in df:
        out["gap_held_median"] = g["gap_held"].median()
        out["gap_held_max"] = g["gap_held"].max()
    if "pred_err" in df:
        out["pred_err_median"] = g["pred_err"].median()
    out["statuses"] = g["status"].agg(_counts)
    if "ref_start" in df:
        out["best_start"] = g["ref_start"].agg(_counts)
    return out


def _counts(s: pd.Series) -> str:
    return ", ".join(f"{k} {v}" for k, v in s.dropna().value_counts().items())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--case", choices=list(CASES), action="append")
    ap.add_argument("--dt", type=float, default=None, help="sample time (default: the case's)")
    ap.add_argument("--csv", type=Path, default=None, help="write the per-state rows here")
    ap.add_argument("--md", type=Path, default=None,
                    help="also write the summaries here, each under its stamp")
    ap.add_argument("--warm", action="store_true",
                    help="each backend in its own closed loop, warm-started (default: cold)")
    ap.add_argument("--control-horizon", default=None,
                    help="block every backend so (3, [1,2,7]); the held reference likewise")
    ap.add_argument("--backend", action="append",
                    help="only this backend (repeatable; default: every backend of the case)")
    ap.add_argument("--override", action="append", default=[], metavar="BACKEND:OVERRIDE",
                    help="one more Hydra override for one backend (repeatable), e.g. "
                         "cvxpy:controller.sl=one_pass")
    args = ap.parse_args()
    names = args.case or list(CASES)
    known = sorted({b for n in names for b in CASES[n].backends})
    overrides: dict[str, list[str]] = {}
    for item in args.override:
        backend, sep, override = item.partition(":")
        if not sep or not override or backend not in known:
            ap.error(f"--override {item!r}: expected BACKEND:OVERRIDE with BACKEND one of "
                     f"{', '.join(known)}")
        overrides.setdefault(backend, []).append(override)
    for backend in args.backend or []:
        if backend not in known:
            ap.error(f"--backend {backend!r}: expected one of {', '.join(known)}")
    frames, summaries = [], []
    for name in names:
        df = compare(CASES[name], args.dt, backends=args.backend, warm=args.warm,
                     control_horizon=args.control_horizon, overrides=overrides)
        df.insert(0, "case", name)
        frames.append(df)
        mode = "warm, own closed loop" if args.warm else "cold"
        if args.control_horizon:
            mode += f", control horizon {args.control_horizon}"
        title = f"{name}  (dt = {args.dt or CASES[name].dt}, {mode})"
        print(f"\n## {title}\n")
        cols = [c for c in ("scenario", "t", "backend", "status", "true_cost", "gap",
                            "gap_held", "du0", "viol", "pred_err") if c in df]
        print(df[cols].to_string(index=False, float_format=lambda v: f"{v:.4g}"))
        summaries.append(f"**{name}**, dt = {args.dt or CASES[name].dt} s, {mode}:\n\n"
                         + summarize(df).to_markdown(floatfmt=".3g"))
    if args.csv:
        pd.concat(frames).to_csv(args.csv, index=False)
    print()
    write_stamped(args.md, summaries)


if __name__ == "__main__":
    main()
