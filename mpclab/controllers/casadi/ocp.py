"""The CasADi backend's optimal control problem, built stage by stage with named parameters.

:class:`Params` is the one layout that both builds the parameter vector (symbols by name)
and fills it at every step (values by name), so the two cannot drift apart. :func:`build_ocp`
writes the NLP with its variables in stage order (``x0, u0, x1, u1, ..., xT`` for multiple
shooting; ``u0, ..., u_{T-1}`` for single shooting) and its constraints stage by stage with
an ``equality`` flag each, the form structure-exploiting solvers (fatrop) need.

Constraints (:mod:`mpclab.constraints`, declared in ``objective.constraints``) write their
rows on each predicted state ``x_k`` (``k = 1..T``) as path constraints of stage ``k``, a
soft one with its slack ``>= 0``, a variable of stage ``k`` placed after ``x_k`` (one per soft
constraint; ``penalty * slack`` in the cost); a constraint coupling ``x_k`` and its successor
(a barrier function) writes its rows at stage ``k = 0..T-1`` on ``x_k`` and
``F(x_k, u_k)``, so that they stay local to stage ``k``.

Move blocking (the control horizon, :mod:`mpclab.controllers.blocking`): the NLP's input
variables are the ``M`` free moves ``v_j``, each placed in the stage where its block starts.
Single shooting, and multiple shooting for IPOPT, substitute ``u_k = v_{j(k)}``
(``U = T V``). A stage-structured solver needs every cost and constraint local to a stage and
its successor, which a move shared by the stages of its block is not: fatrop (and hpipm) read
the stages off the NLP, and sqpmethod convexifies its Hessian block by block, where a shared
move joins the stages of its block into one dense block (the car at ``control_horizon=3``:
its eigenvalue decomposition ran out of iterations and most solves failed). For these
(``stagewise``) the held input is a state: the lifted input before each step ``s_k``
(``s_0 = u_prev``), with ``s_{k+1} = v_j`` at the start of block ``j`` and ``s_{k+1} = s_k``
within it, where the step applies ``u_k = s_k``. A stage within a block then has no control
at all, and the held-input states are fixed by the dynamics as the plant's states are (the
same lifted states an input-rate term already needs). Equality constraints
``u_k = u_{k-1}`` instead would keep all ``T nu`` inputs free in the decision vector.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from enum import StrEnum
from typing import Any

import casadi as ca
import numpy as np

from mpclab.constraints.base import Constraint
from mpclab.controllers.blocking import Blocking
from mpclab.objectives.base import Objective, TermContext
from mpclab.plants.base import Plant


class Shooting(StrEnum):
    multiple = "multiple"
    single = "single"


class Params:
    """Named CasADi parameters: ``add`` declares a symbol, ``pack`` fills the vector by name."""

    def __init__(self) -> None:
        self._syms: dict[str, ca.SX] = {}
        self._shapes: dict[str, tuple[int, int]] | None = None

    def add(self, name: str, rows: int, cols: int = 1) -> ca.SX:
        if name in self._syms:
            raise ValueError(f"parameter {name!r} declared twice")
        self._syms[name] = sym = ca.SX.sym(name, rows, cols)
        self._shapes = None
        return sym

    @property
    def names(self) -> list[str]:
        return list(self._syms)

    def indices(self, name: str) -> np.ndarray:
        """Where the parameter ``name`` sits in the vector (its entries, column-major)."""
        start = 0
        for n, s in self._syms.items():
            size = int(s.numel())
            if n == name:
                return np.arange(start, start + size)
            start += size
        raise KeyError(f"no parameter {name!r}; declared: {', '.join(self._syms)}")

    @property
    def vector(self) -> ca.SX:
        return ca.vertcat(*(ca.vec(s) for s in self._syms.values()))

    def pack(self, **values: Any) -> np.ndarray:
        """The parameter vector from ``name=array`` (each of its symbol's shape)."""
        if values.keys() != self._syms.keys():
            missing, extra = set(self._syms) - set(values), set(values) - set(self._syms)
            raise ValueError(f"parameters missing {sorted(missing)}, unknown {sorted(extra)}")
        if self._shapes is None:  # asking CasADi for shapes costs more than the packing
            self._shapes = {n: s.shape for n, s in self._syms.items()}
        parts = []
        for name, shape in self._shapes.items():
            v = np.asarray(values[name], dtype=float)
            if v.size != shape[0] * shape[1] or (v.ndim == 2 and v.shape != shape):
                raise ValueError(f"parameter {name!r}: shape {v.shape}, expected {shape}")
            parts.append(v.ravel("F") if v.ndim == 2 else v.ravel())
        return np.concatenate(parts) if parts else np.zeros(0)


@dataclass
class OCP:
    """An NLP ``min f(w, p) s.t. lbg <= g(w, p) <= ubg, lbw <= w <= ubw`` and its layout."""

    nlp: dict[str, Any]
    params: Params
    lbg: np.ndarray
    ubg: np.ndarray
    equality: list[bool]
    lbw: np.ndarray
    ubw: np.ndarray
    x_idx: np.ndarray | None   # (T+1, nx) indices of the states in w (multiple shooting)
    u_idx: np.ndarray          # (M, nu) indices of the free moves in w (M = T unblocked)
    s_idx: np.ndarray | None   # (T+1, nu) indices of the lifted inputs-before (or None)
    slack_idx: np.ndarray | None  # (T, n_soft) indices of the soft constraints' slacks
    slack_fn: ca.Function | None  # (w, p) -> the slacks' penalty (None without soft ones)
    #: (stage k = 1..T, soft constraint j) -> the rows of g that share the slack s_k[j]
    soft_rows: dict[tuple[int, int], np.ndarray]
    plan_fn: ca.Function       # (w, p) -> X (nx, T+1)
    #: the rows that fix the states (multiple shooting: the initial value, then each gap), in
    #: the order of the states they fix; empty under single shooting
    dynamics_rows: np.ndarray


def build_ocp(
    plant: Plant, objective: Objective, term_names: Sequence[str], horizon: int, dt: float,
    shooting: Shooting, max_detections: int, constraints: Sequence[Constraint],
    terminal: Sequence[tuple[int, float]], blocking: Blocking | None = None,
    stagewise: bool = False,
) -> OCP:
    """The MPC problem over ``horizon`` steps of ``plant.F`` with the (active) terms' cost,
    its inputs blocked by ``blocking`` (None: every move free); ``stagewise``: for a solver
    that exploits the stage structure (module docstring)."""
    nx, nu, T, M = plant.nx, plant.nu, horizon, max(max_detections, 1)
    blocking = blocking or Blocking.of(None, T)
    move_of, starts = blocking.move_of.tolist(), set(blocking.starts)
    P = Params()
    x0 = P.add("x0", nx)
    goal = P.add("goal", nx)
    target = P.add("target", nx, T + 1)
    det = P.add("detections", 2, M)
    mask = P.add("mask", M)
    active = P.add("active", len(term_names))
    u_prev = P.add("u_prev", nu)
    cpar = [c.declare(P, M) for c in constraints]  # each constraint's own parameters
    soft = [c for c in constraints if c.soft]
    Sl = {k: ca.SX.sym(f"slack{k}", len(soft)) for k in range(1, T + 1)} if soft else {}
    Vs = [ca.SX.sym(f"u{j}", nu) for j in range(blocking.n_moves)]  # the free moves
    # a term coupling each input to the one before (an input rate) makes the NLP's Hessian
    # couple neighbouring stages, which a stage-structured solver cannot take: the input
    # before each step becomes a state of its own (s_0 = u_prev, s_{k+1} = u_k), the "lifted"
    # form, and the term reads s_k; it also holds a blocked input for such a solver. Decided
    # over the whole objective, so that every NLP of one objective (one per active set) has
    # the same variables
    lift = shooting is Shooting.multiple and (
        any(t.uses_input_before for t in objective.terms.values())
        or (stagewise and not blocking.free))
    Ss = [ca.SX.sym(f"s{k}", nu) for k in range(T + 1)] if lift else []
    # the input each step applies: its block's move, held as the state s_k when lifted
    Us = [Vs[move_of[k]] if k in starts or not lift else Ss[k] for k in range(T)]
    ctx = TermContext(x0=x0, target=target, u_prev=u_prev, goal=goal, detections=det,
                      mask=mask, u_before=ca.horzcat(*Ss[:T]) if lift else None)
    g: list[ca.SX] = []
    lbg: list[np.ndarray] = []
    ubg: list[np.ndarray] = []
    dynamics: list[np.ndarray] = []
    soft_rows: dict[tuple[int, int], np.ndarray] = {}
    count = [0]  # rows so far

    def add(expr: Any, lo: Any, hi: Any, fixes_states: bool = False) -> None:
        n = int(expr.shape[0])
        if fixes_states:
            dynamics.append(np.arange(count[0], count[0] + n))
        count[0] += n
        g.append(expr)
        lbg.append(np.broadcast_to(np.asarray(lo, float), (n,)).copy())
        ubg.append(np.broadcast_to(np.asarray(hi, float), (n,)).copy())

    def path(xk: Any) -> None:  # stage constraints on a predicted state x_k, k >= 1
        if shooting is Shooting.single:  # finite state bounds become constraints
            rows = np.flatnonzero(np.isfinite(plant.x_lb) | np.isfinite(plant.x_ub))
            if rows.size:
                add(xk[rows], plant.x_lb[rows], plant.x_ub[rows])

    def rows(k: int, xk: Any, x_next: Any, coupled: bool) -> None:
        """The constraints' rows at stage ``k``: those on one state (``coupled`` False) at
        ``x_next = x_k`` with the stage's slacks, those coupling ``x_k`` and its successor
        (``coupled``) at ``x_k, x_next = F(x_k, u_k)``."""
        j = 0
        for c, par in zip(constraints, cpar, strict=True):
            slack = Sl[k][j] if c.soft and k in Sl else None
            if c.couples_stages is coupled:
                first = count[0]
                add(c.casadi_rows(xk, x_next, slack, ctx, par, k == 0), -np.inf, 0.0)
                if slack is not None:
                    soft_rows[k, j] = np.arange(first, count[0])
            j += int(c.soft)

    inf = np.full(nx, np.inf)
    w_parts, lbw, ubw, where = [], [], [], {}
    size = [0]  # variables so far (a running count: summing the parts is quadratic in T)

    def var(name: str, k: int, sym: Any, lo: Any, hi: Any) -> None:
        n = int(sym.shape[0])
        where[name, k] = np.arange(size[0], size[0] + n)
        size[0] += n
        w_parts.append(sym)
        lbw.append(np.broadcast_to(np.asarray(lo, float), (n,)).copy())
        ubw.append(np.broadcast_to(np.asarray(hi, float), (n,)).copy())

    if shooting is Shooting.multiple:
        Xs = [ca.SX.sym(f"x{k}", nx) for k in range(T + 1)]
        for k in range(T + 1):  # stage k: x_k, s_k, slacks_k (k >= 1), u_k (k < T)
            var("x", k, Xs[k], -inf if k == 0 else plant.x_lb, inf if k == 0 else plant.x_ub)
            if lift:
                var("s", k, Ss[k], -np.inf, np.inf)
            if soft and k > 0:
                var("slack", k, Sl[k], 0.0, np.inf)
            if k == 0:
                add(ca.vertcat(Xs[0] - x0, *([Ss[0] - u_prev] if lift else [])), 0.0, 0.0,
                    fixes_states=True)
            if k < T:  # a stage's gap-closing constraint, then its path constraints (the
                # order fatrop's structure detection takes)
                if k in starts:
                    var("u", move_of[k], Vs[move_of[k]], plant.u_lb, plant.u_ub)
                nxt = plant.F(Xs[k], Us[k], dt)
                gap = [Xs[k + 1] - nxt]
                add(ca.vertcat(*gap, *([Ss[k + 1] - Us[k]] if lift else [])), 0.0, 0.0,
                    fixes_states=True)
            if k > 0:
                path(Xs[k])
                rows(k, None, Xs[k], coupled=False)
            if k < T:
                rows(k, Xs[k], nxt, coupled=True)
        x_idx = np.array([where["x", k] for k in range(T + 1)])
        s_idx = np.array([where["s", k] for k in range(T + 1)]) if lift else None
    else:
        Xs = [x0]
        for k in range(T):
            if k in starts:
                var("u", move_of[k], Vs[move_of[k]], plant.u_lb, plant.u_ub)
            if soft:
                var("slack", k + 1, Sl[k + 1], 0.0, np.inf)
            Xs.append(plant.F(Xs[-1], Us[k], dt))
            path(Xs[-1])
            rows(k + 1, None, Xs[k + 1], coupled=False)
            rows(k, Xs[k], Xs[k + 1], coupled=True)
        x_idx, s_idx = None, None
    u_idx = np.array([where["u", j] for j in range(blocking.n_moves)])
    slack_idx = np.array([where["slack", k] for k in range(1, T + 1)]) if soft else None
    X, U = ca.horzcat(*Xs), ca.horzcat(*Us)
    for i, value in terminal:
        add(X[i, T] - value, 0.0, 0.0)
    w, p = ca.vertcat(*w_parts), P.vector
    cost = 0
    for j, name in enumerate(term_names):
        cost += active[j] * objective.terms[name].casadi_cost(X, U, ctx)
    pen = sum(c.penalty * Sl[k][j] for k in range(1, T + 1) for j, c in enumerate(soft))
    cost += pen
    lo, hi = (np.concatenate(b) if b else np.zeros(0) for b in (lbg, ubg))
    # common subexpressions eliminated: the derived functions are smaller (the generated C
    # of the Zumo NLP by a quarter)
    nlp = {"x": w, "p": p, "f": ca.cse(cost), "g": ca.cse(ca.vertcat(*g))}
    return OCP(
        nlp=nlp, params=P, lbg=lo, ubg=hi,
        equality=[bool(v) for v in (lo == hi)], lbw=np.concatenate(lbw),
        ubw=np.concatenate(ubw), x_idx=x_idx, u_idx=u_idx, s_idx=s_idx,
        slack_idx=slack_idx, slack_fn=ca.Function("penalty", [w, p], [pen]) if soft else None,
        soft_rows=soft_rows,
        plan_fn=ca.Function("plan", [w, p], [X]),
        dynamics_rows=np.concatenate(dynamics) if dynamics else np.zeros(0, dtype=int),
    )

