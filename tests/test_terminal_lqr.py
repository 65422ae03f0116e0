"""The LQR terminal cost (mpclab.objectives.terminal_lqr): its P against the Riccati
recursion, its refusal where the theory does not apply, one cost on both backends, and the
value's decrease in the closed loop."""

from __future__ import annotations

import importlib.util

import casadi as ca
import cvxpy as cp
import numpy as np
import pytest

from conftest import ROOT
from mpclab.core.errors import ConfigError
from mpclab.objectives.base import TermContext
from mpclab.objectives.terminal_lqr import TerminalLQR
from mpclab.plants.dynamic_bicycle import DynamicBicycle
from mpclab.plants.kinematic_car import KinematicCar

_spec = importlib.util.spec_from_file_location("terminal_check",
                                               ROOT / "experiments/bicycle/terminal.py")
TERMINAL = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(TERMINAL)

Q = {"px": 1.0, "py": 1.0, "V": 1.0}
R = {"delta": 0.01, "a": 0.01}


def _bound(plant, **kw) -> TerminalLQR:
    term = TerminalLQR(**kw)
    term.name = "terminal"
    term.bind(plant)
    return term


def test_p_is_the_limit_of_the_riccati_recursion() -> None:
    plant = DynamicBicycle()
    term = _bound(plant, state_weights=Q, input_weights=R, dt=0.02, at={"V": 2.0})
    x = np.zeros(plant.nx)
    x[plant.state_index("V")] = 2.0
    A, B = plant.jacobians(x, np.zeros(plant.nu), 0.02)
    Qm = np.diag([Q.get(s, 0.0) for s in plant.states])
    Rm = np.diag([R[u] for u in plant.inputs])
    P = Qm.copy()
    for _ in range(20000):  # the finite-horizon cost-to-go, horizon growing
        K = np.linalg.solve(Rm + B.T @ P @ B, B.T @ P @ A)
        P = Qm + A.T @ P @ (A - B @ K)
    assert np.linalg.norm(term.P - P) <= 1e-6 * np.linalg.norm(P)
    assert np.all(np.linalg.eigvalsh(term.P) > 0)


def test_a_car_at_rest_is_refused_naming_the_modes() -> None:
    with pytest.raises(ConfigError, match=r"not stabilizable.*along py, theta"):
        _bound(KinematicCar(), state_weights={"px": 100.0, "py": 100.0},
               input_weights={"a": 0.01, "phi_dot": 0.01}, dt=0.1)
    with pytest.raises(ConfigError, match="positive weight on every input; missing: a"):
        _bound(DynamicBicycle(), state_weights=Q, input_weights={"delta": 0.01}, dt=0.02,
               at={"V": 2.0})


def test_one_cost_on_both_backends() -> None:
    plant = DynamicBicycle()
    term = _bound(plant, state_weights=Q, input_weights=R, dt=0.02, at={"V": 2.0})
    rng = np.random.default_rng(0)
    X, target = rng.normal(size=(plant.nx, 5)), rng.normal(size=(plant.nx, 5))
    e = X[:, -1] - target[:, -1]
    want = float(e @ term.P @ e)
    x0, u0 = np.zeros(plant.nx), np.zeros(plant.nu)
    got_casadi = float(ca.DM(term.casadi_cost(
        ca.DM(X), None, TermContext(x0=x0, u_prev=u0, target=ca.DM(target)))))
    got_cvxpy = float(term.cvxpy_cost(
        cp.Constant(X), None, TermContext(x0=x0, u_prev=u0, target=target)).value)
    assert got_casadi == pytest.approx(want, rel=1e-9)
    assert got_cvxpy == pytest.approx(want, rel=1e-6)


def test_the_value_decreases_by_the_stage_cost_with_it_and_not_without(tmp_path) -> None:
    """One random offset from the path (experiments/bicycle/terminal.py's seed 0) on IPOPT
    with horizon 10: with the terminal cost the value falls by at least the stage cost it
    spent on most steps; without it on none (the horizon's new last stage costs more)."""
    mod = TERMINAL
    fast = ["controller=casadi", "controller.horizon=10", "controller.dt=0.02"]
    with_it = mod.check([*mod.start(0), *fast], tmp_path / "a")
    without = mod.check([*mod.start(0), *fast, "~objective.terms.terminal"], tmp_path / "b")
    assert with_it["failed"] == without["failed"] == 0
    assert with_it["kept"] >= 0.6 * with_it["steps"] and without["kept"] <= 0.1 * without["steps"]
    assert with_it["decreased"] == with_it["steps"]
