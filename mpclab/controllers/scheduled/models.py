"""What the scheduled MPC (:mod:`mpclab.controllers.scheduled.mpc`) precomputes and reports
beside its step: each operating point's QP data, the weights it takes from the objective's
quadratic tracking terms, and the statistics of its switches between operating points."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from mpclab.controllers.base import FloatArray
from mpclab.core.errors import ConfigError
from mpclab.objectives.base import Objective
from mpclab.objectives.quadratic import QuadraticTracking
from mpclab.plants.base import Plant


@dataclass
class OpModel:
    """One operating point's precomputed QP data (:mod:`mpclab.controllers.scheduled.dense_qp`)."""

    Px: FloatArray
    Pu: FloatArray
    pc: FloatArray
    H: FloatArray
    Kx: FloatArray
    kc: FloatArray
    Kr: FloatArray
    g_shift: FloatArray
    x_shift: FloatArray
    #: [Kx, -Kr, kc]: g = K [x; ref; 1]
    K: FloatArray
    #: [Px, Pu, pc]: X = P [x; z; 1]
    P: FloatArray
    #: H entries (h00, h01, h11) as floats, for the closed form
    h: tuple[float, float, float]
    #: the operating point's heading (0 without a periodic scheduling state)
    theta: float

    def __post_init__(self) -> None:
        #: g_shift as floats, for the closed form
        self.gs = tuple(self.g_shift.tolist())


def tracking_weights(
    objective: Objective, plant: Plant,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Diagonal state, terminal and input weights summed over the objective's terms."""
    q, qT, r = np.zeros(plant.nx), np.zeros(plant.nx), np.zeros(plant.nu)
    for con in objective.constraints.values():  # its QP has no rows for them
        con.require("scheduled")
    for term in objective:
        if not isinstance(term, QuadraticTracking):
            raise ConfigError(
                f"objective term {term.name!r} ({type(term).__name__}) cannot be expressed by "
                "the scheduled backend, which takes QuadraticTracking terms only; backends "
                f"that accept it: {', '.join(term.backends()) or '(none)'}"
            )
        try:
            for label, w in term.state_weights.items():
                q[plant.state_index(label)] += float(w)
            for label, w in term.terminal_weights.items():
                qT[plant.state_index(label)] += float(w)
            for label, w in term.input_weights.items():
                r[plant.input_index(label)] += float(w)
        except ValueError as exc:
            raise ConfigError(f"objective term {term.name!r}: {exc}") from None
    if not r.all():
        raise ConfigError(
            "the scheduled backend needs a positive weight on every input (the QP must be "
            f"strictly convex); got input weights {dict(zip(plant.inputs, r, strict=True))}"
        )
    return q, qT, r


def switch_metrics(t: FloatArray, ops: FloatArray, U: FloatArray, plant: Plant) -> dict[str, Any]:
    """The switches of the operating point over the controller calls at times ``t`` (their
    operating points ``ops``, inputs ``U``): how many, when, and the largest input jump at one
    (per input and relative to the input's range)."""
    if len(ops) < 2:
        return {"n_switches": 0}
    switch = np.flatnonzero(ops[1:] != ops[:-1]) + 1
    out: dict[str, Any] = {"n_switches": int(switch.size),
                           "switch_times_s": [round(float(v), 6) for v in t[switch]]}
    jumps = np.abs(np.diff(U, axis=0))[switch - 1] if switch.size else np.zeros((0, U.shape[1]))
    span = plant.u_ub - plant.u_lb
    for j, lab in enumerate(plant.inputs):
        out[f"switch_jump_max_{lab}"] = float(jumps[:, j].max()) if switch.size else 0.0
    rel = jumps / np.where(np.isfinite(span), span, np.inf)
    out["switch_jump_max_rel"] = float(rel.max()) if switch.size else 0.0
    return out
