"""Per-step time of mpclab's CasADi backend against do-mpc on the same NLP, interleaved.

    uv sync --extra bench
    uv run python experiments/zumo/compare_dompc.py [--experiment zumo_right_hand]
        [--scenario zumo_wall] [--repeats 3]

Both solve Study B's problem with IPOPT: multiple shooting over the same RK4 step, horizon
10, the experiment's objective terms (the same mpclab Term objects build both costs), the
same wheel-speed bounds and the same detected points. States are replayed from one
closed-loop run of the CasADi backend; at every state each controller makes one step, the
order alternating, each warm-started from its own previous solution. The table gives the
median and p95 of the per-step wall time and their ratio. A third controller, interleaved
with the two, is set by ``--backend`` (default: ``controller=casadi_sqp_capped
controller.solve.sqp_iterations=3``, 3 SQP steps per sample on the single-shooting form of the
same NLP, qpOASES): the same objective, bounds and horizon, but not solved to convergence.
The first controller is the experiment's NLP on IPOPT (``controller=casadi``), whatever
backend the experiment ships with.
With an obstacle distance constraint in the objective (``--experiment zumo_bug2``) do-mpc
gets it as a soft nonlinear constraint with the same rows and linear penalty (one slack per
row and stage, where mpclab has one per stage: the same solution where the hard problem is
feasible). ``--active`` sets the terms on for both (BUG2's go-to-goal: ``J1 J2 J3 dU``; the
input rate dU is do-mpc's own ``rterm``); ``--reference`` the first controller (e.g.
``controller=casadi_fatrop``, the converged default). The table counts the converged solves
of each and the largest difference of the first input between the first controller and
do-mpc at the same state.
The table is printed with its stamp (command, commit, CPU, date); ``--md FILE`` also writes
it. do-mpc is an optional dependency: nothing in mpclab or its tests imports this file.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
import warnings
from pathlib import Path

import casadi as ca
import numpy as np

from mpclab.config.registry import register_all
from mpclab.constraints.obstacle import ObstacleDistance
from mpclab.controllers.base import SolveStatus, StepContext
from mpclab.objectives.base import TermContext
from mpclab.objectives.rate import InputRate
from mpclab.record.provenance import write_stamped
from mpclab.runner.single_run import build_run, compose, run_experiment

warnings.filterwarnings("ignore")
import do_mpc  # noqa: E402


def dompc_controller(run, names_active=None):
    """A do-mpc MPC with the same model, bounds, horizon and objective terms as ``run``."""
    plant, ctrl = run.plant, run.controller
    M, T, dt = ctrl._M, ctrl.horizon, ctrl.dt
    model = do_mpc.model.Model("discrete", "SX")
    x = model.set_variable("_x", "x", shape=(plant.nx, 1))
    u = model.set_variable("_u", "u", shape=(plant.nu, 1))
    model.set_variable("_tvp", "det", shape=(2, M))
    model.set_variable("_tvp", "mask", shape=(M, 1))
    model.set_variable("_tvp", "p0", shape=(plant.nx, 1))
    obstacles = [c for c in ctrl.objective.constraints.values()
                 if isinstance(c, ObstacleDistance)]
    for c in obstacles:
        model.set_variable("_tvp", f"{c.name}_radius", shape=(M, 1))
    model.set_rhs("x", plant.F(x, u, dt))
    model.setup()
    goal = ca.DM(run.scenario.goal)
    p = TermContext(goal=goal, x0=model.tvp["p0"], target=ca.repmat(goal, 1, 2),
                    u_prev=ca.DM.zeros(plant.nu), detections=model.tvp["det"],
                    mask=model.tvp["mask"])
    X = ca.horzcat(model.x["x"], model.x["x"])  # column 1 is the costed state
    state_cost, effort, rate = 0, 0, np.zeros(plant.nu)
    for name, term in ctrl.objective.terms.items():
        if names_active is not None and name not in names_active:
            continue
        if isinstance(term, InputRate):  # do-mpc's own input-change penalty (rterm)
            for label, w in term.weights.items():
                rate[plant.input_index(label)] += float(w)
            continue
        c = term.casadi_cost(X, ca.reshape(model.u["u"], plant.nu, 1), p)
        if getattr(term, "state_weights", None) is not None and not term.state_weights:
            effort += c  # input effort only (J2): a stage term
        else:
            state_cost += term.casadi_cost(X, ca.DM.zeros(plant.nu, 1), p)
    mpc = do_mpc.controller.MPC(model)
    mpc.settings.n_horizon = T
    mpc.settings.t_step = dt
    mpc.settings.store_full_solution = False
    mpc.settings.nlpsol_opts = {"ipopt.print_level": 0, "ipopt.sb": "yes", "print_time": 0,
                                "ipopt.max_iter": ctrl.max_iter, "ipopt.tol": ctrl.tol}
    # stage cost on x_0..x_{T-1} plus terminal on x_T: mpclab's x_1..x_T up to a constant
    mpc.set_objective(lterm=state_cost + effort, mterm=state_cost)
    mpc.set_rterm(u=rate)
    for c in obstacles:  # soft: one slack per row and stage, the same linear penalty
        g = c.g(model.x["x"], p, model.tvp[f"{c.name}_radius"])
        mpc.set_nl_cons(c.name, g, ub=0.0, soft_constraint=True, penalty_term_cons=c.penalty)
    mpc.bounds["lower", "_u", "u"] = plant.u_lb
    mpc.bounds["upper", "_u", "u"] = plant.u_ub
    tvp = mpc.get_tvp_template()
    mpc.set_tvp_fun(lambda t_now: tvp)
    mpc.setup()
    return mpc, tvp, obstacles


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--experiment", default="zumo_right_hand")
    ap.add_argument("--scenario", default="zumo_wall")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--backend", nargs="*",
                    default=["controller=casadi_sqp_capped", "controller.solve.sqp_iterations=3"],
                    help="overrides of the third controller (default: SQP capped at 3 steps)")
    ap.add_argument("--active", nargs="*", default=None,
                    help="the objective terms on (default: all), for both controllers")
    ap.add_argument("--reference", default="controller=casadi",
                    help="the first controller (default: the NLP on IPOPT, as do-mpc)")
    ap.add_argument("--md", type=Path, help="also write the stamped table here")
    args = ap.parse_args()
    register_all()
    over = [f"+experiment={args.experiment}", f"scenario={args.scenario}", "recorder=none",
            "progress=false", "figures.enabled=false"]
    cfg = compose([*over, args.reference])  # IPOPT, as do-mpc, unless told
    cfg_b = compose(over + list(args.backend))

    with tempfile.TemporaryDirectory() as tmp:
        ref = run_experiment(cfg, tmp)
    labels = ["x", "y", "theta"]
    states = ref.steps[ref.steps["status"] != "final"][labels].to_numpy()
    names = ("mpclab_casadi", "do_mpc", "mpclab_backend")
    times = {n: [] for n in names}
    converged = {n: 0 for n in names}
    gaps = []  # |u| of the first controller against do-mpc's, the same state
    for rep in range(args.repeats):
        run = build_run(cfg)
        ctrl, scen = run.controller, run.scenario
        ctrl.reset(states[0])
        ctrl_b = build_run(cfg_b).controller
        ctrl_b.reset(states[0])
        mpc, tvp, obstacles = dompc_controller(run, args.active)
        mpc.x0 = states[0]
        mpc.set_initial_guess()
        for k, x in enumerate(states):
            det, mask = ctrl._pad_detections(x, scen.detect(x))
            ctx = StepContext(goal=scen.goal, target=scen.target(0, ctrl.horizon, ctrl.dt),
                              detections=scen.detect(x),
                              active=None if args.active is None else frozenset(args.active))
            tvp["_tvp", :, "det"] = det
            tvp["_tvp", :, "mask"] = mask
            tvp["_tvp", :, "p0"] = x
            for c in obstacles:
                tvp["_tvp", :, f"{c.name}_radius"] = c.radius(x, det, mask)
            order = names[(k + rep) % 3:] + names[:(k + rep) % 3]  # rotate the order
            inputs = {}
            for who in order:
                t0 = time.perf_counter()
                if who == "mpclab_casadi":
                    out = ctrl.step(k * ctrl.dt, x, ctx)
                    ok, inputs[who] = out.status is SolveStatus.converged, out.u
                elif who == "mpclab_backend":
                    out = ctrl_b.step(k * ctrl.dt, x, ctx)
                    ok = out.status is SolveStatus.converged
                else:
                    inputs[who] = np.asarray(mpc.make_step(x.reshape(-1, 1))).ravel()
                    ok = bool(mpc.solver_stats["success"])
                times[who].append(time.perf_counter() - t0)
                converged[who] += int(ok)
            gaps.append(float(np.max(np.abs(inputs["mpclab_casadi"] - inputs["do_mpc"]))))
    a, b, c = (np.asarray(times[n]) * 1e3 for n in names)
    backend = " ".join(args.backend)
    lines = [f"{args.experiment} on {args.scenario}: {len(states)} states x {args.repeats} "
             "repeats" + (f", terms {' '.join(args.active)}" if args.active else ""), "",
             "| controller | median ms | p95 ms | converged |", "|---|---|---|---|"]
    for name, who, v in ((f"mpclab casadi ({args.reference})", names[0], a),
                         ("do-mpc (IPOPT)", names[1], b),
                         (f"mpclab casadi ({backend})", names[2], c)):
        lines.append(f"| {name} | {np.median(v):.2f} | {np.percentile(v, 95):.2f} | "
                     f"{converged[who]} of {len(v)} |")
    lines.append("")
    for label, v in (("mpclab " + args.reference, a), ("mpclab backend", c)):
        lines.append(f"ratio do-mpc / {label}, of median per-step times: "
                     f"{np.median(b) / np.median(v):.2f}; median of paired ratios: "
                     f"{np.median(b / v):.2f}")
    lines.append(f"first input, {args.reference} against do-mpc, largest difference: median "
                 f"{np.median(gaps):.2g}, max {np.max(gaps):.2g} rad/s")
    write_stamped(args.md, "\n".join(lines), sys.argv)


if __name__ == "__main__":
    main()
