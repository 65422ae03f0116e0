"""Every term with both a CVXPY and a CasADi form gives the same number in each."""

from __future__ import annotations

import casadi as ca
import cvxpy as cp
import numpy as np
import pytest

from mpclab.core.errors import ConfigError
from mpclab.objectives.base import TermContext
from mpclab.objectives.quadratic import QuadraticTracking
from mpclab.objectives.rate import InputRate
from mpclab.plants.kinematic_car import KinematicCar

PLANT = KinematicCar()
T = 4
RNG = np.random.default_rng(3)


def both_forms(term) -> tuple[float, float]:
    """The term's cost at one random horizon, in CVXPY and in CasADi."""
    term.bind(PLANT)
    nx, nu = PLANT.nx, PLANT.nu
    X, U = RNG.normal(size=(nx, T + 1)), RNG.normal(size=(nu, T))
    target, u_prev, x0 = RNG.normal(size=(nx, T + 1)), RNG.normal(size=nu), X[:, 0]
    Xv, Uv = cp.Variable((nx, T + 1)), cp.Variable((nu, T))
    pt, pu, px = cp.Parameter((nx, T + 1)), cp.Parameter(nu), cp.Parameter(nx)
    pt.value, pu.value, px.value = target, u_prev, x0
    expr = term.cvxpy_cost(Xv, Uv, TermContext(x0=px, target=pt, u_prev=pu))
    Xv.value, Uv.value = X, U
    assert cp.Problem(cp.Minimize(expr)).is_dpp()
    ctx = TermContext(x0=ca.DM(x0), target=ca.DM(target), u_prev=ca.DM(u_prev))
    return float(expr.value), float(term.casadi_cost(ca.DM(X), ca.DM(U), ctx))


@pytest.mark.parametrize("term", [
    QuadraticTracking({"px": 100, "py": 3}, {"a": 0.01, "phi_dot": 2}, {"v": 7}),
    InputRate({"a": 0.5, "phi_dot": 3.0}),
    InputRate({"phi_dot": 1.0}),
], ids=["tracking", "rate", "rate_one_input"])
def test_cvxpy_and_casadi_forms_agree(term) -> None:
    a, b = both_forms(term)
    assert a == pytest.approx(b, rel=1e-10, abs=1e-10)


def test_input_rate_charges_the_first_move_against_the_applied_input() -> None:
    term = InputRate({"a": 2.0})
    term.bind(PLANT)
    U = ca.DM([[1.0, 4.0, 4.0], [9.0, -9.0, 0.0]])  # a: 1 -> 4 -> 4; phi_dot is not weighted
    ctx = TermContext(x0=None, target=None, u_prev=ca.DM([0.5, 0.0]))
    # 2 ((1 - 0.5)^2 + (4 - 1)^2 + 0)
    assert float(term.casadi_cost(None, U, ctx)) == pytest.approx(2 * (0.25 + 9.0))


@pytest.mark.parametrize("weights", [{"a": -1.0}, {"a": float("nan")}, {"a": float("inf")}, {}])
def test_input_rate_refuses_bad_weights(weights) -> None:
    with pytest.raises(ConfigError, match="weights"):
        InputRate(weights)


def test_input_rate_names_an_unknown_input() -> None:
    term = InputRate({"steer": 1.0})
    term.name = "rate"
    with pytest.raises(ConfigError, match="steer"):
        term.bind(PLANT)
