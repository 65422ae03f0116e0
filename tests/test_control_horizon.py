"""The control horizon (move blocking) on every backend that solves an OCP.

One blocking definition (:mod:`mpclab.controllers.blocking`) for CVXPY, CasADi (IPOPT,
fatrop, SQP, the real-time iteration, capped SQP, single shooting, generated C), Uno and
the scheduled backend. Checked here: ``control_horizon = horizon`` gives each backend's
unblocked plan; the CVXPY and CasADi car plans agree at ``Nc = 3`` and with a list of
blocks; the plan holds its input within each block; the decision vector holds ``Nc * nu``
free inputs; the summary records the blocking.

Stated tolerances: plans of one backend blocked as ``horizon`` and unblocked are the same
problem, 1e-9 on the inputs; CVXPY's successive linearization and CasADi's NLP solvers to
their tolerance 1e-6 agree on the car's inputs to 1e-4 (in units of 10 m/s^2 and 3 rad/s
bounds) and on the cost to 1e-6 relative (measured: 1e-5 and 2e-9).
"""

from __future__ import annotations

import numpy as np
import pytest
from test_bicycle import controller as bicycle
from test_bicycle import ctx as bicycle_ctx
from test_bicycle import random_target

from conftest import grouped
from mpclab.codegen.build import find_compiler
from mpclab.controllers.base import StepContext
from mpclab.controllers.blocking import Blocking
from mpclab.controllers.casadi.mpc import CasadiMPC
from mpclab.core.errors import ConfigError
from mpclab.objectives.base import Objective
from mpclab.objectives.potential import GoalAttraction
from mpclab.objectives.quadratic import QuadraticTracking
from mpclab.objectives.rate import InputRate
from mpclab.plants.zumo import Zumo
from mpclab.runner.single_run import build_run, compose

X0 = np.array([-10.0, 10.0, 0.0, 0.0, 0.0])
T = 10
QUIET = ["recorder=none", "figures.enabled=false", "progress=false"]
#: the car's backends: (experiment, overrides); CasADi's NLPs uncompiled (same problem)
CAR_BACKENDS = {
    "cvxpy": ("car_cvxpy", []),
    "cvxpy_one_pass": ("car_cvxpy", ["controller.sl=one_pass"]),
    "ipopt": ("car_casadi", ["controller=casadi"]),
    "ipopt_single": ("car_casadi", ["controller=casadi", "controller.build.shooting=single"]),
    "fatrop": ("car_casadi", ["controller=casadi_fatrop", "controller.build.jit=false"]),
    "sqp": ("car_casadi", ["controller.build.jit=false"]),
    "sqp_rti": ("car_casadi", ["controller=casadi_rti"]),
    "sqp_capped": ("car_casadi", ["controller=casadi_sqp_capped"]),
    "uno": ("car_casadi", ["controller=casadi_uno"]),
}


def car(backend: str, control_horizon: str = "null"):
    experiment, overrides = CAR_BACKENDS[backend]
    cfg = compose([f"+experiment={experiment}", *QUIET, *overrides,
                   f"controller.control_horizon={control_horizon}"])
    return build_run(cfg).controller


def plan(controller, steps: int = 2):
    """The plan from ``X0`` after ``steps`` solves there (the later ones warm started)."""
    ctx = StepContext(goal=np.zeros(5), target=np.zeros((T + 1, 5)))
    controller.reset(X0)
    for _ in range(steps):
        res = controller.step(0.0, X0, ctx)
    return res


def assert_held(U: np.ndarray, blocking: Blocking) -> None:
    """``U (T, nu)`` holds one input within each block."""
    for start, length in zip(blocking.starts, blocking.blocks, strict=True):
        assert np.ptp(U[start:start + length], axis=0).max() < 1e-12


# ---------------------------------------------------------------------- the definition
@pytest.mark.parametrize(("value", "blocks"), [
    (None, (1,) * 10), (10, (1,) * 10), (3, (1, 1, 8)), (1, (10,)),
    ([1, 2, 7], (1, 2, 7)), ([2, 3], (2, 8)), ([4, 4, 4], (4, 4, 2)), ([20], (10,)),
])
def test_blocks_of_null_an_integer_and_a_list(value, blocks) -> None:
    b = Blocking.of(value, 10)
    assert b.blocks == blocks and sum(b.blocks) == 10 and b.n_moves == len(blocks)
    assert b.summary() == {"control_horizon": len(blocks), "blocks": list(blocks)}


def test_matrix_expand_reblock_and_shift() -> None:
    b = Blocking.of([1, 2, 7], 10)
    E = b.matrix(2)
    assert E.shape == (20, 6) and set(np.unique(E)) == {0.0, 1.0}
    V = np.array([[1.0, -1.0], [2.0, -2.0], [3.0, -3.0]])
    U = b.expand(V)
    np.testing.assert_array_equal(E @ V.ravel(), U.ravel())
    np.testing.assert_array_equal(b.reblock(U), V)  # a held plan gives its moves back
    # one step later: u_1 starts block 0, u_2..u_3 block 1 (the means of what they held)
    np.testing.assert_allclose(b.shift(U), [[2.0, -2.0], [2.5, -2.5], [3.0, -3.0]])


@pytest.mark.parametrize("value", [0, 11, -1, [], [0, 2], [1.5], "3", True, [[1]], 2.0])
def test_a_bad_control_horizon_is_one_config_error_naming_it(value) -> None:
    with pytest.raises(ConfigError, match=r"controller\.control_horizon") as err:
        Blocking.of(value, 10)
    assert "valid: null" in str(err.value)


# ---------------------------------------------------------------------- per backend
@pytest.mark.parametrize("backend", list(CAR_BACKENDS))
def test_control_horizon_equal_to_the_horizon_is_the_unblocked_plan(backend) -> None:
    free, full = plan(car(backend)), plan(car(backend, str(T)))
    assert free.ok and full.ok
    np.testing.assert_allclose(full.u_pred, free.u_pred, rtol=0, atol=1e-9)
    np.testing.assert_allclose(full.x_pred, free.x_pred, rtol=0, atol=1e-9)


def test_scheduled_control_horizon_equal_to_the_horizon_is_the_unblocked_plan() -> None:
    rng = np.random.default_rng(3)
    x = np.array([0.1, -0.2, 0.3, 0.05, 0.0, 1.5])
    ctx = bicycle_ctx(random_target(rng, x))
    plans = []
    for mode in ("switched", "adaptive"):
        for ch in (None, 32, [1] * 32):
            res = bicycle(control_horizon=ch, solver="active_set", mode=mode).step(0.0, x, ctx)
            assert res.ok
            plans.append(res.u_pred)
        for p in plans[-2:]:
            np.testing.assert_allclose(p, plans[-3], rtol=0, atol=1e-9)
    blocked = bicycle(control_horizon=[1, 2, 7]).step(0.0, x, ctx)
    b = Blocking.of([1, 2, 7], 32)
    assert_held(blocked.u_pred, b)


@pytest.mark.parametrize(("control_horizon", "value"),
                         [("3", 3), ("[2,3]", [2, 3]), ("[1,2,7]", [1, 2, 7])])
def test_cvxpy_and_casadi_car_plans_agree_under_blocking(control_horizon, value) -> None:
    blocking = Blocking.of(value, T)
    ref = plan(car("ipopt", control_horizon))
    assert ref.status == "converged"
    # held within each block: one free move per block
    assert_held(ref.u_pred, blocking)
    for backend in ("cvxpy", "ipopt_single", "fatrop", "sqp", "uno"):
        res = plan(car(backend, control_horizon))
        assert res.status == "converged", backend
        np.testing.assert_allclose(res.u_pred, ref.u_pred, rtol=0, atol=1e-4, err_msg=backend)
        assert res.cost == pytest.approx(ref.cost, rel=1e-6), backend


def test_the_decision_vector_holds_nc_times_nu_free_inputs() -> None:
    """What is counted, per backend: CVXPY, the QP's input variable (beside its states
    ``X``); CasADi, the free moves in the NLP's variables, and the whole vector: IPOPT
    substitutes the moves (states + moves), as Uno does, fatrop and SQP hold them as states
    (states + held inputs + moves), single shooting has the moves only; the scheduled
    backend, its QP's variables."""
    nc, nx, nu = 3, 5, 2
    cv = car("cvxpy", str(nc))
    assert cv.V.size == nc * nu and cv.X.size == (T + 1) * nx
    sizes = {"ipopt": (T + 1) * nx + nc * nu,
             "fatrop": (T + 1) * (nx + nu) + nc * nu,
             "sqp": (T + 1) * (nx + nu) + nc * nu,
             "ipopt_single": nc * nu, "uno": (T + 1) * nx + nc * nu}
    for backend, size in sizes.items():
        ocp = car(backend, str(nc)).ocp
        assert ocp.u_idx.size == nc * nu and ocp.lbw.size == size, backend
    free = car("ipopt").ocp
    assert free.u_idx.size == T * nu and free.lbw.size == (T + 1) * nx + T * nu
    sched = bicycle(control_horizon=[1, 2, 7])
    assert sched.nz == 3 * sched.plant.nu and sched.models[0].H.shape == (sched.nz, sched.nz)


def _zumo(solver: str, shooting: str, control_horizon) -> CasadiMPC:
    plant = Zumo(input_bounds={"u1": [-10, 10], "u2": [-10, 10]})
    terms = {"J1": GoalAttraction(), "J2": QuadraticTracking(input_weights={"u1": 0.01,
                                                                            "u2": 0.01}),
             "dU": InputRate({"u1": 0.05, "u2": 0.05})}
    return CasadiMPC(plant, Objective(terms), **grouped(CasadiMPC, horizon=8, dt=0.2, solver=solver,
                     shooting=shooting, control_horizon=control_horizon, max_detections=0,
                     initial_input={"u1": 2.0, "u2": 2.0}))


def test_zumo_input_rate_counts_at_block_starts_on_every_casadi_form() -> None:
    """The Zumo's input-rate term on the lifted inputs (fatrop, IPOPT's multiple shooting)
    and on ``u_prev`` and the inputs (single shooting): the same blocked plan, whose input
    changes only where a block starts."""
    goal = np.array([0.4, 0.4, 0.0])
    ctx = StepContext(goal=goal, target=np.tile(goal, (9, 1)))
    x = np.array([0.4, 0.8, -1.2])
    plans = []
    for solver, shooting in (("ipopt", "multiple"), ("fatrop", "multiple"),
                             ("ipopt", "single")):
        c = _zumo(solver, shooting, [1, 2, 5])
        assert (c.ocp.s_idx is not None) is (shooting == "multiple")
        res = c.step(0.0, x, ctx)
        assert res.status == "converged", (solver, shooting)
        plans.append(res)
    for res in plans[1:]:
        np.testing.assert_allclose(res.u_pred, plans[0].u_pred, rtol=0, atol=1e-5)
        assert res.cost == pytest.approx(plans[0].cost, rel=1e-6)
    du = np.diff(np.vstack([np.zeros(2), plans[0].u_pred]), axis=0)
    moving = np.flatnonzero(np.abs(du).max(axis=1) > 1e-9)
    assert set(moving) <= {0, 1, 3} and len(moving) >= 2


def test_summary_records_the_blocking(run_cfg) -> None:
    res, _ = run_cfg(["+experiment=car_cvxpy", "controller.control_horizon=3"])
    s = res.summary
    assert s["control_horizon"] == 3 and s["blocks"] == [1, 1, 8] and s["arrived"]
    hz = res.horizons
    first = hz[hz["step"] == 0].sort_values("k")
    a = first["a"].to_numpy()[:T]
    assert np.ptp(a[2:]) < 1e-9  # the third move held to the end of the horizon


@pytest.mark.skipif(find_compiler() is None, reason="no C compiler")
@pytest.mark.parametrize("backend", ["sqp", "fatrop"])
def test_compiled_and_generated_solvers_give_the_blocked_plan(backend) -> None:
    """The NLP's functions compiled (``jit``) and the whole solver as generated C
    (``codegen``) solve the blocked NLP as the library solver does."""
    lib = plan(car(backend, "[2,3]"))
    for option in ("controller.build.jit=true", "controller.codegen=true"):
        experiment, overrides = CAR_BACKENDS[backend]
        cfg = compose([f"+experiment={experiment}", *QUIET, *overrides, option,
                       "controller.control_horizon=[2,3]"])
        c = build_run(cfg).controller
        assert c.compiled
        res = plan(c)
        assert res.status == "converged", option
        np.testing.assert_allclose(res.u_pred, lib.u_pred, rtol=0, atol=1e-6, err_msg=option)
