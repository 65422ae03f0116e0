"""Study C units: the dynamic bicycle, the condensed QP and its solvers, the scheduling grid."""

from __future__ import annotations

import math

import casadi as ca
import numpy as np
import pytest
from scipy.optimize import lsq_linear

from conftest import grouped
from mpclab.config.instantiate import build
from mpclab.controllers.base import StepContext
from mpclab.controllers.scheduled.dense_qp import box_qp_2, box_qp_active_set
from mpclab.controllers.scheduled.mpc import ScheduledMPC
from mpclab.core.errors import ConfigError
from mpclab.objectives.base import Objective
from mpclab.objectives.quadratic import QuadraticTracking
from mpclab.plants.dynamic_bicycle import DynamicBicycle, rk4_amplification
from mpclab.runner.single_run import compose

DELTA_MAX = math.radians(30)
BOUNDS = {"delta": [-DELTA_MAX, DELTA_MAX], "a": [-2.0, 2.0]}


def plant(**kw) -> DynamicBicycle:
    return DynamicBicycle(input_bounds=BOUNDS, **kw)


def objective(theta_w: float = 0.0) -> Objective:
    w = {"px": 1.0, "py": 1.0, "V": 1.0} | ({"theta": theta_w} if theta_w else {})
    return Objective({"tracking": QuadraticTracking(w, {"delta": 0.01, "a": 0.01})})


def controller(p: DynamicBicycle | None = None, **kw) -> ScheduledMPC:
    theta_w = kw.pop("theta_w", 0.0)
    return ScheduledMPC(p or plant(), objective(theta_w), **grouped(ScheduledMPC, **kw))


def ctx(target: np.ndarray) -> StepContext:
    return StepContext(goal=target[-1], target=target)


def random_target(rng: np.random.Generator, x: np.ndarray, T: int = 32) -> np.ndarray:
    """A previewed reference near ``x``: positions ahead, a speed, random offsets."""
    k = np.arange(T + 1)[:, None] * 0.02
    ref = np.zeros((T + 1, 6))
    ref[:, 0:2] = x[0:2] + k * rng.uniform(0.5, 2.5) * np.array(
        [math.cos(x[2]), math.sin(x[2])]
    ) + rng.normal(0, 0.5, 2)
    ref[:, 5] = rng.uniform(0.5, 2.5)
    ref[:, 2] = x[2] + rng.normal(0, 0.3)
    return ref


# ------------------------------------------------------------------ plant
def test_rhs_matches_the_study_equations() -> None:
    p = plant()
    x = np.array([1.0, -2.0, 0.7, 0.3, -0.05, 1.7])
    u = np.array([0.1, 0.5])
    m, lf, lr, I, Kf, Kr = 2000.0, 1.4, 1.6, 4000.0, 12e3, 11e3
    V = x[5]
    Ff = -2 * Kf * (x[4] + lf * x[3] / V - u[0])  # exact 1/V: V is above v_min
    Fr = -2 * Kr * (x[4] - lr * x[3] / V)
    expected = [V * math.cos(x[2]), V * math.sin(x[2]), x[3], (lf * Ff - lr * Fr) / I,
                (Ff + Fr) / (m * V) - x[3], u[1]]
    np.testing.assert_allclose(np.asarray(p.f(x, u)).ravel(), expected, rtol=1e-12)


def exact_plant(substeps: int) -> ca.Function:
    """The study's model with a plain 1/V (no guard), RK4 with ``substeps``, as F(x, u, dt)."""
    x, u, dt = ca.SX.sym("x", 6), ca.SX.sym("u", 2), ca.SX.sym("dt")
    _, _, th, r, b, V = ca.vertsplit(x)
    Ff = -2 * 12e3 * (b + 1.4 * r / V - u[0])
    Fr = -2 * 11e3 * (b - 1.6 * r / V)
    f = ca.Function("f", [x, u], [ca.vertcat(V * ca.cos(th), V * ca.sin(th), r,
                                             (1.4 * Ff - 1.6 * Fr) / 4000,
                                             (Ff + Fr) / (2000 * V) - r, u[1])])
    xn, h = x, dt / substeps
    for _ in range(substeps):
        k1 = f(xn, u)
        k2 = f(xn + h / 2 * k1, u)
        k3 = f(xn + h / 2 * k2, u)
        k4 = f(xn + h * k3, u)
        xn = xn + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return ca.Function("F", [x, u, dt], [xn, ca.jacobian(xn, x), ca.jacobian(xn, u)])


@pytest.mark.parametrize("dt", [0.02, 0.05])
def test_guard_is_exact_above_v_min(dt: float) -> None:
    """Above v_min the step and its Jacobians are the unguarded model's, to rounding."""
    p = plant()
    exact = exact_plant(p.substeps)
    rng = np.random.default_rng(3)
    for V in (0.56, 0.8, 1.0, 1.5, 2.0, 2.5, -1.0):  # stays above v_min = 0.5 over the step
        x = np.array([0.3, -0.2, rng.uniform(-3, 3), rng.normal(0, 0.2), rng.normal(0, 0.05), V])
        u = np.array([rng.uniform(-0.5, 0.5), rng.uniform(-1, 1)])
        xn, A, B = (np.asarray(v) for v in exact(x, u, dt))
        np.testing.assert_allclose(p.step(x, u, dt), xn.ravel(), rtol=1e-12, atol=1e-12)
        Ap, Bp = p.jacobians(x, u, dt)
        np.testing.assert_allclose(Ap, A, rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(Bp, B, rtol=1e-10, atol=1e-12)


def test_guard_is_bounded_smooth_and_zero_at_rest() -> None:
    p = plant()
    v = p.params.v_min
    V = ca.SX.sym("V")
    g = p.inv_speed(V)
    fn = ca.Function("g", [V], [g, ca.jacobian(g, V), ca.hessian(g, V)[0]])
    for side in (1.0, -1.0):  # value, slope and curvature meet 1/V at |V| = v_min (C^2)
        for eps in (1e-9, -1e-9):
            val, d1, d2 = (float(a) for a in fn(side * (v + eps)))
            Vm = side * v
            assert val == pytest.approx(1 / Vm, rel=1e-6)
            assert d1 == pytest.approx(-1 / Vm**2, rel=1e-6)
            assert d2 == pytest.approx(2 / Vm**3, rel=1e-6)
    grid = np.linspace(-v, v, 2001)
    vals = np.array([float(fn(Vi)[0]) for Vi in grid])
    assert np.all(np.abs(vals) <= 1.2429 / v)
    np.testing.assert_allclose(vals, -vals[::-1], atol=1e-12)  # odd
    assert float(fn(0.0)[0]) == 0.0


def test_v_guard_keeps_the_plant_finite_at_rest() -> None:
    p = plant()
    x0 = np.array([0.0, 0.0, 0.3, 0.2, 0.1, 0.0])
    u = np.array([0.4, 0.0])
    xdot = np.asarray(p.f(x0, u)).ravel()
    # at V = 0 the slip terms lf r / V and 1/(m V) vanish: beta' = -r, r' from the tyres
    Ff, Fr = -2 * 12e3 * (0.1 - 0.4), -2 * 11e3 * 0.1
    np.testing.assert_allclose(xdot, [0, 0, 0.2, (1.4 * Ff - 1.6 * Fr) / 4000, -0.2, 0],
                               atol=1e-12)
    for dt in (0.02, 0.05):
        assert np.all(np.isfinite(p.step(x0, u, dt)))
        A, B = p.jacobians(x0, u, dt)
        assert np.all(np.isfinite(A)) and np.all(np.isfinite(B))


@pytest.mark.parametrize("V", [1.3, 0.3, 0.02])  # above v_min, and on the quintic
def test_jacobians_match_finite_differences(V: float) -> None:
    p = plant()
    x = np.array([0.5, 0.2, 2.0, 0.3, 0.05, V])
    u = np.array([0.2, 0.4])  # a > 0: V stays on one side of v_min during the step
    A, B = p.jacobians(x, u, 0.05)
    h = 1e-6
    A_fd = np.column_stack([(p.step(x + h * e, u, 0.05) - p.step(x - h * e, u, 0.05)) / (2 * h)
                            for e in np.eye(6)])
    B_fd = np.column_stack([(p.step(x, u + h * e, 0.05) - p.step(x, u - h * e, 0.05)) / (2 * h)
                            for e in np.eye(2)])
    np.testing.assert_allclose(A, A_fd, atol=1e-7)
    np.testing.assert_allclose(B, B_fd, atol=1e-7)


@pytest.mark.parametrize("dt", [0.02, 0.05])
def test_substeps_keep_rk4_stable_at_every_speed(dt: float) -> None:
    """The configured substeps keep |lambda h| <= 2 (RK4's limit: 2.785) at any speed, and a
    lateral disturbance decays in simulation; one step at dt = 0.05 blows up at 0.35 m/s."""
    p = build(compose(["plant=dynamic_bicycle"]).plant, "plant")
    assert p.substeps == 2
    speeds = np.linspace(0.0, 3.0, 301)
    assert max(p.rk4_z(V, dt) for V in speeds) <= 2.0
    assert max(rk4_amplification(z) for V in speeds[1:]
               for z in p.lateral_eigenvalues(V) * dt / p.substeps) < 1.0

    def lateral_after(q: DynamicBicycle, n: int) -> float:
        x = np.array([0.0, 0.0, 0.0, 0.2, 0.05, 0.35])
        for _ in range(n):
            x = q.step(x, np.zeros(2), dt)
        return float(np.hypot(x[3], x[4]))

    assert lateral_after(p, 40) < 1e-3
    if dt == 0.05:
        assert lateral_after(plant(substeps=1), 40) > 1.0


# ------------------------------------------------------------------ models at operating points
@pytest.mark.parametrize("dt", [0.02, 0.05])
def test_linearization_with_offset_reproduces_the_nonlinear_step(dt: float) -> None:
    p = plant()
    ctrl = controller(p, dt=dt)
    assert len(ctrl.models) == 8
    u0 = np.zeros(2)
    for xbar, m in zip(ctrl.op_states, ctrl.models, strict=True):
        # the condensed model's first step at the operating point is the plant's own step
        x1 = (m.Px @ xbar + m.pc + m.Pu @ u0).reshape(-1, 6)[1]
        np.testing.assert_allclose(x1, p.step(xbar, u0, dt), atol=1e-12)
        # the whole horizon is the affine model (A, B, c) iterated (written out here)
        A, B, c = p.linearize(xbar, u0, dt)
        u = np.array([0.1, 0.3])
        X, xk = [xbar], xbar
        for _ in range(ctrl.horizon):
            xk = A @ xk + B @ u + c
            X.append(xk)
        np.testing.assert_allclose(m.Px @ xbar + m.Pu @ u + m.pc, np.ravel(X), atol=1e-9)
        # off the point the one-step error is second order: halving the offset quarters it
        e = np.array([0.0, 0.0, 0.2, 0.1, 0.02, 0.2])
        err = [np.linalg.norm(p.step(xbar + s * e, u0, dt) - (A @ (xbar + s * e) + c))
               for s in (1.0, 0.5)]
        assert 3.5 < err[0] / err[1] < 4.5


def test_operating_points_are_the_study_grid() -> None:
    ctrl = controller()
    pts = {(round(x[2], 6), x[5]) for x in ctrl.op_states}
    half = round(math.pi / 2, 6)
    assert pts == {(t, v) for t in (0.0, half, round(math.pi, 6), -half) for v in (1.0, 2.0)}
    for x in ctrl.op_states:
        assert not np.any(x[[0, 1, 3, 4]])


# ------------------------------------------------------------------ QP solvers
def reference_box_qp(H: np.ndarray, g: np.ndarray, lb: np.ndarray, ub: np.ndarray) -> np.ndarray:
    """SciPy's bounded-variable least squares (BVLS, an exact active-set method) on the same
    problem: with ``H = L L'``, ``1/2 z'Hz + g'z = 1/2 ||L'z + L^-1 g||^2 + const``."""
    L = np.linalg.cholesky(H)
    res = lsq_linear(L.T, -np.linalg.solve(L, g), bounds=(lb, ub), method="bvls", tol=1e-15)
    assert res.success
    return res.x


def random_qp(rng: np.random.Generator, n: int):
    Q = np.linalg.qr(rng.normal(size=(n, n)))[0]
    H = Q @ np.diag(10 ** rng.uniform(-1, 2, n)) @ Q.T
    lb = -rng.uniform(0.1, 2.0, n)
    ub = rng.uniform(0.1, 2.0, n)
    g = rng.normal(0, 1, n) * 10 ** rng.uniform(-1, 2)
    return H, g, lb, ub


def test_closed_form_matches_a_reference_qp_solver() -> None:
    rng = np.random.default_rng(4)
    active = 0
    for _ in range(300):
        H, g, lb, ub = random_qp(rng, 2)
        z = np.array(box_qp_2(H[0, 0], H[0, 1], H[1, 1], g[0], g[1], lb[0], ub[0], lb[1], ub[1]))
        z_ref = reference_box_qp(H, g, lb, ub)
        np.testing.assert_allclose(z, z_ref, atol=1e-8)
        active += bool(np.any(np.isclose(z, lb) | np.isclose(z, ub)))
    assert 100 < active < 300  # both interior and bound-constrained optima were exercised


def test_active_set_matches_a_reference_qp_solver() -> None:
    rng = np.random.default_rng(5)
    for n in (2, 4, 8):
        for _ in range(40):
            H, g, lb, ub = random_qp(rng, n)
            np.testing.assert_allclose(box_qp_active_set(H, g, lb, ub),
                                       reference_box_qp(H, g, lb, ub), atol=1e-8)


def test_backend_solvers_agree_in_the_controller() -> None:
    """closed form, active set (control horizon 1 and 3) and CVXPY (Clarabel on the compiled
    data, and through Problem.solve) give the same inputs."""
    p = plant()
    rng = np.random.default_rng(6)
    ctrls = {s: controller(p, solver=s) for s in ("closed_form", "active_set", "CLARABEL")}
    ctrls["problem"] = controller(p, solver="CLARABEL", via="problem")
    assert ctrls["problem"]._cvx.direct is None and ctrls["CLARABEL"]._cvx.direct is not None
    long = {s: controller(p, solver=s, control_horizon=3) for s in ("auto", "CLARABEL")}
    for _ in range(5):
        x = np.array([*rng.normal(0, 2, 2), rng.uniform(-4, 4), rng.normal(0, 0.2),
                      rng.normal(0, 0.05), rng.uniform(0.8, 2.2)])
        c = ctx(random_target(rng, x))
        u = {s: ctrl.step(0.0, x, c).u for s, ctrl in ctrls.items()}
        np.testing.assert_allclose(u["active_set"], u["closed_form"], atol=1e-10)
        np.testing.assert_allclose(u["CLARABEL"], u["closed_form"], atol=1e-6)
        np.testing.assert_allclose(u["problem"], u["closed_form"], atol=1e-6)
        ul = {s: ctrl.step(0.0, x, c) for s, ctrl in long.items()}
        np.testing.assert_allclose(ul["auto"].u_pred, ul["CLARABEL"].u_pred, atol=1e-6)


# ------------------------------------------------------------------ scheduling
def test_interpolation_at_a_grid_point_equals_that_points_model() -> None:
    p = plant()
    sw, ip = controller(p), controller(p, schedule={"mode": "interpolated"}, theta_w=0.5)
    sw_th = controller(p, theta_w=0.5)
    rng = np.random.default_rng(7)
    for op, xbar in enumerate(ip.op_states):
        for turns in (0, 1, -2):  # the heading is periodic: theta_op + 2 pi k is the same point
            x = xbar.copy()
            x[2] += 2 * math.pi * turns
            Px, Pu, pc = ip._model(x)
            m = ip.models[op]
            np.testing.assert_array_equal(Px, m.Px)
            np.testing.assert_array_equal(Pu, m.Pu)
            np.testing.assert_allclose(pc, m.pc + turns * m.x_shift, atol=1e-12)
            c = ctx(random_target(rng, x))
            np.testing.assert_allclose(ip.step(0.0, x, c).u, sw_th.step(0.0, x, c).u, atol=1e-10)
            sw.step(0.0, x, c)
    # half way between neighbours, across the -pi/2 .. 0 wrap and between the speeds
    x = np.array([0, 0, -math.pi / 4, 0, 0, 1.25])
    w = dict(ip.grid.weights(x))
    table = ip.operating_table()
    got = {(round(table.theta[op], 6), table.V[op]): round(v, 12) for op, v in w.items()}
    q = round(-math.pi / 2, 6)
    assert got == {(0.0, 1.0): 0.375, (0.0, 2.0): 0.125, (q, 1.0): 0.375, (q, 2.0): 0.125}


@pytest.mark.parametrize("thetas", [[0.0, math.pi / 2, math.pi, -math.pi / 2], [1.0, 2.0, -2.5]])
def test_nearest_operating_point_is_the_nearest_on_the_circle(thetas) -> None:
    ctrl = controller(schedule={"operating_points": {"theta": thetas, "V": [1.0, 1.5, 2.0]}})
    table = ctrl.operating_table()
    rng = np.random.default_rng(8)
    for _ in range(300):
        x = np.array([0, 0, rng.uniform(-20, 20), 0, 0, rng.uniform(0, 3)])
        dist = [abs(math.remainder(x[2] - th, 2 * math.pi)) + 10 * abs(x[5] - v)
                for th, v in zip(table.theta, table.V, strict=True)]
        assert ctrl.grid.nearest(x) == int(np.argmin(dist))


def test_switched_mode_hysteresis_delays_the_switch() -> None:
    plain = controller()
    hyst = controller(schedule={"hysteresis": {"theta": 0.1}})
    g = plain.grid
    at = g.nearest(np.array([0, 0, 0.0, 0, 0, 2.0]))
    past = np.array([0, 0, math.pi / 4 + 0.05, 0, 0, 2.0])
    assert plain.grid.switched(past, at) != at
    assert hyst.grid.switched(past, at) == at
    past[2] += 0.1
    assert hyst.grid.switched(past, at) != at


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"schedule": {"mode": "scheduled"}}, "valid: switched, interpolated, adaptive"),
        ({"schedule": {"operating_points": {"speed": [1.0]}}}, "unknown state label 'speed'"),
        ({"schedule": {"modes": "switched"}}, "unknown key 'modes' in controller.schedule"),
        ({"solver": "closed_form", "control_horizon": 2}, "needs 2 free variables"),
        ({"schedule": {"hysteresis": {"r": 0.1}}}, "not a scheduling state"),
        ({"control_horizon": 40}, "control_horizon must be in 1..32"),
    ],
)
def test_bad_options_are_named(options: dict, message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        controller(**options)
